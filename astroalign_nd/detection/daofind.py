# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The DAOStarFinder pipeline: find, measure and filter the frame's stars."""

import warnings
import numpy as np
from astropy.table import Table
from astropy.utils.exceptions import AstropyWarning
from ..io.read import image_and_mask
from .._kernels import GAUSS_SIGMA_TO_FWHM as _GAUSS_SIGMA_TO_FWHM
from .._kernels import adaptive_fwhm as _adaptive_fwhm
from .._kernels import lost_window_fraction as _lost_window_fraction
from .._kernels import median as _median
from .._kernels import mirrored_windowed_centroid as _mirrored_windowed_centroid
from .._kernels import windowed_centroid as _windowed_centroid
from ..options import Int, convert
from .fwhm import _MAX_FULL_RES_FWHM, _estimate_fwhm
from .candidates import (_DESPIKE_MIN_FWHM, _as_image, _auto_bin, _binned_peaks,
                         _binned_residual, _despike, _extract_cutouts, _recenter)
from .background import (_bin_mean, _correlated_noise_factor, _local_background,
                         estimate_noise)
from .lines import line_background
from .trails import find_trails, trail_pieces
from .options import DetectionConfig
from .base import SourceFinderBase, _standard_table

__all__ = ['find_sources', 'DAOSourceFinder', 'control_sources']


def find_sources(image, *, mask=None, n_sources=50, fwhm=None, nsigma=5.0,
                 sharpness_range=(-np.inf, 1.0), roundness_range=(-1.0, 1.0),
                 peak_max=None, bin_factor=None, refine_centroids=True, finder=None):
    """
    Find the brightest point sources of an image with DAOStarFinder.

    The work goes in named stages (see the module docstring): noise and
    binned candidates (`_binned_candidates`), full-resolution recentring
    (`_recenter`), the FWHM estimate from the population of compact
    candidates (`_estimate_fwhm`), measurement with DAOStarFinder
    (`_measure`), and, when the estimate is doubtful or keeps too few
    sources, a search over other scales (`_best_scale`).

    Parameters
    ----------
    image : 2-D array-like, `~astropy.nddata.NDData`, path, HDU or tuple
        The image: an array, a masked array, NDData/CCDData, a FITS path or
        HDU, or an ``(array, header)`` tuple; its own mask is honoured.
        NaN and infinite pixels count as masked.
    mask : 2-D bool array-like, optional
        True for pixels to ignore.
    n_sources : int, optional
        Number of brightest sources to return (default 50).
    fwhm : float, optional
        Stellar FWHM in pixels.  Estimated from the image when not given.
    nsigma : float, optional
        Detection threshold in units of the per-pixel noise.
    sharpness_range, roundness_range : tuple of 2 floats or None, optional
        DAOStarFinder's limits, applied at full resolution.  The default
        sharpness range has no lower limit, so that saturated (flat-topped)
        stars are kept; its upper limit, binning that drops each block's
        brightest pixel, and a check of each source's own FWHM reject hot
        pixels and cosmic rays.
    peak_max : float, optional
        Sources with a peak above this (e.g. saturated) are dropped.  By
        default saturated stars are kept: their centroids are still good.
    bin_factor : int, optional
        Binning used by the first (candidate) detection pass.  By default
        it is chosen so that the binned image is about 320 pixels across.
    refine_centroids : bool, optional
        Refine DAOStarFinder's centroids with a Gaussian-windowed centroid
        (default True).
    finder : `~astroalign_nd.detection.SourceFinderBase` or callable, optional
        Another detector, instead of the DAOStarFinder pipeline: a finder
        such as `~astroalign_nd.detection.SegmentationFinder`, or any
        callable ``finder(data, mask=None)`` returning an
        `~astropy.table.Table` with ``x``, ``y`` (or photutils'
        ``x_centroid``, ``y_centroid``) and ``flux`` columns, such as a
        photutils star finder.  Its ``n_sources`` brightest sources are
        returned.  The options above (but ``mask`` and ``n_sources``)
        configure the DAOStarFinder pipeline: with ``finder``, they must be
        left at their defaults (set the finder's own instead).

    Returns
    -------
    sources : `~astropy.table.Table`
        Columns ``x``, ``y`` (0-based pixels), ``flux`` (background
        subtracted, in an aperture of radius 1.5 FWHM), ``position_error``
        (expected centroid error per axis, pixels), ``snr`` (matched-filter
        signal-to-noise), ``peak``,
        ``sharpness``, ``roundness1``, ``roundness2``; sorted by decreasing
        flux.  The table's ``meta`` holds ``fwhm``, ``noise``,
        ``bin_factor`` and ``fwhm_source`` (``'user'``, ``'estimate'`` or
        ``'scale search'``).  It may have fewer rows than ``n_sources``
        (or none).  With ``finder``: the finder's table, brightest first
        (``fwhm_source`` ``'finder'`` unless the finder sets it).

    Examples
    --------
    The 30 brightest stars of a simulated frame, each within a fraction of
    a pixel of a true star:

    >>> import numpy as np
    >>> from scipy.spatial import cKDTree
    >>> from astroalign_nd.detection import find_sources
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> sources = find_sources(pair.source, n_sources=30)
    >>> len(sources), sources.colnames[:3]
    (30, ['x', 'y', 'flux'])
    >>> sources.meta["fwhm_source"]
    'estimate'
    >>> truth = np.column_stack([pair.source_stars["x"], pair.source_stars["y"]])
    >>> dist, _ = cKDTree(truth).query(np.column_stack([sources["x"], sources["y"]]))
    >>> bool(np.median(dist) < 0.2)
    True

    The same frame with another detector:

    >>> from astroalign_nd.detection import SegmentationFinder
    >>> len(find_sources(pair.source, n_sources=30, finder=SegmentationFinder(nsigma=3.0)))
    30
    """
    n_sources = convert("n_sources", Int(1, None), n_sources)
    # The options' one check: their config field (`astroalign_nd.config`).
    config = DetectionConfig(fwhm=fwhm, nsigma=nsigma, sharpness_range=sharpness_range,
                             roundness_range=roundness_range, peak_max=peak_max,
                             bin_factor=bin_factor, refine_centroids=refine_centroids,
                             finder=finder)
    threshold = _CONFIDENT_NSIGMA if config.nsigma is None else config.nsigma
    return _Rows.as_table(_detect(image, mask, n_sources, config, threshold))


