# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Every star paired: a transform refitted on all the pairs it makes.

`pair_all` is the engine of `~astroalign_nd.cross_match`.  From a starting
transform (the match of the brightest stars, or one the caller gives), it
pairs every source position with a target position (nearest neighbours
under the model, one source per target, as
``matching.pairing.mutual_matches`` pairs them), refits the
model on all the pairs, sets the pairing radius from the fit's own
residuals, and repeats until the pairs no longer change.

Bounded time and memory for millions of points: one grid of the targets
(``_kernels.PointGrid``, cells of about ``GRID_STARS``
stars), one look-up of each source's two nearest targets within the first
radius (``_kernels.two_nearest``: compiled, or a k-d tree),
and, in later iterations, only the distances to these candidates.  A
candidate list is exact for a moved prediction as long as the prediction
moved by less than the gap to the next target: the sources where it is
not are looked up again (usually none).  The fits of the iterations are
normal-equation fits of the model's parameter layer (its ``fit_layer``,
as the distortion stage fits it: ``astroalign_nd.transforms.layers``),
accumulated in chunks; the final model is `~astroalign_nd.transforms.fit_transform`'s, of
the last of these fits for the linear models (the same least-squares
problem), or fitted by it for the others.
"""

from dataclasses import dataclass

import numpy as np
from scipy.stats import poisson

from .._kernels import PointGrid, two_nearest
from ..exceptions import TooFewSourcesError, TransformNotFoundError
from ..transforms.convert import as_matrix
from ..transforms.fitting import fit_from_matrix, fit_transform
from ..transforms.linear import LinearTransform2D, SimilarityLayer
from ..transforms.layers import PolynomialLayer
from ..transforms.registry import TRANSFORM_REGISTRY, transform_type_of
from ..transforms.selection import (normalise, predict_with, solve_normal_equations,
                                    weighted_fit)
from .grow import fit_nonlinear
from .pairing import resolve_claims

__all__ = ['pair_all', 'AllPairs', 'pairing_radius', 'bounds']

#: Rows of the design matrix built at once (bounds the memory of a fit).
CHUNK = 1 << 17

#: Target stars per cell of the grid of the nearest-neighbour look-ups
#: (`~astroalign_nd._kernels.PointGrid`), on average.
GRID_STARS = 0.5

#: The pairing radius is kept between these many residual sigmas (per axis).
MIN_SIGMAS, MAX_SIGMAS = 3.0, 5.0

#: The pairs must be this improbable as chance coincidences (Poisson, at the
#: target density and the final radius), else the start did not map the
#: source onto the target.
MAX_CHANCE = 1e-6

#: degree='auto' chooses the polynomial degree on at most this many pairs
#: (a deterministic subsample): the choice is settled long before, and its
#: cross-validation's memory grows with the pairs.
AUTO_PAIRS = 20000


@dataclass
class AllPairs:
    """
    The outcome of `pair_all`.

    Attributes
    ----------
    transform : astropy Model
        The model refitted on all the pairs.
    covariance : ndarray
        Its parameter covariance (`~astroalign_nd.transforms.fit_transform`).
    source_index, target_index : ndarray of int
        The pairs (rows of the point lists), by increasing source index.
    residuals : (K, 2) ndarray
        ``transform(source) - target`` of the pairs, pixels.
    radius : float
        The final pairing radius, pixels.
    sigma : float
        The residual scatter per axis (robust), pixels.
    n_iterations : int
        Pairings made.
    converged : bool
        True if the last pairing repeated the one before.
    degree : int or None
        The polynomial degree used (chosen, with ``degree='auto'``).

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.matching.allpairs import AllPairs, pair_all
    >>> rng = np.random.default_rng(1)
    >>> src = rng.uniform(0, 1000, (400, 2))
    >>> out = pair_all(src, src + [3.0, -2.0] + rng.normal(0, 0.05, src.shape), np.eye(3),
    ...                transform_type="translation", tolerance=5.0)
    >>> isinstance(out, AllPairs), len(out.source_index), round(out.sigma, 2)
    (True, 400, 0.05)
    """

    transform: object
    covariance: np.ndarray
    source_index: np.ndarray
    target_index: np.ndarray
    residuals: np.ndarray
    radius: float
    sigma: float
    n_iterations: int
    converged: bool
    degree: object = None


class _Candidates:
    """Each source's two nearest targets at some prediction (its anchor)."""

    def __init__(self, targets, bound, workers):
        # The targets bucketed in cells of about GRID_STARS stars (and at least
        # ``bound`` wide): a query reads its 3x3 cells (`two_nearest`).
        n = len(targets)
        self.grid = PointGrid(targets, float(bound), max_cells=max(int(n / GRID_STARS), 16))
        held = self.grid.points
        # One more row, at infinity, read by the index of an absent neighbour
        # (n): the candidates are gathered without masks.
        self.x = np.append(held[:, 0], np.inf)
        self.y = np.append(held[:, 1], np.inf)
        self.rows = np.append(self.grid.order[:n], n)
        self.bound, self.workers = float(bound), workers
        self.anchor = self.j = self.gap = self.cx = self.cy = None

    def _query(self, pred):
        """(indices, guard distance, candidate x, candidate y, nearest distance) of the
        two nearest targets."""
        d, j = two_nearest(pred, self.grid, self.workers)
        # Absent candidates sit at infinity (their distance is infinite, never NaN);
        # any other target was beyond the second candidate (or the bound).
        return (self.rows[j], np.minimum(d[:, 1], self.bound), self.x[j], self.y[j],
                d[:, 0])

    def nearest(self, pred, radius):
        """(source, target, distance) of the nearest target within ``radius`` of each
        source (exactly: sources whose candidates may be out of date are queried again)."""
        if self.anchor is None:  # the query's own distances: nothing has moved yet
            self.anchor = pred.copy()
            self.j, self.gap, self.cx, self.cy, d0 = self._query(pred)
            si = np.flatnonzero(d0 <= radius)
            return si, self.j[si, 0], d0[si]
        moved = _norm(pred[:, 0] - self.anchor[:, 0], pred[:, 1] - self.anchor[:, 1])
        best, bd = self._best(pred)
        guard = self.gap - moved
        stale = np.flatnonzero(~((bd <= guard) | ((bd > radius) & (radius <= guard))))
        if stale.size:
            self.anchor[stale] = pred[stale]
            self.j[stale], self.gap[stale], self.cx[stale], self.cy[stale], _ = \
                self._query(pred[stale])
            best[stale], bd[stale] = self._best(pred, stale)
        si = np.flatnonzero(bd <= radius)
        return si, best[si], bd[si]

    def _best(self, pred, rows=None):
        j, cx, cy = ((self.j, self.cx, self.cy) if rows is None
                     else (self.j[rows], self.cx[rows], self.cy[rows]))
        p = pred if rows is None else pred[rows]
        dist = _norm(cx - p[:, 0:1], cy - p[:, 1:2])
        second = dist[:, 1] < dist[:, 0]
        return np.where(second, j[:, 1], j[:, 0]), np.where(second, dist[:, 1], dist[:, 0])


