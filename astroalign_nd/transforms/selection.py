# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Stage 4 (for wide fields): the choice of a non-linear model, and how far it
can be trusted.

Wide-field optics (camera lenses, small refractors, all-sky cameras) leave
several pixels of residual at the corners under any linear model.  This
stage takes the trusted linear match of `~astroalign_nd.matching` (found on
the brightest stars) and extends it to a projective (homography) or
polynomial-distortion model over all detected stars.

Steps 1 (**grow** the match outwards from the matched stars) and 2
(**refine** it over the whole frame) pair stars: they are the matching's,
described in `~astroalign_nd.matching.grow`.  This module holds steps 3
and 4:

3. **Choose.** With ``degree='auto'`` the candidate models (the linear one
   of the match, affine, polynomial degrees 2 to 5) are fitted to the same
   pairs with the same weights.  A candidate with more terms replaces the
   current choice if an F-test (p < ``significance``) and the Bayesian
   information criterion (BIC) both call for its extra terms; degrees 4
   and 5 must also predict held-out stars meaningfully better, in a
   spatially blocked cross-validation (each cell of a 4x4 grid predicted
   by the fit to the others): with hundreds of real stars, whose centroid
   errors are slightly systematic, the tests alone accept terms that swing
   away where stars are few.  From ``CV_ALL_DEGREES_PAIRS`` pairs on, every
   degree must also not raise the held-out error of the one before.  The
   pairs are then paired and clipped again with the chosen model.
4. **Trust.** The stars must cover the frame well enough for the model's
   terms: the occupancy of a grid of ``(degree + 1)**2`` cells and the
   number of stars per coefficient.  Too little coverage is refused
   (`~astroalign_nd.exceptions.PoorCoverageError`), borderline coverage
   warned about (`~astroalign_nd.exceptions.PoorFitWarning`).  The
   parameter covariance gives the predicted 1-sigma error of the mapping on
   a grid over the frame (largest and RMS), reported in the quality dict.

``fit_nonlinear`` (in `~astroalign_nd.matching.grow`) runs the four; this
module holds what they fit (`Problem`, the robust fit) and steps 3 and 4
(`choose_model`).  The fitting is done here on the models' parameter
layers (`~astroalign_nd.transforms.layers`; coordinates normalised to the
half diagonal of the frame, for conditioning); the returned models are
built by `~astroalign_nd.transforms.fit_transform` on the final pairs, like
the linear ones.
"""

from dataclasses import dataclass
import numpy as np
from scipy.special import betainc
from ..exceptions import PoorCoverageError, PoorFitWarning, TooFewSourcesError, warn
from .convert import as_matrix
from .fitting import fit_transform
from .linear import SimilarityLayer
from .layers import PolynomialLayer, polynomial_terms
from .polynomial import DEGREES
from .registry import check_degree, is_nonlinear, nonlinear_name
from .registry import NONLINEAR_TYPES, TRANSFORM_REGISTRY, transform_type_of

__all__ = ['NONLINEAR_TYPES', 'check_degree', 'DistortionFit', 'choose_model', 'grown_types']


def grown_types():
    """The non-linear types (`NONLINEAR_TYPES`) whose model class has a parameter
    layer: those the distortion stage can grow."""
    return tuple(n for n in NONLINEAR_TYPES if hasattr(TRANSFORM_REGISTRY[n].cls, "layer"))


#: Chi-square (2 degrees of freedom) above which a pair is clipped: p = 3e-4.
CLIP_CHI2 = 16.0

#: Coverage refused below these (explicit degree) ...
MIN_OCCUPANCY = 0.6

MIN_STARS_PER_TERM = 3.0

#: ... and warned about below these.
WARN_OCCUPANCY = 0.85

WARN_STARS_PER_TERM = 6.0

#: Predicted 1-sigma error (px) above which the fit is reported as uncertain.
WARN_PREDICTED = 0.3

#: degree='auto' warns when a linear choice leaves residuals this many times
#: larger than the centroid errors predict.
WARN_EXCESS = 3.0

#: Grid (per axis) on which the predicted error is evaluated.
ERROR_GRID = 33

#: degree='auto': blocks per axis of the spatially blocked cross-validation
#: (each block is held out in turn, so a model is scored where it extrapolates) ...
CV_BLOCKS = 4

#: ... for the degrees above this one (the tests alone decide up to it) ...
CV_FROM_DEGREE = 3

#: ... and a candidate with more terms must lower the held-out error by more
#: than this factor (and by twice its standard error over the cells).
CV_MARGIN = 1.1

#: From this many pairs (a dozen per held-out cell), ``degree='auto'`` also
#: asks every degree, not only those above ``CV_FROM_DEGREE``, not to raise the
#: held-out error.
CV_ALL_DEGREES_PAIRS = 200


# -- the candidate models, as design matrices ---------------------------------------


# Each candidate is its model's parameter layer: the polynomial terms of
# `PolynomialLayer`, the similarity's and the homography's Jacobians.

def _n_terms(degree):
    return len(polynomial_terms(degree))


def predict_with(cand, params, uv):
    """The predicted positions of ``uv`` under a candidate layer's parameters."""
    if cand.linear:
        return np.einsum("nik,k->ni", cand.design(uv), params)
    return cand.predict(params, uv)


