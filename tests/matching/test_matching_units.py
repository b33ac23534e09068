# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Unit tests of the matching stage's parts: triangles, false alarms, model misfit, FWHM."""

import numpy as np
import pytest

from astroalign_nd.matching import build_asterisms, match_triangles
from astroalign_nd.matching.triangles import _sorted_pairs
from astroalign_nd.detection import estimate_fwhm
from astroalign_nd.matching.verify import _log10_false_alarm, _model_misfit
from astroalign_nd.simulate import simulate_field
from astroalign_nd.transforms import SimilarityTransform, fit_transform

FRAME = (-0.5, 499.5, -0.5, 499.5)


def _stars(n, seed=0):
    return np.random.default_rng(seed).uniform(20, 480, (n, 2))


def _by_vertices(ast):
    """{sorted vertex triple: (invariants, orientation, size)}."""
    return {tuple(sorted(t)): (inv, o, s) for t, inv, o, s in
            zip(ast.triangles.tolist(), ast.invariants, ast.orientation, ast.size)}


# -- build_asterisms ----------------------------------------------------------------------

def test_asterisms_canonical_order_and_sizes():
    pts = _stars(60)
    ast = build_asterisms(pts)
    p = pts[ast.triangles]
    # side opposite vertex i: between the other two
    side = np.stack([np.hypot(*(p[:, 1] - p[:, 2]).T), np.hypot(*(p[:, 0] - p[:, 2]).T),
                     np.hypot(*(p[:, 0] - p[:, 1]).T)], axis=1)
    assert np.all(np.diff(side, axis=1) >= 0)
    np.testing.assert_allclose(ast.size, side[:, 2])
    np.testing.assert_allclose(ast.invariants, np.log(
        np.column_stack([side[:, 2] / side[:, 1], side[:, 1] / side[:, 0]])))
    assert len({tuple(sorted(t)) for t in ast.triangles.tolist()}) == len(ast)
    # 5 stars give at most 10 triangles each; every star is in one
    assert len(ast) <= 10 * len(pts)
    assert set(np.unique(ast.triangles)) == set(range(len(pts)))


@pytest.mark.parametrize("mirror", [False, True])
def test_asterisms_invariant_under_similarity(mirror):
    pts = _stars(50, seed=1)
    t = SimilarityTransform(scale=1.7, rotation=123.0, translation_x=-40.0, translation_y=7.5,
                            parity=-1 if mirror else 1)
    moved = np.column_stack(t(pts[:, 0], pts[:, 1]))
    a, b = _by_vertices(build_asterisms(pts)), _by_vertices(build_asterisms(moved))
    assert a.keys() == b.keys()  # same neighbourhoods: distances scale uniformly
    for key, (inv, orient, size) in a.items():
        inv2, orient2, size2 = b[key]
        np.testing.assert_allclose(inv2, inv, atol=1e-9)
        assert orient2 == (-orient if mirror else orient)
        assert size2 == pytest.approx(1.7 * size, rel=1e-9)


def test_asterisms_drop_short_sides_and_tiny_lists():
    pts = np.array([[0.0, 0.0], [0.5, 0.0], [10.0, 3.0], [4.0, 9.0]])
    ast = build_asterisms(pts)
    assert all(not {0, 1} <= set(t) for t in ast.triangles.tolist())  # 0.5 px side dropped
    assert len(build_asterisms(pts[:2])) == 0


# -- match_triangles ----------------------------------------------------------------------

@pytest.mark.parametrize("ties", [False, True])
def test_triangle_pairs_come_by_distance_then_indices(ties):
    # Pairs by distance, equal distances by source then target triangle: with or
    # without ties (the fast sort serves only without), the order of a lexsort.
    rng = np.random.default_rng(4)
    i, j = rng.integers(0, 300, 2000), rng.integers(0, 300, 2000)
    ij = np.unique(np.column_stack([i, j]), axis=0)
    ij = ij[rng.permutation(len(ij))]
    d = rng.uniform(0.0, 0.1, len(ij))
    if ties:
        d = np.round(d, 3)  # about 100 distinct values
    pairs, dist = _sorted_pairs(ij[:, 0], ij[:, 1], d, 500)
    order = np.lexsort((ij[:, 1], ij[:, 0], d))[:500]
    assert np.array_equal(pairs, ij[order]) and np.array_equal(dist, d[order])


