# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Full-frame and all-hypotheses passes of detection and matching.

Only a few passes touch every pixel of a frame (binning, the candidate peak
search, the finiteness check) or every (hypothesis, star) pair (inlier
counting).  They are single loops compiled with Cython
(`astroalign_nd._ckernels`); this module wraps them, splits large jobs over
threads (`num_threads`, set by ``astroalign_nd.conf.num_threads``), and
holds NumPy versions of the same operations, which the tests use as
references and which run if the compiled module is missing from a source
checkout that was never built (or with ``conf.use_compiled = False``).
"""

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ._settings import _ENV_NUM_THREADS, NUM_THREADS_ENV, conf

try:
    from . import _ckernels

    HAVE_COMPILED = True
except ImportError:  # pragma: no cover - installed without a C compiler, or an unbuilt tree
    _ckernels = None
    HAVE_COMPILED = False

__all__ = ["bin_despike", "peak_candidates", "median", "finite_sample", "windowed_centroid",
           "adaptive_fwhm", "PointGrid", "two_nearest",
           "count_inliers", "num_threads", "compiled_kernels",
           "run_split", "GAUSS_SIGMA_TO_FWHM"]

#: FWHM of a Gaussian in units of its sigma (detection and simulation share it).
GAUSS_SIGMA_TO_FWHM = 2.0 * np.sqrt(2.0 * np.log(2.0))

#: Whether `warn_if_slow` has warned in this process.
_WARNED_SLOW = False

#: The command that installs a binary wheel (compiled loops included), never a build from source.
WHEEL_COMMAND = "pip install --only-binary astroalign_nd astroalign_nd"

#: What `warn_if_slow` says.  The cost is measured with
#: ``benchmarks/bench_speed_workloads.py --numpy-kernels`` (docs/benchmarks.rst,
#: "Without the compiled loops"): ``register`` of a simulated pair against the
#: compiled loops' time, in the same run.
SLOW_KERNELS_MESSAGE = (
    "astroalign_nd's compiled loops are not built, so detection, matching and resampling "
    "run their NumPy versions: the same results, slower (register() of a simulated "
    "1024x1024 pair took 1.7 times as long as with the compiled loops, of a 4096x4096 pair "
    "2.1 times). For the compiled loops, install a binary wheel: "
    f"`{WHEEL_COMMAND}` (or reinstall from source with a C compiler and Cython present). "
    "astroalign_nd.HAVE_COMPILED tells which loops run; this warning is given once per "
    "process.")


def warn_if_slow():
    """
    Say once per process that the compiled loops are not built
    (`~astroalign_nd.exceptions.SlowKernelsWarning`, `SLOW_KERNELS_MESSAGE`:
    what it costs, and the command that installs a wheel), at the first
    registration rather than at import: an import that registers nothing
    (a catalog tool, the docs) has nothing to be told.  Loops turned off
    on purpose (``conf.use_compiled = False``) are not warned about.
    """
    global _WARNED_SLOW
    if HAVE_COMPILED or _WARNED_SLOW:
        return
    _WARNED_SLOW = True
    from .exceptions import SlowKernelsWarning, warn

    warn(SLOW_KERNELS_MESSAGE, SlowKernelsWarning)


# -- threads -----------------------------------------------------------------------

_POOL = None
_POOL_KEY = None
_POOL_LOCK = threading.Lock()


def num_threads():
    """
    Threads used by the compiled loops.

    ``astroalign_nd.conf.num_threads`` if not 0; otherwise
    ``ASTROALIGN_ND_NUM_THREADS`` if it was set in the environment (e.g. 1
    when several worker processes share a machine); otherwise the number of
    CPUs this process may run on.
    """
    n = conf.num_threads
    if n == 0 and _ENV_NUM_THREADS:
        try:
            n = int(_ENV_NUM_THREADS)
        except ValueError:
            n = 0
        if n < 1:
            raise ValueError(
                f"{NUM_THREADS_ENV} must be a positive integer (1 or more; unset it "
                f"to use every CPU); got {_ENV_NUM_THREADS!r}.")
    if n < 0:
        raise ValueError("astroalign_nd.conf.num_threads must be a positive integer, or 0 for "
                         f"every CPU; got {n}.")
    if n:
        return n
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def threads_chosen():
    """
    True when the user chose the thread count (configuration or environment).

    Examples
    --------
    >>> from astroalign_nd._kernels import threads_chosen
    >>> isinstance(threads_chosen(), bool)
    True
    """
    return conf.num_threads != 0 or bool(_ENV_NUM_THREADS)


def core_to_spare():
    """
    Is a CPU idle enough for a second thread of Python work: the system's
    load average (1 minute) below the CPUs this process may use less a
    half?  True where the load is unknown (not Unix).

    A thread pays only on a free core: two GIL-bound detections on busy
    cores take turns and hand the interpreter over at every NumPy call
    (on 2 busy cores, two small frames detected at once took 1.02-1.15
    times as long as one after the other).

    Examples
    --------
    >>> from astroalign_nd._kernels import core_to_spare
    >>> isinstance(core_to_spare(), bool)
    True
    """
    try:
        load = os.getloadavg()[0]
    except (AttributeError, OSError):  # pragma: no cover - not Unix
        return True
    return bool(load < num_threads() - 0.5)


def _compiled():
    """Run the compiled loops: built, and not turned off by ``conf.use_compiled``."""
    return HAVE_COMPILED and conf.use_compiled


def compiled_kernels():
    """
    The compiled extension module (``astroalign_nd._ckernels``) for other stages' loops
    (the resampling kernels), or None: not built, or ``conf.use_compiled`` is False.
    """
    return _ckernels if _compiled() else None


def _after_fork_in_child():
    # The parent's worker threads do not exist in the child, and a lock held by
    # one of its other threads at fork time would never be released.
    global _POOL, _POOL_KEY, _POOL_LOCK
    _POOL, _POOL_KEY, _POOL_LOCK = None, None, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def _pool(n):
    global _POOL, _POOL_KEY
    key = (os.getpid(), n)  # a forked child must not reuse its parent's (dead) threads
    with _POOL_LOCK:
        if _POOL_KEY != key:
            # A replaced pool's idle threads exit once it is garbage collected; it
            # is not shut down, as another thread may still be submitting to it.
            _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix="astroalign_nd")
            _POOL_KEY = key
        return _POOL


_SIDE_POOL = None
_SIDE_PID = None


def side_pool():
    """
    A one-thread pool for whole tasks run beside the caller (the target's
    detection in `~astroalign_nd.register`), kept between calls.

    Separate from the compiled loops' pool: a task here may itself split
    its loops over that pool, which must then have its threads free.
    """
    global _SIDE_POOL, _SIDE_PID
    with _POOL_LOCK:
        if _SIDE_PID != os.getpid():  # not a forked parent's (dead) thread
            _SIDE_POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="astroalign_nd_side")
            _SIDE_PID = os.getpid()
        return _SIDE_POOL


def run_split(fn, n, args, min_per_thread=1, parallel=True, start=0):
    """
    Call ``fn(*args, start, stop)`` over ``range(start, start + n)`` split
    into contiguous chunks, one per thread; return the list of results in
    chunk order.

    The compiled functions release the GIL, so the chunks run at the same
    time.  Each chunk writes its own rows, so the result does not depend on
    the number of threads.
    """
    most = num_threads() if parallel else 1
    nt = max(1, min(most, n // max(1, min_per_thread)))
    if nt == 1:
        return [fn(*args, start, start + n)]
    bounds = [start + int(k) for k in np.linspace(0, n, nt + 1)]
    # The calling thread runs the first chunk itself; the pool (one size per
    # thread setting, whatever this call's chunk count) runs the others.
    pool = _pool(most - 1)
    futures = [pool.submit(fn, *args, a, b) for a, b in zip(bounds[1:-1], bounds[2:])]
    try:
        first = fn(*args, bounds[0], bounds[1])
    finally:
        rest = [f.result() for f in futures]  # never leave a chunk running
    return [first] + rest


# -- detection ---------------------------------------------------------------------

#: Input pixels `bin_despike` gives a thread at least (about a millisecond of
#: work): a smaller frame is binned in the calling thread, since waking
#: another costs more than it saves when the cores are busy (a 256 x 256
#: frame binned in 0.13 ms alone took 0.26 ms at best and 7.7 ms at the
#: median in two threads, at a load average of 7 on 2 cores).
_BIN_PIXELS_PER_THREAD = 1 << 20


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
    if _compiled() and data.dtype in (np.float32, np.float64) and ny > 0 and nx > 0:
        arr = np.ascontiguousarray(data)
        m = np.zeros((1, 1), np.uint8) if mask is None else np.ascontiguousarray(
            mask, dtype=bool).view(np.uint8)
        args = (arr, m, mask is not None, int(b), float(fill), out)
        # Whole output rows read b full-width input rows each.
        rows = -(-_BIN_PIXELS_PER_THREAD // (b * data.shape[1]))
        run_split(_ckernels.bin_despike_rows, ny, args, min_per_thread=max(64, rows))
        return out
    blocks = np.asarray(data[: ny * b, : nx * b], dtype=np.float32)
    bad = ~np.isfinite(blocks)
    if mask is not None:
        bad |= mask[: ny * b, : nx * b]
    if bad.any():
        blocks = np.where(bad, np.float32(fill), blocks)
    if b <= 6:
        # Small blocks: one plane per position in the block, gathered once
        # into contiguous planes (one pass over the frame), then summed in
        # the block's raster order (the compiled loop's) and maximised:
        # beats any reshaped reduction, and strided planes read b * b times.
        planes = np.ascontiguousarray(
            blocks.reshape(ny, b, nx, b).transpose(1, 3, 0, 2)).reshape(b * b, ny, nx)
        total = np.zeros((ny, nx))
        for v in planes:
            total += v
        peak = planes.max(axis=0)
    else:
        # Down each block first (whole rows at a time, fast), then across the
        # remaining b columns: reducing both axes of a block at once is slow.
        cols = blocks.reshape(ny, b, nx * b)
        total = cols.sum(axis=1, dtype=np.float64).reshape(ny, nx, b).sum(axis=2)
        peak = cols.max(axis=1).reshape(ny, nx, b).max(axis=2)
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
    if _compiled():
        y, x, s = _ckernels.peaks(np.ascontiguousarray(img, dtype=np.float32),
                                  float(threshold), int(border))
    else:  # same result without the compiled module (the tests compare them)
        img = np.asarray(img, dtype=np.float32)
        ny, nx = img.shape
        pad = np.pad(img, 1, constant_values=-np.inf)
        cand = img > threshold
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                if di == 0 and dj == 0:
                    continue
                w = pad[1 + di:1 + di + ny, 1 + dj:1 + dj + nx]
                # Ties go to the first pixel in raster order.
                cand &= (img > w) if (di < 0 or (di == 0 and dj < 0)) else (img >= w)
        if border:
            cand[:border] = cand[ny - border:] = False
            cand[:, :border] = cand[:, nx - border:] = False
        y, x = np.nonzero(cand)
        # The 3x3 sums at the peaks only (in float64, in the compiled loop's order).
        s = np.zeros(len(y))
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                w = pad[1 + di + y, 1 + dj + x].astype(np.float64)
                s += np.where(np.isfinite(w), w, 0.0)
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

    def __init__(self, points, radius, max_cells=None):
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if max_cells is None:
            # A few cells per point keep a look-up at a few points; more only
            # cost building the index (4M cells: 8 ms on a 4k frame).
            max_cells = min(4_000_000, max(4096, 16 * len(pts)))
        radius = float(radius)
        if not (np.isfinite(radius) and radius > 0):
            raise ValueError(f"the matching radius (tolerance) must be a finite number > 0 "
                             f"pixels; got {radius!r}.")
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0 or not np.all(np.isfinite(pts)):
            raise ValueError("PointGrid needs a non-empty (N, 2) array of finite positions.")
        # (Reductions by column: along the first axis of an (N, 2) array they are slow.)
        x, y = pts[:, 0], pts[:, 1]
        lo = np.array([x.min(), y.min()]) - radius
        hi = np.array([x.max(), y.max()]) + radius
        span = hi - lo
        # Cells at least `radius` wide, and few enough: a cell of
        # sqrt(area / max_cells) already fits, so doubling ends within a few steps.
        cell = max(radius, float(np.sqrt(span[0] * span[1] / max_cells)))
        for _ in range(64):
            if (span[0] / cell + 1) * (span[1] / cell + 1) <= max_cells:
                break
            cell *= 2.0
        self.radius = float(radius)
        self.cell = cell
        self.origin = lo
        self.nx = int(span[0] // cell) + 1
        self.ny = int(span[1] // cell) + 1
        cx = ((pts[:, 0] - lo[0]) // cell).astype(np.int64)
        cy = ((pts[:, 1] - lo[1]) // cell).astype(np.int64)
        cid = cy * self.nx + cx
        #: ``points`` are the input's rows ``order``, cell after cell.
        self.order = np.argsort(cid)  # (a cell's points in any order: no stable sort)
        self.points = np.take(pts, self.order, axis=0)  # (rows: faster than [] indexing)
        # The first point of each cell (the count of the points in the cells before it).
        self.start = np.zeros(self.nx * self.ny + 1, np.intp)
        np.cumsum(np.bincount(cid, minlength=self.nx * self.ny), out=self.start[1:])


#: Queries of `two_nearest` per thread at least (a query costs ~50 ns).
_QUERIES_PER_THREAD = 1 << 16


#: A grid whose points see more than this many points in their own cell, on
#: average, is queried through a k-d tree (a dense cluster in a wide field).
_CROWDED = 32.0


def _crowded(grid):
    """True if the grid's cells are too unevenly filled for cell look-ups."""
    crowded = getattr(grid, "_crowded", None)
    if crowded is None:
        counts = np.diff(grid.start)
        crowded = grid._crowded = bool(
            float(counts @ counts) > _CROWDED * max(len(grid.points), 1))
    return crowded


