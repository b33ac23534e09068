# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Stage 3 of the method: match triangles, verify, refine.

1. Triangles of the two images whose invariants lie within ``radius`` of
   each other (a k-d tree query) become candidate matches, best first.
2. Each match proposes a similarity transform from its 3 vertex pairs
   (closed form, vectorised over all matches; the match's orientation
   tells whether it is mirrored).
3. Hypotheses are scored in batches by how many source stars land within
   ``tolerance`` pixels of a target star.  This is RANSAC with early
   acceptance, but deterministic: hypotheses come in order of invariant
   distance instead of at random.
4. A promising hypothesis is refined: cross-match every star under it,
   least-squares fit of the requested model, tighten the matching radius
   to the residual scatter, repeat.
5. It is accepted only if the number of matched stars is very unlikely to
   be chance (a binomial false-alarm probability, with a trials factor for
   every hypothesis tried, in the spirit of astrometry.net's odds test).
"""

import functools
import inspect
from collections.abc import MutableMapping
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from scipy.special import betainc

from ._kernels import PointGrid, count_inliers
from ._kernels import median as _median
from ._validate import OPTIONS, check_options, check_points
from .asterisms import build_asterisms
from .exceptions import PoorFitWarning, TooFewSourcesError, TransformNotFoundError, warn
from .transforms import AffineTransform, _apply, fit_transform, transform_class

__all__ = ["MatchResult", "match_points", "match_triangles", "hypothesis_matrices"]


@dataclass
class MatchResult:
    """
    The outcome of matching two star lists.

    Attributes
    ----------
    transform : `~astroalign_nd.transforms.LinearTransform2D`
        The fitted source-to-target transform.
    source_index, target_index : ndarray of int
        Indices of the matched stars in the source and target point lists.
    residuals : (K, 2) ndarray
        ``transform(source) - target`` for the matched stars, in pixels.
    rms : float
        Root-mean-square residual distance in target pixels.
    covariance : ndarray
        Covariance of the transform's free parameters.
    log10_false_alarm : float
        log10 of the probability that this many stars match by chance
        (including a trials factor for the hypotheses tried).
    n_source, n_target : int
        Number of points in each list.
    n_triangle_matches : int
        Candidate triangle matches found in invariant space.
    n_hypotheses : int
        Hypotheses scored before the answer was accepted.
    model_misfit : float
        Largest difference (pixels) over the target frame between the
        transform and an affine fit of the same stars, when the affine fit
        is significantly better (0 otherwise).
    predicted_error : float
        Largest 1-sigma position error (pixels) over the target frame,
        propagated from the covariance.
    source_points, target_points : (K, 2) ndarray
        The matched positions (``source_index`` and ``target_index`` rows
        of the point lists).
    n_sources_used : int or None
        The control points of the successful attempt of
        `~astroalign_nd.find_match` (None from ``match_points``).
    extra : dict-like
        The five attributes above, by name (read and write), for code
        written when they were keys of a dict.

    Examples
    --------
    `match_points` (and `~astroalign_nd.find_match`) return one:

    >>> import numpy as np
    >>> from astroalign_nd.matching import match_points
    >>> rng = np.random.default_rng(0)
    >>> src = rng.uniform(0, 200, (40, 2))
    >>> result = match_points(src, src + [10.0, -5.0])
    >>> result.n_matches, result.source_points.shape
    (40, (40, 2))
    >>> bool(result.rms < 1e-6), bool(result.log10_false_alarm < -6)
    (True, True)
    >>> sorted(result.extra)[:2]
    ['model_misfit', 'predicted_error']
    """

    transform: object
    source_index: np.ndarray
    target_index: np.ndarray
    residuals: np.ndarray
    rms: float
    covariance: np.ndarray
    log10_false_alarm: float
    n_source: int
    n_target: int
    n_triangle_matches: int
    n_hypotheses: int
    model_misfit: float = 0.0
    predicted_error: float = 0.0
    source_points: np.ndarray = None
    target_points: np.ndarray = None
    n_sources_used: int = None
    _other: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n_matches(self):
        """Number of matched stars used in the final fit."""
        return len(self.source_index)

    @property
    def extra(self):
        """The attributes that used to be the keys of a dict ``extra`` (a live view)."""
        return _ExtraView(self)


class _ExtraView(MutableMapping):
    """``MatchResult.extra``: its fields by name; other keys are kept aside."""

    _FIELDS = ("model_misfit", "predicted_error", "source_points", "target_points",
               "n_sources_used")

    def __init__(self, result):
        self._result = result

    def _keys(self):
        return [k for k in self._FIELDS if getattr(self._result, k) is not None] + list(
            self._result._other)

    def __getitem__(self, key):
        if key in self._FIELDS and getattr(self._result, key) is not None:
            return getattr(self._result, key)
        return self._result._other[key]

    def __setitem__(self, key, value):
        if key in self._FIELDS:
            setattr(self._result, key, value)
        else:
            self._result._other[key] = value

    def __delitem__(self, key):
        if key in self._FIELDS:
            setattr(self._result, key, None)
        else:
            del self._result._other[key]

    def __iter__(self):
        return iter(self._keys())

    def __len__(self):
        return len(self._keys())


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
    >>> from astroalign_nd.asterisms import build_asterisms
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

    # (No count is needed when even every pair would fit.)
    if len(src_ast) * len(dst_ast) > budget and n_pairs(radius) > budget:
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
    sdm = src_ast.tree.sparse_distance_matrix(dst_ast.tree, radius, output_type="ndarray")
    return _sorted_pairs(sdm["i"].astype(int), sdm["j"].astype(int), sdm["v"], max_matches)


def _sorted_pairs(i, j, d, max_matches):
    # By distance, equal distances in (i, j) order: bit-identical results.
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
    >>> from astroalign_nd.asterisms import build_asterisms
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


@functools.lru_cache(maxsize=32)
def _grid_points(frame, n_grid):
    """An ``n_grid`` x ``n_grid`` grid of points over a frame (read-only, kept:
    a search asks for the same few grids again and again)."""
    x0, x1, y0, y1 = frame
    xx, yy = np.meshgrid(np.linspace(x0, x1, n_grid), np.linspace(y0, y1, n_grid))
    grid = np.column_stack([xx.ravel(), yy.ravel()])
    grid.flags.writeable = False
    return grid


def _frame_grid(frame, n_grid):
    return _grid_points(tuple(float(v) for v in frame), n_grid)


def _frame_area_fraction(m, src_frame, dst_frame, n_grid=48):
    """Overlap of the source frame mapped into the target frame (fraction, area)."""
    (x0, x1, y0, y1) = dst_frame
    inv = np.linalg.inv(m)
    q = _apply(inv, _frame_grid(dst_frame, n_grid))
    sx0, sx1, sy0, sy1 = src_frame
    inside = (q[:, 0] >= sx0) & (q[:, 0] <= sx1) & (q[:, 1] >= sy0) & (q[:, 1] <= sy1)
    frac = inside.mean()
    return frac, frac * (x1 - x0) * (y1 - y0)


def _overlap_box(m, src_frame, dst_frame, n_grid=24):
    """Bounding box (x0, x1, y0, y1) in the target of the source frame's footprint there."""
    grid = _frame_grid(dst_frame, n_grid)
    inside = grid[_in_frame(_apply(np.linalg.inv(m), grid), src_frame)]
    if len(inside) == 0:
        return dst_frame
    (ox0, oy0), (ox1, oy1) = inside.min(axis=0), inside.max(axis=0)
    return (ox0, ox1, oy0, oy1)


def _in_frame(pts, frame):
    x0, x1, y0, y1 = frame
    return (pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1)


def _log10_false_alarm(m, src_pts, dst_pts, n_matched, tol, src_frame, dst_frame,
                       n_trials, tri_rms, tri_size, inv_radius, n_dof=4):
    """
    log10 probability that ``n_matched`` stars agree by chance.

    Under the null hypothesis (unrelated fields), each source star that
    lands in the overlap falls within ``tol`` of one of the ``m_o`` target
    stars there with probability ``p = m_o * pi * tol^2 / area``.  The 3
    stars of the proposing triangle match by construction, so the binomial
    tail is taken over the others, and the defining triangle contributes
    the chance that random triangles agree as closely as it does.  The
    trials factor counts every hypothesis examined.
    """
    frac, area = _frame_area_fraction(m, src_frame, dst_frame)
    if area <= 0:
        return 0.0
    n_s = int(np.sum(_in_frame(_apply(m, src_pts), dst_frame)))
    m_o = int(np.sum(_in_frame(_apply(np.linalg.inv(m), dst_pts), src_frame)))
    p = min(1.0, max(m_o, 1) * np.pi * tol**2 / area)
    k_extra = max(n_matched - 3, 0)
    n_extra = max(n_s - 3, k_extra)
    if k_extra > 0:
        # P(X >= k) for X ~ Binomial(n, p) is the regularised incomplete beta
        # function I_p(k, n - k + 1) (scipy.special: no scipy.stats import).
        tail = betainc(k_extra, n_extra - k_extra + 1, p) if p < 1 else 1.0
        log_tail = np.log10(tail) if tail > 0 else -300.0
    else:
        log_tail = 0.0
    # Chance that a random triangle pair within the invariant radius fits
    # its own three vertices as well as this one does: the 6 coordinates of
    # the 3 vertex pairs less the model's free parameters (2 spare for a
    # similarity; none for an affine model, which fits any 3 pairs exactly).
    spare = max(0, 6 - max(n_dof, 4))
    spread = max(inv_radius * tri_size, 1e-9)
    log_tri = spare * np.log10(min(1.0, max(tri_rms, 1e-3) / spread))
    # Below 1e-300 the number means "certain"; keep it finite (FITS headers
    # cannot hold -inf).
    return float(max(np.log10(max(n_trials, 1)) + log_tail + log_tri, -300.0))


def _jitter(r2, var, dof):
    """Extra variance ``j2`` so that ``sum(r2 / (var + j2)) = dof`` (0 if none needed)."""
    if dof <= 0 or np.sum(r2 / var) <= dof:
        return 0.0
    lo, hi = 0.0, float(np.max(r2)) + 1e-12
    chi = np.empty(np.broadcast_shapes(np.shape(r2), np.shape(var)))
    for _ in range(40):  # bisection: chi2 decreases monotonically in j2
        mid = 0.5 * (lo + hi)
        np.divide(r2, np.add(var, mid, out=chi), out=chi)  # r2 / (var + mid)
        if chi.sum() > dof:
            lo = mid
        else:
            hi = mid
    return hi


def _inflation(r2, var):
    """
    Factor by which the predicted variances must grow so that the median
    of ``r2 / (f var)`` is that of a chi-square with 2 degrees of freedom.

    A median is not inflated by the few wrong pairs the cut after it must
    remove, and a factor (unlike an added "jitter") keeps the bright,
    well-measured stars' weight above the faint ones'.
    """
    return max(1.0, float(_median(r2 / var)) / (2.0 * np.log(2.0)))


def _prediction_variance(cls, fit_src, fit_w, parity, pts):
    """Per-axis variance of the fitted model's prediction at ``pts``."""
    d_fit = cls._design(fit_src, fit_w, parity)
    d_all = cls._design(pts, np.ones(len(pts)), parity)
    cov = np.linalg.pinv(d_fit.T @ (d_fit * np.repeat(fit_w, 2)[:, None]))
    rows = d_all.reshape(len(pts), 2, -1)
    return np.einsum("nij,jk,nik->n", rows, cov, rows) / 2.0


def _grow_region(m, seed, src_pts, dst_pts, dst_tree, cls, tol):
    """
    Extend a local solution outwards from its seed triangle.

    A similarity proposed by one triangle is right near that triangle and
    increasingly wrong away from it when the true transform has shear or
    anisotropic scale.  Fitting the model to the stars within a radius of
    the triangle, then doubling the radius, lets the solution follow the
    field instead of locking onto wrong pairs far away.
    """
    center, radius = seed
    dist = np.hypot(*(src_pts - center).T)
    r_max = dist.max()
    radius = max(radius, 1.0)
    need = max(cls.min_points, 4)
    for _ in range(128):  # radius grows by 1.5 up to r_max (< 1.5**128 px)
        inside = np.flatnonzero(dist <= radius)
        for _ in range(3):
            # Match, fit, drop the pairs far off the fit (chance pairs pull a
            # local fit away from the field), refit; repeat with the new model.
            si, dj = _mutual_matches(_apply(m, src_pts[inside]), dst_pts, dst_tree, tol)
            if len(si) < need:
                break
            s_in, d_in = src_pts[inside[si]], dst_pts[dj]
            m_new, _ = cls.fit_matrix(s_in, d_in, np.ones(len(si)), 1)
            r = np.hypot(*(_apply(m_new, s_in) - d_in).T)
            good = r <= max(3.0 * _median(r), 0.1 * tol)
            if need <= good.sum() < len(si):
                m_new, _ = cls.fit_matrix(s_in[good], d_in[good], np.ones(good.sum()), 1)
            converged = np.max(np.abs(m_new - m)) < 1e-9
            m = m_new
            if converged:
                break
        if radius >= r_max:
            break
        radius *= 1.5
    return m


def _refine(m0, parity, src_pts, dst_pts, dst_tree, transform_type, tol, min_tol,
            src_err=None, dst_err=None, n_iter=8, seed=None):
    """
    Iterative cross-match and weighted least-squares fit from a matrix.

    Stages: grow a local solution over the field (`_grow_region`, for the
    models with shear), iterate match, weigh, cut and fit
    (`_iterate_fit`), refuse a random set of pairs (`_random_pairs`), and
    fit the model with its covariance (`_final_fit`).  Returns ``(model,
    si, dj, resid, cov, tolerance used)``, or None.
    """
    cls = transform_class(transform_type)
    fit_parity = parity if transform_type in ("similarity", "euclidean") else 1
    m = m0
    if seed is not None and cls.n_dof > 4:
        m = _grow_region(m, seed, src_pts, dst_pts, dst_tree, cls, tol)
    last = _iterate_fit(m, cls, fit_parity, src_pts, dst_pts, dst_tree, tol, min_tol,
                        src_err, dst_err, n_iter)
    if last is None or _random_pairs(last, src_pts, dst_pts, tol):
        return None
    return _final_fit(last, cls, fit_parity, src_pts, dst_pts)


def _pair_variances(m, src, dst, src_err, dst_err):
    """
    Squared residuals of matched pairs under ``m`` and their expected values.

    Each pair's expected squared residual is ``f (s^2 e_src^2 + e_dst^2)``
    (``s`` the scale, ``e`` the detection's centroid errors; 0.01 px^2
    without errors), where the factor ``f >= 1`` (`_inflation`) makes the
    median normalised residual that of a Gaussian: it absorbs what the
    centroid errors do not predict (undersampling, blends) while outliers
    cannot inflate it.
    """
    scale2 = abs(m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0])
    if src_err is not None and dst_err is not None:
        var = scale2 * src_err ** 2 + dst_err ** 2
    else:
        var = np.full(len(src), 0.01)
    resid = _apply(m, src) - dst
    r2 = np.einsum("ij,ij->i", resid, resid)
    return r2, var * _inflation(r2, var)


