# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Bright rows and columns: edge bands of raw frames, bad rows, bad columns.

The first rows read out of a raw CCD frame often hold a band, brightest on
the edge and fading over a few rows, with its own (larger) noise; a bad
column is a column above the sky.  Judged against the frame's background
and noise, the noise peaks along such a line are a row of "stars".  Here
each row and column is judged against its neighbours: a line whose level
stands above the trend of the lines around it has that excess subtracted,
and a line noisier than the frame has its own noise, by which candidates
on it are judged (`LineBackground.factor`).

The check runs on the binned candidate image (a few hundred lines, no
full-frame pass); only a frame with such a line is measured again at full
resolution.
"""

import warnings

import numpy as np
from .._kernels import median as _median

__all__ = []

#: A binned line this many binned-pixel sigmas above the lines next to it
#: is a line defect (a star cluster's core, a nebula's edge: at most 4-5,
#: and only over several lines; the band of a raw frame: 10 to 30).
_BINNED_EXCESS = 6.0

#: Lines either side that the binned check compares a line with.
_BINNED_WINDOW = 7

#: At full resolution, a line's excess is subtracted when above this many
#: sigmas of the frame (and significant against its own noise) ...
_EXCESS = 0.3

#: ... and its own noise counts when this many times the frame's.
_NOISY = 1.15

#: Pixels sampled per row (or column) at full resolution.
_SAMPLES = 256


def _trend(level, window):
    """Running median of a line profile (reflected at the ends, so that a band along
    an edge is a minority of the window there)."""
    from scipy.ndimage import median_filter

    window = int(min(window, 2 * (len(level) // 2) - 1))
    if window < 3:
        return np.full_like(level, np.median(level))
    return median_filter(level, size=window, mode="reflect")


def _bright_lines(resid, noise):
    """
    Are there bright or noisy rows or columns in the binned residual image?

    ``resid`` is the binned image less its coarse background, ``noise`` its
    per-pixel noise.  The answer of every line's median and their trend,
    from bounds where they decide it (most frames: no median at all): a
    line with more than half its pixels within ``+-a`` has its median there
    too, and a trend is at least the trend of such lower bounds.  Medians
    are computed for the lines outside the bounds and, where a bound allows
    an excess, for the lines around it (then exact).
    """
    if min(resid.shape) < 16:
        return False
    limit = _BINNED_EXCESS * noise
    # Bounds +-a at most the limit apart (in float32, as the medians).
    a = np.float32(min(limit / 2, 1e37))
    if not 2.0 * float(a) <= limit:
        a = np.nextafter(a, np.float32(0))
    near = np.abs(resid) <= a
    for axis in (1, 0):
        lines = resid if axis == 1 else resid.T
        n = lines.shape[1]
        todo = near.view(np.uint8).sum(axis=axis, dtype=np.intp) <= n - n // 2
        lo, hi = np.full(len(lines), -a, resid.dtype), np.full(len(lines), a, resid.dtype)
        known = np.zeros(len(lines), bool)
        while todo.any():  # (none: every excess is at most 2a)
            lo[todo] = hi[todo] = _median(lines[todo], axis=1)
            known |= todo
            if not np.isfinite(hi).all():  # (the bounds do not hold: every line's median)
                level = _median(lines, axis=1)
                with np.errstate(invalid="ignore"):
                    if np.any(level - _trend(level, _BINNED_WINDOW) > limit):
                        return True
                break
            # A narrow window: a defect stands out from the very next lines,
            # where smooth structure (clusters, nebulae) does not.  (The
            # trend of the lower bounds: a line's median is at least its.)
            over = hi - _trend(lo, _BINNED_WINDOW) > limit
            # (a line's window known, its excess is exact)
            todo = (np.convolve(over, np.ones(_BINNED_WINDOW), "same") > 0) & ~known
            if over.any() and not todo.any():
                return True
    return False


class LineBackground:
    """
    Excess level and noise of each row and column of a frame.

    Attributes
    ----------
    row_excess, col_excess : ndarray
        Counts above the neighbouring lines' trend (0 where not significant).
    row_factor, col_factor : ndarray
        Each line's noise over the frame's (1 where not significantly more).
    """

    def __init__(self, row_excess, row_factor, col_excess, col_factor):
        self.row_excess, self.row_factor = row_excess, row_factor
        self.col_excess, self.col_factor = col_excess, col_factor

    def subtract(self, data):
        """A float32 copy of ``data`` less the lines' excess."""
        out = np.array(data, dtype=np.float32)
        rows = np.flatnonzero(self.row_excess)
        out[rows] -= self.row_excess[rows, None].astype(np.float32)
        cols = np.flatnonzero(self.col_excess)
        out[:, cols] -= self.col_excess[None, cols].astype(np.float32)
        return out

    def factor(self, y, x):
        """Noise factor (over the frame's) at integer pixels ``(y, x)``, broadcast."""
        ny, nx = len(self.row_factor), len(self.col_factor)
        return np.maximum(self.row_factor[np.clip(y, 0, ny - 1)],
                          self.col_factor[np.clip(x, 0, nx - 1)])

    def binned_factor(self, shape, b):
        """The noise factor of each pixel of a ``b`` x ``b`` binned image of ``shape``:
        the RMS of the factors of the lines it averages."""
        ny, nx = shape

        def per_block(f, n):
            f = f[: n * b] ** 2
            if f.size < n * b:
                f = np.concatenate([f, np.ones(n * b - f.size)])
            return np.sqrt(f.reshape(n, b).mean(axis=1))

        return np.maximum(per_block(self.row_factor, ny)[:, None],
                          per_block(self.col_factor, nx)[None, :])


