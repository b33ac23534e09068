# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Tests of astroalign_nd.resample (interpolating and exact resampling)."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import ndimage

from astroalign_nd import _kernels, conf
from astroalign_nd import resample as rs
from astroalign_nd.resample import ORDERS, resample, resample_exact
from astroalign_nd.transforms import SimilarityTransform

ALL_ORDERS = [0, 1, 2, 3]


def run(*args, **kwargs):
    # Most tests run on one thread; test_threads_match_serial covers the split.
    kwargs.setdefault("parallel", False)
    return resample(*args, **kwargs)


def similarity(scale=1.0, rotation=0.0, tx=0.0, ty=0.0):
    """The matrix of a similarity; ``rotation`` in radians."""
    return SimilarityTransform(scale=scale, rotation=np.degrees(rotation), translation_x=tx,
                               translation_y=ty).matrix


def shift_matrix(dx, dy):
    m = np.eye(3)
    m[:2, 2] = dx, dy
    return m


def source_positions(matrix, shape_out):
    """(x, y) source positions of every output pixel, straight from the inverse."""
    inv = np.linalg.inv(matrix)
    yy, xx = np.mgrid[:shape_out[0], :shape_out[1]].astype(float)
    return inv[0, 0] * xx + inv[0, 1] * yy + inv[0, 2], inv[1, 0] * xx + inv[1, 1] * yy + inv[1, 2]


def keys(s, a=-0.5):
    """Keys (1981) cubic convolution kernel, written from the paper's formula."""
    s = np.abs(s)
    return np.where(s <= 1, (a + 2) * s**3 - (a + 3) * s**2 + 1,
                    np.where(s < 2, a * s**3 - 5 * a * s**2 + 8 * a * s - 4 * a, 0.0))


def dodgson(s):
    """Dodgson (1997) interpolating quadratic kernel."""
    s = np.abs(s)
    return np.where(s <= 0.5, 1 - 2 * s**2, np.where(s <= 1.5, s**2 - 2.5 * s + 1.5, 0.0))


def direct_convolution(image, x, y, kernel, radius):
    """Interpolate at (x, y) by summing kernel(dx) kernel(dy) over nearby pixels."""
    ix, iy = int(np.floor(x)), int(np.floor(y))
    total = 0.0
    for j in range(iy - radius, iy + radius + 2):
        for i in range(ix - radius, ix + radius + 2):
            total += kernel(x - i) * kernel(y - j) * image[j, i]
    return float(total)


@pytest.fixture(scope="module")
def noise_image():
    return np.random.default_rng(42).normal(10.0, 3.0, size=(48, 52))


# -- kernels against references -----------------------------------------------------

def test_orders_names():
    assert ORDERS == {"nearest-neighbor": 0, "bilinear": 1, "biquadratic": 2, "bicubic": 3}
    img = np.arange(30.0).reshape(5, 6)
    m = shift_matrix(0.3, 0.2)
    for name, k in ORDERS.items():
        assert_array_equal(run(img, m, (5, 6), order=name)[0],
                           run(img, m, (5, 6), order=k)[0])


def test_bilinear_matches_map_coordinates(noise_image):
    m = similarity(1.07, 0.3, 4.2, -3.1)
    shape_out = (50, 55)
    out, _, bad = run(noise_image, m, shape_out, order="bilinear")
    x, y = source_positions(m, shape_out)
    ref = ndimage.map_coordinates(noise_image, [y, x], order=1, mode="constant", cval=np.nan)
    # Same footprint (scipy mixes in the NaN cval as soon as a tap is outside).
    assert_array_equal(bad, ~np.isfinite(ref))
    assert (~bad).sum() > 1000
    assert_allclose(out[~bad], ref[~bad], rtol=0, atol=1e-10)


