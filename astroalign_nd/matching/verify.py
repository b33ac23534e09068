# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Verification of a hypothesis: its false-alarm probability, growth, refit and misfit checks."""

import functools
import numpy as np
from scipy.special import betainc
from .._kernels import median as _median
from ..transforms.linear import AffineTransform, LinearTransform2D
from ..transforms import apply_matrix
from ..transforms.fitting import parameter_covariance, checked_weights
from ..transforms.registry import transform_class, transform_type_of
from .geometry import _frame_area_fraction, bounding_frame, overlap_counts
from .pairing import mutual_matches

__all__ = []


def _log10_false_alarm(m, src_pts, dst_pts, n_matched, tol, src_frame, dst_frame,
                       n_trials, tri_rms, tri_size, inv_radius, n_dof=4, matched=None,
                       dst_line=None):
    """
    log10 probability that ``n_matched`` stars agree by chance.

    Under the null hypothesis (unrelated fields), each source star that
    lands in the overlap falls within ``tol`` of one of the ``m_o`` target
    stars there with probability ``p = m_o * pi * tol^2 / area``.  The 3
    stars of the proposing triangle match by construction, so the binomial
    tail is taken over the others, and the defining triangle contributes
    the chance that random triangles agree as closely as it does.  The
    trials factor counts every hypothesis examined.

    With ``matched`` (the matched source and target indices), the chance
    of the pairs is also taken from the density of detections where the
    matched stars are, over the area they actually span
    (`_local_log_tail`), and the larger of the two figures is returned: a
    match along a row of detections is not credited with the frame's
    average density.  ``dst_line``: the matched target stars' `_densest_line`
    at `_strip_halfwidth` of ``tol``, when the caller has it already.
    """
    frac, area = _frame_area_fraction(m, src_frame, dst_frame)
    if area <= 0:
        return 0.0
    n_s, m_o = overlap_counts(m, src_pts, dst_pts, src_frame, dst_frame)
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
    if matched is not None and len(matched[0]) >= 4:
        log_tail = max(log_tail, _local_log_tail(m, src_pts, dst_pts, matched, tol, dst_line))
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
            si, dj = mutual_matches(apply_matrix(m, src_pts[inside]), dst_tree, tol)
            if len(si) < need:
                break
            s_in, d_in = src_pts[inside[si]], dst_pts[dj]
            m_new, _ = cls.fit_matrix(s_in, d_in, np.ones(len(si)), 1)
            r = np.hypot(*(apply_matrix(m_new, s_in) - d_in).T)
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
    (`_iterate_fit`), refuse a random set of pairs, and fit the model with
    its covariance (`_final_fit`).

    A random set of pairs, however many (a wrong local optimum), is one
    whose scatter fills the capture radius even under the most flexible
    model.  If only the requested model leaves a large scatter, the pairs
    are real and the model inadequate, which the caller reports
    (PoorFitWarning).  Returns ``(model,
    si, dj, resid, cov, tolerance used)``, or None.
    """
    cls = transform_class(transform_type)
    # Models with a parity are fitted with the hypothesis's; the others take it from the data.
    fit_parity = parity if transform_type_of(cls).parity else 1
    m = m0
    if seed is not None and cls.n_dof > 4:
        m = _grow_region(m, seed, src_pts, dst_pts, dst_tree, cls, tol)
    last = _iterate_fit(m, cls, fit_parity, src_pts, dst_pts, dst_tree, tol, min_tol,
                        src_err, dst_err, n_iter)
    if last is None:
        return None
    si, dj, total = last[:3]
    if 4.0 * np.sqrt(_median(total)) > tol and len(si) >= 4:
        aff, _ = AffineTransform.fit_matrix(src_pts[si], dst_pts[dj], 1.0 / total, 1)
        r = apply_matrix(aff, src_pts[si]) - dst_pts[dj]
        if 4.0 * np.sqrt(_median(np.einsum("ij,ij->i", r, r)) / 1.386) > tol:
            return None
    return _final_fit(last, cls, fit_parity, src_pts, dst_pts)


def _iterate_fit(m, cls, fit_parity, src_pts, dst_pts, dst_tree, tol, min_tol, src_err,
                 dst_err, n_iter):
    """
    Match, weigh, cut and fit until the matrix and the radius settle.

    Each pair's expected squared residual is ``f (s^2 e_src^2 + e_dst^2)``
    (``s`` the scale, ``e`` the detection's centroid errors; 0.01 px^2
    without errors), where the factor ``f >= 1`` makes the median of the
    normalised residuals that of a chi-square with 2 degrees of freedom
    (a Gaussian's): it absorbs what the centroid errors do not predict
    (undersampling, blends) while the few wrong pairs the cut must remove
    cannot inflate a median, and a factor (unlike an added "jitter") keeps
    the bright, well-measured stars' weight above the faint ones'.

    Pairs whose chi-square, counting the current model's own prediction
    variance, is above 16 are rejected, and the matching radius shrinks to
    5 sigma.  Returns the last fit's ``(si, dj, total variance, radius,
    (matrix, design))`` (the fit, for `_final_fit`; None if the type's
    `fit_matrix` is its own), or None when too few pairs matched.
    """
    need = max(cls.min_points, 3)
    cur_tol = tol
    last = prev = None
    own_design = cls._linear_fit.__func__ is LinearTransform2D._linear_fit.__func__
    base_fit = cls.fit_matrix.__func__ is LinearTransform2D.fit_matrix.__func__
    for _ in range(n_iter):
        si, dj = mutual_matches(apply_matrix(m, src_pts), dst_tree, cur_tol)
        if len(si) < need:
            break
        if src_err is not None and dst_err is not None:
            scale2 = abs(m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0])
            var = scale2 * src_err[si] ** 2 + dst_err[dj] ** 2
        else:
            var = np.full(len(si), 0.01)
        resid = apply_matrix(m, src_pts[si]) - dst_pts[dj]
        r2 = np.einsum("ij,ij->i", resid, resid)
        total = var * max(1.0, float(_median(r2 / var)) / (2.0 * np.log(2.0)))
        # The current model is itself uncertain (early on it rests on the
        # faint majority): its prediction variance (per axis, at the matched
        # stars) enters the cut, so that the brightest stars are not rejected
        # for the model's error.
        pv = 0.0
        if prev:
            # (The last fit's own design, when it is the type's `_design`.)
            d_fit = prev[2] if own_design else cls._design(prev[0], prev[1], fit_parity)
            d_all = cls._design(src_pts[si], np.ones(len(si)), fit_parity)
            cov = np.linalg.pinv(d_fit.T @ (d_fit * np.repeat(prev[1], 2)[:, None]))
            rows = d_all.reshape(len(si), 2, -1)
            pv = np.einsum("nij,jk,nik->n", rows, cov, rows) / 2.0
        # chi2 with 2 dof above 16 happens with probability 3e-4.
        keep = r2 / (total + pv) <= 16.0 if len(si) > cls.n_dof else np.ones(len(si), bool)
        if keep.sum() >= need:
            si, dj, total = si[keep], dj[keep], total[keep]
        # Matrix-level fit: building astropy models here would dominate.
        s_in, w = src_pts[si], 1.0 / total
        m_new, design = cls.fit_matrix(s_in, dst_pts[dj], w, fit_parity)
        prev = (s_in, w, design)
        last = (si, dj, total, cur_tol, (m_new, design) if base_fit else None)
        new_tol = float(min(max(5.0 * np.sqrt(_median(total)), min_tol), tol))  # (np.clip)
        converged = np.max(np.abs(m_new - m)) < 1e-10 and new_tol == cur_tol
        m, cur_tol = m_new, new_tol
        if converged:
            break
    return last


class _Fitted:
    """
    A fitted linear model as plain numbers: its type, parameter values and
    matrix, as the astropy model of the same fit would hold them.

    The refinement fits and judges dozens of hypotheses per search, and an
    astropy model costs milliseconds to build (more than the fit): they
    are judged on these, and `model` builds the one that is returned.

    Parameters
    ----------
    cls : type
        A `~astroalign_nd.transforms.LinearTransform2D` subclass.
    matrix : (3, 3) ndarray
        The fitted matrix; ValueError when the type cannot represent it
        (as its ``_from_matrix``).
    """

    __slots__ = ("cls", "values", "matrix")
    _free = {}  # each class's free parameter names (class attributes: found once)

    def __init__(self, cls, matrix):
        self.cls = cls
        self.values = cls._model_values(matrix)
        self.matrix = cls._matrix_of(self.values)  # the model's own (its low bits)

    @property
    def n_dof(self):
        return self.cls.n_dof

    @property
    def free(self):
        """The names of the free (fitted) parameters, in the model's order."""
        free = self._free.get(self.cls)
        if free is None:
            free = self._free[self.cls] = tuple(
                n for n in self.cls.param_names if not getattr(self.cls, n).fixed)
        return list(free)

    def model(self):
        """The astropy model of these values."""
        return self.cls(**self.values)


