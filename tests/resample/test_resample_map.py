# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Resampling through a coordinate map (non-linear transforms, issue 18).

The maps here have exact inverses that the tests know, while `resample` is
given only an approximate (fitted) one, so every test checks the Newton
polish too.  Truth is in pixels: an image whose value is its own x (or y)
coordinate is reproduced exactly by every interpolating kernel except
nearest-neighbour, so resampling it returns the source position the
kernel used, to compare with the exact inverse.
"""

import tracemalloc

import numpy as np
import pytest
from astropy.modeling import Model, fitting, models
from astropy.nddata import CCDData, StdDevUncertainty
from numpy.testing import assert_allclose, assert_array_equal

import astroalign_nd.resample as rs
from astroalign_nd import apply_transform, conf
from astroalign_nd.resample import resample, resample_exact

# A shear x' = x + A (y - C1)^2, then a stretch of y varying with x',
# y' = y (1 + B (x' - C2)), then a scale S about the origin: non-linear, the
# local pixel area changes over the frame, and the exact inverse is known.
A, C1, B, C2, S = 2.0e-4, 120.0, 3.0e-4, 90.0, 1.15


class TwoShears(Model):
    """A non-linear source -> target map with a known exact inverse (`exact_inverse`)."""

    n_inputs = 2
    n_outputs = 2

    @staticmethod
    def evaluate(x, y):
        u = x + A * (y - C1) ** 2
        return S * u, S * y * (1.0 + B * (u - C2))


def exact_inverse(xo, yo):
    u, v = xo / S, yo / S
    y = v / (1.0 + B * (u - C2))
    return u - A * (y - C1) ** 2, y


def exact_forward(x, y):
    return TwoShears.evaluate(x, y)


def jacobian_det_inverse(xo, yo, h=1e-4):
    """|det| of the exact inverse's Jacobian (finite differences of the exact inverse)."""
    x1, y1 = exact_inverse(xo + h, yo)
    x0, y0 = exact_inverse(xo - h, yo)
    x3, y3 = exact_inverse(xo, yo + h)
    x2, y2 = exact_inverse(xo, yo - h)
    return np.abs((x1 - x0) * (y3 - y2) - (x3 - x2) * (y1 - y0)) / (4 * h * h)


def fitted_model(shape, degree=2):
    """`TwoShears` with a polynomial inverse fitted over the target grid (error ~0.1 px)."""
    model = TwoShears()
    yy, xx = np.mgrid[:shape[0]:4, :shape[1]:4].astype(float)
    xo, yo = model(xx, yy)
    fit = fitting.LinearLSQFitter()
    px = fit(models.Polynomial2D(degree), xo, yo, xx)
    py = fit(models.Polynomial2D(degree), xo, yo, yy)
    model.inverse = models.Mapping((0, 1, 0, 1)) | px & py
    return model


SHAPE = (260, 300)


@pytest.fixture(scope="module")
def model():
    m = fitted_model(SHAPE)
    yy, xx = np.mgrid[:SHAPE[0], :SHAPE[1]].astype(float)
    err = np.hypot(*(np.array(m.inverse(xx, yy)) - np.array(exact_inverse(xx, yy))))
    assert 0.01 < err.max() < 2.0  # the fitted inverse alone is visibly off
    return m


def coordinate_images(shape):
    yy, xx = np.mgrid[:shape[0], :shape[1]].astype(float)
    return np.stack([xx, yy], axis=-1)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_source_positions_match_exact_inverse(model, order):
    out, var, bad = resample(coordinate_images(SHAPE), model, SHAPE, order=order)
    yy, xx = np.mgrid[:SHAPE[0], :SHAPE[1]].astype(float)
    ex, ey = exact_inverse(xx, yy)
    assert bad.mean() < 0.3 and (~bad).sum() > 30000
    assert np.abs(out[..., 0] - ex)[~bad].max() < 2e-6  # pixels
    assert np.abs(out[..., 1] - ey)[~bad].max() < 2e-6
    # Bad exactly where the kernel's taps leave the source (a margin for ties).
    half = {1: 0.0, 2: 0.5, 3: 1.0}[order]
    inside = ((ex >= half) & (ex <= SHAPE[1] - 1 - half)
              & (ey >= half) & (ey <= SHAPE[0] - 1 - half))
    # (A position within round-off of a boundary or of a pixel centre on the
    # edge rows and columns may fall either way.)
    edge = np.zeros(SHAPE, bool)
    for pos, n in ((ex, SHAPE[1]), (ey, SHAPE[0])):
        for b in (0.0, half, n - 1 - half, n - 1.0):
            edge |= np.abs(pos - b) < 1e-3
    assert_array_equal(bad[~edge], ~inside[~edge])


