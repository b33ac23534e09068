# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The high-level API, top to bottom as the method goes:

``find_transform`` = parse inputs -> detect (`~astroalign_nd.detection`)
-> triangles (`~astroalign_nd.matching`) -> match and verify
(`~astroalign_nd.matching`) -> model (`~astroalign_nd.transforms`).

``apply_transform`` = resample (`~astroalign_nd.resample`) -> CCDData
(``astroalign_nd.resample.nddata``).  ``register`` = find, then apply.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np
from astropy import log
from astropy.utils.exceptions import AstropyWarning

from .io.read import parse_input
from .config import RegistrationConfig, split_options
from .detection.options import DetectionConfig
from .matching.options import DEFAULT_NEIGHBORS, MatchingConfig
from .resample.options import ResampleConfig
from .detection.daofind import control_sources, keep_confident
from .exceptions import TooFewSourcesError, TransformNotFoundError
from ._kernels import core_to_spare, num_threads, side_pool, threads_chosen, warn_if_slow
from ._validate import check_points
from .matching.asterisms import build_asterisms, check_triangle_budget
from .matching.search import match_control_points, search_tolerance
from .resample.nddata import apply_transform
from .matching.grow import SEARCH_TOLERANCE_FACTOR, extend_match
from .transforms.registry import nonlinear_name
from .exceptions import PoorFitWarning

if TYPE_CHECKING:
    from astropy.nddata import CCDData

    from .matching.result import MatchResult
    from .transforms.linear import LinearTransform2D

__all__ = ["find_transform", "find_match", "register", "Reference"]

#: Points of a catalog used (brightest first) when ``2 * n_sources`` is fewer.
_CATALOG_POINTS = 1000

#: Batches of hypotheses (``batch_size`` each) an attempt may score after one
#: that failed far from trust (`_escalate`).  Where a later attempt found the
#: match (the benchmarks' hard, trust and real cases), it did so in its first
#: batch: its triangles agree best.
LATER_ATTEMPT_BATCHES = 4

#: The detection and the matching options (the fields of their configs).
_DETECT_KEYS = tuple(f.name for f in dataclasses.fields(DetectionConfig))
_MATCH_KEYS = tuple(f.name for f in dataclasses.fields(MatchingConfig))
#: `apply_transform`'s options that `register` takes (the fields of its config).
_RESAMPLE_KEYS = tuple(f.name for f in dataclasses.fields(ResampleConfig))


