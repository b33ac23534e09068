# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Tests of the non-linear models: ProjectiveTransform and PolynomialTransform."""

import pickle

import numpy as np
import pytest
from astropy.modeling.models import Rotation2D, Shift

import astroalign_nd
from astroalign_nd import AffineTransform, PolynomialTransform, ProjectiveTransform
from astroalign_nd.transforms import TRANSFORM_TYPES, fit_transform, transform_class

SHAPE = (2048, 3072)  # (ny, nx)
DOMAIN = (0.0, SHAPE[1] - 1.0, 0.0, SHAPE[0] - 1.0)


def _grid(n=33, domain=DOMAIN):
    gx, gy = np.meshgrid(np.linspace(domain[0], domain[1], n), np.linspace(domain[2], domain[3], n))
    return gx.ravel(), gy.ravel()


def _frame_error(a, b, domain=DOMAIN):
    """Largest distance in pixels between two models over the frame."""
    x, y = _grid(domain=domain)
    xa, ya = a(x, y)
    xb, yb = b(x, y)
    return float(np.max(np.hypot(xa - xb, ya - yb)))


def homography():
    # A tilted focal plane: a few pixels of keystone at the corners of a 3072 px frame.
    return ProjectiveTransform(h11=0.998, h12=0.015, h13=12.5, h21=-0.012, h22=1.003,
                               h23=-30.25, h31=2.0e-6, h32=-1.5e-6)


def barrel(degree=3):
    # Radial-looking distortion, about 6 px at the corners, with rotation and shift.
    c, s = np.cos(np.radians(1.5)), np.sin(np.radians(1.5))
    params = dict(a11=1.001 * c, a12=-1.001 * s, a21=1.001 * s, a22=1.001 * c,
                  translation_x=1530.0, translation_y=1010.0,
                  A_3_0=-1.8e-9, A_1_2=-1.8e-9, B_2_1=-1.8e-9, B_0_3=-1.8e-9,
                  A_2_0=3e-7, B_1_1=-2e-7)
    if degree >= 5:
        params.update(A_5_0=1e-16, B_0_5=-1e-16)
    return PolynomialTransform(degree=degree, crpix=(1535.5, 1023.5), domain=DOMAIN, **params)


def _pairs(model, n=200, seed=0, noise=0.0):
    rng = np.random.default_rng(seed)
    src = rng.uniform((0, 0), (SHAPE[1] - 1, SHAPE[0] - 1), (n, 2))
    dst = np.column_stack(model(src[:, 0], src[:, 1]))
    return src, dst + rng.normal(0.0, noise, dst.shape) if noise else dst


# -- registration of the classes ----------------------------------------------------------

def test_lookup_and_top_level():
    assert transform_class("projective") is ProjectiveTransform
    assert transform_class("Polynomial") is PolynomialTransform
    assert transform_class(PolynomialTransform) is PolynomialTransform
    assert TRANSFORM_TYPES["projective"] is astroalign_nd.ProjectiveTransform
    assert astroalign_nd.transforms.PolynomialTransform is PolynomialTransform
    assert "PolynomialTransform" in astroalign_nd.__all__
    assert ProjectiveTransform.min_points == 4
    assert [PolynomialTransform(degree=d).min_points for d in (2, 3, 4, 5)] == [6, 10, 15, 21]
    assert PolynomialTransform.min_points == 10 and PolynomialTransform.n_dof == 20
    assert PolynomialTransform(degree=5).n_dof == 42 and ProjectiveTransform.n_dof == 8


# -- projective --------------------------------------------------------------------------

def test_projective_evaluates_the_homography():
    t = homography()
    m = t.matrix
    x, y = 1000.0, 1500.0
    w = m[2] @ [x, y, 1.0]
    assert t(x, y) == pytest.approx(((m[0] @ [x, y, 1.0]) / w, (m[1] @ [x, y, 1.0]) / w),
                                    abs=1e-9)
    assert m[2, 2] == 1.0


