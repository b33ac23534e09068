# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
`solve_sequence` with a frame it cannot use (another field, a blank frame) or a frame given
twice: the other frames keep their joint solution and predicted errors, and the frame is
reported.
"""

import numpy as np
import pytest

from astroalign_nd import AstroalignWarning, solve_sequence
from astroalign_nd.simulate import simulate_field, simulate_sequence

CORNERS = np.array([[0.0, 0.0], [191.0, 0.0], [0.0, 191.0], [191.0, 191.0]])


@pytest.fixture(scope="module")
def frames():
    seq = simulate_sequence((192, 192), n_frames=4, n_stars=120, seed=2)
    return [np.asarray(f.data) for f in seq.frames]


@pytest.fixture(scope="module")
def clean(frames):
    return solve_sequence(frames, reference=0)


def _corner_shift(a, b):
    pa, pb = np.array(a(*CORNERS.T)), np.array(b(*CORNERS.T))
    return float(np.max(np.hypot(*(pa - pb))))


def _same_solution(clean, sol, index):
    """Frame k of ``clean`` is frame index[k] of ``sol``: transforms and errors agree."""
    for k, j in enumerate(index):
        assert _corner_shift(clean.transforms[k], sol.transforms[j]) < 1e-3
    np.testing.assert_allclose(sol.predicted_errors[index[1:]], clean.predicted_errors[1:],
                               rtol=0.01)
    assert np.all(clean.predicted_errors[1:] > 0.005)  # a joint solution, not zeros


def _other_field():
    image, _ = simulate_field((192, 192), n_stars=120, seed=99)
    return np.asarray(image)


@pytest.mark.parametrize("bad", ["other field", "blank"])
def test_an_unusable_frame_leaves_the_joint_solution(frames, clean, bad):
    intruder = _other_field() if bad == "other field" else np.full((192, 192), np.nan)
    sol = solve_sequence(frames[:2] + [intruder] + frames[2:], reference=0)
    assert sol.transforms[2] is None and 2 in sol.unsolved
    _same_solution(clean, sol, [0, 1, 3, 4])


def test_a_frame_given_twice_counts_once(frames, clean):
    with pytest.warns(AstroalignWarning, match="frame2 is the same frame as frame1"):
        sol = solve_sequence(frames[:2] + [frames[1]] + frames[2:], reference=0)
    _same_solution(clean, sol, [0, 1, 3, 4])
    assert sol.unsolved == {}
    assert _corner_shift(sol.transforms[2], sol.transforms[1]) == 0.0
    assert sol.predicted_errors[2] == sol.predicted_errors[1]


def test_the_solution_prints_in_one_line(clean):
    text = repr(clean)
    assert "\n" not in text
    assert text.startswith("<SequenceSolution: 4 of 4 frames solved onto frame 0")
