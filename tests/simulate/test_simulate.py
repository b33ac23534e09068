# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Tests of astroalign_nd.simulate, the star-field and image-pair simulator."""

import numpy as np
import pytest
from astropy.table import Table

from astroalign_nd.simulate import (
    SimulatedPair,
    draw_fluxes,
    render_stars,
    simulate_field,
    simulate_image,
    simulate_pair,
)
from astroalign_nd.transforms import AffineTransform, SimilarityTransform


def _centroid(img):
    yy, xx = np.indices(img.shape)
    total = img.sum(dtype=np.float64)
    return (
        (img * xx).sum(dtype=np.float64) / total,
        (img * yy).sum(dtype=np.float64) / total,
        total,
    )


def _reference_render(shape, x, y, flux, fwhm):
    """Slow, obviously correct per-star rendering of pixel-integrated Gaussians."""
    from scipy.special import erf

    sigma = fwhm / (2 * np.sqrt(2 * np.log(2)))
    img = np.zeros(shape)
    edges_x = np.arange(shape[1] + 1) - 0.5
    edges_y = np.arange(shape[0] + 1) - 0.5
    for xi, yi, fi in zip(x, y, flux):
        px = np.diff(erf((edges_x - xi) / (np.sqrt(2) * sigma))) / 2
        py = np.diff(erf((edges_y - yi) / (np.sqrt(2) * sigma))) / 2
        img += fi * np.outer(py, px)
    return img


# -- render_stars ---------------------------------------------------------------

@pytest.mark.parametrize("fwhm", [1.5, 3.0, 5.5])
def test_render_total_flux(fwhm):
    img = render_stars((128, 128), 60.37, 55.81, 12345.0, fwhm=fwhm, dtype=np.float64)
    assert img.sum() == pytest.approx(12345.0, rel=5e-3)
    assert img.sum() == pytest.approx(12345.0, rel=1e-9)  # in fact exact


@pytest.mark.parametrize(
    "x, y", [(50.0, 50.0), (50.25, 49.5), (50.49, 50.51), (49.73, 50.12), (50.5, 50.5)]
)
@pytest.mark.parametrize("psf", ["gaussian", "moffat"])
def test_render_centroid(x, y, psf):
    img = render_stars((101, 101), x, y, 1e4, fwhm=3.0, psf=psf, dtype=np.float64)
    cx, cy, total = _centroid(img)
    assert abs(cx - x) < 0.02
    assert abs(cy - y) < 0.02
    assert total == pytest.approx(1e4, rel=1e-6)
    # The peak pixel is the one containing the star.
    iy, ix = np.unravel_index(np.argmax(img), img.shape)
    assert abs(ix - x) <= 0.5 + 1e-9 and abs(iy - y) <= 0.5 + 1e-9


def test_render_matches_reference_with_overlaps_and_borders():
    rng = np.random.default_rng(0)
    # Overlapping stars (np.add.at must accumulate duplicates) and stars on,
    # across and beyond the borders of a rectangular image.
    x = np.concatenate([rng.uniform(-5, 45, 40), [10.0, 10.2, -0.5, 39.5, 60.0]])
    y = np.concatenate([rng.uniform(-5, 35, 40), [10.0, 10.1, 15.0, 29.5, 10.0]])
    flux = rng.uniform(10, 1000, x.size)
    img = render_stars((30, 40), x, y, flux, fwhm=2.5, dtype=np.float64)
    ref = _reference_render((30, 40), x, y, flux, 2.5)
    np.testing.assert_allclose(img, ref, rtol=0, atol=1e-9 * flux.max())