def _star_field(shape, positions, sigma=1.6, flux=1000.0):
    yy, xx = np.mgrid[:shape[0], :shape[1]].astype(float)
    img = np.zeros(shape)
    for x, y in positions:
        img += flux / (2 * np.pi * sigma**2) * np.exp(
            -((xx - x) ** 2 + (yy - y) ** 2) / (2 * sigma**2))
    return img


def _centroid_offsets(img, bad, xs, ys, radius=7, tol=0.05):
    """
    Distances (px) from each expected star position to the centroid of ``img``
    within ``radius``, each asserted below ``tol``; stars whose disc is off the
    frame or touches a ``bad`` pixel are not checked (not in the result).
    """
    yy, xx = np.mgrid[:img.shape[0], :img.shape[1]].astype(float)
    offsets = []
    for x, y in zip(xs, ys):
        r = np.hypot(xx - x, yy - y) < radius
        if bad[r].any() or not r.any():
            continue
        w = img[r]
        offsets.append(np.hypot((w * xx[r]).sum() / w.sum() - x, (w * yy[r]).sum() / w.sum() - y))
        assert offsets[-1] < tol, (x, y)  # pixels
    return np.array(offsets)


def test_star_field_positions_and_pixel_values(model):
    # Stars on a grid over the frame: after resampling each lies at the
    # forward map of its source position (checked by its centroid), and the
    # pixel values are those of the source image at the exact inverse position.
    rng = np.random.default_rng(3)
    src_xy = np.array([(x, y) for x in range(20, 240, 40) for y in range(20, 200, 40)],
                      float) + rng.uniform(-0.5, 0.5, (30, 2))
    source = _star_field(SHAPE, src_xy, sigma=2.5)
    out, _, bad = resample(source, model, SHAPE, order="bicubic", fill_value=0.0)
    tx, ty = exact_forward(src_xy[:, 0], src_xy[:, 1])
    assert _centroid_offsets(out, bad, tx, ty).size >= 20
    yy, xx = np.mgrid[:SHAPE[0], :SHAPE[1]].astype(float)
    # Direct evaluation of the analytic source at the exact source positions.
    ex, ey = exact_inverse(xx, yy)
    direct = np.zeros(SHAPE)
    for x, y in src_xy:
        direct += 1000.0 / (2 * np.pi * 2.5**2) * np.exp(
            -((ex - x) ** 2 + (ey - y) ** 2) / (2 * 2.5**2))
    peak = direct.max()
    assert np.abs(out - direct)[~bad].max() < 0.01 * peak


