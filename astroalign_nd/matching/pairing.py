# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Pairing of points under a model: mutual nearest neighbours."""

import numpy as np

__all__ = ['mutual_matches']


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
    j = j[ok]
    if np.bincount(j).max() == 1:  # (usually) no target claimed twice
        return ok, j
    # Resolve several sources claiming one target: keep the closest.
    order = np.lexsort((ok, d[ok]))
    _, first = np.unique(j[order], return_index=True)
    keep = np.sort(order[first])
    return ok[keep], j[keep]