def _norm(dx, dy):
    """``hypot(dx, dy)``, ten times faster (no overflow to guard against in pixels)."""
    return np.sqrt(dx * dx + dy * dy)


def bounds(points):
    """(lower, upper) corners of an (N, 2) array's bounding box.

    By columns: a reduction along the first axis of an (N, 2) array is
    twenty times slower than one over each column.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.matching.allpairs import bounds
    >>> bounds(np.array([[1.0, 5.0], [3.0, -2.0]]))
    (array([ 1., -2.]), array([3., 5.]))
    """
    x, y = points[:, 0], points[:, 1]
    return np.array([x.min(), y.min()]), np.array([x.max(), y.max()])


def pairing_radius(sigma, density, n_pairs, n_unpaired):
    """
    The pairing radius (pixels) that loses the fewest pairs either way.

    True pairs are off by a residual with a Gaussian scatter ``sigma`` per
    axis (the distance follows a Rayleigh law); an unpaired source finds a
    chance target within ``r`` with probability ``pi r**2 density``.  The
    radius where both losses balance, ``exp(-r**2 / 2 sigma**2) = 2 pi
    sigma**2 density n_unpaired / n_pairs``, is kept between
    ``MIN_SIGMAS`` and ``MAX_SIGMAS`` sigmas.

    Examples
    --------
    >>> from astroalign_nd.matching.allpairs import pairing_radius
    >>> round(pairing_radius(0.14, 5e-3, 64000, 26000), 3)  # 100,000 stars on 4096 px
    0.57
    """
    sigma = max(float(sigma), 1e-9)
    ratio = 2.0 * np.pi * sigma ** 2 * max(density, 1e-300) * max(n_unpaired, 1) / max(n_pairs, 1)
    k = np.sqrt(max(-2.0 * np.log(min(ratio, 1.0)), 0.0))
    return float(sigma * np.clip(k, MIN_SIGMAS, MAX_SIGMAS))