@pytest.mark.parametrize("order, kernel, radius", [(3, keys, 1), (2, dodgson, 1)])
def test_kernels_match_direct_formula(noise_image, order, kernel, radius):
    m = similarity(0.93, -0.4, 6.0, 9.0)
    shape_out = (40, 40)
    out, _, bad = run(noise_image, m, shape_out, order=order)
    x, y = source_positions(m, shape_out)
    rng = np.random.default_rng(0)
    rows, cols = np.nonzero(~bad)
    for k in rng.choice(len(rows), 12, replace=False):
        r, c = rows[k], cols[k]
        ref = direct_convolution(noise_image, x[r, c], y[r, c], kernel, radius)
        assert_allclose(out[r, c], ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_linear_ramp_reproduced(order):
    # Every kernel reproduces straight lines (sum w = 1, sum w x = x).
    yy, xx = np.mgrid[:30, :30].astype(float)
    img = 2.0 * xx - 0.5 * yy + 3.0
    m = similarity(1.2, 0.7, 3.0, -2.0)
    out, _, bad = run(img, m, (30, 30), order=order)
    x, y = source_positions(m, (30, 30))
    assert_allclose(out[~bad], (2.0 * x - 0.5 * y + 3.0)[~bad], atol=1e-9)


# -- exact cases -----------------------------------------------------------------

@pytest.mark.parametrize("order, dtype", [(k, np.float64) for k in ALL_ORDERS]
                         + [(1, np.float32)])
def test_identity_is_exact(noise_image, order, dtype):
    img = noise_image.astype(dtype)
    out, _, bad = run(img, np.eye(3), img.shape, order=order)
    # Positions on pixel centres use one pixel with weight 1, even at the edges.
    assert not bad.any()
    assert_array_equal(out, img)


@pytest.mark.parametrize("order", ALL_ORDERS)
def test_integer_shift_moves_pixels(noise_image, order):
    out, _, bad = run(noise_image, shift_matrix(3, -2), noise_image.shape, order=order,
                      fill_value=-1.0)
    assert_array_equal(out[:-2, 3:], noise_image[2:, :-3])
    assert bad[:, :3].all() and bad[-2:].all()
    assert not bad[:-2, 3:].any()
    assert np.all(out[bad] == -1.0)


# -- masks ---------------------------------------------------------------------

# Output columns (shift 0.3) and rows (shift 0.4) that use source pixel 20.
FOOTPRINT = {0: [20], 1: [20, 21], 2: [19, 20, 21], 3: [19, 20, 21, 22]}


@pytest.mark.parametrize("order", ALL_ORDERS)
@pytest.mark.parametrize("how", ["nan", "inf", "mask", "variance"])
def test_bad_pixel_footprint(order, how):
    img = np.ones((40, 40))
    var = np.ones((40, 40))
    mask = None
    m = shift_matrix(0.3, 0.4)
    clean = run(img, m, img.shape, order=order, variance=var)[2]
    if how == "nan":
        img[20, 20] = np.nan
    elif how == "inf":
        img[20, 20] = np.inf
    elif how == "variance":
        var[20, 20] = np.nan
    else:
        mask = np.zeros(img.shape, bool)
        mask[20, 20] = True
    out, var_out, bad = run(img, m, img.shape, order=order, variance=var, mask=mask)
    expected = np.zeros(img.shape, bool)
    expected[np.ix_(FOOTPRINT[order], FOOTPRINT[order])] = True
    assert expected.sum() == (order + 1) ** 2
    assert_array_equal(bad, clean | expected)
    assert np.isnan(out[bad]).all() and np.isinf(var_out[bad]).all()
    assert np.isfinite(out[~bad]).all()


def test_nan_with_zero_weight_is_not_used():
    # A half-pixel shift in x gives zero weight to the third quadratic tap, and an
    # integer y position zero weight to every other row: the NaN stays contained.
    img = np.ones((20, 20))
    img[10, 10] = np.nan
    bad = run(img, shift_matrix(0.5, 0.0), img.shape, order=2)[2]
    assert_array_equal(np.nonzero(bad[10])[0], [0, 10, 11])
    assert bad[[9, 11], 1:].sum() == 0


def test_masked_array_mask_is_used():
    data = np.ma.masked_array(np.ones((10, 10)), mask=np.zeros((10, 10), bool))
    data.mask[5, 5] = True
    bad = run(data, np.eye(3), (10, 10), order=1)[2]
    assert bad.sum() == 1 and bad[5, 5]


def test_outside_footprint():
    img = np.ones((20, 30))
    # Bilinear: source x = x' - 10.5 must be >= 0, so x' >= 11 (x' <= 39.5 + ...).
    out, _, bad = run(img, shift_matrix(10.5, 0.0), (20, 50), order=1, fill_value=0.0)
    valid_cols = np.nonzero(~bad[0])[0]
    assert valid_cols[0] == 11 and valid_cols[-1] == 39
    assert np.all(out[bad] == 0.0) and np.all(out[~bad] == 1.0)
    # Nearest: the whole pixel area counts, [-0.5, nx - 0.5].
    bad0 = run(img, shift_matrix(10.5, 0.0), (20, 50), order=0)[2]
    valid_cols = np.nonzero(~bad0[0])[0]
    assert valid_cols[0] == 10 and valid_cols[-1] == 40
    # Completely outside: everything masked.
    assert run(img, shift_matrix(1000.0, 0.0), (20, 30))[2].all()


# -- variance ----------------------------------------------------------------------

@pytest.mark.parametrize("order, shift, factor", [
    (1, (0.5, 0.0), 0.25 + 0.25),
    (1, (0.5, 0.5), 4 * 0.25**2),
    (3, (0.5, 0.0), 2 * (0.0625**2 + 0.5625**2)),  # Keys weights at f = 0.5
    (0, (0.5, 0.5), 1.0),
])
def test_variance_sum_of_squared_weights(order, shift, factor):
    img = np.full((30, 30), 5.0)
    var = np.full((30, 30), 4.0)
    out, var_out, bad = run(img, shift_matrix(*shift), img.shape, order=order, variance=var)
    assert_allclose(out[~bad], 5.0, rtol=1e-14)
    assert_allclose(var_out[~bad], 4.0 * factor, rtol=1e-14)
    assert np.isinf(var_out[bad]).all()


def test_no_variance_returns_none():
    assert run(np.ones((5, 5)), np.eye(3), (5, 5))[1] is None


# -- dtypes, determinism, channels -----------------------------------------------

def test_dtypes(noise_image):
    m = similarity(1.01, 0.1, 0.5, 0.5)
    f32 = noise_image.astype(np.float32)
    out, var, bad = run(f32, m, (40, 40), variance=f32)
    assert out.dtype == np.float32 and var.dtype == np.float32 and bad.dtype == bool
    out64 = run(noise_image, m, (40, 40))[0]
    assert out64.dtype == np.float64
    assert_allclose(out, out64, rtol=1e-6, equal_nan=True)
    # Integers run in float32 since issue 29 (they were float64): half the output size.
    for kind in (np.int16, np.uint16, np.int32, np.uint8):
        ints = run(np.arange(100, dtype=kind).reshape(10, 10), np.eye(3), (10, 10))[0]
        assert ints.dtype == np.float32 and ints[3, 4] == 34.0
    big_endian = run(noise_image.astype(">f4"), m, (40, 40))[0]
    assert big_endian.dtype == np.float32
    assert_array_equal(big_endian, out)


@pytest.mark.parametrize("order", ALL_ORDERS)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_threads_match_serial(monkeypatch, noise_image, order, dtype):
    monkeypatch.setattr(rs.core, "_MIN_PIXELS_PER_THREAD", 1)  # small images normally use one
    monkeypatch.setattr(conf, "num_threads", 3)  # uneven chunks of 61 rows
    img = noise_image.astype(dtype)
    m = similarity(1.01, 0.2, 3.3, -1.7)
    var = img**2
    a = resample(img, m, (61, 60), order=order, variance=var, parallel=True)
    b = resample(img, m, (61, 60), order=order, variance=var, parallel=True)
    c = resample(img, m, (61, 60), order=order, variance=var, parallel=False)
    for x, y, z in zip(a, b, c):
        assert_array_equal(x, y)  # deterministic: no cross-thread reductions
        assert_array_equal(x, z)


@pytest.mark.skipif(not _kernels.HAVE_COMPILED,
                    reason="the thread count is read by the compiled loops only")
def test_bad_thread_count_is_explained(monkeypatch, noise_image):
    monkeypatch.setattr(_kernels, "_ENV_NUM_THREADS", "two")  # as read from the environment
    with pytest.raises(ValueError, match="ASTROALIGN_ND_NUM_THREADS"):
        resample(noise_image, np.eye(3), (300, 300), parallel=True)


def test_multichannel(noise_image):
    rgb = np.stack([noise_image, 2 * noise_image, noise_image**2], axis=-1)
    var = np.abs(rgb)
    m = similarity(0.9, 0.4, 10.0, -2.0)
    out, var_out, bad = run(rgb, m, (45, 45), order=3, variance=var)
    assert out.shape == var_out.shape == (45, 45, 3) and bad.shape == (45, 45)
    for c in range(3):
        o, v, b = run(np.ascontiguousarray(rgb[..., c]), m, (45, 45), order=3,
                      variance=np.ascontiguousarray(var[..., c]))
        assert_array_equal(out[..., c], o)
        assert_array_equal(var_out[..., c], v)
        assert_array_equal(bad, b)
    # A NaN in one channel masks every channel; a 2-D variance applies to all.
    rgb[20, 20, 1] = np.nan
    out, var_out, bad2 = run(rgb, m, (45, 45), order=3, variance=var[..., 0])
    assert bad2.sum() > bad.sum()
    assert np.isnan(out[bad2]).all()
    assert_array_equal(var_out[..., 0], var_out[..., 2])


# -- flux ------------------------------------------------------------------------

def gaussian_blob(shape=(64, 64), x0=30.3, y0=33.1, sigma=3.0):
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    return 100.0 * np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * sigma**2))