def _iterate_fit(m, cls, fit_parity, src_pts, dst_pts, dst_tree, tol, min_tol, src_err,
                 dst_err, n_iter):
    """
    Match, weigh, cut and fit until the matrix and the radius settle.

    Pairs whose chi-square, counting the current model's own prediction
    variance, is above 16 are rejected, and the matching radius shrinks to
    5 sigma.  Returns the last fit's ``(si, dj, total variance, radius)``,
    or None when too few pairs matched.
    """
    need = max(cls.min_points, 3)
    cur_tol = tol
    last = prev = None
    for _ in range(n_iter):
        si, dj = _mutual_matches(_apply(m, src_pts), dst_pts, dst_tree, cur_tol)
        if len(si) < need:
            break
        r2, total = _pair_variances(m, src_pts[si], dst_pts[dj],
                                    None if src_err is None else src_err[si],
                                    None if dst_err is None else dst_err[dj])
        # The current model is itself uncertain (early on it rests on the
        # faint majority): its prediction variance enters the cut, so that
        # the brightest stars are not rejected for the model's error.
        pv = _prediction_variance(cls, *prev, fit_parity, src_pts[si]) if prev else 0.0
        # chi2 with 2 dof above 16 happens with probability 3e-4.
        keep = r2 / (total + pv) <= 16.0 if len(si) > cls.n_dof else np.ones(len(si), bool)
        if keep.sum() >= need:
            si, dj, total = si[keep], dj[keep], total[keep]
        # Matrix-level fit: building astropy models here would dominate.
        m_new, _ = cls.fit_matrix(src_pts[si], dst_pts[dj], 1.0 / total, fit_parity)
        prev = (src_pts[si], 1.0 / total)
        last = (si, dj, total, cur_tol)
        new_tol = float(min(max(5.0 * np.sqrt(_median(total)), min_tol), tol))  # (np.clip)
        converged = np.max(np.abs(m_new - m)) < 1e-10 and new_tol == cur_tol
        m, cur_tol = m_new, new_tol
        if converged:
            break
    return last


