# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Triangle matching: pairs of similar triangles and the transform hypotheses they give."""

import numpy as np

__all__ = ['match_triangles', 'hypothesis_matrices']

#: Most candidate triangle pairs held in memory at once (about 24 bytes each).
_MAX_PAIRS = 2_000_000


def match_triangles(src_ast, dst_ast, radius, *, max_matches=None):
    """
    Pairs of triangles whose invariants are within ``radius``, best first.

    Memory is bounded: when more than ``4 * max_matches`` pairs (at most
    2 million) would lie within ``radius``, the radius shrinks until
    about half that many do (the pairs kept are the best ones anyway), and
    if even near-identical invariants are too many (a regular lattice of
    points), each source triangle keeps only its nearest target triangles.

    Returns
    -------
    pairs : (K, 2) int ndarray
        Indices into ``src_ast.triangles`` and ``dst_ast.triangles``.
    dist : (K,) ndarray
        Distance in invariant space.

    Examples
    --------
    The same stars listed in reverse order and twice as far apart: the
    closest pair of triangles is one triangle of stars in both lists.

    >>> import numpy as np
    >>> from astroalign_nd.matching import build_asterisms
    >>> from astroalign_nd.matching import match_triangles
    >>> src = np.random.default_rng(0).uniform(0, 200, (40, 2))
    >>> a, b = build_asterisms(src), build_asterisms(2.0 * src[::-1])
    >>> pairs, dist = match_triangles(a, b, 0.01)
    >>> pairs.shape[1], bool(dist[0] < 1e-9)
    (2, True)
    >>> i, j = pairs[0]
    >>> bool(np.all(a.triangles[i] == 39 - b.triangles[j]))
    True
    """
    if len(src_ast) == 0 or len(dst_ast) == 0:
        return np.empty((0, 2), int), np.empty(0)
    budget = _MAX_PAIRS if max_matches is None else min(_MAX_PAIRS, max(4 * max_matches, 10_000))
    # The number of pairs, estimated from up to 1000 source triangles (exact
    # when there are fewer) before any pair is listed: counting them all
    # costs as much as listing them.
    step = max(1, len(src_ast) // 1000)
    sample = src_ast.invariants[::step]

    def n_pairs(r):
        counts = dst_ast.tree.query_ball_point(sample, r, return_length=True)
        return float(np.sum(counts)) * len(src_ast) / len(sample)

    # (No count is needed when even every pair would fit.  When every source
    # triangle is counted and even every pair of the two lists stays within
    # _MAX_PAIRS, the pairs are listed at once: the exact count costs as much
    # as the listing, which then serves when within the budget.)
    n_all, sdm = len(src_ast) * len(dst_ast), None
    if n_all <= budget:
        too_many = False
    elif step == 1 and n_all <= _MAX_PAIRS:
        sdm = src_ast.tree.sparse_distance_matrix(dst_ast.tree, radius, output_type="ndarray")
        too_many = len(sdm) > budget
    else:
        too_many = n_pairs(radius) > budget
    if too_many:
        sdm = None
        # Shrink the radius (the pairs kept are the closest ones anyway).
        for r in radius * np.geomspace(1.0, 1e-6, 25)[1:]:
            if n_pairs(r) <= budget / 2:
                radius = float(r)
                break
        else:
            # Even near-identical invariants are too many (a lattice of points):
            # each source triangle keeps its nearest target triangles only.
            k = max(1, min(len(dst_ast), budget // len(src_ast)))
            d, j = dst_ast.tree.query(src_ast.invariants, k=k, distance_upper_bound=radius)
            d = np.asarray(d).reshape(len(src_ast), k).ravel()
            j = np.asarray(j).reshape(len(src_ast), k).ravel()
            i = np.repeat(np.arange(len(src_ast)), k)
            ok = np.isfinite(d)
            return _sorted_pairs(i[ok], j[ok], d[ok], max_matches)
    if sdm is None:
        sdm = src_ast.tree.sparse_distance_matrix(dst_ast.tree, radius, output_type="ndarray")
    return _sorted_pairs(sdm["i"].astype(int), sdm["j"].astype(int), sdm["v"], max_matches)


def _sorted_pairs(i, j, d, max_matches):
    # By distance, equal distances in (i, j) order: bit-identical results.
    # Without equal distances (the usual case) any sort by distance gives that
    # order, and NumPy's default one is several times faster than a stable sort.
    order = np.argsort(d)
    d_sorted = d[order]
    if np.any(d_sorted[1:] == d_sorted[:-1]):
        # (The pairs are distinct: one stable sort by distance of the pairs put
        # in (i, j) order is np.lexsort((j, i, d)) at a third of its cost.)
        by_ij = np.argsort(i * (int(j.max(initial=0)) + 1) + j, kind="stable")
        order = by_ij[np.argsort(d[by_ij], kind="stable")]
    if max_matches is not None:
        order = order[:max_matches]
    pairs = np.empty((len(order), 2), int)
    pairs[:, 0], pairs[:, 1] = i[order], j[order]
    return pairs, d[order]


def hypothesis_matrices(src_ast, dst_ast, pairs):
    """
    Similarity matrices proposed by triangle matches (vectorised).

    Returns
    -------
    matrices : (K, 3, 3) ndarray
    rms : (K,) ndarray
        RMS residual of each triangle's own three vertices.
    parity : (K,) ndarray
        -1 for mirrored hypotheses.

    Examples
    --------
    A rotation by 20 degrees and a shift, recovered from the best triangle
    match:

    >>> import numpy as np
    >>> from astroalign_nd.matching import build_asterisms
    >>> from astroalign_nd.matching import hypothesis_matrices, match_triangles
    >>> src = np.random.default_rng(0).uniform(0, 200, (40, 2))
    >>> c, s = np.cos(np.deg2rad(20.0)), np.sin(np.deg2rad(20.0))
    >>> truth = np.array([[c, -s, 10.0], [s, c, -5.0], [0.0, 0.0, 1.0]])
    >>> dst = src @ truth[:2, :2].T + truth[:2, 2]
    >>> a, b = build_asterisms(src), build_asterisms(dst)
    >>> pairs, _ = match_triangles(a, b, 0.01)
    >>> matrices, rms, parity = hypothesis_matrices(a, b, pairs[:1])
    >>> matrices.shape
    (1, 3, 3)
    >>> bool(np.allclose(matrices[0], truth)), bool(rms[0] < 1e-9), float(parity[0])
    (True, True, 1.0)
    """
    i, j = pairs[:, 0], pairs[:, 1]
    ts, td = src_ast.triangles[i], dst_ast.triangles[j]
    parity = src_ast.orientation[i] * dst_ast.orientation[j]
    # Coordinates as (K, 3) planes, the arithmetic written out term by term:
    # small einsums and reductions over axes of length 2 and 3 cost more than
    # the arithmetic.  Sums run left to right, in the order NumPy's
    # reductions over those axes add them, so the numbers are the same.
    sx, sy = src_ast.points[ts, 0], src_ast.points[ts, 1]
    dx, dy = dst_ast.points[td, 0], dst_ast.points[td, 1]
    spy = sy * parity[:, None]
    scx, scy = sx - _mean3(sx)[:, None], spy - _mean3(spy)[:, None]
    dcx, dcy = dx - _mean3(dx)[:, None], dy - _mean3(dy)[:, None]
    den = scx[:, 0]**2 + scy[:, 0]**2 + scx[:, 1]**2 + scy[:, 1]**2 + scx[:, 2]**2 \
        + scy[:, 2]**2
    a = _sum3(scx * dcx + scy * dcy) / den
    b = _sum3(scx * dcy - scy * dcx) / den
    m = np.zeros((len(pairs), 3, 3))
    m00, m01, m10, m11 = a, -b * parity, b, a * parity
    m[:, 0, 0], m[:, 0, 1], m[:, 1, 0], m[:, 1, 1] = m00, m01, m10, m11
    mx, my = _mean3(sx), _mean3(sy)
    tx = _mean3(dx) - (m00 * mx + m01 * my)
    ty = _mean3(dy) - (m10 * mx + m11 * my)
    m[:, 0, 2], m[:, 1, 2], m[:, 2, 2] = tx, ty, 1.0
    ex = m00[:, None] * sx + m01[:, None] * sy + tx[:, None] - dx
    ey = m10[:, None] * sx + m11[:, None] * sy + ty[:, None] - dy
    rms = np.sqrt(_sum3(ex**2 + ey**2) / 3)
    return m, rms, parity


def _sum3(v):
    """Row sums of a (K, 3) array, added left to right."""
    return v[:, 0] + v[:, 1] + v[:, 2]


def _mean3(v):
    """Row means of a (K, 3) array, as ``v.mean(axis=1)`` computes them."""
    return _sum3(v) / 3