def _normal_equations(cand, uv, dst):
    """(A^T A, A^T b) of the candidate's design over these pairs."""
    k = cand.k
    if cand.affine_in_position:
        # From the moments of (u, v): no design matrix of all the pairs.
        # (Sums of column products: a matrix product of (N, 2) arrays is slower, and
        # threaded BLAS calls stall on a busy machine.)
        # D0, Du, Dv with ``design(u, v) = D0 + u Du + v Dv`` (each (2, k)).
        d = cand.design(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))
        d0, du, dv = d[0], d[1] - d[0], d[2] - d[0]
        u, v = uv[:, 0], uv[:, 1]
        x, y = dst[:, 0], dst[:, 1]

        def dot(a, b):
            return float(np.sum(a * b))

        n = (len(uv) * d0.T @ d0 + u.sum() * (d0.T @ du + du.T @ d0)
             + v.sum() * (d0.T @ dv + dv.T @ d0) + dot(u, u) * du.T @ du
             + dot(u, v) * (du.T @ dv + dv.T @ du) + dot(v, v) * dv.T @ dv)
        b = (d0.T @ np.array([x.sum(), y.sum()]) + du.T @ np.array([dot(u, x), dot(u, y)])
             + dv.T @ np.array([dot(v, x), dot(v, y)]))
        return n, b
    n, v = np.zeros((k, k)), np.zeros(k)
    for lo in range(0, len(uv), CHUNK):
        a = cand.design(uv[lo:lo + CHUNK]).reshape(-1, k)
        n += a.T @ a
        v += a.T @ dst[lo:lo + CHUNK].reshape(-1)
    return n, v


def _chunked_fit(cand, uv, dst):
    """Least squares of a linear candidate through its normal equations."""
    sol = solve_normal_equations(*_normal_equations(cand, uv, dst))
    return None if sol is None else sol[0]


def _offset(problem, uv):
    """The pixel positions of normalised source points."""
    return problem.centre + problem.half * uv


def _fit_params(problem, cand, uv, dst, params):
    """The candidate's parameters on these pairs (None if degenerate)."""
    if cand.adds_position:  # (a shift: the fixed part, the position, is subtracted)
        dst = dst - _offset(problem, uv)
    if cand.linear:
        return _chunked_fit(cand, uv, dst)
    if params is None or len(params) != cand.k:  # from an affine fit of the same pairs
        aff = _chunked_fit(PolynomialLayer(1), uv, dst)
        if aff is None:
            return None
        params = cand.from_affine(aff)
    fit = weighted_fit(cand, uv, dst, np.ones(len(uv)), params)
    return None if fit is None else fit[0]