def _detect(image, mask, n_sources, config, nsigma, cache=None, grow=True, width=None):
    """
    `find_sources` on checked options: ``config``, at threshold ``nsigma``.

    ``cache`` (a dict, optional) keeps what the detection computed for a
    later detection of the same image with the same ``config`` and
    ``nsigma``, of more or fewer sources: the full-frame stage 1, the FWHM
    estimate and every candidate's measurement at each width tried
    (`_per_candidate`).  That detection then measures only the candidates
    it adds, and returns what a detection without the cache returns.
    ``grow``: whether a list cut short by candidates that are not stars
    may be made from more candidates (`_grown`); without, the list at the
    estimated width (or ``width``), no other widths tried.
    """
    fwhm, bin_factor = config.fwhm, config.bin_factor
    # Paths, NDData, HDUs, (array, header) tuples, masked arrays: their own
    # mask is combined with ``mask``.
    image, mask = image_and_mask(image, mask)
    data, mask = _as_image(image, mask)
    if mask is not None and mask.all():
        raise ValueError("every pixel of the image is masked or not finite.")
    if config.finder is not None:
        return _run_finder(config.finder, data, mask, n_sources, dict(
            fwhm=config.fwhm, nsigma=nsigma, sharpness_range=config.sharpness_range,
            roundness_range=config.roundness_range, peak_max=config.peak_max,
            bin_factor=config.bin_factor, refine_centroids=config.refine_centroids))
    opts = dict(n_sources=n_sources, nsigma=nsigma, sharpness_range=config.sharpness_range,
                roundness_range=config.roundness_range, peak_max=config.peak_max,
                refine_centroids=config.refine_centroids, cache=cache)

    # Stage 1: noise, then candidate peaks on a binned copy.
    stage1 = None if cache is None else cache.get("stage 1")
    if stage1 is None:
        stage1 = _stage1(data, mask, bin_factor, nsigma)
        if cache is not None:
            cache["stage 1"] = stage1
    noise, b, residual = stage1["noise"], stage1["b"], stage1["residual"]
    if residual is None:  # no noise to judge anything by
        return _empty_table(fwhm or 0.0, noise, 1)
    opts["noise_corr"] = stage1["noise_corr"]
    if "lines" in stage1:
        lines = opts["lines"] = stage1["lines"]
        if lines is not None:
            data = lines.subtract(data)
    # Spare candidates for what stage 2 rejects (binning already removed
    # most hot pixels and cosmic rays).
    n_cand = n_sources + n_sources // 2 + 30
    cand = _binned_peaks(residual, nsigma, n_cand)
    if len(cand["x"]) == 0:
        return _empty_table(fwhm or 0.0, noise, b)
    coarse = cand
    cand = _recentered(data, mask, coarse, b, fwhm, cache)
    trails = find_trails(cand["x"], cand["y"], data, mask, noise)
    if trails:
        # A trail's pieces (`trails`) are not stars, and took the places of
        # faint ones among the candidates: more candidates, less the pieces.
        n_pieces = int(trail_pieces(data, mask, cand["x"], cand["y"], trails, noise).sum())
        coarse = _binned_peaks(residual, nsigma, n_cand + n_pieces)
        cand = _recentered(data, mask, coarse, b, fwhm, cache)
        keep = ~trail_pieces(data, mask, cand["x"], cand["y"], trails, noise)
        coarse = {k: v[keep] for k, v in coarse.items()}
        cand = {k: v[keep] for k, v in cand.items()}
        if len(cand["x"]) == 0:
            return _empty_table(fwhm or 0.0, noise, b)

    # Single-pixel spikes (hot pixels) are removed from the cutouts of a
    # frame whose stars are wide enough not to be spikes themselves.
    spike_fwhm = fwhm if fwhm is not None and fwhm >= _DESPIKE_MIN_FWHM else None
    if fwhm is not None:
        if spike_fwhm is not None:
            cand = _recentered(data, mask, coarse, b, fwhm, cache, noise, spike_fwhm)
        opts["spike_fwhm"] = spike_fwhm
        tab = _measure(data, mask, cand, fwhm, noise, b, opts)
        tab.meta["fwhm_source"] = "user"
    else:
        # Stage 2: the FWHM of the population of compact sources.
        # (Cached while the first 80 candidates, all `_estimate_fwhm` reads, are the same.)
        ident = np.column_stack([cand["x"], cand["y"], cand["bkg"]])[:80]
        old = (cache or {}).get("fwhm estimate")
        est = (old[1] if old is not None and np.array_equal(old[0], ident)
               else _estimate_fwhm(data, mask, cand, noise))
        if cache is not None:
            cache["fwhm estimate"] = (ident, est)
        plain = cand
        tab, cand = _measure_at_estimate(data, mask, coarse, plain, est, b, noise, opts, width)
        if est.from_gap and width is None and _inconsistency(tab) >= _CONSISTENT:
            # The sources do not share the width the larger cutouts found
            # (diffuse light, knots): the estimate without them.
            est = _estimate_fwhm(data, mask, plain, noise, gap=False)
            tab, cand = _measure_at_estimate(data, mask, coarse, plain, est, b, noise, opts)
        tab.meta["fwhm_source"] = "estimate"
        # (Without ``grow``, `_grown`'s probe: the list at the estimate only.)
        if grow and (not est.doubtful and not est.alternatives and len(coarse["x"]) >= n_cand
                     and _too_few(tab, cand, n_sources) and _inconsistency(tab) < _CONSISTENT):
            more = _grown(image, mask, n_sources, config, nsigma, cache, cand)
            if more is not None:
                return more
        if grow and (est.doubtful or _too_few(tab, cand, n_sources)):
            trials = []
            tab = _best_scale(data, mask, cand, noise, b, opts, tab,
                              est.alternatives + _SCALE_LADDER, trials)
            if len(coarse["x"]) >= n_cand and _inconsistency(tab) >= _ASTRAY:
                # No width explains the sources of the list kept (peaks that
                # are not stars took most candidates): the width that
                # explains its own, at more candidates.
                more = _grown(image, mask, n_sources, config, nsigma, cache, cand, trials, tab)
                if more is not None:
                    return more
        elif grow and est.alternatives:
            tab = _best_scale(data, mask, cand, noise, b, opts, tab, est.alternatives)
    # Every candidate was measured, and all could be kept: a detection for
    # more sources finds the same (registration does not detect again).
    tab.meta["all_candidates"] = len(cand["x"]) <= n_sources
    return tab


def _measure_at_estimate(data, mask, coarse, cand, est, b, noise, opts, width=None):
    """
    Stage 2's list: ``(table, candidates)`` measured at the estimate ``est``
    (or ``width``), the candidates recentred without single-pixel spikes
    when the estimate is sure and the stars wide enough not to be spikes.
    """
    spike_fwhm = None
    if not est.doubtful and est.fwhm >= _DESPIKE_MIN_FWHM:
        # (The estimate, a mode, stays: hot pixels by a few stars do not move it.)
        spike_fwhm = est.fwhm
        cand = _recentered(data, mask, coarse, b, None, opts["cache"], noise, spike_fwhm)
    opts["spike_fwhm"] = spike_fwhm
    return _measure(data, mask, cand, est.fwhm if width is None else width, noise, b, opts), cand


def _grown(image, mask, n_sources, config, nsigma, cache, cand, trials=None, best=None):
    """
    The ``n_sources`` brightest of a detection for ``_GROWTH`` times as
    many at the same (estimated) width, or None when that one too keeps
    too few of ``cand``, the candidates of the detection for ``n_sources``.

    For a list whose sources measure the width they were found at (the
    width is right) yet are too few of the candidates: most of the
    brightest peaks were not stars (a bright band, the step at the edge
    of a resampled frame), and the stars are among the fainter peaks,
    which other widths (the scale ladder) would not find.

    With the scale search's ``trials`` and the list it kept, ``best`` (no
    width explained it): at the width of the trials' most strong sources
    among those whose sources measure it themselves, kept only when that
    detection is consistent too and has more strong sources than ``best``.
    """
    width = None
    if trials is not None:
        strong = [int(np.sum(np.asarray(t["snr"]) >= 10.0)) if len(t) else 0 for t in trials]
        fits = [i for i, t in enumerate(trials) if _inconsistency(t) < _CONSISTENT and strong[i]]
        if not fits:
            return None
        width = trials[max(fits, key=lambda i: (strong[i], -i))].meta["fwhm"]
    more = _detect(image, mask, _GROWTH * n_sources, config, nsigma, cache, grow=False,
                   width=width)
    if _too_few(more, cand, n_sources):
        return None
    table = more[:n_sources]
    # (All its candidates measured, and fewer sources than asked for.)
    table.meta["all_candidates"] = bool(more.meta["all_candidates"] and len(more) < n_sources)
    if trials is not None:
        if (_inconsistency(table) >= _CONSISTENT or np.sum(np.asarray(table["snr"]) >= 10.0)
                <= np.sum(np.asarray(best["snr"]) >= 10.0)):
            return None
        table.meta["fwhm_source"] = "scale search"
    return table