def _random_pairs(last, src_pts, dst_pts, tol):
    """
    True when the pairs' scatter fills the capture radius even under the
    most flexible model: a random set, however many (a wrong local
    optimum), not to be returned.  If only the requested model leaves a
    large scatter, the pairs are real and the model inadequate, which the
    caller reports (PoorFitWarning).
    """
    si, dj, total, _ = last
    if 4.0 * np.sqrt(_median(total)) > tol and len(si) >= 4:
        aff, _ = AffineTransform.fit_matrix(src_pts[si], dst_pts[dj], 1.0 / total, 1)
        r = _apply(aff, src_pts[si]) - dst_pts[dj]
        return bool(4.0 * np.sqrt(_median(np.einsum("ij,ij->i", r, r)) / 1.386) > tol)
    return False


def _final_fit(last, cls, fit_parity, src_pts, dst_pts):
    """The model, with its covariance and residuals, on the last fit's pairs; or None."""
    si, dj, total, used_tol = last
    try:
        model, cov, resid = fit_transform(src_pts[si], dst_pts[dj], cls,
                                          parity=fit_parity if cls.n_dof in (3, 4) else None,
                                          weights=1.0 / total)
    except ValueError:  # collinear or coincident stars: no transform to trust
        return None
    return model, si, dj, resid, cov, used_tol