def _chunked_predict(problem, cand, params, uv):
    """The candidate's predicted target positions of all the sources."""
    if cand.affine_in_position:
        p = predict_with(cand, params, np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))
        j = p[1:] - p[0]
        out = np.empty_like(uv)
        out[:, 0] = uv[:, 0] * j[0, 0] + uv[:, 1] * j[1, 0] + p[0, 0]
        out[:, 1] = uv[:, 0] * j[0, 1] + uv[:, 1] * j[1, 1] + p[0, 1]
    else:
        out = np.empty_like(uv)
        for lo in range(0, len(uv), CHUNK):
            out[lo:lo + CHUNK] = predict_with(cand, params, uv[lo:lo + CHUNK])
    if cand.adds_position:
        out += _offset(problem, uv)
    return out


def _predict_start(start, src):
    """Predicted target positions of ``src`` under the starting model or matrix."""
    linear = isinstance(start, LinearTransform2D)
    if linear or isinstance(start, np.ndarray) or not callable(start):
        m = as_matrix(start)  # (a linear model through its matrix: no model evaluation)
        if np.allclose(m[2], [0.0, 0.0, 1.0]):
            return src @ m[:2, :2].T + m[:2, 2]
        w = src @ m[2, :2] + m[2, 2]
        return (src @ m[:2, :2].T + m[:2, 2]) / w[:, None]
    x, y = start(src[:, 0], src[:, 1])
    return np.column_stack([x, y]).astype(float)


class _State:
    """The iteration's current pairs, model and radius."""

    def __init__(self, problem, pred, radius):
        self.p = problem
        self.pred, self.radius = pred, radius
        self.si = self.dj = self.cand = None
        self.params, self.sigma = None, 0.0

    def pair(self):
        si, dj, dist = self.p.cands.nearest(self.pred, self.radius)
        return resolve_claims(si, dj, dist)

    def refit(self, si, dj, cand):
        """Fit ``cand`` on the pairs, predict all sources, set the next radius."""
        p = self.p
        uv, dst = np.take(p.uv, si, axis=0), np.take(p.dst, dj, axis=0)
        params = _fit_params(p, cand, uv, dst, self.params)
        if params is None:
            return False
        self.params, self.si, self.dj, self.cand = params, si, dj, cand
        self.pred = _chunked_predict(p, cand, params, p.uv)
        r = np.take(self.pred, si, axis=0) - dst
        # The per-axis scatter from the median squared distance (Rayleigh law).
        r2 = r[:, 0] ** 2 + r[:, 1] ** 2
        self.sigma = float(np.sqrt(np.median(r2) / (2.0 * np.log(2.0)))) if len(r2) else 0.0
        if p.fixed_radius is None:
            new = pairing_radius(self.sigma, p.density, len(si), len(p.uv) - len(si))
            self.radius = min(max(new, p.min_radius), p.tolerance)
        return True


@dataclass
class _Problem:
    src: np.ndarray
    dst: np.ndarray
    uv: np.ndarray
    centre: np.ndarray
    half: float
    frame: tuple
    cands: _Candidates
    density: float
    tolerance: float
    fixed_radius: object
    min_radius: float


def _iterate(state, cand, max_iterations):
    """Pair and refit until the pairs repeat: (iterations, converged)."""
    for it in range(1, max_iterations + 1):
        si, dj = state.pair()
        if len(si) * 2 <= cand.k:
            raise _too_few(len(si), state.radius)
        same = (state.si is not None and np.array_equal(si, state.si)
                and np.array_equal(dj, state.dj))
        if same:
            return it, True
        if not state.refit(si, dj, cand):
            raise _too_few(len(si), state.radius, degenerate=True)
    return max_iterations, False


def _too_few(n, radius, degenerate=False):
    why = "do not constrain the model (degenerate geometry)" if degenerate else "are too few"
    return TooFewSourcesError(
        f"{n} pairs within {radius:.3g} px {why}: the starting transform does not map the "
        "source onto the target, or the radius is too small. Check transform= (or the "
        "match found), or pass a larger first radius (max_radius).")