def _solve(a, b):
    """Least squares through the normal equations (well conditioned: coordinates are
    normalised); (solution, inverse normal matrix), or None if rank deficient."""
    return solve_normal_equations(a.T @ a, a.T @ b)


def solve_normal_equations(n, v):
    """
    ``(n^-1 v, n^-1)`` for a normal matrix ``n`` (scaled to unit diagonal
    before it is judged and inverted), or None if it is rank deficient.
    """
    d = np.sqrt(np.diag(n))
    if not np.all(d > 0):
        return None
    ns = n / np.outer(d, d)  # unit diagonal: the condition number is meaningful
    if np.linalg.cond(ns) > 1e12:
        return None
    inv = np.linalg.inv(ns) / np.outer(d, d)
    return inv @ v, inv


def weighted_fit(cand, uv, dst, w, start=None):
    """Weighted least squares: (params, unscaled covariance), or None if degenerate."""
    sw = np.sqrt(np.repeat(w, 2))
    if cand.linear:
        a = cand.design(uv).reshape(-1, cand.k) * sw[:, None]
        sol = _solve(a, dst.reshape(-1) * sw)
        return sol
    params = np.array(start, float)
    for _ in range(20):  # Gauss-Newton; converges in a few steps from an affine start
        a = cand.design(uv, params).reshape(-1, cand.k) * sw[:, None]
        r = (dst - cand.predict(params, uv)).reshape(-1) * sw
        sol = _solve(a, r)
        if sol is None:
            return None
        params = params + sol[0]
        if np.max(np.abs(sol[0])) < 1e-13:
            break
    a = cand.design(uv, params).reshape(-1, cand.k) * sw[:, None]
    sol = _solve(a, np.zeros(len(a)))
    return None if sol is None else (params, sol[1])


def _prediction_var(cand, params, cov, uv):
    """Variance (x plus y, px^2) of the fitted mapping at ``uv``."""
    d = cand.design(uv, params)
    return np.einsum("nik,kl,nil->n", d, cov, d)


# -- the robust fit -----------------------------------------------------------------


def _robust_fit(cand, uv, dst, var, start=None, keep=None):
    """
    Fit, clip pairs above ``CLIP_CHI2`` (residual over expected variance,
    scaled so that the median is Gaussian, plus the prediction variance),
    refit, until the kept set is stable.  Returns (params, cov, keep,
    total variance) or None.
    """
    n = len(uv)
    keep = np.ones(n, bool) if keep is None else keep.copy()
    out = None
    for _ in range(12):
        if keep.sum() * 2 <= cand.k:
            return out
        fit = weighted_fit(cand, uv[keep], dst[keep], 1.0 / var[keep], start)
        if fit is None:
            return out
        params, cov = fit
        r = predict_with(cand, params, uv) - dst
        r2 = np.einsum("ij,ij->i", r, r)
        # A median is not moved by the wrong pairs the cut must remove.
        infl = max(1.0, float(np.median(r2[keep] / var[keep])) / (2.0 * np.log(2.0)))
        total = var * infl
        pv = _prediction_var(cand, params, cov * infl, uv)
        new = r2 / (total + pv) <= CLIP_CHI2
        out = (params, cov * infl, keep, total)
        if new.sum() * 2 <= cand.k or np.array_equal(new, keep):
            break
        keep = new
        if not cand.linear:
            start = params
    return out


def _coverage(uv, frame_uv, degree, n_terms):
    """
    How the stars ``uv`` cover the frame: the fraction of the ``(degree + 1)**2``
    cells of the frame holding a star (``occupancy``), and the stars per term.
    """
    g = degree + 1
    x0, x1, y0, y1 = frame_uv
    ix = np.clip(((uv[:, 0] - x0) / (x1 - x0) * g).astype(int), 0, g - 1)
    iy = np.clip(((uv[:, 1] - y0) / (y1 - y0) * g).astype(int), 0, g - 1)
    occ = len(np.unique(iy * g + ix)) / float(g * g)
    return dict(grid=(g, g), occupancy=occ, n_stars=int(len(uv)),
                stars_per_term=len(uv) / float(n_terms))