def match_points(src_pts, dst_pts, *, transform_type="similarity", tolerance=3.0,
                 min_tolerance=0.5, invariant_radius=0.1, n_neighbors=4,
                 allow_mirror=True, scale_range=None, max_false_alarm=1e-6,
                 accept_matches=10, batch_size=512, max_hypotheses=20_000,
                 source_frame=None, target_frame=None, source_errors=None,
                 target_errors=None):
    """
    Find the transform that maps ``src_pts`` onto ``dst_pts``.

    Parameters
    ----------
    src_pts, dst_pts : (N, 2) ndarray
        Star positions, brightest first.
    transform_type : str, optional
        'translation', 'euclidean', 'similarity' or 'affine'.
    tolerance : float, optional
        Radius (target pixels) within which a transformed source star
        counts as matching a target star while searching.
    min_tolerance : float, optional
        Smallest matching radius the refinement may shrink to.
    invariant_radius : float, optional
        Radius for triangle matches in (log) invariant space.
    n_neighbors : int, optional
        Neighbours per star when building triangles.
    allow_mirror : bool, optional
        Consider mirrored (reflected) solutions (default True).
    scale_range : (float, float), optional
        Allowed source-to-target scale.  Defaults to (0.9, 1.1) for
        'translation' and 'euclidean', and to anything otherwise.
    max_false_alarm : float, optional
        Largest accepted probability that the match is chance.
    accept_matches : int, optional
        Early acceptance: stop searching once a hypothesis that passes the
        false-alarm test has this many matched stars (or all the stars).
    batch_size, max_hypotheses : int, optional
        Hypotheses scored per batch, and at most in total.
    source_frame, target_frame : (x0, x1, y0, y1), optional
        Extent of each image; the points' bounding box by default.
    source_errors, target_errors : (N,) ndarray, optional
        Expected position error of each point (pixels); used to weight the
        final fit.
    Returns
    -------
    result : `MatchResult`

    Raises
    ------
    TooFewSourcesError
        If either list has fewer than 3 points.
    TransformNotFoundError
        If no hypothesis passes the false-alarm test.
    ValueError, TypeError
        If an option is outside its range (one message per option, from
        ``astroalign_nd._validate.OPTIONS``), the positions are not finite
        pixel coordinates, or the triangles would exceed the memory budget.

    Notes
    -----
    Memory is bounded: at most ``MAX_TRIANGLES`` triangles per list and
    ``4 * max_hypotheses`` candidate triangle pairs (the closest) are held.

    Examples
    --------
    Two star lists related by a rotation of 20 degrees and a shift:

    >>> import numpy as np
    >>> from astroalign_nd.matching import match_points
    >>> src = np.random.default_rng(0).uniform(0, 200, (40, 2))
    >>> c, s = np.cos(np.deg2rad(20.0)), np.sin(np.deg2rad(20.0))
    >>> dst = src @ np.array([[c, -s], [s, c]]).T + [10.0, -5.0]
    >>> result = match_points(src, dst)
    >>> result.n_matches
    40
    >>> bool(abs(result.transform.rotation_deg - 20.0) < 1e-6)
    True
    >>> bool(np.allclose(result.transform(*src.T), dst.T))
    True
    """
    return _match_points(
        src_pts, dst_pts, transform_type=transform_type, tolerance=tolerance,
        min_tolerance=min_tolerance, invariant_radius=invariant_radius,
        n_neighbors=n_neighbors, allow_mirror=allow_mirror, scale_range=scale_range,
        max_false_alarm=max_false_alarm, accept_matches=accept_matches,
        batch_size=batch_size, max_hypotheses=max_hypotheses, source_frame=source_frame,
        target_frame=target_frame, source_errors=source_errors, target_errors=target_errors)


