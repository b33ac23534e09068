# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The search: RANSAC over triangle hypotheses with early acceptance."""

import inspect
from dataclasses import dataclass, field
import numpy as np
from scipy.spatial import cKDTree
from .._kernels import PointGrid, count_inliers
from .._validate import check_points
from ..options import check_values
from .options import DEFAULT_TOLERANCE, MatchingConfig
from .asterisms import build_asterisms
from ..exceptions import PoorFitWarning, TooFewSourcesError, TransformNotFoundError, warn
from ..transforms.layers import layer_of
from ..transforms.registry import transform_class, transform_type_of
from .result import MatchResult
from .geometry import _overlap_box, bounding_frame
from .verify import (MAX_ERROR_BOUND, WARN_ERROR_BOUND, _affine_comparison, _degenerate,
                     _densest_line, _log10_false_alarm, _model_misfit, _on_line,
                     _predicted_error, _refine, _strip_halfwidth)
from .triangles import hypothesis_matrices, match_triangles

__all__ = ['match_points', 'search_tolerance']


def match_points(src_pts, dst_pts, *, transform_type="similarity", tolerance=3.0,
                 min_tolerance=0.5, invariant_radius=0.1, n_neighbors=4,
                 allow_mirror=True, scale_range=None, max_false_alarm=1e-6,
                 accept_matches=10, batch_size=512, max_hypotheses=20_000,
                 source_frame=None, target_frame=None, source_errors=None,
                 target_errors=None, n_control=None, prior_trials=0, source_asterisms=None,
                 target_asterisms=None):
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
        Extent of each image; the points' `bounding_frame` by default.
    source_errors, target_errors : (N,) ndarray, optional
        Expected position error of each point (pixels); used to weight the
        final fit.
    n_control : int or (int, int), optional
        Only the first ``n_control`` points (the brightest) form triangles
        and score hypotheses; all points are used to refine and verify.  A
        pair gives different numbers for the source and the target.  By
        default every point is a control point.
    prior_trials : int, optional
        Hypotheses already tried on this pair by earlier searches (the
        ``n_hypotheses`` of their `~astroalign_nd.TransformNotFoundError`);
        they count in the trials factor of the false-alarm probability, so
        that searching again does not make a chance match likelier to pass.
    source_asterisms, target_asterisms : `~astroalign_nd.matching.Asterisms`, optional
        Triangles of the first ``n_control`` points, when already built
        (a reference frame used for many registrations builds them once).

    Returns
    -------
    result : `MatchResult`

    Raises
    ------
    TooFewSourcesError
        If either list has fewer than 3 points.
    TransformNotFoundError
        If no hypothesis passes the false-alarm test; its ``n_hypotheses``
        attribute holds the number of hypotheses tried.
    ValueError, TypeError
        If an option is outside its range (one message per option, from
        ``astroalign_nd.config.OPTIONS``), the positions are not finite
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

    Only the 15 brightest stars of each list as control points, after an
    earlier search that tried 500 hypotheses:

    >>> result = match_points(src, dst, n_control=15, prior_trials=500)
    >>> result.n_matches
    40
    """
    return match_control_points(
        src_pts, dst_pts, n_control=n_control, prior_trials=prior_trials,
        source_asterisms=source_asterisms, target_asterisms=target_asterisms,
        transform_type=transform_type, tolerance=tolerance,
        min_tolerance=min_tolerance, invariant_radius=invariant_radius,
        n_neighbors=n_neighbors, allow_mirror=allow_mirror, scale_range=scale_range,
        max_false_alarm=max_false_alarm, accept_matches=accept_matches,
        batch_size=batch_size, max_hypotheses=max_hypotheses, source_frame=source_frame,
        target_frame=target_frame, source_errors=source_errors, target_errors=target_errors)


#: What a search knows beyond its settings (the control points, triangles already built,
#: earlier trials): arguments of `match_control_points`, not settings.
_CONTEXT = ("n_control", "prior_trials", "source_asterisms", "target_asterisms")

#: The settings of `match_points` and their defaults (its signature is their one home).
_SETTINGS = {name: p.default for name, p in inspect.signature(match_points).parameters.items()
             if p.kind is p.KEYWORD_ONLY and name not in _CONTEXT}


def search_tolerance(fwhm=None):
    """
    The search's matching radius (pixels) for stars ``fwhm`` pixels wide.

    `match_points`' default (`~astroalign_nd.matching.DEFAULT_TOLERANCE`),
    or half the FWHM where that is wider (defocus, digitised plates: wide
    stars have wide position errors).  A registration uses it when no
    ``tolerance`` is given.

    Parameters
    ----------
    fwhm : float, optional
        The stars' FWHM (pixels); None for a catalog.

    Returns
    -------
    tolerance : float

    Examples
    --------
    >>> from astroalign_nd.matching.search import search_tolerance
    >>> search_tolerance(None), search_tolerance(4.0), search_tolerance(10.0)
    (3.0, 3.0, 5.0)
    """
    return max(DEFAULT_TOLERANCE, 0.5 * (fwhm or 0.0))


def match_control_points(src_pts, dst_pts, *, n_control=None, source_asterisms=None,
                         target_asterisms=None, prior_trials=0, budget=None, **settings):
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
    source_asterisms, target_asterisms : `~astroalign_nd.matching.Asterisms`, optional
        Triangles of the first ``n_control`` points, when already built
        (a reference frame used for many registrations builds them once).
    prior_trials : int, optional
        Hypotheses already tried on this pair by earlier attempts; they
        count in the trials factor of the false-alarm probability.
    budget : int, optional
        A search after others that failed (`~astroalign_nd.find_match`'s
        later attempts): at most this many hypotheses are scored, only the
        best of each batch is refined, and the final pass refines the best
        `BUDGET_FINAL_REFINES` left.  A true match that an earlier attempt
        missed comes at the head of the later attempt's list (its triangles
        agree best), and is accepted at its first refinement; a pair that
        does not match would have every hypothesis scored and dozens refined
        by each attempt.  By default (None) the search is complete.

    **settings
        The keyword arguments of `match_points` (its defaults otherwise).

    Returns
    -------
    result : `MatchResult`

    Notes
    -----
    The stages: `_prepare` (checks, frames, control points), triangles and
    their `_Hypotheses` (made batch by batch, through `_filter_hypotheses`),
    `_score_batches` (early acceptance), without it a final pass over the best
    few hypotheses not refined yet, and `_failure_message`.

    Examples
    --------
    Triangles of the 20 brightest of 40 stars; all 40 refine the fit:

    >>> import numpy as np
    >>> from astroalign_nd.matching.search import match_control_points
    >>> src = np.random.default_rng(0).uniform(0, 200, (40, 2))
    >>> result = match_control_points(src, src + [3.0, -2.0], n_control=20)
    >>> result.n_matches
    40
    """
    unknown = set(settings) - set(_SETTINGS)
    if unknown:
        raise TypeError(f"unexpected keyword argument(s) {sorted(unknown)}; match_points "
                        f"accepts {list(_SETTINGS)}.")
    s = _prepare(src_pts, dst_pts, {**_SETTINGS, **settings}, n_control, prior_trials)
    s.budget = budget
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
    if not progress.accepted:  # refine the overall best few hypotheses not refined yet
        counts = progress.counts
        n_final = 10 if s.budget is None else BUDGET_FINAL_REFINES
        for h in np.argsort(-counts, kind="stable")[:n_final]:
            if int(h) in progress.refined or counts[h] < 3:
                continue
            cand = _evaluate(s, hyp, h, progress.n_scored)
            if cand is not None and (progress.best is None
                                     or cand.rank() < progress.best.rank()):
                progress.best = cand
    if progress.best is not None and progress.best.ok:
        return _result(progress.best, s, n_tri, progress.n_scored)
    exc = _not_found(progress.n_scored, _failure_message(s, progress, n_tri))
    # Did a candidate pass the false-alarm test (real stars, a fit not yet
    # trusted)?  Then a later attempt searches in full (`budget`).
    exc.near_trust = bool(progress.best is not None and progress.best.lfa <= s.log_limit)
    raise exc


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
    dst_tree: object = None  # the target points' k-d tree and grid, built once
    grid: object = None
    budget: object = None  # hypotheses a later attempt may score (None: all)

    @property
    def log_limit(self):
        return np.log10(self.max_false_alarm)