@pytest.mark.parametrize("order", [1, 3])
def test_conserve_flux(order):
    img = gaussian_blob()
    var = np.full(img.shape, 9.0)
    m = similarity(1.5, 0.4, 20.2, -5.1)
    out, var_out, bad = run(img, m, (110, 110), order=order, variance=var,
                            conserve_flux=True, fill_value=0.0)
    assert_allclose(out.sum(), img.sum(), rtol=5e-3)
    plain, sum_w2, _ = run(img, m, (110, 110), order=order, fill_value=0.0,
                           variance=np.ones(img.shape))
    assert_allclose(plain.sum(), 1.5**2 * img.sum(), rtol=5e-3)  # surface brightness
    assert_allclose(out, plain / 1.5**2, rtol=1e-14)
    assert_allclose(var_out[~bad], 9.0 * sum_w2[~bad] / 1.5**4, rtol=1e-14)


# -- fallback --------------------------------------------------------------------

@pytest.mark.parametrize("order", ALL_ORDERS)
def test_numpy_fallback_matches_compiled(monkeypatch, noise_image, order):
    img = noise_image.copy()
    img[10, 12] = np.nan
    mask = np.zeros(img.shape, bool)
    mask[30, 30] = True
    var = np.abs(img)
    m = similarity(1.03, 0.25, 2.0, 1.0)
    fast = run(img, m, (50, 50), order=order, variance=var, mask=mask, fill_value=-5)
    monkeypatch.setattr(conf, "use_compiled", False)
    slow = run(img, m, (50, 50), order=order, variance=var, mask=mask, fill_value=-5)
    # Same positions, weights and summation order: the same bits.
    assert_array_equal(fast[2], slow[2])
    assert_array_equal(fast[0], slow[0])
    assert_array_equal(fast[1], slow[1])


