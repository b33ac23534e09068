# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Stage 1 of the method: find the brightest point sources of an image.

Only the ~50 brightest stars are needed as control points, so full-frame
work is avoided (it dominates the cost of a naive DAOStarFinder run on a
4k frame):

1. noise is measured on a subsample of pixel differences (robust to
   background gradients and to stars);
2. the image is binned (~300 px across), each block dropping its brightest
   pixel, which removes hot pixels and most cosmic-ray hits; after a
   coarse block-median sky is subtracted, a compiled local-maximum search
   finds candidate peaks, ranked by flux (the only full-frame passes);
3. full-resolution cutouts around the candidates are tiled into one
   mosaic, and `~photutils.detection.DAOStarFinder` measures every
   candidate there (given their positions) with the full-resolution FWHM
   and its sharpness and roundness limits; sources whose shape is unlike
   the population's (hot pixels, cosmic-ray tracks) or whose
   matched-filter signal-to-noise is below the threshold are dropped;
4. centroids are refined with an iterative Gaussian-windowed centroid
   (the estimator of SExtractor's ``XWIN_IMAGE``), vectorised over all
   stars, which is more precise than DAOFIND's marginal fits.

Stars wider than ~10 px (defocused frames, digitised plates) are measured
on a binned copy instead, where they are well sampled and cheap.
"""

import warnings

import numpy as np
from astropy.table import Table
from numpy.lib.stride_tricks import sliding_window_view
from astropy.utils.exceptions import AstropyWarning

from ._input import image_and_mask
from ._kernels import GAUSS_SIGMA_TO_FWHM as _GAUSS_SIGMA_TO_FWHM
from ._kernels import adaptive_fwhm as _adaptive_fwhm
from ._kernels import bin_despike, finite_sample, peak_candidates
from ._kernels import median as _median
from ._kernels import windowed_centroid as _windowed_centroid

__all__ = ["find_sources", "estimate_noise", "estimate_fwhm"]


def estimate_noise(data, mask=None, *, max_samples=50_000):
    """
    Robust per-pixel noise of an image from neighbouring-pixel differences.

    Differences of adjacent pixels cancel smooth background and gradients;
    the median absolute deviation then ignores stars and hot pixels.

    Parameters
    ----------
    data : 2-D ndarray
    mask : 2-D bool ndarray, optional
        True for pixels to ignore.
    max_samples : int, optional
        Rows are subsampled so that about this many differences are used.

    Returns
    -------
    sigma : float

    Examples
    --------
    The sky of this simulated frame is 100 counts with a read noise of 5
    counts, so the noise is ``sqrt(100 + 5**2)``, about 11.2 counts:

    >>> from astroalign_nd.detection import estimate_noise
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> sigma = estimate_noise(pair.source)
    >>> bool(abs(sigma - 125**0.5) < 1.0)
    True
    """
    ny, nx = data.shape
    step = max(1, (ny * nx) // max_samples)
    rows = data[::step]
    sigma = _diff_sigma(rows, None if mask is None else mask[::step], 1)
    if np.isfinite(sigma) and nx > 8:
        # Resampled, drizzled, JPEG-compressed or interpolated frames have
        # correlated noise: neighbouring pixels differ less than the pixels
        # scatter, and the lag-1 figure is too low (too many detections).
        # Differences 3 pixels apart see the full scatter.
        sigma = max(sigma, _diff_sigma(rows, None if mask is None else mask[::step], 3))
    return float(sigma)


def _diff_sigma(rows, mrows, lag):
    """Robust sigma of one pixel from differences ``lag`` pixels apart."""
    with np.errstate(invalid="ignore"):  # inf - inf: filtered just below
        diff = (rows[:, lag:] - rows[:, :-lag]).ravel()
    good = np.isfinite(diff)
    if mrows is not None:
        good &= ~(mrows[:, lag:] | mrows[:, :-lag]).ravel()
    diff = diff[good]
    if diff.size < 10:
        return float("nan")
    med = _median(diff)
    sigma = 1.4826 * _median(np.abs(diff - med)) / np.sqrt(2.0)
    if sigma <= 0:
        # Quantised or noiseless images: fall back to the standard deviation.
        sigma = np.std(diff) / np.sqrt(2.0)
    return float(sigma)


def _interp_weights(n_out, n_blocks, block):
    """
    Bilinear weights from block centres to pixels: for each output pixel,
    the lower block ``k`` and the weights of blocks ``k`` and ``k + 1``.
    """
    if n_blocks == 1:
        return np.zeros(n_out, int), np.ones(n_out), np.zeros(n_out)
    centres = (np.arange(n_blocks) + 0.5) * block - 0.5
    # Beyond the outer block centres the sky is extrapolated linearly, so
    # that a steep gradient leaves no ramp along the frame's edges.
    pos = np.arange(n_out, dtype=float)
    k = np.clip(np.searchsorted(centres, pos, side="right") - 1, 0, n_blocks - 2)
    f = (pos - centres[k]) / (centres[k + 1] - centres[k])
    return k, 1.0 - f, f


def _background_map(binned, box):
    """
    Coarse block-median background, bilinearly expanded to ``binned``.

    Medians of ``box`` x ``box`` blocks follow gradients while ignoring
    stars; the expansion is separable, two blocks per pixel along each axis.
    """
    ny, nx = binned.shape
    by, bx = max(1, ny // box), max(1, nx // box)
    cy, cx = ny // by, nx // bx
    blocks = binned[: by * cy, : bx * cx].reshape(by, cy, bx, cx)
    blocks = np.moveaxis(blocks, 2, 1).reshape(by, bx, cy * cx)
    bkg = _median(blocks, axis=2)
    ky, wy0, wy1 = _interp_weights(ny, by, cy)
    kx, wx0, wx1 = _interp_weights(nx, bx, cx)
    # Two products per pixel (not matrix products: those wake OpenBLAS's
    # threads, which then spin and take the cores from the compiled kernels
    # that follow).
    b64 = bkg.astype(float)
    if by == 1:
        rows = np.broadcast_to(b64[0], (ny, bx))
    else:
        rows = wy0[:, None] * b64[ky] + wy1[:, None] * b64[ky + 1]
    if bx == 1:
        return np.broadcast_to(rows[:, :1], (ny, nx)).astype(np.float32), bkg
    full = wx0 * rows[:, kx]
    full += wx1 * rows[:, kx + 1]
    return full.astype(np.float32), bkg


def _extract_cutouts(data, mask, xc, yc, half, fill):
    """Stack of (2*half+1)^2 cutouts centred on integer pixels (xc, yc)."""
    size = 2 * half + 1
    ny, nx = data.shape
    n = len(xc)
    cut = np.empty((n, size, size))
    bad = np.zeros((n, size, size), dtype=bool)
    inner = (xc >= half) & (xc < nx - half) & (yc >= half) & (yc < ny - half)
    if inner.any():
        # Cutouts inside the frame (almost all): block copies from a
        # sliding-window view, not an index per pixel.
        x0, y0 = xc[inner] - half, yc[inner] - half
        cut[inner] = sliding_window_view(data, (size, size))[y0, x0]
        if mask is not None:
            bad[inner] = sliding_window_view(mask, (size, size))[y0, x0]
    if not inner.all():
        edge = ~inner
        offs = np.arange(-half, half + 1)
        iy = yc[edge, None] + offs[None, :]
        ix = xc[edge, None] + offs[None, :]
        vy = (iy >= 0) & (iy < ny)
        vx = (ix >= 0) & (ix < nx)
        iyc = np.clip(iy, 0, ny - 1)
        ixc = np.clip(ix, 0, nx - 1)
        cut[edge] = data[iyc[:, :, None], ixc[:, None, :]]
        bad_edge = ~(vy[:, :, None] & vx[:, None, :])
        if mask is not None:
            bad_edge |= mask[iyc[:, :, None], ixc[:, None, :]]
        bad[edge] = bad_edge
    bad |= ~np.isfinite(cut)
    cut[bad] = fill if np.isscalar(fill) else np.broadcast_to(
        np.asarray(fill)[:, None, None], cut.shape)[bad]
    return cut, bad


def _local_background(cut, bad, r_in):
    """Median of each cutout's pixels at least ``r_in`` from its centre."""
    n, size, _ = cut.shape
    g = np.arange(size) - size // 2
    outer = (g[:, None] ** 2 + g[None, :] ** 2) >= r_in**2
    sel = outer.ravel()
    vals = cut.reshape(n, -1)[:, sel]
    badv = bad.reshape(n, -1)[:, sel]
    bkg = _median(vals, axis=1)  # right for every cutout without bad pixels
    for i in np.flatnonzero(badv.any(axis=1)):  # the few at edges or masks
        good = vals[i][~badv[i]]
        bkg[i] = np.median(good) if good.size else 0.0
    return bkg


def estimate_fwhm(data, *, mask=None, n_stars=30):
    """
    Estimate the stellar FWHM (pixels) of an image.

    The mode of the second-moment FWHMs of the brightest compact
    candidates found by `find_sources`'s first (binned) detection stage,
    so that nebulosity, galaxies, blends and saturated stars do not move it.

    Parameters
    ----------
    data : 2-D array-like
    mask : 2-D bool array, optional
    n_stars : int, optional
        About a third of the number of bright candidates measured.

    Returns
    -------
    fwhm : float

    Examples
    --------
    >>> from astroalign_nd.detection import estimate_fwhm
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, fwhm=3.0, seed=1)
    >>> fwhm = estimate_fwhm(pair.source)
    >>> bool(abs(fwhm - 3.0) < 0.3)
    True
    """
    data, mask = _as_image(data, mask)
    noise = estimate_noise(data, mask)
    b = _auto_bin(data.shape)
    cand = _binned_candidates(data, mask, b, noise, 5.0, 4 * n_stars)
    if len(cand["x"]) == 0:
        return float("nan")
    cand = _recenter(data, mask, cand, b, None)
    return _estimate_fwhm(data, mask, cand, noise, n_max=max(5 * n_stars, 30)).fwhm


def _auto_bin(shape):
    # Aim for a binned image of ~300 px on its long side: DAOStarFinder's
    # cost scales with the pixel count, and candidates are refined later.
    # At least 2, because the binning also removes hot pixels.
    return int(max(2, round(max(shape) / 320.0)))


def _as_image(data, mask):
    arr = np.asarray(data)
    if arr.ndim != 2:
        raise ValueError(
            f"find_sources needs a 2-D image; got an array with shape {arr.shape}. For "
            "multichannel images pass the channel mean (or use register, which does it)."
        )
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"image data must be numeric; got dtype {arr.dtype}.")
    if min(arr.shape) < 8:
        raise ValueError(f"image is too small to detect stars in: shape {arr.shape}.")
    if arr.dtype != np.float32 and arr.dtype != np.float64:
        arr = arr.astype(np.float32)
    # Non-finite pixels are not collected here (a full-frame pass): every
    # step that reads pixels (noise samples, binning, cutouts) skips them.
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != arr.shape:
            raise ValueError(
                f"mask shape {mask.shape} does not match the image shape {arr.shape}."
            )
        if not mask.any():
            mask = None
    return arr, mask