def _prepare(src_pts, dst_pts, settings, n_control, prior_trials):
    """Check the inputs and settings; the frames and control points of a search."""
    src_pts = check_points(src_pts, "source")
    dst_pts = check_points(dst_pts, "target")
    cls = transform_class(settings["transform_type"])
    transform_type = transform_type_of(cls).name
    opts = check_values(MatchingConfig, settings)
    for name, pts in (("source", src_pts), ("target", dst_pts)):
        if len(pts) < 3:
            raise TooFewSourcesError(
                f"the {name} has {len(pts)} usable source(s); at least 3 are needed to find "
                "a transform. Lower nsigma, give fwhm, or pass a catalog of positions."
            )
    scale_range = opts["scale_range"]
    layer = layer_of(cls)
    if scale_range is None and layer is not None and layer.unit_scale:
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
        src_frame=settings["source_frame"] or bounding_frame(src_pts),
        dst_frame=settings["target_frame"] or bounding_frame(dst_pts),
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
        prior_trials=prior_trials)


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
        # None yet: `_filter_hypotheses`' columns, empty.
        self.mats, self.tri_rms, self.parity = np.empty((0, 3, 3)), np.empty(0), np.empty(0)
        self.pairs, self.tri_size = pairs[:0], np.empty(0)

    @property
    def n_pairs(self):
        """The triangle pairs: at most one hypothesis each."""
        return len(self._all_pairs)

    def __len__(self):
        return len(self.mats)

    def grow(self, n):
        """Make hypotheses until ``n`` are held or every pair is used; return how many are."""
        have = len(self.mats)
        parts = [(self.mats, self.tri_rms, self.parity, self.pairs, self.tri_size)] if have else []
        while have < n and self._used < len(self._all_pairs):
            chunk = self._all_pairs[self._used:self._used + max(n - have, 256)]
            self._used += len(chunk)
            parts.append(_filter_hypotheses(self.src_ast, self._dst_ast, chunk, self._s))
            have += len(parts[-1][0])
        if parts:  # (one part is held as it is: the first batch's, usually)
            (self.mats, self.tri_rms, self.parity, self.pairs,
             self.tri_size) = parts[0] if len(parts) == 1 else (
                np.concatenate(col) for col in zip(*parts))
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

    model: object         # a `~astroalign_nd.matching.verify._Fitted` (no astropy model yet)
    si: np.ndarray        # matched source indices
    dj: np.ndarray        # matched target indices
    resid: np.ndarray
    cov: np.ndarray
    lfa: float            # log10 false-alarm probability
    h: int                # the hypothesis it came from
    pred: float           # largest predicted 1-sigma position error in the overlap
    bound: float          # how far off the self-consistency witnesses say it can be (px)
    inconsistent: object  # why the stars do not support the model over the frame, or None
    ok: bool              # passes the false-alarm and self-consistency tests
    degenerate: object = None  # why the stars cannot pin a 2-D transform (a line), or None
    affine: object = None      # its stars' `_affine_comparison` (for `_result`'s misfit)

    def rank(self):
        # A trustworthy candidate beats any other; then the less likely chance.
        return (not self.ok, self.lfa)