#: The settings of `match_points` and their defaults (its signature is their one home).
_SETTINGS = {name: p.default for name, p in inspect.signature(match_points).parameters.items()
             if p.kind is p.KEYWORD_ONLY}


def _search_tolerance(fwhm=None):
    """
    The search's matching radius (pixels) for stars ``fwhm`` pixels wide:
    `match_points`' default, or half the FWHM where that is wider (defocus,
    digitised plates: wide stars have wide position errors).
    """
    return max(_SETTINGS["tolerance"], 0.5 * (fwhm or 0.0))


def _match_points(src_pts, dst_pts, *, n_control=None, source_asterisms=None,
                  target_asterisms=None, prior_trials=0, **settings):
    """
    `match_points`, with what `~astroalign_nd.find_match` knows beyond it.

    Parameters
    ----------
    src_pts, dst_pts : (N, 2) ndarray
        As in `match_points`.
    n_control : int or (int, int), optional
        Only the first ``n_control`` points (the brightest) form triangles
        and score hypotheses; all points are used to refine and verify.  A
        pair gives different numbers for the source and the target.
    source_asterisms, target_asterisms : `~astroalign_nd.asterisms.Asterisms`, optional
        Triangles of the first ``n_control`` points, when already built
        (a reference frame used for many registrations builds them once).
    prior_trials : int, optional
        Hypotheses already tried on this pair by earlier attempts; they
        count in the trials factor of the false-alarm probability.

    **settings
        The keyword arguments of `match_points` (its defaults otherwise).

    The stages: `_prepare` (checks, frames, control points), triangles and
    their `_Hypotheses` (made batch by batch, through `_filter_hypotheses`),
    `_score_batches` (early acceptance), `_final_pass` and `_failure_message`.
    """
    unknown = set(settings) - set(_SETTINGS)
    if unknown:
        raise TypeError(f"unexpected keyword argument(s) {sorted(unknown)}; match_points "
                        f"accepts {list(_SETTINGS)}.")
    s = _prepare(src_pts, dst_pts, {**_SETTINGS, **settings}, n_control, prior_trials)
    src_ast = source_asterisms or build_asterisms(s.src_ctl, n_neighbors=s.n_neighbors)
    dst_ast = target_asterisms or build_asterisms(s.dst_ctl, n_neighbors=s.n_neighbors)
    pairs, _ = match_triangles(src_ast, dst_ast, s.invariant_radius,
                               max_matches=s.max_hypotheses)
    n_tri = len(pairs)
    if n_tri == 0:
        raise _not_found(0, (
            f"no transform found: the source gave {len(s.src_pts)} sources and the target "
            f"{len(s.dst_pts)}, but no triangle matched between them (best inlier count 0). "
            "The images may not overlap, or too few stars are in common; try more sources "
            "(n_sources) or a larger invariant_radius."))
    hyp = _Hypotheses(src_ast, dst_ast, pairs, s)
    s.dst_tree, s.grid = cKDTree(s.dst_pts), PointGrid(s.dst_pts, s.tolerance)
    progress = _score_batches(s, hyp)
    if not progress.accepted:
        _final_pass(s, hyp, progress)
    if progress.best is not None and progress.best.ok:
        return _result(progress.best, s, n_tri, progress.n_scored)
    raise _not_found(progress.n_scored, _failure_message(s, progress, n_tri))


@dataclass
class _Search:
    """What every stage of one search reads: the points, their frames, the settings."""

    src_pts: np.ndarray
    dst_pts: np.ndarray
    src_ctl: np.ndarray  # control points: they form triangles and score hypotheses
    dst_ctl: np.ndarray
    src_frame: tuple
    dst_frame: tuple
    src_err: object
    dst_err: object
    transform_type: str
    n_dof: int
    tolerance: float
    min_tolerance: float
    invariant_radius: float
    n_neighbors: int
    allow_mirror: bool
    scale_range: object
    max_false_alarm: float
    accept_at: int
    n_possible: int
    batch_size: int
    max_hypotheses: int
    prior_trials: int
    max_predicted: float
    dst_tree: object = None  # the target points' k-d tree and grid, built once
    grid: object = None

    @property
    def log_limit(self):
        return np.log10(self.max_false_alarm)


