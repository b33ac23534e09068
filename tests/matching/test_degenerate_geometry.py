# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Matches whose stars lie along one line (a band of detections on a frame's edge) are refused."""

import warnings

import numpy as np
import pytest

from astroalign_nd import find_transform
from astroalign_nd.exceptions import PoorFitWarning, TransformNotFoundError
from astroalign_nd.matching import match_points
from astroalign_nd.matching.verify import _degenerate, _log10_false_alarm
from astroalign_nd.simulate import simulate_pair

from _frame_defects import add_edge_band

FRAME = (-0.5, 511.5, -0.5, 511.5)


def _band_catalog(rng, n_band, n_stars, row):
    """Unrelated stars and a row of detections on ``y = row`` (the band's noise peaks)."""
    stars = rng.uniform(0.0, 511.0, (n_stars, 2))
    band = np.column_stack([rng.uniform(0.0, 511.0, n_band),
                            row + rng.normal(0.0, 0.05, n_band)])
    pts = np.vstack([band, stars])
    return pts[rng.permutation(len(pts))]


def _stars_and_a_row(rng, n_stars, n_row, rotation_deg, shift):
    """
    Related catalogs: ``n_stars`` stars under a rotation and shift (the truth, 3x3),
    then ``n_row`` unrelated detections on row 0 in the source and 0.6 in the target.
    """
    stars = rng.uniform(0, 511, (n_stars, 2))
    c, s = np.cos(np.deg2rad(rotation_deg)), np.sin(np.deg2rad(rotation_deg))
    truth = np.array([[c, -s, shift[0]], [s, c, shift[1]], [0, 0, 1]])
    mapped = stars @ truth[:2, :2].T + truth[:2, 2]
    src = np.vstack([stars, np.column_stack([rng.uniform(0, 511, n_row), np.zeros(n_row)])])
    dst = np.vstack([mapped, np.column_stack([rng.uniform(0, 511, n_row),
                                              np.full(n_row, 0.6)])])
    return src, dst, truth


def test_collinear_matched_points_are_refused_with_the_reason():
    rng = np.random.default_rng(3)
    src = np.column_stack([np.sort(rng.uniform(0, 511, 17)), np.zeros(17)])
    dst = src * [0.237, 0.0] + [300.0, 0.65]
    reason = _degenerate(src, dst, FRAME, FRAME, 0.5)
    assert reason is not None
    assert "the 17 matched stars lie along a line by the bottom edge" in reason
    assert "px across" in reason
    # Spread over the frame: accepted by the check.
    spread = rng.uniform(0, 511, (17, 2))
    assert _degenerate(spread, spread + 3.0, FRAME, FRAME, 0.5) is None


def test_stars_near_one_edge_are_degenerate():
    rng = np.random.default_rng(4)
    pts = np.column_stack([rng.uniform(0, 511, 12), rng.uniform(0, 8, 12)])
    reason = _degenerate(pts, pts, FRAME, FRAME, 0.5)
    assert reason is not None and "bottom edge" in reason


def test_false_alarm_uses_the_density_along_the_line():
    # 20 of 60 detections on a row pair up under the identity: over the frame
    # that looks certain, along the row (the density where they are) it does not.
    rng = np.random.default_rng(5)
    row = np.column_stack([rng.uniform(0, 511, 60), np.zeros(60)])
    others = rng.uniform(0, 511, (40, 2))
    src = np.vstack([row, others])
    dst = np.vstack([row[:20], row[20:] + [2.0, 0.0], others + [0.0, 200.0]])
    args = (np.eye(3), src, dst, 20, 0.5, FRAME, FRAME, 1, 0.1, 50.0, 0.1)
    frame_only = _log10_false_alarm(*args)
    local = _log10_false_alarm(*args, matched=(np.arange(20), np.arange(20)))
    assert frame_only < -20
    assert local > frame_only + 15


@pytest.mark.parametrize("seed", [8, 18])
def test_unrelated_catalogs_with_a_row_of_detections_are_refused(seed):
    # (the old code returned scale 0.4 / 0.2 transforms for these seeds)
    rng = np.random.default_rng(seed)
    src = _band_catalog(rng, 60, 40, 0.0)
    dst = _band_catalog(rng, 60, 40, 0.65)
    with pytest.raises(TransformNotFoundError, match="a 2-D transform needs stars spread"):
        match_points(src, dst, source_frame=FRAME, target_frame=FRAME, n_control=50)


def test_related_catalogs_with_a_row_of_detections_still_match():
    src, dst, truth = _stars_and_a_row(np.random.default_rng(7), 60, 40, 10.0, (12.0, -7.0))
    result = match_points(src, dst, source_frame=FRAME, target_frame=FRAME)
    assert result.n_matches >= 50
    np.testing.assert_allclose(result.transform.matrix, truth, atol=1e-6)


def test_related_images_with_edge_bands_keep_their_answer():
    pair = simulate_pair((256, 256), n_stars=80, rotation=20.0, translation=(6.0, -4.0),
                         seed=5)
    src = add_edge_band(pair.source, seed=6)
    dst = add_edge_band(pair.target, seed=7)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        t, _ = find_transform(src, dst)
    g = np.array([[0.0, 0.0], [255.0, 0.0], [0.0, 255.0], [255.0, 255.0]])
    np.testing.assert_allclose(t(*g.T), pair.transform(*g.T), atol=0.3)


@pytest.mark.parametrize("seed", [0, 4])
def test_search_goes_on_past_a_row_of_detections_to_the_real_stars(seed):
    # 60 detections on a row (exactly collinear, as a band's peaks on row 0)
    # outnumber 20 real stars: the row's chance hypotheses have the most
    # inliers, and the search must set them aside and find the stars.
    # (The old code raised LinAlgError on the collinear stars.)
    rng = np.random.default_rng(seed)
    src, dst, truth = _stars_and_a_row(rng, 20, 60, 3.0, (5.0, -2.0))
    src, dst = src[rng.permutation(len(src))], dst[rng.permutation(len(dst))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PoorFitWarning)  # a chance pair on the row may join
        result = match_points(src, dst, source_frame=FRAME, target_frame=FRAME)
    g = np.array([[0.0, 0.0], [511.0, 0.0], [0.0, 511.0], [511.0, 511.0]])
    expected = g @ truth[:2, :2].T + truth[:2, 2]
    assert result.n_matches >= 20
    np.testing.assert_allclose(np.column_stack(result.transform(*g.T)), expected, atol=0.3)
