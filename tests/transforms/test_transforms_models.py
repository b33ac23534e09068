# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Tests of the transform models in astroalign_nd.transforms."""

import numpy as np
import pytest
from astropy import units as u
from astropy.modeling import Model
from astropy.modeling.models import Identity, Shift

from astroalign_nd import (AffineTransform, EuclideanTransform, LinearTransform2D,
                           SimilarityTransform, TranslationTransform)
from astroalign_nd.transforms import (TRANSFORM_TYPES, fit_transform, from_matrix,
                                      transform_class)

# One instance of every class, with "awkward" parameter values (large shifts,
# rotations beyond 90 degrees, mirrored variants).
MODELS = {
    "translation": TranslationTransform(translation_x=-12.25, translation_y=301.5),
    "euclidean": EuclideanTransform(rotation=2.1 * u.rad, translation_x=250.0, translation_y=-40.0),
    "euclidean-mirrored": EuclideanTransform(rotation=-0.7 * u.rad, translation_x=5.0,
                                             translation_y=612.0, parity=-1),
    "similarity": SimilarityTransform(scale=1.37, rotation=271.0,
                                      translation_x=-80.5, translation_y=1000.25),
    "similarity-mirrored": SimilarityTransform(scale=0.52, rotation=0.3 * u.rad, translation_x=17.0,
                                               translation_y=-3.5, parity=-1),
    "affine": AffineTransform(a11=1.2, a12=0.31, a21=-0.12, a22=0.9, translation_x=33.0,
                              translation_y=-7.0),
    "affine-mirrored": AffineTransform(a11=0.8, a12=0.2, a21=0.25, a22=-1.1,
                                       translation_x=-400.0, translation_y=90.0),
}
MODEL_IDS = list(MODELS)
N_FREE = {TranslationTransform: 2, EuclideanTransform: 3, SimilarityTransform: 4,
          AffineTransform: 6}


@pytest.fixture(params=MODEL_IDS)
def model(request):
    return MODELS[request.param].copy()


def _points(n=25, seed=0, lo=-50.0, hi=600.0):
    rng = np.random.default_rng(seed)
    return rng.uniform(lo, hi, size=(n, 2))


def _apply(model, pts):
    xo, yo = model(pts[:, 0], pts[:, 1])
    return np.column_stack([xo, yo])


def _apply_matrix(m, pts):
    return pts @ m[:2, :2].T + m[:2, 2]


# -- evaluation, matrix, inverse -------------------------------------------------------

def test_is_astropy_model(model):
    assert isinstance(model, Model)
    assert isinstance(model, LinearTransform2D)
    assert model.n_inputs == 2 and model.n_outputs == 2
    assert model.inputs == ("x", "y") and model.outputs == ("x", "y")


