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

__all__ = ["bin_despike", "peak_candidates", "has_nonfinite", "PointGrid", "count_inliers"]


if HAVE_NUMBA:

    @njit(cache=True, parallel=True, nogil=True)
    def _bin_despike_nb(data, mask, use_mask, b, fill, out):
        ny, nx = out.shape
        inv = 1.0 / (b * b - 1)
        for i in prange(ny):
            # Walk the b source rows of this output row in memory order.
            total = np.zeros(nx)
            peak = np.full(nx, -np.inf)
            for di in range(b):
                row = data[i * b + di]
                for j in range(nx):
                    t = 0.0
                    p = peak[j]
                    for dj in range(b):
                        v = row[j * b + dj]
                        if not np.isfinite(v) or (use_mask and mask[i * b + di, j * b + dj]):
                            v = fill
                        t += v
                        if v > p:
                            p = v
                    total[j] += t
                    peak[j] = p
            for j in range(nx):
                out[i, j] = (total[j] - peak[j]) * inv

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
        m = np.zeros((1, 1), bool) if mask is None else np.ascontiguousarray(mask)
        _bin_despike_nb(arr, m, mask is not None, b, float(fill), out)
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


class PointGrid:
    """
    Target points bucketed in square cells, for exact radius look-ups.

    A cell is at least ``radius`` wide, so the neighbours of a position
    within ``radius`` are all in its 3x3 block of cells.  Used to count the
    inliers of thousands of hypotheses at once (`count_inliers`), which a
    k-d tree does one query at a time.
    """

    def __init__(self, points, radius, max_cells=4_000_000):
        pts = np.ascontiguousarray(points, dtype=np.float64)
        lo = pts.min(axis=0) - radius
        hi = pts.max(axis=0) + radius
        cell = float(radius)
        span = hi - lo
        while (span[0] / cell + 1) * (span[1] / cell + 1) > max_cells:
            cell *= 2.0
        self.radius = float(radius)
        self.cell = cell
        self.origin = lo
        self.nx = int(span[0] // cell) + 1
        self.ny = int(span[1] // cell) + 1
        cx = ((pts[:, 0] - lo[0]) // cell).astype(np.int64)
        cy = ((pts[:, 1] - lo[1]) // cell).astype(np.int64)
        cid = cy * self.nx + cx
        order = np.argsort(cid, kind="stable")
        self.points = pts[order]
        self.start = np.searchsorted(cid[order], np.arange(self.nx * self.ny + 1)).astype(
            np.int64)


if HAVE_NUMBA:

    @njit(cache=True, parallel=True, nogil=True)
    def _count_nb(mats, src, pts, start, ox, oy, cell, nx, ny, r2, out):
        for h in prange(mats.shape[0]):
            a, b, c = mats[h, 0, 0], mats[h, 0, 1], mats[h, 0, 2]
            d, e, f = mats[h, 1, 0], mats[h, 1, 1], mats[h, 1, 2]
            n = 0
            for k in range(src.shape[0]):
                x = a * src[k, 0] + b * src[k, 1] + c
                y = d * src[k, 0] + e * src[k, 1] + f
                if not (x == x and y == y):
                    continue
                fx = (x - ox) / cell
                fy = (y - oy) / cell
                if fx < -1.0 or fy < -1.0 or fx > nx or fy > ny:
                    continue
                cx = int(np.floor(fx))
                cy = int(np.floor(fy))
                found = False
                for j in range(max(cy - 1, 0), min(cy + 2, ny)):
                    if found:
                        break
                    for i in range(max(cx - 1, 0), min(cx + 2, nx)):
                        cid = j * nx + i
                        for q in range(start[cid], start[cid + 1]):
                            dx = pts[q, 0] - x
                            dy = pts[q, 1] - y
                            if dx * dx + dy * dy < r2:
                                found = True
                                break
                        if found:
                            break
                if found:
                    n += 1
            out[h] = n


def count_inliers(mats, src, grid):
    """
    For each 3x3 matrix, how many ``src`` points land within the grid's
    radius of one of its points.

    Parameters
    ----------
    mats : (K, 3, 3) ndarray
    src : (N, 2) ndarray
    grid : `PointGrid`

    Returns
    -------
    counts : (K,) int ndarray
    """
    mats = np.ascontiguousarray(mats, dtype=np.float64)
    src = np.ascontiguousarray(src, dtype=np.float64)
    if HAVE_NUMBA:
        out = np.zeros(len(mats), dtype=np.int64)
        _count_nb(mats, src, grid.points, grid.start, float(grid.origin[0]),
                  float(grid.origin[1]), grid.cell, grid.nx, grid.ny, grid.radius**2, out)
        return out
    from scipy.spatial import cKDTree  # pragma: no cover

    tree = cKDTree(grid.points)
    pred = np.einsum("kij,nj->kni", mats[:, :2, :2], src) + mats[:, None, :2, 2]
    d, _ = tree.query(pred.reshape(-1, 2), distance_upper_bound=grid.radius)
    return np.isfinite(d).reshape(len(mats), -1).sum(axis=1)


if HAVE_NUMBA:

    @njit(cache=True, parallel=True, nogil=True)
    def _count_nonfinite_nb(flat):
        n = 0
        for i in prange(flat.size):
            if not np.isfinite(flat[i]):
                n += 1
        return n


def has_nonfinite(arr):
    """True if a float array has a NaN or infinite value (one parallel pass)."""
    if arr.dtype.kind != "f":
        return False
    if HAVE_NUMBA and arr.flags.c_contiguous:
        return _count_nonfinite_nb(arr.reshape(-1)) > 0
    return not np.isfinite(arr).all()