def _coverage_ok(cov, strict):
    occ_min = MIN_OCCUPANCY if strict else WARN_OCCUPANCY
    per_min = MIN_STARS_PER_TERM if strict else WARN_STARS_PER_TERM
    return cov["occupancy"] >= occ_min and cov["stars_per_term"] >= per_min


def _blocked_cv(cand, uv, dst, w, frame_uv, blocks=CV_BLOCKS):
    """
    Spatially blocked cross-validation: the frame is cut into ``blocks x
    blocks`` cells; each cell's pairs are predicted by the model fitted to
    all the others.  Returns the mean held-out chi-square per pair (inf when
    a training set cannot constrain the model).

    A fit to the stars of one region is judged where it has none: terms that
    only follow the noise (or slightly systematic centroid errors) of
    thousands of stars lower the in-sample chi-square, and the F-test and BIC
    accept them, but they swing away from the stars towards the corners,
    which the held-out cells expose.
    """
    x0, x1, y0, y1 = frame_uv
    ix = np.clip(((uv[:, 0] - x0) / (x1 - x0) * blocks).astype(int), 0, blocks - 1)
    iy = np.clip(((uv[:, 1] - y0) / (y1 - y0) * blocks).astype(int), 0, blocks - 1)
    cell = iy * blocks + ix
    sw = np.sqrt(np.repeat(w, 2))
    a = cand.design(uv).reshape(-1, cand.k) * sw[:, None]
    b = dst.reshape(-1) * sw
    per_cell = np.full(blocks * blocks, np.nan)
    for c in np.unique(cell):
        out = cell == c
        rows = np.repeat(~out, 2)
        sol = _solve(a[rows], b[rows])
        if sol is None:
            return np.inf, None
        r = a[~rows] @ sol[0] - b[~rows]
        per_cell[c] = float(r @ r)
    return float(np.nansum(per_cell)) / len(uv), per_cell / len(uv)


def _cv_better(cells_new, cv_new, cells_old, cv_old):
    """
    True if the held-out error ``cv_new`` improves on ``cv_old`` meaningfully:
    by more than a fraction ``CV_MARGIN - 1`` of it, and either by half or by
    more than twice the standard error of the per-cell differences (a model
    that wins a little, in a single held-out cell, is not better).
    """
    if not np.isfinite(cv_new):
        return False
    if not np.isfinite(cv_old):
        return True
    gain = cv_old - cv_new
    if gain <= (CV_MARGIN - 1.0) * cv_new:
        return False
    if cv_new * 2.0 < cv_old:  # halved: no doubt, however it spreads over the cells
        return True
    ok = np.isfinite(cells_new) & np.isfinite(cells_old)
    diff = (cells_old - cells_new)[ok] * ok.sum()  # per-cell contributions to the mean
    se = float(np.std(diff, ddof=1) / np.sqrt(len(diff))) if len(diff) > 1 else np.inf
    return gain > 2.0 * se


class DistortionFit:
    """
    The outcome of `~astroalign_nd.matching.fit_nonlinear`.

    Attributes
    ----------
    transform : astropy Model
        The chosen source-to-target model: a
        `~astroalign_nd.transforms.ProjectiveTransform`, a
        `~astroalign_nd.transforms.PolynomialTransform`, or a linear model
        when ``degree='auto'`` found no distortion.
    covariance : ndarray
        Covariance of the model's free parameters (from
        `~astroalign_nd.transforms.fit_transform`).
    source_index, target_index : ndarray of int
        The pairs used in the final fit (indices into the point lists).
    residuals : (K, 2) ndarray
        ``transform(source) - target`` for them, pixels.
    rms : float
        Their RMS distance, pixels.
    info : dict
        How the model was chosen and how far it can be trusted: ``model``,
        ``degree``, ``requested_degree``, ``candidates`` (name, number of
        parameters, chi-square, BIC and F-test p-value of each model
        compared), ``coverage`` (grid, occupancy, stars per term),
        ``predicted_error_max`` and ``predicted_error_rms`` (1-sigma
        position error of the mapping in pixels on a grid over the source
        frame, from the covariance), ``residual_excess`` (residual scatter
        over what the centroid errors predict), ``n_pairs`` and
        ``n_clipped``; with ``degree='auto'``, each candidate's
        ``cv_chi2`` (held-out chi-square per star) and ``degrees_tested``.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.matching import fit_nonlinear
    >>> from astroalign_nd.transforms import DistortionFit
    >>> rng = np.random.default_rng(0)
    >>> src = rng.uniform(0, 1000, (200, 2))
    >>> fit = fit_nonlinear(src, src + 2.0, np.eye(3), transform_type="projective",
    ...                     pairs_given=True)
    >>> isinstance(fit, DistortionFit), type(fit.transform).__name__
    (True, 'ProjectiveTransform')
    """

    def __init__(self, transform, covariance, source_index, target_index, residuals, info):
        self.transform = transform
        self.covariance = covariance
        self.source_index = source_index
        self.target_index = target_index
        self.residuals = residuals
        self.rms = float(np.sqrt(np.mean(np.sum(residuals ** 2, axis=1))))
        self.info = info

    def __repr__(self):
        return (f"<DistortionFit {type(self.transform).__name__} {self.info.get('model')} "
                f"degree={self.info.get('degree')} n={len(self.source_index)} "
                f"rms={self.rms:.3f} px>")