def _grid_tree(grid):
    """A k-d tree of the grid's points, built once per grid (the NumPy paths' index)."""
    tree = getattr(grid, "_tree", None)
    if tree is None:
        from scipy.spatial import cKDTree

        # (Unbalanced, larger leaves: built in half the time, queried as fast.)
        tree = grid._tree = cKDTree(grid.points, leafsize=32, balanced_tree=False,
                                    compact_nodes=False)
    return tree


def two_nearest(query, grid, workers=1):
    """
    Each query's two nearest grid points closer than the grid's radius.

    What ``cKDTree(grid.points).query(query, k=2,
    distance_upper_bound=grid.radius)`` returns, from the 3x3 cells around
    each query: no tree to build, and one look-up at a few points.

    Parameters
    ----------
    query : (N, 2) ndarray
        Positions (non-finite ones find nothing).
    grid : `PointGrid`
    workers : int, optional
        Threads at most (-1: `num_threads`).

    Returns
    -------
    distance : (N, 2) ndarray
        Nearest first; ``inf`` where there is no point that close.
    index : (N, 2) ndarray of intp
        Rows of ``grid.points``; ``len(grid.points)`` where there is none.
    """
    query = np.ascontiguousarray(query, dtype=np.float64).reshape(-1, 2)
    kernel = getattr(_ckernels, "two_nearest_range", None) if _compiled() else None
    if kernel is None or _crowded(grid):  # (None: an extension built before it existed)
        tree = _grid_tree(grid)
        finite = np.isfinite(query).all(axis=1)  # (cKDTree refuses NaN queries)
        d = np.full((len(query), 2), np.inf)
        j = np.full((len(query), 2), len(grid.points), np.intp)
        if finite.any():
            d[finite], j[finite] = tree.query(query[finite], k=2,
                                              distance_upper_bound=grid.radius)
        return d, j
    d, j = np.empty((len(query), 2)), np.empty((len(query), 2), np.intp)
    if len(query):
        run_split(kernel, len(query),
                  (grid.points, grid.start, float(grid.origin[0]), float(grid.origin[1]),
                   grid.cell, grid.nx, grid.ny, query, grid.radius, j, d),
                  min_per_thread=_QUERIES_PER_THREAD, parallel=workers != 1)
    return d, j