def _model_type(model):
    """The model class of an astropy model or of a `_Fitted`."""
    return model.cls if isinstance(model, _Fitted) else type(model)


def _final_fit(last, cls, fit_parity, src_pts, dst_pts):
    """The model (a `_Fitted`), with its covariance and residuals, on the last
    fit's pairs; or None."""
    si, dj, total, used_tol = last[:4]
    parity = fit_parity if transform_type_of(cls).parity else None
    src, dst = src_pts[si], dst_pts[dj]
    try:
        # The detections' errors are checked against the residuals' scatter:
        # on faint frames they can be wrong, and a few stars claiming tiny
        # errors would pin the fit (with the refinement's last fit of these
        # pairs and weights, when the caller has it: the same fit).
        w = checked_weights(src, dst, 1.0 / total, cls, parity=parity,
                            fit=last[4] if len(last) > 4 else None)
        if not np.all(np.isfinite(w)):
            return None
        # fit_transform's fit, checks and covariance, on matrices (the pairs
        # were checked by checked_weights' fit, and w is zero where its weights are).
        matrix, design, resid = cls._fit_parts(src, dst, weights=w, parity=parity, checked=True)
        fit = _Fitted(cls, matrix)
    except ValueError:  # collinear or coincident stars: no transform to trust
        return None
    cov = parameter_covariance(cls, fit.matrix, fit.free, design, resid, w)
    return fit, si, dj, resid, cov, used_tol