def test_render_clipping_and_out():
    # A star on the corner pixel centre keeps a quarter of its light (plus a half pixel).
    img = render_stars((50, 50), -0.5, -0.5, 1000.0, fwhm=3.0, dtype=np.float64)
    assert img.sum() == pytest.approx(250.0, rel=1e-6)
    # Far outside: nothing, no error.
    assert render_stars((20, 30), 1e6, -1e6, 1e5).sum() == 0
    # In place, with the dtype of ``out``; non-contiguous ``out`` too.
    out = np.full((40, 60), 7.0, dtype=np.float64)
    res = render_stars((40, 60), 20.0, 30.0, 100.0, out=out)
    assert res is out and res.dtype == np.float64
    assert out.sum() == pytest.approx(7.0 * 40 * 60 + 100.0)
    big = np.zeros((40, 120))
    view = big[:, ::2]
    render_stars((40, 60), [20.0, 59.0], [30.0, 0.0], 100.0, out=view)
    np.testing.assert_allclose(view, render_stars((40, 60), [20.0, 59.0], [30.0, 0.0], 100.0,
                                                  dtype=np.float64), atol=1e-9)
    # Empty star list.
    assert render_stars((10, 10), [], [], []).sum() == 0


def test_render_dtype_and_per_star_fwhm():
    img = render_stars((64, 64), [20.0, 40.0], [20.0, 40.0], [100.0, 200.0], fwhm=[2.0, 4.0])
    assert img.dtype == np.float32 and img.shape == (64, 64)
    assert img.sum() == pytest.approx(300.0, rel=1e-5)
    # The broader star has the lower peak despite twice the flux.
    assert img[20, 20] > img[40, 40]


def test_render_many_stars():
    rng = np.random.default_rng(1)
    n = 30_000
    x = rng.uniform(20, 1004, n)
    y = rng.uniform(20, 1004, n)
    flux = rng.uniform(100, 1e4, n)
    img = render_stars((1024, 1024), x, y, flux)
    assert img.shape == (1024, 1024) and img.dtype == np.float32
    assert img.sum(dtype=np.float64) == pytest.approx(flux.sum(), rel=1e-4)


# -- simulate_image / simulate_field ---------------------------------------------

def test_simulate_image_noise_and_background():
    img = simulate_image((200, 300), [], [], [], background=100.0, read_noise=5.0, seed=0)
    assert img.shape == (200, 300) and img.dtype == np.float32
    assert img.mean() == pytest.approx(100.0, abs=0.2)
    assert img.std() == pytest.approx(np.sqrt(100.0 + 25.0), rel=0.03)
    g = simulate_image((200, 300), [], [], [], background=100.0, read_noise=5.0, gain=4.0,
                       noise="gaussian", seed=0, dtype=np.float64)
    assert g.dtype == np.float64
    assert g.std() == pytest.approx(np.sqrt(100.0 / 4 + 25.0), rel=0.03)


def test_simulate_image_noiseless_gradient_saturation():
    clean = simulate_image((101, 201), [], [], [], background=50.0, gradient=1.0, noise=False)
    assert clean[0, 0] == pytest.approx(50.0)
    assert clean[-1, -1] == pytest.approx(100.0)
    assert clean[50, 100] == pytest.approx(75.0)
    star = simulate_image((64, 64), 30.2, 31.7, 5e4, background=10.0, noise=False,
                          dtype=np.float64)
    assert star.sum() - 10.0 * 64 * 64 == pytest.approx(5e4, rel=1e-6)
    sat = simulate_image((64, 64), 30.2, 31.7, 5e5, background=10.0, saturation=1000.0,
                         seed=1)
    assert sat.max() == 1000.0
    assert np.count_nonzero(sat == 1000.0) > 4  # flat-topped


def test_simulate_image_artifacts_and_determinism():
    kw = dict(background=100.0, n_hot_pixels=20, n_cosmic_rays=10, seed=123)
    a = simulate_image((128, 128), [40.0], [40.0], [1e4], **kw)
    b = simulate_image((128, 128), [40.0], [40.0], [1e4], **kw)
    np.testing.assert_array_equal(a, b)
    c = simulate_image((128, 128), [40.0], [40.0], [1e4], **{**kw, "seed": 124})
    assert not np.array_equal(a, c)
    # Hot pixels and cosmic rays: isolated, very high values.
    n_high = np.count_nonzero(a > 100.0 + 500.0)
    assert 20 <= n_high <= 20 + 10 * 4 + 25  # hot + cosmic + the star's core
    clean = simulate_image((128, 128), [], [], [], background=100.0, noise=False,
                           n_hot_pixels=5, seed=3)
    assert np.count_nonzero(clean > 100.0 + 900.0) == 5


