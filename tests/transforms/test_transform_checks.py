# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""One rule each: candidate models' design matrices, the degree, point and singularity checks."""

import numpy as np
import pytest
from astropy.io import fits

from astroalign_nd.io import transform_from_header, transform_to_header
from astroalign_nd.matching import match_points
from astroalign_nd.resample import resample
from astroalign_nd.transforms import (AffineTransform, PolynomialTransform, ProjectiveTransform,
                                      SimilarityTransform, check_degree)
from astroalign_nd.transforms import selection
from astroalign_nd.transforms._matrix import SINGULAR_RTOL, _close, check_invertible, is_singular
from astroalign_nd.transforms.layers import monomials, polynomial_terms
from astroalign_nd.transforms.polynomial import DEGREES
from astroalign_nd.transforms.projective import _homography_jacobian


# -- one set of design matrices, one degree check --------------------------------------------

def test_candidate_design_matrices_are_the_models():
    rng = np.random.default_rng(4)
    uv = rng.uniform(-1, 1, (30, 2))
    poly = PolynomialTransform.layer(degree=3).design(uv)
    base = monomials(uv[:, 0], uv[:, 1], polynomial_terms(3))
    assert np.array_equal(poly[:, 0, :10], base) and np.array_equal(poly[:, 1, 10:], base)
    for parity in (1, -1):
        sim = SimilarityTransform.layer(parity).design(uv)
        assert np.array_equal(sim.reshape(-1, 4), SimilarityTransform._design(uv, None, parity))
    params = np.array([1.01, 0.02, 0.1, -0.03, 0.99, -0.2, 0.05, -0.04])
    cand = ProjectiveTransform.layer()
    h = cand._matrix(params)
    assert np.array_equal(cand.design(uv, params).reshape(-1, 8), _homography_jacobian(h, uv))
    model = ProjectiveTransform.from_matrix(h)
    assert np.allclose(cand.predict(params, uv), np.column_stack(model(*uv.T)), rtol=0,
                       atol=1e-14)
    assert polynomial_terms(5, lowest=2) == [(p, q) for p, q in polynomial_terms(5)
                                             if p + q >= 2]
    assert selection.DEGREES is DEGREES


@pytest.mark.parametrize("bad, error", [(7, ValueError), (1, ValueError), (2.5, TypeError),
                                        (True, TypeError)])
def test_one_degree_check(bad, error):
    core = "degree must be an integer from 2 to 5"
    with pytest.raises(error, match=core):
        PolynomialTransform(degree=bad)
    with pytest.raises(error, match=core + " or 'auto'"):
        check_degree("polynomial", bad)
    hdr = transform_to_header(PolynomialTransform(degree=2, crpix=(5.0, 5.0)))
    hdr["AATDEG"] = bad
    with pytest.raises(ValueError, match="AATDEG must be the polynomial's degree.*" + core):
        transform_from_header(hdr)


# -- one check of point lists ------------------------------------------------------------------

def test_one_point_check():
    good = np.random.default_rng(0).uniform(0, 100, (10, 2))
    for bad, error, match in [(good[:, :1], ValueError, r"\(N, 2\)"),
                              (np.where(good > 90, np.nan, good), ValueError, "finite"),
                              ("ten points", TypeError, r"\(N, 2\)")]:
        with pytest.raises(error, match=match):
            AffineTransform.from_points(bad, good)
        with pytest.raises(error, match=match):
            PolynomialTransform.from_points(bad, good, degree=2)
        with pytest.raises(error, match=match):
            match_points(bad, good)
    # Catalogs are pixel coordinates within 1e9; the models fit any positions.
    far = good * 1e8
    AffineTransform.from_points(far, far + 1.0)
    with pytest.raises(ValueError, match="within"):
        match_points(far, far)


# -- one singularity test, one threshold --------------------------------------------------

def test_is_singular_one_rule():
    assert is_singular(np.diag([1.0, 0.0, 1.0])) and is_singular([[np.nan, 0], [0, 1]])
    for scale in (1e-8, 1.0, 1e8):  # the rule does not depend on the scale
        lin = scale * np.array([[1.0, 0.0], [0.0, 1e-13]])
        assert is_singular(lin) and not is_singular(lin * [[1.0], [1e2]])
    # A homography: its linear part h33 A - t v^T, whatever the shift.
    h = np.array([[1.0, 0.0, 2e4], [0.0, 1.0, 1e4], [1e-6, 2e-6, 1.0]])
    assert not is_singular(h)
    back = ProjectiveTransform.from_matrix(h).inverse.matrix @ h
    assert np.allclose(back / back[2, 2], np.eye(3), atol=1e-9)
    t, v = np.array([3.0, 4.0]), np.array([1e-3, 2e-3])
    folded = np.eye(3)
    folded[:2, :2] = np.outer(t, v) + np.diag([1e-14, 0.0])  # A - t v^T ~ 0: det H ~ 0
    folded[:2, 2], folded[2, :2] = t, v
    assert is_singular(folded) and abs(np.linalg.det(folded)) < 1e-12
    assert is_singular([[1, 2, 0], [2, 4, 0], [1, 2, 0]])  # h33 = 0: tested as 3x3
    assert SINGULAR_RTOL == 1e-12


def test_every_singular_check_uses_it():
    m = np.array([[1.0, 2.0, 3.0], [2.0, 4.0 + 1e-13, 1.0], [0.0, 0.0, 1.0]])
    assert is_singular(m)
    with pytest.raises(ValueError, match="singular"):
        check_invertible(m, "AffineTransform")
    with pytest.raises(ValueError, match="singular"):
        AffineTransform.from_matrix(m).inverse
    with pytest.raises(ValueError, match="singular"):
        ProjectiveTransform.from_matrix(m)
    with pytest.raises(ValueError, match="singular"):
        resample(np.ones((8, 8)), m, (8, 8))
    hdr = fits.Header(transform_to_header(PolynomialTransform(degree=2)))
    hdr["AATM00"], hdr["AATM00S"], hdr["AATM01"], hdr["AATM01S"] = 2.0, "2.0", 4.0, "4.0"
    hdr["AATM10"], hdr["AATM10S"], hdr["AATM11"], hdr["AATM11S"] = 1.0, "1.0", 2.0, "2.0"
    with pytest.raises(ValueError, match="singular"):
        transform_from_header(hdr)


def test_close_is_allclose_without_relative_tolerance():
    # The conversions' tolerance test answers as np.allclose(rtol=0): equal
    # infinities are close, NaN never is, and the tolerance is inclusive.
    rng = np.random.default_rng(2)
    base = rng.normal(size=(200, 2, 2))
    other = base + rng.normal(scale=1e-9, size=base.shape) * rng.integers(0, 3, base.shape)
    other[0, 0, 0], base[1, 1, 1], other[2, 1, 0] = np.nan, np.inf, -np.inf
    base[3] = other[3] = np.inf
    other[4] = base[4] + 1e-9 * np.array([[1.0, -1.0], [0.5, 0.0]])
    for a, b in zip(base, other):
        for atol in (0.0, 1e-9, 2e-9):
            assert _close(a, b, atol) == np.allclose(a, b, rtol=0.0, atol=atol)
    assert _close(base[3], other[3], 0.0) and not _close(base[0], other[0], 1.0)