def test_evaluation_matches_matrix(model):
    pts = _points()
    m = model.matrix
    assert m.shape == (3, 3)
    np.testing.assert_array_equal(m[2], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(_apply(model, pts), _apply_matrix(m, pts), rtol=0, atol=1e-9)


def test_evaluation_broadcasts_and_scalars(model):
    x = np.linspace(0, 100, 12).reshape(3, 4)
    y = x[::-1] * 0.5
    xo, yo = model(x, y)
    assert np.shape(xo) == (3, 4) and np.shape(yo) == (3, 4)
    xs, ys = model(float(x[1, 2]), float(y[1, 2]))
    assert xs == pytest.approx(xo[1, 2], abs=1e-9)
    assert ys == pytest.approx(yo[1, 2], abs=1e-9)


def test_origin_maps_to_translation(model):
    xo, yo = model(0.0, 0.0)
    np.testing.assert_allclose([xo, yo], model.translation, atol=1e-12)


def test_inverse_is_analytic_and_exact(model):
    inv = model.inverse
    assert type(inv) is type(model)
    pts = _points(50, seed=1)
    back = _apply(inv, _apply(model, pts))
    np.testing.assert_allclose(back, pts, rtol=0, atol=1e-9)
    np.testing.assert_allclose(inv.matrix @ model.matrix, np.eye(3), rtol=0, atol=1e-12)
    # and the other way round
    np.testing.assert_allclose(_apply(model, _apply(inv, pts)), pts, rtol=0, atol=1e-9)
    # the inverse of the inverse is the model again
    np.testing.assert_allclose(inv.inverse.matrix, model.matrix, rtol=1e-12, atol=1e-9)


def test_inverse_keeps_parity(model):
    assert model.inverse.mirrored == model.mirrored
    if "parity" in model.param_names:
        assert float(model.inverse.parity.value) == float(model.parity.value)


def test_compound_with_inverse_is_identity(model):
    ident = model | model.inverse
    pts = _points(10, seed=2)
    xo, yo = ident(pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(np.column_stack([xo, yo]), pts, rtol=0, atol=1e-9)


# -- composition with astropy models -----------------------------------------------------

def test_compose_with_shifts():
    t = MODELS["similarity"]
    comp = Shift(1) & Shift(2) | t
    assert comp.n_inputs == 2 and comp.n_outputs == 2
    pts = _points(10, seed=3)
    xo, yo = comp(pts[:, 0], pts[:, 1])
    expect = _apply(t, pts + [1.0, 2.0])
    np.testing.assert_allclose(np.column_stack([xo, yo]), expect, rtol=0, atol=1e-9)


def test_compose_then_shift():
    t = MODELS["similarity-mirrored"]
    comp = t | Shift(-3.0) & Shift(4.5)
    pts = _points(10, seed=4)
    xo, yo = comp(pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(np.column_stack([xo, yo]), _apply(t, pts) + [-3.0, 4.5],
                               atol=1e-9)


def test_compound_inverse_through_astropy():
    t = MODELS["euclidean"]
    comp = Shift(1) & Shift(2) | t
    pts = _points(10, seed=5)
    xo, yo = comp(pts[:, 0], pts[:, 1])
    xb, yb = comp.inverse(xo, yo)
    np.testing.assert_allclose(np.column_stack([xb, yb]), pts, atol=1e-9)


def test_parallel_combination_with_ampersand():
    t = MODELS["affine"]
    par = t & Identity(1)
    assert par.n_inputs == 3 and par.n_outputs == 3
    xo, yo, zo = par(3.0, 4.0, 7.0)
    ex, ey = t(3.0, 4.0)
    assert (xo, yo, zo) == pytest.approx((ex, ey, 7.0), abs=1e-12)


def test_composition_of_two_transforms_is_matrix_product():
    a, b = MODELS["similarity"], MODELS["affine-mirrored"]
    comp = a | b
    pts = _points(10, seed=6)
    xo, yo = comp(pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(np.column_stack([xo, yo]),
                               _apply_matrix(b.matrix @ a.matrix, pts), rtol=1e-12, atol=1e-8)


# -- from_points / from_matrix ------------------------------------------------------------

@pytest.mark.parametrize("name", MODEL_IDS)
def test_from_points_exact_recovery(name):
    truth = MODELS[name]
    cls = type(truth)
    src = _points(20, seed=7)
    dst = _apply(truth, src)
    est = cls.from_points(src, dst)
    assert type(est) is cls
    np.testing.assert_allclose(est.matrix, truth.matrix, rtol=1e-10, atol=1e-8)
    assert est.mirrored == truth.mirrored
    if "parity" in truth.param_names:
        assert float(est.parity.value) == float(truth.parity.value)


@pytest.mark.parametrize("name", MODEL_IDS)
def test_from_points_minimum_number_of_points(name):
    truth = MODELS[name]
    cls = type(truth)
    src = _points(cls.min_points, seed=8)
    if cls is TranslationTransform:
        assert cls.min_points == 1
    dst = _apply(truth, src)
    est = cls.from_points(src, dst)
    np.testing.assert_allclose(_apply(est, src), dst, atol=1e-8)
    # a third point, not used in the fit, is mapped correctly too (except for
    # the 2-point rotation models, whose parity is ambiguous from 2 points).
    if cls.min_points >= 3 or cls is TranslationTransform:
        extra = np.array([[123.4, -56.7]])
        np.testing.assert_allclose(_apply(est, extra), _apply(truth, extra), atol=1e-7)


@pytest.mark.parametrize("cls", [EuclideanTransform, SimilarityTransform])
def test_mirrored_data_detected_by_default(cls):
    kw = dict(rotation=1.1, translation_x=40.0, translation_y=-9.0, parity=-1)
    if cls is SimilarityTransform:
        kw["scale"] = 1.8
    truth = cls(**kw)
    src = _points(8, seed=9)
    dst = _apply(truth, src)
    est = cls.from_points(src, dst)
    assert est.mirrored
    assert float(est.parity.value) == -1.0
    np.testing.assert_allclose(est.matrix, truth.matrix, rtol=1e-10, atol=1e-8)
    # Forcing a proper solution cannot reproduce mirrored data.
    proper = cls.from_points(src, dst, parity=1)
    assert not proper.mirrored
    assert np.max(np.abs(_apply(proper, src) - dst)) > 1.0


def test_from_points_with_noise_is_least_squares():
    truth = MODELS["similarity"]
    src = _points(200, seed=10)
    rng = np.random.default_rng(11)
    dst = _apply(truth, src) + rng.normal(0.0, 0.05, size=src.shape)
    est = SimilarityTransform.from_points(src, dst)
    # The fit must be closer to the data than the truth is (least squares).
    sse_est = np.sum((_apply(est, src) - dst) ** 2)
    sse_true = np.sum((_apply(truth, src) - dst) ** 2)
    assert sse_est <= sse_true + 1e-9
    assert float(est.scale.value) == pytest.approx(1.37, abs=1e-4)


def test_from_points_weights():
    truth = MODELS["translation"]
    src = _points(4, seed=12)
    dst = _apply(truth, src)
    dst[0] += [10.0, 10.0]  # one bad point
    w = np.array([0.0, 1.0, 1.0, 1.0])
    est = TranslationTransform.from_points(src, dst, weights=w)
    np.testing.assert_allclose(est.translation, truth.translation, atol=1e-9)


@pytest.mark.parametrize("name", MODEL_IDS)
def test_from_matrix_round_trip(name):
    truth = MODELS[name]
    cls = type(truth)
    rebuilt = cls.from_matrix(truth.matrix)
    np.testing.assert_allclose(rebuilt.matrix, truth.matrix, rtol=1e-12, atol=1e-9)
    rebuilt2 = cls.from_matrix(truth.matrix[:2])  # 2x3 form
    np.testing.assert_allclose(rebuilt2.matrix, truth.matrix, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("name, expected", [
    ("translation", TranslationTransform),
    ("euclidean", EuclideanTransform),
    ("euclidean-mirrored", EuclideanTransform),
    ("similarity", SimilarityTransform),
    ("similarity-mirrored", SimilarityTransform),
    ("affine", AffineTransform),
])
def test_from_matrix_picks_simplest_class(name, expected):
    est = from_matrix(MODELS[name].matrix)
    assert type(est) is expected


def test_transform_class_lookup():
    for name, cls in TRANSFORM_TYPES.items():
        assert transform_class(name) is cls
        assert transform_class(name.upper()) is cls
        assert transform_class(cls) is cls
    with pytest.raises(ValueError, match="transform_type must be one of"):
        transform_class("homography")
    with pytest.raises(ValueError):
        transform_class(3)


# -- fit_transform covariance --------------------------------------------------------------

@pytest.mark.parametrize("name", ["translation", "euclidean", "similarity", "affine",
                                  "similarity-mirrored"])
def test_fit_transform_covariance_shape(name):
    truth = MODELS[name]
    cls = type(truth)
    src = _points(30, seed=13)
    rng = np.random.default_rng(14)
    dst = _apply(truth, src) + rng.normal(0, 0.1, size=src.shape)
    model, cov, resid = fit_transform(src, dst, cls)
    n_free = N_FREE[cls]
    free = [p for p in model.param_names if not model.fixed[p]]
    assert len(free) == n_free
    assert cov.shape == (n_free, n_free)
    assert np.all(np.isfinite(cov))
    np.testing.assert_allclose(cov, cov.T, rtol=0, atol=1e-12 * np.max(np.abs(cov)))
    assert np.all(np.linalg.eigvalsh(0.5 * (cov + cov.T)) > 0)
    assert resid.shape == (30, 2)
    np.testing.assert_allclose(resid, _apply(model, src) - dst, atol=1e-9)


@pytest.mark.parametrize("transform_type", ["translation", "euclidean", "similarity",
                                            "affine"])
def test_fit_transform_covariance_shrinks_with_more_points(transform_type):
    truth = MODELS[transform_type]
    rng = np.random.default_rng(15)
    sizes = (10, 100, 1000)
    diags = []
    for n in sizes:
        src = rng.uniform(0, 500, size=(n, 2))
        dst = _apply(truth, src) + rng.normal(0, 0.1, size=src.shape)
        _, cov, _ = fit_transform(src, dst, transform_type)
        diags.append(np.diag(cov))
    diags = np.array(diags)
    assert np.all(diags[1] < diags[0])
    assert np.all(diags[2] < diags[1])
    # Roughly 1/N: 100 times more points -> variances ~100 times smaller.
    ratio = diags[0] / diags[2]
    assert np.all(ratio > 20) and np.all(ratio < 500)


def test_fit_transform_covariance_is_calibrated():
    """Predicted parameter errors agree with the Monte-Carlo scatter."""
    truth = MODELS["similarity"]
    rng = np.random.default_rng(16)
    src = rng.uniform(0, 500, size=(30, 2))
    clean = _apply(truth, src)
    params, sig = [], []
    for _ in range(150):
        dst = clean + rng.normal(0, 0.2, size=src.shape)
        model, cov, _ = fit_transform(src, dst, "similarity")
        params.append([float(model.scale.value), float(model.rotation.value),
                       float(model.translation_x.value), float(model.translation_y.value)])
        sig.append(np.sqrt(np.diag(cov)))
    scatter = np.std(np.array(params), axis=0)
    predicted = np.mean(np.array(sig), axis=0)
    np.testing.assert_allclose(predicted, scatter, rtol=0.2)


def test_fit_transform_covariance_nan_without_spare_dof():
    truth = MODELS["similarity"]
    src = _points(2, seed=17)
    _, cov, _ = fit_transform(src, _apply(truth, src), "similarity")
    assert cov.shape == (4, 4)
    assert np.all(np.isnan(cov))


def test_fit_transform_parity_argument():
    truth = MODELS["similarity-mirrored"]
    src = _points(10, seed=18)
    dst = _apply(truth, src)
    model, _, resid = fit_transform(src, dst, "similarity")
    assert model.mirrored and np.max(np.abs(resid)) < 1e-8
    model, _, resid = fit_transform(src, dst, "similarity", parity=1)
    assert not model.mirrored and np.max(np.abs(resid)) > 1.0


# -- attributes ----------------------------------------------------------------------------

def test_similarity_attributes():
    t = SimilarityTransform(scale=2.0, rotation=np.pi / 6 * u.rad, translation_x=10.0,
                            translation_y=-4.0)
    assert t.scale == pytest.approx(2.0)
    assert float(t.scale.value) == pytest.approx(2.0)
    assert t.rotation == pytest.approx(30.0)
    assert isinstance(t.rotation_deg, float)
    assert t.rotation_deg == pytest.approx(30.0)
    np.testing.assert_allclose(t.translation, [10.0, -4.0])
    np.testing.assert_allclose(t.params, t.matrix)
    c, s = 2 * np.cos(np.pi / 6), 2 * np.sin(np.pi / 6)
    np.testing.assert_allclose(t.matrix, [[c, -s, 10.0], [s, c, -4.0], [0, 0, 1]], atol=1e-12)
    assert t.mirrored is False
    assert t.fixed["parity"] is True
    # the translation is a copy: changing it does not change the model
    tr = t.translation
    tr[0] = 99.0
    assert t.translation[0] == 10.0


def test_mirrored_attribute():
    t = SimilarityTransform(scale=1.5, rotation=0.2 * u.rad, parity=-1)
    assert t.mirrored is True
    assert np.linalg.det(t.matrix[:2, :2]) == pytest.approx(-1.5 ** 2)
    assert MODELS["affine-mirrored"].mirrored is True
    assert MODELS["affine"].mirrored is False
    assert MODELS["translation"].mirrored is False


def test_translation_attributes():
    t = MODELS["translation"]
    assert t.scale == 1.0
    assert t.rotation == 0.0
    assert t.rotation_deg == 0.0
    np.testing.assert_allclose(t.translation, [-12.25, 301.5])
    np.testing.assert_allclose(t.matrix[:2, :2], np.eye(2))


def test_euclidean_attributes():
    t = EuclideanTransform(rotation=-37.0, translation_x=1.0, translation_y=2.0)
    assert t.scale == 1.0
    assert t.rotation_deg == pytest.approx(-37.0)
    assert np.linalg.det(t.matrix[:2, :2]) == pytest.approx(1.0)


def test_affine_attributes_match_skimage():
    skt = pytest.importorskip("skimage.transform")
    t = MODELS["affine"]
    ref = skt.AffineTransform(matrix=t.matrix)
    np.testing.assert_allclose(t.scale, ref.scale, rtol=1e-12)
    assert t.rotation == pytest.approx(np.degrees(ref.rotation), abs=1e-10)
    assert t.shear == pytest.approx(np.degrees(ref.shear), abs=1e-10)
    np.testing.assert_allclose(t.translation, ref.translation)
    np.testing.assert_allclose(t.params, ref.params)


def test_similarity_attributes_match_skimage():
    skt = pytest.importorskip("skimage.transform")
    t = MODELS["similarity"]
    ref = skt.SimilarityTransform(matrix=t.matrix)
    assert t.scale == pytest.approx(ref.scale, rel=1e-12)
    # same angle modulo 2 pi
    d = (np.deg2rad(float(t.rotation.value)) - ref.rotation + np.pi) % (2 * np.pi) - np.pi
    assert d == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(t.translation, ref.translation)


# -- bad input -----------------------------------------------------------------------------

@pytest.mark.parametrize("cls", [TranslationTransform, EuclideanTransform, SimilarityTransform,
                                 AffineTransform])
def test_from_points_bad_shapes(cls):
    src = _points(6, seed=19)
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        cls.from_points(np.zeros((6, 3)), src)
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        cls.from_points(src, np.zeros(12))
    with pytest.raises(ValueError, match="same length"):
        cls.from_points(src, src[:5])


@pytest.mark.parametrize("cls", [TranslationTransform, EuclideanTransform, SimilarityTransform,
                                 AffineTransform])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_from_points_non_finite(cls, bad):
    src = _points(6, seed=20)
    dst = src.copy()
    dst[2, 1] = bad
    with pytest.raises(ValueError, match="NaN or infinity"):
        cls.from_points(src, dst)
    with pytest.raises(ValueError, match="NaN or infinity"):
        cls.from_points(dst, src)


@pytest.mark.parametrize("cls", [EuclideanTransform, SimilarityTransform, AffineTransform])
def test_from_points_too_few(cls):
    n = cls.min_points - 1
    src = _points(n, seed=21)
    with pytest.raises(ValueError, match=rf"at least {cls.min_points} point pairs; got {n}"):
        cls.from_points(src, src)


def test_from_points_zero_points():
    empty = np.empty((0, 2))
    with pytest.raises(ValueError, match="at least 1 point pairs; got 0"):
        TranslationTransform.from_points(empty, empty)


def test_from_points_bad_weights_and_parity():
    src = _points(6, seed=22)
    with pytest.raises(ValueError, match="weights"):
        SimilarityTransform.from_points(src, src, weights=-np.ones(6))
    with pytest.raises(ValueError, match="weights"):
        SimilarityTransform.from_points(src, src, weights=np.ones(5))
    with pytest.raises(ValueError, match="weights"):
        SimilarityTransform.from_points(src, src, weights=np.full(6, np.nan))
    with pytest.raises(ValueError, match="parity"):
        SimilarityTransform.from_points(src, src, parity=2)


def test_from_matrix_errors():
    with pytest.raises(ValueError, match="shape"):
        SimilarityTransform.from_matrix(np.eye(2))
    with pytest.raises(ValueError, match="NaN or infinite"):
        AffineTransform.from_matrix(np.full((3, 3), np.nan))
    proj = np.eye(3)
    proj[2, 0] = 1e-3
    with pytest.raises(ValueError, match="projective"):
        AffineTransform.from_matrix(proj)
    sheared = MODELS["affine"].matrix
    with pytest.raises(ValueError, match="shear"):
        SimilarityTransform.from_matrix(sheared)
    with pytest.raises(ValueError, match="scale or shear"):
        EuclideanTransform.from_matrix(MODELS["similarity"].matrix)
    with pytest.raises(ValueError, match="rotation, scale or shear"):
        TranslationTransform.from_matrix(MODELS["euclidean"].matrix)
    with pytest.raises(ValueError, match="singular"):
        SimilarityTransform.from_matrix(np.diag([0.0, 0.0, 1.0]))


def test_fit_transform_bad_type():
    src = _points(5, seed=23)
    with pytest.raises(ValueError, match="transform_type"):
        fit_transform(src, src, "homography")