def test_simulate_field():
    img, stars = simulate_field((200, 150), n_stars=80, seed=7)
    assert img.shape == (200, 150)
    assert isinstance(stars, Table) and len(stars) == 80
    assert stars.colnames == ["x", "y", "flux", "id"]
    assert np.all(np.diff(stars["flux"]) <= 0)  # brightest first
    img2, stars2 = simulate_field((200, 150), n_stars=80, seed=7)
    np.testing.assert_array_equal(img, img2)
    assert np.array_equal(stars["x"], stars2["x"])


def test_draw_fluxes():
    f = draw_fluxes(20_000, flux_range=(100.0, 1e5), flux_index=1.5, seed=0)
    assert f.min() >= 100.0 and f.max() <= 1e5
    # N(>F) ~ F**-1.5: the fraction above 1000 is 10**-1.5 (truncation is negligible).
    assert np.mean(f > 1000.0) == pytest.approx(10**-1.5, rel=0.1)


# -- simulate_pair ----------------------------------------------------------------

def test_pair_determinism():
    kw = dict(n_stars=150, missing_fraction=0.1, n_transients=3, n_hot_pixels=5,
              n_cosmic_rays=5, seed=2024)
    a = simulate_pair((200, 240), **kw)
    b = simulate_pair((200, 240), **kw)
    np.testing.assert_array_equal(a.source, b.source)
    np.testing.assert_array_equal(a.target, b.target)
    np.testing.assert_array_equal(a.truth_matrix, b.truth_matrix)
    for name in ("source_stars", "target_stars", "transients"):
        for col in ("x", "y", "flux", "id"):
            np.testing.assert_array_equal(getattr(a, name)[col], getattr(b, name)[col])
    c = simulate_pair((200, 240), **{**kw, "seed": 2025})
    assert not np.array_equal(a.source, c.source)
    # Transients do not change the star field (independent random streams).
    d = simulate_pair((200, 240), **{**kw, "n_transients": 0})
    np.testing.assert_array_equal(a.source, d.source)


def test_pair_fields_shapes_dtypes():
    p = simulate_pair((128, 160), n_stars=60, seed=1)
    assert isinstance(p, SimulatedPair)
    assert p.source.shape == (128, 160) and p.target.shape == (128, 160)
    assert p.source.dtype == np.float32 and p.target.dtype == np.float32
    assert isinstance(p.transform, SimilarityTransform)
    assert p.truth_matrix.shape == (3, 3)
    np.testing.assert_allclose(p.truth_matrix, p.transform.matrix)
    for t in (p.source_stars, p.target_stars, p.transients):
        assert isinstance(t, Table) and t.colnames == ["x", "y", "flux", "id"]
    assert len(p.source_stars) == 60
    assert len(p.transients) == 0
    assert "SimulatedPair" in repr(p)
    p64 = simulate_pair((64, 64), n_stars=10, seed=1, dtype=np.float64)
    assert p64.source.dtype == np.float64 and p64.target.dtype == np.float64


def test_pair_default_transform_is_random_rotation_and_small_shift():
    p = simulate_pair((200, 300), n_stars=50, seed=11)
    assert p.transform.scale.value == pytest.approx(1.0)
    assert p.transform.parity.value == 1.0
    assert 0 <= p.meta["rotation"] < 360
    assert p.transform.rotation.value % 360 == pytest.approx(p.meta["rotation"])
    dx, dy = p.meta["translation"]
    assert abs(dx) <= 0.1 * 300 and abs(dy) <= 0.1 * 200
    assert p.meta["random_transform"]