#: The largest error (px) over the overlap that a match may admit by its own
#: witnesses (`_model_misfit`) and still be returned, whatever the matching
#: radius: a radius widened for trailed or bloated stars widens the search,
#: not what is trusted.
MAX_ERROR_BOUND = 3.0

#: Above this error bound (px), a returned match comes with a PoorFitWarning.
WARN_ERROR_BOUND = 1.0


def _affine_comparison(model, src, dst, src_err, dst_err):
    """
    What `_model_misfit` compares the model with, on the matched stars
    ``src``, ``dst``: ``(var, affine, significant)``.

    ``var`` are the pairs' expected squared residuals (0.01 px^2 without
    errors); ``affine`` the inverse of the matrix of an affine fit of the
    stars (None when the model is already affine or too few stars leave
    residuals to test it); ``significant``, whether that fit is a
    significant improvement (F-test, p < 1e-6).  It does not depend on the
    frame: the search judges a candidate over the overlap and returns it
    over the target frame, from the one comparison.
    """
    n = len(src)
    k_model, k_aff = _model_type(model).n_dof, 6
    if src_err is not None and dst_err is not None:
        s2 = abs(np.linalg.det(model.matrix[:2, :2]))
        var = s2 * src_err**2 + dst_err**2
    else:
        var = np.full(n, 0.01)
    if not (k_model < k_aff and 2 * n > k_aff + 2):
        return var, None, False
    aff, _ = AffineTransform.fit_matrix(src, dst, 1.0 / var, 1)
    r_aff = apply_matrix(aff, src) - dst
    r2_aff = np.einsum("ij,ij->i", r_aff, r_aff)
    # Weights from the better (affine) model, with its own jitter.
    var_j = var + _jitter(r2_aff / 2.0, var, n - k_aff / 2.0)
    r_mod = apply_matrix(model.matrix, src) - dst
    chi_mod = np.sum(np.einsum("ij,ij->i", r_mod, r_mod) / var_j)
    chi_aff = np.sum(r2_aff / var_j)
    dof_aff = 2 * n - k_aff
    f_stat = ((chi_mod - chi_aff) / (k_aff - k_model)) / max(chi_aff / dof_aff, 1e-300)
    # Survival function of F(d1, d2): I_x(d2/2, d1/2) with x = d2 / (d2 + d1 F).
    d1, d2 = k_aff - k_model, dof_aff
    significant = bool(f_stat > 0 and betainc(d2 / 2.0, d1 / 2.0, d2 / (d2 + d1 * f_stat)) < 1e-6)
    return var, np.linalg.inv(aff), significant


