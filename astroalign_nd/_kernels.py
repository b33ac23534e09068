# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Small compiled kernels for the full-frame passes of detection.

Only two passes touch every pixel of a frame during detection: binning
and the candidate peak search.  They are single loops, compiled with numba
(``cache=True`` keeps the compiled code on disk, so only the very first
call in an environment pays for compilation).  NumPy versions of the same
operations are used when numba is not available; both give the same
result.
"""

import numpy as np

try:  # numba is a hard dependency, but keep the package importable without it
    from numba import njit, prange

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    HAVE_NUMBA = False

__all__ = ["bin_despike", "peak_candidates"]


if HAVE_NUMBA:

    @njit(cache=True, parallel=True, nogil=True)
    def _bin_despike_nb(data, mask, b, fill, out):
        ny, nx = out.shape
        inv = 1.0 / (b * b - 1)
        for i in prange(ny):
            for j in range(nx):
                total = 0.0
                peak = -np.inf
                for di in range(b):
                    for dj in range(b):
                        v = data[i * b + di, j * b + dj]
                        if mask[i * b + di, j * b + dj] or not np.isfinite(v):
                            v = fill
                        total += v
                        if v > peak:
                            peak = v
                out[i, j] = (total - peak) * inv

    @njit(cache=True, parallel=True, nogil=True)
    def _bin_despike_nomask_nb(data, b, fill, out):
        ny, nx = out.shape
        inv = 1.0 / (b * b - 1)
        for i in prange(ny):
            for j in range(nx):
                total = 0.0
                peak = -np.inf
                for di in range(b):
                    for dj in range(b):
                        v = data[i * b + di, j * b + dj]
                        if not np.isfinite(v):
                            v = fill
                        total += v
                        if v > peak:
                            peak = v
                out[i, j] = (total - peak) * inv

    @njit(cache=True, nogil=True)
    def _peaks_nb(img, threshold, border):
        ny, nx = img.shape
        ys = []
        xs = []
        scores = []
        for i in range(border, ny - border):
            for j in range(border, nx - border):
                v = img[i, j]
                if v <= threshold:
                    continue
                is_max = True
                s = 0.0
                for di in range(-1, 2):
                    for dj in range(-1, 2):
                        ii = i + di
                        jj = j + dj
                        if ii < 0 or ii >= ny or jj < 0 or jj >= nx:
                            continue
                        w = img[ii, jj]
                        s += w
                        if di == 0 and dj == 0:
                            continue
                        # Ties go to the first pixel in raster order.
                        if w > v or (w == v and (di < 0 or (di == 0 and dj < 0))):
                            is_max = False
                if is_max:
                    ys.append(i)
                    xs.append(j)
                    scores.append(s)
        return np.array(ys), np.array(xs), np.array(scores)


def bin_despike(data, b, mask=None, fill=0.0):
    """
    Bin by ``b`` (cropping the ragged edge), dropping each block's maximum.

    Dropping the brightest pixel of every block removes isolated hot pixels
    and most of a cosmic-ray hit, while a star, several pixels across,
    keeps most of its signal.  Masked and non-finite pixels count as
    ``fill``.

    Returns
    -------
    binned : float32 ndarray of shape ``(ny // b, nx // b)``
    """
    ny, nx = data.shape[0] // b, data.shape[1] // b
    out = np.empty((ny, nx), dtype=np.float32)
    if HAVE_NUMBA and data.dtype in (np.float32, np.float64):
        arr = np.ascontiguousarray(data)
        if mask is None:
            _bin_despike_nomask_nb(arr, b, float(fill), out)
        else:
            _bin_despike_nb(arr, np.ascontiguousarray(mask), b, float(fill), out)
        return out
    blocks = np.asarray(data[: ny * b, : nx * b], dtype=np.float32)
    bad = ~np.isfinite(blocks)
    if mask is not None:
        bad |= mask[: ny * b, : nx * b]
    if bad.any():
        blocks = np.where(bad, np.float32(fill), blocks)
    blocks = blocks.reshape(ny, b, nx, b)
    total = blocks.sum(axis=(1, 3), dtype=np.float64)
    peak = blocks.max(axis=(1, 3))
    out[:] = (total - peak) / (b * b - 1)
    return out


def peak_candidates(img, threshold, n_max, border=0):
    """
    Strict 3x3 local maxima above ``threshold``, brightest first.

    Returns
    -------
    y, x : int ndarrays
        Peak pixels.
    score : ndarray
        Sum of the 3x3 neighbourhood (a flux proxy used for ranking).
    """
    if HAVE_NUMBA:
        y, x, s = _peaks_nb(np.ascontiguousarray(img, dtype=np.float32), float(threshold),
                            int(border))
    else:  # pragma: no cover - same result without numba
        from scipy.ndimage import maximum_filter, uniform_filter

        mx = maximum_filter(img, size=3, mode="constant", cval=-np.inf)
        cand = (img >= mx) & (img > threshold)
        if border:
            cand[:border] = cand[-border:] = False
            cand[:, :border] = cand[:, -border:] = False
        y, x = np.nonzero(cand)
        s = uniform_filter(img.astype(np.float64), 3, mode="constant")[y, x] * 9
    order = np.lexsort((x, y, -s))[:n_max]
    return y[order], x[order], s[order]
