# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""What a refusal costs: budgeted later attempts, and no astropy model in the fit loop."""

import numpy as np
import pytest

import astroalign_nd.registration as registration
from astroalign_nd import find_match
from astroalign_nd.exceptions import TransformNotFoundError
from astroalign_nd.matching import match_points
from astroalign_nd.transforms import SimilarityTransform
from astroalign_nd.transforms.linear import LinearTransform2D


def _unrelated(seed, n=300, size=1000.0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, size, (n, 2)), rng.uniform(0, size, (n, 2))


@pytest.fixture
def attempts(monkeypatch):
    """The (budget, hypotheses scored or None when it matched) of each attempt."""
    calls = []
    real = registration.match_control_points

    def spy(*args, budget=None, **kwargs):
        try:
            result = real(*args, budget=budget, **kwargs)
        except TransformNotFoundError as exc:
            calls.append((budget, exc.n_hypotheses))
            raise
        calls.append((budget, None))
        return result

    monkeypatch.setattr(registration, "match_control_points", spy)
    return calls


def test_refusal_budgets_later_attempts(attempts):
    # Unrelated catalogs of 300 stars: four attempts (50 / 200 control points
    # each side), every one with thousands of triangle pairs to try.
    src, dst = _unrelated(1)
    with pytest.raises(TransformNotFoundError):
        find_match(src, dst)
    budget = registration.LATER_ATTEMPT_BATCHES * 512
    assert len(attempts) == 4
    first, *later = attempts
    assert first[0] is None and first[1] > budget  # the first attempt searches in full
    for b, scored in later:
        assert b == budget and 0 < scored <= budget


def test_later_budgeted_attempt_still_solves(attempts):
    # The target's 60 brightest stars are not in the source: the first attempt
    # (50 brightest each side) fails far from trust; the second (200 of the
    # target) holds the source's stars and must find them within its budget.
    rng = np.random.default_rng(7)
    src = rng.uniform(0, 1000, (150, 2))
    truth = SimilarityTransform(scale=1.01, rotation=25.0, translation_x=40.0,
                                translation_y=-30.0)
    mapped = np.column_stack(truth(*src.T)) + rng.normal(0, 0.05, src.shape)
    dst = np.vstack([rng.uniform(0, 1000, (60, 2)), mapped])
    result = find_match(src, dst)
    assert attempts[0] == (None, attempts[0][1]) and attempts[0][1] > 0
    assert attempts[-1] == (registration.LATER_ATTEMPT_BATCHES * 512, None)
    corners = np.array([[0.0, 0.0], [1000.0, 0.0], [0.0, 1000.0], [1000.0, 1000.0]])
    err = np.hypot(*(np.column_stack(result.transform(*corners.T))
                     - np.column_stack(truth(*corners.T))).T)
    assert err.max() < 0.5


@pytest.fixture
def models_built(monkeypatch):
    """How many linear astropy models are constructed."""
    count = [0]
    real = LinearTransform2D.__init__

    def counting(self, *args, **kwargs):
        count[0] += 1
        real(self, *args, **kwargs)

    monkeypatch.setattr(LinearTransform2D, "__init__", counting)
    return count


@pytest.mark.parametrize("transform_type", ["similarity", "affine", "euclidean"])
def test_fit_loop_builds_no_model(models_built, transform_type):
    # A refused search refines many hypotheses and builds no model; a match
    # builds one, the answer.
    src, dst = _unrelated(2, n=80, size=500.0)
    with pytest.raises(TransformNotFoundError):
        match_points(src, dst, transform_type=transform_type)
    assert models_built[0] == 0
    shift = np.array([12.5, -7.25])
    result = match_points(src, src + shift, transform_type=transform_type)
    assert models_built[0] == 1
    assert np.allclose(result.transform.matrix[:2, 2], shift, atol=1e-6)