def test_numpy_fallback_multichannel(monkeypatch, noise_image):
    rgb = np.stack([noise_image, -noise_image], axis=-1).astype(np.float32)
    m = similarity(0.8, -0.3, 12.0, 0.0)
    fast = run(rgb, m, (40, 40), order=1, variance=np.abs(rgb))
    monkeypatch.setattr(conf, "use_compiled", False)
    slow = run(rgb, m, (40, 40), order=1, variance=np.abs(rgb))
    assert slow[0].dtype == np.float32
    assert_array_equal(fast[2], slow[2])
    assert_allclose(fast[0], slow[0], atol=1e-5)


# -- input checking -------------------------------------------------------------

@pytest.mark.parametrize("kwargs, error, match", [
    (dict(matrix=np.eye(2)), ValueError, "shape"),
    (dict(matrix=np.zeros((3, 3)) + np.diag([0, 0, 1])), ValueError, "singular"),
    (dict(matrix=[[1, 2, 0], [2, 4, 0], [0, 0, 1]]), ValueError, "singular"),
    (dict(matrix=np.full((3, 3), np.nan)), ValueError, "NaN"),
    (dict(matrix="identity"), TypeError, "3x3"),
    (dict(data=np.ones(10)), ValueError, "2-D"),
    (dict(data=np.ones((2, 3, 4, 5))), ValueError, "2-D"),
    (dict(data=np.ones((5, 5), complex)), TypeError, "real"),
    (dict(data=np.ones((3, 0))), ValueError, "empty"),
    (dict(data=np.ones((0, 4, 3))), ValueError, "empty"),
    (dict(order="cubic"), ValueError, "bicubic"),
    (dict(order=4), ValueError, "0-3"),
    (dict(order=True), ValueError, "order"),
    (dict(shape_out=(5,)), ValueError, "shape_out"),
    (dict(shape_out=(5, 0)), ValueError, "shape_out"),
    (dict(shape_out=(5.5, 3)), TypeError, "shape_out"),
    (dict(variance=np.ones((4, 4))), ValueError, "variance"),
    (dict(mask=np.ones((4, 4), bool)), ValueError, "mask"),
    (dict(fill_value="zero"), TypeError, "fill_value"),
])
def test_bad_input(kwargs, error, match):
    args = dict(data=np.ones((5, 5)), matrix=np.eye(3), shape_out=(5, 5))
    options = {k: kwargs.pop(k) for k in list(kwargs) if k not in args}
    args.update(kwargs)
    with pytest.raises(error, match=match):
        resample(args["data"], args["matrix"], args["shape_out"], **options)