class Reference:
    """
    A frame prepared once for many registrations.

    Detection, and the triangles of its control points, are computed on
    first use and kept, so registering thousands of frames onto one
    reference pays for the reference only once.  The largest detection
    made so far serves every smaller number of control points (its
    brightest stars), so the frame is detected again only when a search
    needs more stars than any before it, and never when its detection
    already measured every candidate it has; that detection reuses the
    full-frame passes and the measurements of the first, and measures only
    the candidates it adds.  Pass it wherever a
    ``target`` (or ``source``) is accepted.

    Parameters
    ----------
    image : array-like, `~astropy.nddata.NDData`, HDU, path, tuple or catalog
        Anything `find_transform` accepts.
    hdu : int or str, optional
        The HDU of a FITS path or HDUList (index or extension name); by
        default the first one with image data.
    unit : `~astropy.units.Unit` or str, optional
        The unit of an image that has none (no ``BUNIT``, a bare array).
    **detect_options
        Options of `~astroalign_nd.find_sources` (``fwhm``, ``nsigma``...).

    Attributes
    ----------
    detect_options : dict
        The detection options given, checked.
    config : `~astroalign_nd.detection.DetectionConfig`
        Every detection option (the defaults for those not given).
    fwhm : float or None
        The stars' FWHM (pixels) that detection used, once it has run; None
        for a catalog.

    Examples
    --------
    >>> from astroalign_nd import Reference, find_transform
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> ref = Reference(pair.target)
    >>> t, _ = find_transform(pair.source, ref)
    """

    def __init__(self, image: Any, *, hdu: int | str | None = None, unit: Any = None,
                 _role: str = "reference", _config: DetectionConfig | None = None,
                 **detect_options: Any) -> None:
        if _config is None:  # the user's keywords; a registration passes its checked config
            det, _ = split_options(detect_options, accept=("detection",), caller="Reference")
            _config = DetectionConfig(**det)
        # The role ('source', 'target') names the input in error messages.
        self._role = _role
        self._pixels = parse_input(image, _role, hdu=hdu, unit=unit)
        self._shape = self._pixels.shape
        self._is_catalog = self._pixels.is_catalog
        # A file can be read again: its pixels may be let go (`release_pixels`).
        self._reload = (os.fspath(image), hdu, unit) if isinstance(
            image, (str, os.PathLike)) else None
        self.config = _config
        defaults = DetectionConfig()
        self.detect_options = {k: getattr(_config, k) for k in _DETECT_KEYS
                               if k in detect_options or getattr(_config, k) != getattr(
                                   defaults, k)}
        self._stars = {}
        # (control points it was made for, table, threshold) of the largest detection.
        self._detected = None
        # Per detection FWHM option: what detection computed, for a detection of
        # more stars (`~astroalign_nd.detection.daofind.control_sources`' cache).
        self._detection_caches = {}
        self._asterisms = {}
        self._fwhms = {}
        self.fwhm = None

    @property
    def shape(self) -> tuple[int, int] | None:
        """(ny, nx) of the image, None for a catalog."""
        return self._shape

    @property
    def _parsed(self):
        """The parsed input; read again from its file after `release_pixels`."""
        if self._pixels is None:
            path, hdu, unit = self._reload
            self._pixels = parse_input(path, self._role, hdu=hdu, unit=unit)
        return self._pixels

    def release_pixels(self) -> bool:
        """
        Let go of the image's pixels, keeping the stars detected so far.

        For a frame read from a file: a further detection (more stars, a
        wider search) reads it again.  What a sequence of hundreds of
        frames keeps in memory is then their star lists, not their pixels.

        Returns
        -------
        released : bool
            False (nothing done) for an input that cannot be read again: an
            array, NDData or catalog.

        Examples
        --------
        >>> import os, tempfile
        >>> from astropy.io import fits
        >>> from astroalign_nd import Reference
        >>> from astroalign_nd.simulate import simulate_field
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     path = os.path.join(tmp, "frame.fits")
        ...     fits.writeto(path, simulate_field((128, 128), n_stars=40, seed=1)[0])
        ...     ref = Reference(path)
        ...     n = len(ref.stars(20)[0])
        ...     released = ref.release_pixels()
        ...     same = len(ref.stars(20)[0]) == n  # cached: the file is not read again
        >>> released, same, ref.shape
        (True, True, (128, 128))
        """
        if self._reload is None:
            return False
        self._pixels = None
        return True

    def stars(self, n_sources: int, fwhm: float | None = None
              ) -> tuple[np.ndarray, np.ndarray | None, tuple | None]:
        """
        Stars for ``n_sources`` control points (cached).

        Parameters
        ----------
        n_sources : int
            Control points wanted; up to twice as many stars are detected.
        fwhm : float, optional
            Detect with this stellar FWHM (pixels) instead of estimating it,
            unless the detection options already fix one.  The distortion
            stage passes the FWHM of the control-point detection, so that
            its larger star lists are measured like the control points: a
            scale search run on a longer list can pick another width in one
            frame than in the other, and centroids of asymmetric stars then
            shift between the frames.

        Returns
        -------
        points : (N, 2) ndarray
            Brightest first.  For images, up to ``2 * n_sources`` stars:
            the first ``n_sources`` are the control points, all of them
            refine the fit.
        errors : (N,) ndarray or None
            Expected position errors (pixels); None for catalogs.
        frame : (x0, x1, y0, y1) or None
            The image extent in pixels; None for catalogs.
        """
        fixed = fwhm is not None and not self._is_catalog and self.config.fwhm is None
        key = (n_sources, float(fwhm)) if fixed else n_sources
        if key not in self._stars:
            p = self._parsed  # (a released frame is read again only here)
            if p.is_catalog:
                # Brightest first: the method needs the brightest stars only, and
                # a cap keeps a million-point catalog from costing a million.
                cap = max(2 * n_sources, _CATALOG_POINTS)
                self._stars[key] = (p.points[:cap], None, None)
                return self._stars[key]
            if fixed:
                det = dataclasses.replace(self.config, fwhm=float(fwhm))
                table, nsigma = self._detect(p, det, n_sources)
            else:
                # The largest detection so far serves every smaller count: a
                # frame met again (a Reference, a batch's target) is not
                # detected again for fewer stars.
                if self._needs_detection(n_sources):
                    self._detected = (n_sources, *self._detect(p, self.config, n_sources))
                det = self.config
                _, table, nsigma = self._detected
            rows = _brightest(table, n_sources, det)
            if len(rows) < 3:
                raise TooFewSourcesError(_too_few_advice(
                    self._role, len(rows), table.meta, nsigma, det.fwhm is not None))
            ny, nx = p.shape
            pts = np.column_stack([np.asarray(table["x"], float)[rows],
                                   np.asarray(table["y"], float)[rows]])
            self._stars[key] = (pts, np.asarray(table["position_error"], float)[rows],
                                (-0.5, nx - 0.5, -0.5, ny - 0.5))
            self._fwhms[key] = table.meta.get("fwhm")
            if not fixed:
                self.fwhm = self._fwhms[key]
        return self._stars[key]

    def _needs_detection(self, n_sources: int) -> bool:
        """Would `stars` ``(n_sources)`` run detection?"""
        if self._is_catalog or n_sources in self._stars:
            return False
        if self._detected is None:
            return True
        n, table, _ = self._detected
        # A detection that measured every candidate of the frame has all
        # the stars a larger one would find (the sparse frames of refusals).
        return n < n_sources and not table.meta.get("all_candidates", False)

    def _detect(self, parsed, config, n_sources):
        """
        Every source detection can give for ``n_sources`` control points:
        up to ``2 * n_sources`` stars, the faint ones too (`_brightest` picks).
        """
        with warnings.catch_warnings():
            # An empty image is reported by the caller (TooFewSourcesError),
            # not by photutils' per-frame warning.
            warnings.simplefilter("ignore", _no_detections_warning())
            # (More than it can return: the confident ones are never kept alone here.)
            # A search that asks for more stars measures only the candidates
            # the larger detection adds (the cache of this FWHM option).
            return control_sources(parsed.detection_image, mask=parsed.mask,
                                   n_sources=2 * n_sources, n_enough=2 * n_sources + 1,
                                   config=config, as_table=False,
                                   cache=self._detection_caches.setdefault(config.fwhm, {}))

    def detection_fwhm(self, n_sources: int) -> float | None:
        """The FWHM (pixels) the detection of `stars` ``(n_sources)`` used; None
        for a catalog or before that detection ran."""
        return self._fwhms.get(n_sources)

    def asterisms(self, n_sources: int, n_neighbors: int = DEFAULT_NEIGHBORS) -> Any:
        """Triangles of the ``n_sources`` brightest stars (cached)."""
        key = (n_sources, n_neighbors)
        if key not in self._asterisms:
            pts = self.stars(n_sources)[0][:n_sources]
            self._asterisms[key] = build_asterisms(pts, n_neighbors=n_neighbors)
        return self._asterisms[key]