def _evaluate(s, hyp, h, n_scored):
    """
    Refine hypothesis h and compute its false-alarm probability (None if hopeless).

    Could it pass the false-alarm test, even optimistically?  Its matches at the
    search radius, counted over all stars, are first judged at the smallest radius
    the refinement may reach: chance hypotheses fail this cheaply and are not refined.
    """
    k_all = int(count_inliers(hyp.mats[h:h + 1], s.src_pts, s.grid)[0])
    lfa = _log10_false_alarm(hyp.mats[h], s.src_pts, s.dst_pts, k_all, s.min_tolerance,
                             s.src_frame, s.dst_frame, n_scored + s.prior_trials,
                             hyp.tri_rms[h], hyp.tri_size[h], s.invariant_radius)
    if not lfa <= s.log_limit:
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
    # The matched target stars' densest line, which both the local chance
    # and the degeneracy test look at (found once).
    line = _densest_line(s.dst_pts[dj], _strip_halfwidth(tol)) if len(si) >= 4 else None
    lfa = _log10_false_alarm(model.matrix, s.src_pts, s.dst_pts, len(si), tol, s.src_frame,
                             s.dst_frame, n_scored + s.prior_trials, hyp.tri_rms[h],
                             hyp.tri_size[h], s.invariant_radius, s.n_dof, matched=(si, dj),
                             dst_line=line)
    # Stars along one line (a band of detections on a raw frame's edge) fix
    # no 2-D transform, however many: refused, and the search goes on.
    degenerate = _degenerate(s.src_pts[si], s.dst_pts[dj], s.src_frame, s.dst_frame, tol,
                             dst_line=line)
    if degenerate is not None:  # (an affine fit of collinear stars is singular)
        return _Candidate(model=model, si=si, dj=dj, resid=resid, cov=cov, lfa=lfa, h=h,
                          pred=0.0, bound=0.0, inconsistent=None, degenerate=degenerate,
                          ok=False)
    # Where the registered image has data: the overlap of the two frames.
    box = _overlap_box(model.matrix, s.src_frame, s.dst_frame)
    pred = _predicted_error(model, cov, box)
    # Does the match check itself over the overlap: richer model, leave-one-out
    # and residual scatter all within the matching radius?
    # The limit is the matching radius, but never above MAX_ERROR_BOUND: a
    # radius widened for trailed or bloated stars does not widen what is
    # trusted (an answer that can be 4 px off is refused, not returned).
    src, dst = s.src_pts[si], s.dst_pts[dj]
    src_err = None if s.src_err is None else s.src_err[si]
    dst_err = None if s.dst_err is None else s.dst_err[dj]
    # (Kept: an accepted candidate's misfit over the target frame, `_result`'s,
    # compares it with the same affine fit.)
    affine = _affine_comparison(model, src, dst, src_err, dst_err)
    _, bound, inconsistent = _model_misfit(
        model, src, dst, src_err, dst_err, box, min(s.tolerance, MAX_ERROR_BOUND), pred,
        affine=affine)
    return _Candidate(model=model, si=si, dj=dj, resid=resid, cov=cov, lfa=lfa, h=h,
                      pred=pred, bound=bound, inconsistent=inconsistent,
                      ok=bool(lfa <= s.log_limit and inconsistent is None), affine=affine)