def test_accepts_transforms_and_2x3():
    img = np.arange(25.0).reshape(5, 5)
    t = SimilarityTransform(translation_x=1.0)
    ref = run(img, t.matrix, (5, 5))[0]
    assert_array_equal(run(img, t, (5, 5))[0], ref)
    assert_array_equal(run(img, t.matrix[:2], (5, 5))[0], ref)


def test_keyword_only():
    with pytest.raises(TypeError):
        resample(np.ones((5, 5)), np.eye(3), (5, 5), "bilinear")


# -- resample_exact ----------------------------------------------------------------

def test_exact_conserves_flux():
    img = gaussian_blob()
    m = similarity(1.5, 0.4, 20.2, -5.1)
    out, _, bad = resample_exact(img, m, (110, 110), conserve_flux=True, fill_value=0.0)
    assert abs(out.sum() / img.sum() - 1) < 1e-3
    sb = resample_exact(img, m, (110, 110), fill_value=0.0)[0]
    assert_allclose(sb.sum(), 1.5**2 * img.sum(), rtol=1e-3)
    # Close to the interpolating kernel; not equal, because pixel overlap averages
    # over the pixel area (~3% lower peak for this sigma = 3 pixel blob).
    interp = run(img, m, (110, 110), order=3, conserve_flux=True, fill_value=0.0)[0]
    assert np.abs(out - interp).max() < 0.05 * out.max()


def test_exact_identity_shift_mask_and_variance(noise_image):
    img = noise_image[:20, :20].astype(np.float32)
    var = np.full(img.shape, 4.0)
    mask = np.zeros(img.shape, bool)
    mask[10, 10] = True
    out, var_out, bad = resample_exact(img, np.eye(3), img.shape, variance=var, mask=mask)
    assert out.dtype == np.float32
    assert_array_equal(np.nonzero(bad), ([10], [10]))
    assert_allclose(out[~bad], img[~bad], rtol=1e-6)
    assert_allclose(var_out[~bad], 4.0, rtol=1e-9)
    # A half-pixel shift: each target pixel straddles two source pixels.
    out, var_out, bad = resample_exact(img, shift_matrix(0.5, 0.0), img.shape,
                                       variance=var, mask=mask)
    assert_array_equal(np.nonzero(bad[10])[0], [0, 10, 11])
    assert bad[:, 0].all() and bad.sum() == 20 + 2
    expected = 0.5 * (img[:, :-1] + img[:, 1:])
    assert_allclose(out[~bad], expected[~bad[:, 1:]], rtol=1e-5)
    # reproject averages variances (an upper bound of sum p**2 var = 2.0).
    assert_allclose(var_out[~bad], 4.0, rtol=1e-9)


