# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
A linear match grown into a non-linear one over many more stars.

Wide-field optics (camera lenses, small refractors, all-sky cameras) leave
several pixels of residual at the corners under any linear model.
`extend_match` takes the trusted linear match of `find_match` (found on
the brightest stars) and extends it, through `~astroalign_nd.matching.fit_nonlinear`, to a
projective (homography) or polynomial-distortion model over all detected
stars:

1. **Grow.** Starting from the linear model, the fit is extended outwards
   from the matched stars in discs of growing radius: predict every star of
   the disc with the current model, pair it with the nearest target star
   within ``tolerance`` (mutual nearest neighbours), refit, clip.  Near the
   matched stars the linear model is right; each larger disc is predicted
   by a model fitted on the previous one, so the pairing follows the
   distortion instead of locking onto chance pairs at the corners.  The
   degree used while growing is capped by the number of paired stars.
2. **Refine.** Over the whole frame, the pairing radius shrinks to five
   times the residual scatter and pairs more than 4 sigma off the model
   are clipped, as in the linear refinement.
3. **Choose** and 4. **trust**: the model selection of
   `~astroalign_nd.transforms.selection` (`choose_model`).

The pairing is this module's; what is fitted (the candidate models'
parameter layers, the robust fit) and the choice are the transforms'.
"""

import numpy as np
from scipy.spatial import cKDTree

from ..exceptions import TooFewSourcesError
from ..transforms.layers import PolynomialLayer
from ..transforms.registry import nonlinear_name, transform_type_of
from ..transforms.selection import (choose_model, kept_pairs, predict_with, prepare_problem)
from .pairing import mutual_matches
from .result import MatchResult

__all__ = ['fit_nonlinear', 'extend_match', 'nonlinear_name', 'SEARCH_TOLERANCE_FACTOR',
           'FIT_SOURCES']


#: The linear search's matching radius is this many times the usual one when a
#: distortion model follows: a tilted or distorted wide field is several
#: pixels off any linear model away from the centre.
SEARCH_TOLERANCE_FACTOR = 2.5


class _Pairs:
    """How source and target stars are paired: by position, or as given."""

    def __init__(self, src, dst, given):
        self.src, self.dst, self.given = src, dst, given
        self.tree = None if given else cKDTree(dst)

    def pair(self, pred, idx, tol):
        """Pairs among source stars ``idx`` whose prediction lies within ``tol``."""
        if self.given:
            r = np.hypot(*(pred - self.dst[idx]).T)
            ok = r <= tol
            return idx[ok], idx[ok]
        si, dj = mutual_matches(pred, self.tree, tol)
        return idx[si], dj


def fit_nonlinear(src_pts, dst_pts, linear, *, transform_type="polynomial", degree=3,
                  seed_points=None, source_errors=None, target_errors=None, source_frame=None,
                  tolerance=3.0, min_tolerance=0.3, significance=1e-4, pairs_given=False,
                  linear_type=None):
    """
    Grow a linear match into a projective or polynomial model over all stars.

    Parameters
    ----------
    src_pts, dst_pts : (N, 2), (M, 2) array-like
        Source and target star positions (pixels).  With ``pairs_given``,
        two arrays of the same length whose rows are candidate pairs (some
        may be wrong).
    linear : (3, 3) array-like, linear model or None
        The linear source-to-target transform to start from (the matched
        similarity or affine transform).  None, with ``pairs_given``: the
        affine transform that the most pairs agree with, to ``tolerance``
        (a deterministic consensus over 1000 triples of pairs).
    transform_type : {'polynomial', 'projective'}, optional
    degree : int or 'auto', optional
        Polynomial degree, 2 to 5, or 'auto' to choose it (linear
        included): a candidate with more terms is chosen only if an F-test
        (p < ``significance``) and the BIC both prefer it, and, for degrees
        4 and 5, its held-out error in a spatially blocked cross-validation
        is meaningfully lower.
    seed_points : (K, 2) array-like, optional
        Source positions of the stars matched by the linear stage: the
        growth starts around them (by default around the stars the linear
        model pairs within ``tolerance``).
    source_errors, target_errors : (N,), (M,) array-like, optional
        Expected centroid errors (pixels); 0.1 px when not given.
    source_frame : (x0, x1, y0, y1), optional
        The source image's extent; the source stars' bounding box by default.
        Coverage and the predicted error are evaluated over it.
    tolerance : float, optional
        Pairing radius (pixels) while growing.
    min_tolerance : float, optional
        Smallest pairing radius of the final refinement.
    significance : float, optional
        F-test p-value below which extra terms are accepted (``'auto'``).
    pairs_given : bool, optional
        Treat rows of ``src_pts`` and ``dst_pts`` as given pairs instead of
        pairing stars by position.
    linear_type : str, optional
        The linear match's type: with ``degree='auto'``, a conformal one
        ('similarity', 'euclidean', 'translation') adds a similarity
        candidate before the affine model (default: affine only).

    Returns
    -------
    `~astroalign_nd.transforms.DistortionFit`

    Raises
    ------
    PoorCoverageError
        If the paired stars do not cover the frame well enough for the
        requested degree (or any projective model).
    TooFewSourcesError
        If too few stars pair up to fit even an affine model.

    Examples
    --------
    Stars of a 4096-pixel frame through a barrel distortion of 10 px at
    the corners, and 30% of the pairs wrong:

    >>> import numpy as np
    >>> from astroalign_nd.matching import fit_nonlinear
    >>> rng = np.random.default_rng(0)
    >>> src = rng.uniform(0, 4095, (600, 2))
    >>> u = (src - 2047.5) / 2896.0
    >>> dst = src + (u * -0.0035 * (u ** 2).sum(1)[:, None]) * 2896.0
    >>> dst[:180] = rng.uniform(0, 4095, (180, 2))       # wrong pairs
    >>> fit = fit_nonlinear(src, dst, np.eye(3), degree="auto", pairs_given=True,
    ...                     tolerance=15.0, source_frame=(-0.5, 4095.5, -0.5, 4095.5))
    >>> fit.info["model"], fit.info["degree"], fit.info["n_pairs"]
    ('polynomial', 3, 420)
    >>> bool(fit.rms < 0.01)
    True
    """
    prob = prepare_problem(src_pts, dst_pts, linear, transform_type=transform_type,
                           degree=degree, source_errors=source_errors,
                           target_errors=target_errors, source_frame=source_frame,
                           tolerance=tolerance, min_tolerance=min_tolerance,
                           pairs_given=pairs_given, pairing=_Pairs)
    # 1. Grow outwards from the linear match's stars.
    cand, params = _grow(prob, seed_points)
    # 2. Refine over the whole frame with a shrinking pairing radius.
    cand, params, final, tol = _refine(prob, cand, params)
    paired = kept_pairs(prob, final, tol)

    def repair(layer, start, cap):  # (degree='auto': again with the model chosen)
        _, _, final, tol = _refine(prob, layer, start, cap=cap)
        return kept_pairs(prob, final, tol)

    # 3. Choose (degree='auto') or check the requested model; 4. trust it.
    return choose_model(prob, cand, params, paired, significance, linear_type, repair)


def _grow(prob, seed_points):
    """Grow the fit from the linear match's stars in discs of growing radius:
    (candidate, parameters)."""
    cand, params = PolynomialLayer(1), prob.lin_params
    uv, all_idx = prob.uv, np.arange(len(prob.src))
    if seed_points is None or len(seed_points) == 0:
        seed_si, _ = prob.pairs.pair(predict_with(cand, params, uv), all_idx, prob.tolerance)
        seed_uv = uv[seed_si]
    else:
        seed_uv = (np.asarray(seed_points, float).reshape(-1, 2) - prob.centre) / prob.half
    if len(seed_uv) < 3:
        raise TooFewSourcesError(
            f"only {len(seed_uv)} star(s) pair up under the linear transform within "
            f"{prob.tolerance:g} px; a distortion model needs many more. Pass more stars or a "
            "larger tolerance.")
    seed_centre = seed_uv.mean(axis=0)
    dist = np.hypot(*(uv - seed_centre).T)
    radius = max(float(np.median(np.hypot(*(seed_uv - seed_centre).T))), 1e-3)
    r_max = float(dist.max())
    while True:
        idx = all_idx[dist <= radius]
        si, dj = prob.pairs.pair(predict_with(cand, params, uv[idx]), idx, prob.tolerance)
        new = prob.growth_model(len(si))
        fit = prob.fit_on(new, cand, params, si, dj) if len(si) * 2 > new.k else None
        if fit is not None:
            cand, params = new, fit[0]
        if radius >= r_max:
            break
        radius = min(radius * 1.4, r_max)
    return cand, params


def _refine(prob, cand, params, cap=None):
    """Pair over the whole frame, refit and clip with a shrinking pairing radius:
    (candidate, parameters, (si, dj, keep, total variance), pairing radius)."""
    all_idx = np.arange(len(prob.src))
    tol = float(prob.tolerance)
    final = None
    for _ in range(10):
        si, dj = prob.pairs.pair(predict_with(cand, params, prob.uv), all_idx, tol)
        new = prob.growth_model(len(si), cap)
        fit = prob.fit_on(new, cand, params, si, dj) if len(si) * 2 > new.k else None
        if fit is None:
            break
        cand, params = new, fit[0]
        _, _, keep, total = fit
        final = (si, dj, keep, total)
        new_tol = float(np.clip(5.0 * np.sqrt(np.median(total[keep])), prob.min_tolerance, tol))
        if new_tol == tol:
            break
        tol = new_tol
    if final is None:
        raise TooFewSourcesError(
            f"too few stars pair up under the linear transform to fit a {prob.transform_type} "
            f"model; pass more stars (n_sources, nsigma) or use transform_type='affine'.")
    return cand, params, final, tol


#: Stars of each image used to grow a distortion model: ``Reference.stars``
#: detects twice this many (brightest first).
FIT_SOURCES = 1000

#: Stellar widths of the two frames (at the same scale) that differ by less than
#: this factor are taken as consistent measurements.
FWHM_AGREEMENT = 1.25


def _fwhm_mismatch(fwhm_src, fwhm_dst, scale):
    """|log| of the target FWHM over the source FWHM mapped to the target scale."""
    return abs(float(np.log(fwhm_dst / (scale * fwhm_src))))


def extend_match(result, source, target, *, transform_type, degree=3, tolerance=3.0,
                 significance=1e-4, n_fit=FIT_SOURCES, n_control=None):
    """
    Grow the linear `~astroalign_nd.matching.MatchResult` of
    `~astroalign_nd.find_match` into a non-linear one over many more stars.

    Parameters
    ----------
    result : `~astroalign_nd.matching.MatchResult`
        The trusted linear match.
    source, target : `~astroalign_nd.Reference`
        The two frames (their detections are cached and reused).
    transform_type, degree, tolerance, significance
        See `~astroalign_nd.matching.fit_nonlinear`.
    n_fit : int, optional
        Detect up to ``2 * n_fit`` stars per image for the fit.
    n_control : (int, int), optional
        The control points of each frame in the linear match (by default
        ``result.n_sources_used`` for both).  When the larger star lists'
        detections found stellar widths that disagree between the frames
        (by more than ``FWHM_AGREEMENT``, at the match's scale) and the
        control points' widths agree better, the larger lists are detected
        again at the control points' widths, so that both frames are
        measured consistently.

    Returns
    -------
    `~astroalign_nd.matching.MatchResult`
        ``transform`` is the chosen model; the indices refer to the larger
        star lists; ``extra['model_selection']`` holds the ``info`` of the
        `~astroalign_nd.transforms.DistortionFit` and
        ``extra['linear_transform']`` the linear match.

    Examples
    --------
    >>> from astroalign_nd import Reference, find_match
    >>> from astroalign_nd.simulate import simulate_pair
    >>> from astroalign_nd.matching import extend_match
    >>> pair = simulate_pair((512, 512), n_stars=300, rotation=30.0, seed=1)
    >>> source, target = Reference(pair.source), Reference(pair.target)
    >>> linear = find_match(source, target)
    >>> grown = extend_match(linear, source, target, transform_type="polynomial", degree=2)
    >>> type(grown.transform).__name__, len(grown.source_index) > len(linear.source_index)
    ('PolynomialTransform', True)
    """
    n = max(int(n_fit), int(result.n_sources_used or 0))
    if n_control is None:
        n_control = (result.n_sources_used, result.n_sources_used)
    src_pts, src_err, src_frame = source.stars(n)
    dst_pts, dst_err, _ = target.stars(n)
    # Asking for many more stars can make detection search other scales and
    # choose a very different width in one frame only; centroids of asymmetric
    # stars (plate scans) then shift between the frames by a good fraction of
    # a pixel.  If the control points' widths agreed better, detect again at them.
    scale = float(np.sqrt(abs(np.linalg.det(result.transform.matrix[:2, :2]))))
    free = (source.detection_fwhm(n), target.detection_fwhm(n))
    ctrl = (source.detection_fwhm(n_control[0]), target.detection_fwhm(n_control[1]))
    if (None not in free + ctrl and _fwhm_mismatch(*free, scale) > np.log(FWHM_AGREEMENT)
            and _fwhm_mismatch(*ctrl, scale) < _fwhm_mismatch(*free, scale)):
        if free[0] != ctrl[0]:
            src_pts, src_err, src_frame = source.stars(n, fwhm=ctrl[0])
        if free[1] != ctrl[1]:
            dst_pts, dst_err, _ = target.stars(n, fwhm=ctrl[1])
    fit = fit_nonlinear(src_pts, dst_pts, result.transform.matrix, transform_type=transform_type,
                        degree=degree, seed_points=result.source_points,
                        source_errors=src_err, target_errors=dst_err, source_frame=src_frame,
                        tolerance=tolerance, significance=significance,
                        linear_type=transform_type_of(result.transform).name)
    out = MatchResult(
        transform=fit.transform, source_index=fit.source_index, target_index=fit.target_index,
        residuals=fit.residuals, rms=fit.rms, covariance=fit.covariance,
        log10_false_alarm=result.log10_false_alarm, n_source=len(src_pts),
        n_target=len(dst_pts), n_triangle_matches=result.n_triangle_matches,
        n_hypotheses=result.n_hypotheses, model_misfit=0.0,
        predicted_error=fit.info["predicted_error_max"],
        source_points=src_pts[fit.source_index], target_points=dst_pts[fit.target_index],
        n_sources_used=result.n_sources_used)
    out.extra["model_selection"] = fit.info
    out.extra["linear_transform"] = result.transform
    return out