def _brightest(table, n_sources, config):
    """
    The stars (rows of ``table``) for ``n_sources`` control points from a
    detection for as many or more: the ``2 * n_sources`` brightest, of the confident ones only when
    there are ``n_sources`` of them (`~astroalign_nd.detection.daofind.keep_confident`,
    `~astroalign_nd.detection.daofind.control_sources`' rule, so that the list is the
    one a detection for ``n_sources`` gives).
    """
    return keep_confident(table, n_sources, config, rows=True)[:2 * n_sources]


def _no_detections_warning():
    try:
        from photutils.utils.exceptions import NoDetectionsWarning
    except ImportError:  # moved in a future photutils: its base class then
        from astropy.utils.exceptions import AstropyWarning as NoDetectionsWarning
    return NoDetectionsWarning


def _too_few_advice(role, n, meta, nsigma, user_fwhm):
    """A TooFewSourcesError message whose advice fits what detection saw."""
    fwhm = meta.get("fwhm", float("nan"))
    if not fwhm or not np.isfinite(fwhm):
        # Nothing star-like at all: a blank, constant or all-NaN frame.
        return (f"the {role} gave {n} usable source(s) at {nsigma:g} sigma, and at least 3 are "
                "needed to find a transform: nothing in it looks like a star (is it blank, "
                "constant or all NaN?). Pass the image with the stars, or a catalog of positions.")
    msg = (f"the {role} gave {n} usable source(s) at {nsigma:g} sigma with a stellar FWHM of "
           f"{fwhm:.1f} px; at least 3 are needed to find a transform. ")
    if user_fwhm:
        return msg + ("Check fwhm (the stars' width at half maximum, in pixels), lower "
                      "nsigma, or pass a catalog of positions.")
    return msg + (f"If its stars are not about {fwhm:.1f} px wide, pass fwhm=<their width in "
                  "pixels> (CLI: --fwhm); if they are and the frame is faint or sparse, lower "
                  "nsigma; or pass a catalog of positions.")


def _as_reference(obj, name, config, hdu=None, unit=None):
    """``obj`` as a `Reference` detected with ``config`` (a Reference keeps its own)."""
    if isinstance(obj, Reference):
        return obj
    return Reference(obj, hdu=hdu, unit=unit, _role=name, _config=config)