def test_variance_mask_and_stddev(model):
    rng = np.random.default_rng(1)
    data = rng.normal(100, 5, SHAPE)
    std = rng.uniform(1, 3, SHAPE)
    mask = np.zeros(SHAPE, bool)
    mask[100, 150] = True
    out, var, bad = resample(data, model, SHAPE, order="nearest-neighbor", variance=std**2,
                             mask=mask)
    yy, xx = np.mgrid[:SHAPE[0], :SHAPE[1]].astype(float)
    ex, ey = exact_inverse(xx, yy)
    ix = np.floor(ex + 0.5).astype(int)
    iy = np.floor(ey + 0.5).astype(int)
    ok = ~bad
    # Nearest neighbour copies the pixel and its variance.
    assert_array_equal(out[ok], data[iy[ok], ix[ok]])
    assert_array_equal(var[ok], std[iy[ok], ix[ok]] ** 2)
    hit = (ix == 150) & (iy == 100)
    assert hit.any() and bad[hit].all()
    assert np.isinf(var[bad]).all() and np.isnan(out[bad]).all()

    # Bilinear: the masked pixel spoils exactly the outputs whose 2x2 taps reach it.
    out, var, bad = resample(data, model, SHAPE, order=1, variance=std**2, mask=mask)
    near = (np.abs(ex - 150) < 1 - 1e-6) & (np.abs(ey - 100) < 1 - 1e-6)
    far = (np.abs(ex - 150) > 1 + 1e-6) | (np.abs(ey - 100) > 1 + 1e-6)
    inside = (ex > 1e-6) & (ex < SHAPE[1] - 1 - 1e-6) & (ey > 1e-6) & (ey < SHAPE[0] - 1 - 1e-6)
    assert near.sum() >= 3 and bad[near].all()
    assert not bad[far & inside].any()
    # Variance = sum of w^2 var, here checked for a constant variance plane.
    _, var1, bad1 = resample(data, model, SHAPE, order=1, variance=np.full(SHAPE, 4.0))
    fx, fy = ex - np.floor(ex), ey - np.floor(ey)
    w2 = ((1 - fx) ** 2 + fx**2) * ((1 - fy) ** 2 + fy**2)
    assert_allclose(var1[~bad1], 4.0 * w2[~bad1], rtol=1e-5)  # positions to 1e-6 px

    # The kernel squares a standard deviation tap by tap: the same result.
    std32 = std.astype(np.float32)
    ref = resample(data.astype(np.float32), model, SHAPE, order=3, variance=std32 * std32,
                   mask=mask)
    got = resample(data.astype(np.float32), model, SHAPE, order=3, variance=std32, mask=mask,
                   _variance_kind="stddev")
    for a, b in zip(ref, got):
        assert_array_equal(a, b)


def test_conserve_flux_uses_local_jacobian(model):
    src_xy = np.array([(x, y) for x in range(40, 260, 60) for y in range(30, 220, 50)], float)
    source = _star_field(SHAPE, src_xy, sigma=2.0, flux=500.0)
    var = np.ones(SHAPE)
    out, vout, bad = resample(source, model, (330, 360), order=3, fill_value=0.0,
                              conserve_flux=True, variance=var)
    plain, vplain, _ = resample(source, model, (330, 360), order=3, fill_value=0.0,
                                variance=var)
    yy, xx = np.mgrid[:330, :360].astype(float)
    jac = jacobian_det_inverse(xx, yy)
    assert jac.max() < 0.8 and jac.max() / jac.min() > 1.05  # enlarges, not uniformly
    assert_allclose(out[~bad], plain[~bad] * jac[~bad], rtol=1e-5, atol=1e-9)
    assert_allclose(vout[~bad], vplain[~bad] * jac[~bad] ** 2, rtol=1e-5)  # (positions to 1e-6 px)
    tx, ty = exact_forward(src_xy[:, 0], src_xy[:, 1])
    checked = 0
    for x, y in zip(tx, ty):
        r = np.hypot(xx - x, yy - y) < 12
        if bad[r].any():
            continue
        assert abs(out[r].sum() - 500.0) < 0.01 * 500.0  # counts kept
        assert abs(plain[r].sum() - 500.0) > 0.2 * 500.0  # surface brightness is not
        checked += 1
    assert checked >= 10


def test_multichannel_and_numpy_path_agree(model, monkeypatch):
    rng = np.random.default_rng(2)
    data = rng.normal(0, 1, SHAPE + (3,)).astype(np.float32)
    var = rng.uniform(1, 2, SHAPE).astype(np.float32)
    mask = rng.random(SHAPE) < 0.002
    for order in range(4):
        ref = resample(data, model, (200, 210), order=order, variance=var, mask=mask,
                       conserve_flux=True)
        for c in range(3):  # every channel as a 2-D image: the same values
            one = resample(data[..., c], model, (200, 210), order=order, variance=var,
                           mask=mask, conserve_flux=True)
            assert_array_equal(one[0][~ref[2]], ref[0][..., c][~ref[2]])
        monkeypatch.setattr(conf, "use_compiled", False)
        slow = resample(data, model, (200, 210), order=order, variance=var, mask=mask,
                        conserve_flux=True)
        monkeypatch.setattr(conf, "use_compiled", True)
        assert_array_equal(slow[2], ref[2])
        assert_allclose(slow[0], ref[0], rtol=1e-5, atol=1e-6)
        assert_allclose(slow[1], ref[1], rtol=1e-5)