def median(a, axis=None):
    """
    `numpy.median`, the same values, several times faster.

    numpy's median partitions around two elements for even lengths, which
    is slow (~8 ms along an axis for 1500 cutouts of 300 pixels; in 1-D
    several times slower than around one, which NumPy selects with SIMD
    code); one partition plus the maximum of the lower half gives the same
    values.  In 1-D a NaN makes the median NaN, as in numpy; along an axis,
    callers pass finite values only.
    """
    a = np.asarray(a)
    if axis is None:
        a, axis = a.ravel(), 0
    n = a.shape[axis]
    k = n // 2
    if a.ndim > 1:
        # Along the last axis of a C-ordered array: rows laid out so partition
        # several times faster (3.5x for the cutouts' outskirts, a column selection).
        a, axis = np.ascontiguousarray(np.moveaxis(a, axis, -1)), -1
    part = np.partition(a, k, axis=axis)
    if a.ndim == 1:
        hi = part[k]
        # NaN sorts last: the largest value from the middle on says whether there is one.
        if a.dtype.kind == "f" and np.isnan(np.max(part[k:])):
            return a.dtype.type(np.nan)
        # (lo + hi) / 2 in the array's type, as np.mean of the two.
        return hi if n % 2 else (np.max(part[:k]) + hi) / 2
    hi = part.take(k, axis=-1)
    if n % 2:
        return hi
    lo = np.max(part[..., :k], axis=-1)
    return np.mean(np.stack([lo, hi]), axis=0)