def _escalate(src, dst, nn, config):
    """
    The search over its attempts, ``(source stars, target stars, neighbours)``:
    (the first trusted match, its numbers of source and target control points,
    the usual matching tolerance or None when the caller set one).  Raises the
    last attempt's `TransformNotFoundError` when none is trusted.

    More control points help crowded fields, small overlaps and pairs whose
    brightest stars differ; more neighbours per star (``nn``, then 6 or 8 when
    the caller did not set it) help sparse, noisy lists (at most 60 stars):
    they miss many stars of the other image, so few of the 4-nearest-neighbour
    triangles are common.

    A refusal is an attempt that failed far from trust (no candidate passed
    the false-alarm test): the attempts after it are budgeted
    (`LATER_ATTEMPT_BATCHES` batches of hypotheses, the best of each
    refined; ``budget`` of `~astroalign_nd.matching.search.match_control_points`),
    so that a pair that does not match costs about one full attempt.  After
    an attempt whose best candidate passed the false-alarm test (real
    stars, not yet consistent), the next ones search in full.
    """
    n_sources, n_top = config.n_sources, config.n_sources
    while 2 * n_top <= config.max_sources:
        n_top *= 2
    plan = [(n_sources, n_sources, nn)]
    if n_top > n_sources:
        # Depth-matched attempts: when the pixel scales differ a lot, the
        # brightest stars of the narrow field are found among many more of
        # the wide field's; then many stars on both sides.
        plan += [(n_sources, n_top, nn), (n_top, n_sources, nn), (n_top, n_top, nn)]
    matching, nonlinear = config.matching, config.model.nonlinear
    user_nn = matching.n_neighbors is not None
    attempt_matching = matching
    trials, tried, k, last_exc, result = 0, set(), 0, None, None
    budget = None  # full attempts until one fails far from trust
    grow_tolerance = None
    _detect_both(src, plan[0][0], dst, plan[0][1])
    while k < len(plan):
        ns, nd, nn = plan[k]
        k += 1
        src_pts, src_err, src_frame = src.stars(ns)
        dst_pts, dst_err, dst_frame = dst.stars(nd)
        src_pts, dst_pts = check_points(src_pts, "source"), check_points(dst_pts, "target")
        # An image with fewer stars than asked for makes steps repeat.
        key = (min(ns, len(src_pts)), min(nd, len(dst_pts)), len(src_pts), len(dst_pts), nn)
        if key not in tried:
            tried.add(key)
            if matching.tolerance is None:
                grow_tolerance = search_tolerance(dst.fwhm)
                tolerance = grow_tolerance
                if nonlinear:  # a linear model is pixels off at the corners of a wide field
                    tolerance *= SEARCH_TOLERANCE_FACTOR
                # A copy for this attempt: the config the caller built stays as it was.
                attempt_matching = dataclasses.replace(matching, tolerance=tolerance)
            log.debug(f"astroalign_nd: attempt {len(tried)}: {key[0]} of {key[2]} source and "
                      f"{key[1]} of {key[3]} target stars, {nn} neighbours per star")
            try:
                result = _attempt(src, dst, (ns, nd, nn), (src_pts, src_err, src_frame),
                                  (dst_pts, dst_err, dst_frame), attempt_matching, trials,
                                  linear_type=config.model.linear_type, nonlinear=nonlinear,
                                  budget=budget)
                break
            except TransformNotFoundError as exc:
                # Earlier attempts count in the trials factor of later ones.
                trials += getattr(exc, "n_hypotheses", 0)
                last_exc = exc
                if getattr(exc, "near_trust", False):
                    budget = None
                elif getattr(exc, "n_hypotheses", 0) > 0:  # (not when no triangle matched)
                    budget = LATER_ATTEMPT_BATCHES * attempt_matching.batch_size
                log.debug(f"astroalign_nd: attempt {len(tried)} found no trusted match; "
                          f"{trials} hypotheses so far")
        if (k == len(plan) and not user_nn and nn < 8
                and max(len(src_pts), len(dst_pts)) <= 60):
            plan.append((ns, nd, nn + 2))
            log.debug("astroalign_nd: escalating to more neighbours per star")
    if result is None:
        raise last_exc
    log.debug(f"astroalign_nd: match found at attempt {len(tried)}: {result.n_matches} "
              f"stars, RMS {result.rms:.3f} px")
    return result, ns, nd, grow_tolerance


#: Pixels of the smaller frame from which two detections in two threads pay
#: (measured on idle cores: 0.8-0.9 Mpx frames took 0.7-0.8 of the time of one
#: after the other; 0.07-0.5 Mpx frames took 1.0-1.25 times as long).
PARALLEL_DETECTION_PIXELS = 750_000


