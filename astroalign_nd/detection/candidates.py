# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Candidate peaks on a (binned) image, and cutouts around them."""

import functools

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from .._kernels import GAUSS_SIGMA_TO_FWHM as _GAUSS_SIGMA_TO_FWHM
from .._kernels import bin_despike, compiled_kernels, finite_sample, peak_candidates
from .._kernels import median as _median
from .._kernels import windowed_centroid as _windowed_centroid
from .background import _background_map
from .lines import _bright_lines

__all__ = []


def _extract_cutouts(data, mask, xc, yc, half, fill):
    """Stack of (2*half+1)^2 cutouts centred on integer pixels (xc, yc)."""
    size = 2 * half + 1
    ny, nx = data.shape
    n = len(xc)
    cut = np.empty((n, size, size))
    ck = compiled_kernels()
    if ck is not None and np.isscalar(fill) and data.dtype in (np.float32, np.float64):
        bad = np.empty((n, size, size), dtype=bool)  # (every pixel written)
        # One pass, without NumPy's gather of many small windows (a cold
        # frame's rows read once each).
        m = np.zeros((1, 1), np.uint8) if mask is None else mask.view(np.uint8)
        ck.extract_cutouts(data, m, mask is not None, np.asarray(xc, np.intp),
                           np.asarray(yc, np.intp), int(half), float(fill), cut,
                           bad.view(np.uint8))
        return cut, bad
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


#: Frames whose stars are narrower than this (FWHM, pixels) are not
#: despiked: a star of a heavily undersampled frame is a spike itself.
_DESPIKE_MIN_FWHM = 2.0

#: Spikes are judged against stars this much narrower than the frame's
#: (a margin for the estimate and for stars off the pixel centre) ...
_SPIKE_FWHM_MARGIN = 0.7

#: ... and a spike stands this many noise sigmas above what its
#: neighbours allow.
_SPIKE_NSIGMA = 5.0


@functools.lru_cache(maxsize=64)
def _neighbour_ratio(fwhm):
    """
    The least ratio of a star's brightest neighbouring pixel to its centre
    pixel: a Gaussian star of this FWHM centred on a pixel, integrated over
    the pixels.
    """
    from scipy.special import ndtr

    s = fwhm / _GAUSS_SIGMA_TO_FWHM
    centre = ndtr(0.5 / s) - ndtr(-0.5 / s)
    return float((ndtr(1.5 / s) - ndtr(0.5 / s)) / centre)


def _despike(cut, bad, noise, fwhm):
    """
    The cutouts with their single-pixel spikes (hot pixels, cosmic-ray hits
    of one pixel) replaced by the median of their neighbours.

    A spike stands above all its eight neighbours by more than the centre of
    any star of the frame can: more than ``1 / _neighbour_ratio`` times the
    brightest neighbour, plus `_SPIKE_NSIGMA` noise sigmas, the ratio being
    that of a star narrower than the frame's ``fwhm`` (by
    `_SPIKE_FWHM_MARGIN`), so that no star's centre is taken for one.  Only
    for frames whose stars are `_DESPIKE_MIN_FWHM` wide or more (the
    callers' check).  ``cut`` holds background-subtracted tiles (not
    modified: a new array is returned when a spike is found); ``bad``
    pixels are neither spikes nor neighbours.
    """
    allow = 1.0 / _neighbour_ratio(_SPIKE_FWHM_MARGIN * fwhm)
    # Only pixels above the noise margin can be spikes.
    k, iy, ix = np.nonzero(~bad & (cut > _SPIKE_NSIGMA * noise))
    if k.size == 0:
        return cut
    n, ny, nx = cut.shape
    # The eight neighbours of a pixel, from a copy with a border: bad
    # pixels and those beyond the tile read -inf.
    framed = np.full((n, ny + 2, nx + 2), -np.inf)
    framed[:, 1:-1, 1:-1] = np.where(bad, -np.inf, cut)

    def neighbours(k, iy, ix):  # (8, len(k)): gathered for these pixels only
        return framed.reshape(-1)[(k * (ny + 2) + iy + 1) * (nx + 2) + ix + 1
                                  + _neighbour_steps(nx + 2)[:, None]]

    nbs = None
    if _WHOLE_STACK_FRACTION * k.size > cut.size:
        # Most pixels stand above the margin (a bright plate): the shifted
        # stacks' maximum, a few whole-array passes, beats gathering them.
        top = framed[:, :ny, :nx].copy()
        for dy, dx in _NEIGHBOURS[1:]:
            np.maximum(top, framed[:, 1 + dy:ny + 1 + dy, 1 + dx:nx + 1 + dx], out=top)
        top = top[k, iy, ix]
    else:
        nbs = neighbours(k, iy, ix)
        top = nbs.max(axis=0)
    # (A pixel with no good neighbour is not judged.)
    spike = np.isfinite(top) & (cut[k, iy, ix] > allow * np.maximum(top, 0.0)
                                + _SPIKE_NSIGMA * noise)
    if not spike.any():
        return cut
    k, iy, ix = k[spike], iy[spike], ix[spike]
    nbs = neighbours(k, iy, ix) if nbs is None else nbs[:, spike]
    nbs[~np.isfinite(nbs)] = np.nan
    out = np.array(cut)
    out[k, iy, ix] = _nanmedian_columns(nbs)  # one at least is good
    return out


