# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The NumPy resampling path (no compiled loops) works in square output tiles:
its result must not depend on the tiling, nor differ from the compiled
kernels' by a bit.
"""

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from astroalign_nd import _kernels, conf
from astroalign_nd.resample import interpolation, resample
from astroalign_nd.transforms import SimilarityTransform

ROTATED = SimilarityTransform(scale=1.02, rotation=33.0, translation_x=40.3,
                              translation_y=-75.1).matrix


def _frame(shape, dtype=np.float64, nan=False, seed=3):
    rng = np.random.default_rng(seed)
    img = rng.normal(100.0, 10.0, shape).astype(dtype)
    if nan:
        img[rng.integers(0, shape[0], 20), rng.integers(0, shape[1], 20)] = np.nan
    return img


def _numpy(img, matrix, shape, **kwargs):
    with conf.set_temp("use_compiled", False):
        return resample(img, matrix, shape, parallel=False, **kwargs)


def _one_tile(monkeypatch):
    # The whole output as a single tile: the computation over whole rows
    # that the tiles replaced (neither the off-source nor the on-source
    # shortcut applies to a frame that is partly both).
    monkeypatch.setattr(interpolation, "_NUMPY_TILE", 1 << 20)
    monkeypatch.setattr(interpolation, "_NUMPY_BLOCK_PIXELS", 1 << 40)


def _assert_same(a, b):
    for x, y in zip(a, b):
        if x is None:
            assert y is None
        else:
            assert x.dtype == y.dtype
            assert_array_equal(x, y)  # (NaN equal to NaN)


CASES = [  # (source shape, output shape, kwargs of the frame and of resample)
    ((300, 283), (301, 290), dict()),
    ((300, 283), (301, 290), dict(nan=True)),
    ((300, 283), (301, 290), dict(variance=True, mask=True)),
    ((300, 283), (301, 290), dict(nan=True, variance="stddev", conserve_flux=True)),
    ((260, 301), (131, 387), dict(dtype=np.float32, variance=True, mask=True)),
    ((200, 200), (517, 3), dict(variance=True)),  # a thin output: tall tiles
]


def _inputs(src_shape, nan=False, dtype=np.float64, variance=False, mask=False, **kwargs):
    img = _frame(src_shape, dtype, nan)
    rng = np.random.default_rng(11)
    if variance == "stddev":
        kwargs.update(variance=rng.uniform(1.0, 3.0, src_shape), _variance_kind="stddev")
    elif variance:
        kwargs["variance"] = rng.uniform(1.0, 9.0, src_shape).astype(dtype)
    if mask:
        kwargs["mask"] = rng.random(src_shape) < 0.01
    return img, kwargs


@pytest.mark.parametrize("order", [0, 1, 2, 3])
@pytest.mark.parametrize("src_shape, shape, case", CASES)
def test_tiles_equal_one_block(monkeypatch, order, src_shape, shape, case):
    img, kwargs = _inputs(src_shape, **case)
    before = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in kwargs.items()}
    tiled = _numpy(img, ROTATED, shape, order=order, **kwargs)
    # The frame has pixels off the source, on it, and both in one tile.
    assert tiled[2].any() and not tiled[2].all()
    _one_tile(monkeypatch)
    whole = _numpy(img, ROTATED, shape, order=order, **kwargs)
    _assert_same(tiled, whole)
    for k, v in before.items():  # the caller's arrays untouched
        if isinstance(v, np.ndarray):
            assert_array_equal(kwargs[k], v)


@pytest.mark.skipif(not _kernels.HAVE_COMPILED, reason="needs the compiled kernels")
@pytest.mark.parametrize("order", [0, 1, 3])
@pytest.mark.parametrize("src_shape, shape, case", CASES)
def test_tiles_equal_compiled(order, src_shape, shape, case):
    img, kwargs = _inputs(src_shape, **case)
    tiled = _numpy(img, ROTATED, shape, order=order, **kwargs)
    compiled = resample(img, ROTATED, shape, order=order, parallel=False, **kwargs)
    _assert_same(tiled, compiled)


def test_tile_shapes_cover_the_output():
    # Square tiles, or as many pixels in a strip when the output is thinner.
    assert interpolation._tile_shape(1000, 1000) == (128, 128)
    assert interpolation._tile_shape(1000, 3) == (1000, 3)
    assert interpolation._tile_shape(40, 7000) == (40, 128)


def test_known_values_across_tile_edges():
    # A pure shift of a plane a + b x + c y: bilinear interpolation is exact,
    # so every output pixel (across every tile edge) has a known value.
    yy, xx = np.mgrid[:300, :290].astype(float)
    img = 5.0 + 0.5 * xx - 0.25 * yy
    shift = np.array([[1.0, 0.0, 2.5], [0.0, 1.0, -3.25], [0.0, 0.0, 1.0]])
    out, _, bad = _numpy(img, shift, (300, 290), order=1)
    yo, xo = np.mgrid[:300, :290].astype(float)
    truth = 5.0 + 0.5 * (xo - 2.5) - 0.25 * (yo + 3.25)
    inside = (xo - 2.5 >= 0) & (xo - 2.5 <= 289) & (yo + 3.25 >= 0) & (yo + 3.25 <= 299)
    assert_array_equal(bad, ~inside)
    np.testing.assert_allclose(out[inside], truth[inside], rtol=0, atol=1e-12)
    assert np.isnan(out[bad]).all()


@pytest.mark.parametrize("order", [0, 1, 2, 3])
def test_source_edge_on_a_tile_edge(order):
    # The source's last column and row fall on the first column and row of a
    # tile (129 = 128 + 1 pixels): that tile is mostly off the source, but
    # those pixels are on it, with their values (an identity transform).
    img = _frame((129, 129))
    out, _, bad = _numpy(img, np.eye(3), (200, 260), order=order)
    assert not bad[:129, :129].any() and bad[129:].all() and bad[:, 129:].all()
    assert_array_equal(out[:129, :129], img)


@pytest.mark.parametrize("n", [1, 2, 7])
def test_fast_bilinear_validity_follows_the_tap_rules(n):
    # The short validity test of the bilinear path against the general rule
    # (every tap of nonzero weight on the plane), on the edge cases: the
    # ends of the plane, just past them, and negatives so small that the
    # far tap takes the whole weight.
    tiny = [-2.0**-54, -2.0**-53, -1e-17, -5e-324, 0.0, 2.0**-60]
    edges = [-3.5, -3.0, -2.0, -1.0, -0.5, 0.5, n - 1.0, n - 1.0 + 1e-15, n - 0.5, n + 2.0,
             np.nextafter(n - 1.0, 0.0), np.nextafter(n - 1.0, np.inf), 1e30, -1e30]
    rng = np.random.default_rng(0)
    u = np.concatenate([tiny, edges, rng.uniform(-4.0, n + 3.0, 500)])
    i, ok, w0, w1 = interpolation._linear_taps(u, n)
    i_ref, ok_ref, w_ref = interpolation._axis_taps_numpy(u, n, 1)
    assert_array_equal(ok, ok_ref)
    assert ok.any() and not ok.all()
    assert_array_equal(i[ok], i_ref[ok])
    assert_array_equal(w0[ok], w_ref[0][ok])
    assert_array_equal(w1[ok], w_ref[1][ok])