def test_pair_positions_follow_transform():
    p = simulate_pair((300, 400), n_stars=400, rotation=37.0, scale=0.8,
                      translation=(25.0, -12.0), mirror=True, target_shape=(350, 250),
                      seed=5)
    t = p.transform
    assert isinstance(t, SimilarityTransform)
    assert t.rotation.value == pytest.approx(37.0)
    assert t.scale.value == pytest.approx(0.8)
    assert t.parity.value == -1
    # Rotation and scale are about the frame centres, the shift is of the centre.
    xc, yc = t((400 - 1) / 2, (300 - 1) / 2)
    assert (xc, yc) == pytest.approx(((250 - 1) / 2 + 25.0, (350 - 1) / 2 - 12.0))
    src = {int(i): (x, y, f) for x, y, f, i in p.source_stars.iterrows("x", "y", "flux", "id")}
    n_common = 0
    for x, y, f, i in p.target_stars.iterrows("x", "y", "flux", "id"):
        if int(i) in src:
            xs, ys, fs = src[int(i)]
            assert t(xs, ys) == pytest.approx((x, y), abs=1e-9)
            assert f == fs  # same total flux in both frames
            n_common += 1
    m = p.matched_stars()
    assert len(m) == n_common > 50
    xt, yt = t(m["x_source"], m["y_source"])
    np.testing.assert_allclose(xt, m["x_target"], atol=1e-9)
    np.testing.assert_allclose(yt, m["y_target"], atol=1e-9)
    # Star tables only list stars inside their frames.
    for tab, (ny, nx) in ((p.source_stars, (300, 400)), (p.target_stars, (350, 250))):
        assert np.all((tab["x"] >= -0.5) & (tab["x"] < nx - 0.5))
        assert np.all((tab["y"] >= -0.5) & (tab["y"] < ny - 0.5))
    assert p.meta["target_fwhm"] == pytest.approx(3.0 * 0.8)


def test_pair_target_fully_populated():
    # Partial overlap and a demagnified target: the target must still be
    # uniformly filled, with the density implied by the transform.
    p = simulate_pair((200, 200), n_stars=1000, rotation=20.0, scale=0.5,
                      translation=(150.0, 90.0), noise=False, seed=9)
    area_ratio = 1.0 / 0.5**2
    assert len(p.target_stars) == pytest.approx(1000 * area_ratio, rel=0.1)
    x, y = np.asarray(p.target_stars["x"]), np.asarray(p.target_stars["y"])
    counts = [np.sum((x < 99.5) == a) for a in (True, False)]
    counts += [np.sum((y < 99.5) == a) for a in (True, False)]
    expected = len(x) / 2
    for c in counts:
        assert abs(c - expected) < 5 * np.sqrt(expected)


def test_pair_bright_star_is_in_image():
    p = simulate_pair((128, 128), n_stars=40, rotation=10.0, seed=3)
    for img, tab in ((p.source, p.source_stars), (p.target, p.target_stars)):
        star = tab[0]  # the brightest
        ix, iy = int(round(star["x"])), int(round(star["y"]))
        assert img[iy, ix] > 100.0 + 10 * np.sqrt(125.0)