def _choose_degree(state, conformal, significance):
    """degree='auto': the model chosen by ``fit_nonlinear`` on (a subsample of) the pairs."""
    p = state.p
    si, dj = state.si, state.dj
    if len(si) > AUTO_PAIRS:
        pick = np.sort(np.random.default_rng(0).choice(len(si), AUTO_PAIRS, replace=False))
        si, dj = si[pick], dj[pick]
    aff = _chunked_fit(PolynomialLayer(1), p.uv[si], p.dst[dj])
    m = np.eye(3)  # the affine fit, back in pixels
    m[0, :2], m[1, :2] = aff[1:3] / p.half, aff[4:6] / p.half
    m[0, 2] = aff[0] - m[0, :2] @ p.centre
    m[1, 2] = aff[3] - m[1, :2] @ p.centre
    fit = fit_nonlinear(p.src[si], p.dst[dj], m, transform_type="polynomial", degree="auto",
                        pairs_given=True, tolerance=5.0 * max(state.radius, 1e-3),
                        min_tolerance=state.radius, source_frame=p.frame,
                        significance=significance, linear_type="similarity")
    info = fit.info
    entry = TRANSFORM_REGISTRY[info["model"]]
    if entry.degrees:
        return entry.cls.fit_layer(degree=info["degree"]), entry.name, info["degree"]
    return conformal if entry.conformal else PolynomialLayer(1), entry.name, None


def pair_all(src, dst, start, *, transform_type="similarity", degree=None, parity=None,
             tolerance=2.0, radius=None, max_iterations=10, min_radius=1e-3, frame=None,
             significance=1e-4, workers=1):
    """
    Pair every source position with a target one, refitting the model on all pairs.

    Parameters
    ----------
    src, dst : (N, 2), (M, 2) ndarray
        Source and target positions (pixels).
    start : model or (3, 3) array-like
        The starting source-to-target transform.
    transform_type : str, optional
        The model refitted (a `~astroalign_nd.transforms.TRANSFORM_TYPES` name).
    degree : int or 'auto', optional
        The polynomial degree; 'auto' chooses it (and may choose a linear
        model) on the pairs of a first, affine iteration.
    parity : {1, -1}, optional
        Of the rotation-like models; by default that of ``start``.
    tolerance : float, optional
        The first pairing radius (pixels), and the largest.
    radius : float, optional
        A fixed pairing radius instead of the one set by the residuals.
    max_iterations : int, optional
        Pairings made at most (per model).
    min_radius : float, optional
        The smallest radius the residuals may set (pixels).
    frame : (x0, x1, y0, y1), optional
        The source frame (by default the sources' bounding box).
    significance : float, optional
        The F-test level of ``degree='auto'`` (see
        `~astroalign_nd.matching.fit_nonlinear`).
    workers : int, optional
        Threads of the nearest-neighbour look-ups.

    Returns
    -------
    `AllPairs`

    Raises
    ------
    TooFewSourcesError
        If too few stars pair up to fit the model.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import SimilarityTransform
    >>> from astroalign_nd.matching.allpairs import pair_all
    >>> rng = np.random.default_rng(0)
    >>> src = rng.uniform(0, 2048, (5000, 2))
    >>> truth = SimilarityTransform(scale=1.1, rotation=30.0, translation_x=5.0)
    >>> dst = np.column_stack(truth(*src.T)) + rng.normal(0, 0.1, src.shape)
    >>> start = SimilarityTransform(scale=1.1, rotation=30.01, translation_x=5.5)
    >>> out = pair_all(src, dst, start, tolerance=3.0)
    >>> len(out.source_index), out.converged
    (5000, True)
    """
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    entry = transform_type_of(transform_type)
    if parity is None:  # the sign of the start's Jacobian at the sources' centre
        c = np.array([src[:, 0].mean(), src[:, 1].mean()]) if len(src) else np.zeros(2)
        q = _predict_start(start, np.array([c, c + [1.0, 0.0], c + [0.0, 1.0]]))
        parity = 1 if np.linalg.det(np.array([q[1] - q[0], q[2] - q[0]])) > 0 else -1
    if frame is None:  # the sources' bounding box, as normalise takes it
        lo, hi = bounds(src)
        frame = (lo[0] - 0.5, hi[0] + 0.5, lo[1] - 0.5, hi[1] + 0.5)
    frame, centre, half, uv, _ = normalise(src, frame)
    # degree='auto' starts from the polynomial of degree 1 (an affine map); else
    # the iterations fit the type's ``fit_layer``.
    if degree == "auto":
        cand, deg = PolynomialLayer(1), None
    else:
        cand = entry.cls.fit_layer(parity=parity, degree=degree)
        deg = cand.degree if entry.degrees else None
    lo, hi = bounds(dst)
    density = len(dst) / max(float(np.prod(hi - lo)), 1.0)
    tol = float(tolerance if radius is None else max(radius, 0.0))
    problem = _Problem(src, dst, uv, centre, half, frame, _Candidates(dst, tol, workers),
                       density, tol, radius, float(min_radius))
    state = _State(problem, _predict_start(start, src), tol)
    n_it, converged = _iterate(state, cand, max_iterations)
    name = entry.name
    if degree == "auto":
        cand, name, deg = _choose_degree(state, SimilarityLayer(parity), significance)
        state.params = state.si = None  # refit at least once with the chosen model
        more, converged = _iterate(state, cand, max_iterations)
        n_it += more
    return _final(state, name, deg, parity, n_it, converged, max_iterations)


