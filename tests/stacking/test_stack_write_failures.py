# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
A disk that fills up while `stack` writes its registered frames: one line that says where and
what to do (in the stack's own options, not the batch's), and no stack written; with every
way of combining (drizzle, the quality selection and weights).
"""

import errno
import os

import pytest
from _helpers import run_cli, write_sequence

import astroalign_nd.io.write as write_mod


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return write_sequence(tmp_path_factory.mktemp("frames"), 4, seed=8, shape=(80, 80))


@pytest.mark.parametrize("extra", [[], ["--drizzle", "2"], ["--select", "auto"]])
def test_a_full_disk_while_registering_is_one_line_and_no_stack(
        frames, tmp_path, monkeypatch, extra):
    def publish(self, path, overwrite):  # the disk is full from the first registered frame on
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(write_mod._PrivateFolder, "publish", publish)
    out, kept = tmp_path / "st.fits", tmp_path / "registered"
    code, _, err = run_cli("stack", *frames, "-o", out, "--aligned-dir", kept, "--no-progress",
                           *extra)
    assert code == 2
    (line,) = err.strip().splitlines()
    assert line.startswith("astroalign-nd: error: the stack stopped at f1.fits: cannot write ")
    assert "the disk is full" in line and "nothing was written" in line
    assert f"The registered frames go to {kept} before they are combined: free some space " \
           "there, or give --aligned-dir a folder on another disk." in line
    assert "skip" not in line and "batch" not in line and "aligned_dir" not in line
    assert not out.exists() and not kept.exists()  # the folder it made is removed, empty
