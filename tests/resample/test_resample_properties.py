# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Resampling under any linear transform (property-based, hypothesis)."""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from astroalign_nd.resample import resample

from _helpers import random_matrix

FAST = settings(max_examples=12, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])
TYPES = ["translation", "euclidean", "similarity", "affine"]


# -- resampling ----------------------------------------------------------------------

@FAST
@given(ny=st.integers(1, 40), nx=st.integers(1, 40), dx=st.integers(-45, 45),
       dy=st.integers(-45, 45), order=st.sampled_from([0, 1, 3]), seed=st.integers(0, 99))
def test_resample_integer_shift_exact(ny, nx, dx, dy, order, seed):
    data = np.random.default_rng(seed).normal(size=(ny, nx))
    before = data.copy()
    m = np.array([[1.0, 0, dx], [0, 1.0, dy], [0, 0, 1]])
    out, _, mask = resample(data, m, (ny, nx), order=order)
    np.testing.assert_array_equal(data, before)
    yo, xo = np.mgrid[:ny, :nx]
    inside = (xo - dx >= 0) & (xo - dx < nx) & (yo - dy >= 0) & (yo - dy < ny)
    # Interior pixels (away from the edge the kernel needs) copy the source exactly.
    core = inside & (xo - dx >= 2) & (xo - dx < nx - 2) & (yo - dy >= 2) & (yo - dy < ny - 2)
    np.testing.assert_allclose(out[core], data[(yo - dy)[core], (xo - dx)[core]], atol=1e-12)
    assert mask[~inside].all() and np.isnan(out[~inside]).all()


@FAST
@given(seed=st.integers(0, 2**31), transform_type=st.sampled_from(TYPES),
       mirrored=st.booleans(),
       order=st.sampled_from(["nearest-neighbor", "bilinear", "bicubic"]))
def test_resample_any_transform_finite_and_round_trips(seed, transform_type, mirrored, order):
    rng = np.random.default_rng(seed)
    m = random_matrix(rng, transform_type, mirrored)
    m[:2, 2] = 0.0
    m[:2, 2] = np.array([32.0, 32.0]) - m[:2, :2] @ np.array([32.0, 32.0])  # about the centre
    data = rng.normal(100, 5, (64, 64))
    out, var, mask = resample(data, m, (64, 64), order=order, variance=np.ones((64, 64)))
    assert out.shape == (64, 64) and np.all(np.isfinite(out[~mask]))
    assert np.all(var[~mask] >= 0)
    # Values stay within the range of the data (up to the cubic's overshoot).
    assert np.all(out[~mask] > 50) and np.all(out[~mask] < 150)
