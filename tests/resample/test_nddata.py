# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
CCDData output of `register` and `apply_transform` (issue 3): every input
kind, every uncertainty class, mask propagation and flux conservation
against the simulator's truth, header/WCS bookkeeping, a ccdproc stack, and
the command line.
"""

import copy

import numpy as np
import pytest
from astropy import units as u
from astropy.io import fits
from astropy.nddata import (CCDData, InverseVariance, NDData, StdDevUncertainty,
                            VarianceUncertainty)
from astropy.table import Table
from astropy.wcs import WCS
from numpy.testing import assert_allclose, assert_array_equal

from astroalign_nd import apply_transform, find_transform, register, transform_from_header
from astroalign_nd.resample import resample
from astroalign_nd.simulate import simulate_image, simulate_pair
from astroalign_nd.transforms import SimilarityTransform, TranslationTransform

ORDER_NAMES = ("nearest-neighbor", "bilinear", "biquadratic", "bicubic")
UNCERTAINTY_CLASSES = (StdDevUncertainty, VarianceUncertainty, InverseVariance)

# Numbers of the flux-conservation measurement, printed at the end of the module
# (run with ``pytest -s`` to see them).
FLUX_REPORT = {}


# -- shared data -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def pair():
    """A small pair with a generic similarity transform (rotation, shift, scale)."""
    return simulate_pair((160, 160), n_stars=80, rotation=17.0, scale=1.05,
                         translation=(3.3, -2.1), flux_range=(2e3, 2e5), seed=11)


def _simple_tan_wcs(crpix=(60.0, 70.0), crval=(10.0, 20.0), use_cd=False, scale=1e-4,
                    rot_deg=0.0):
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = list(crval)
    w.wcs.crpix = list(crpix)
    c, s = np.cos(np.radians(rot_deg)), np.sin(np.radians(rot_deg))
    if use_cd:
        w.wcs.cd = scale * np.array([[-c, s], [s, c]])
    else:
        w.wcs.cdelt = [-scale, scale]
        w.wcs.pc = np.array([[c, -s], [s, c]])
    return w


def _output_source_coords(matrix, shape):
    """Source position (u, v) of every output pixel centre, from the true matrix."""
    inv = np.linalg.inv(matrix)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    return (inv[0, 0] * xx + inv[0, 1] * yy + inv[0, 2],
            inv[1, 0] * xx + inv[1, 1] * yy + inv[1, 2])


def _snapshot(obj):
    return copy.deepcopy(obj)


# -- input kinds ----------------------------------------------------------------------------


def test_ndarray_input(pair):
    out = apply_transform(pair.transform, pair.source, pair.target)
    assert isinstance(out, CCDData)
    assert out.shape == pair.target.shape
    assert out.unit == u.adu
    assert out.mask is not None and out.mask.dtype == bool and out.mask.shape == out.shape
    assert out.uncertainty is None
    assert out.wcs is None
    assert np.all(np.isfinite(out.data[~out.mask]))
    assert np.all(np.isnan(out.data[out.mask]))
    # unit= sets the unit of unitless input
    out_e = apply_transform(pair.transform, pair.source, pair.target, unit="electron")
    assert out_e.unit == u.electron
    assert_array_equal(out_e.data, out.data)


def test_register_ndarray_end_to_end(pair):
    out = register(pair.source, pair.target)
    assert isinstance(out, CCDData)
    t = transform_from_header(out.meta)
    ms = pair.matched_stars()
    xt, yt = t(ms["x_source"], ms["y_source"])
    err = np.hypot(xt - ms["x_target"], yt - ms["y_target"])
    assert np.max(err) < 0.1


def test_masked_array_input_mask_propagates(pair):
    data = pair.source.copy()
    mask = np.zeros(data.shape, bool)
    mask[70, 80] = True
    masked = np.ma.MaskedArray(data, mask=mask)
    out = apply_transform(pair.transform, masked, pair.target, order="bilinear")
    xt, yt = pair.transform(80.0, 70.0)
    iy, ix = int(round(float(yt))), int(round(float(xt)))
    # bilinear uses every source pixel within 1 px: the output pixel nearest to
    # the transformed position is within 0.75 px of it (scale 1.05)
    assert out.mask[iy, ix]
    plain = apply_transform(pair.transform, data, pair.target, order="bilinear")
    assert not plain.mask[iy, ix]
    assert out.mask.sum() > plain.mask.sum()
    # register() with the masked array: the mask reaches the output too
    reg = register(masked, pair.target, order="bilinear")
    assert reg.mask[iy, ix]


def test_nddata_input(pair):
    mask = np.zeros(pair.source.shape, bool)
    mask[70, 80] = True
    nd = NDData(pair.source.copy(), mask=mask, meta={"OBJECT": "field-1"})
    out = apply_transform(pair.transform, nd, pair.target, order="bilinear")
    assert isinstance(out, CCDData)
    assert out.unit == u.adu  # NDData without unit -> adu
    assert out.meta["OBJECT"] == "field-1"
    xt, yt = pair.transform(80.0, 70.0)
    assert out.mask[int(round(float(yt))), int(round(float(xt)))]
    nd_unit = NDData(pair.source.copy(), unit="electron")
    assert register(nd_unit, pair.target).unit == u.electron


def test_ccddata_input_keeps_unit_meta_mask(pair):
    mask = np.zeros(pair.source.shape, bool)
    mask[70, 80] = True
    ccd = CCDData(pair.source.copy(), unit=u.electron / u.s, mask=mask,
                  meta={"OBJECT": "M 31", "EXPTIME": 30.0})
    out = register(ccd, CCDData(pair.target, unit=u.electron / u.s))
    assert out.unit == u.electron / u.s
    assert out.meta["OBJECT"] == "M 31"
    assert out.meta["EXPTIME"] == 30.0
    xt, yt = pair.transform(80.0, 70.0)
    assert out.mask[int(round(float(yt))), int(round(float(xt)))]


@pytest.mark.parametrize("kind", ["path", "hdu", "hdulist"])
def test_fits_input_bunit_header_wcs(pair, tmp_path, kind):
    w_src = _simple_tan_wcs(crpix=(80.0, 80.0))
    w_tgt = _simple_tan_wcs(crpix=(81.0, 79.0), crval=(10.001, 20.002))
    hdr = w_src.to_header()
    hdr["BUNIT"] = "electron"
    hdr["OBJECT"] = "NGC 1234"
    hdr["EXPTIME"] = (120.0, "exposure time [s]")
    hdr["FILTER"] = "R"
    hdu = fits.PrimaryHDU(pair.source.copy(), header=hdr)
    thdr = w_tgt.to_header()
    thdr["BUNIT"] = "electron"
    thdu = fits.PrimaryHDU(pair.target.copy(), header=thdr)
    if kind == "path":
        src, tgt = tmp_path / "src.fits", tmp_path / "tgt.fits"
        hdu.writeto(src)
        thdu.writeto(tgt)
        src, tgt = str(src), str(tgt)
    elif kind == "hdu":
        src, tgt = hdu, thdu
    else:
        src, tgt = fits.HDUList([hdu]), fits.HDUList([thdu])
    out = register(src, tgt)
    assert out.unit == u.electron
    assert out.meta["OBJECT"] == "NGC 1234"
    assert out.meta["EXPTIME"] == 120.0
    assert out.meta.comments["EXPTIME"] == "exposure time [s]"
    assert out.meta["FILTER"] == "R"
    # the target's WCS defines the output grid's sky coordinates
    assert out.wcs is not None
    xp, yp = np.array([0.0, 40.0, 159.0]), np.array([3.0, 100.0, 150.0])
    assert_allclose(np.array(out.wcs.pixel_to_world_values(xp, yp)),
                    np.array(w_tgt.pixel_to_world_values(xp, yp)), atol=1e-12, rtol=0)
    # the source's WCS cards no longer describe the output grid: they must not survive
    # in the header where they would contradict out.wcs when written
    wcs_hdr = out.wcs.to_header()
    for key in ("CRPIX1", "CRPIX2", "CRVAL1", "CRVAL2"):
        assert key not in out.meta or out.meta[key] == pytest.approx(wcs_hdr[key])
    # write and read back: unit and WCS survive the FITS round trip
    path = tmp_path / f"out_{kind}.fits"
    out.write(path)
    back = CCDData.read(path)
    assert back.unit == u.electron
    assert_allclose(np.array(back.wcs.pixel_to_world_values(xp, yp)),
                    np.array(w_tgt.pixel_to_world_values(xp, yp)), atol=1e-10, rtol=0)
    assert back.meta["OBJECT"] == "NGC 1234"


def test_fits_nan_pixels_are_masked(pair):
    data = pair.source.copy()
    data[70, 80] = np.nan
    out = apply_transform(pair.transform, fits.PrimaryHDU(data), pair.target,
                          order="bilinear")
    xt, yt = pair.transform(80.0, 70.0)
    assert out.mask[int(round(float(yt))), int(round(float(xt)))]
    assert np.all(np.isfinite(out.data[~out.mask]))


def _rgb(source):
    rng = np.random.default_rng(5)
    return np.stack([source, 0.5 * source + 10.0,
                     2.0 * source + rng.normal(0, 3, source.shape).astype(np.float32)],
                    axis=-1).astype(np.float32)


def test_multichannel_apply_each_channel_equals_single(pair):
    rgb = _rgb(pair.source)
    rgb[30, 40, 1] = np.nan  # one bad channel masks every channel there
    out = apply_transform(pair.transform, rgb, pair.target)
    assert out.shape == pair.target.shape + (3,)
    assert out.mask.shape == out.shape
    # one mask for all channels
    assert np.all(out.mask == out.mask[..., :1])
    mask2d = out.mask[..., 0]
    for c in range(3):
        single = apply_transform(pair.transform, np.ascontiguousarray(rgb[..., c]),
                                 pair.target)
        good = ~mask2d
        assert_array_equal(out.data[..., c][good], single.data[good])
        assert np.all(single.mask <= mask2d)  # single-channel mask is a subset
    xt, yt = pair.transform(40.0, 30.0)
    assert mask2d[int(round(float(yt))), int(round(float(xt)))]
    # the NaN of channel 1 only masks channel 0 where channel 0 alone is fine
    single0 = apply_transform(pair.transform, np.ascontiguousarray(rgb[..., 0]), pair.target)
    assert not single0.mask[int(round(float(yt))), int(round(float(xt)))]


def test_multichannel_register_detects_on_mean(pair):
    rgb = _rgb(pair.source)
    out = register(rgb, pair.target)
    assert out.shape == pair.target.shape + (3,)
    t_rgb = transform_from_header(out.meta)
    t_mean, _ = find_transform(rgb.mean(axis=2, dtype=np.float32), pair.target)
    x = np.array([0.0, 80.0, 159.0, 10.0])
    y = np.array([0.0, 80.0, 159.0, 150.0])
    assert_allclose(np.array(t_rgb(x, y)), np.array(t_mean(x, y)), atol=1e-9, rtol=0)
    # every channel is resampled with that transform
    for c in range(3):
        single = apply_transform(t_mean, np.ascontiguousarray(rgb[..., c]), pair.target)
        good = ~out.mask[..., 0]
        assert_allclose(out.data[..., c][good], single.data[good], rtol=1e-6, atol=1e-3)


@pytest.mark.parametrize("cls", UNCERTAINTY_CLASSES)
def test_multichannel_uncertainty(cls):
    rng = np.random.default_rng(8)
    data = rng.normal(100.0, 5.0, (40, 50, 3))
    var = rng.uniform(1.0, 9.0, data.shape)
    ccd = CCDData(data, unit=u.electron, uncertainty=_uncertainty(cls, var))
    t = TranslationTransform(translation_x=3.0, translation_y=-2.0)
    out = apply_transform(t, ccd, (40, 50), order="bicubic")
    assert type(out.uncertainty) is cls
    assert out.uncertainty.array.shape == data.shape
    assert_allclose(np.asarray(out.uncertainty.array)[:38, 3:],
                    np.asarray(ccd.uncertainty.array)[2:, :47], rtol=1e-14)


# -- uncertainty classes ------------------------------------------------------------------


def _uncertainty(cls, var):
    if cls is StdDevUncertainty:
        return StdDevUncertainty(np.sqrt(var), unit=u.electron)
    if cls is VarianceUncertainty:
        return VarianceUncertainty(var, unit=u.electron**2)
    return InverseVariance(1.0 / var, unit=u.electron**-2)


def _as_variance(unc):
    with np.errstate(divide="ignore"):  # InverseVariance 0 (masked) -> variance inf
        return np.asarray(unc.represent_as(VarianceUncertainty).array, float)


@pytest.fixture(scope="module")
def noisy_frame():
    rng = np.random.default_rng(3)
    data = rng.normal(100.0, 10.0, (48, 64))
    var = rng.uniform(1.0, 50.0, data.shape)
    return data, var


@pytest.mark.parametrize("cls", UNCERTAINTY_CLASSES)
@pytest.mark.parametrize("order", ["bilinear", "bicubic"])
def test_uncertainty_integer_shift_moves_exactly(noisy_frame, cls, order):
    data, var = noisy_frame
    ccd = CCDData(data, unit=u.electron, uncertainty=_uncertainty(cls, var))
    t = TranslationTransform(translation_x=3.0, translation_y=-2.0)
    out = apply_transform(t, ccd, data.shape, order=order)
    assert type(out.uncertainty) is cls
    assert out.uncertainty.unit == ccd.uncertainty.unit
    ny, nx = data.shape
    # out[y, x] = in[y + 2, x - 3]
    sl_out = (slice(0, ny - 2), slice(3, nx))
    sl_in = (slice(2, ny), slice(0, nx - 3))
    assert_array_equal(out.data[sl_out], data[sl_in])
    assert_allclose(np.asarray(out.uncertainty.array)[sl_out],
                    np.asarray(ccd.uncertainty.array)[sl_in], rtol=1e-14, atol=0)
    expected_mask = np.ones(data.shape, bool)
    expected_mask[sl_out] = False
    assert_array_equal(out.mask, expected_mask)
    var_out = _as_variance(out.uncertainty)
    assert np.all(np.isinf(var_out[out.mask]))


@pytest.mark.parametrize("cls", UNCERTAINTY_CLASSES)
def test_uncertainty_half_pixel_bilinear_squared_weights(noisy_frame, cls):
    data, var = noisy_frame
    ccd = CCDData(data, unit=u.electron, uncertainty=_uncertainty(cls, var))
    # source x = x' - 0.5 (weights 1/2, 1/2 on columns x'-1, x');
    # source y = y' - 0.25 (weights 1/4, 3/4 on rows y'-1, y')
    t = TranslationTransform(translation_x=0.5, translation_y=0.25)
    out = apply_transform(t, ccd, data.shape, order="bilinear")
    assert type(out.uncertainty) is cls
    wx, wy = (0.5, 0.5), (0.25, 0.75)
    exp_data = np.full(data.shape, np.nan)
    exp_var = np.full(data.shape, np.inf)
    d, v = 0.0, 0.0
    for ky, wyk in enumerate(wy):
        for kx, wxk in enumerate(wx):
            # taps (y'-1+ky, x'-1+kx) for output rows/cols >= 1
            d = d + wyk * wxk * data[ky:data.shape[0] - 1 + ky, kx:data.shape[1] - 1 + kx]
            v = v + (wyk * wxk) ** 2 * var[ky:var.shape[0] - 1 + ky, kx:var.shape[1] - 1 + kx]
    exp_data[1:, 1:] = d
    exp_var[1:, 1:] = v
    expected_mask = np.ones(data.shape, bool)
    expected_mask[1:, 1:] = False
    assert_array_equal(out.mask, expected_mask)
    assert_allclose(out.data[1:, 1:], exp_data[1:, 1:], rtol=1e-12)
    assert_allclose(_as_variance(out.uncertainty)[1:, 1:], exp_var[1:, 1:], rtol=1e-12)
    # and in the class's own representation
    if cls is StdDevUncertainty:
        assert_allclose(out.uncertainty.array[1:, 1:], np.sqrt(exp_var[1:, 1:]), rtol=1e-12)
    elif cls is InverseVariance:
        assert_allclose(out.uncertainty.array[1:, 1:], 1.0 / exp_var[1:, 1:], rtol=1e-12)
        assert np.all(out.uncertainty.array[out.mask] == 0)
    # the resampled variance is smaller than the input (averaging), never larger
    assert np.all(exp_var[1:, 1:] <= var.max())


@pytest.mark.parametrize("cls", UNCERTAINTY_CLASSES)
def test_uncertainty_with_register_and_conserve_flux(pair, cls):
    var = np.maximum(pair.source.astype(float), 0.0) + 25.0
    ccd = CCDData(pair.source.astype(float), unit=u.electron, uncertainty=_uncertainty(cls, var))
    out = register(ccd, pair.target, conserve_flux=True, order="bilinear")
    assert type(out.uncertainty) is cls
    t = transform_from_header(out.meta)
    # same as resampling data and variance directly
    d, v, m = resample(pair.source.astype(float), t.matrix, pair.target.shape,
                       order="bilinear", variance=var, conserve_flux=True)
    assert_array_equal(out.mask, m)
    assert_allclose(out.data[~m], d[~m], rtol=1e-12)
    assert_allclose(_as_variance(out.uncertainty)[~m], v[~m], rtol=1e-10)
    # conserve_flux scales variance by 1/det^2 relative to conserve_flux=False
    out0 = apply_transform(t, ccd, pair.target, conserve_flux=False, order="bilinear")
    det = abs(np.linalg.det(t.matrix[:2, :2]))
    assert_allclose(_as_variance(out.uncertainty)[~m],
                    _as_variance(out0.uncertainty)[~m] / det**2, rtol=1e-10)


# -- mask propagation against the simulator's truth ---------------------------------------


def _expected_mask(u_, v_, shape_in, order, bad_pixels):
    """Output mask predicted from the kernel supports (module docs of resample)."""
    ny, nx = shape_in

    def axis_ok(c, n):
        if order == "nearest-neighbor":
            return (c >= -0.5) & (c <= n - 0.5)
        if order == "bilinear":
            return (c >= 0) & (c <= n - 1)
        if order == "biquadratic":
            cc = np.floor(c + 0.5)
            return (cc - 1 >= 0) & (cc + 1 <= n - 1)
        fl = np.floor(c)
        return (fl - 1 >= 0) & (fl + 2 <= n - 1)

    reach = {"nearest-neighbor": None, "bilinear": 1.0, "biquadratic": 1.5, "bicubic": 2.0}
    mask = ~(axis_ok(u_, nx) & axis_ok(v_, ny))
    for yb, xb in bad_pixels:
        if order == "nearest-neighbor":
            near = (np.floor(u_ + 0.5) == xb) & (np.floor(v_ + 0.5) == yb)
        else:
            h = reach[order]
            near = (np.abs(u_ - xb) < h) & (np.abs(v_ - yb) < h)
        mask |= near
    return mask


@pytest.fixture(scope="module")
def mask_pair():
    # magnifying (scale 1.3) and rotated: every source pixel owns >= 1 output pixel
    return simulate_pair((96, 96), n_stars=40, rotation=23.0, scale=1.3,
                         translation=(1.7, -2.6), seed=4)


@pytest.mark.parametrize("order", ORDER_NAMES)
def test_mask_propagation_vs_truth(mask_pair, order):
    p = mask_pair
    data = p.source.copy()
    nan_pix, masked_pix = (40, 50), (60, 30)  # (row, col)
    data[nan_pix] = np.nan
    mask = np.zeros(data.shape, bool)
    mask[masked_pix] = True
    ccd = CCDData(data, mask=mask, unit="adu")
    out = apply_transform(p.transform, ccd, p.target, order=order)
    u_, v_ = _output_source_coords(p.truth_matrix, p.target.shape)

    for (yb, xb) in (nan_pix, masked_pix):
        # output pixels that take their value from the bad source pixel (nearest) or
        # whose kernel touches it: all masked, and they sit at the transformed position
        own = (np.floor(u_ + 0.5) == xb) & (np.floor(v_ + 0.5) == yb)
        assert own.any()
        assert np.all(out.mask[own])
        xt, yt = p.transform(float(xb), float(yb))
        iy, ix = np.nonzero(own)
        assert np.all(np.hypot(ix - float(xt), iy - float(yt)) < 1.3)

    expected = _expected_mask(u_, v_, data.shape, order, [nan_pix, masked_pix])
    assert_array_equal(out.mask, expected)
    # outside the source footprint: masked
    ny, nx = data.shape
    outside = (u_ < -0.5) | (u_ > nx - 0.5) | (v_ < -0.5) | (v_ > ny - 0.5)
    assert outside.any()
    assert np.all(out.mask[outside])
    # unmasked output pixels are finite; masked ones hold the fill value
    assert np.all(np.isfinite(out.data[~out.mask]))
    assert np.all(np.isnan(out.data[out.mask]))
    # the caller's arrays were not touched
    assert np.isnan(data[nan_pix]) and mask.sum() == 1


# -- flux conservation (issue 3 measurement) -------------------------------------------


def _aperture_fluxes(image, mask, xy, r, r_in, r_out):
    from photutils.aperture import (ApertureStats, CircularAnnulus, CircularAperture,
                                    aperture_photometry)

    ap = CircularAperture(xy, r)
    ann = CircularAnnulus(xy, r_in, r_out)
    # the mean is linear, so sky noise shared by two images of the same data cancels
    bkg = ApertureStats(image, ann, mask=mask, sigma_clip=None).mean
    tab = aperture_photometry(image, ap, mask=mask)
    return np.asarray(tab["aperture_sum"], float) - bkg * ap.area


def _isolated_stars(p, r, margin):
    from scipy.spatial import cKDTree

    ms = p.matched_stars()
    xy_t = np.column_stack([ms["x_target"], ms["y_target"]])
    xy_s = np.column_stack([ms["x_source"], ms["y_source"]])
    all_t = np.column_stack([p.target_stars["x"], p.target_stars["y"]])
    dist, _ = cKDTree(all_t).query(xy_t, k=2)
    ny, nx = p.target.shape
    ok = ((dist[:, 1] > 2 * r + 2) & (xy_t[:, 0] > margin) & (xy_t[:, 0] < nx - 1 - margin)
          & (xy_t[:, 1] > margin) & (xy_t[:, 1] < ny - 1 - margin))
    return xy_t[ok], xy_s[ok], np.asarray(ms["flux"], float)[ok]


FLUX_SCALE = 1.5
FLUX_PAIR = dict(shape=(512, 512), n_stars=60, scale=FLUX_SCALE, rotation=10.0,
                 translation=(2.3, -1.7), flux_range=(2e4, 2e5), seed=3)


def _stats(ratio):
    return float(np.median(ratio)), float(np.std(ratio)), len(ratio)


def test_flux_conservation_noiseless_vs_true_fluxes():
    p = simulate_pair(noise=False, **FLUX_PAIR)
    r = 3.5 * p.meta["target_fwhm"]  # ~16 px in the target grid
    xy_t, _, flux_true = _isolated_stars(p, r, r + 20)
    assert len(flux_true) >= 10
    results = {}
    for label, kw in (("conserve_flux=True", dict(conserve_flux=True)),
                      ("conserve_flux=False", dict(conserve_flux=False)),
                      ("exact, conserve_flux=True",
                       dict(conserve_flux=True, method="exact"))):
        out = register(p.source, p.target, **kw)
        f = _aperture_fluxes(np.asarray(out.data, float), out.mask, xy_t, r, r + 5, r + 15)
        results[label] = _stats(f / flux_true)
    FLUX_REPORT["noiseless, vs true flux"] = results
    for label in ("conserve_flux=True", "exact, conserve_flux=True"):
        med, std, _ = results[label]
        assert abs(med - 1.0) < 0.003, (label, results)
        assert std <= 0.003, (label, results)
    med, std, _ = results["conserve_flux=False"]
    assert abs(med / FLUX_SCALE**2 - 1.0) < 0.003, results  # surface brightness kept


def test_flux_conservation_noisy_vs_source_photometry():
    p = simulate_pair(**FLUX_PAIR)
    r = 3.5 * p.meta["target_fwhm"]
    xy_t, xy_s, flux_true = _isolated_stars(p, r, r + 20)
    assert len(flux_true) >= 10
    s = FLUX_SCALE
    f_src = _aperture_fluxes(p.source.astype(float), None, xy_s, r / s, (r + 5) / s,
                             (r + 15) / s)
    results_src, results_true = {}, {}
    for label, kw in (("conserve_flux=True", dict(conserve_flux=True)),
                      ("conserve_flux=False", dict(conserve_flux=False))):
        out = register(p.source, p.target, **kw)
        f = _aperture_fluxes(np.asarray(out.data, float), out.mask, xy_t, r, r + 5, r + 15)
        results_src[label] = _stats(f / f_src)
        results_true[label] = _stats(f / flux_true)
    results_true["source image itself"] = _stats(f_src / flux_true)
    FLUX_REPORT["noisy, vs source-image photometry"] = results_src
    FLUX_REPORT["noisy, vs true flux (photon-noise limited)"] = results_true
    med, std, _ = results_src["conserve_flux=True"]
    assert abs(med - 1.0) < 0.003, results_src
    assert std <= 0.003, results_src
    med, std, _ = results_src["conserve_flux=False"]
    assert abs(med / s**2 - 1.0) < 0.003, results_src


# -- header and WCS -----------------------------------------------------------------------


def test_history_and_transform_keywords(pair):
    out = register(pair.source, pair.target)
    history = "".join(str(h) for h in out.meta["HISTORY"])
    assert "astroalign_nd" in history
    assert "SimilarityTransform" in history
    n = out.meta["AATNMAT"]
    rms = out.meta["AATRMS"]
    assert n >= 3 and 0 <= rms < 1
    assert f"{n} matched stars" in history
    assert "RMS" in history and f"{rms:.4f}" in history
    t_hdr = transform_from_header(out.meta)
    t_fit, _ = find_transform(pair.source, pair.target)
    assert t_fit.meta["quality"]["n_matches"] == n
    yy, xx = np.mgrid[0:160:15, 0:160:15]
    x, y = xx.ravel().astype(float), yy.ravel().astype(float)
    assert_allclose(np.array(t_hdr(x, y)), np.array(t_fit(x, y)), atol=1e-9, rtol=0)


def test_header_from_apply_transform_without_quality(pair):
    t = SimilarityTransform(scale=1.02, rotation=0.1 * u.rad, translation_x=1.0, translation_y=2.0)
    out = apply_transform(t, pair.source, pair.target)
    assert "astroalign_nd" in "".join(str(h) for h in out.meta["HISTORY"])
    assert_allclose(transform_from_header(out.meta).matrix, t.matrix, atol=1e-15)


def test_target_wcs_is_used(pair):
    w_src = _simple_tan_wcs(crpix=(70.0, 70.0), crval=(150.0, 2.0))
    w_tgt = _simple_tan_wcs(crpix=(81.0, 79.0), crval=(150.01, 2.02), use_cd=True)
    src = CCDData(pair.source, unit="adu", wcs=w_src)
    tgt = CCDData(pair.target, unit="adu", wcs=w_tgt)
    out = apply_transform(pair.transform, src, tgt)
    xp, yp = np.array([0.0, 33.3, 159.0]), np.array([0.0, 120.0, 7.0])
    assert_allclose(np.array(out.wcs.pixel_to_world_values(xp, yp)),
                    np.array(w_tgt.pixel_to_world_values(xp, yp)), atol=1e-12, rtol=0)
    assert out.wcs is not tgt.wcs  # a copy


@pytest.mark.parametrize("use_cd", [False, True])
@pytest.mark.parametrize("rot_deg", [0.0, 35.0])
def test_source_wcs_is_carried_through_transform(use_cd, rot_deg):
    rng = np.random.default_rng(2)
    data = rng.normal(100, 5, (120, 140))
    w_src = _simple_tan_wcs(crpix=(60.5, 55.0), crval=(210.0, -30.0), use_cd=use_cd,
                            scale=2e-4, rot_deg=rot_deg)
    t = SimilarityTransform(scale=1.2, rotation=25.0, translation_x=14.2,
                            translation_y=-9.7)
    out = apply_transform(t, CCDData(data, unit="adu", wcs=w_src), (130, 150))
    assert out.wcs is not None
    yy, xx = np.mgrid[0:130:13, 0:150:13]
    xo, yo = xx.ravel().astype(float), yy.ravel().astype(float)
    xs, ys = t.inverse(xo, yo)
    ra_o, dec_o = out.wcs.pixel_to_world_values(xo, yo)
    ra_s, dec_s = w_src.pixel_to_world_values(xs, ys)
    assert_allclose(ra_o, ra_s, atol=1e-6, rtol=0)
    assert_allclose(dec_o, dec_s, atol=1e-6, rtol=0)
    # the caller's WCS is untouched
    assert_allclose(w_src.wcs.crpix, [60.5, 55.0])


def test_carried_wcs_has_output_shape():
    w_src = _simple_tan_wcs()
    w_src.pixel_shape = (50, 40)  # (nx, ny) of the source
    data = np.random.default_rng(1).normal(100, 5, (40, 50))
    t = TranslationTransform(translation_x=3.0, translation_y=-2.0)
    out = apply_transform(t, CCDData(data, unit="adu", wcs=w_src), (30, 70))
    assert out.wcs.array_shape in (None, (30, 70))


# -- ccdproc stack ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def stack_frames():
    """A target and three sources of the same sky, each with its own transform."""
    rng = np.random.default_rng(0)
    shape = (192, 192)
    n = 150
    x = rng.uniform(-30, 222, n)
    y = rng.uniform(-30, 222, n)
    flux = np.exp(rng.uniform(np.log(2e3), np.log(1e5), n))
    target = simulate_image(shape, x, y, flux, seed=99)
    frames = []
    for k, (rot, dx, dy) in enumerate([(3.0, 5.2, -4.1), (-2.0, -6.3, 3.7),
                                       (1.0, 2.5, 7.9)]):
        # S maps target pixels to source pixels; registration must find S^-1
        s = SimilarityTransform(scale=1.0, rotation=rot, translation_x=dx,
                                translation_y=dy)
        xs, ys = s(x, y)
        src = simulate_image(shape, xs, ys, flux, seed=k)
        ccd = CCDData(src, unit="adu",
                      uncertainty=StdDevUncertainty(np.sqrt(np.maximum(src, 0) + 25.0)))
        frames.append(register(ccd, target))
    inside = (x > 15) & (x < shape[1] - 16) & (y > 15) & (y < shape[0] - 16)
    stars = Table({"x": x[inside], "y": y[inside], "flux": flux[inside]})
    stars.sort("flux", reverse=True)
    return target, frames, stars


@pytest.mark.parametrize("method", ["median", "average"])
def test_ccdproc_combine_registered_frames(stack_frames, method):
    import warnings

    import ccdproc
    from photutils.centroids import centroid_com

    target, frames, stars = stack_frames
    assert all(isinstance(f, CCDData) and f.uncertainty is not None for f in frames)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-masked corners
        combined = ccdproc.combine(frames, method=method)
    assert isinstance(combined, CCDData)
    assert combined.shape == target.shape
    assert combined.unit == u.adu
    # a pixel is masked only when it is masked in every frame
    all_masked = np.logical_and.reduce([f.mask for f in frames])
    assert_array_equal(combined.mask, all_masked)
    none_masked = ~np.logical_or.reduce([f.mask for f in frames])
    assert np.all(np.isfinite(combined.data[none_masked]))
    # stars at the target positions
    offsets = []
    for row in stars[:15]:
        ix, iy = int(round(row["x"])), int(round(row["y"]))
        if not none_masked[iy - 6:iy + 7, ix - 6:ix + 7].all():
            continue
        cut = np.asarray(combined.data[iy - 6:iy + 7, ix - 6:ix + 7], float) - 100.0
        cx, cy = centroid_com(np.clip(cut, 0, None))
        offsets.append(np.hypot(ix - 6 + cx - row["x"], iy - 6 + cy - row["y"]))
    assert len(offsets) >= 8
    assert np.median(offsets) < 0.1
    # and the stack looks like the target (sky level, star peaks)
    diff = np.asarray(combined.data, float)[none_masked] - target[none_masked]
    assert abs(np.median(diff)) < 2.0


# -- the caller's objects are not modified ---------------------------------------------------


def test_inputs_not_modified(pair, tmp_path):
    src = pair.source.copy()
    src[5, 5] = np.nan
    src_before = src.copy()
    tgt_before = pair.target.copy()
    register(src, pair.target)
    assert_array_equal(src, src_before)
    assert_array_equal(pair.target, tgt_before)

    mask = np.zeros(src.shape, bool)
    mask[10, 10] = True
    masked = np.ma.MaskedArray(pair.source.copy(), mask=mask.copy())
    m_before = (masked.data.copy(), masked.mask.copy())
    register(masked, pair.target)
    assert_array_equal(masked.data, m_before[0])
    assert_array_equal(masked.mask, m_before[1])

    w = _simple_tan_wcs()
    ccd = CCDData(pair.source.copy(), unit="electron", mask=mask.copy(),
                  uncertainty=VarianceUncertainty(np.abs(pair.source) + 1.0),
                  meta={"OBJECT": "x"}, wcs=w)
    snap = _snapshot(ccd)
    out = register(ccd, pair.target, conserve_flux=True)
    assert_array_equal(ccd.data, snap.data)
    assert_array_equal(ccd.mask, snap.mask)
    assert_array_equal(ccd.uncertainty.array, snap.uncertainty.array)
    assert type(ccd.uncertainty) is VarianceUncertainty
    assert dict(ccd.meta) == dict(snap.meta)
    assert "HISTORY" not in ccd.meta and "AATTYPE" not in ccd.meta
    assert_array_equal(ccd.wcs.wcs.crpix, snap.wcs.wcs.crpix)
    assert out.data is not ccd.data and out.meta is not ccd.meta

    hdr = fits.Header({"BUNIT": "adu", "OBJECT": "y"})
    hdu = fits.PrimaryHDU(pair.source.copy(), header=hdr)
    hdu_data, hdu_hdr = hdu.data.copy(), hdu.header.copy()
    register(hdu, pair.target)
    assert_array_equal(hdu.data, hdu_data)
    assert hdu.header == hdu_hdr

    path = tmp_path / "src.fits"
    fits.PrimaryHDU(pair.source.copy(), header=hdr).writeto(path)
    before = path.read_bytes()
    register(str(path), pair.target)
    assert path.read_bytes() == before


# -- bad input -----------------------------------------------------------------------------


def test_bad_inputs(pair):
    cat = Table({"x": [1.0, 5.0, 9.0, 20.0], "y": [2.0, 8.0, 3.0, 15.0]})
    t = SimilarityTransform(scale=1.0, rotation=0.1 * u.rad, translation_x=1.0, translation_y=2.0)
    with pytest.raises(TypeError, match="catalog"):
        apply_transform(t, cat, pair.target)
    with pytest.raises(TypeError, match="catalog"):
        apply_transform(t, np.column_stack([cat["x"], cat["y"]]), pair.target)
    with pytest.raises(TypeError, match="catalog"):
        apply_transform(t, pair.source, cat)
    # a shape tuple is fine where a catalog is not
    assert apply_transform(t, pair.source, (50, 60)).shape == (50, 60)
    with pytest.raises(TypeError, match="catalog"):
        register(pair.source, cat)
    with pytest.raises(ValueError, match="order"):
        apply_transform(t, pair.source, pair.target, order="bicubik")
    with pytest.raises(ValueError):
        register(pair.source, pair.target, order="lanczos")
    singular = np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="singular"):
        apply_transform(singular, pair.source, pair.target)
    with pytest.raises(ValueError):
        apply_transform(np.zeros((3, 3)), pair.source, pair.target)
    with pytest.raises(ValueError, match="method"):
        apply_transform(t, pair.source, pair.target, method="drizzle")
    # find_transform's (transform, point lists) tuple, passed whole by mistake
    with pytest.raises(TypeError, match="first element"):
        apply_transform((t, (np.zeros((3, 2)), np.zeros((3, 2)))), pair.source, pair.target)
    with pytest.raises(TypeError, match="3x3 matrix"):
        apply_transform([[1.0, 2.0], [3.0]], pair.source, pair.target)


def test_zz_print_flux_report():
    """Print the flux-conservation numbers (visible with ``pytest -s``)."""
    for case, rows in FLUX_REPORT.items():
        print(f"\n{case}:")
        for label, (med, std, n) in rows.items():
            print(f"  {label:30s} median ratio {med:.5f}  std {std:.5f}  (N={n})")


@pytest.mark.parametrize("order", ["nearest-neighbor", "bilinear", "biquadratic", "bicubic"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64, ">f4"])
@pytest.mark.parametrize("nchan", [None, 3])
def test_uncertainty_classes_agree_with_mask_and_inputs_untouched(dtype, order, nchan):
    # StdDev/InverseVariance are squared/inverted into a scratch plane that
    # also takes the mask (issue 16); a VarianceUncertainty is the caller's
    # array, so the data are copied instead.  Both paths must give the same
    # data, mask and variance, and leave the caller's arrays as they were.
    rng = np.random.default_rng(7)
    shape = (64, 80) if nchan is None else (64, 80, nchan)
    data = (100.0 + 10.0 * rng.standard_normal(shape)).astype(dtype)
    sigma = (1.0 + rng.random(shape)).astype(dtype)
    mask = np.zeros((64, 80), bool)
    mask[20:23, 30:50] = True
    mask[5, 7] = True
    if nchan:
        mask = np.repeat(mask[..., None], nchan, axis=2)
    t = SimilarityTransform(scale=1.0, rotation=7.0, translation_x=2.3, translation_y=-1.7)
    out = {}
    for cls, arr in ((StdDevUncertainty, sigma), (VarianceUncertainty, sigma.astype(float)**2),
                     (InverseVariance, 1.0 / sigma.astype(float)**2)):
        ccd = CCDData(data, unit="adu", mask=mask.copy(), uncertainty=cls(arr))
        keep = (ccd.data.copy(), ccd.mask.copy(), ccd.uncertainty.array.copy())
        r = apply_transform(t, ccd, shape[:2], order=order)
        assert_array_equal(ccd.data, keep[0])
        assert_array_equal(ccd.mask, keep[1])
        assert_array_equal(ccd.uncertainty.array, keep[2])
        assert type(r.uncertainty) is cls
        assert r.uncertainty.unit == ccd.uncertainty.unit
        with np.errstate(divide="ignore"):  # InverseVariance 0 -> inf
            var = r.uncertainty.represent_as(VarianceUncertainty).array
        out[cls] = (r.data, r.mask, var)
    d0, m0, v0 = out[StdDevUncertainty]
    # Masked input pixels reach the output mask (the block is far from the edges).
    assert m0[20:23, 30:50].any()
    for cls in (VarianceUncertainty, InverseVariance):
        d, m, v = out[cls]
        assert_array_equal(m, m0)
        assert_array_equal(np.isnan(d), np.isnan(d0))
        assert_allclose(d[~m], d0[~m], rtol=1e-6)
        assert np.all(np.isinf(v[m]))
        assert_allclose(v[~m], v0[~m], rtol=1e-5)
    # Without an uncertainty the mask is the same too.
    r = apply_transform(t, CCDData(data, unit="adu", mask=mask), shape[:2], order=order)
    assert_array_equal(r.mask, m0)
    assert_allclose(r.data[~m0], d0[~m0], rtol=1e-6)