@dataclass
class Problem:
    """The validated inputs of ``fit_nonlinear``, in normalised coordinates."""

    transform_type: str
    degree: object  # int, 'auto' or None (projective)
    src: np.ndarray
    dst: np.ndarray
    matrix: np.ndarray  # the linear start, 3x3
    centre: np.ndarray
    half: float  # half diagonal of the frame: the unit of ``uv``
    uv: np.ndarray  # source points, normalised
    frame: tuple  # (x0, x1, y0, y1), floats
    frame_uv: tuple
    # Scales the source centroid variance into the target frame: the linear
    # start's area scale; the choice of a polynomial replaces it by the residual
    # variance scale of its most flexible candidate, which the re-pairing of
    # degree='auto' and the residual excess then use.
    var_scale: float
    e_src: np.ndarray
    e_dst: np.ndarray
    pairs: object  # ``pair(predicted, idx, tolerance)``: the pairs among sources ``idx``
    tolerance: float
    min_tolerance: float
    lin_params: np.ndarray  # the linear start as affine parameters (``PolynomialLayer(1)``)
    top: int  # the highest degree offered while growing

    def variance(self, si, dj):
        return np.maximum(self.var_scale * self.e_src[si] ** 2 + self.e_dst[dj] ** 2, 1e-6)

    def growth_model(self, n_pairs, cap=None):
        """The most flexible model ``n_pairs`` pairs support while growing
        (of degree ``cap`` at most)."""
        entry = TRANSFORM_REGISTRY[self.transform_type]
        if not entry.degrees:  # a model of its own, once enough pairs support it
            own = entry.cls.layer()
            return own if n_pairs >= 4 * own.k else PolynomialLayer(1)
        d = self.top if cap is None else cap
        while d > 1 and n_pairs < 2 * WARN_STARS_PER_TERM * _n_terms(d):
            d -= 1
        return PolynomialLayer(d)

    def fit_on(self, cand_new, cand_old, params_old, si, dj):
        """Robust fit of ``cand_new`` to these pairs, started from the previous model."""
        uv, dst = self.uv[si], self.dst[dj]
        var = self.variance(si, dj)
        start = None
        if not cand_new.linear:
            start = (params_old if not cand_old.linear
                     else cand_new.from_affine(_fit_affine(uv, dst, var, params_old)))
        return _robust_fit(cand_new, uv, dst, var, start)


@dataclass
class _Paired:
    """The pairs kept by the refinement (after clipping)."""

    si: np.ndarray
    dj: np.ndarray
    w: np.ndarray  # weights: 1 / total variance
    fuv: np.ndarray  # their normalised source positions
    fdst: np.ndarray  # their target positions
    n_paired: int  # pairs before clipping
    tol: float  # the final pairing radius


@dataclass
class _Choice:
    """The chosen model in normalised coordinates, and the candidates compared."""

    cand: object
    params: np.ndarray
    cov: np.ndarray
    name: str
    deg: object  # the degree (1 for a linear choice, None for projective)
    candidates: list


@dataclass
class _Trust:
    """How far the chosen model can be trusted."""

    coverage: dict
    pred_max: float
    pred_rms: float
    excess: float
    tested: list