def finite_sample(data, mask, step):
    """
    The finite, unmasked pixels of ``data[::step, ::step]``, row by row
    (a frame's sample for the value that stands in for its bad pixels).
    """
    if _compiled() and data.dtype in (np.float32, np.float64):
        ny, nx = -(-data.shape[0] // step), -(-data.shape[1] // step)
        out = np.empty(ny * nx, data.dtype)
        m = np.zeros((1, 1), np.uint8) if mask is None else mask.view(np.uint8)
        k = _ckernels.finite_sample(data, m, mask is not None, int(step), out)
        return out[:k]
    good = data[::step, ::step]
    ok = np.isfinite(good)
    if mask is not None:
        ok &= ~mask[::step, ::step]
    return good[ok]


def windowed_centroid(cut, bad, x0, y0, sigma, n_iter=8):
    """
    Iterative Gaussian-windowed centroids (SExtractor's XWIN) of a stack
    of cutouts.

    Parameters
    ----------
    cut, bad : (n, size, size) ndarrays
        The cutouts and their bad pixels (which count as zero).
    x0, y0 : (n,) ndarrays
        Starting positions, pixels within the cutouts.
    sigma : (n,) ndarray
        Gaussian window widths (pixels).
    n_iter : int
        At most this many steps; the iterations stop once no star moves by
        1e-4 px or more.  A step is at most 1 px per axis.

    Returns
    -------
    x, y : (n,) ndarrays
    """
    x = np.array(x0, dtype=float)
    y = np.array(y0, dtype=float)
    img = np.where(bad, 0.0, cut)
    if _compiled() and img.ndim == 3 and img.shape[0]:
        # One pass per star and step, without NumPy's per-call overhead on
        # small arrays (and without the GIL).
        _ckernels.windowed_centroid(np.ascontiguousarray(img, dtype=float), x, y,
                                    np.ascontiguousarray(sigma, dtype=float), int(n_iter))
        return x, y
    n, size, _ = cut.shape
    g = np.arange(size, dtype=float)
    for _ in range(n_iter):
        dx = g[None, :] - x[:, None]
        dy = g[None, :] - y[:, None]
        wx = np.exp(-0.5 * (dx / sigma[:, None]) ** 2)
        wy = np.exp(-0.5 * (dy / sigma[:, None]) ** 2)
        # The window is separable: collapse one axis at a time instead of
        # forming the (n, size, size) weighted stack.
        col = np.matmul(wy[:, None, :], img)[:, 0, :]  # sum over rows
        row = np.matmul(img, wx[:, :, None])[:, :, 0]  # sum over columns
        tot = np.einsum("nj,nj->n", col, wx)
        ok = tot > 0
        sx = np.einsum("nj,nj->n", col, wx * dx)
        sy = np.einsum("ni,ni->n", row, wy * dy)
        # The factor 2 is the XWIN update for a Gaussian window.
        step_x = np.where(ok, 2.0 * sx / np.where(ok, tot, 1.0), 0.0)
        step_y = np.where(ok, 2.0 * sy / np.where(ok, tot, 1.0), 0.0)
        step_x = np.clip(step_x, -1.0, 1.0)
        step_y = np.clip(step_y, -1.0, 1.0)
        x += step_x
        y += step_y
        if np.max(np.abs(step_x), initial=0) < 1e-4 and np.max(np.abs(step_y), initial=0) < 1e-4:
            break
    return x, y


def lost_window_fraction(bad, x, y, sigma):
    """
    The fraction of each star's Gaussian window (width ``sigma``, centred
    at ``(x, y)`` in its cutout) that falls on bad pixels (beyond the
    frame's edge, masked): 0 for a star clear of edges and masks.
    """
    n, size, _ = bad.shape
    out = np.zeros(n)
    # Only cutouts with a bad pixel can lose any (the cutouts reach 3 FWHM).
    k = np.flatnonzero(bad.reshape(n, -1).any(axis=1))
    if not len(k):
        return out
    g = np.arange(size, dtype=float)
    wx = np.exp(-0.5 * ((g[None, :] - x[k, None]) / sigma[k, None]) ** 2)
    wy = np.exp(-0.5 * ((g[None, :] - y[k, None]) / sigma[k, None]) ** 2)
    lost = np.matmul(np.matmul(wy[:, None, :], bad[k].astype(float)), wx[:, :, None])[:, 0, 0]
    out[k] = lost / (wy.sum(axis=1) * wx.sum(axis=1))
    return out


def mirrored_windowed_centroid(cut, bad, x0, y0, sigma, n_iter=10):
    """
    Gaussian-windowed centroids of stars whose window meets bad pixels (the
    frame's edge, a mask), each bad pixel filled with the star's value at
    its mirror image through the current centre (iterated).

    Counting bad pixels as zero pulls a star cut by an edge towards the
    good side (0.16 px, 0.25 px for bright stars, within 1 FWHM of a frame's
    edge, on simulated frames).  A symmetric star filled from its mirror is
    whole again, and the window then converges to its centre.  Mirror
    images that are themselves bad, or beyond the cutout, count as zero.

    Parameters
    ----------
    cut, bad : (n, size, size) ndarrays
    x0, y0 : (n,) ndarrays
        Starting positions (pixels in the cutouts), e.g. `windowed_centroid`'s.
    sigma : (n,) ndarray
        Gaussian window widths (pixels).
    n_iter : int
        At most this many steps (each at most 1 px per axis).

    Returns
    -------
    x, y : (n,) ndarrays
    """
    x, y = np.array(x0, dtype=float), np.array(y0, dtype=float)
    sigma = np.asarray(sigma, dtype=float)
    n, size, _ = cut.shape
    if not n:
        return x, y
    if _compiled() and size:
        # One star at a time, the same floats as below without NumPy's
        # per-call overhead on a few small arrays (and without the GIL).
        img = np.where(bad, 0.0, cut).astype(float, copy=False)
        _ckernels.mirrored_windowed_centroid(
            np.ascontiguousarray(img), np.ascontiguousarray(bad, dtype=bool).view(np.uint8),
            x, y, np.ascontiguousarray(sigma), int(n_iter))
        return x, y
    return _mirrored_windowed_centroid_numpy(cut, bad, x, y, sigma, n_iter, _compiled())


def _mirrored_windowed_centroid_numpy(cut, bad, x, y, sigma, n_iter, fast):
    # `mirrored_windowed_centroid` in NumPy, updating x and y (float arrays)
    # in place; ``fast``: its windowed step is the compiled one.
    n, size, _ = cut.shape
    # All stars at once (a loop over stars cost 0.2 ms each, most of a
    # detection's time on a frame with many stars near its edges).
    img = np.where(bad, 0.0, cut).astype(float, copy=False).reshape(n, -1)
    # Each pixel's value and whether it is good, side by side: one lookup
    # reads both at a mirror image.
    pairs = np.stack([img.ravel(), (~bad).astype(float).ravel()])
    # Only the bad pixels are filled: their mirror images alone are read.
    kb, pb = np.nonzero(bad.reshape(n, -1))
    g = np.stack(np.divmod(pb, size)).astype(float)  # their (y, x)
    none_bad = np.zeros((1, 1, 1), bool)
    k = np.arange(n)
    yx = np.stack([y, x])
    last = max(size - 2, 0)
    sx, sy = (1, size) if size > 1 else (0, 0)
    # The four bilinear taps of a pixel, from its lower corner's index.
    taps = np.array([0, sx, sy, sy + sx])[:, None]
    filled = None
    for _ in range(n_iter):
        if filled is None:  # (again when stars stop)
            # The moving stars' images, their good pixels as they are, and
            # where their bad pixels are in them (refilled at every step).
            filled = img[k]
            at = (np.searchsorted(k, kb), pb)
            first = kb * (size * size)
        # Bilinear values at the mirror images (y then x in each array's two
        # rows), zero beyond [0, size - 1] (as `scipy.ndimage.map_coordinates`
        # with order 1 and ``cval=0`` gives them).
        c = 2.0 * yx.take(kb, axis=1) - g
        within = (c >= 0.0) & (c <= size - 1.0)
        inside = within[0] & within[1]
        c = np.where(inside, c, 0.0)
        # The last interval is [size - 2, size - 1]: its far tap then stays
        # inside.  (minimum/maximum: np.clip's overhead dominates here.)
        f = np.minimum(np.maximum(np.floor(c), 0), last)
        t = c - f
        u = 1.0 - t
        i00 = (f[0] * size + f[1]).astype(np.intp) + first
        p00, p01, p10, p11 = pairs.take(i00 + taps, axis=-1).transpose(1, 0, 2)
        val = u[0] * (u[1] * p00 + t[1] * p01) + t[0] * (u[1] * p10 + t[1] * p11)
        val = np.where(inside, val, 0.0)
        # A mirror image that touches a bad pixel is not the star's.
        filled[at] = np.where(val[1] > 0.999, val[0], 0.0)
        # One step of the windowed centroid on the stars made whole.
        y1, x1 = yx.take(k, axis=1)
        if fast:
            _ckernels.windowed_centroid(filled.reshape(len(k), size, size), x1, y1,
                                        sigma[k], 1)
        else:
            x1, y1 = windowed_centroid(filled.reshape(len(k), size, size),
                                       np.broadcast_to(none_bad, (len(k), size, size)),
                                       x1, y1, sigma[k], n_iter=1)
        moved = np.maximum(np.abs(x1 - yx[1, k]), np.abs(y1 - yx[0, k]))
        yx[0, k], yx[1, k] = y1, x1
        if (moved < 1e-4).any():  # those stop; the others go on
            k = k[moved >= 1e-4]
            if not len(k):
                break
            on = np.isin(kb, k)
            kb, pb, g = kb[on], pb[on], g[:, on]
            filled = None
    x[:], y[:] = yx[1], yx[0]
    return x, y


def adaptive_fwhm(cut, bad, dx, dy, sigma0=1.5, n_iter=8):
    """
    FWHM per cutout from Gaussian-weighted ("adaptive") second moments.

    A Gaussian window of width ``sigma_w`` measures a weighted variance
    ``s2`` of a Gaussian star of width ``sigma`` with
    ``1/s2 = 1/sigma^2 + 1/sigma_w^2``; iterating ``sigma_w = sigma``
    converges without the noise bias of unweighted moments.

    Parameters
    ----------
    cut, bad : (n, size, size) ndarrays
        The cutouts (sky subtracted) and their bad pixels (which count as zero).
    dx, dy : (n,) ndarrays
        Star positions relative to the cutouts' central pixel.
    sigma0 : float
        The first window's width (pixels).
    n_iter : int
        Iterations.

    Returns
    -------
    fwhm : (n,) ndarray
        NaN where the moments fail (no flux, or wider than the window allows).
    """
    n, size, _ = cut.shape
    half = size // 2
    img = np.where(bad, 0.0, cut)
    if _compiled() and n:
        sig = _ckernels.adaptive_sigma(np.ascontiguousarray(img, dtype=float),
                                       np.ascontiguousarray(dx, dtype=float),
                                       np.ascontiguousarray(dy, dtype=float),
                                       float(sigma0), int(n_iter))
    else:
        g = np.arange(size) - half
        sig_w = np.full(n, float(sigma0))
        ex = g[None, :] - dx[:, None]
        ey = g[None, :] - dy[:, None]
        sig = sig_w
        for _ in range(n_iter):
            wx = np.exp(-0.5 * (ex / sig_w[:, None]) ** 2)
            wy = np.exp(-0.5 * (ey / sig_w[:, None]) ** 2)
            col = np.matmul(wy[:, None, :], img)[:, 0, :]  # separable window, as above
            row = np.matmul(img, wx[:, :, None])[:, :, 0]
            tot = np.einsum("nj,nj->n", col, wx)
            mxx = np.einsum("nj,nj->n", col, wx * ex**2)
            myy = np.einsum("ni,ni->n", row, wy * ey**2)
            with np.errstate(invalid="ignore", divide="ignore"):
                s2 = 0.5 * (mxx + myy) / tot
                inv = 1.0 / s2 - 1.0 / sig_w**2
                sig = np.where((tot > 0) & (inv > 0), 1.0 / np.sqrt(np.abs(inv)), np.nan)
            sig_w = np.clip(np.nan_to_num(sig, nan=half / 3.0), 0.5, half / 3.0)
    # Remove the pixel-integration term (1/12 px^2 per axis).
    with np.errstate(invalid="ignore"):
        return GAUSS_SIGMA_TO_FWHM * np.sqrt(np.clip(sig**2 - 1.0 / 12.0, 0.0, None))


# -- matching ----------------------------------------------------------------------

#: Star lookups of `count_inliers` per thread before a second thread is used.
_INLIER_LOOKUPS_PER_THREAD = 50_000


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
    if _compiled():
        out = np.zeros(len(mats), dtype=np.intp)
        # A lookup costs ~10 ns: a thread is worth waking for ~50,000 of them
        # (a batch of 512 hypotheses of 50 stars runs faster on one thread).
        run_split(_ckernels.count_inliers_range, len(mats),
                  (mats, src, grid.points, grid.start, float(grid.origin[0]),
                   float(grid.origin[1]), grid.cell, grid.nx, grid.ny, grid.radius**2, out),
                  min_per_thread=max(1, _INLIER_LOOKUPS_PER_THREAD // max(1, len(src))))
        return out
    pred = (np.einsum("kij,nj->kni", mats[:, :2, :2], src) + mats[:, None, :2, 2]).reshape(-1, 2)
    # cKDTree refuses NaN/inf queries; such points match nothing (as in the compiled loop).
    finite = np.isfinite(pred).all(axis=1)
    hit = np.zeros(len(pred), dtype=bool)
    if finite.any():
        d, _ = _grid_tree(grid).query(pred[finite], distance_upper_bound=grid.radius)
        hit[finite] = np.isfinite(d)
    return hit.reshape(len(mats), -1).sum(axis=1)