@dataclass
class _Progress:
    """Where the search stands after scoring."""

    counts: np.ndarray                          # control-point inliers per hypothesis
    best: _Candidate = None
    n_scored: int = 0
    refined: set = field(default_factory=set)   # hypotheses refined so far
    accepted: bool = False                      # early acceptance
    n_degenerate: int = 0                       # refined candidates along one line
    ctl_keep: np.ndarray = None                 # source control points that score


#: Degenerate candidates (`_degenerate`) refined before they count in the
#: refinement budget of `_score_batches`.
MAX_DEGENERATE = 30

#: Hypotheses the final pass of a budgeted search (`match_control_points`'
#: ``budget``) refines, of the best not refined yet (10 otherwise).
BUDGET_FINAL_REFINES = 3


def _score_batches(s, hyp):
    """Score the hypotheses batch by batch, refining the best few of each."""
    counts = np.zeros(hyp.n_pairs, int)  # the hypotheses' (at most one per pair)
    progress = _Progress(counts=counts[:0], ctl_keep=np.ones(len(s.src_ctl), bool))
    refined_max, start = 0, 0
    limit = hyp.n_pairs if s.budget is None else min(hyp.n_pairs, s.budget)
    per_batch = 3 if s.budget is None else 1  # refinements of each batch's best
    while start < limit and hyp.grow(min(start + s.batch_size, limit)) > start:
        stop = min(start + s.batch_size, len(hyp), limit)
        progress.counts = counts[:stop]
        # Control points of the source against every target star: a true
        # match also counts stars that are not among the target's brightest.
        counts[start:stop] = count_inliers(hyp.mats[start:stop], s.src_ctl[progress.ctl_keep],
                                           s.grid)
        progress.n_scored = stop
        # Try the best few of this batch (ties broken by invariant distance).
        order = start + np.argsort(-counts[start:stop], kind="stable")[:per_batch]
        for h in order:
            if counts[h] < min(s.accept_at, 4) and s.n_possible > 3:
                break
            # Refinement budget: after 10 refinements, only a hypothesis
            # that beats every one refined so far is worth another.
            if len(progress.refined) >= 10 and counts[h] <= refined_max:
                break
            cand = _evaluate(s, hyp, h, progress.n_scored)
            progress.refined.add(int(h))
            if cand is not None and cand.degenerate is not None:
                # A row of detections pairs with another by chance, often with
                # more inliers than the real stars: it sets no bar for them,
                # and its stars no longer score (a few dozen refined at most).
                progress.n_degenerate += 1
                if progress.n_degenerate > MAX_DEGENERATE:
                    refined_max = max(refined_max, int(counts[h]))
                _set_aside_line(s, hyp, progress, cand)
            else:
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


def _set_aside_line(s, hyp, progress, cand):
    """
    Stop scoring with the source control points on a degenerate candidate's
    line (a row of detections), and score the hypotheses so far again.

    Rows of detections make many triangles and hypotheses that pair them
    with each other; without them the real stars' hypotheses come first.
    """
    on = _on_line(s.src_ctl, s.src_pts[cand.si], s.min_tolerance)
    keep = progress.ctl_keep & ~on
    if keep.sum() < 3 or keep.sum() == progress.ctl_keep.sum():
        return
    progress.ctl_keep = keep
    n = len(progress.counts)
    progress.counts[:] = count_inliers(hyp.mats[:n], s.src_ctl[keep], s.grid)


