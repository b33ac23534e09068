# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Pairing of points under a model: mutual nearest neighbours."""

import numpy as np

__all__ = []


def _mutual_matches(pred, dst_pts, dst_tree, tol):
    """Source i <-> target j when each is the other's nearest within tol."""
    d, j = dst_tree.query(pred, distance_upper_bound=tol)
    ok = np.flatnonzero(np.isfinite(d))
    if ok.size == 0:
        return ok, ok
    j = j[ok]
    if np.bincount(j).max() == 1:  # (usually) no target claimed twice
        return ok, j
    # Resolve several sources claiming one target: keep the closest.
    order = np.lexsort((ok, d[ok]))
    _, first = np.unique(j[order], return_index=True)
    keep = np.sort(order[first])
    return ok[keep], j[keep]