def _binned_candidates(data, mask, b, noise, nsigma, n_candidates):
    """
    Stage 1: candidate peaks on the binned, background-subtracted image.

    Binning drops each block's brightest pixel (hot pixels and cosmic rays
    go), and candidates are ranked by the flux around the peak.  Positions
    are good to about a binned pixel; stage 2 measures them properly.
    """
    fill = 0.0
    if mask is not None or not np.all(np.isfinite(data[:: max(1, data.shape[0] // 64)])):
        good = finite_sample(data, mask, 4)
        fill = float(_median(good)) if good.size else 0.0  # np.median, bit for bit
    if b > 1:
        binned = bin_despike(data, b, mask, fill)
        # Mean of b*b - 1 pixels: the noise drops by about that square root.
        noise_b = noise / np.sqrt(b * b - 1)
    else:  # no binning (tiny images, or an already binned copy)
        bad = ~np.isfinite(data) if mask is None else (~np.isfinite(data) | mask)
        binned = np.where(bad, fill, data).astype(np.float32)
        noise_b = noise
    # Sky boxes of ~128 full-resolution pixels follow gradients, and stay
    # few enough for the expansion to be cheap.
    box = max(4, int(round(128 / b)))
    bkg_map, _ = _background_map(binned, box)
    resid = binned - bkg_map
    y, x, score = peak_candidates(resid, nsigma * noise_b, n_candidates)
    if len(x) == 0:
        return {"x": np.empty(0), "y": np.empty(0), "bkg": np.empty(0), "flux": np.empty(0),
                "snr": np.empty(0)}
    # Binned pixel i covers full-res pixels [i*b, i*b + b - 1].  The score
    # is a 3x3 sum, whose noise is 3 binned-pixel sigmas.
    return {"x": x * b + (b - 1) / 2.0, "y": y * b + (b - 1) / 2.0,
            "bkg": bkg_map[y, x].astype(float), "flux": score * (b * b),
            "snr": score / (3.0 * noise_b)}


def find_sources(image, *, mask=None, n_sources=50, fwhm=None, nsigma=5.0,
                 sharpness_range=(-np.inf, 1.0), roundness_range=(-1.0, 1.0),
                 peak_max=None, bin_factor=None, refine_centroids=True):
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
        (or none).

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
    """
    n_sources = _check_positive_int(n_sources, "n_sources")
    if fwhm is not None and not (np.isfinite(fwhm) and fwhm > 0):
        raise ValueError(f"fwhm must be a positive number of pixels or None; got {fwhm!r}.")
    # Paths, NDData, HDUs, (array, header) tuples, masked arrays: their own
    # mask is combined with ``mask``.
    image, mask = image_and_mask(image, mask)
    data, mask = _as_image(image, mask)
    if mask is not None and mask.all():
        raise ValueError("every pixel of the image is masked or not finite.")
    opts = dict(n_sources=n_sources, nsigma=nsigma, sharpness_range=sharpness_range,
                roundness_range=roundness_range, peak_max=peak_max,
                refine_centroids=refine_centroids)

    # Stage 1: noise, then candidate peaks on a binned copy.
    noise = estimate_noise(data, mask)
    if not np.isfinite(noise) or noise <= 0:
        return _empty_table(fwhm or 0.0, noise, 1)
    b = _auto_bin(data.shape) if bin_factor is None else _check_positive_int(
        bin_factor, "bin_factor")
    b = min(b, max(1, min(data.shape) // 8))  # a few binned pixels across at least
    # Spare candidates for what stage 2 rejects (binning already removed
    # most hot pixels and cosmic rays).
    n_cand = n_sources + n_sources // 2 + 30
    cand = _binned_candidates(data, mask, b, noise, nsigma, n_cand)
    if len(cand["x"]) == 0:
        return _empty_table(fwhm or 0.0, noise, b)
    cand = _recenter(data, mask, cand, b, fwhm)

    if fwhm is not None:
        tab = _measure(data, mask, cand, fwhm, noise, b, opts)
        tab.meta["fwhm_source"] = "user"
        return tab

    # Stage 2: the FWHM of the population of compact sources.
    est = _estimate_fwhm(data, mask, cand, noise)
    tab = _measure(data, mask, cand, est.fwhm, noise, b, opts)
    tab.meta["fwhm_source"] = "estimate"
    if est.doubtful or _too_few(tab, cand, n_sources):
        tab = _best_scale(data, mask, cand, noise, b, opts, tab,
                          est.alternatives + _SCALE_LADDER)
    elif est.alternatives:
        tab = _best_scale(data, mask, cand, noise, b, opts, tab, est.alternatives)
    return tab


class _FwhmEstimate:
    """An FWHM estimate, whether it deserves a second opinion, and others to try."""

    def __init__(self, fwhm, doubtful, alternatives=()):
        self.fwhm, self.doubtful = float(fwhm), bool(doubtful)
        self.alternatives = tuple(float(a) for a in alternatives)


def _recenter(data, mask, cand, b, fwhm):
    """
    Recentre the coarse candidates at full resolution.

    The brightest 3x3 sum in the block around each binned peak (a sum, so
    that a lone hot pixel does not win), then a few windowed-centroid steps.
    """
    rc = int(np.ceil(b + 3))
    xc = np.round(cand["x"]).astype(int)
    yc = np.round(cand["y"]).astype(int)
    cut, bad = _extract_cutouts(data, mask, xc, yc, rc, 0.0)
    cut -= cand["bkg"][:, None, None]
    cut[bad] = 0.0
    box = np.zeros_like(cut)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            box[:, 1:-1, 1:-1] += cut[:, 1 + dy:cut.shape[1] - 1 + dy,
                                      1 + dx:cut.shape[2] - 1 + dx]
    peak = box.reshape(len(xc), -1).argmax(axis=1)
    py, px = np.divmod(peak, cut.shape[2])
    sig0 = np.full(len(xc), max(1.0, (fwhm or 3.0) / _GAUSS_SIGMA_TO_FWHM))
    lx, ly = _windowed_centroid(np.clip(cut, 0, None), bad, px.astype(float),
                                py.astype(float), sig0, n_iter=4)
    out = dict(cand)
    out["x"] = xc - rc + lx
    out["y"] = yc - rc + ly
    return out


def _log_mode(values, width=0.1):
    """
    The densest value of a positive sample, in log space.

    Each value counts its neighbours within ``width`` dex; the value with
    the most (the smaller on ties: stars are more compact than knots of
    nebulosity) is refined to the median of the values within 1.5 widths.
    Returns (mode, fraction of the sample near it).
    """
    lv = np.log10(values)
    near = np.abs(lv[:, None] - lv[None, :]) <= width
    count = near.sum(axis=1)
    best = np.flatnonzero(count == count.max())
    centre = lv[best[np.argmin(lv[best])]]
    close = np.abs(lv - centre) <= 1.5 * width
    return float(10 ** np.median(lv[close])), float(close.mean())


def _estimate_fwhm(data, mask, cand, noise=None, n_max=80, half=14):
    """
    Stage 2: FWHM from the population of compact candidates.

    The second moments of up to ``n_max`` of the brightest candidates are
    measured; candidates whose cutout leaves the frame or touches masked
    pixels (edges, overscan strips, chip gaps) and saturation plateaus are
    left out, and the *mode* of the rest is taken, so that knots of
    nebulosity, galaxies, blends and bloated bright stars (all wider) and
    hot pixels (narrower) do not move it.  Stars wider than the cutouts
    can measure are measured on a binned copy.  When both a compact and a
    wide population are large (digitised plates: faint stars of a few
    pixels, bright ones of tens), both widths are returned and the scale
    search of `_best_scale` chooses.
    """
    fw, ok = _candidate_fwhms(data, mask, cand, n_max, half, noise)
    vals = fw[ok]
    wide = np.isfinite(fw) & (fw >= half / 1.5 - 0.5)
    compact = None
    if vals.size >= 10:
        mode, frac = _log_mode(vals)
        if frac >= 0.3 and mode < half / 2.0:
            # Enough compact sources share one width: those are the stars,
            # unless the wide ones are stars too (checked below).
            compact = float(np.clip(mode, 1.0, half / 1.5))
    if wide.sum() >= max(3, 0.5 * max(1, ok.sum() + wide.sum())):
        # Digitised plates and defocused frames: measure on a binned copy.
        broad = _wide_fwhm(data, mask, n_max, half)
        if compact is not None:
            # Two populations: only the two widths compete (a ladder would
            # let a width between them win on nebulosity).
            return _FwhmEstimate(compact, False, () if broad is None else (broad,))
        # A few compact candidates beside the wide ones: the wide ones may be
        # galaxies or knots, so let the scale search have a say.
        return _FwhmEstimate(half / 1.5 if broad is None else broad,
                             broad is None or vals.size >= 3)
    if compact is not None:
        return _FwhmEstimate(compact, False)
    if vals.size < 3:
        return _FwhmEstimate(3.0 if vals.size == 0 else np.median(vals), True)
    mode, frac = _log_mode(vals)
    # Too few candidates share one width (or too few to tell): the list is
    # dominated by something other than stars; let the scale search decide.
    doubtful = frac < 0.3 or vals.size < 5 or (vals.size < 8 and frac < 0.6)
    return _FwhmEstimate(np.clip(mode, 1.0, half / 1.5), doubtful)


def _wide_fwhm(data, mask, n_max, half):
    """FWHM of stars too wide for the cutouts, measured on 4x or 16x binned copies."""
    for k in (4, 16):
        if min(data.shape) // k < 16:
            break
        binned, bmask = _bin_mean(data, mask, k)
        bnoise = estimate_noise(binned, bmask)
        if not (np.isfinite(bnoise) and bnoise > 0):
            break
        bc = _binned_candidates(binned, bmask, 1, bnoise, 5.0, 150)
        if len(bc["x"]) < 3:
            break
        bc = _recenter(binned, bmask, bc, 1, None)
        bfw, bok = _candidate_fwhms(binned, bmask, bc, n_max, half, bnoise)
        bwide = np.isfinite(bfw) & (bfw >= half / 1.5 - 0.5)
        if bok.sum() >= 3 and bwide.sum() < 0.5 * (bok.sum() + bwide.sum()):
            mode, _ = _log_mode(bfw[bok])
            return float(max(mode * k, _MAX_FULL_RES_FWHM))
    return None


def _candidate_fwhms(data, mask, cand, n_max, half, noise=None):
    """FWHM of each of the first ``n_max`` candidates, and which are usable."""
    top = np.arange(min(n_max, len(cand["x"])))
    x, y, bkg = cand["x"][top], cand["y"][top], cand["bkg"][top]
    xc = np.round(x).astype(int)
    yc = np.round(y).astype(int)
    cut, bad = _extract_cutouts(data, mask, xc, yc, half, 0.0)
    # A local sky: any pedestal left would inflate the moments.
    cut = cut - _local_background(cut - bkg[:, None, None], bad, 0.75 * half)[
        :, None, None] - bkg[:, None, None]
    cut[bad] = 0.0
    fwhm = _adaptive_fwhm(cut, bad, x - xc, y - yc, sigma0=max(1.5, half / 10.0), n_iter=6)
    peak = cut.reshape(len(x), -1).max(axis=1)
    # Hot pixels and cosmic rays give a tiny FWHM; saturated (flat-topped)
    # stars a biased one; cutouts that leave the frame or touch a mask a
    # wrong one (overscan strips, frame edges).
    inner = ~bad[:, half - 3:half + 4, half - 3:half + 4].any(axis=(1, 2))
    ok = np.isfinite(fwhm) & (fwhm > 0.7) & (fwhm < half / 1.5) & inner
    ok &= bad.mean(axis=(1, 2)) < 0.25
    if ok.sum() >= 3:
        sat = peak >= 0.98 * np.max(peak[ok])
        if (sat & ok).sum() >= 2:  # several equal peaks: a saturation plateau
            ok &= ~sat
    # Bright peaks only, when there are enough: faint candidates are mostly
    # noise peaks, whose width is the noise's correlation length, not the
    # stars'.  The full-resolution peak counts (binning that drops each
    # block's brightest pixel hides undersampled stars).
    if noise is not None and np.isfinite(noise) and noise > 0:
        bright = ok & (peak >= 10.0 * noise)
        if bright.sum() < 10:
            # Sparse or faint: the ten highest peaks above 5 sigma instead.
            top = np.flatnonzero(ok & (peak >= 5.0 * noise))
            top = top[np.argsort(-peak[top], kind="stable")[:10]]
            if top.size > bright.sum():
                bright = np.zeros_like(ok)
                bright[top] = True
        if bright.sum() >= 5:
            ok = bright
    return fwhm, ok


def _bin_mean(data, mask, k):
    """k x k mean-binned copy; a block with a masked or NaN pixel is masked."""
    ny, nx = (data.shape[0] // k) * k, (data.shape[1] // k) * k
    work = data[:ny, :nx]
    if mask is not None:
        work = np.where(mask[:ny, :nx], np.nan, work)
    binned = work.reshape(ny // k, k, nx // k, k).mean(axis=(1, 3), dtype=np.float64)
    bmask = ~np.isfinite(binned)
    return binned, (bmask if bmask.any() else None)


def _too_few(tab, cand, n_sources):
    """Did the measurement keep too few of the candidates to be trusted?"""
    wanted = min(n_sources, len(cand["x"]))
    return len(tab) < max(3, min(12, wanted // 2)) or len(tab) < 0.2 * wanted


#: FWHMs (pixels) tried when the estimate is doubtful.
_SCALE_LADDER = (1.6, 2.5, 4.0, 6.5, 10.0)


def _best_scale(data, mask, cand, noise, b, opts, first, alternatives=()):
    """
    Stage 2b: try other widths (a ladder when the estimate is doubtful, or
    the wide population's width on a digitised plate).

    Each trial FWHM gives a list of sources; a list is *consistent* when
    the median FWHM its sources measure on their own agrees with the trial
    value.  Among the lists with nearly the most strong sources, the most
    consistent wins; the first attempt is kept on ties.
    """
    trials = [first]
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
    call.  Falls back to the public call if photutils' internals change.
    """
    if hasattr(finder, "_get_raw_catalog"):
        try:
            cat = finder._get_raw_catalog(data, mask=mask)
            if cat is not None:
                cat = cat.apply_all_filters()
            if cat is None:
                return None
            return {c: np.asarray(getattr(cat, c), float) for c in _DAO_COLUMNS}
        except (AttributeError, TypeError):  # internals changed: use the public call
            pass
    tab = finder(data, mask=mask)
    if tab is None:
        return None
    return {c: np.asarray(tab[c], float) for c in _DAO_COLUMNS}


def _measure(data, mask, cand, fwhm, noise, b, opts):
    """
    Stage 3: measure the candidates with DAOStarFinder at a given FWHM.

    Full-resolution cutouts around the candidates, less their local sky,
    are measured as one mosaic (`_dao_on_mosaic`); the brightest detection
    near each tile's centre is kept (`_brightest_per_tile`), its centroid
    refined (`_refined_positions`), and hot pixels, cosmic rays and faint
    or duplicate sources dropped (`_filtered_table`).  Wide stars are
    measured on a binned copy (as well, at a fraction of the cost: the
    mosaic of cutouts grows with the FWHM squared).
    """
    if fwhm > _MAX_FULL_RES_FWHM:
        k = int(fwhm // (_MAX_FULL_RES_FWHM / 2))
        return _find_on_binned(data, mask, k, fwhm / k, opts)
    half = int(np.ceil(max(3.0 * fwhm, 6)))
    xc = np.clip(np.round(cand["x"]).astype(int), 0, data.shape[1] - 1)
    yc = np.clip(np.round(cand["y"]).astype(int), 0, data.shape[0] - 1)
    cut, bad = _extract_cutouts(data, mask, xc, yc, half, 0.0)
    # Local sky from the tile's outskirts (beyond 2 FWHM): the coarse map
    # of stage 1 is only good to a fraction of the noise, and any pedestal
    # biases fluxes and pulls centroids towards the tile centre.
    cut = cut - _local_background(cut, bad, min(2.0 * fwhm, half - 1.0))[:, None, None]
    cut[bad] = 0.0
    tab, ncol = _dao_on_mosaic(cut, bad, cand, xc, yc, half, fwhm, noise, opts)
    if tab is None or len(tab["flux"]) == 0:
        return _empty_table(fwhm, noise, b)
    sel, kk, lx, ly = _brightest_per_tile(tab, len(cand["x"]), ncol, half, fwhm)
    if sel.size == 0:
        return _empty_table(fwhm, noise, b)
    xs, ys = _refined_positions(cut[kk], bad[kk], lx[sel], ly[sel], fwhm, opts)
    tab = {c: np.asarray(tab[c], float)[sel] for c in ("peak", "sharpness", "roundness1",
                                                       "roundness2")}
    return _filtered_table(cut[kk], bad[kk], xc[kk] - half + xs, yc[kk] - half + ys, xs, ys,
                           tab, half, fwhm, noise, b, opts)


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
    # (n, tile, tile) -> (nrow*tile, ncol*tile) without a Python loop.
    pad = np.zeros((nrow * ncol, tile, tile))
    pad[:n] = cut
    mosaic = pad.reshape(nrow, ncol, tile, tile).swapaxes(1, 2).reshape(nrow * tile, ncol * tile)
    padm = np.ones((nrow * ncol, tile, tile), dtype=bool)
    padm[:n] = bad
    mmask = padm.reshape(nrow, ncol, tile, tile).swapaxes(1, 2).reshape(nrow * tile, ncol * tile)
    # Tile centres are given as xycoords, so DAOStarFinder skips its peak
    # search and only measures centroid, sharpness and roundness.
    centers = np.empty((n, 2))
    kk = np.arange(n)
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
    with warnings.catch_warnings():
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
    # A refinement that wandered away means a blend: keep DAOFIND's.
    moved = np.hypot(xs - x0, ys - y0) > 0.5 * fwhm
    return np.where(moved, x0, xs), np.where(moved, y0, ys)


def _filtered_table(cut, bad, gx, gy, xs, ys, dao, half, fwhm, noise, b, opts):
    """
    The output table: fluxes and errors, without hot pixels, cosmic rays,
    faint sources and duplicates, brightest first.

    ``cut`` and ``bad`` are the kept stars' tiles, ``gx, gy`` their image
    positions, ``xs, ys`` their positions in the tiles, ``dao`` their
    DAOStarFinder measurements.
    """
    nsigma = opts["nsigma"]
    aflux, perr, snr = _aperture_flux_and_error(cut, bad, xs, ys, fwhm, noise)

    # Hot pixels and cosmic rays that got this far (a bright hit can pass
    # DAOFIND's sharpness limit) are much narrower than the stars.
    own_fwhm = _adaptive_fwhm(cut, bad, xs - half, ys - half,
                              sigma0=fwhm / _GAUSS_SIGMA_TO_FWHM, n_iter=4)
    real = ~(own_fwhm < 0.6 * fwhm) if fwhm >= 1.5 else np.ones(len(gx), bool)
    sharp, round1, round2 = dao["sharpness"], dao["roundness1"], dao["roundness2"]
    # Given positions, DAOStarFinder does not apply its threshold: apply
    # it as a matched-filter signal-to-noise.
    real &= snr >= nsigma
    real &= _population_inliers(sharp, round1, round2, real)

    # The same star can sit in two overlapping candidate tiles.
    keep = _dedupe(gx, gy, np.where(real, aflux, -np.inf), max(1.0, 0.5 * fwhm))
    keep = keep[real[keep]]
    cols = {
        "x": gx[keep], "y": gy[keep], "flux": aflux[keep], "position_error": perr[keep],
        "snr": snr[keep],
        "peak": dao["peak"][keep], "sharpness": sharp[keep],
        "roundness1": round1[keep], "roundness2": round2[keep],
    }
    order = np.argsort(-cols["flux"], kind="stable")[:opts["n_sources"]]
    out = Table({k: v[order] for k, v in cols.items()}, copy=False)
    # The sources' own widths, from the strong ones when there are enough:
    # faint ones are often noise peaks, as wide as the noise's correlation.
    own = own_fwhm[keep][order]
    strong = cols["snr"][order] >= 10.0
    if strong.sum() >= 3:
        own = own[strong]
    own = own[np.isfinite(own)]
    out.meta.update(fwhm=float(fwhm), noise=float(noise), bin_factor=int(b),
                    own_fwhm_median=float(np.median(own)) if own.size else float("nan"))
    return out


def _aperture_flux_and_error(cut, bad, xs, ys, fwhm, noise):
    """
    Aperture flux (radius 1.5 FWHM), expected centroid error and
    matched-filter signal-to-noise.

    The error is the background-limited centroid precision of a Gaussian
    star, ``sqrt(8 pi) sigma_psf^2 sigma_noise / flux`` per axis, with a
    0.005 px floor; it is used to weight stars in the final fit.
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
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = (w * cut).sum(axis=(1, 2)) / (noise * np.sqrt((w * w).sum(axis=(1, 2))))
    snr = np.where(np.isfinite(snr), snr, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.sqrt(8 * np.pi) * sig_psf**2 * noise / np.where(flux > 0, flux, np.nan)
    err = np.where(np.isfinite(err), err, 10.0 * fwhm)
    return flux, np.hypot(err, 0.005), snr


_MAX_FULL_RES_FWHM = 10.0
#: Stars narrower than this (FWHM, pixels) count as undersampled ...
_UNDERSAMPLED_FWHM = 2.5
#: ... and get a centroid window of this FWHM (pixels).
_MIN_WINDOW_FWHM = 4.0


def _find_on_binned(data, mask, k, fwhm, opts):
    """find_sources on a k x k mean-binned copy, in full-resolution pixels."""
    binned, bmask = _bin_mean(data, mask, k)
    tab = find_sources(binned, mask=bmask, fwhm=fwhm, **opts)
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
    med = np.median(s)
    mad = 1.4826 * np.median(np.abs(s - med))
    keep &= sharp <= med + max(0.15, 5.0 * mad)
    # A star's centre is brighter than its surroundings (sharpness > 0, also
    # for a saturated plateau); cosmic-ray tracks off the tile centre are not.
    keep &= sharp >= min(0.0, med - 0.3)
    r = np.maximum(np.abs(round1), np.abs(round2))
    keep &= r <= max(0.35, 4.0 * np.median(r[ok]))
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


def _empty_table(fwhm, noise, b):
    t = Table(names=["x", "y", "flux", "position_error", "snr", "peak", "sharpness",
                     "roundness1", "roundness2"], dtype=[float] * 9)
    t.meta.update(fwhm=float(fwhm), noise=float(noise), bin_factor=int(b))
    return t


def _check_positive_int(value, name):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be a positive integer; got {value!r}.")
    if value < 1:
        raise ValueError(f"{name} must be a positive integer; got {value}.")
    return int(value)


#: The deep threshold (noise units) of registration's one detection pass, for
#: faint or sparse fields.
_DEEP_NSIGMA = 3.0
#: The confident threshold kept when enough sources pass it: `find_sources`' default.
_CONFIDENT_NSIGMA = find_sources.__kwdefaults__["nsigma"]


def _control_sources(image, *, mask, n_sources, n_enough, nsigma=None, **options):
    """
    The sources registration uses: the detection thresholds' one home.

    With ``nsigma`` given, one `find_sources` pass at it; without, one
    pass at ``_DEEP_NSIGMA``, of which only the sources at ``_CONFIDENT_NSIGMA``
    are kept when there are ``n_enough`` of them.
    Returns the table and the threshold of the pass (for messages).
    """
    threshold = _DEEP_NSIGMA if nsigma is None else nsigma
    table = find_sources(image, mask=mask, n_sources=n_sources, nsigma=threshold, **options)
    if nsigma is None:
        strong = table[table["snr"] >= _CONFIDENT_NSIGMA]
        if len(strong) >= n_enough:
            table = strong
    return table, threshold