def test_projective_inverse_is_analytic():
    t = homography()
    inv = t.inverse
    assert isinstance(inv, ProjectiveTransform)
    x, y = _grid()
    xb, yb = inv(*t(x, y))
    assert np.max(np.hypot(xb - x, yb - y)) < 1e-9


def test_projective_from_points_recovers_truth():
    truth = homography()
    src, dst = _pairs(truth, n=60, noise=0.05)
    fit = ProjectiveTransform.from_points(src, dst)
    # 0.05 px noise on 60 stars: the frame is recovered to a few hundredths of a pixel.
    assert _frame_error(fit, truth) < 0.05
    # The best affine model leaves pixels at the corners.
    assert _frame_error(AffineTransform.from_points(src, dst), truth) > 1.0


def test_projective_exact_from_four_points():
    truth = homography()
    src = np.array([[0.0, 0.0], [3071.0, 0.0], [3071.0, 2047.0], [0.0, 2047.0]])
    fit = ProjectiveTransform.from_points(src, np.column_stack(truth(*src.T)))
    assert _frame_error(fit, truth) < 1e-6


def test_projective_weights_leave_out_bad_pairs():
    truth = homography()
    src, dst = _pairs(truth, n=30)
    dst[:3] += 40.0
    w = np.ones(len(src))
    w[:3] = 0.0
    assert _frame_error(ProjectiveTransform.from_points(src, dst, weights=w), truth) < 1e-6
    assert _frame_error(ProjectiveTransform.from_points(src, dst), truth) > 1.0


def test_projective_fit_transform_covariance():
    truth = homography()
    src, dst = _pairs(truth, n=80, seed=3, noise=0.1)
    model, cov, resid = fit_transform(src, dst, "projective")
    assert cov.shape == (8, 8)
    assert np.allclose(resid, np.column_stack(model(*src.T)) - dst)
    # The truth lies within 5 sigma of the fit, parameter by parameter.
    sigma = np.sqrt(np.diag(cov))
    diff = np.array(model.parameters) - np.array(truth.parameters)
    assert np.all(np.abs(diff) < 5 * sigma)
    assert np.std(resid) == pytest.approx(0.1, rel=0.3)


def test_projective_composes_with_astropy_models():
    t = homography()
    chain = (Shift(5.0) & Shift(-3.0)) | t | Rotation2D(10.0)
    x, y = 300.0, 700.0
    expected = Rotation2D(10.0)(*t(x + 5.0, y - 3.0))
    assert chain(x, y) == pytest.approx(expected, abs=1e-9)
    back = chain.inverse(*chain(x, y))
    assert back == pytest.approx((x, y), abs=1e-8)
    assert pickle.loads(pickle.dumps(t))(x, y) == t(x, y)


