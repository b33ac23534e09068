# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Detection where its first look misleads it: stars a little too wide for the
FWHM estimate's cutouts, and bright peaks that are not stars ahead of the
stars among the candidates.
"""

import warnings

import numpy as np
import pytest
from scipy.spatial import cKDTree

from astroalign_nd import find_sources
from astroalign_nd.detection import estimate_fwhm
from astroalign_nd.simulate import simulate_field


@pytest.mark.parametrize("fwhm", [8.0, 9.0])
def test_estimate_of_stars_just_too_wide_for_the_cutouts(fwhm):
    # 7 to 10 px: too wide for the estimate's 29-px cutouts, measured in
    # larger ones (before, the binned copies' floor of 10 px).
    image, _ = simulate_field((256, 256), n_stars=150, fwhm=fwhm, flux_range=(2e3, 2e5),
                              seed=11)
    assert estimate_fwhm(image) == pytest.approx(fwhm, rel=0.05)


def test_stars_of_nine_pixels_are_measured_at_their_width():
    image, _ = simulate_field((256, 256), n_stars=150, fwhm=9.0, flux_range=(2e3, 2e5),
                              seed=12)
    tab = find_sources(image, n_sources=40)
    # (Before: the scale ladder's widest trial, 10 px.)
    assert tab.meta["fwhm"] == pytest.approx(9.0, rel=0.05)
    assert tab.meta["fwhm_source"] == "estimate"
    assert len(tab) == 40


def _banded_field():
    """A sparse field whose bottom edge is a slanted band 2 sigma above the sky
    (a resampled frame's outside, filled at the wrong level): its noise peaks
    are brighter than most stars."""
    image, stars = simulate_field((512, 512), n_stars=120, fwhm=2.0, flux_range=(300, 3e4),
                                  background=1000.0, seed=2)
    yy, xx = np.mgrid[:512, :512]
    band = yy > 452 + 0.035 * xx
    return image + np.where(band, 2.0 * np.sqrt(1025.0), 0.0).astype(image.dtype), stars


def test_stars_behind_a_band_of_bright_peaks_are_found():
    image, stars = _banded_field()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tab = find_sources(image, n_sources=100, nsigma=3.0)
    # The band's peaks took most of the candidates: the stars are among
    # more of them, at the width the few stars found first measure.
    assert tab.meta["fwhm"] == pytest.approx(2.0, rel=0.2)
    d, _ = cKDTree(np.column_stack([stars["x"], stars["y"]])).query(
        np.column_stack([tab["x"], tab["y"]]))
    assert (d < 1.0).sum() >= 25
    # The image the caller passed is not modified.
    again, _ = _banded_field()
    np.testing.assert_array_equal(image, again)
