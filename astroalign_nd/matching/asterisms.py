# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Stage 2 of the method: triangles (asterisms) and their invariants.

Each star and its 4 nearest neighbours give the 10 triangles of those 5
stars; duplicates are removed.  A triangle with sides ``L0 <= L1 <= L2`` is
described by the invariant pair ``(L2/L1, L1/L0)`` of the astroalign paper,
stored as logarithms so that a centroid error moves every triangle by about
the same distance in invariant space (the plain ratios of a thin triangle
blow up).  The vertices are put in a canonical order (by the length of the
opposite side), which gives the vertex correspondence of two matched
triangles, and the sign of the canonical triangle's area tells whether a
match is mirrored.
"""

from dataclasses import dataclass
from itertools import combinations
from math import comb
import numpy as np
from scipy.spatial import cKDTree
from .._validate import MAX_TRIANGLES, check_points
from ..options import check_values
from .options import MatchingConfig

__all__ = ['Asterisms', 'build_asterisms', 'check_triangle_budget']

_COMBOS = np.array(list(combinations(range(5), 3)))


@dataclass
class Asterisms:
    """
    Triangles of a point set and their invariants.

    Attributes
    ----------
    points : (N, 2) ndarray
        The star positions the triangles index.
    triangles : (M, 3) int ndarray
        Vertex indices in canonical order: the vertex opposite the shortest
        side first, the vertex opposite the longest side last.
    invariants : (M, 2) ndarray
        ``(log(L2/L1), log(L1/L0))``.
    orientation : (M,) ndarray
        +1 or -1, the sign of the canonical triangle's signed area.
    size : (M,) ndarray
        Longest side ``L2`` in pixels.

    Examples
    --------
    The four right isosceles triangles of a square: sides ``a, a,
    a*sqrt(2)``, so the invariants are ``(log(sqrt(2)), log(1))``.

    >>> import numpy as np
    >>> from astroalign_nd.matching import build_asterisms
    >>> square = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]]
    >>> ast = build_asterisms(square)
    >>> len(ast), ast.triangles.shape, ast.invariants.shape
    (4, (4, 3), (4, 2))
    >>> bool(np.allclose(ast.invariants, [np.log(np.sqrt(2)), 0.0]))
    True
    >>> bool(np.allclose(ast.size, 10 * np.sqrt(2)))
    True
    """

    points: np.ndarray
    triangles: np.ndarray
    invariants: np.ndarray
    orientation: np.ndarray
    size: np.ndarray

    def __len__(self):
        return len(self.triangles)

    @property
    def tree(self):
        """k-d tree of the invariants (built on first use)."""
        if getattr(self, "_tree", None) is None:
            self._tree = cKDTree(self.invariants)
        return self._tree


def check_triangle_budget(n_points, n_neighbors):
    """
    Refuse, before allocating, more triangles than ``MAX_TRIANGLES``.

    Each of ``n_points`` stars gives at most ``C(n_neighbors + 1, 3)``
    triangles.

    Raises
    ------
    ValueError
        Naming both numbers and what to lower.

    Examples
    --------
    >>> from astroalign_nd.matching import check_triangle_budget
    >>> check_triangle_budget(200, 4)  # 200 stars, 10 triangles each: fine
    >>> check_triangle_budget(1_000_000, 4)
    Traceback (most recent call last):
    ...
    ValueError: 1000000 control points with n_neighbors=4 would build up to 10,000,000 ...
    """
    per_star = comb(min(n_neighbors + 1, max(n_points, 3)), 3)
    n_tri = n_points * per_star
    if n_tri > MAX_TRIANGLES:
        raise ValueError(
            f"{n_points} control points with n_neighbors={n_neighbors} would build up to "
            f"{n_tri:,} triangles per image ({per_star} per star); the limit is "
            f"{MAX_TRIANGLES:,} (about {MAX_TRIANGLES * 100 // 10**6} MB). Lower max_sources "
            f"(at most {MAX_TRIANGLES // per_star} for this n_neighbors) or n_neighbors.")


def build_asterisms(points, *, n_neighbors=4, min_side=1.0):
    """
    Build the nearest-neighbour triangles of a point set.

    Parameters
    ----------
    points : (N, 2) array-like
        Star positions (x, y).
    n_neighbors : int, optional
        Neighbours per star (4 gives the paper's 10 triangles per star).
    min_side : float, optional
        Triangles with a side shorter than this (pixels) are dropped: their
        invariants are dominated by centroid noise.

    Returns
    -------
    asterisms : `Asterisms`

    Examples
    --------
    A 3-4-5 triangle: the vertex opposite the shortest side comes first,
    and the invariants are ``(log(5/4), log(4/3))``.

    >>> import numpy as np
    >>> from astroalign_nd.matching import build_asterisms
    >>> ast = build_asterisms([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]])
    >>> ast.triangles
    array([[2, 1, 0]])
    >>> bool(np.allclose(ast.invariants, [[np.log(5 / 4), np.log(4 / 3)]]))
    True
    >>> float(ast.size[0])
    5.0

    Triangles with a side shorter than ``min_side`` are dropped:

    >>> len(build_asterisms([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0]], min_side=3.5))
    0
    """
    pts = check_points(points, "star")
    n_neighbors = check_values(MatchingConfig, {"n_neighbors": n_neighbors})["n_neighbors"]
    n = len(pts)
    if n < 3:
        return Asterisms(pts, np.empty((0, 3), int), np.empty((0, 2)), np.empty(0), np.empty(0))
    k = min(n_neighbors + 1, n)
    check_triangle_budget(n, n_neighbors)
    _, nbr = cKDTree(pts).query(pts, k)
    nbr = np.asarray(nbr).reshape(n, k)
    combos = _COMBOS if k == 5 else np.array(list(combinations(range(k), 3)))
    tri = np.sort(nbr[:, combos].reshape(-1, 3), axis=1)
    # Each triangle appears once per star whose neighbourhood holds it.  The
    # sorted unique rows, through one integer key per row (np.unique with
    # axis=0 costs ten times as much; a sort and a comparison with the previous
    # key give np.unique's values at a fraction of its cost on a few hundred keys).
    key = np.sort((tri[:, 0].astype(np.int64) * n + tri[:, 1]) * n + tri[:, 2])
    first = np.ones(len(key), bool)
    first[1:] = key[1:] != key[:-1]
    key = key[first]
    tri = np.column_stack([key // (n * n), key // n % n, key % n]).astype(tri.dtype)

    x, y = pts[:, 0][tri], pts[:, 1][tri]  # (M, 3) each
    # side[i] is the length of the side opposite vertex i.
    side = np.stack([
        np.hypot(x[:, 1] - x[:, 2], y[:, 1] - y[:, 2]),
        np.hypot(x[:, 0] - x[:, 2], y[:, 0] - y[:, 2]),
        np.hypot(x[:, 0] - x[:, 1], y[:, 0] - y[:, 1]),
    ], axis=1)
    order = np.argsort(side, axis=1, kind="stable")
    tri = np.take_along_axis(tri, order, axis=1)
    side = np.take_along_axis(side, order, axis=1)
    keep = side[:, 0] >= min_side
    if not keep.all():
        tri, side = tri[keep], side[keep]
    if len(tri) == 0:
        return Asterisms(pts, np.empty((0, 3), int), np.empty((0, 2)), np.empty(0), np.empty(0))
    inv = np.column_stack([np.log(side[:, 2] / side[:, 1]), np.log(side[:, 1] / side[:, 0])])
    p = pts[tri]
    cross = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    orient = np.where(cross >= 0, 1.0, -1.0)
    return Asterisms(pts, tri, inv, orient, side[:, 2])
