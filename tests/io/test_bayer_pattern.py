# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The Bayer pattern of raw colour frames: header keywords, a given pattern, the grey version."""

from pathlib import Path

import numpy as np
import pytest
from astropy.io import fits

from astroalign_nd.io.bayer import bayer_channels, bayer_pattern, superpixel, superpixel_to_raw
from astroalign_nd.transforms import EuclideanTransform, PolynomialTransform

SEESTAR = Path(__file__).resolve().parents[3] / "shared" / "data" / "seestar_raw"


@pytest.mark.parametrize("header, shape, expected", [
    ({"BAYERPAT": "GRBG"}, (4, 4), "GRBG"),
    ({"BAYERPAT": "rggb "}, (4, 4), "RGGB"),
    ({"BAYERPAT": "RGGB", "XBAYROFF": 1}, (4, 4), "GRBG"),
    ({"BAYERPAT": "RGGB", "YBAYROFF": 1}, (4, 4), "GBRG"),
    ({"BAYERPAT": "RGGB", "XBAYROFF": 1, "YBAYROFF": 1}, (4, 4), "BGGR"),
    ({"BAYERPAT": "RGGB", "ROWORDER": "TOP-DOWN"}, (4, 4), "RGGB"),
    # Flipped rows: the pattern's first row is the file's last one.
    ({"BAYERPAT": "RGGB", "ROWORDER": "BOTTOM-UP"}, (4, 4), "GBRG"),
    ({"BAYERPAT": "RGGB", "ROWORDER": "BOTTOM-UP"}, (5, 4), "RGGB"),
])
def test_pattern_from_header(header, shape, expected):
    assert bayer_pattern(header, shape=shape) == expected
    # The pattern found names the colours of the array's first cell: a flipped array
    # read from its own first row gives the pattern of the flipped rows.
    if header.get("ROWORDER") == "BOTTOM-UP":
        top_down = bayer_channels(shape, bayer_pattern({"BAYERPAT": header["BAYERPAT"]}))
        assert np.array_equal(bayer_channels(shape, expected), top_down[::-1])


def test_given_pattern_wins_and_bad_patterns_are_refused():
    assert bayer_pattern({"BAYERPAT": "RGGB", "XBAYROFF": 1}, "gbrg") == "GBRG"
    with pytest.raises(ValueError, match="no BAYERPAT.*bayer='GRBG'"):
        bayer_pattern({})
    with pytest.raises(ValueError, match="unknown Bayer pattern 'CYMG'.*RGGB, BGGR"):
        bayer_pattern({"BAYERPAT": "CYMG"})
    with pytest.raises(ValueError, match="unknown Bayer pattern 'RGB'"):
        bayer_pattern(pattern="RGB")
    with pytest.raises(TypeError, match="string such as 'GRBG'"):
        bayer_pattern(pattern=3)
    with pytest.raises(ValueError, match="XBAYROFF = 'a'"):
        bayer_pattern({"BAYERPAT": "RGGB", "XBAYROFF": "a"})
    with pytest.raises(ValueError, match="ROWORDER = 'SIDEWAYS'"):
        bayer_pattern({"BAYERPAT": "RGGB", "ROWORDER": "SIDEWAYS"})


@pytest.mark.skipif(not SEESTAR.is_dir(), reason="../shared/data/seestar_raw is absent")
def test_seestar_pattern_is_read_from_the_first_row():
    """
    The Seestar writes BAYERPAT = 'GRBG' and no ROWORDER: its two green sites (equal
    sky, equal star light) are the GRBG ones counted from the file's first row.
    """
    path = sorted(SEESTAR.glob("*.fit*"))[0]
    with fits.open(path) as hdul:
        data, header = hdul[0].data.astype(float), hdul[0].header
    pattern = bayer_pattern(header, shape=data.shape)
    assert pattern == "GRBG"
    channels = bayer_channels(data.shape, pattern)
    sky = {c: np.median(data[channels == c]) for c in range(3)}
    green = [np.median(data[dy::2, dx::2]) for dy, dx in ((0, 0), (1, 1))]
    assert abs(green[0] - green[1]) < 0.01 * sky[1]
    assert abs(sky[0] - sky[1]) > 0.1 * sky[1] and abs(sky[2] - sky[1]) > 0.1 * sky[1]


def test_superpixel_and_its_coordinates():
    raw = np.arange(30.0).reshape(5, 6)
    mask = np.zeros(raw.shape, bool)
    mask[3, 4] = True
    grey, gmask = superpixel(raw, mask)
    assert grey.shape == (2, 3) and grey[0, 0] == 0 + 1 + 6 + 7
    assert gmask.tolist() == [[False, False, False], [False, False, True]]
    # A superpixel shift of 1 is 2 raw pixels; a rotation turns about the cells' centres.
    t = EuclideanTransform(rotation=np.radians(3.0), translation_x=1.0, translation_y=-2.0)
    raw_t = superpixel_to_raw(t)
    assert isinstance(raw_t, EuclideanTransform)
    s = np.array([[0.0, 0.0], [10.0, 4.0], [-3.0, 7.5]])
    xs, ys = t(s[:, 0], s[:, 1])
    xr, yr = raw_t(2 * s[:, 0] + 0.5, 2 * s[:, 1] + 0.5)
    np.testing.assert_allclose(xr, 2 * xs + 0.5, atol=1e-9)
    np.testing.assert_allclose(yr, 2 * ys + 0.5, atol=1e-9)
    # A distortion model goes through the same conversions.
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 100, (30, 2))
    dst = src + 1.0 + 1e-4 * src ** 2
    poly = PolynomialTransform.from_points(src, dst, degree=2)
    xp, yp = superpixel_to_raw(poly)(2 * s[:, 0] + 0.5, 2 * s[:, 1] + 0.5)
    xq, yq = poly(s[:, 0], s[:, 1])
    np.testing.assert_allclose(xp, 2 * np.asarray(xq) + 0.5, atol=1e-6)
    np.testing.assert_allclose(yp, 2 * np.asarray(yq) + 0.5, atol=1e-6)