def prepare_problem(src_pts, dst_pts, linear, *, transform_type, degree, source_errors,
                    target_errors, source_frame, tolerance, min_tolerance, pairs_given,
                    pairing):
    """
    Validate ``fit_nonlinear``'s inputs and normalise them: a `Problem`;
    ``pairing(src, dst, pairs_given)`` makes its ``pairs``.
    """
    if not is_nonlinear(transform_type):
        raise ValueError(f"transform_type must be one of {list(NONLINEAR_TYPES)}; got "
                         f"{transform_type!r}.")
    transform_type = nonlinear_name(transform_type)
    if transform_type not in grown_types():
        raise ValueError(f"fit_nonlinear grows {list(grown_types())} models; it has no "
                         f"candidate model for transform_type={transform_type!r}.")
    degree = (check_degree(transform_type, degree) if TRANSFORM_REGISTRY[transform_type].degrees
              else None)
    src = np.asarray(src_pts, float).reshape(-1, 2)
    dst = np.asarray(dst_pts, float).reshape(-1, 2)
    if pairs_given and len(src) != len(dst):
        raise ValueError(f"pairs_given needs as many source as target points; got {len(src)} "
                         f"and {len(dst)}.")
    if linear is None:
        if not pairs_given:
            raise ValueError("linear=None needs pairs_given=True; pass the linear match's "
                             "matrix or model to grow from.")
        linear = _consensus_affine(src, dst, tolerance)
    m = np.asarray(as_matrix(linear), float)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ValueError("linear must be a finite 3x3 matrix or a linear transform model.")
    frame, centre, half, uv, frame_uv = normalise(src, source_frame)
    e_src = np.full(len(src), 0.1) if source_errors is None else np.asarray(source_errors, float)
    e_dst = np.full(len(dst), 0.1) if target_errors is None else np.asarray(target_errors, float)
    lin_params = np.array([m[0, 2] + m[0, 0] * centre[0] + m[0, 1] * centre[1],
                           m[0, 0] * half, m[0, 1] * half,
                           m[1, 2] + m[1, 0] * centre[0] + m[1, 1] * centre[1],
                           m[1, 0] * half, m[1, 1] * half])
    top = 5 if degree == "auto" else (degree if degree is not None else 1)
    return Problem(transform_type, degree, src, dst, m, centre, half, uv, frame, frame_uv,
                   abs(np.linalg.det(m[:2, :2])), e_src, e_dst, pairing(src, dst, pairs_given),
                   tolerance, min_tolerance, lin_params, top)


def normalise(src, source_frame):
    """(frame, centre, half diagonal, normalised source points, normalised frame)."""
    if source_frame is None:
        x0, y0 = src.min(axis=0) - 0.5
        x1, y1 = src.max(axis=0) + 0.5
        source_frame = (x0, x1, y0, y1)
    x0, x1, y0, y1 = (float(v) for v in source_frame)
    centre = np.array([(x0 + x1) / 2.0, (y0 + y1) / 2.0])
    half = 0.5 * float(np.hypot(x1 - x0, y1 - y0))
    uv = (src - centre) / half
    frame_uv = ((x0 - centre[0]) / half, (x1 - centre[0]) / half,
                (y0 - centre[1]) / half, (y1 - centre[1]) / half)
    return (x0, x1, y0, y1), centre, half, uv, frame_uv


def kept_pairs(prob, final, tol):
    """The `_Paired` of a refinement's outcome."""
    si, dj, keep, total = final
    n_paired = len(si)
    si, dj, total = si[keep], dj[keep], total[keep]
    return _Paired(si, dj, 1.0 / total, prob.uv[si], prob.dst[dj], n_paired, tol)


def choose_model(prob, cand, params, paired, significance, linear_type, repair):
    """
    Steps 3 and 4 of ``fit_nonlinear``: choose (``degree='auto'``) or check
    the requested model on the kept pairs, judge how far it can be trusted
    (warning when it cannot quite), and build it: a `DistortionFit`.

    ``cand``, ``params``: the refinement's last layer and parameters;
    ``paired``: its `kept_pairs`; ``repair(layer, params, degree)``: the
    pairs kept by a refinement with that model, of that degree at most.
    """
    p = paired
    if not TRANSFORM_REGISTRY[prob.transform_type].degrees:
        # A model without degrees (the homography), its coverage checked.  Too few
        # pairs while growing leave the affine model of the growth stage (6
        # parameters): the model starts from its equivalent.
        name = prob.transform_type
        own = TRANSFORM_REGISTRY[name].cls.layer()
        start = params if not cand.linear else own.from_affine(
            _fit_affine(p.fuv, p.fdst, 1.0 / p.w, params))
        chosen, chosen_params, chosen_cov = _check_and_fit(
            own, p.fuv, p.fdst, p.w, prob.frame_uv, 1, strict=True, start=start,
            what=f"a {name} model")
        choice = _Choice(chosen, chosen_params, chosen_cov, name, None, [])
    else:
        # The requested polynomial, checked, or ('auto') the chosen candidate.
        fits = _fit_candidates(prob, p, linear_type)
        # The residual variance scale, from the most flexible candidate (as in
        # the F-test): the BIC needs chi-squares in units of the actual scatter.
        n_eq = 2 * len(p.fuv)
        prob.var_scale = max(fits[-1][4] / max(n_eq - fits[-1][0].k, 1), 1e-300)
        best, candidates = _select(prob, p, fits, significance)
        c, d, label, _, _ = fits[best]
        if prob.degree == "auto":
            chosen, chosen_params, chosen_cov = c, *fits[best][3]
            if d < prob.top and isinstance(cand, PolynomialLayer) and cand.degree > d:
                # The pairs were paired and clipped by a model of higher degree:
                # pair and clip again with the chosen one, as an explicit degree
                # would have (a few pairs that only the discarded terms followed
                # would otherwise stay).
                p = repair(c, chosen_params, d)
                refit = weighted_fit(c, p.fuv, p.fdst, p.w)
                if refit is not None:
                    chosen_params, chosen_cov = refit
        else:
            chosen, chosen_params, chosen_cov = _check_and_fit(
                c, p.fuv, p.fdst, p.w, prob.frame_uv, d, strict=True, start=None,
                what=f"a polynomial of degree {d}")
        deg = d if TRANSFORM_REGISTRY[label].degrees else 1
        choice = _Choice(chosen, chosen_params, chosen_cov, label, deg, candidates)
    trust = _trust(prob, choice, p)
    return _build(prob, choice, p, trust, significance)