def _prepare(src_pts, dst_pts, settings, n_control, prior_trials):
    """Check the inputs and settings; the frames and control points of a search."""
    src_pts = check_points(src_pts, "source")
    dst_pts = check_points(dst_pts, "target")
    cls = transform_class(settings["transform_type"])
    transform_type = cls.__name__.replace("Transform", "").lower()
    opts = check_options({k: v for k, v in settings.items() if k in OPTIONS})
    for name, pts in (("source", src_pts), ("target", dst_pts)):
        if len(pts) < 3:
            raise TooFewSourcesError(
                f"the {name} has {len(pts)} usable source(s); at least 3 are needed to find "
                "a transform. Lower nsigma, give fwhm, or pass a catalog of positions."
            )
    scale_range = opts["scale_range"]
    if scale_range is None and transform_type in ("translation", "euclidean"):
        scale_range = (0.9, 1.1)
    if n_control is None:
        ns, nd = len(src_pts), len(dst_pts)
    else:
        ns, nd = (n_control, n_control) if np.isscalar(n_control) else n_control
    src_ctl, dst_ctl = src_pts[:int(ns)], dst_pts[:int(nd)]
    n_possible = min(len(src_ctl), len(dst_ctl))
    tolerance = opts["tolerance"]
    return _Search(
        src_pts=src_pts, dst_pts=dst_pts, src_ctl=src_ctl, dst_ctl=dst_ctl,
        src_frame=settings["source_frame"] or _bbox(src_pts),
        dst_frame=settings["target_frame"] or _bbox(dst_pts),
        src_err=settings["source_errors"], dst_err=settings["target_errors"],
        transform_type=transform_type,
        # Free parameters of the fitted model: an affine fit bends to chance
        # agreements that a similarity cannot, so its matches are worth less.
        n_dof=cls.n_dof, tolerance=tolerance, min_tolerance=opts["min_tolerance"],
        invariant_radius=opts["invariant_radius"], n_neighbors=opts["n_neighbors"],
        allow_mirror=opts["allow_mirror"], scale_range=scale_range,
        max_false_alarm=opts["max_false_alarm"],
        accept_at=min(opts["accept_matches"], n_possible), n_possible=n_possible,
        batch_size=opts["batch_size"], max_hypotheses=opts["max_hypotheses"],
        prior_trials=prior_trials,
        # An affine fit extrapolates its shear and anisotropic scale from the
        # matched stars: when they fix it only to a 3-sigma position error above
        # the matching radius somewhere in the overlap of the frames (stars
        # clustered in a corner), it is refused.  Rotation-like models keep the
        # PoorFitWarning: a few widely spread stars (3 are enough) fix them.
        max_predicted=tolerance / 3.0 if cls.n_dof > 4 else np.inf)


class _Hypotheses:
    """
    The triangle-pair hypotheses that pass the filters, best invariant match
    first: ``mats`` (H, 3, 3) source -> target, ``tri_rms`` (how well each
    fits its own triangle's vertices), ``parity`` (-1 for mirrored),
    ``pairs`` (H, 2) source and target triangle indices, ``tri_size`` (the
    target triangle's size) and ``src_ast`` (the source triangles, for the
    refinement's seed).

    They are made as the search reaches them (`grow`): a match is usually
    accepted in the first batch, and the matrices of the thousands of
    pairs after it would be made for nothing.
    """

    def __init__(self, src_ast, dst_ast, pairs, s):
        self.src_ast, self._dst_ast, self._all_pairs, self._s = src_ast, dst_ast, pairs, s
        self._used = 0  # triangle pairs turned into hypotheses so far
        (self.mats, self.tri_rms, self.parity, self.pairs,
         self.tri_size) = _filter_hypotheses(src_ast, dst_ast, pairs[:0], s)

    @property
    def n_pairs(self):
        """The triangle pairs: at most one hypothesis each."""
        return len(self._all_pairs)

    def __len__(self):
        return len(self.mats)

    def grow(self, n):
        """Make hypotheses until ``n`` are held or every pair is used; return how many are."""
        parts = [(self.mats, self.tri_rms, self.parity, self.pairs, self.tri_size)]
        have = len(self.mats)
        while have < n and self._used < len(self._all_pairs):
            chunk = self._all_pairs[self._used:self._used + max(n - have, 256)]
            self._used += len(chunk)
            parts.append(_filter_hypotheses(self.src_ast, self._dst_ast, chunk, self._s))
            have += len(parts[-1][0])
        if len(parts) > 1:
            (self.mats, self.tri_rms, self.parity, self.pairs,
             self.tri_size) = (np.concatenate(col) for col in zip(*parts))
        return have


def _filter_hypotheses(src_ast, dst_ast, pairs, s):
    """Hypotheses of the triangle pairs, less those the settings exclude: (mats,
    tri_rms, parity, pairs, tri_size) as `_Hypotheses` holds them."""
    mats, tri_rms, parity = hypothesis_matrices(src_ast, dst_ast, pairs)
    ok = np.ones(len(mats), bool)
    if not s.allow_mirror:
        ok &= parity > 0
    if s.scale_range is not None:
        scale = np.sqrt(np.abs(np.linalg.det(mats[:, :2, :2])))
        ok &= (scale >= s.scale_range[0]) & (scale <= s.scale_range[1])
    if s.transform_type == "translation":
        rot = np.arctan2(mats[:, 1, 0], mats[:, 0, 0])
        ok &= (np.abs(rot) < 0.1) & (parity > 0)
    sel = np.flatnonzero(ok)
    mats, tri_rms, parity, pairs = mats[sel], tri_rms[sel], parity[sel], pairs[sel]
    tri_size = dst_ast.size[pairs[:, 1]] if len(pairs) else np.empty(0)
    return mats, tri_rms, parity, pairs, tri_size


@dataclass
class _Candidate:
    """A refined hypothesis: its model, matched stars and trust figures."""

    model: object
    si: np.ndarray        # matched source indices
    dj: np.ndarray        # matched target indices
    resid: np.ndarray
    cov: np.ndarray
    lfa: float            # log10 false-alarm probability
    h: int                # the hypothesis it came from
    pred: float           # largest predicted 1-sigma position error in the overlap
    ok: bool              # passes the false-alarm and predicted-error tests

    def rank(self):
        # A trustworthy candidate beats any other; then the less likely chance.
        return (not self.ok, self.lfa)


def _promising(s, hyp, h, n_scored):
    """
    Could hypothesis h pass the false-alarm test, even optimistically?

    Its matches at the search radius, counted over all stars, are judged
    at the smallest radius the refinement may reach.  Chance hypotheses
    fail this cheaply and are not refined.
    """
    k_all = int(count_inliers(hyp.mats[h:h + 1], s.src_pts, s.grid)[0])
    lfa = _log10_false_alarm(hyp.mats[h], s.src_pts, s.dst_pts, k_all, s.min_tolerance,
                             s.src_frame, s.dst_frame, n_scored + s.prior_trials,
                             hyp.tri_rms[h], hyp.tri_size[h], s.invariant_radius)
    return lfa <= s.log_limit