def _detect_both(src, ns, dst, nd):
    """
    Detect the stars of both images of the first attempt at once, the
    target's in a second thread (when `~astroalign_nd.conf` allows two).

    Detection is most of a small frame's registration, and much of it runs
    in NumPy and compiled code that releases the GIL: two frames at once
    take about 0.8 of the time of one after the other, on a core of their
    own.  On busy cores, or for frames smaller than
    `PARALLEL_DETECTION_PIXELS` (whose detection is mostly Python work that
    holds the GIL), they only take turns: with the default thread count
    they are then detected one after the other (`core_to_spare`); a thread
    count the user set is followed.  The results are the same
    (each frame is detected alone, from its own data); errors are raised
    in the sequential order (the source's first).
    """
    todo = [ref for ref, n in ((src, ns), (dst, nd)) if ref._needs_detection(n)]
    if len(todo) < 2 or src is dst or num_threads() < 2:
        return
    if not threads_chosen() and (
            not core_to_spare()
            or min(np.prod(ref._shape) for ref in todo) < PARALLEL_DETECTION_PIXELS):
        return
    # The warning filters are one global list, and ``catch_warnings`` blocks
    # in two threads restore each other's lists in any order (photutils
    # ignores NumPy's RuntimeWarnings inside its own).  So this block holds
    # every filter either thread sets, which then holds whatever order the
    # threads exit in, and restores the caller's filters at the end.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", _no_detections_warning())
        warnings.simplefilter("ignore", AstropyWarning)
        warnings.simplefilter("ignore", RuntimeWarning)
        later = side_pool().submit(dst.stars, nd)
        try:
            src.stars(ns)
        finally:
            error = later.exception()
    if error is not None:
        raise error


def _attempt(src, dst, sizes, src_stars, dst_stars, matching, trials, *, linear_type,
             nonlinear, budget=None):
    """One attempt of the search: ``match_control_points`` on ``sizes = (ns, nd, nn)``
    (``budget``: hypotheses it may score, None for all)."""
    ns, nd, nn = sizes
    settings = matching.match_kwargs()
    del settings["n_neighbors"]  # the attempt's own: ``nn``
    (src_pts, src_err, src_frame), (dst_pts, dst_err, dst_frame) = src_stars, dst_stars
    with warnings.catch_warnings():
        if nonlinear:  # the distortion model answers the linear fit's misfit
            warnings.simplefilter("ignore", PoorFitWarning)
        return match_control_points(src_pts, dst_pts, transform_type=linear_type,
                                    source_frame=src_frame, target_frame=dst_frame,
                                    source_errors=src_err, target_errors=dst_err,
                                    n_control=(ns, nd), n_neighbors=nn,
                                    source_asterisms=src.asterisms(ns, nn),
                                    target_asterisms=dst.asterisms(nd, nn),
                                    prior_trials=trials, budget=budget, **settings)


def find_match(source: Any, target: Any, *, transform_type: str | type = "similarity",
               n_sources: int = 50, max_sources: int = 200, hdu: int | str | None = None,
               degree: int | str | None = None, **options: Any) -> MatchResult:
    """
    Find the transform from ``source`` to ``target`` with its quality.

    Same arguments as `find_transform`; returns the full
    `~astroalign_nd.matching.MatchResult`, whose ``source_points`` and
    ``target_points`` hold the matched positions.
    Each attempt of the search is logged at debug level to astropy's
    logger (``astropy.log.setLevel("DEBUG")`` shows them).

    Examples
    --------
    A simulated pair of frames rotated by 30 degrees:

    >>> from astroalign_nd import find_match
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> result = find_match(pair.source, pair.target)
    >>> bool(abs(result.transform.rotation_deg - 30.0) < 0.1)
    True
    >>> bool(result.n_matches >= 20), bool(result.rms < 1.0)
    (True, True)
    >>> result.source_points.shape == (result.n_matches, 2)
    True
    """
    config = RegistrationConfig.from_keywords(
        transform_type=transform_type, degree=degree, n_sources=n_sources,
        max_sources=max_sources, **options)
    return find_match_from_config(source, target, config, hdu=hdu)


def find_match_from_config(source: Any, target: Any, config: RegistrationConfig, *,
                           hdu: int | str | None = None) -> MatchResult:
    """
    `find_match` with its options already checked, as a config.

    Parameters
    ----------
    source, target
        As in `find_transform`.
    config : `~astroalign_nd.config.RegistrationConfig`
        The search's options.
    hdu : int or str, optional
        As in `find_transform`.

    Returns
    -------
    result : `~astroalign_nd.matching.MatchResult`

    Examples
    --------
    >>> from astroalign_nd.config import RegistrationConfig
    >>> from astroalign_nd.registration import find_match_from_config
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> config = RegistrationConfig.from_keywords(n_sources=40)
    >>> result = find_match_from_config(pair.source, pair.target, config)
    >>> bool(result.n_matches >= 20)
    True
    """
    num_threads()  # a bad thread setting is reported before any work
    warn_if_slow()
    nn = config.matching.n_neighbors or DEFAULT_NEIGHBORS
    # Memory is bounded before any work: the largest attempt's triangles.
    check_triangle_budget(config.max_sources, nn)
    src = _as_reference(source, "source", config.detection, hdu)
    dst = _as_reference(target, "target", config.detection, hdu)

    result, ns, nd, grow_tolerance = _escalate(src, dst, nn, config)
    result.n_sources_used = max(ns, nd)
    if config.model.nonlinear:
        result = _grow(result, src, dst, config, (ns, nd), grow_tolerance)
    return result


