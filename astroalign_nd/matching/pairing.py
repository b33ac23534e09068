# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Pairing of points under a model: mutual nearest neighbours."""

import numpy as np

__all__ = ['mutual_matches', 'resolve_claims']


def mutual_matches(predicted, tree, tolerance):
    """
    Pair predicted source positions with target points: mutual nearest neighbours.

    Each predicted position is paired with its nearest target point within
    ``tolerance``; a target point claimed by several is kept by the nearest
    of them (at equal distances, the one of lowest index).  The matching's
    refinement and the distortion stage's growth both pair stars this way.

    Parameters
    ----------
    predicted : (N, 2) ndarray
        Source positions mapped into the target frame by the current model.
    tree : `scipy.spatial.cKDTree`
        The k-d tree of the (M, 2) target points.
    tolerance : float
        Pairing radius, in target pixels.

    Returns
    -------
    source_index, target_index : ndarray of int
        The pairs, by increasing source index; each index appears once.

    Examples
    --------
    >>> import numpy as np
    >>> from scipy.spatial import cKDTree
    >>> from astroalign_nd.matching.pairing import mutual_matches
    >>> targets = np.array([[0.0, 0.0], [10.0, 0.0]])
    >>> predicted = np.array([[0.5, 0.0], [0.2, 0.0], [10.4, 0.0], [50.0, 0.0]])
    >>> mutual_matches(predicted, cKDTree(targets), 1.0)  # source 0 loses target 0 to 1
    (array([1, 2]), array([0, 1]))
    """
    if len(predicted) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    d, j = tree.query(predicted, distance_upper_bound=tolerance)
    ok = np.flatnonzero(np.isfinite(d))
    if ok.size == 0:
        return ok, ok
    return resolve_claims(ok, j[ok], d[ok])


def resolve_claims(source_index, target_index, distance):
    """
    One source per target: of the sources that claim a target, keep the nearest.

    The step of `mutual_matches` after the nearest-neighbour query, for
    callers that find each source's nearest target themselves (the
    whole-catalog cross-match keeps its candidates from one query over
    several refits).

    Parameters
    ----------
    source_index, target_index : (K,) ndarray of int
        Each source with the target nearest to it, by increasing source index.
    distance : (K,) ndarray
        Their distances; at equal distances the source of lowest index wins.

    Returns
    -------
    source_index, target_index : ndarray of int
        The pairs kept, by increasing source index.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.matching.pairing import resolve_claims
    >>> resolve_claims(np.array([0, 1, 2]), np.array([5, 5, 7]), np.array([0.3, 0.1, 0.2]))
    (array([1, 2]), array([5, 7]))
    """
    if len(target_index) == 0:
        return source_index, target_index
    shared = np.flatnonzero(np.bincount(target_index)[target_index] > 1)
    if shared.size == 0:  # (usually) no target claimed twice
        return source_index, target_index
    # Only the claims on shared targets are sorted (a few in a million-star list).
    order = shared[np.lexsort((source_index[shared], distance[shared]))]
    _, first = np.unique(target_index[order], return_index=True)
    keep = np.ones(len(target_index), bool)
    keep[shared] = False
    keep[order[first]] = True
    return source_index[keep], target_index[keep]