def _model_misfit(model, src, dst, src_err, dst_err, frame, tol=None, predicted=0.0,
                  affine=None):
    """
    Is the fitted model consistent with its own matched stars, over the frame?

    Three witnesses, each an estimate of how far the answer can be from the
    truth at the frame's corners (target pixels):

    * the richer model: an affine fit of the same stars.  If it is
      significantly better (F-test, p < 1e-6), the stars are real and the
      model inadequate (shear, distortion): its departure is the returned
      ``misfit``, which the caller warns about.  If it is not significant,
      the stars cannot tell the model from an affine one that far away:
      the departure is an uncertainty of the answer;
    * leave-one-out: the jackknife spread of the corners' positions when
      each star in turn is left out (3 sigma), which wrong pairs or biased
      centroids inflate whatever the errors claim;
    * the residual scatter, through the covariance of the parameters
      (``predicted``, 1 sigma; 3 sigma is used).

    With ``tol`` (the matching radius), a match whose witnesses say that it
    can be off by more than ``tol`` somewhere in ``frame`` is inconsistent.
    ``affine``: the stars' `_affine_comparison`, when the caller has it
    already (it does not depend on ``frame``).

    Returns
    -------
    misfit : float
        The significant departure from the affine fit (0 if not significant).
    bound : float
        The largest of the witnesses' errors (target px).
    reason : str or None
        What was inconsistent, when ``bound > tol``; else None.
    """
    n = len(src)
    k_model, k_aff = _model_type(model).n_dof, 6
    x0, x1, y0, y1 = frame if frame is not None else bounding_frame(dst)
    corners = np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]])
    var, aff_inv, significant = (affine if affine is not None else
                                 _affine_comparison(model, src, dst, src_err, dst_err))
    misfit = departure = 0.0
    if aff_inv is not None:
        pre = apply_matrix(aff_inv, corners)
        departure = float(np.max(np.hypot(*(apply_matrix(model.matrix, pre) - corners).T)))
        if significant:
            misfit, departure = departure, 0.0  # real stars, inadequate model: a warning
    if tol is None:
        return misfit, 0.0, None
    if k_model < k_aff and 2 * n - k_model < 8:
        # Three to five stars fix a rotation-like model, but leave too few
        # residuals to judge their own scatter: only the affine model (which
        # extrapolates its shear from them) is held to the witnesses then.
        return misfit, 0.0, None
    jack = _jackknife_error(model, src, dst, 1.0 / var, corners)
    witnesses = [
        (departure, f"an affine fit of the same {n} stars lies {departure:.2f} px from it "
                    "(not a significant improvement: the stars cannot tell them apart)"),
        (3.0 * jack, f"leaving one star out moves the frame's corners by {jack:.2f} px "
                     f"(1 sigma, {n} stars)"),
        (3.0 * predicted, f"the residual scatter gives a 1-sigma error of {predicted:.2f} px"),
    ]
    bound = max(w for w, _ in witnesses)
    if bound <= tol:
        return misfit, bound, None
    said = "; ".join(text for w, text in witnesses if w > tol)
    return misfit, bound, (f"its {n} matched stars are inconsistent with it: {said}, so that it "
                           f"can be off by {bound:.1f} px over the frame (more than the "
                           f"tolerance, {tol:.2f} px)")


