# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""stack(drizzle=...): resolution, flux, uncertainty, rejection, WCS, bad input."""

import warnings

import numpy as np
import pytest
from astropy.io import fits
from astropy.modeling import fitting, models
from astropy.wcs import WCS
from scipy.ndimage import zoom

from astroalign_nd import stack
from astroalign_nd.simulate import (add_satellite_trail, dither_transforms, render_stars,
                                    simulate_views)
from astroalign_nd.stacking.drizzle import pixel_map, scaled_wcs
from astroalign_nd.transforms import PolynomialTransform

SHAPE, S, FWHM, SKY = (96, 96), 2, 0.9, 100.0


@pytest.fixture(scope="module")
def sequence():
    """16 undersampled frames (0.9 px FWHM), sub-pixel dithers and rotations; the truth."""
    ts = dither_transforms(16, max_shift=3.0, max_rotation=1.0, shape=SHAPE, seed=21)
    seq = simulate_views(ts, SHAPE, n_stars=45, fwhm=FWHM, flux_range=(3e3, 4e4),
                         background=SKY, read_noise=5.0, gain=1.0, seed=22)
    st = seq.stars
    x, y = S * (np.asarray(st["x"]) + 0.5) - 0.5, S * (np.asarray(st["y"]) + 0.5) - 0.5
    fine = (SHAPE[0] * S, SHAPE[1] * S)
    truth = render_stars(fine, x, y, st["flux"], fwhm=FWHM * S, out=np.full(fine, SKY / S ** 2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        drizzled = stack(seq.frames, drizzle=S, pixfrac=0.5, gain=1.0, read_noise=5.0)
    return seq, (x, y, np.asarray(st["flux"])), truth, drizzled


def _stars(x, y, flux, shape):
    """Bright isolated stars inside, and the pixels far from every star."""
    d = np.hypot(x[:, None] - x[None], y[:, None] - y[None])
    np.fill_diagonal(d, np.inf)
    m = 8 * S
    pick = (flux > 5e3) & (d.min(axis=1) > 6 * S) & (x > m) & (y > m) & \
        (x < shape[1] - m) & (y < shape[0] - m)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    free = np.ones(shape, dtype=bool)
    for xi, yi in zip(x, y):
        free &= np.hypot(xx - xi, yy - yi) > 5 * S
    free[:16], free[-16:], free[:, :16], free[:, -16:] = False, False, False, False
    return pick, free


def _fwhm_flux(img, x, y, flux, pick, sky):
    h = 4 * S
    yy, xx = np.mgrid[-h:h + 1, -h:h + 1]
    fwhm, err = [], []
    for xi, yi, f in zip(x[pick], y[pick], flux[pick]):
        r0, c0 = int(round(yi)), int(round(xi))
        cut = img[r0 - h:r0 + h + 1, c0 - h:c0 + h + 1] - sky
        err.append(cut[np.hypot(xx, yy) <= h].sum() / f - 1)
        g = fitting.LevMarLSQFitter()(models.Gaussian2D(cut.max(), xi - c0, yi - r0, 1, 1),
                                      xx, yy, cut)
        fwhm.append(2.3548 * np.sqrt(abs(g.x_stddev.value * g.y_stddev.value)) / S)
    return np.median(fwhm), np.median(err)


def test_drizzle_sharper_flux_and_uncertainty(sequence):
    seq, (x, y, flux), truth, d = sequence
    pick, free = _stars(x, y, flux, truth.shape)
    assert pick.sum() >= 5
    assert d.shape == truth.shape and not d.mask[free].any()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = stack(seq.frames, gain=1.0, read_noise=5.0)
    up = zoom(np.nan_to_num(plain.data, nan=SKY), S, order=3, grid_mode=True,
              mode="nearest") / S ** 2
    fw_d, err_d = _fwhm_flux(d.data, x, y, flux, pick, np.median(d.data[free]))
    fw_s, _ = _fwhm_flux(up, x, y, flux, pick, np.median(up[free]))
    assert fw_d < 0.85 * fw_s  # resolution back from the dithers
    assert abs(err_d) < 0.01  # flux conserved
    r = ((d.data - truth) / d.uncertainty.array)[free]
    assert 0.9 < np.std(r) < 1.1  # the uncertainty is the scatter's
    assert d.meta["AADRIZ"] == 2 and d.meta["AADZKERN"] == "square"
    assert d.flags.max() == 16 and d.meta["AADZEMPT"] == 0
    assert sum("drizzled frame" in str(h) for h in d.meta["HISTORY"]) == 16


def _with_outliers(frames):
    """A trail in frame 3, cosmic rays (single hot pixels) in frames 3 and 9."""
    out = [np.array(f, dtype=float) for f in frames]
    out[3] = add_satellite_trail(out[3], (-5, 20), (100, 80), amplitude=800.0)
    rng = np.random.default_rng(5)
    for k in (3, 9):
        r, c = rng.integers(8, 88, 25), rng.integers(8, 88, 25)
        out[k][r, c] += 3000.0
    return out


def test_rejection_before_drizzling(sequence, tmp_path):
    seq, (x, y, flux), truth, clean = sequence
    frames = _with_outliers(seq.frames)
    out = tmp_path / "d.fits"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = stack(frames, drizzle=S, pixfrac=0.5, gain=1.0, read_noise=5.0, output=out)
        raw = stack(frames, drizzle=S, pixfrac=0.5, gain=1.0, read_noise=5.0, clip=None)
    # Off the stars (whose undersampled cores the clipping also trims, differently
    # with other outliers among the frames): where the trail and the hits fall.
    _, sky = _stars(x, y, flux, truth.shape)
    dev = ((d.data - clean.data) / clean.uncertainty.array)[sky]
    dev_raw = ((raw.data - clean.data) / clean.uncertainty.array)[sky]
    assert np.nanmax(dev_raw) > 5  # without the rejection the trail and hits stay
    assert np.nanmax(dev) < 5  # with it: nothing above 5 sigma
    with fits.open(out) as hdul:
        assert {"WEIGHT", "FLAGS", "UNCERT", "MASK"} <= {h.name for h in hdul}
        assert hdul["WEIGHT"].data.shape == truth.shape


@pytest.mark.parametrize("kw, what", [({"drizzle": 0}, "drizzle"),
                                      ({"drizzle": -2}, "drizzle"),
                                      ({"drizzle": 2, "pixfrac": 0}, "pixfrac"),
                                      ({"drizzle": 2, "pixfrac": 1.5}, "pixfrac"),
                                      ({"drizzle": 2, "kernel": "cubic"}, "kernel"),
                                      ({"drizzle": 2, "method": "median"}, "median")])
def test_bad_drizzle_options(kw, what):
    with pytest.raises(ValueError, match=what):
        stack([np.zeros((8, 8)), np.zeros((8, 8))], **kw)


def test_the_kernel_option_lists_the_drizzle_packages_kernels():
    # The option declares the list itself (the CLI imports no drizzle): it must stay drizzle's.
    from drizzle.resample import SUPPORTED_DRIZZLE_KERNELS

    from astroalign_nd.stacking.drizzle import DRIZZLE_KERNELS
    assert set(DRIZZLE_KERNELS) == set(SUPPORTED_DRIZZLE_KERNELS)


def test_pixel_map_of_a_polynomial_and_sip_scaled_wcs():
    t = PolynomialTransform(degree=2, A_2_0=1e-4, translation_x=1.0)
    pm = pixel_map(t, (5, 200), scale=2, offset=(-3, 0))
    xo, yo = t(100.0, 2.0)
    assert np.allclose(pm[2, 100], [2 * (xo + 3 + 0.5) - 0.5, 2 * (yo + 0.5) - 0.5])
    h = fits.Header({"CTYPE1": "RA---TAN-SIP", "CTYPE2": "DEC--TAN-SIP", "CRVAL1": 10.0,
                     "CRVAL2": 20.0, "CRPIX1": 40.0, "CRPIX2": 30.0, "CD1_1": -1e-3,
                     "CD1_2": 1e-5, "CD2_1": 2e-5, "CD2_2": 1e-3, "A_ORDER": 2, "B_ORDER": 2,
                     "A_2_0": 1e-4, "B_0_2": -1e-4, "NAXIS": 2, "NAXIS1": 100, "NAXIS2": 80})
    w = WCS(h)
    fine = scaled_wcs(w, 2.0, (160, 200), offset=(-5, 7))
    X, Y = np.array([3.0, 70.0, 99.0]), np.array([5.0, 60.0, 79.0])
    a = np.array(w.pixel_to_world_values(X, Y))
    b = np.array(fine.pixel_to_world_values(2 * (X + 5 + 0.5) - 0.5, 2 * (Y - 7 + 0.5) - 0.5))
    assert np.abs(a - b).max() * 3600 < 1e-6


def test_live_stack_drizzles_each_frame_as_it_arrives(sequence):
    from astroalign_nd.stacking import LiveStack

    seq, (x, y, flux), truth, _ = sequence
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        live = LiveStack(seq.frames[0], drizzle=S, pixfrac=0.7, gain=1.0, read_noise=5.0)
        for k, f in enumerate(seq.frames[1:8], start=1):
            live.add(f, name=f"frame{k}")
        d = live.result()
    _, free = _stars(x, y, flux, truth.shape)
    assert d.shape == truth.shape and d.flags.max() == 8 and d.meta["AADRIZ"] == 2
    assert 0.9 < np.std(((d.data - truth) / d.uncertainty.array)[free]) < 1.1
    assert d.weight.shape == truth.shape