def test_parallel_and_band_size_do_not_change_result(model, monkeypatch):
    data = coordinate_images(SHAPE)[..., 0]
    ref = resample(data, model, SHAPE, order=3, conserve_flux=True, parallel=False)
    got = resample(data, model, SHAPE, order=3, conserve_flux=True, parallel=True)
    for a, b in zip(got, ref):
        assert_array_equal(a, b)  # threads: the same bits
    monkeypatch.setattr(rs.coordinate_map, "_MAP_BAND_PIXELS", 1000)  # bands of 3 rows
    got = resample(data, model, SHAPE, order=3, conserve_flux=True, parallel=True)
    # (Band edges change the first Newton step's Jacobian: round-off only.)
    assert_array_equal(got[2], ref[2])
    assert_allclose(got[0], ref[0], rtol=0, atol=1e-9)


def test_memory_stays_banded(model):
    # The coordinate maps are made band by band: the memory a resampling
    # needs beyond its outputs does not grow with the frame, and stays far
    # below what whole-frame maps would take (the map, its Jacobian and the
    # Newton polish's temporaries: some 30 float64 planes, 8 MB each at
    # 1024x1024).
    extra = []
    for n in (512, 1024):
        big = fitted_model((n, n))
        data = np.ones((n, n), np.float32)
        resample(data[:64, :64], big, (64, 64))  # warm up
        tracemalloc.start()
        try:
            out, _, bad = resample(data, big, (n, n), order=1)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        extra.append(peak - out.nbytes - bad.nbytes)
    assert extra[1] < 4 * 8 * 2**20, extra
    assert extra[1] < 1.2 * extra[0] + 2**20, extra


def test_homography_matrix_and_skimage():
    from skimage import transform as sktf

    h = np.array([[1.01, 0.02, 3.0], [-0.01, 0.99, -2.0], [2e-5, -3e-5, 1.0]])
    out, _, bad = resample(coordinate_images(SHAPE), h, SHAPE, order=1)
    hi = np.linalg.inv(h)
    yy, xx = np.mgrid[:SHAPE[0], :SHAPE[1]].astype(float)
    w = hi[2, 0] * xx + hi[2, 1] * yy + hi[2, 2]
    ex = (hi[0, 0] * xx + hi[0, 1] * yy + hi[0, 2]) / w
    ey = (hi[1, 0] * xx + hi[1, 1] * yy + hi[1, 2]) / w
    assert bad.mean() < 0.2
    assert np.abs(out[..., 0] - ex)[~bad].max() < 1e-9
    assert np.abs(out[..., 1] - ey)[~bad].max() < 1e-9
    ccd = apply_transform(sktf.ProjectiveTransform(matrix=h), coordinate_images(SHAPE)[..., 0],
                          SHAPE)
    assert_array_equal(ccd.mask, bad)
    assert_array_equal(ccd.data[~bad], out[..., 0][~bad])
    assert ccd.header["AATTYPE"] == "projective"  # the matrix, stored as the model


def test_linear_models_keep_affine_path():
    m = np.array([[0.98, 0.1, 4.5], [-0.1, 0.98, -3.2], [0, 0, 1]])
    affine = models.AffineTransformation2D(matrix=m[:2, :2], translation=m[:2, 2])
    data = np.random.default_rng(0).normal(size=(80, 90))
    for order in range(4):
        ref = resample(data, m, (70, 75), order=order)
        got = resample(data, affine, (70, 75), order=order)
        for a, b in zip(ref, got):
            assert_array_equal(a, b)