def _jackknife_error(model, src, dst, w, corners, n_max=60):
    """
    Jackknife (leave-one-out) 1-sigma error of the model at ``corners``.

    Left out for more than ``n_max`` stars, where one star moves nothing
    and the covariance is reliable (0).
    """
    n = len(src)
    cls = _model_type(model)
    if n > n_max or n <= max(cls.min_points, 3):
        return 0.0
    parity = 1 if np.linalg.det(model.matrix[:2, :2]) > 0 else -1
    pre = apply_matrix(np.linalg.inv(model.matrix), corners)  # corners in source pixels
    mats = cls._leave_one_out(src, dst, w, parity)
    # `apply_matrix` of each matrix, stacked (the same products, slice by slice).
    preds = pre @ mats[:, :2, :2].transpose(0, 2, 1) + mats[:, None, :2, 2]
    dev = preds - preds.mean(axis=0)
    var = (n - 1) / n * np.einsum("ikj,ikj->k", dev, dev)
    return float(np.sqrt(np.max(var)))


def _predicted_error(model, cov, frame):
    """
    Largest 1-sigma position error (target px) over the frame's corners,
    propagated from the parameter covariance.
    """
    cov = np.asarray(cov, float)
    if isinstance(model, _Fitted):
        cls, free, values = model.cls, model.free, model.values
    else:
        fixed = model.fixed  # (a new dict at each access)
        cls, free = type(model), [n for n in model.param_names if not fixed[n]]
        values = {n: float(getattr(model, n).value) for n in model.param_names}
    if cov.shape != (len(free), len(free)) or not np.all(np.isfinite(cov)):
        return 0.0
    x0, x1, y0, y1 = frame
    # Errors are largest at the frame's corners, in target pixels; map them
    # back to source pixels, where the model's parameters act.
    inv = np.linalg.inv(model.matrix)
    corners = apply_matrix(inv, np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]]))

    # Finite differences through the model's static ``evaluate`` with perturbed
    # parameter values (copying an astropy model costs ~2 ms each): every set at once,
    # as astropy evaluates a model set (a column of values per parameter; row 0 the
    # values, row 1 + k those with free parameter k stepped: the same numbers).
    steps = np.array([1e-6 * max(1.0, abs(values[name])) for name in free])
    sets = []
    for name in cls.param_names:
        col = np.full((len(free) + 1, 1), float(values[name]))
        if name in free:
            k = free.index(name)
            col[1 + k] = values[name] + steps[k]
        sets.append(col)
    out = np.array(cls.evaluate(corners[:, 0], corners[:, 1], *sets), dtype=float)
    # (x', y') of each corner, in rows: (2 * corners, free parameters).
    jac = ((out[:, 1:] - out[:, :1]) / steps[:, None]).transpose(2, 0, 1).reshape(-1, len(free))
    var = np.einsum("ik,kl,il->i", jac, cov, jac).reshape(len(corners), 2)
    return float(np.sqrt(np.max(var.sum(axis=1))))


#: A match needs at least this many matched stars off its densest line
#: (`_degenerate`): three pairs off a line fix what the line leaves free.
MIN_OFF_LINE = 3
#: Fewest matched stars on one line for the line to count as a row of detections (a few
#: stars of a sparse field can lie near a line by chance and still pin the transform).
MIN_ON_LINE = 8


def _strip_halfwidth(tol):
    """Half-width (px) of the strip in which stars count as lying along one line."""
    return max(2.0 * tol, 2.0)


@functools.lru_cache(maxsize=64)
def _line_pairs(n, n_lines):
    """
    The pairs of ``n`` points whose lines `_densest_line` tries: every pair
    for a few points, a fixed sample of ``n_lines`` otherwise (read-only,
    kept: a search asks for the same few sizes again and again).
    """
    i, j = np.triu_indices(n, 1)
    if len(i) > n_lines:
        pick = np.random.default_rng(0).choice(len(i), n_lines, replace=False)
        i, j = i[pick], j[pick]
    i.flags.writeable = j.flags.writeable = False
    return i, j


