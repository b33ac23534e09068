# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Checks of point pairs and parameter values shared by the models."""

from __future__ import annotations

import numpy as np
from .._validate import check_points

__all__ = []


def _check_pairs(cls_name, src, dst, weights, need):
    """Validated (src, dst, weights) for a fit needing ``need`` point pairs."""
    # (No coordinate limit: a fit may be given any positions.)
    src = check_points(src, "src", max_coordinate=None)
    dst = check_points(dst, "dst", max_coordinate=None)
    if len(src) != len(dst):
        raise ValueError(
            f"src and dst must have the same length; got {len(src)} and {len(dst)}.")
    if len(src) < need:
        raise ValueError(f"{cls_name} needs at least {need} point pairs; got {len(src)}.")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (len(src),) or np.any(w < 0) or not np.all(np.isfinite(w)):
        raise ValueError(
            f"weights must be a finite, non-negative array of shape ({len(src)},), one "
            f"per point pair; got shape {w.shape}.")
    if np.count_nonzero(w) < need:
        raise ValueError(
            f"{cls_name} needs at least {need} point pairs with non-zero weight; got "
            f"{np.count_nonzero(w)}.")
    return src, dst, w


def _scalar_values(model):
    return [float(np.ravel(getattr(model, name).value)[0]) for name in model.param_names]