def test_errors(model):
    data = np.ones(SHAPE)
    with pytest.raises(ValueError, match="resample_exact handles affine.*Use resample"):
        resample_exact(data, model, SHAPE)
    with pytest.raises(ValueError, match="resample_exact handles affine"):
        apply_transform(model, data, SHAPE, method="exact")
    with pytest.raises(ValueError, match="resample_exact handles affine"):
        resample_exact(data, [[1, 0, 0], [0, 1, 0], [1e-3, 0, 1]], SHAPE)
    with pytest.raises(ValueError, match="no inverse.*model.inverse"):
        resample(data, TwoShears(), SHAPE)
    with pytest.raises(ValueError, match="singular"):
        resample(data, [[1, 2, 0], [2, 4, 0], [1, 2, 0]], SHAPE)
    with pytest.raises(TypeError, match="2 inputs and 2 outputs"):
        resample(data, models.Gaussian2D(), SHAPE)


def test_apply_transform_ccddata(model):
    rng = np.random.default_rng(4)
    data = rng.normal(50, 2, SHAPE).astype(np.float32)
    std = np.full(SHAPE, 2.0, np.float32)
    mask = np.zeros(SHAPE, bool)
    mask[50:53, 60:64] = True
    flags = np.zeros(SHAPE, np.int16)
    flags[100:110, 100:110] = 4
    ccd = CCDData(data, unit="adu", uncertainty=StdDevUncertainty(std), mask=mask,
                  flags=flags)
    keep = data.copy(), std.copy(), mask.copy()
    out = apply_transform(model, ccd, SHAPE, order="bicubic")
    assert_array_equal(ccd.data, keep[0])
    assert_array_equal(ccd.uncertainty.array, keep[1])
    assert_array_equal(ccd.mask, keep[2])
    ref, var, bad = resample(data, model, SHAPE, order=3, variance=std.astype(np.float32) ** 2,
                             mask=mask)
    assert_array_equal(out.mask, bad)
    assert_array_equal(out.data[~bad], ref[~bad])
    assert isinstance(out.uncertainty, StdDevUncertainty)
    assert_allclose(out.uncertainty.array[~bad], np.sqrt(var[~bad]), rtol=1e-7)
    assert "TwoShears" in str(out.header["HISTORY"])
    # Flags follow by nearest neighbour through the same map.
    yy, xx = np.mgrid[:SHAPE[0], :SHAPE[1]].astype(float)
    ex, ey = exact_inverse(xx, yy)
    ix, iy = np.rint(ex).astype(int), np.rint(ey).astype(int)
    inside = (ix >= 0) & (ix < SHAPE[1]) & (iy >= 0) & (iy < SHAPE[0])
    expect = np.zeros(SHAPE, np.int16)
    expect[inside] = flags[iy[inside], ix[inside]]
    assert_array_equal(out.flags, expect)


# -- the package's non-linear models ------------------------------------------------

def barrel(n=512, k=1.05e-7, domain=True):
    """A PolynomialTransform with radial distortion x_d = u (1 + k r^2), ~5 px at the corners."""
    from astroalign_nd import PolynomialTransform

    c = (n - 1) / 2.0
    return PolynomialTransform(degree=3, crpix=(c, c), translation_x=c + 3.0,
                               translation_y=c - 2.0, a11=1.01, a12=0.02, a21=-0.02,
                               a22=1.01, A_3_0=k, A_1_2=k, B_2_1=k, B_0_3=k,
                               domain=(0, n - 1, 0, n - 1) if domain else None)