def _densest_line(pts, half_width, n_lines=600):
    """
    The line through the most of ``pts`` (within ``half_width``).

    Candidate lines pass through two of the points (every pair for a few
    points, a fixed sample of pairs otherwise: deterministic) and through
    the centroid along the principal axis.  Returns ``(mask, centre,
    direction)``: the points on the line, and the line.
    """
    n = len(pts)
    i, j = _line_pairs(n, n_lines)
    centre = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centre, full_matrices=False)
    # The lines' points and unit normals, coordinate by coordinate (fewer, smaller
    # NumPy calls than (lines, 2) arrays; the same numbers).
    x, y = pts[:, 0], pts[:, 1]
    sx, sy = np.append(x[i], centre[0]), np.append(y[i], centre[1])
    dx, dy = np.append(x[j] - x[i], vt[0, 0]), np.append(y[j] - y[i], vt[0, 1])
    length = np.hypot(dx, dy)
    ok = length > 0
    if not ok.all():
        sx, sy, dx, dy, length = sx[ok], sy[ok], dx[ok], dy[ok], length[ok]
    nx, ny = -(dy / length), dx / length
    # (points, lines) perpendicular distances, written out: einsum does not vectorise this
    # two-term sum and took most of a 300-star match's verification (the same values);
    # in place, in blocks of lines of about 16,000 distances (blocks of 32,000 took 1.3-2
    # times as long for 50-100 points, on busy cores; the counts do not depend on it).
    # Points along the first axis: the counts add whole rows (a fast reduction).
    px, py = pts[:, :1], pts[:, 1:]
    counts = np.empty(len(sx), int)
    block = max(128, 16384 // n)
    for k in range(0, len(sx), block):
        part = slice(k, k + block)
        dist = px - sx[part]
        dist *= nx[part]
        other = py - sy[part]
        other *= ny[part]
        dist += other
        counts[part] = np.count_nonzero(np.abs(dist, out=dist) <= half_width, axis=0)
    best = int(np.argmax(counts))
    mask = np.abs(nx[best] * (x - sx[best]) + ny[best] * (y - sy[best])) <= half_width
    # The line through its own stars (principal axis), then its stars again.
    on = pts[mask]
    c = on.mean(axis=0)
    _, _, vt = np.linalg.svd(on - c, full_matrices=False)
    u = vt[0]
    mask = np.abs((pts - c) @ np.array([-u[1], u[0]])) <= half_width
    return mask, c, u


def _on_line(points, matched, tol):
    """
    Which of ``points`` lie on the line of the ``matched`` ones, when all
    but fewer than `MIN_OFF_LINE` of these lie on one (`_densest_line`);
    none otherwise.
    """
    half = _strip_halfwidth(tol)
    n = len(matched)
    if n < 4:
        return np.zeros(len(points), bool)
    on, c, u = _densest_line(matched, half)
    k = int(on.sum())
    if k < max(MIN_ON_LINE, n // 2) or n - k >= MIN_OFF_LINE:
        return np.zeros(len(points), bool)
    return np.abs((points - c) @ np.array([-u[1], u[0]])) <= half


def _in_box(pts, box):
    centre, u, (a0, a1), (b0, b1) = box
    v = np.array([-u[1], u[0]])
    d = pts - centre
    a, b = d @ u, d @ v
    return (a >= a0) & (a <= a1) & (b >= b0) & (b <= b1)


def _local_log_tail(m, src_pts, dst_pts, matched, tol, line=None):
    """
    log10 chance of the matched pairs, from the density of detections where
    they are, not over the whole frame.

    The matched target stars are split into those along their densest line
    (`_densest_line`, when it holds 4 or more) and the others.  Each group
    is given the oriented box its stars span (principal axes, ``tol``
    wider); a star of the source mapped into a box pairs by chance with
    probability ``(target detections in the box) * pi * tol^2 / (box
    area)``.  A row of detections along a frame's edge thus counts with
    the density along that row, where chance pairs are likely.  The 3 stars
    of the proposing triangle match by construction and are not counted.
    ``line``: that densest line, when the caller has it already.
    """
    si, dj = matched
    d = dst_pts[dj]
    mapped = apply_matrix(m, src_pts)
    groups = [np.ones(len(dj), bool)]
    if len(dj) >= 4:
        on, c, u = line if line is not None else _densest_line(d, _strip_halfwidth(tol))
        if on.sum() >= MIN_ON_LINE:
            groups = [~on, on] if (~on).any() else [on]
    log_tail, spare = 0.0, 3  # the triangle's stars, taken off the largest group first
    for g in sorted(groups, key=lambda g: -g.sum()):
        pts = d[g]
        k = int(g.sum())
        if k == 0:
            continue
        if k >= 2:
            c = pts.mean(axis=0)
            off = pts - c
            _, _, vt = np.linalg.svd(off, full_matrices=False)
            u = vt[0]
        else:
            c, u = pts[0], np.array([1.0, 0.0])
            off = pts - c
        # The oriented box (centre, u, along range, across range), tol wider.
        v = np.array([-u[1], u[0]])
        a, b = off @ u, off @ v
        box = c, u, (a.min() - tol, a.max() + tol), (b.min() - tol, b.max() + tol)
        area = (box[2][1] - box[2][0]) * (box[3][1] - box[3][0])
        m_box = max(int(_in_box(dst_pts, box).sum()), 1)
        n_box = int(_in_box(mapped, box).sum())
        p = min(1.0, m_box * np.pi * tol ** 2 / area)
        k_extra = k - min(spare, k)
        spare -= k - k_extra
        if k_extra > 0:  # log10 P(X >= k_extra), X ~ Binomial(n, p)
            n = max(n_box - (k - k_extra), k_extra)
            tail = betainc(k_extra, n - k_extra + 1, p) if p < 1 else 1.0
            log_tail += float(np.log10(tail)) if tail > 0 else -300.0
    return log_tail


def _degenerate(src, dst, src_frame, dst_frame, tol, dst_line=None):
    """
    Why the matched stars cannot pin a 2-D transform, or None.

    They cannot when, in either frame, all but fewer than `MIN_OFF_LINE`
    of them lie along one line (within `_strip_halfwidth`: collinear, or
    a thin strip), or all lie within a few pixels of one edge (a band of
    detections along a raw frame's first rows).  Along a line, a transform
    is fixed only along that line, and a row of detections makes chance
    pairs along it likely.  ``dst_line``: the target stars' `_densest_line`
    (at `_strip_halfwidth` of ``tol``), when the caller has it already.
    """
    n = len(src)
    if n < 4:
        return None
    half = _strip_halfwidth(tol)
    for name, pts, frame, line in (("source", src, src_frame, None),
                                   ("target", dst, dst_frame, dst_line)):
        x0, x1, y0, y1 = frame
        near = max(3.0 * tol, 0.02 * min(x1 - x0, y1 - y0))
        edges = {"left": pts[:, 0] - x0, "right": x1 - pts[:, 0],
                 "bottom": pts[:, 1] - y0, "top": y1 - pts[:, 1]}
        on, c, u = line if line is not None else _densest_line(pts, half)
        k = int(on.sum())
        if k >= max(MIN_ON_LINE, n // 2) and n - k < MIN_OFF_LINE:
            across = np.abs((pts[on] - c) @ np.array([-u[1], u[0]]))
            along = (pts[on] - c) @ u
            where = ""
            for edge, dist in edges.items():
                if np.all(dist[on] <= half + 1.0):
                    where = f" by the {edge} edge"
            who = f"{k} of the {n} matched stars lie" if n > k else f"the {n} matched stars lie"
            return (f"{who} along a line{where} of the {name} frame (spread "
                    f"{2.0 * across.max():.1f} px across, {np.ptp(along):.0f} px along)")
        for edge, dist in edges.items():
            if np.all(dist <= near):
                return (f"all {n} matched stars lie within {near:.0f} px of the {edge} edge "
                        f"of the {name} frame (at most {dist.max():.1f} px from it)")
    return None