def _nanmedian_columns(a):
    """
    ``np.nanmedian(a, axis=0)`` of a few rows whose every column has a
    value, without its masked-array path for small arrays (a tenth of a
    millisecond a call): the same sort, and the mean of the middle two.
    """
    good = ~np.isnan(a)
    srt = np.sort(np.where(good, a, np.inf), axis=0)  # (NaN last, as masked values)
    count = good.sum(axis=0)
    hi = count // 2
    lo = np.where(count % 2 == 1, hi, hi - 1)
    cols = np.arange(a.shape[1])
    low, high = srt[lo, cols], srt[hi, cols]
    med = (low + high) / 2.0
    # Which zero (+0 or -0) a sort leaves in the middle is its own.
    zero = (low == 0) | (high == 0)
    if zero.any():
        med[zero] = np.nanmedian(a[:, zero], axis=0)
    return med


#: A pixel's eight neighbours (dy, dx), in raster order.
_NEIGHBOURS = tuple((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx)


def _neighbour_steps(width):
    """The neighbours' offsets in a raveled array of rows ``width`` long."""
    return np.array([dy * width + dx for dy, dx in _NEIGHBOURS])


#: `_despike` takes every neighbour's maximum over the whole stack when
#: more than 1 / this of its pixels are above the noise margin (measured
#: break-even: about a quarter to a third).
_WHOLE_STACK_FRACTION = 4


def _auto_bin(shape):
    # Aim for a binned image of ~300 px on its long side: DAOStarFinder's
    # cost scales with the pixel count, and candidates are refined later.
    # At least 2, because the binning also removes hot pixels.
    return int(max(2, round(max(shape) / 320.0)))


def _as_image(data, mask, caller="find_sources"):
    """The image as a float array and its mask (None if nothing is masked), checked."""
    arr = np.asarray(data)
    if arr.ndim != 2:
        raise ValueError(
            f"{caller} needs a 2-D image; got an array with shape {arr.shape}. For "
            "multichannel images pass the channel mean (or use register, which does it)."
        )
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"image data must be numeric; got dtype {arr.dtype}.")
    if min(arr.shape) < 8:
        raise ValueError(f"image is too small to detect stars in: shape {arr.shape}.")
    single = not (arr.dtype.kind == "f" and arr.dtype.itemsize >= 8)  # (FITS: big-endian)
    if not single:
        # Detection reads single precision at half the memory traffic (most
        # of a small frame's full-frame passes) when float32 keeps the
        # noise: its rounding of a sample of rows stays below a thousandth
        # of their neighbouring-pixel scatter (not so for noiseless frames
        # float32 cannot hold, or a faint signal on a large pedestal).
        rows = arr[:: max(1, arr.shape[0] // 64)]
        with np.errstate(invalid="ignore", over="ignore"):
            err = np.abs(rows - rows.astype(np.float32))
            scatter = np.abs(np.diff(rows, axis=1))
        finite = np.isfinite(rows)
        if finite.any() and np.abs(rows[finite]).max() > np.finfo(np.float32).max:
            raise ValueError("image values reach beyond float32's range (3.4e38), which the "
                             "detection's binning and sky passes use; pass the image scaled "
                             "down (e.g. divided by its maximum).")
        err, scatter = err[finite], scatter[np.isfinite(scatter)]
        single = not err.any() or (scatter.size > 0
                                   and err.max() <= 1e-3 * _median(scatter))
    if arr.dtype != np.float32 and single:
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


def _binned_candidates(data, mask, b, noise, nsigma, n_candidates, lines=None,
                       check_lines=False):
    """
    Stage 1: candidate peaks on the binned, background-subtracted image
    (`_binned_residual`, then `_binned_peaks`).

    Binning drops each block's brightest pixel (hot pixels and cosmic rays
    go), and candidates are ranked by the flux around the peak.  Positions
    are good to about a binned pixel; stage 2 measures them properly.

    ``lines`` (a ``detection.lines.LineBackground`` of a frame
    whose bright lines are already subtracted from ``data``) gives each
    binned pixel its own noise: the image is searched in local sigmas, so
    that the noise peaks of a band or a bad column are not candidates.
    With ``check_lines``, None is returned instead when the binned image
    has bright or noisy rows or columns (the caller then measures them).
    """
    residual = _binned_residual(data, mask, b, noise, lines, check_lines)
    if residual is None:
        return None
    return _binned_peaks(residual, nsigma, n_candidates)


def _binned_residual(data, mask, b, noise, lines=None, check_lines=False):
    """
    The full-frame part of `_binned_candidates`: the binned image less its
    coarse sky, with what `_binned_peaks` needs to read its peaks (the
    same for any number of candidates: a detection of more sources picks
    more of its peaks).  None as `_binned_candidates` returns it.
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
    if check_lines and _bright_lines(resid, noise_b):
        return None
    factor = None
    if lines is not None:
        factor = lines.binned_factor(resid.shape, b) if b > 1 else lines.factor(
            np.arange(resid.shape[0])[:, None], np.arange(resid.shape[1])[None, :])
        resid = resid / factor
    return {"resid": resid, "bkg_map": bkg_map, "factor": factor, "noise_b": noise_b, "b": b}


def _binned_peaks(residual, nsigma, n_candidates):
    """
    The ``n_candidates`` brightest peaks of a `_binned_residual` above
    ``nsigma``: those of a detection of fewer candidates come first, in the
    same order (`~astroalign_nd._kernels.peak_candidates` ranks them all).
    """
    resid, bkg_map, factor = residual["resid"], residual["bkg_map"], residual["factor"]
    noise_b, b = residual["noise_b"], residual["b"]
    y, x, score = peak_candidates(resid, nsigma * noise_b, n_candidates)
    if factor is not None:  # fluxes in counts again (ranking stays local)
        score = score * factor[y, x]
    if len(x) == 0:
        return {"x": np.empty(0), "y": np.empty(0), "bkg": np.empty(0), "flux": np.empty(0),
                "snr": np.empty(0)}
    # Binned pixel i covers full-res pixels [i*b, i*b + b - 1].  The score
    # is a 3x3 sum, whose noise is 3 binned-pixel sigmas.
    snr = score / (3.0 * noise_b) if factor is None else score / (3.0 * noise_b * factor[y, x])
    return {"x": x * b + (b - 1) / 2.0, "y": y * b + (b - 1) / 2.0,
            "bkg": bkg_map[y, x].astype(float), "flux": score * (b * b), "snr": snr}


def _recenter(data, mask, cand, b, fwhm, noise=None, spike_fwhm=None):
    """
    Recentre the coarse candidates at full resolution.

    The brightest 3x3 sum in the block around each binned peak (a sum, so
    that a lone hot pixel does not win), then a few windowed-centroid steps.
    With ``noise`` and ``spike_fwhm`` (the stars' FWHM), single-pixel spikes
    are removed first (`_despike`: a hot pixel beside a faint star does not
    pull it).
    """
    rc = int(np.ceil(b + 3))
    xc = np.round(cand["x"]).astype(int)
    yc = np.round(cand["y"]).astype(int)
    cut, bad = _extract_cutouts(data, mask, xc, yc, rc, 0.0)
    cut -= cand["bkg"][:, None, None]
    cut[bad] = 0.0
    if spike_fwhm is not None:
        cut = _despike(cut, bad, noise, spike_fwhm)
    # The 3x3 sums of the inner pixels, each cutout as one row: a neighbour
    # is an offset along it (long vector operations, not the cutouts' short
    # rows); the sums that wrapped around a row's ends are set to zero.
    n, h, w = cut.shape
    box = np.zeros((n, h * w))
    lo, hi = w + 1, h * w - w - 1
    flat = cut.reshape(n, h * w)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            box[:, lo:hi] += flat[:, lo + dy * w + dx:hi + dy * w + dx]
    box = box.reshape(n, h, w)
    box[:, :, 0] = box[:, :, -1] = 0.0
    peak = box.reshape(n, -1).argmax(axis=1)
    py, px = np.divmod(peak, cut.shape[2])
    sig0 = np.full(len(xc), max(1.0, (fwhm or 3.0) / _GAUSS_SIGMA_TO_FWHM))
    lx, ly = _windowed_centroid(np.clip(cut, 0, None), bad, px.astype(float),
                                py.astype(float), sig0, n_iter=4)
    out = dict(cand)
    out["x"] = xc - rc + lx
    out["y"] = yc - rc + ly
    return out