def _evaluate(s, hyp, h, n_scored):
    """Refine hypothesis h and compute its false-alarm probability (None if hopeless)."""
    if not _promising(s, hyp, h, n_scored):
        return None
    ast = hyp.src_ast
    tri = ast.points[ast.triangles[hyp.pairs[h, 0]]]
    seed = (tri.mean(axis=0), 2.0 * ast.size[hyp.pairs[h, 0]])
    res = _refine(hyp.mats[h], hyp.parity[h], s.src_pts, s.dst_pts, s.dst_tree,
                  s.transform_type, s.tolerance, s.min_tolerance, s.src_err, s.dst_err,
                  seed=seed)
    if res is None:
        return None
    model, si, dj, resid, cov, tol = res
    lfa = _log10_false_alarm(model.matrix, s.src_pts, s.dst_pts, len(si), tol, s.src_frame,
                             s.dst_frame, n_scored + s.prior_trials, hyp.tri_rms[h],
                             hyp.tri_size[h], s.invariant_radius, s.n_dof)
    # Where the registered image has data: the overlap of the two frames.
    pred = _predicted_error(model, cov, _overlap_box(model.matrix, s.src_frame, s.dst_frame))
    return _Candidate(model=model, si=si, dj=dj, resid=resid, cov=cov, lfa=lfa, h=h,
                      pred=pred, ok=bool(lfa <= s.log_limit and pred <= s.max_predicted))


@dataclass
class _Progress:
    """Where the search stands after scoring."""

    counts: np.ndarray                          # control-point inliers per hypothesis
    best: _Candidate = None
    n_scored: int = 0
    refined: set = field(default_factory=set)   # hypotheses refined so far
    accepted: bool = False                      # early acceptance


def _score_batches(s, hyp):
    """Score the hypotheses batch by batch, refining the best few of each."""
    counts = np.zeros(hyp.n_pairs, int)  # the hypotheses' (at most one per pair)
    progress = _Progress(counts=counts[:0])
    refined_max, start = 0, 0
    while hyp.grow(start + s.batch_size) > start:
        stop = min(start + s.batch_size, len(hyp))
        progress.counts = counts[:stop]
        # Control points of the source against every target star: a true
        # match also counts stars that are not among the target's brightest.
        counts[start:stop] = count_inliers(hyp.mats[start:stop], s.src_ctl, s.grid)
        progress.n_scored = stop
        # Try the best few of this batch (ties broken by invariant distance).
        order = start + np.argsort(-counts[start:stop], kind="stable")[:3]
        for h in order:
            if counts[h] < min(s.accept_at, 4) and s.n_possible > 3:
                break
            # Refinement budget: after 10 refinements, only a hypothesis
            # that beats every one refined so far is worth another.
            if len(progress.refined) >= 10 and counts[h] <= refined_max:
                break
            cand = _evaluate(s, hyp, h, progress.n_scored)
            progress.refined.add(int(h))
            refined_max = max(refined_max, int(counts[h]))
            if cand is None:
                continue
            if progress.best is None or cand.rank() < progress.best.rank():
                progress.best = cand
            if cand.ok and counts[h] >= s.accept_at:
                # The best so far is returned: an earlier candidate may have
                # matched more stars without reaching accept_at inliers.
                progress.accepted = True
                return progress
        start = stop
    return progress


def _final_pass(s, hyp, progress):
    """No early acceptance: refine the overall best few hypotheses not refined yet."""
    counts = progress.counts
    for h in np.argsort(-counts, kind="stable")[:10]:
        if int(h) in progress.refined or counts[h] < 3:
            continue
        cand = _evaluate(s, hyp, h, progress.n_scored)
        if cand is not None and (progress.best is None or cand.rank() < progress.best.rank()):
            progress.best = cand


def _failure_message(s, progress, n_tri):
    """Why no transform is trusted, and what to try."""
    counts, best = progress.counts, progress.best
    best_count = int(counts.max()) if len(counts) else 0
    detail = ""
    if best is not None and best.lfa > s.log_limit:
        detail = (f"; the best candidate matched {len(best.si)} stars but its false-alarm "
                  f"probability is 10^{best.lfa:.1f} (limit {s.max_false_alarm:g})")
    elif best is not None:
        detail = (f"; the best candidate matched {len(best.si)} stars, but they fix the "
                  f"transform only to {best.pred:.1f} px (1 sigma) somewhere in the frame "
                  f"(limit tolerance / 3 = {s.max_predicted:.2f} px): they cover too small a "
                  "part of it for an affine model; try transform_type='similarity'")
    return (
        f"no trustworthy transform found: the source gave {len(s.src_pts)} sources and the "
        f"target {len(s.dst_pts)}; {n_tri} triangle matches gave {progress.n_scored} "
        f"hypotheses, the best with {best_count} inliers{detail}. The images may not overlap; "
        "otherwise try more sources (n_sources), a larger tolerance, or catalogs of positions.")


def _not_found(n_hypotheses, message):
    exc = TransformNotFoundError(message)
    exc.n_hypotheses = n_hypotheses
    return exc


def _bbox(pts):
    x0, y0 = pts.min(axis=0)
    x1, y1 = pts.max(axis=0)
    pad = 0.5
    return (x0 - pad, x1 + pad, y0 - pad, y1 + pad)