def _failure_message(s, progress, n_tri):
    """Why no transform is trusted, and what to try."""
    counts, best = progress.counts, progress.best
    best_count = int(counts.max()) if len(counts) else 0
    detail = ""
    if best is not None and best.degenerate is not None:
        detail = (f"; the best candidate matched {len(best.si)} stars (false-alarm "
                  f"probability 10^{best.lfa:.1f}), but {best.degenerate}: a 2-D transform "
                  "needs stars spread over the frame, and a row of detections (a bright band "
                  "or a bad row or column) pairs by chance along its length")
    elif best is not None and best.lfa > s.log_limit:
        detail = (f"; the best candidate matched {len(best.si)} stars but its false-alarm "
                  f"probability is 10^{best.lfa:.1f} (limit {s.max_false_alarm:g})")
    elif best is not None:
        hint = ("; they may cover too small a part of the frame for an affine model: try "
                "transform_type='similarity'") if s.n_dof > 4 else ""
        detail = (f"; the best candidate matched {len(best.si)} stars (false-alarm "
                  f"probability 10^{best.lfa:.1f}), but {best.inconsistent}{hint}")
    return (
        f"no trustworthy transform found: the source gave {len(s.src_pts)} sources and the "
        f"target {len(s.dst_pts)}; {n_tri} triangle matches gave {progress.n_scored} "
        f"hypotheses, the best with {best_count} inliers{detail}. The images may not overlap; "
        "otherwise try more sources (n_sources), a larger tolerance, or catalogs of positions.")


def _not_found(n_hypotheses, message):
    exc = TransformNotFoundError(message)
    exc.n_hypotheses = n_hypotheses
    return exc


def _result(c, s, n_tri, n_scored):
    """The `MatchResult` of an accepted candidate, with the warnings its fit calls for."""
    src_pts, dst_pts, src_err, dst_err, dst_frame = (s.src_pts, s.dst_pts, s.src_err,
                                                     s.dst_err, s.dst_frame)
    resid = c.resid
    rms = float(np.sqrt(np.mean(np.sum(resid**2, axis=1)))) if len(resid) else float("nan")
    si, dj = c.si, c.dj
    model = c.model.model()  # the one astropy model of the search: the answer's
    # (Its figures from the plain numbers it was built from: the same values and
    # matrix, without astropy's parameter access.)
    predicted = _predicted_error(c.model, c.cov, dst_frame or bounding_frame(dst_pts[dj]))
    if predicted > 0.3:  # 3 sigma above 1 px somewhere in the frame
        warn(
            f"the transform is uncertain: its parameter covariance gives a 1-sigma position "
            f"error of up to {predicted:.2f} px over the frame ({len(si)} matched stars, RMS "
            f"{rms:.2f} px). Check it, or give more or brighter stars (n_sources, nsigma).",
            PoorFitWarning)
    elif c.bound > WARN_ERROR_BOUND:
        # The covariance trusts the residuals; leave-one-out and the affine
        # fit do not, and they say the answer can be more than 1 px off.
        warn(
            f"the transform is uncertain: its {len(si)} matched stars (RMS {rms:.2f} px) "
            f"leave it uncertain by up to {c.bound:.2f} px over the overlap (3 sigma, by "
            "leaving one star out and by an affine fit of the same stars). Check it, or give "
            "more or brighter stars (n_sources, nsigma).", PoorFitWarning)
    misfit, _, _ = _model_misfit(c.model, src_pts[si], dst_pts[dj],
                                 None if src_err is None else src_err[si],
                                 None if dst_err is None else dst_err[dj], dst_frame,
                                 affine=c.affine)
    if misfit > 0.5:
        name = type(model).__name__
        warn(
            f"the {name} leaves systematic residuals: an affine fit of the same "
            f"{len(si)} stars differs from it by up to {misfit:.2f} px over the frame. The "
            "images have shear, anisotropic scale or distortion; use transform_type='affine'.",
            PoorFitWarning)
    return MatchResult(
        transform=model, source_index=si, target_index=dj, residuals=resid,
        rms=rms, covariance=c.cov, log10_false_alarm=c.lfa, n_source=len(src_pts),
        n_target=len(dst_pts), n_triangle_matches=n_tri, n_hypotheses=n_scored,
        model_misfit=misfit, predicted_error=predicted, error_bound=c.bound,
        source_points=src_pts[si],
        target_points=dst_pts[dj])
