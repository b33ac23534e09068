"""Helpers shared by the test modules (not a test module itself)."""

import numpy as np


def frame_error(estimate, truth, target_shape, n=17):
    """Largest error (target pixels) of ``estimate`` over the whole target frame.

    For a grid of target pixels ``p``: ``max |T_est(T_true^-1(p)) - p|``.
    Both transforms may be models (with ``.matrix``) or 3x3 matrices.
    """
    m_est = estimate.matrix if hasattr(estimate, "matrix") else np.asarray(estimate)
    m_true = truth.matrix if hasattr(truth, "matrix") else np.asarray(truth)
    ny, nx = target_shape
    gx, gy = np.meshgrid(np.linspace(-0.5, nx - 0.5, n), np.linspace(-0.5, ny - 0.5, n))
    p = np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
    r = p @ np.linalg.inv(m_true).T @ m_est.T
    return float(np.max(np.hypot(r[:, 0] - p[:, 0], r[:, 1] - p[:, 1])))