def _model_misfit(model, src, dst, src_err, dst_err, frame):
    """
    How far the fitted model is from an affine fit of the same stars.

    Returns the largest difference (target pixels) between the two models
    over the target frame, if the affine fit is significantly better
    (F-test, p < 1e-6), else 0.  A rotation-like model that leaves
    systematic residuals (shear, anisotropic scale, field distortion) shows
    up here instead of being returned silently.
    """
    n = len(src)
    k_model, k_aff = type(model).n_dof, 6
    if k_model >= k_aff or 2 * n <= k_aff + 2:
        return 0.0
    if src_err is not None and dst_err is not None:
        s2 = abs(np.linalg.det(model.matrix[:2, :2]))
        var = s2 * src_err**2 + dst_err**2
    else:
        var = np.full(n, 0.01)
    aff, _ = AffineTransform.fit_matrix(src, dst, 1.0 / var, 1)
    r_aff = _apply(aff, src) - dst
    r2_aff = np.einsum("ij,ij->i", r_aff, r_aff)
    # Weights from the better (affine) model, with its own jitter.
    var = var + _jitter(r2_aff / 2.0, var, n - k_aff / 2.0)
    r_mod = _apply(model.matrix, src) - dst
    chi_mod = np.sum(np.einsum("ij,ij->i", r_mod, r_mod) / var)
    chi_aff = np.sum(r2_aff / var)
    dof_aff = 2 * n - k_aff
    f_stat = ((chi_mod - chi_aff) / (k_aff - k_model)) / max(chi_aff / dof_aff, 1e-300)
    # Survival function of F(d1, d2): I_x(d2/2, d1/2) with x = d2 / (d2 + d1 F).
    d1, d2 = k_aff - k_model, dof_aff
    if f_stat <= 0 or betainc(d2 / 2.0, d1 / 2.0, d2 / (d2 + d1 * f_stat)) >= 1e-6:
        return 0.0
    x0, x1, y0, y1 = frame if frame is not None else _bbox(dst)
    corners = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]])
    inv_aff = np.linalg.inv(aff)
    pre = _apply(inv_aff, corners)
    return float(np.max(np.hypot(*(_apply(model.matrix, pre) - corners).T)))


def _predicted_error(model, cov, frame):
    """
    Largest 1-sigma position error (target px) over the frame's corners,
    propagated from the parameter covariance.
    """
    cov = np.asarray(cov, float)
    fixed = model.fixed  # (a new dict at each access)
    free = [n for n in model.param_names if not fixed[n]]
    if cov.shape != (len(free), len(free)) or not np.all(np.isfinite(cov)):
        return 0.0
    x0, x1, y0, y1 = frame
    # Errors are largest at the frame's corners, in target pixels; map them
    # back to source pixels, where the model's parameters act.
    inv = np.linalg.inv(model.matrix)
    corners = _apply(inv, np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]]))
    # Finite differences through the model's static ``evaluate`` with perturbed
    # parameter values (copying an astropy model costs ~2 ms each).
    values = {n: float(getattr(model, n).value) for n in model.param_names}

    def at(vals):
        return np.array(model.evaluate(corners[:, 0], corners[:, 1],
                                       *[vals[n] for n in model.param_names]), dtype=float)

    base = at(values)
    jac = np.zeros((2 * len(corners), len(free)))
    for k, name in enumerate(free):
        step = 1e-6 * max(1.0, abs(values[name]))
        jac[:, k] = ((at({**values, name: values[name] + step}) - base) / step).T.ravel()
    var = np.einsum("ik,kl,il->i", jac, cov, jac).reshape(len(corners), 2)
    return float(np.sqrt(np.max(var.sum(axis=1))))


def _result(c, s, n_tri, n_scored):
    """The `MatchResult` of an accepted candidate, with the warnings its fit calls for."""
    src_pts, dst_pts, src_err, dst_err, dst_frame = (s.src_pts, s.dst_pts, s.src_err,
                                                     s.dst_err, s.dst_frame)
    resid = c.resid
    rms = float(np.sqrt(np.mean(np.sum(resid**2, axis=1)))) if len(resid) else float("nan")
    si, dj = c.si, c.dj
    predicted = _predicted_error(c.model, c.cov, dst_frame or _bbox(dst_pts[dj]))
    if predicted > 0.3:  # 3 sigma above 1 px somewhere in the frame
        warn(
            f"the transform is uncertain: its parameter covariance gives a 1-sigma position "
            f"error of up to {predicted:.2f} px over the frame ({len(si)} matched stars, RMS "
            f"{rms:.2f} px). Check it, or give more or brighter stars (n_sources, nsigma).",
            PoorFitWarning)
    misfit = _model_misfit(c.model, src_pts[si], dst_pts[dj],
                           None if src_err is None else src_err[si],
                           None if dst_err is None else dst_err[dj], dst_frame)
    if misfit > 0.5:
        name = type(c.model).__name__
        warn(
            f"the {name} leaves systematic residuals: an affine fit of the same "
            f"{len(si)} stars differs from it by up to {misfit:.2f} px over the frame. The "
            "images have shear, anisotropic scale or distortion; use transform_type='affine'.",
            PoorFitWarning)
    return MatchResult(
        transform=c.model, source_index=si, target_index=dj, residuals=resid,
        rms=rms, covariance=c.cov, log10_false_alarm=c.lfa, n_source=len(src_pts),
        n_target=len(dst_pts), n_triangle_matches=n_tri, n_hypotheses=n_scored,
        model_misfit=misfit, predicted_error=predicted, source_points=src_pts[si],
        target_points=dst_pts[dj])