def test_pair_given_transform_model_and_matrix():
    model = AffineTransform(a11=1.02, a12=0.05, a21=-0.03, a22=0.98,
                            translation_x=10.0, translation_y=-5.0)
    p = simulate_pair((100, 100), n_stars=50, transform=model, seed=0)
    assert isinstance(p.transform, AffineTransform)
    np.testing.assert_allclose(p.truth_matrix, model.matrix)
    m = np.array([[0.0, -1.0, 99.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg rotation
    q = simulate_pair((100, 100), n_stars=50, transform=m, seed=0)
    np.testing.assert_allclose(q.transform.matrix, m, atol=1e-12)
    assert len(q.target_stars) == pytest.approx(50, abs=25)


def test_pair_rectangular_and_missing_and_transients():
    p = simulate_pair((120, 200), n_stars=300, target_shape=(90, 60), rotation=0.0,
                      missing_fraction=0.3, n_transients=7, seed=8,
                      target_fwhm=4.0, target_background=20.0)
    assert p.source.shape == (120, 200) and p.target.shape == (90, 60)
    assert len(p.source_stars) == pytest.approx(300 * 0.7, abs=40)
    assert len(p.transients) == 7
    ids = set(p.transients["id"])
    assert not ids & set(p.target_stars["id"]) and not ids & set(p.source_stars["id"])
    assert np.all((p.transients["x"] >= -0.5) & (p.transients["x"] < 59.5))
    assert p.meta["target_background"] == 20.0 and p.meta["target_fwhm"] == 4.0
    assert np.median(p.target) < 40.0 < 90.0 < np.median(p.source)


# -- bad arguments ---------------------------------------------------------------

@pytest.mark.parametrize(
    "func, args, kwargs, exc, match",
    [
        (render_stars, ((10,), 1, 1, 1), {}, ValueError, r"shape must be a \(ny, nx\)"),
        (render_stars, ((10, 0), 1, 1, 1), {}, ValueError, "positive integers"),
        (render_stars, ((10, 10), [1, 2], [1, 2, 3], 1), {}, ValueError, "same length"),
        (render_stars, ((10, 10), np.nan, 1, 1), {}, ValueError, "NaN"),
        (render_stars, ((10, 10), 1, 1, 1), {"fwhm": 0}, ValueError, "fwhm must be > 0"),
        (render_stars, ((10, 10), 1, 1, 1), {"psf": "airy"}, ValueError, "psf must be one of"),
        (render_stars, ((10, 10), 1, 1, 1), {"psf": "moffat", "beta": 1.0}, ValueError,
         "beta"),
        (render_stars, ((10, 10), 1, 1, 1), {"dtype": np.int32}, TypeError, "floating"),
        (render_stars, ((10, 10), 1, 1, 1), {"out": np.zeros((5, 5))}, ValueError,
         "must match"),
        (render_stars, ((10, 10), 1, 1, 1), {"out": np.zeros((10, 10), int)}, TypeError,
         "floating"),
        (simulate_image, ((10, 10), 1, 1, 1), {"background": -1}, ValueError, "background"),
        (simulate_image, ((10, 10), 1, 1, 1), {"gain": 0}, ValueError, "gain must be > 0"),
        (simulate_image, ((10, 10), 1, 1, 1), {"n_hot_pixels": 2.5}, TypeError,
         "n_hot_pixels"),
        (simulate_image, ((10, 10), 1, 1, 1), {"noise": "uniform"}, ValueError, "noise must"),
        (simulate_image, ((10, 10), 1, 1, 1), {"gradient": -2}, ValueError, "gradient"),
        (simulate_image, ((10, 10), 1, 1, 1), {"read_noise": "5"}, TypeError,
         "read_noise must be a real number"),
        (simulate_pair, (), {"n_stars": -1}, ValueError, "n_stars"),
        (simulate_pair, (), {"scale": 0}, ValueError, "scale must be > 0"),
        (simulate_pair, (), {"translation": (1, 2, 3)}, ValueError, r"\(dx, dy\)"),
        (simulate_pair, (), {"transform": np.eye(3), "rotation": 5}, ValueError,
         "either transform or rotation"),
        (simulate_pair, (), {"transform": np.zeros((3, 3)) + np.diag([0, 0, 1])}, ValueError,
         "singular"),
        (simulate_pair, (), {"transform": "rotate"}, TypeError, "transform must be"),
        (simulate_pair, (), {"missing_fraction": 1.0}, ValueError, "missing_fraction"),
        (simulate_pair, (), {"flux_range": (10, 1)}, ValueError, "flux_range"),
        (simulate_pair, (), {"flux_index": 0}, ValueError, "flux_index"),
        (simulate_pair, (), {"mirror": "yes"}, TypeError, "mirror"),
        (simulate_pair, (), {"target_shape": (10, -1)}, ValueError, "target_shape"),
        (simulate_pair, ((64, 64),), {"n_stars": 100, "scale": 1e-3}, ValueError,
         "reduce n_stars"),
    ],
)
def test_bad_arguments(func, args, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        func(*args, **kwargs)


def test_keyword_only():
    with pytest.raises(TypeError):
        simulate_pair((64, 64), 10)
    with pytest.raises(TypeError):
        render_stars((10, 10), 1, 1, 1, 3.0)


# -- the real-frame effects: bad input gets a clear error, the input is not modified ----------

def _effects_bad_inputs():
    from _frame_defects import add_nebulosity, add_overscan, bayer_bin, to_8bit

    img = np.full((64, 64), 100.0, np.float32)
    return [
        (lambda: add_nebulosity("x", amplitude=1), TypeError),
        (lambda: add_nebulosity(img, amplitude=np.nan), ValueError),
        (lambda: add_nebulosity(np.ones(10), amplitude=1), ValueError),
        (lambda: add_nebulosity(np.ones((2, 2)), amplitude=1), ValueError),
        (lambda: add_nebulosity(img, amplitude=1, knot_fwhm=(5,)), TypeError),
        (lambda: add_nebulosity(img, amplitude=1, n_knots=-1), ValueError),
        (lambda: add_overscan(img, width=1000), ValueError),
        (lambda: add_overscan(img, width=0), ValueError),
        (lambda: add_overscan(img, width="a"), TypeError),
        (lambda: add_overscan(np.ones(10)), ValueError),
        (lambda: add_overscan(img, edges=("middle",)), ValueError),
        (lambda: to_8bit(np.full((8, 8), np.nan)), ValueError),
        (lambda: to_8bit(np.ones((0, 0))), ValueError),
        (lambda: to_8bit(img, jpeg_quality=200), ValueError),
        (lambda: to_8bit(img, gamma=0), ValueError),
        (lambda: bayer_bin(img), TypeError),
    ]


@pytest.mark.parametrize("case", range(16))
def test_effects_reject_bad_input(case):
    call, exc = _effects_bad_inputs()[case]
    with pytest.raises(exc):
        call()


def test_effects_leave_input_alone():
    from _frame_defects import add_nebulosity, add_overscan, to_8bit

    img = simulate_pair((64, 64), n_stars=20, seed=3).source
    before = img.copy()
    add_nebulosity(img, amplitude=50.0, seed=1)
    strips = add_overscan(img, width=4, level=0.0, read_noise=0.0)
    to_8bit(img, jpeg_quality=80)
    np.testing.assert_array_equal(img, before)
    # Only the strips change: the interior is the input's.
    np.testing.assert_array_equal(strips[:-4, 4:-4], img[:-4, 4:-4])
    assert np.all(strips[:, :4] == 0.0)


# -- distortion (issue 18) -------------------------------------------------------


def test_distortion_none_is_bit_identical():
    a = simulate_pair((128, 128), n_stars=60, rotation=12.0, seed=5)
    b = simulate_pair((128, 128), n_stars=60, rotation=12.0, seed=5, distortion=None)
    assert np.array_equal(a.source, b.source) and np.array_equal(a.target, b.target)
    assert b.mapping is None and "corner_shift" not in b.meta
    xt, yt = b.truth_map([3.0, 100.0], [7.0, 50.0])
    lx, ly = b.transform([3.0, 100.0], [7.0, 50.0])
    assert np.array_equal(xt, lx) and np.array_equal(yt, ly)


@pytest.mark.parametrize("k1, k2", [(-0.01, 0.0), (0.008, 0.0), (-0.006, -0.003)])
def test_radial_distortion_truth(k1, k2):
    shape = (300, 400)
    pair = simulate_pair(shape, n_stars=200, rotation=20.0, translation=(4.0, -3.0), seed=2,
                         distortion={"k1": k1, "k2": k2})
    half = 0.5 * np.hypot(400, 300)
    assert pair.meta["corner_shift"] == pytest.approx(half * abs(k1 + k2), rel=1e-9)
    m = pair.matched_stars()
    xt, yt = pair.truth_map(m["x_source"], m["y_source"])
    assert np.allclose(xt, m["x_target"]) and np.allclose(yt, m["y_target"])
    # The distortion is radial: about the centre, along the radius, growing as r**3.
    c = np.array([199.5, 149.5])
    lin_inv = np.linalg.inv(pair.truth_matrix)
    p = np.array([[399.5, 149.5], [199.5 + 100.0, 149.5]])
    xt, yt = pair.truth_map(p[:, 0], p[:, 1])
    back = (lin_inv @ np.vstack([xt, yt, np.ones(2)]))[:2].T - c
    r = np.hypot(*(p - c).T)
    rho2 = (r / half) ** 2
    assert np.allclose(np.hypot(*back.T), r * (1 + k1 * rho2 + k2 * rho2 ** 2))
    assert np.allclose(back[:, 1], 0.0, atol=1e-9)  # along the radius


def test_tilt_is_projective():
    pair = simulate_pair((256, 256), n_stars=100, seed=3, rotation=0.0,
                         distortion={"tilt": (0.02, 0.0)})
    # A homography maps straight lines onto straight lines ...
    y = np.linspace(0.0, 255.0, 7)
    xt, yt = pair.truth_map(np.full(7, 40.0), y)
    assert np.allclose(np.polyval(np.polyfit(yt, xt, 1), yt), xt, atol=1e-9)
    # ... but shrinks the side it tilts away from, stretches the other.
    xl, _ = pair.truth_map([0.0, 10.0], [127.5, 127.5])
    xr, _ = pair.truth_map([245.0, 255.0], [127.5, 127.5])
    assert np.diff(xl)[0] > 10.0 > np.diff(xr)[0]
    assert pair.meta["corner_shift"] > 2.0


def test_distortion_bad_options():
    with pytest.raises(TypeError, match="distortion must be a dict"):
        simulate_pair((64, 64), n_stars=10, distortion=0.01)
    with pytest.raises(ValueError, match="unknown distortion key"):
        simulate_pair((64, 64), n_stars=10, distortion={"k3": 0.1})
    with pytest.raises(ValueError, match="folds the image over"):
        simulate_pair((64, 64), n_stars=10, distortion={"k1": -0.5})
    with pytest.raises(ValueError, match="too strong"):
        simulate_pair((64, 64), n_stars=10, distortion={"tilt": (0.6, 0.0)})
    with pytest.raises(ValueError, match="finite"):
        simulate_pair((64, 64), n_stars=10, distortion={"center": (np.nan, 3.0)})
    with pytest.raises(TypeError, match="real number"):
        simulate_pair((64, 64), n_stars=10, distortion={"k1": "big"})


@pytest.mark.parametrize("translation", [(np.nan, 1.0), (1.0, 2.0, 3.0), "ab", [[1.0, 2.0]]])
def test_bad_translation(translation):
    with pytest.raises(ValueError, match=r"translation must be a finite \(dx, dy\) pair"):
        simulate_pair((64, 64), n_stars=10, translation=translation)


@pytest.mark.parametrize("tilt", ["x", (0.1,), (0.1, np.inf)])
def test_bad_distortion_pair(tilt):
    with pytest.raises(ValueError, match=r"distortion\['tilt'\] must be a finite \(x, y\) pair"):
        simulate_pair((64, 64), n_stars=10, distortion={"tilt": tilt})


def test_distortion_fills_the_target_frame():
    """Stars reach the target's corners although barrel distortion pulls them in."""
    pair = simulate_pair((256, 256), n_stars=2000, rotation=0.0, seed=4,
                         distortion={"k1": -0.04})
    t = pair.target_stars
    assert len(t) > 0.95 * 2000 * (1 - 0.01)  # about the source's density
    for cx in (0, 255):
        for cy in (0, 255):
            assert np.min(np.hypot(t["x"] - cx, t["y"] - cy)) < 10.0


def test_bayer_bin_keeps_the_distortion():
    full = simulate_pair((256, 256), n_stars=200, fwhm=2.6, seed=1, rotation=10.0,
                         distortion={"k1": -0.02})
    from _frame_defects import bayer_bin

    binned = bayer_bin(full)
    m = binned.matched_stars()
    xt, yt = binned.truth_map(m["x_source"], m["y_source"])
    assert np.allclose(xt, m["x_target"]) and np.allclose(yt, m["y_target"])
