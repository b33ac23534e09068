# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Output formats behind one interface: batch output names and resume, and the
command line, go through `astroalign_nd.io.writers`, so a new format is one
`Writer`.
"""

import os

import numpy as np
import pytest
from astropy.io import fits

from astroalign_nd.batch import plan_outputs, register_batch
from astroalign_nd.cli import main
from astroalign_nd.io import (WRITERS, FITSWriter, Writer, atomic_write, output_suffixes,
                              register_writer, writer_for)
from astroalign_nd.simulate import simulate_pair

from _helpers import frame_error


class NpzWriter(Writer):
    """A toy format: pixels and header in a NumPy archive."""

    name, suffixes = "npz", (".npz",)

    def write(self, ccd, path, *, overwrite=False):
        with atomic_write(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
            np.savez(f, data=ccd.data, header=fits.Header(ccd.meta).tostring())

    def read_done(self, path):
        # Our own file object: np.load leaves its file open when the archive is damaged.
        with open(path, "rb") as fh, np.load(fh) as f:
            return fits.Header.fromstring(str(f["header"])), f["data"].shape


@pytest.fixture
def npz():
    writer = register_writer(NpzWriter())
    yield writer
    del WRITERS["npz"]


@pytest.fixture(scope="module")
def pair():
    return simulate_pair((192, 192), n_stars=120, rotation=4.0, translation=(6.3, -4.1),
                         seed=5)


def test_fits_is_the_builtin_and_default_writer():
    assert list(WRITERS) == ["fits"] and isinstance(WRITERS["fits"], FITSWriter)
    assert output_suffixes()[0] == ".fits"
    assert writer_for("night/M31_aligned.FITS.GZ").name == "fits"
    with pytest.raises(ValueError, match="no output format for 'a.png'.*.fits, .fit"):
        writer_for("a.png")
    # A suffix with an output format's ending is used as given.
    paths, _ = plan_outputs(["a.fits", "b.fit"], "out", suffix="_r.fits.gz")
    assert [os.path.basename(p) for p in paths] == ["a_r.fits.gz", "b_r.fits.gz"]
    paths, _ = plan_outputs(["a.fits"], "out", suffix="_r")
    assert os.path.basename(paths[0]) == "a_r.fits"


def test_register_writer_refuses_what_cannot_be_chosen(npz):
    with pytest.raises(TypeError, match="instance of astroalign_nd.io.Writer"):
        register_writer(NpzWriter)
    other = NpzWriter()
    other.name = "npz2"
    with pytest.raises(ValueError, match="shares the suffix"):
        register_writer(other)
    nameless = NpzWriter()
    nameless.name = None
    with pytest.raises(ValueError, match="needs a name"):
        register_writer(nameless)
    assert writer_for("x.NPZ") is npz and ".npz" in output_suffixes()


def test_a_new_format_end_to_end_through_register_batch(npz, pair, tmp_path):
    frames = [pair.source, np.rot90(pair.source, 2)]
    out = register_batch(frames, pair.target, output_dir=tmp_path, suffix="_aligned.npz",
                         workers=2)
    assert sorted(os.listdir(tmp_path)) == ["frame0_aligned.npz", "frame1_aligned.npz"]
    assert [f.status for f in out.frames] == ["registered"] * 2
    with np.load(tmp_path / "frame0_aligned.npz") as f:
        assert f["data"].shape == pair.target.shape
    # Resume reads the transforms back through the writer.
    again = register_batch(frames, pair.target, output_dir=tmp_path, suffix="_aligned.npz",
                           skip_existing=True)
    assert [f.status for f in again.frames] == ["skipped"] * 2
    for a, b in zip(out.frames, again.frames):
        np.testing.assert_allclose(b.transform.matrix, a.transform.matrix, atol=1e-9)
    assert frame_error(again.frames[0].transform, pair.truth_matrix, pair.target.shape) < 0.1
    # A damaged file is not complete: refused, or redone with overwrite.
    (tmp_path / "frame1_aligned.npz").write_bytes(b"PK\x03\x04 truncated")
    refused = register_batch(frames, pair.target, output_dir=tmp_path,
                             suffix="_aligned.npz", skip_existing=True)
    assert [f.status for f in refused.frames] == ["skipped", "failed"]
    assert "incomplete or unreadable" in refused.frames[1].error
    redone = register_batch(frames, pair.target, output_dir=tmp_path, suffix="_aligned.npz",
                            skip_existing=True, overwrite=True)
    assert [f.status for f in redone.frames] == ["skipped", "registered"]


def test_fits_resume_goes_through_the_writer(pair, tmp_path, monkeypatch):
    register_batch([pair.source], pair.target, output_dir=tmp_path)
    read = []
    original = FITSWriter.read_done

    def spy(self, path):
        read.append(os.path.basename(path))
        return original(self, path)

    monkeypatch.setattr(FITSWriter, "read_done", spy)
    again = register_batch([pair.source], pair.target, output_dir=tmp_path,
                           skip_existing=True)
    assert again.frames[0].status == "skipped" and read == ["frame0_aligned.fits"]


def test_the_command_line_writes_any_registered_format(npz, pair, tmp_path, capsys):
    src, ref = str(tmp_path / "s.fits"), str(tmp_path / "r.fits")
    fits.writeto(src, pair.source)
    fits.writeto(ref, pair.target)
    assert main(["register", src, ref, "-o", str(tmp_path / "out.npz")]) == 0
    header, shape = npz.read_done(str(tmp_path / "out.npz"))
    assert shape == pair.target.shape and header["AATTYPE"] == "similarity"
    assert main(["register", src, ref, "-o", str(tmp_path / "out.png")]) == 2
    assert ".npz" in capsys.readouterr().err