def test_polynomial_transform_positions_and_stars():
    n = 512
    model = barrel(n)
    out, _, bad = resample(coordinate_images((n, n)), model, (n, n), order=1)
    yy, xx = np.mgrid[:n, :n].astype(float)
    assert bad.mean() < 0.1
    fx, fy = model(out[..., 0], out[..., 1])  # the positions used, sent forward
    assert np.hypot(fx - xx, fy - yy)[~bad].max() < 2e-6  # pixels
    # Distortion is really there: the linear part alone is off by pixels.
    lx, ly = model.linear_part(out[..., 0], out[..., 1])
    assert np.hypot(lx - xx, ly - yy)[~bad].max() > 3.0
    # Stars land where the model sends them.
    src_xy = np.array([(x, y) for x in range(30, 500, 70) for y in range(30, 500, 70)], float)
    source = _star_field((n, n), src_xy, sigma=2.0)
    img, _, bad = resample(source, model, (n, n), order="bicubic")
    tx, ty = model(src_xy[:, 0], src_xy[:, 1])
    assert _centroid_offsets(img, bad, tx, ty).size >= 40
    # Without a domain, the source frame is the domain of the fitted inverse.
    again = resample(coordinate_images((n, n)), barrel(n, domain=False), (n, n), order=1)
    assert_array_equal(again[2], resample(coordinate_images((n, n)), model, (n, n))[2])
    assert_allclose(again[0][~again[2]], out[~again[2]], atol=1e-6)


def test_projective_transform_model():
    from astroalign_nd import ProjectiveTransform

    data = np.random.default_rng(5).normal(size=(120, 130))
    h = np.array([[1.01, 0.02, 3.0], [-0.01, 0.99, -2.0], [2e-4, -3e-4, 1.0]])
    t = ProjectiveTransform.from_matrix(h)
    for order in range(4):
        for a, b in zip(resample(data, t, (110, 125), order=order),
                        resample(data, h, (110, 125), order=order)):
            assert_array_equal(a, b)
    affine = ProjectiveTransform.from_matrix(np.vstack([h[:2], [0, 0, 1]]))
    for a, b in zip(resample(data, affine, (110, 125)), resample(data, h[:2], (110, 125))):
        assert_array_equal(a, b)  # h31 = h32 = 0: the affine path, same bits


def test_apply_transform_polynomial_header_round_trip():
    from astroalign_nd.io import transform_from_header

    n = 256
    model = barrel(n, k=4e-7)
    data = _star_field((n, n), [(60.0, 70.0), (200.0, 180.0)], sigma=2.0).astype(np.float32)
    ccd = CCDData(data, unit="adu", uncertainty=StdDevUncertainty(np.ones_like(data)))
    out = apply_transform(model, ccd, (n, n))
    back = transform_from_header(out.meta)
    pts = np.array([[10.0, 20.0], [128.0, 128.0], [250.0, 5.0]])
    assert_allclose(np.column_stack(back(*pts.T)), np.column_stack(model(*pts.T)), atol=1e-6)
    ref, var, bad = resample(data, model, (n, n), variance=np.ones_like(data))
    assert_array_equal(out.mask, bad)
    assert_array_equal(out.data[~bad], ref[~bad])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_output_kind_same_bits_as_numpy(model, monkeypatch, dtype):
    # The kernel may store the standard deviation or inverse variance (for
    # apply_transform's uncertainty classes): the same bits as converting the
    # variance output with NumPy, masked pixels included (inf and 0).
    rng = np.random.default_rng(7)
    data = rng.normal(10, 1, (90, 100, 2)).astype(dtype)
    std = rng.uniform(1, 3, (90, 100)).astype(dtype)
    bad = rng.random((90, 100)) < 0.01
    m = np.array([[0.98, 0.1, 4.5], [-0.1, 0.98, -3.2], [0, 0, 1]])
    for compiled in (True, False):
        monkeypatch.setattr(conf, "use_compiled", compiled)
        for t in (m, model):
            for order in range(4):
                for plane in (data, data[..., 0]):
                    _, var, _ = resample(plane, t, (80, 95), order=order, variance=std,
                                         mask=bad, _variance_kind="stddev")
                    with np.errstate(divide="ignore"):
                        for kind, expect in (("stddev", np.sqrt(var)), ("inverse", 1 / var)):
                            got = resample(plane, t, (80, 95), order=order, variance=std,
                                           mask=bad, _variance_kind="stddev",
                                           _output_kind=kind)[1]
                            assert_array_equal(got, expect)