def _fit_candidates(prob, p, linear_type):
    """
    (candidate, degree, label, (params, cov), chi-square) of each model to compare
    that fits the kept pairs ``p``, fewest terms first.
    """
    if prob.degree != "auto":
        pool = [(PolynomialLayer(prob.degree), prob.degree, "polynomial")]
    else:
        pool = []
        parity = 1 if np.linalg.det(prob.matrix[:2, :2]) > 0 else -1
        linear_entry = transform_type_of(linear_type) if isinstance(linear_type, str) else None
        if linear_entry is not None and linear_entry.conformal:
            pool.append((SimilarityLayer(parity), 1, "similarity"))
        pool.append((PolynomialLayer(1), 1, "affine"))
        for d in DEGREES:
            cov_d = _coverage(p.fuv, prob.frame_uv, d, _n_terms(d))
            if _coverage_ok(cov_d, strict=True):
                pool.append((PolynomialLayer(d), d, "polynomial"))
    fits = []
    for c, d, label in pool:
        fit = weighted_fit(c, p.fuv, p.fdst, p.w)
        if fit is None:
            continue
        r = predict_with(c, fit[0], p.fuv) - p.fdst
        chi2 = float(np.sum(p.w * np.einsum("ij,ij->i", r, r)))
        fits.append((c, d, label, fit, chi2))
    if not fits:
        raise PoorCoverageError(
            f"the {len(p.fuv)} paired stars cannot constrain a polynomial model; use "
            "transform_type='affine' or pass more stars.")
    return fits


def _select(prob, p, fits, significance):
    """Index of the chosen fit, and the candidates' entries of the quality dict."""
    auto = prob.degree == "auto"
    n_eq = 2 * len(p.fuv)
    best, cv_cells, accepted, candidates = 0, [], [0], []
    for i, (c, d, label, fit, chi2) in enumerate(fits):
        # The p-value of the F-test that the extra terms over the best so far are needed.
        d1, d2 = c.k - fits[best][0].k, n_eq - c.k
        p_value = 1.0
        if i > 0 and d1 > 0 and d2 > 0:
            f = ((fits[best][4] - chi2) / d1) / max(chi2 / d2, 1e-300)
            if not f <= 0:
                p_value = float(betainc(d2 / 2.0, d1 / 2.0, d2 / (d2 + d1 * f)))
        bic = float(chi2 / prob.var_scale + c.k * np.log(n_eq))
        cv, cells = (_blocked_cv(c, p.fuv, p.fdst, p.w, prob.frame_uv) if auto
                     else (None, None))
        cv_cells.append(cells)
        candidates.append(dict(model=label, degree=d, n_parameters=c.k, chi2=chi2,
                               bic=bic, p_value=p_value, cv_chi2=cv))
        # Both tests must agree: the F-test guards small samples, BIC (whose
        # penalty grows with the number of stars) large ones, where centroid
        # errors that are not quite Gaussian make tiny p-values cheap.
        if i > 0 and p_value < significance and bic < candidates[best]["bic"]:
            best = i
            accepted.append(i)
    if auto and len(p.fuv) >= CV_ALL_DEGREES_PAIRS:
        # The last accepted candidate that also lowers the held-out error of the
        # one before.  With hundreds of stars every cell holds enough of them for
        # its held-out error to judge: terms the tests accept but that predict
        # held-out cells worse follow centroid systematics (a night's frames
        # drifting over the detector chose degrees 2 to 4; the held-out error
        # said affine).
        best = accepted[0]
        for i in accepted[1:]:
            if candidates[i]["cv_chi2"] < candidates[best]["cv_chi2"]:
                best = i
    if auto and fits[best][1] > CV_FROM_DEGREE:
        # With hundreds of stars the tests accept terms that only follow
        # slightly systematic centroid errors; those terms extrapolate badly
        # where stars are few.  Up to the cubic (a radial distortion, a
        # tilt) the tests decide: with tens of stars held-out cells are too
        # noisy to.  Beyond it, a degree the tests accept replaces the
        # current one only if it also predicts the held-out cells (blocked
        # cross-validation) meaningfully better.
        last, best = best, max(i for i in accepted if fits[i][1] <= CV_FROM_DEGREE)
        for i in range(best + 1, last + 1):
            if _cv_better(cv_cells[i], candidates[i]["cv_chi2"], cv_cells[best],
                          candidates[best]["cv_chi2"]):
                best = i
    for i, entry in enumerate(candidates):
        entry["chosen"] = i == best
    return best, candidates


