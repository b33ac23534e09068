# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""read_transform / write_transform: ASDF and FITS files of one transform."""

import numpy as np
import pytest
from astropy.io import fits

from astroalign_nd import (AffineTransform, PolynomialTransform, ProjectiveTransform,
                           SimilarityTransform)
from astroalign_nd.io import read_transform, write_transform

MODELS = {
    "similarity": SimilarityTransform(scale=1.01, rotation=3.0, translation_x=5.0,
                                      translation_y=-2.0),
    "mirrored": SimilarityTransform(scale=0.99, rotation=-40.0, parity=-1),
    "affine": AffineTransform(a11=1.01, a12=0.02, a21=-0.01, a22=0.98, translation_x=3.0,
                              translation_y=4.0),
    "projective": ProjectiveTransform(h11=1.0, h12=0.01, h13=2.0, h21=0.0, h22=1.0,
                                      h23=-3.0, h31=1e-6, h32=0.0),
}


@pytest.mark.parametrize("suffix", [".asdf", ".fits"])
@pytest.mark.parametrize("name", list(MODELS))
def test_round_trip(tmp_path, name, suffix):
    model = MODELS[name]
    path = tmp_path / f"t{suffix}"
    write_transform(path, model)
    back = read_transform(path)
    assert type(back) is type(model)
    x, y = np.meshgrid(np.linspace(0, 2000, 5), np.linspace(0, 2000, 5))
    assert np.allclose(back(x, y), model(x, y), atol=1e-9)
    with pytest.raises(FileExistsError):
        write_transform(path, model)


def test_polynomial_round_trip(tmp_path):
    from astroalign_nd.simulate import simulate_pair
    from astroalign_nd import find_transform

    pair = simulate_pair((512, 512), n_stars=400, rotation=10.0, seed=4,
                         distortion={"k1": -0.02})
    model, _ = find_transform(pair.source, pair.target, transform_type="polynomial",
                              degree=3)
    assert isinstance(model, PolynomialTransform)
    for suffix in (".asdf", ".fits"):
        write_transform(tmp_path / f"p{suffix}", model)
        back = read_transform(tmp_path / f"p{suffix}")
        assert np.allclose(back(100.0, 200.0), model(100.0, 200.0), atol=1e-9)


@pytest.mark.parametrize("bad", ["parity: 0", "parity: 5", "scale: [1, 2]"])
def test_damaged_asdf_is_a_value_error(tmp_path, bad):
    path = tmp_path / "t.asdf"
    write_transform(path, MODELS["similarity"])
    text = path.read_bytes().decode("latin-1")
    key = bad.split(":")[0]
    lines = text.split("\n")
    for i, line in enumerate(lines):
        if line.strip().startswith(f"{key}:"):
            indent = line[: len(line) - len(line.lstrip())]
            lines[i] = indent + bad
            break
    else:
        pytest.fail(f"no {key} in the file")
    path.write_bytes("\n".join(lines).encode("latin-1"))
    with pytest.raises(ValueError, match=r"t\.asdf.*(parity|scale)"):
        read_transform(path)


def test_fits_without_transform_is_a_value_error(tmp_path):
    path = tmp_path / "plain.fits"
    fits.PrimaryHDU(header=fits.Header({"OBJECT": "M31"})).writeto(path)
    with pytest.raises(ValueError, match="plain.fits"):
        read_transform(path)


def test_not_a_file_format(tmp_path):
    with pytest.raises(ValueError, match="must end in .asdf"):
        write_transform(tmp_path / "t.txt", MODELS["similarity"])
    with pytest.raises(TypeError, match="astropy Model"):
        write_transform(tmp_path / "t.asdf", np.eye(3))
    (tmp_path / "junk.asdf").write_bytes(b"not asdf at all")
    with pytest.raises(ValueError, match="junk.asdf"):
        read_transform(tmp_path / "junk.asdf")


def test_bad_paths_are_clear(tmp_path):
    with pytest.raises(TypeError, match="path must be a file name"):
        read_transform(None)
    with pytest.raises(FileNotFoundError, match="does not exist; create it first"):
        write_transform(tmp_path / "missing" / "t.asdf", MODELS["similarity"])
    assert list(tmp_path.iterdir()) == []
