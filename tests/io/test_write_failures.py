# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""A write that fails (a full disk, a removed folder) gives one clear error and no file."""

import errno
import gzip
import os
from types import SimpleNamespace

import numpy as np
import pytest
from astropy.io import fits
from astropy.nddata import CCDData

from astroalign_nd import SimilarityTransform
from astroalign_nd.cli.main import main
from astroalign_nd.io import read_transform, write_ccddata, write_transform
from astroalign_nd.io import write as write_module


def _full_disk_write(self, f, **kwargs):
    """What astropy.io.fits does on a full disk with a file object: part of the file, an
    OSError, then an AttributeError of its own while it checks the free space."""
    f.write(b"SIMPLE  =" + b" " * 100)
    try:
        raise OSError(errno.ENOSPC, "No space left on device")
    except OSError:
        [].name  # noqa: B018 - the AttributeError astropy raises while handling it


@pytest.fixture
def ccd():
    return CCDData(np.arange(20, dtype=np.float32).reshape(4, 5), unit="adu")


def test_full_disk_is_one_clear_oserror(ccd, tmp_path, monkeypatch):
    monkeypatch.setattr(CCDData, "write", _full_disk_write)
    path = tmp_path / "out.fits"
    with pytest.raises(OSError, match="cannot write .*out.fits: the disk is full") as info:
        write_ccddata(ccd, path)
    assert info.value.errno == errno.ENOSPC
    assert "nothing was written" in str(info.value)
    assert os.listdir(tmp_path) == []  # no partial file, no private folder left


def test_short_write_without_errno_is_named_by_the_free_space(ccd, tmp_path, monkeypatch):
    def short_write(self, f, **kwargs):
        raise OSError("262144 requested and 49760 written")

    monkeypatch.setattr(CCDData, "write", short_write)
    monkeypatch.setattr(write_module.shutil, "disk_usage",
                        lambda folder: SimpleNamespace(total=1, used=1, free=0))
    with pytest.raises(OSError, match="the disk is full"):
        write_ccddata(ccd, tmp_path / "out.fits")
    assert os.listdir(tmp_path) == []


def test_other_errors_pass_through(ccd, tmp_path, monkeypatch):
    def bad(self, f, **kwargs):
        raise ValueError("a writer's own complaint")

    monkeypatch.setattr(CCDData, "write", bad)
    with pytest.raises(ValueError, match="a writer's own complaint"):
        write_ccddata(ccd, tmp_path / "out.fits")
    assert os.listdir(tmp_path) == []


def test_full_disk_through_the_command_line(tmp_path, monkeypatch, capsys):
    assert main(["demo", "--output-dir", str(tmp_path / "demo")]) == 0
    capsys.readouterr()
    monkeypatch.setattr(CCDData, "write", _full_disk_write)
    out = tmp_path / "aligned.fits"
    code = main(["register", str(tmp_path / "demo" / "source.fits"),
                 str(tmp_path / "demo" / "target.fits"), "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines == [f"astroalign-nd: error: cannot write {out}: the disk is full; free some "
                     "space or write to another disk (No space left on device); nothing "
                     "was written."]
    assert "AttributeError" not in err
    assert not out.exists()


def test_transform_to_a_gz_name_is_compressed(tmp_path):
    t = SimilarityTransform(scale=1.01, rotation=3.0, translation_x=5.0, translation_y=-2.0)
    path = tmp_path / "t.fits.gz"
    write_transform(path, t)
    with open(path, "rb") as f:
        assert f.read(2) == b"\x1f\x8b"  # gzip's magic number
    with gzip.open(path) as f, fits.open(f) as hdul:
        assert hdul[0].header["AATTYPE"] == "similarity"
    back = read_transform(path)
    x, y = np.array([0.0, 100.0, 500.0]), np.array([0.0, 300.0, 20.0])
    np.testing.assert_allclose(back(x, y), t(x, y), atol=1e-9)
