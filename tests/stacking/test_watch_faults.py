# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""`watch_folder` against slow writers, a folder that goes away, and its own outputs."""

import os
import shutil
import threading
import time

import pytest
from astropy.nddata import CCDData

from astroalign_nd import register
from astroalign_nd.io import write_ccddata
from astroalign_nd.stacking import watch_folder

from _helpers import write_sequence


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return write_sequence(tmp_path_factory.mktemp("src"), 3, seed=4, n_stars=40,
                          noise_sigma=None)


def _write_slowly(data, path, n_chunks=4, pause=0.4):
    """A file written in chunks with pauses, as over a slow share or USB."""
    step = -(-len(data) // n_chunks)
    with open(path, "wb") as f:
        for k in range(0, len(data), step):
            f.write(data[k:k + step])
            f.flush()
            time.sleep(pause)


def test_a_slowly_written_file_is_stacked_once_complete(frames, tmp_path):
    watched = tmp_path / "watched"
    watched.mkdir()
    with open(frames[1], "rb") as f:
        data = f.read()
    writer = threading.Thread(target=_write_slowly, args=(data, watched / "slow.fits"))
    writer.start()
    try:
        # Pauses of 8 polls: the file is given up (unreadable) in between, then looked at
        # again when it grows.
        live = watch_folder(watched, frames[0], tmp_path / "stack.fits", interval=0.05,
                            timeout=3.0)
    finally:
        writer.join()
    assert live.used == ["f0.fits (reference)", "slow.fits"]
    assert live.rejected == []


def test_a_removed_folder_is_an_error_not_a_quiet_end(frames, tmp_path):
    watched = tmp_path / "watched"
    watched.mkdir()
    remover = threading.Timer(0.3, shutil.rmtree, args=(watched,))
    remover.start()
    try:
        with pytest.raises(OSError, match=r"the watched folder .*watched cannot be read any "
                           r"more .*removed, renamed or made unreadable"):
            watch_folder(watched, frames[0], tmp_path / "stack.fits", interval=0.05,
                         timeout=5.0)
    finally:
        remover.join()
    assert (tmp_path / "stack.fits").exists()  # the stack so far is kept


def test_the_package_own_outputs_are_set_aside_and_named(frames, tmp_path):
    watched = tmp_path / "watched"
    watched.mkdir()
    shutil.copy(frames[1], watched / "f1.fits")
    aligned = register(CCDData.read(frames[2]), CCDData.read(frames[0]))
    write_ccddata(aligned, watched / "f2_aligned.fits")
    seen = []
    live = watch_folder(watched, frames[0], tmp_path / "stack.fits", interval=0.05,
                        timeout=0.4, callback=lambda path, error: seen.append(
                            (os.path.basename(path), error)))
    assert live.used == ["f0.fits (reference)", "f1.fits"]
    assert [name for name, _ in live.rejected] == ["f2_aligned.fits"]
    assert "an astroalign_nd output" in live.rejected[0][1]
    assert ("f2_aligned.fits", live.rejected[0][1]) in seen  # named, not only counted