def _grow(result, src, dst, config, n_control, grow_tolerance):
    """The distortion model, grown from the linear ``result`` over more stars."""
    model = config.model
    kind = nonlinear_name(model.transform_type)
    # The growth pairs stars with the usual radius, not the widened search's:
    # it follows the distortion disc by disc, and in a crowded field a wide
    # radius pairs chance neighbours that a polynomial then chases.
    tol = grow_tolerance if config.matching.tolerance is None else config.matching.tolerance
    result = extend_match(result, src, dst, transform_type=kind,
                          degree=model.degree, tolerance=tol,
                          n_control=n_control)
    info = result.extra["model_selection"]
    log.debug(f"astroalign_nd: {info['model']} model (degree {info['degree']}) over "
              f"{result.n_matches} stars, RMS {result.rms:.3f} px")
    return result


def find_transform(source: Any, target: Any, *, transform_type: str | type = "similarity",
                   n_sources: int = 50, max_sources: int = 200,
                   hdu: int | str | None = None, degree: int | str | None = None,
                   **options: Any) -> tuple[LinearTransform2D, tuple[np.ndarray, np.ndarray]]:
    """
    Find the transform that maps ``source`` pixel coordinates onto ``target``.

    Parameters
    ----------
    source, target : array-like, `~astropy.nddata.NDData`, path, tuple or catalog
        2-D (or channels-last) arrays, numpy masked arrays, NDData/CCDData
        (their masks are honoured), FITS HDUs or paths (read as
        `~astropy.nddata.CCDData.read` reads them, with their ``MASK``;
        JPEG/PNG/TIFF too), ``(array, header)`` or ``(array, WCS)`` tuples
        (as reproject takes them), or catalogs: an `~astropy.table.Table`
        with ``x``/``y`` columns (masked entries are left out) or an
        (N, 2) array of positions, brightest first (a catalog contributes
        its first ``max(2 * n_sources, 1000)`` positions).
    transform_type : {'similarity', 'euclidean', 'translation', 'affine', \
'projective', 'polynomial'}, optional
        The model to fit (default 'similarity': scale, rotation, shift,
        mirrored or not).  'projective' (a homography) and 'polynomial'
        (distortion in the SIP form) are for wide fields: they start from
        the similarity match of the brightest stars and grow the fit over
        up to 2000 stars per image (``astroalign_nd.matching.grow``).
    n_sources : int, optional
        Brightest sources used as control points (default 50).
    max_sources : int, optional
        If no trustworthy match is found, the number of control points is
        doubled up to this limit before giving up (default 200).
    hdu : int or str, optional
        The HDU of FITS paths and HDULists to read (index or extension
        name, as in `~astropy.nddata.CCDData.read`); by default the first
        one with image data.
    degree : int or 'auto', optional
        Degree of a 'polynomial' model, 2 to 5 (default 3), or 'auto': an
        F-test admits each extra group of terms only if the stars need it,
        so that a pair with no distortion gets a linear model.
    **options
        Detection options (``fwhm``, ``nsigma``, ``sharpness_range``,
        ``roundness_range``, ``peak_max``, ``bin_factor``,
        ``refine_centroids``, or ``finder``: another detector; see
        `~astroalign_nd.find_sources`) and matching options
        (``tolerance``, ``min_tolerance``, ``invariant_radius``,
        ``n_neighbors``, ``allow_mirror``, ``scale_range``,
        ``max_false_alarm``, ``accept_matches``, ``batch_size``,
        ``max_hypotheses``; see `~astroalign_nd.matching.match_points`).

    Returns
    -------
    transform : `~astroalign_nd.transforms.LinearTransform2D` or non-linear model
        The source-to-target model.  ``transform.meta['quality']`` holds the
        number of matched stars, the RMS residual (pixels), the parameter
        covariance, the log10 false-alarm probability and ``error_bound``
        (how far off, 3 sigma, the matched stars say the transform can be
        over the overlap; see `~astroalign_nd.matching.MatchResult`); for the
        'projective' and 'polynomial' types also ``model``, ``degree``,
        ``predicted_error_max`` and ``predicted_error_rms`` (the 1-sigma
        error of the mapping over the frame, from the covariance) and
        ``model_selection`` (the candidates compared, their test
        statistics and the stars' coverage of the frame).
    (source_points, target_points) : tuple of (K, 2) ndarray
        The matched control points.

    Raises
    ------
    TooFewSourcesError
        If an image gave fewer than 3 sources.
    TransformNotFoundError
        If no transform could be found or trusted.
    PoorCoverageError
        If the stars do not cover the frame well enough for the requested
        polynomial degree or projective model.
    ValueError, TypeError
        If an option is outside its accepted range (the message names it
        and the range), or ``max_sources`` with ``n_neighbors`` would build
        more triangles than the memory budget allows.

    Examples
    --------
    >>> from astroalign_nd import find_transform
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> t, (src, dst) = find_transform(pair.source, pair.target)
    >>> bool(abs(t.rotation_deg - 30.0) < 0.05)
    True
    """
    result = find_match(source, target, transform_type=transform_type, n_sources=n_sources,
                        max_sources=max_sources, hdu=hdu, degree=degree, **options)
    model = result.transform
    model.meta["quality"] = _quality_dict(result)
    return model, (result.source_points, result.target_points)