def test_triangle_pairs_of_one_list_with_itself():
    # Each triangle matches itself at distance 0 (ties, by index); a search that
    # keeps 500 keeps the first 500 of the whole list, which holds every pair
    # within the radius.
    ast = build_asterisms(_stars(150))
    assert 500 < len(ast) and 10_000 < len(ast) ** 2 <= 2_000_000  # (listed at once)
    full, full_dist = match_triangles(ast, ast, 0.005)
    sdm = ast.tree.sparse_distance_matrix(ast.tree, 0.005, output_type="ndarray")
    assert len(full) == len(sdm) < 10_000 and np.all(np.diff(full_dist) >= 0)
    assert np.array_equal(full[:len(ast)], np.repeat(np.arange(len(ast))[:, None], 2, axis=1))
    pairs, dist = match_triangles(ast, ast, 0.005, max_matches=500)
    assert np.array_equal(pairs, full[:500]) and np.array_equal(dist, full_dist[:500])
    # Too many pairs within the radius for the budget (4 x 500, at least 10,000):
    # the radius shrinks to the first of its steps that holds at most half of it.
    many = ast.tree.sparse_distance_matrix(ast.tree, 0.5, output_type="ndarray")
    assert len(many) > 10_000
    steps = 0.5 * np.geomspace(1.0, 1e-6, 25)[1:]
    shrunk = next(r for r in steps if np.sum(ast.tree.query_ball_point(
        ast.invariants, r, return_length=True)) <= 5_000)
    pairs, dist = match_triangles(ast, ast, 0.5, max_matches=500)
    assert len(pairs) == 500 and dist.max() <= shrunk
    direct, direct_dist = match_triangles(ast, ast, shrunk, max_matches=500)
    assert np.array_equal(pairs, direct) and np.array_equal(dist, direct_dist)


# -- _log10_false_alarm -------------------------------------------------------------------

def _lfa(n_matched, n_trials=1, tol=1.0, n=60):
    pts = _stars(n, seed=2)
    return _log10_false_alarm(np.eye(3), pts, pts, n_matched, tol, FRAME, FRAME, n_trials,
                              tri_rms=0.01, tri_size=100.0, inv_radius=0.1)


def test_false_alarm_falls_with_matches_and_rises_with_trials():
    values = [_lfa(k) for k in (3, 6, 12, 30, 60)]
    assert np.all(np.diff(values) < 0)
    assert values[-1] < -50  # 60 of 60 stars within 1 px: no chance
    # The trials factor adds log10(n_trials) exactly.
    assert _lfa(12, n_trials=1000) - _lfa(12) == pytest.approx(3.0, abs=1e-12)
    # A wider radius makes chance agreement likelier.
    assert _lfa(12, tol=3.0) > _lfa(12, tol=1.0)


def test_false_alarm_of_chance_agreement_is_not_small():
    """Unrelated lists: the chance matches at 3 px of 60 random stars are expected."""
    rng = np.random.default_rng(4)
    src, dst = rng.uniform(0, 500, (60, 2)), rng.uniform(0, 500, (60, 2))
    d = np.hypot(*(src[:, None] - dst[None]).transpose(2, 0, 1))
    k = int(np.sum(d.min(axis=1) <= 3.0))
    lfa = _log10_false_alarm(np.eye(3), src, dst, k, 3.0, FRAME, FRAME, 1000, 0.5, 50.0, 0.1)
    assert lfa > np.log10(1e-6)


# -- _model_misfit ------------------------------------------------------------------------

def _sheared_pair(shear, seed=5):
    rng = np.random.default_rng(seed)
    src = rng.uniform(0, 500, (80, 2))
    lin = np.array([[1.0, shear], [0.0, 1.0]])
    dst = src @ lin.T + [3.0, -2.0] + rng.normal(0, 0.05, src.shape)
    return src, dst


def test_model_misfit_flags_shear_and_passes_similarity():
    err = np.full(80, 0.05)
    src, dst = _sheared_pair(0.01)
    model = fit_transform(src, dst, "similarity")[0]
    assert _model_misfit(model, src, dst, err, err, FRAME)[0] > 0.5  # several px at the corners
    # An affine model is its own best affine fit.
    model = fit_transform(src, dst, "affine")[0]
    assert _model_misfit(model, src, dst, err, err, FRAME)[0] == 0.0
    src, dst = _sheared_pair(0.0)
    model = fit_transform(src, dst, "similarity")[0]
    assert _model_misfit(model, src, dst, err, err, FRAME)[0] == 0.0


# -- estimate_fwhm ------------------------------------------------------------------------

@pytest.mark.parametrize("fwhm", [2.5, 4.0, 7.0])
def test_estimate_fwhm_recovers_simulated_width(fwhm):
    image, _ = simulate_field((256, 256), n_stars=150, fwhm=fwhm, flux_range=(2e3, 2e5),
                              seed=11)
    assert estimate_fwhm(image) == pytest.approx(fwhm, rel=0.15)


def test_estimate_fwhm_of_a_blank_image_is_nan():
    assert np.isnan(estimate_fwhm(np.random.default_rng(0).normal(100, 5, (128, 128))))