def _stage1(data, mask, bin_factor, nsigma):
    """
    The full-frame passes of `_detect`, the same for any number of sources:
    the noise, its correlation factor, the binning and the binned residual
    whose peaks are the candidates (with the frame's bright lines, when
    its rows or columns stand out).  ``residual`` is None when the noise
    cannot be measured.
    """
    noise = estimate_noise(data, mask)
    if not np.isfinite(noise) or noise <= 0:
        return {"noise": noise, "b": 1, "residual": None}
    # Correlated noise (resampled frames): the matched filter's S/N is
    # judged against the noise it really sees.
    out = {"noise": noise, "noise_corr": _correlated_noise_factor(data, mask, noise)}
    b = _auto_bin(data.shape) if bin_factor is None else bin_factor
    b = out["b"] = min(b, max(1, min(data.shape) // 8))  # a few binned pixels across at least
    residual = _binned_residual(data, mask, b, noise, check_lines=True)
    if residual is None:
        # Bright or noisy rows or columns (an edge band, a bad column):
        # their excess is subtracted and candidates on them are judged
        # against their own noise (`lines`).
        lines = out["lines"] = line_background(data, mask, noise)
        if lines is not None:
            data = lines.subtract(data)
        residual = _binned_residual(data, mask, b, noise, lines=lines)
    out["residual"] = residual
    return out


def _per_candidate(cache, key, ident, compute):
    """
    ``compute(rows)``, a dict of per-candidate arrays for the candidates
    ``rows`` (a slice), over every candidate, from ``cache`` for those an
    earlier call with the same ``key`` computed.

    ``ident`` (one row per candidate) identifies the candidates: the cached
    rows serve when they are the first rows of ``ident`` (a detection of
    more sources has the candidates of one of fewer first, `_binned_peaks`),
    or ``ident`` is their first rows.  Each candidate's values depend on it
    alone, so that they are the values a call without the cache computes.
    """
    n = len(ident)
    old = None if cache is None else cache.get(key)
    if old is not None:
        m = len(old["ident"])
        if m >= n and np.array_equal(old["ident"][:n], ident):
            return {k: v[:n] for k, v in old["rows"].items()}
        if m < n and np.array_equal(old["ident"], ident[:m]):
            new = compute(slice(m, n))
            rows = {k: np.concatenate([old["rows"][k], new[k]]) for k in new}
            cache[key] = {"ident": ident, "rows": rows}
            return rows
    rows = compute(slice(0, n))
    if cache is not None:
        cache[key] = {"ident": ident, "rows": rows}
    return rows


def _recentered(data, mask, coarse, b, fwhm, cache, noise=None, spike_fwhm=None):
    """`_recenter` of the coarse candidates (each one's position depends on it alone)."""
    ident = np.column_stack([coarse["x"], coarse["y"], coarse["bkg"]])

    def compute(rows):
        out = _recenter(data, mask, {k: v[rows] for k, v in coarse.items()}, b, fwhm, noise,
                        spike_fwhm)
        return {"x": out["x"], "y": out["y"]}

    pos = _per_candidate(cache, ("recenter", fwhm, spike_fwhm), ident, compute)
    return {**coarse, "x": pos["x"], "y": pos["y"]}


def _too_few(tab, cand, n_sources):
    """Did the measurement keep too few of the candidates to be trusted?"""
    wanted = min(n_sources, len(cand["x"]))
    return len(tab) < max(3, min(12, wanted // 2)) or len(tab) < 0.2 * wanted


#: A list whose sources' own median FWHM is within this (natural log) of
#: the FWHM used measured them at the right width (`_inconsistency`).
_CONSISTENT = 0.2

#: A list whose sources' own median FWHM is this far (natural log) or
#: further from the FWHM used was not measured at the stars' width.
_ASTRAY = 0.5

#: Times the sources a detection left with too few stars by its candidates
#: that were not stars tries again for, at the same width (`_detect`).
_GROWTH = 4

#: FWHMs (pixels) tried when the estimate is doubtful.
_SCALE_LADDER = (1.6, 2.5, 4.0, 6.5, 10.0)


def _best_scale(data, mask, cand, noise, b, opts, first, alternatives=(), trials_out=None):
    """
    Stage 2b: try other widths (a ladder when the estimate is doubtful, or
    the wide population's width on a digitised plate).

    Each trial FWHM gives a list of sources; a list is *consistent* when
    the median FWHM its sources measure on their own agrees with the trial
    value.  Among the lists with nearly the most strong sources, the most
    consistent wins; the first attempt is kept on ties.  ``trials_out``
    (a list) receives every trial's list.
    """
    trials = [] if trials_out is None else trials_out
    trials.append(first)
    for f in alternatives:
        if any(abs(np.log(f / t.meta["fwhm"])) < 0.15 for t in trials):
            continue
        trials.append(_measure(data, mask, cand, f, noise, b, opts))
    # Only strong sources count: at a wrong (small) scale, noise peaks of a
    # resampled or compressed frame pass a low threshold in numbers.
    strong = [int(np.sum(np.asarray(t["snr"]) >= 10.0)) if len(t) else 0 for t in trials]
    top = max(strong)
    if top == 0:
        return first
    # Among the lists with nearly the most strong sources, the one whose
    # sources' own FWHMs agree best with the FWHM used.
    near = [i for i, n in enumerate(strong) if n >= 0.8 * top]
    best = trials[min(near, key=lambda i: (_inconsistency(trials[i]), i))]
    best.meta["fwhm_source"] = "scale search" if best is not first else "estimate"
    return best


def _inconsistency(tab):
    """|log(own FWHM / FWHM used)| of a list (infinite when unknown)."""
    own = tab.meta.get("own_fwhm_median", np.nan)
    if not np.isfinite(own) or own <= 0:
        return np.inf
    return abs(np.log(own / tab.meta["fwhm"]))


_DAO_COLUMNS = ("x_centroid", "y_centroid", "flux", "peak", "sharpness", "roundness1",
                "roundness2")


def _daofind(finder, data, mask):
    """
    ``finder(data, mask=mask)`` as a dict of float arrays (None if empty).

    The same measurements and filters as calling the finder, read straight
    from its catalog: `~photutils.detection.DAOStarFinder` builds its output
    table with metadata that imports matplotlib, scikit-image and more on
    first use (a tenth of a second in a fresh process) and costs a table per
    call.  Given positions (``xycoords``), the convolved image is computed
    only where the catalog reads it (`_convolved_near`), not over the
    whole mosaic.  Falls back to the public call if photutils' internals
    change.
    """
    if hasattr(finder, "_get_raw_catalog"):
        try:
            xy = getattr(finder, "xycoords", None)
            try:
                from photutils.detection.daofinder import _DAOStarFinderCatalog
            except ImportError:  # another photutils: its own convolution
                xy = None
            if xy is None or len(xy) == 0:
                cat = finder._get_raw_catalog(data, mask=mask)
            else:
                k = finder.kernel
                cat = _DAOStarFinderCatalog(
                    data, _convolved_near(data, k.data, np.asarray(xy)), xy, finder.threshold,
                    k, sharpness_range=finder.sharpness_range,
                    roundness_range=finder.roundness_range, n_brightest=finder.n_brightest,
                    peak_max=finder.peak_max, scale_threshold=finder.scale_threshold)
            if cat is not None:
                cat = cat.apply_all_filters()
            if cat is None:
                return None
            return {c: np.asarray(getattr(cat, c), float) for c in _DAO_COLUMNS}
        except (AttributeError, TypeError, ValueError):  # internals changed: the public call
            pass
    tab = finder(data, mask=mask)
    if tab is None:
        return None
    return {c: np.asarray(tab[c], float) for c in _DAO_COLUMNS}


def _convolved_near(data, kernel, xy):
    """
    ``scipy.ndimage.convolve(data, kernel, mode='constant', cval=0)`` (what
    DAOStarFinder convolves with) in a kernel-sized window around each
    integer position ``xy`` (x, y), zero elsewhere.

    DAOStarFinder given positions reads the convolved image only there
    (the centre's value and its neighbours for the roundness), and the
    mosaic of cutouts is mostly pixels it never reads.  Each value is
    summed as `scipy.ndimage.correlate` sums it (the flipped kernel's
    weights above DBL_EPSILON, in raster order, in float64), so that the
    values are the same, bit for bit.
    """
    ky, kx = kernel.shape
    ry, rx = ky // 2, kx // 2
    w = np.asarray(kernel, float)[::-1, ::-1]  # convolution: the flipped kernel correlated
    # Zeros beyond the frame (mode 'constant'), so that every window fits.
    pad = np.zeros((data.shape[0] + 4 * ry, data.shape[1] + 4 * rx))
    pad[2 * ry:2 * ry + data.shape[0], 2 * rx:2 * rx + data.shape[1]] = data
    x = np.asarray(xy[:, 0], int)
    y = np.asarray(xy[:, 1], int)
    # Data around each output window: (n, ky + 2 ry, kx + 2 rx), output centre at its middle.
    win = np.lib.stride_tricks.sliding_window_view(pad, (ky + 2 * ry, kx + 2 * rx))[y, x]
    # The positions last (contiguous): each step is one long vector operation.
    win = np.ascontiguousarray(win.transpose(1, 2, 0))
    acc = np.zeros((ky, kx, len(x)))
    tmp = np.empty_like(acc)
    eps = np.finfo(float).eps
    for dy in range(ky):
        for dx in range(kx):
            if abs(w[dy, dx]) > eps:
                np.multiply(win[dy:dy + ky, dx:dx + kx], w[dy, dx], out=tmp)
                acc += tmp
    acc = acc.transpose(2, 0, 1)
    out = np.zeros(data.shape)
    # Window pixels inside the frame (positions near its edge lose some).
    oy = y[:, None] + np.arange(-ry, ry + 1)[None, :]
    ox = x[:, None] + np.arange(-rx, rx + 1)[None, :]
    iny, inx = (oy >= 0) & (oy < data.shape[0]), (ox >= 0) & (ox < data.shape[1])
    if iny.all() and inx.all():  # (the tiles' centres: always) every window whole
        out[oy[:, :, None], ox[:, None, :]] = acc  # (in the same order: the last write wins)
        return out
    k, iy, ix = np.nonzero(iny[:, :, None] & inx[:, None, :])
    out[oy[k, iy], ox[k, ix]] = acc[k, iy, ix]
    return out


#: DAOStarFinder's roundness limits by default (those of `find_sources`).
_DEFAULT_ROUNDNESS = (-1.0, 1.0)


def _measure(data, mask, cand, fwhm, noise, b, opts):
    """
    Stage 3 (`_measure_at`), with a second look for trailed stars.

    Trailed or elongated stars (tracking errors, wind, field rotation) have
    DAOStarFinder roundness beyond the default limits of +-1 and are all
    dropped, leaving a handful of sources, or noise peaks in their place.
    When the default limits keep too few of the candidates, the candidates
    are measured again without them; that list is used if its strong
    sources are an elongated population (median roundness above 0.5, where
    round stars give 0.1 to 0.2) and outnumber the first list's.  The
    population's own limits (`_population_inliers`) then judge each
    source, so that cosmic rays, which are not trailed like the stars, are
    still dropped.
    """
    if opts.get("cache") is None:  # (the second look reuses the first's rows)
        opts = {**opts, "cache": {}}
    tab = _measure_at(data, mask, cand, fwhm, noise, b, opts)
    if (opts["roundness_range"] is None
            or tuple(opts["roundness_range"]) != _DEFAULT_ROUNDNESS
            or not _too_few(tab, cand, opts["n_sources"])):
        return tab
    trailed = _measure_at(data, mask, cand, fwhm, noise, b, {**opts, "roundness_range": None})
    strong = np.asarray(trailed["snr"]) >= 10.0
    if strong.sum() < 3:
        return tab
    r = np.maximum(np.abs(trailed["roundness1"]), np.abs(trailed["roundness2"]))[strong]
    if np.median(r) > 0.5 and strong.sum() > np.sum(np.asarray(tab["snr"]) >= 10.0):
        trailed.meta["trailed"] = True
        return trailed
    return tab


def _measure_at(data, mask, cand, fwhm, noise, b, opts):
    """
    Stage 3: measure the candidates with DAOStarFinder at a given FWHM.

    Full-resolution cutouts around the candidates, less their local sky,
    are measured as one mosaic (`_dao_on_mosaic`); the brightest detection
    near each tile's centre is kept (`_brightest_per_tile`), its centroid
    refined (`_refined_positions`), and hot pixels, cosmic rays and faint
    or duplicate sources dropped (`_filtered_table`).  Wide stars are
    measured on a binned copy (as well, at a fraction of the cost: the
    mosaic of cutouts grows with the FWHM squared).

    Each candidate is measured on its own (`_measure_rows`), and once per
    width with ``opts['cache']``: a later detection of more sources
    measures only the candidates it adds (`_per_candidate`).  Saturation
    plateaus are found at the tiles' common largest value, which the rows
    are measured for (it is part of their key).
    """
    if fwhm > _MAX_FULL_RES_FWHM:
        k = int(fwhm // (_MAX_FULL_RES_FWHM / 2))
        return _find_on_binned(data, mask, k, fwhm / k, opts)
    half = int(np.ceil(max(3.0 * fwhm, 6)))
    cache = opts.get("cache")
    ident = np.column_stack([cand["x"], cand["y"]])

    cutouts = {}  # (first row, last row) -> tiles: cut once for both steps

    def tiles(rows):
        if (rows.start, rows.stop) not in cutouts:
            xc, yc = _tile_centres(data, cand, rows)
            cutouts[rows.start, rows.stop] = _extract_cutouts(data, mask, xc, yc, half, 0.0)
        return cutouts[rows.start, rows.stop]

    def tile_peaks(rows):
        cut, bad = tiles(rows)
        good = ~bad
        top = np.where(good, cut, -np.inf).max(axis=(1, 2))
        return {"top": top, "n_top": (good & (cut >= top[:, None, None])).sum(axis=(1, 2))}

    # The tiles' largest value is a saturation level when enough pixels
    # share it (over every tile: a plateau of 3 x 3 or more, `_MIN_PLATEAU`).
    peaks = _per_candidate(cache, ("tile peaks", half), ident, tile_peaks)
    level = None
    if np.isfinite(peaks["top"]).any():
        top = peaks["top"].max()
        if peaks["n_top"][peaks["top"] == top].sum() >= _MIN_PLATEAU:
            level = top
    # Measured without the roundness limits, which are DAOStarFinder's last
    # filter and are applied here: the second look for trailed stars
    # (`_measure`, no limits) reuses the rows.
    key = ("measure", fwhm, opts.get("spike_fwhm"), level)
    rows = _per_candidate(cache, key, ident, lambda r: _measure_rows(
        data, {k: v[r] for k, v in cand.items()}, tiles(r), fwhm, noise,
        {**opts, "roundness_range": None}, half, level))
    rr = opts["roundness_range"]
    if rr is not None:
        with np.errstate(invalid="ignore"):  # (NaN: not found anyway)
            rows = {**rows, "found": rows["found"] & np.all(
                [(rows[c] >= rr[0]) & (rows[c] <= rr[1]) for c in ("roundness1", "roundness2")],
                axis=0)}
    return _filtered_table(rows, fwhm, noise, b, opts)


def _tile_centres(data, cand, rows=slice(None)):
    """The candidates' integer pixels (the centres of their tiles)."""
    xc = np.clip(np.round(cand["x"][rows]).astype(int), 0, data.shape[1] - 1)
    yc = np.clip(np.round(cand["y"][rows]).astype(int), 0, data.shape[0] - 1)
    return xc, yc


#: The per-candidate measurements of `_measure_rows`.
_ROW_COLUMNS = ("x", "y", "flux", "position_error", "snr", "peak", "sharpness", "roundness1",
                "roundness2", "own_fwhm")


def _measure_rows(data, cand, tiles, fwhm, noise, opts, half, level):
    """
    Each candidate's measurement at ``fwhm`` (`_measure_at` before the
    population's filters): ``found`` (False for a tile DAOStarFinder finds
    nothing near the centre of), the position, aperture flux and error,
    signal-to-noise, DAOStarFinder's shape figures and the source's own
    FWHM (NaN where not found).  ``level``: the saturation level of the
    tiles (None for none).  Each row depends on its candidate alone.
    """
    n = len(cand["x"])
    out = {c: np.full(n, np.nan) for c in _ROW_COLUMNS}
    out["found"] = np.zeros(n, bool)
    xc, yc = _tile_centres(data, cand)
    cut, bad = tiles  # (`_extract_cutouts` of the candidates, ``half`` pixels around)
    sat = None if level is None else (~bad & (cut >= level))
    # Local sky from the tile's outskirts (beyond 2 FWHM): the coarse map
    # of stage 1 is only good to a fraction of the noise, and any pedestal
    # biases fluxes and pulls centroids towards the tile centre.
    cut = cut - _local_background(cut, bad, min(2.0 * fwhm, half - 1.0))[:, None, None]
    cut[bad] = 0.0
    if opts.get("spike_fwhm") is not None:  # hot pixels in a tile pull its centroid and width
        cut = _despike(cut, bad, noise, min(fwhm, opts["spike_fwhm"]))
    tab, ncol = _dao_on_mosaic(cut, bad, cand, xc, yc, half, fwhm, noise, opts)
    if tab is None or len(tab["flux"]) == 0:
        return out
    sel, kk, lx, ly = _brightest_per_tile(tab, n, ncol, half, fwhm)
    if sel.size == 0:
        return out
    cut, bad = cut[kk], bad[kk]
    xs, ys = _refined_positions(cut, bad, lx[sel], ly[sel], fwhm, opts)
    noise_factor = None
    lines = opts.get("lines")
    if lines is not None:  # each tile pixel's noise, in units of the frame's
        offs = np.arange(-half, half + 1)
        noise_factor = lines.factor((yc[kk, None] + offs)[:, :, None],
                                    (xc[kk, None] + offs)[:, None, :])
    plateau_error = np.full(len(xs), np.nan)
    if sat is not None and opts["refine_centroids"]:
        xs, ys, plateau_error = _plateau_centroids(sat[kk], bad, xs, ys, fwhm)
    aflux, perr, snr = _aperture_flux_and_error(cut, bad, xs, ys, fwhm, noise, noise_factor)
    # A saturated star's (clipped) flux says nothing of its centroid: its plateau does.
    perr = np.where(np.isfinite(plateau_error), np.hypot(plateau_error, 0.005), perr)
    out["found"][kk] = True
    out["x"][kk], out["y"][kk] = xc[kk] - half + xs, yc[kk] - half + ys
    out["flux"][kk], out["position_error"][kk] = aflux, perr
    out["snr"][kk] = snr / opts.get("noise_corr", 1.0)
    for c in ("peak", "sharpness", "roundness1", "roundness2"):
        out[c][kk] = np.asarray(tab[c], float)[sel]
    # Hot pixels and cosmic rays that got this far (a bright hit can pass
    # DAOFIND's sharpness limit) are much narrower than the stars.
    out["own_fwhm"][kk] = _adaptive_fwhm(cut, bad, xs - half, ys - half,
                                         sigma0=fwhm / _GAUSS_SIGMA_TO_FWHM, n_iter=4)
    return out


def _dao_on_mosaic(cut, bad, cand, xc, yc, half, fwhm, noise, opts):
    """
    DAOStarFinder's measurements of the cutouts tiled into one mosaic.

    Returns the measurements (a dict of arrays, or None) and the number of
    tiles per mosaic row.
    """
    tile = 2 * half + 1
    n = len(cand["x"])
    ncol = int(np.ceil(np.sqrt(n)))
    nrow = int(np.ceil(n / ncol))
    # (n, tile, tile) -> (nrow*tile, ncol*tile) without a Python loop: each
    # tile written once into its place (the spare tiles empty and masked).
    kk = np.arange(n)
    mosaic = np.zeros((nrow, tile, ncol, tile))
    mosaic.transpose(0, 2, 1, 3)[kk // ncol, kk % ncol] = cut
    mosaic = mosaic.reshape(nrow * tile, ncol * tile)
    mmask = np.ones((nrow, tile, ncol, tile), dtype=bool)
    mmask.transpose(0, 2, 1, 3)[kk // ncol, kk % ncol] = bad
    mmask = mmask.reshape(nrow * tile, ncol * tile)
    # Tile centres are given as xycoords, so DAOStarFinder skips its peak
    # search and only measures centroid, sharpness and roundness.
    centers = np.empty((n, 2))
    centers[:, 0] = (kk % ncol) * tile + half + (cand["x"] - xc)
    centers[:, 1] = (kk // ncol) * tile + half + (cand["y"] - yc)
    # Imported here: photutils' import is the largest part of a fresh
    # process's first call, and a bare ``import astroalign_nd.detection``
    # (or a catalog-only run) does not need it.
    from photutils.detection import DAOStarFinder

    finder = DAOStarFinder(
        threshold=opts["nsigma"] * noise,
        fwhm=fwhm,
        sharpness_range=opts["sharpness_range"],
        roundness_range=opts["roundness_range"],
        peak_max=opts["peak_max"],
        exclude_border=False,
        xycoords=np.round(centers),
    )
    # NumPy's error state, unlike the warning filters, is per thread: empty
    # tiles divide by zero in photutils' measures whatever thread this is.
    with warnings.catch_warnings(), np.errstate(divide="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", AstropyWarning)
        return _daofind(finder, mosaic, mmask if mmask.any() else None), ncol


def _brightest_per_tile(tab, n, ncol, half, fwhm):
    """
    Per tile, the brightest detection near the candidate's centre.

    Returns the indices of the kept detections, their tiles, and every
    detection's position in its tile.
    """
    tile = 2 * half + 1
    nrow = int(np.ceil(n / ncol))
    tx = np.asarray(tab["x_centroid"], float)
    ty = np.asarray(tab["y_centroid"], float)
    col = np.clip((tx // tile).astype(int), 0, ncol - 1)
    row = np.clip((ty // tile).astype(int), 0, nrow - 1)
    k = row * ncol + col
    lx = tx - col * tile
    ly = ty - row * tile
    near = (np.hypot(lx - half, ly - half) <= 0.5 * fwhm + 1.5) & (k < n)
    flux = np.asarray(tab["flux"], float)
    sel = np.flatnonzero(near)
    if sel.size == 0:
        return sel, sel, lx, ly
    # Sort by tile then by flux descending; take the first per tile.
    order = np.lexsort((-flux[sel], k[sel]))
    sel = sel[order]
    _, first = np.unique(k[sel], return_index=True)
    sel = sel[first]
    return sel, k[sel], lx, ly


def _refined_positions(cut, bad, x0, y0, fwhm, opts):
    """Gaussian-windowed centroids of the stars in their tiles (DAOFIND's if not refined)."""
    if not opts["refine_centroids"]:
        return x0, y0
    # On undersampled stars a window as narrow as the star follows the
    # pixel grid (pixel-phase bias), and hot pixels and noise pull it:
    # a wider one measures them better.  Well-sampled stars keep the
    # matched window, the most precise.
    win = fwhm if fwhm >= _UNDERSAMPLED_FWHM else _MIN_WINDOW_FWHM
    sigma = np.full(len(x0), win / _GAUSS_SIGMA_TO_FWHM)
    xs, ys = _windowed_centroid(cut, bad, x0, y0, sigma)
    # A star cut by the frame's edge or a mask is pulled towards its good
    # side: refine those from their mirror images.
    cut_off = _lost_window_fraction(bad, xs, ys, sigma) > _LOST_WINDOW
    if cut_off.any():
        xs[cut_off], ys[cut_off] = _mirrored_windowed_centroid(
            cut[cut_off], bad[cut_off], xs[cut_off], ys[cut_off], sigma[cut_off])
    # A refinement that wandered away means a blend: keep DAOFIND's.
    moved = np.hypot(xs - x0, ys - y0) > 0.5 * fwhm
    return np.where(moved, x0, xs), np.where(moved, y0, ys)


def _filtered_table(rows, fwhm, noise, b, opts):
    """
    The output table from the candidates' `_measure_rows`: without hot
    pixels, cosmic rays, faint sources and duplicates, brightest first.
    """
    found = np.flatnonzero(rows["found"])
    if found.size == 0:
        return _empty_table(fwhm, noise, b)
    m = {c: rows[c][found] for c in _ROW_COLUMNS}
    gx, gy, aflux, snr, own_fwhm = m["x"], m["y"], m["flux"], m["snr"], m["own_fwhm"]
    real = ~(own_fwhm < 0.6 * fwhm) if fwhm >= 1.5 else np.ones(len(gx), bool)
    sharp, round1, round2 = m["sharpness"], m["roundness1"], m["roundness2"]
    # Given positions, DAOStarFinder does not apply its threshold: apply
    # it as a matched-filter signal-to-noise.
    real &= snr >= opts["nsigma"]
    real &= _population_inliers(sharp, round1, round2, real)

    # The same star can sit in two overlapping candidate tiles.
    keep = _dedupe(gx, gy, np.where(real, aflux, -np.inf), max(1.0, 0.5 * fwhm))
    keep = keep[real[keep]]
    cols = {c: m[c][keep] for c in _ROW_COLUMNS if c != "own_fwhm"}
    order = np.argsort(-cols["flux"], kind="stable")[:opts["n_sources"]]
    out = _Rows({k: v[order] for k, v in cols.items()})
    # The sources' own widths, from the strong ones when there are enough:
    # faint ones are often noise peaks, as wide as the noise's correlation.
    own = own_fwhm[keep][order]
    strong = cols["snr"][order] >= 10.0
    if strong.sum() >= 3:
        own = own[strong]
    own = own[np.isfinite(own)]
    out.meta.update(fwhm=float(fwhm), noise=float(noise), bin_factor=int(b),
                    own_fwhm_median=float(_median(own)) if own.size else float("nan"))
    return out


#: Saturated pixels (at the tiles' largest value) that make a plateau
#: whose centroid replaces the windowed one (a 3x3 block and more).
_MIN_PLATEAU = 9


#: A windowed centroid this many plateau errors from the plateau's is replaced.
_PLATEAU_K = 2.0


def _plateau_centroids(sat, bad, x0, y0, fwhm):
    """
    Centroids of saturated stars from their plateaus, with their errors.

    A saturated star is flat-topped: a Gaussian window as narrow as the
    PSF has no restoring force on a plateau wider than itself and stops
    near where it started, up to a pixel or more from the centre (8-bit
    frames, where every star saturates).  The plateau of a symmetric star
    is symmetric about its centre: the mean of its pixels measures the
    centre to the quantisation of its boundary.  Where the plateau meets
    the frame's edge or a mask, only the pixels whose mirror image through
    the centre is valid count (iterated), and the error grows with the
    part lost.  A plateau that reaches the tile's border, or whose centre
    lies more than half its radius plus half a FWHM from the windowed one
    (two stars' plateaus merged), keeps the windowed centroid.

    Returns
    -------
    x, y : (n,) ndarray
        Positions in the tiles.
    error : (n,) ndarray
        The plateau centroid's 1-sigma error per axis (NaN where the
        windowed centroid is kept).
    """
    from scipy import ndimage

    n, size, _ = sat.shape
    xs, ys, err = np.array(x0, float), np.array(y0, float), np.full(n, np.nan)
    tiles = np.flatnonzero(sat.sum(axis=(1, 2)) >= _MIN_PLATEAU)
    if tiles.size == 0:
        return xs, ys, err
    # Every tile at once: a 3-D stack whose structure joins no two tiles.
    cross = np.zeros((3, 3, 3), bool)
    cross[1] = ndimage.generate_binary_structure(2, 1)
    lab, n_lab = ndimage.label(sat[tiles], structure=cross)
    ix, iy = (np.clip(np.rint(v[tiles]), 0, size - 1).astype(int) for v in (x0, y0))
    own = lab[np.arange(tiles.size), iy, ix]  # the plateau under each windowed centroid
    count = np.bincount(lab.ravel(), minlength=n_lab + 1)
    rim = np.zeros(n_lab + 1, bool)
    rim[np.concatenate([lab[:, [0, -1], :].ravel(), lab[:, :, [0, -1]].ravel()])] = True
    ok = (own > 0) & (count[own] >= _MIN_PLATEAU) & ~rim[own]
    if not ok.any():
        return xs, ys, err
    tiles, own = tiles[ok], own[ok]
    reg = lab[ok] == own[:, None, None]
    which, yy, xx = np.nonzero(reg)
    n_pix = count[own]
    # (Sums of integer coordinates are exact: these are the pixels' means.)
    cx = np.bincount(which, weights=xx, minlength=tiles.size) / n_pix
    cy = np.bincount(which, weights=yy, minlength=tiles.size) / n_pix
    edge = reg & ~ndimage.binary_erosion(reg, structure=cross)
    n_edge = edge.sum(axis=(1, 2)).astype(float)
    n_use = n_pix.astype(float)
    # Plateaus next to a masked pixel or the frame's edge: mirrored support.
    near_bad = (ndimage.binary_dilation(reg, structure=cross) & bad[tiles]).any(axis=(1, 2))
    for i in np.flatnonzero(near_bad):
        k = tiles[i]
        py, px = np.nonzero(reg[i])
        cx[i], cy[i], use = _mirrored_support(px, py, ~bad[k], cx[i], cy[i])
        n_use[i] = use.sum()
        n_edge[i] = edge[i][py[use], px[use]].sum()
    radius = np.sqrt(n_pix / np.pi)
    dist = np.hypot(cx - x0[tiles], cy - y0[tiles])
    keep = (n_use >= _MIN_PLATEAU) & (dist <= 0.5 * (radius + fwhm))
    # Each boundary pixel is in or out by the noise: variance ~1/4 each,
    # at a distance ~radius, over the plateau's pixel count.
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.sqrt(n_edge / 8.0) * radius / n_use
        e = np.hypot(e, (1.0 - n_use / n_pix) * radius)
    tiles, cx, cy, e, dist = tiles[keep], cx[keep], cy[keep], e[keep], dist[keep]
    err[tiles] = e
    # A windowed centroid that agrees with the plateau's within its error
    # is kept (sharp, clean wings measure the centre better than the
    # pixel grid of the plateau); one that disagrees stopped on the flat top.
    moved = dist > _PLATEAU_K * e
    xs[tiles[moved]], ys[tiles[moved]] = cx[moved], cy[moved]
    return xs, ys, err


def _mirrored_support(xx, yy, valid, cx, cy, n_iter=5):
    """
    Centroid of the plateau pixels ``(xx, yy)`` whose mirror image through
    the centroid is a valid pixel, iterated from ``(cx, cy)``; with the
    pixels used.
    """
    size = valid.shape[0]
    use = np.ones(len(xx), bool)
    for _ in range(n_iter):
        mx, my = np.rint(2 * cx - xx).astype(int), np.rint(2 * cy - yy).astype(int)
        inside = (mx >= 0) & (mx < size) & (my >= 0) & (my < size)
        use = inside.copy()
        use[inside] = valid[my[inside], mx[inside]]
        if use.sum() < _MIN_PLATEAU:
            break
        cx, cy = xx[use].mean(), yy[use].mean()
    return cx, cy, use


def _aperture_flux_and_error(cut, bad, xs, ys, fwhm, noise, factor=None):
    """
    Aperture flux (radius 1.5 FWHM), expected centroid error and
    matched-filter signal-to-noise.

    The error is the background-limited centroid precision of a Gaussian
    star, ``sqrt(8 pi) sigma_psf^2 sigma_noise / flux`` per axis, with a
    0.005 px floor; it is used to weight stars in the final fit.
    ``factor`` (tiles' shape, optional) is each pixel's noise in units of
    ``noise`` (a band's, a bad column's).
    """
    n, size, _ = cut.shape
    g = np.arange(size, dtype=float)
    r = 1.5 * fwhm
    d2 = (g[None, :, None] - ys[:, None, None]) ** 2 + (g[None, None, :] - xs[:, None, None]) ** 2
    ap = (d2 <= r * r) & ~bad
    flux = np.where(ap, cut, 0.0).sum(axis=(1, 2))
    sig_psf = fwhm / _GAUSS_SIGMA_TO_FWHM
    # Matched-filter signal-to-noise: the PSF-weighted sum over its noise.
    w = np.where(bad, 0.0, np.exp(-0.5 * d2 / sig_psf**2))
    if factor is not None:
        # The noise seen through the PSF window, per star.
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.sqrt((w * w * factor**2).sum(axis=(1, 2)) / (w * w).sum(axis=(1, 2)))
        noise = noise * np.where(np.isfinite(f), np.maximum(f, 1.0), 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = (w * cut).sum(axis=(1, 2)) / (noise * np.sqrt((w * w).sum(axis=(1, 2))))
    snr = np.where(np.isfinite(snr), snr, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.sqrt(8 * np.pi) * sig_psf**2 * noise / np.where(flux > 0, flux, np.nan)
    err = np.where(np.isfinite(err), err, 10.0 * fwhm)
    return flux, np.hypot(err, 0.005), snr


#: Stars narrower than this (FWHM, pixels) count as undersampled ...
_UNDERSAMPLED_FWHM = 2.5

#: ... and get a centroid window of this FWHM (pixels).
_MIN_WINDOW_FWHM = 4.0

#: A star whose centroid window loses more than this fraction of its
#: weight to bad pixels (an edge, a mask) is refined from its mirror image.
_LOST_WINDOW = 0.01


def _find_on_binned(data, mask, k, fwhm, opts):
    """find_sources on a k x k mean-binned copy, in full-resolution pixels."""
    binned, bmask = _bin_mean(data, mask, k)
    tab = find_sources(binned, mask=bmask, fwhm=fwhm,
                       **{k: v for k, v in opts.items()
                          if k not in ("lines", "noise_corr", "spike_fwhm", "cache")})
    tab["x"] = tab["x"] * k + (k - 1) / 2.0
    tab["y"] = tab["y"] * k + (k - 1) / 2.0
    tab["position_error"] = tab["position_error"] * k
    tab.meta["fwhm"] = tab.meta["fwhm"] * k
    tab.meta["own_fwhm_median"] = tab.meta.get("own_fwhm_median", np.nan) * k
    tab.meta["noise"] = estimate_noise(data, mask)
    tab.meta["bin_factor"] = tab.meta["bin_factor"] * k
    tab.meta["measured_on_binned"] = k
    return tab


def _population_inliers(sharp, round1, round2, ok):
    """
    Reject sources whose shape is unlike the rest of the population.

    Stars of one image share their sharpness and roundness; hot pixels are
    sharper, cosmic-ray tracks less round (more elongated).  Limits relative
    to the median adapt to the image, where fixed ones cannot.
    """
    keep = np.ones(len(sharp), bool)
    if ok.sum() < 5:
        return keep
    s = sharp[ok]
    med = _median(s)  # np.median's values, without its overhead
    mad = 1.4826 * _median(np.abs(s - med))
    keep &= sharp <= med + max(0.15, 5.0 * mad)
    # A star's centre is brighter than its surroundings (sharpness > 0, also
    # for a saturated plateau); cosmic-ray tracks off the tile centre are not.
    keep &= sharp >= min(0.0, med - 0.3)
    r = np.maximum(np.abs(round1), np.abs(round2))
    keep &= r <= max(0.35, 4.0 * _median(r[ok]))
    return keep


def _dedupe(x, y, flux, radius):
    """Indices of the sources to keep: the brighter of any two closer than radius."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(np.column_stack([x, y])).query_pairs(radius, output_type="ndarray")
    drop = np.zeros(len(x), bool)
    if len(pairs):
        # Visit pairs brightest-first so that a dropped source cannot drop another.
        first = np.maximum(flux[pairs[:, 0]], flux[pairs[:, 1]])
        for i, j in pairs[np.argsort(-first, kind="stable")]:
            if drop[i] or drop[j]:
                continue
            drop[j if flux[i] >= flux[j] else i] = True
    return np.flatnonzero(~drop)


class _Rows(dict):
    """
    A measured list as NumPy columns (name -> array) with a ``meta`` dict,
    read like a `~astropy.table.Table` (a column by name, rows by a slice
    or an index array): detection's trials and registration's lists are
    these, and only what `find_sources` returns becomes a Table
    (`as_table`), astropy's costs paid once.
    """

    def __init__(self, columns, meta=None):
        super().__init__(columns)
        self.meta = {} if meta is None else dict(meta)

    def __getitem__(self, key):
        if isinstance(key, str):
            return dict.__getitem__(self, key)
        return _Rows({k: v[key] for k, v in self.items()}, self.meta)

    def __len__(self):
        return len(dict.__getitem__(self, "x"))

    @property
    def colnames(self):
        return list(self)

    @staticmethod
    def as_table(rows):
        """A detection's list (these or a Table) as the `~astropy.table.Table`
        `find_sources` returns."""
        if isinstance(rows, _Rows):
            return Table(dict(rows), meta=rows.meta, copy=False)
        return rows


def _empty_table(fwhm, noise, b):
    t = Table(names=["x", "y", "flux", "position_error", "snr", "peak", "sharpness",
                     "roundness1", "roundness2"], dtype=[float] * 9)
    t.meta.update(fwhm=float(fwhm), noise=float(noise), bin_factor=int(b))
    return t


# -- other finders -----------------------------------------------------------------------------

#: `find_sources`' options of the DAOStarFinder pipeline (not ``finder``'s).
_PIPELINE_DEFAULTS = {k: v for k, v in find_sources.__kwdefaults__.items()
                      if k not in ("mask", "n_sources", "finder")}


def _run_finder(finder, data, mask, n_sources, options):
    """`find_sources` with ``finder``: its table, brightest first, ``n_sources`` rows."""
    if not callable(finder):
        raise TypeError(f"finder must be a source finder (a SourceFinderBase, or a callable "
                        f"finder(data, mask=None) returning a Table); got {finder!r}.")
    changed = [k for k, v in options.items() if not _is_default(v, _PIPELINE_DEFAULTS[k])]
    if changed:
        raise TypeError(f"the option(s) {', '.join(changed)} of find_sources configure its "
                        f"DAOStarFinder pipeline, which finder={finder!r} replaces; set the "
                        "finder's own options instead.")
    table = _standard_table(finder(data, mask=mask), finder, n_sources)
    table.meta.setdefault("fwhm_source", "finder")
    return table


def _is_default(value, default):
    if value is None or default is None:
        return value is default
    try:
        return bool(np.array_equal(np.asarray(value, float), np.asarray(default, float)))
    except (TypeError, ValueError):  # a value that cannot be compared is not the default
        return False


class DAOSourceFinder(SourceFinderBase):
    """
    The DAOStarFinder pipeline of `~astroalign_nd.detection.find_sources`, as
    a finder.

    Its stages are the parts of the `~astroalign_nd.detection` subpackage:
    the noise (`~astroalign_nd.detection.estimate_noise`), candidate peaks
    on a binned copy less a coarse background, the FWHM estimate
    (`~astroalign_nd.detection.estimate_fwhm`), the measurement with
    `~photutils.detection.DAOStarFinder` and the windowed centroids.
    Calling the finder gives what ``find_sources(data, mask=mask,
    **options)`` gives.

    Parameters
    ----------
    **options
        Options of `~astroalign_nd.detection.find_sources` (``n_sources``,
        ``fwhm``, ``nsigma``, ``sharpness_range``, ``roundness_range``,
        ``peak_max``, ``bin_factor``, ``refine_centroids``), with its
        defaults; their values are checked when the finder is called.

    Attributes
    ----------
    options : dict
        The options given.

    Examples
    --------
    >>> from astroalign_nd.detection import DAOSourceFinder, find_sources
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> finder = DAOSourceFinder(n_sources=20, fwhm=3.0)
    >>> finder
    DAOSourceFinder(n_sources=20, fwhm=3.0)
    >>> found = finder(pair.source)
    >>> len(found), found.meta["fwhm_source"]
    (20, 'user')
    >>> bool((found["x"] == find_sources(pair.source, n_sources=20, fwhm=3.0)["x"]).all())
    True
    """

    def __init__(self, **options):
        unknown = sorted(set(options) - set(_PIPELINE_DEFAULTS) - {"n_sources"})
        if unknown:
            raise TypeError(f"unexpected option(s) {unknown}; DAOSourceFinder takes "
                            f"find_sources' options {['n_sources', *_PIPELINE_DEFAULTS]}.")
        self.options = dict(options)

    @property
    def nsigma(self):
        """The detection threshold, in noise units."""
        return self.options.get("nsigma", _PIPELINE_DEFAULTS["nsigma"])

    def __call__(self, data, mask=None):
        # find_sources checks and reads every input itself (and collects no
        # non-finite pixels: its stages skip them).
        return find_sources(data, mask=mask, **self.options)

    def find_stars(self, data, mask=None):
        """
        The sources of a checked image: ``find_sources(data, mask=mask, **options)``.

        Parameters
        ----------
        data : 2-D float ndarray
        mask : 2-D bool ndarray or None

        Returns
        -------
        sources : `~astropy.table.Table`
        """
        return find_sources(data, mask=mask, **self.options)

    def __repr__(self):
        return f"DAOSourceFinder({', '.join(f'{k}={v!r}' for k, v in self.options.items())})"


# -- the detection of registration ---------------------------------------------------------

#: The deep threshold (noise units) of registration's one detection pass, for
#: faint or sparse fields.
_DEEP_NSIGMA = 3.0

#: The confident threshold kept when enough sources pass it: `find_sources`' default.
_CONFIDENT_NSIGMA = find_sources.__kwdefaults__["nsigma"]

#: The centroid error (pixels per axis) of a finder's sources that come without one,
#: as the distortion fit assumes for unknown errors.
_UNKNOWN_POSITION_ERROR = 0.1


def control_sources(image, *, mask, n_sources, n_enough, config, cache=None, as_table=True):
    """
    The sources registration uses: the detection thresholds' one home.

    With ``config.nsigma`` given, one detection pass at it; without, one
    pass at ``_DEEP_NSIGMA``, of which only the sources at ``_CONFIDENT_NSIGMA``
    are kept when there are ``n_enough`` of them.

    Parameters
    ----------
    image, mask
        As in `find_sources`.
    n_sources : int
        Sources wanted (the brightest).
    n_enough : int
        Sources above the confident threshold that make the deep ones
        unnecessary.
    config : `~astroalign_nd.detection.DetectionConfig`
        The detection options, already checked.
    cache : dict, optional
        Kept by the caller between detections of one image with one
        ``config`` (start with an empty dict): a detection of more sources
        then reuses the work of the earlier ones (the full-frame passes,
        the FWHM estimate, every candidate's measurement) and measures only
        the candidates it adds.  The table is the one a detection without
        the cache gives.
    as_table : bool, optional
        False: the list as NumPy columns, read like the table (a column by
        name, ``meta``, rows by slices or index arrays), without the cost
        of an astropy Table (registration reads a few columns).

    Returns
    -------
    table : `~astropy.table.Table`
        As `find_sources` returns it.
    nsigma : float
        The threshold of the pass (for messages).

    Examples
    --------
    >>> from astroalign_nd.detection import DetectionConfig
    >>> from astroalign_nd.detection.daofind import control_sources
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> table, nsigma = control_sources(pair.source, mask=None, n_sources=40, n_enough=20,
    ...                                 config=DetectionConfig())
    >>> len(table), nsigma
    (40, 3.0)
    """
    nsigma = config.nsigma
    if config.finder is not None:
        # One pass of the finder, at its own threshold (the DAO thresholds do not apply).
        table = _detect(image, mask, convert("n_sources", Int(1, None), n_sources), config,
                        _CONFIDENT_NSIGMA if nsigma is None else nsigma)
        if "position_error" not in table.colnames:  # the final fit weighs every star alike
            table["position_error"] = np.full(len(table), _UNKNOWN_POSITION_ERROR)
        return table, float(table.meta.get("nsigma", getattr(config.finder, "nsigma", np.nan)))
    threshold = _DEEP_NSIGMA if nsigma is None else nsigma
    table = _detect(image, mask, convert("n_sources", Int(1, None), n_sources), config,
                    threshold, cache)
    table = keep_confident(table, n_enough, config)
    return (_Rows.as_table(table) if as_table else table), threshold


def keep_confident(table, n_enough, config, rows=False):
    """
    The sources of a `control_sources` table at the confident threshold
    (`find_sources`' default ``nsigma``) when there are ``n_enough`` of
    them; all of them otherwise, or when ``config`` sets the threshold or
    the finder.  With ``rows``, their row numbers instead (a table is not
    sliced).

    Registration applies it again to a detection made for more sources,
    so that each attempt's list is the one a detection for its count gives.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from astroalign_nd.config import DetectionConfig
    >>> from astroalign_nd.detection.daofind import keep_confident
    >>> table = Table({"snr": [40.0, 12.0, 4.0]})
    >>> config = DetectionConfig()
    >>> len(keep_confident(table, 2, config)), len(keep_confident(table, 3, config))
    (2, 3)
    """
    if config.nsigma is None and config.finder is None:
        strong = np.flatnonzero(np.asarray(table["snr"]) >= _CONFIDENT_NSIGMA)
        if len(strong) >= n_enough:
            return strong if rows else table[strong]
    return np.arange(len(table)) if rows else table