def _quality_dict(result: MatchResult) -> dict:
    """The quality figures of a `~astroalign_nd.matching.MatchResult` as a dict."""
    quality = dict(
        n_matches=int(result.n_matches),
        rms=float(result.rms),
        covariance=np.array(result.covariance),
        log10_false_alarm=float(result.log10_false_alarm),
        n_source=int(result.n_source),
        n_target=int(result.n_target),
        n_triangle_matches=int(result.n_triangle_matches),
        n_hypotheses=int(result.n_hypotheses),
        error_bound=float(result.error_bound),
    )
    info = result.extra.get("model_selection")
    if info is not None:
        quality.update(model=info["model"], degree=info["degree"],
                       predicted_error_max=info["predicted_error_max"],
                       predicted_error_rms=info["predicted_error_rms"], model_selection=info)
    return quality


def register(source: Any, target: Any, *, transform_type: str | type = "similarity",
             n_sources: int = 50, max_sources: int = 200, order: str | int = "bilinear",
             conserve_flux: bool = False, fill_value: float = np.nan,
             method: str = "interpolate", unit: Any = None, parallel: bool = True,
             hdu: int | str | None = None, add_keyword: bool = True,
             degree: int | str | None = None, **options: Any) -> CCDData:
    """
    Align ``source`` onto ``target``: `find_transform`, then
    `~astroalign_nd.apply_transform`.

    Parameters
    ----------
    source, target
        As in `find_transform`, but both must be images: the source is
        resampled onto the target's pixel grid.
    transform_type, n_sources, max_sources, hdu, degree, **options
        As in `find_transform`.
    order, conserve_flux, fill_value, method, unit, parallel, add_keyword
        As in `~astroalign_nd.apply_transform`.

    Returns
    -------
    registered : `~astropy.nddata.CCDData`
        ``source`` on the target's pixel grid, with mask, propagated
        uncertainty, unit, WCS and a header recording the transform and the
        quality of the fit.  ``registered.meta`` rebuilds the transform with
        `~astroalign_nd.transform_from_header`.

    Examples
    --------
    >>> from astroalign_nd import register
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> ccd = register(pair.source, pair.target)
    >>> ccd.shape, ccd.mask.dtype
    ((256, 256), dtype('bool'))
    """
    return register_and_match(
        source, target, transform_type=transform_type, n_sources=n_sources,
        max_sources=max_sources, order=order, conserve_flux=conserve_flux,
        fill_value=fill_value, method=method, unit=unit, parallel=parallel, hdu=hdu,
        add_keyword=add_keyword, degree=degree, **options)[0]