def line_background(data, mask, noise):
    """
    The rows' and columns' excess and noise factors of a full-resolution frame.

    Each line is sampled at up to `_SAMPLES` pixels; its median is compared
    with the running median of the lines around it, and its noise (from
    differences of neighbouring samples, which cancel gradients) with the
    frame's ``noise``.

    Returns
    -------
    lines : `LineBackground` or None
        None when no line stands out.
    """
    arr = np.asarray(data)
    if mask is not None or not np.isfinite(arr[:: max(1, arr.shape[0] // 64)]).all():
        arr = np.where(np.isfinite(arr) & (True if mask is None else ~mask), arr, np.nan)
    ny, nx = arr.shape
    out = []
    for axis, n_lines, n_along in ((1, ny, nx), (0, nx, ny)):
        step = max(1, n_along // _SAMPLES)
        sub = arr[:, ::step] if axis == 1 else arr[::step, :].T
        sub = np.ascontiguousarray(sub, dtype=np.float32)
        # Each line's median (NaN-aware), and its count of finite samples.
        if np.isnan(sub).any():
            n = np.sum(np.isfinite(sub), axis=1)
            level = np.full(sub.shape[0], np.nan)
            some = n > 0
            level[some] = np.nanmedian(sub[some], axis=1)
            # Lines with nothing valid follow the others (the trend ignores them).
            level[~some] = np.nanmedian(level) if some.any() else 0.0
        else:
            level, n = _median(sub, axis=1), np.full(sub.shape[0], sub.shape[1])
        excess = level - _trend(level, max(31, (n_lines // 16) | 1))
        excess_out = np.zeros(n_lines)
        factor = np.ones(n_lines)
        with np.errstate(invalid="ignore"):
            cand = np.flatnonzero(excess > _EXCESS * noise)
        if cand.size:
            # Only lines above the floor are measured further (few): their
            # noise, and whether the excess is significant against it (the
            # median's error is 1.25 sigma / sqrt(n)).  Lines below the sky
            # (overscan, dead columns) make no false peaks and are left.
            # (a line's noise: the MAD of differences of neighbouring samples, as a
            # standard deviation of one pixel; NaN for a line without two valid neighbours)
            diff = np.diff(sub[cand].astype(np.float64), axis=1)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                dev = np.abs(diff - np.nanmedian(diff, axis=1)[:, None])
                sig = 1.4826 * np.nanmedian(dev, axis=1) / np.sqrt(2.0)
            err = 1.25 * np.maximum(sig, noise) / np.sqrt(np.maximum(n[cand], 1))
            with np.errstate(invalid="ignore"):
                bright = excess[cand] > 5.0 * err
                # Only the bright lines' own noise counts (a band's, a bad
                # column's): elsewhere the frame's noise judges, as before.
                noisy = bright & (sig > _NOISY * noise)
            excess_out[cand[bright]] = excess[cand[bright]]
            factor[cand[noisy]] = sig[noisy] / noise
        out += [excess_out, factor]
    lines = LineBackground(*out)
    if not (lines.row_excess.any() or lines.col_excess.any()):
        return None
    return lines