def _trust(prob, choice, p):
    """
    Coverage, predicted error over the frame and residual excess: a `_Trust`,
    after the PoorFitWarnings they call for.
    """
    chosen, fuv, frame_uv = choice.cand, p.fuv, prob.frame_uv
    coverage = _coverage(fuv, frame_uv, choice.deg or 1, chosen.k / 2.0)
    r = predict_with(chosen, choice.params, fuv) - p.fdst
    r2 = np.einsum("ij,ij->i", r, r)
    dof = max(2 * len(fuv) - chosen.k, 1)
    chi_red = float(np.sum(p.w * r2)) / dof
    # The residual scatter over what the centroid errors alone predict (the
    # weights above are scaled to the scatter; these are not).
    excess = float(np.sqrt(np.sum(r2 / prob.variance(p.si, p.dj)) / dof))
    gx = np.linspace(frame_uv[0], frame_uv[1], ERROR_GRID)
    gy = np.linspace(frame_uv[2], frame_uv[3], ERROR_GRID)
    grid = np.column_stack([a.ravel() for a in np.meshgrid(gx, gy)])
    pv = _prediction_var(chosen, choice.params, choice.cov * max(chi_red, 1.0), grid)
    tested = sorted({c["degree"] for c in choice.candidates})
    trust = _Trust(coverage, float(np.sqrt(pv.max())), float(np.sqrt(pv.mean())), excess, tested)
    # The PoorFitWarnings: sparse coverage, excess residuals, uncertainty.
    name, n = choice.name, len(fuv)
    what = _label(name, choice.deg)
    if not TRANSFORM_REGISTRY[name].linear and not _coverage_ok(coverage, strict=False):
        warn(f"the {n} stars fitting the {what} cover "
             f"{coverage['occupancy']:.0%} of a {coverage['grid'][0]}x{coverage['grid'][1]} grid "
             f"over the frame with {coverage['stars_per_term']:.1f} stars per term (want "
             f"{WARN_OCCUPANCY:.0%} and {WARN_STARS_PER_TERM:g}); the model is poorly "
             "constrained where there are no stars. Use a lower degree (or degree='auto') or "
             "more stars (n_sources, nsigma).", PoorFitWarning)
    if (prob.degree == "auto" and not TRANSFORM_REGISTRY[name].degrees
            and (excess > WARN_EXCESS or trust.tested == [1])):
        why = (f"its residuals are {excess:.1f} times what the centroid errors predict"
               if excess > WARN_EXCESS else "no polynomial could be tested")
        warn(f"degree='auto' chose the {what}, but {why}: the {n} stars it "
             f"fits (covering {coverage['occupancy']:.0%} of a {coverage['grid'][0]}x"
             f"{coverage['grid'][1]} grid) are too few to find or rule out a distortion, and "
             "away from them the mapping can be off by more than the residuals show. Pass "
             "more stars (n_sources, a lower nsigma) or check the registered frame's edges.",
             PoorFitWarning)
    elif excess > WARN_EXCESS:
        warn(f"the {what}'s residuals over its {n} stars are {excess:.1f} "
             "times what their centroid errors predict: many pairs may be wrong (a crowded "
             "field) or the model does not follow the mapping. Check "
             "quality['model_selection'] and the registered frame; a lower degree, "
             "transform_type='affine', or a smaller tolerance may do better.", PoorFitWarning)
    if trust.pred_max > WARN_PREDICTED:
        warn(f"the {what} is uncertain: its covariance gives a 1-sigma position "
             f"error of up to {trust.pred_max:.2f} px over the frame (RMS {trust.pred_rms:.2f} "
             f"px, {n} stars). Use a lower degree (or degree='auto') or more stars.",
             PoorFitWarning)
    return trust