def register_and_match(source: Any, target: Any, *, hdu: int | str | None = None,
                       unit: Any = None, **options: Any) -> tuple[CCDData, MatchResult]:
    """
    `register`, also returning the match that the registration used.

    Parameters
    ----------
    source, target, hdu, unit, **options
        As in `register` (the options it does not get are its defaults).

    Returns
    -------
    registered : `~astropy.nddata.CCDData`
        As `register` returns it.
    result : `~astroalign_nd.matching.MatchResult`
        The match (its transform's ``meta['quality']`` filled in as
        `find_transform` fills it), e.g. for a diagnostic figure that does
        not search again.

    Examples
    --------
    >>> from astroalign_nd.registration import register_and_match
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> ccd, result = register_and_match(pair.source, pair.target)
    >>> ccd.shape, result.source_points.shape == result.target_points.shape
    ((256, 256), True)
    """
    resample = ResampleConfig(**{k: options.pop(k) for k in _RESAMPLE_KEYS if k in options})
    config = RegistrationConfig.from_keywords(**options)
    src, dst, result = find_for_apply(source, target, config, hdu=hdu, unit=unit)
    quality = _quality_dict(result)
    # Resampling needs the target's grid, WCS and name, not its pixels: a
    # frame read from a file here is freed before the output is made.
    # (its pixels replaced by a read-only view of one zero of the same shape)
    zeros = np.broadcast_to(np.zeros((), dst._parsed.data.dtype), dst._parsed.data.shape)
    grid = dataclasses.replace(dst._parsed, data=zeros, mask=None, uncertainty=None, flags=None)
    if not isinstance(target, Reference) and dst._parsed is not target:
        # Ours: the pixels go now, not at the next garbage collection.
        dst._parsed.data = dst._parsed.mask = dst._parsed.uncertainty = None
        dst._parsed.flags = None
    del dst
    ccd = apply_transform(result.transform, src._parsed, grid, unit=unit, quality=quality,
                          **dataclasses.asdict(resample))
    result.transform.meta["quality"] = quality
    return ccd, result


def find_for_apply(source: Any, target: Any, config: RegistrationConfig, *,
                   hdu: int | str | None = None, unit: Any = None
                   ) -> tuple[Reference, Reference, MatchResult]:
    """
    The find step of `register` and `~astroalign_nd.register_batch`: one
    policy for both.

    Both inputs are read as images (a catalog cannot be resampled) and the
    transform is found with ``config``.

    Parameters
    ----------
    source, target
        Images, as `register` takes them (or `Reference` objects).
    config : `~astroalign_nd.config.RegistrationConfig`
        The search's options.
    hdu, unit : optional
        As in `register`.

    Returns
    -------
    source, target : `Reference`
    result : `~astroalign_nd.matching.MatchResult`

    Raises
    ------
    TypeError
        If an input is a catalog.

    Examples
    --------
    >>> from astroalign_nd.config import RegistrationConfig
    >>> from astroalign_nd.registration import find_for_apply
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> src, dst, result = find_for_apply(pair.source, pair.target, RegistrationConfig())
    >>> src.shape, bool(result.n_matches >= 20)
    ((256, 256), True)
    """
    src = _as_reference(source, "source", config.detection, hdu, unit)
    dst = _as_reference(target, "target", config.detection, hdu)
    for name, p in (("source", src._parsed), ("target", dst._parsed)):
        if p.is_catalog:
            raise TypeError(
                f"register needs images; the {name} is a catalog. Use find_transform with "
                "catalogs, then apply_transform on the source image."
            )
    return src, dst, find_match_from_config(src, dst, config)


def quality_dict(result: MatchResult) -> dict:
    """
    The quality figures of a `~astroalign_nd.matching.MatchResult` as a dict,
    as `find_transform` puts them in ``transform.meta['quality']`` and
    `~astroalign_nd.apply_transform` records them in the header.

    Examples
    --------
    >>> from astroalign_nd import find_match
    >>> from astroalign_nd.registration import quality_dict
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> sorted(quality_dict(find_match(pair.source, pair.target)))[:3]
    ['covariance', 'error_bound', 'log10_false_alarm']
    """
    return _quality_dict(result)


def prepare_target(target: Any, config: RegistrationConfig, hdu: int | str | None = None
                   ) -> Reference:
    """
    The target of many finds (`~astroalign_nd.register_batch`): an image
    `Reference` whose stars and triangles for the first attempt are computed
    once, before it is shipped to workers.

    Parameters
    ----------
    target
        An image, as `register` takes it, or a `Reference`.
    config : `~astroalign_nd.config.RegistrationConfig`
        The search's options.
    hdu : int or str, optional
        As in `register`.

    Returns
    -------
    reference : `Reference`

    Raises
    ------
    TypeError
        If the target is a catalog.

    Examples
    --------
    >>> from astroalign_nd.config import RegistrationConfig
    >>> from astroalign_nd.registration import prepare_target
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> prepare_target(pair.target, RegistrationConfig()).shape
    (256, 256)
    """
    ref = _as_reference(target, "target", config.detection, hdu)
    if ref._parsed.is_catalog:
        raise TypeError("the target of register_batch must be an image (it defines the "
                        "output grid); it is a catalog.")
    ref.stars(config.n_sources)
    ref.asterisms(config.n_sources, config.matching.n_neighbors or DEFAULT_NEIGHBORS)
    return ref