def test_exact_multichannel_and_errors():
    rgb = np.stack([gaussian_blob((20, 20), 9, 9), np.ones((20, 20))], axis=-1)
    out, _, bad = resample_exact(rgb, similarity(1.2, 0.3, 2.0, 1.0), (24, 24))
    assert out.shape == (24, 24, 2)
    assert_allclose(out[..., 1][~bad], 1.0, rtol=1e-9)
    with pytest.raises(ValueError, match="singular"):
        resample_exact(rgb, np.diag([1.0, 0.0, 1.0]), (24, 24))


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16, ">f4"])
@pytest.mark.parametrize("kind", ["plain", "masked_array", "variance32", "variance64"])
def test_masked_resample_leaves_inputs_untouched(dtype, kind):
    # Masked pixels are written as NaN into a working array (the data, or a
    # variance that is already a copy): never into the caller's arrays.
    rng = np.random.default_rng(2)
    data = (50 + 10 * rng.standard_normal((40, 48))).astype(dtype)
    mask = np.zeros(data.shape, bool)
    mask[10:13, 20:30] = True
    var = None
    if kind.startswith("variance"):
        var = rng.uniform(1.0, 4.0, data.shape).astype(
            np.float32 if kind == "variance32" else np.float64)
    arg = np.ma.MaskedArray(data, mask=mask.copy()) if kind == "masked_array" else data
    keep = (np.array(data), None if var is None else var.copy(), mask.copy())
    m = np.array([[1.0, 0.0, 1.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])
    out, vout, bad = resample(arg, m, data.shape, variance=var,
                              mask=None if kind == "masked_array" else mask)
    assert_array_equal(data, keep[0])
    assert_array_equal(mask, keep[2])
    if var is not None:
        assert_array_equal(var, keep[1])
        assert np.all(np.isinf(vout[bad]))
    # The masked block moved by (+1.5, -0.5) px: bilinear taps reach it from
    # output columns 21..32 of rows 9..13.
    assert bad[10:12, 23:30].all()
    assert not bad[20:38, 5:40].any()
    assert np.all(np.isnan(out[bad]))


@pytest.mark.parametrize("order", [0, 1, 2, 3])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_banded_working_planes_match_whole_frame(monkeypatch, order, dtype):
    # With a mask or a standard deviation, working planes are made one band of
    # output rows at a time (issue 16): many small bands give what one band
    # gives (to the last bits of the weights) and the same mask, for every
    # way of passing the uncertainty.
    rng = np.random.default_rng(order)
    data = rng.normal(100, 10, (90, 110)).astype(dtype)
    std = rng.uniform(1, 3, data.shape).astype(dtype)
    bad = rng.random(data.shape) < 0.01
    th = np.deg2rad(33.0)
    m = np.array([[1.1 * np.cos(th), -1.1 * np.sin(th), 60.0],
                  [1.1 * np.sin(th), 1.1 * np.cos(th), -20.0], [0, 0, 1]])
    monkeypatch.setattr(rs.core, "_BAND_PIXELS", 1 << 30)
    ref = resample(data, m, (100, 95), order=order, variance=std.astype(float) ** 2, mask=bad)
    assert ref[2].any() and not ref[2].all()
    monkeypatch.setattr(rs.core, "_BAND_PIXELS", 700)  # bands of 16 rows
    coefficients = rs.coordinate_map._inverse_coefficients(m)[0]
    assert len(rs.core._bands(coefficients, (100, 95), 90, order)) > 5
    rtol = 1e-6 if dtype == np.float32 else 1e-12
    for kind, var in (("stddev", std), ("variance", std.astype(float) ** 2),
                      ("inverse", 1 / std.astype(float) ** 2)):
        out, vout, mask = resample(data, m, (100, 95), order=order, variance=var, mask=bad,
                                   _variance_kind=kind)
        assert_array_equal(mask, ref[2])
        assert_allclose(out[~mask], ref[0][~mask], rtol=rtol)
        assert_allclose(vout[~mask], ref[1][~mask], rtol=rtol)
        assert np.all(np.isinf(vout[mask])) and np.all(np.isnan(out[mask]))
    out, _, mask = resample(data, m, (100, 95), order=order, mask=bad)
    assert_array_equal(mask, ref[2])
    assert_allclose(out[~mask], ref[0][~mask], rtol=rtol)


def test_exact_quarter_turn_masks_nothing():
    """cos(90 deg) = 6e-17 must not push edge pixels outside the source."""
    from astroalign_nd import apply_transform
    from astroalign_nd.transforms import SimilarityTransform

    img = np.arange(64, dtype=np.float32).reshape(8, 8)
    t = SimilarityTransform(scale=1.0, rotation=90.0, translation_x=7.0, translation_y=0.0)
    out = apply_transform(t, img, img)
    assert out.mask is None or not out.mask.any()
    # Source (x, y) lands on (7 - y, x): in numpy's (row, column) view, a clockwise turn.
    np.testing.assert_array_equal(np.asarray(out.data), np.rot90(img, k=-1))