def test_projective_bad_input():
    with pytest.raises(ValueError, match="at least 4"):
        ProjectiveTransform.from_points([[0, 0], [1, 0], [0, 1]], [[0, 0], [1, 0], [0, 1]])
    line = np.column_stack([np.arange(10.0), 2 * np.arange(10.0)])
    with pytest.raises(ValueError, match="do not determine a homography"):
        ProjectiveTransform.from_points(line, line)
    with pytest.raises(ValueError, match="singular"):
        ProjectiveTransform(h11=1.0, h12=2.0, h21=2.0, h22=4.0).inverse
    with pytest.raises(ValueError, match="singular"):
        ProjectiveTransform.from_matrix(np.diag([1.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match=r"\[2, 2\] is 0"):
        ProjectiveTransform.from_matrix([[1.0, 0, 0], [0, 1.0, 0], [0, 0.01, 0]])
    with pytest.raises(ValueError, match="shape"):
        ProjectiveTransform.from_matrix(np.eye(2))
    with pytest.raises(ValueError, match="same length"):
        ProjectiveTransform.from_points(np.zeros((5, 2)), np.zeros((6, 2)))
    with pytest.raises(ValueError, match="weights"):
        ProjectiveTransform.from_points(*_pairs(homography(), 10), weights=-np.ones(10))


# -- polynomial --------------------------------------------------------------------------

def test_polynomial_is_the_sip_form():
    t = barrel()
    x, y = 100.0, 1900.0
    u, v = x - 1535.5, y - 1023.5
    f = -1.8e-9 * (u ** 3 + u * v ** 2) + 3e-7 * u ** 2
    g = -1.8e-9 * (u ** 2 * v + v ** 3) - 2e-7 * u * v
    lin = t.linear_matrix
    expected = lin @ [u + f, v + g] + [1530.0, 1010.0]
    assert t(x, y) == pytest.approx(tuple(expected), abs=1e-9)
    assert t.crpix == (1535.5, 1023.5)
    assert t.fixed["crpix1"] and t.fixed["crpix2"]
    # The linear part is the model without its distortion terms.
    bare = PolynomialTransform(degree=3, crpix=(1535.5, 1023.5), a11=lin[0, 0], a12=lin[0, 1],
                               a21=lin[1, 0], a22=lin[1, 1], translation_x=1530.0,
                               translation_y=1010.0)
    assert _frame_error(t.linear_part, bare) < 1e-9


@pytest.mark.parametrize("degree", [2, 3, 4, 5])
def test_polynomial_from_points_recovers_truth(degree):
    truth = barrel(degree=max(degree, 3)) if degree >= 3 else PolynomialTransform(
        degree=2, crpix=(1535.5, 1023.5), translation_x=3.0, A_2_0=2e-6, B_1_1=-1e-6,
        domain=DOMAIN)
    src, dst = _pairs(truth, n=300, seed=degree, noise=0.03)
    fit = PolynomialTransform.from_points(src, dst, degree=degree, domain=DOMAIN)
    assert fit.degree == degree
    assert _frame_error(fit, truth) < 0.05
    # The linear model leaves pixels at the corners.
    if degree >= 3:
        assert _frame_error(AffineTransform.from_points(src, dst), truth) > 2.0


def test_polynomial_exact_fit_any_crpix():
    truth = barrel()
    src, dst = _pairs(truth, n=100, seed=5)
    for crpix in (None, (0.0, 0.0), (3000.0, 100.0)):
        fit = PolynomialTransform.from_points(src, dst, degree=3, crpix=crpix)
        assert _frame_error(fit, truth) < 1e-6
    assert PolynomialTransform.from_points(src, dst).crpix == pytest.approx(
        (0.5 * (src[:, 0].min() + src[:, 0].max()), 0.5 * (src[:, 1].min() + src[:, 1].max())))


@pytest.mark.parametrize("degree", [2, 3, 5])
def test_polynomial_inverse_accuracy(degree):
    truth = barrel(degree=max(degree, 3)) if degree > 2 else PolynomialTransform(
        degree=2, crpix=(1535.5, 1023.5), A_2_0=1e-6, B_0_2=-1e-6, domain=DOMAIN)
    inv = truth.inverse
    assert isinstance(inv, PolynomialTransform)
    x, y = _grid(n=51)
    xb, yb = inv(*truth(x, y))
    err = float(np.max(np.hypot(xb - x, yb - y)))
    # The reported error is what one measures, and small for a few pixels of distortion.
    assert err <= truth.inverse_error * 1.5 + 1e-9
    assert truth.inverse_error < 0.01
    # Changing a parameter refits the inverse.
    truth.translation_x = truth.translation_x + 7.0
    assert truth.inverse(*truth(500.0, 600.0)) == pytest.approx((500.0, 600.0), abs=0.01)


def test_polynomial_without_domain_has_no_inverse():
    t = PolynomialTransform(degree=2, A_2_0=1e-6)
    assert not t.has_inverse()
    with pytest.raises(ValueError, match="domain"):
        t.inverse
    t.domain = (0, 100, 0, 100)
    assert t.has_inverse()


def test_polynomial_fit_transform_covariance():
    truth = barrel()
    src, dst = _pairs(truth, n=400, seed=7, noise=0.05)
    model, cov, resid = fit_transform(src, dst, "polynomial", degree=3, crpix=truth.crpix,
                                      domain=DOMAIN, weights=np.full(400, 4.0))
    free = [n for n in model.param_names if not model.fixed[n]]
    assert model.crpix == truth.crpix and model.domain == DOMAIN
    assert cov.shape == (len(free), len(free)) == (20, 20)
    assert np.allclose(resid, np.column_stack(model(*src.T)) - dst)
    # The truth lies within 5 sigma of the fit, parameter by parameter, and the
    # covariance does not depend on the scale of the weights.
    diff = np.array([getattr(model, n).value - getattr(truth, n).value for n in free])
    assert np.all(np.abs(diff) < 5 * np.sqrt(np.diag(cov)))
    _, cov1, _ = fit_transform(src, dst, "polynomial", degree=3, crpix=truth.crpix)
    assert np.allclose(cov1, cov, rtol=1e-6)
    with pytest.raises(ValueError, match="polynomial"):
        fit_transform(src, dst, "affine", degree=3)


def test_polynomial_composes_and_copies():
    t = barrel()
    chain = (Shift(10.0) & Shift(20.0)) | t
    assert chain(100.0, 200.0) == pytest.approx(t(110.0, 220.0), abs=1e-12)
    back = chain.inverse(*chain(100.0, 200.0))
    assert back == pytest.approx((100.0, 200.0), abs=0.01)
    for other in (t.copy(), pickle.loads(pickle.dumps(t))):
        assert other.param_names == t.param_names and other.domain == t.domain
        assert other(123.0, 456.0) == t(123.0, 456.0)
    # Instances of different degree do not share parameters.
    assert len(PolynomialTransform(degree=2).param_names) == 8 + 6
    assert len(PolynomialTransform(degree=5).param_names) == 8 + 36
    assert len(t.param_names) == 8 + 14


def test_polynomial_bad_input():
    for degree in (1, 6, 0):
        with pytest.raises(ValueError, match="degree must be an integer from 2 to 5"):
            PolynomialTransform(degree=degree)
    with pytest.raises(TypeError, match="integer"):
        PolynomialTransform(degree=2.5)
    with pytest.raises(TypeError, match="A_4_0"):
        PolynomialTransform(degree=3, A_4_0=1.0)
    with pytest.raises(ValueError, match="crpix"):
        PolynomialTransform(crpix=(1.0, np.nan))
    with pytest.raises(ValueError, match="domain"):
        PolynomialTransform(domain=(10, 0, 0, 10))
    src, dst = _pairs(barrel(), n=9)
    with pytest.raises(ValueError, match="at least 10"):
        PolynomialTransform.from_points(src, dst, degree=3)
    with pytest.raises(ValueError, match="degree must be an integer from 2 to 5"):
        PolynomialTransform.from_points(src, dst, degree=7)
    # Points on two lines do not determine a cubic.
    xs = np.linspace(0, 1000, 20)
    lines = np.concatenate([np.column_stack([xs, xs * 0]), np.column_stack([xs, xs * 0 + 500])])
    with pytest.raises(ValueError, match="do not determine a degree-3 polynomial"):
        PolynomialTransform.from_points(lines, lines + 1.0, degree=3)
    # A fit that squashes the plane onto a line.
    src, _ = _pairs(barrel(), n=40)
    flat = np.column_stack([src[:, 0], np.zeros(40)])
    with pytest.raises(ValueError, match="singular"):
        PolynomialTransform.from_points(src, flat, degree=2)


@pytest.mark.parametrize("cls", [ProjectiveTransform, PolynomialTransform])
def test_from_points_refuses_text_with_a_type_error(cls):
    with pytest.raises(TypeError, match=r"\(N, 2\) array"):
        cls.from_points("abc", np.ones((12, 2)))