def _build(prob, choice, p, trust, significance):
    """The model object, through the same fitting function as the linear models,
    and the `DistortionFit`."""
    name, deg, degree = choice.name, choice.deg, prob.degree
    s_pts, d_pts = prob.src[p.si], prob.dst[p.dj]
    entry = TRANSFORM_REGISTRY[name]
    if entry.degrees:
        # About the frame's centre, on its domain.
        model, cov, resid = fit_transform(
            s_pts, d_pts, "polynomial", degree=deg, weights=p.w,
            crpix=(float(prob.centre[0]), float(prob.centre[1])),
            domain=tuple(float(v) for v in prob.frame))
    else:
        # (The candidates' labels are registry names: similarity, affine, projective.)
        kw = ({"parity": 1 if np.linalg.det(prob.matrix[:2, :2]) > 0 else -1}
              if TRANSFORM_REGISTRY[name].parity else {})
        model, cov, resid = fit_transform(s_pts, d_pts, name, weights=p.w, **kw)
    info = dict(model=name, degree=deg, requested_degree=(
                    degree if entry.linear or entry.degrees else None),
                selection=("F-test, BIC and blocked cross-validation" if degree == "auto"
                           else None), significance=significance,
                candidates=choice.candidates, coverage=trust.coverage,
                predicted_error_max=trust.pred_max, predicted_error_rms=trust.pred_rms,
                residual_excess=trust.excess,
                degrees_tested=trust.tested if degree == "auto" else None,
                n_pairs=int(len(p.si)), n_clipped=int(p.n_paired - len(p.si)),
                pairing_tolerance=float(p.tol))
    return DistortionFit(model, cov, p.si, p.dj, resid, info)


def _consensus_affine(src, dst, tolerance, n_trials=1000):
    """
    The affine transform of the triple of given pairs that the most pairs
    agree with (within ``tolerance``), refitted to them: a start that wrong
    pairs cannot pull away.  Deterministic (a fixed seed).
    """
    n = len(src)
    if n < 3:
        raise TooFewSourcesError(f"{n} pair(s) given; at least 3 are needed.")
    rng = np.random.default_rng(0)
    tri = np.array([rng.choice(n, 3, replace=False) for _ in range(n_trials)])
    ones = np.ones((n_trials, 3, 1))
    a = np.concatenate([src[tri], ones], axis=2)  # (T, 3, 3)
    ok = np.abs(np.linalg.det(a)) > 1e-6 * np.ptp(src) ** 2
    if not ok.any():
        raise TooFewSourcesError("the given pairs are collinear; no affine start exists.")
    coef = np.linalg.solve(a[ok], dst[tri[ok]])  # (T, 3, 2): x' = [x y 1] @ coef
    full = np.concatenate([src, np.ones((n, 1))], axis=1)
    pred = np.einsum("nk,tkj->tnj", full, coef)
    votes = (np.hypot(*(pred - dst).transpose(2, 0, 1)) <= tolerance).sum(axis=1)
    best = coef[np.argmax(votes)]
    inl = np.hypot(*(full @ best - dst).T) <= tolerance
    if inl.sum() >= 3:
        best, *_ = np.linalg.lstsq(full[inl], dst[inl], rcond=None)
    m = np.eye(3)
    m[:2, :] = best.T
    return m


def _label(name, degree):
    if TRANSFORM_REGISTRY[name].degrees:
        return f"{name} model of degree {degree}"
    return f"{name} model"


def _fit_affine(uv, dst, var, params):
    """Affine parameters (``PolynomialLayer(1)``) of these pairs (``params`` if degenerate)."""
    fit = weighted_fit(PolynomialLayer(1), uv, dst, 1.0 / var)
    return params if fit is None else fit[0]


def _check_and_fit(cand, uv, dst, w, frame_uv, degree, *, strict, start, what):
    """Refuse too little coverage for ``cand``, then fit it: (cand, params, cov)."""
    n_terms = cand.k / 2.0
    cov = _coverage(uv, frame_uv, degree, n_terms)
    if not _coverage_ok(cov, strict=True):
        raise PoorCoverageError(
            f"the {len(uv)} paired stars do not cover the frame well enough for {what}: they "
            f"fill {cov['occupancy']:.0%} of a {cov['grid'][0]}x{cov['grid'][1]} grid of cells "
            f"(need {MIN_OCCUPANCY:.0%}) with {cov['stars_per_term']:.1f} stars per term (need "
            f"{MIN_STARS_PER_TERM:g}). Pass a lower degree or degree='auto', "
            "transform_type='affine', or more stars (n_sources, nsigma).")
    fit = weighted_fit(cand, uv, dst, w, start)
    if fit is None:
        raise PoorCoverageError(f"the paired stars cannot constrain {what} (degenerate "
                                "geometry); use a lower degree or transform_type='affine'.")
    return cand, fit[0], fit[1]