def _final(state, name, deg, parity, n_it, converged, max_iterations):
    """
    The model of the chosen type fitted on the final pairs: an `AllPairs`;
    pairs no more numerous than chance coincidences would give are refused.
    """
    p = state.p
    n, expected = len(state.si), len(p.uv) * -np.expm1(-np.pi * state.radius ** 2 * p.density)
    chance = float(poisson.sf(n - 1, expected))
    if chance > MAX_CHANCE:
        raise TransformNotFoundError(
            f"the {n} pairs within {state.radius:.3g} px are no more than chance coincidences "
            f"would give ({expected:.1f} expected at this density; probability {chance:.2g}): "
            "the starting transform does not map the source onto the target. Check "
            "transform= (or let the search find it), or pass a larger first radius (max_radius).")
    kw = {}
    entry = TRANSFORM_REGISTRY[name]
    if entry.degrees:
        kw = dict(degree=deg, crpix=(float(p.centre[0]), float(p.centre[1])),
                  domain=tuple(float(v) for v in p.frame))
    elif entry.parity:
        kw = dict(parity=parity)
    for _ in range(max_iterations):
        s, d = np.take(p.src, state.si, axis=0), np.take(p.dst, state.dj, axis=0)
        # The linear types whose iterations solved their own problem: their final
        # model is the last of these fits (built by `fit_from_matrix`, not solved again).
        if (entry.linear and entry.cls.iterated_exactly() and state.cand is not None
                and state.cand.affine_in_position):
            # The 3x3 pixel matrix of the last fit (the candidate is affine in (u, v)).
            q = _chunked_predict(p, state.cand, state.params,
                                 np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))
            m = np.eye(3)
            if not state.cand.adds_position:  # (a shift keeps its exact identity)
                m[:2, :2] = np.column_stack([q[1] - q[0], q[2] - q[0]]) / p.half
            m[:2, 2] = q[0] - m[:2, :2] @ p.centre
            model, cov, resid = fit_from_matrix(name, m, s, d, kw.get("parity", 1))
        else:
            model, cov, resid = fit_transform(s, d, name, **kw)
        if entry.cls.iterated_exactly():
            break
        # Another model than the iterations': pair again under its own fit.
        si, dj = resolve_claims(*p.cands.nearest(_predict_start(model, p.src), state.radius))
        n_it += 1
        if np.array_equal(si, state.si) and np.array_equal(dj, state.dj):
            break
        state.si, state.dj = si, dj
    return AllPairs(model, cov, state.si, state.dj, resid, float(state.radius),
                    float(state.sigma), n_it, converged, deg)
