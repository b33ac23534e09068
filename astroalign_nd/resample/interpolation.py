# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Interpolation orders and the NumPy interpolation kernels (the compiled ones' fallback)."""

import numpy as np

# The orders' table and their check are resample.options' (ORDERS, order_index).
__all__ = []

# Output pixels per tile of the NumPy path: its dozen temporaries then stay
# in the CPU's cache (a block of 2**14 pixels runs twice as fast as one of 2**18).
_NUMPY_BLOCK_PIXELS = 1 << 14

#: Side of the NumPy path's square output tiles (128 x 128 = `_NUMPY_BLOCK_PIXELS`).
_NUMPY_TILE = 128

# -- kernel weights (NumPy path; the compiled kernels in _ckernels.pyx are the same) --


def _linear_weights(f):
    # Two taps (the NumPy path uses ``order + 1`` weights).
    return 1.0 - f, f


def _quadratic_weights(t):
    # Dodgson's interpolating quadratic, taps c-1, c, c+1 with t = x - c in [-0.5, 0.5).
    return t * (t - 0.5), 1.0 - 2.0 * t * t, t * (t + 0.5), 0.0 * t


def _keys_weights(f):
    # Keys cubic convolution, a = -0.5, taps floor(x)-1 .. floor(x)+2, f = x - floor(x).
    return (
        ((-0.5 * f + 1.0) * f - 0.5) * f,
        (1.5 * f - 2.5) * f * f + 1.0,
        ((-1.5 * f + 2.0) * f + 0.5) * f,
        (0.5 * f - 0.5) * f * f,
    )


_WEIGHT_FUNCS = (None, _linear_weights, _quadratic_weights, _keys_weights)

# -- NumPy fallback ------------------------------------------------------------------


def _axis_taps_numpy(u, n, order):
    """Vectorised `_axis_taps`: first tap index, validity and the 4 weights."""
    if order == 0:
        ok = (u >= -0.5) & (u <= n - 0.5)
        i0 = np.clip(np.floor(np.where(ok, u, 0.0) + 0.5), 0, n - 1).astype(np.intp)
        one, zero = np.ones_like(u), np.zeros_like(u)
        return i0, ok, (one, zero, zero, zero)
    ok = (u > -3.0) & (u < n + 2.0)
    u = np.where(ok, u, 0.0)
    if order == 2:
        c = np.floor(u + 0.5)
        w = _WEIGHT_FUNCS[2](u - c)
        i0 = c - 1
    else:
        fl = np.floor(u)
        w = _WEIGHT_FUNCS[order](u - fl)
        i0 = fl if order == 1 else fl - 1
    i0 = i0.astype(np.intp)
    for k in range(order + 1):
        # Only taps with nonzero weight must lie inside the image.
        ok &= (w[k] == 0.0) | ((i0 + k >= 0) & (i0 + k <= n - 1))
    return i0, ok, w


def _interp_numpy(data, var, has_var, u, v, fill, sd, sv, out, out_var, out_mask, order,
                  finite=False, bounds=None):
    """
    The compiled kernel's interpolation at source positions ``(u, v)`` (NaN: outside).

    The same taps, weights and summation order as the compiled kernel, so the
    same bits.  ``finite`` says the planes hold no NaN or infinity: then a tap
    of zero weight adds zero, and the guards that keep its NaN out are skipped.
    ``bounds``, if known: ``(u.min(), u.max(), v.min(), v.max())``.
    """
    ny, nx = data.shape
    if finite and order == 1:
        return _bilinear_finite(data, var, has_var, u, v, fill, sd, sv, out, out_var, out_mask,
                                bounds)
    jx, okx, wx = _axis_taps_numpy(u, nx, order)
    jy, oky, wy = _axis_taps_numpy(v, ny, order)
    inside = okx & oky
    flat = data.ravel()  # (gathers from a flat plane: much faster than [rows, cols])
    flat_var = var.ravel() if has_var else None
    acc = np.zeros(inside.shape)
    accv = np.zeros(inside.shape) if has_var else 0.0
    rows = [np.clip(jy + ky, 0, ny - 1) * nx for ky in range(order + 1)]
    cols = [np.clip(jx + kx, 0, nx - 1) for kx in range(order + 1)]
    for ky in range(order + 1):
        for kx in range(order + 1):
            idx = rows[ky] + cols[kx]
            w = wy[ky] * wx[kx]
            if finite:
                acc += w * flat.take(idx)
                if has_var:
                    accv += w * w * flat_var.take(idx)
                continue
            # Taps with zero weight along an axis are not used (the compiled
            # kernel skips them), so their NaNs must not leak in.
            use = inside & (wy[ky] != 0.0) & (wx[kx] != 0.0)
            acc += np.where(use, w * flat.take(idx), 0.0)
            if has_var:
                accv += np.where(use, w * w * flat_var.take(idx), 0.0)
    good = inside & np.isfinite(acc) & np.isfinite(accv)
    out[...] = np.where(good, acc * sd, fill)
    if has_var:
        out_var[...] = np.where(good, accv * sv, np.inf)
    out_mask[...] = ~good


def _linear_taps(u, n):
    """
    `_axis_taps_numpy` for order 1, unclipped: first tap, validity, the 2 weights.

    The validity in three passes instead of a dozen: a position's two taps
    ``i = floor(u)`` and ``i + 1``, weighted ``1 - f`` and ``f = u - i``,
    are both on the plane or of weight zero exactly when ``0 <= u <= n - 1``,
    or when ``u`` is a negative so small that ``f = u + 1`` rounds to 1 (the
    weight of tap -1 is then zero): together, ``u + 1 >= 1`` and
    ``u <= n - 1``.  (The tests check it against the rules of
    `_axis_taps_numpy`.)  Elsewhere the taps and weights are of no use.
    """
    u = np.clip(u, -3.0, n + 2.0)  # (no cast of a huge position to an integer)
    fl = np.floor(u)
    i = fl.astype(np.intp)
    f = np.subtract(u, fl, out=fl)
    ok = u + 1.0 >= 1.0
    ok &= u <= n - 1.0
    return i, ok, 1.0 - f, f


def _bilinear_finite(data, var, has_var, u, v, fill, sd, sv, out, out_var, out_mask,
                     bounds=None):
    """
    `_interp_numpy` at order 1 on planes without NaN or infinity: the same
    taps, weights and sums, with fewer passes.  Taps off the plane are read
    clipped (any finite value): their weight is zero, or the pixel is outside.
    """
    ny, nx = data.shape
    ulo, uhi, vlo, vhi = (u.min(), u.max(), v.min(), v.max()) if bounds is None else bounds
    if nx > 1 and ny > 1 and ulo >= 0.0 and uhi <= nx - 2.0 and vlo >= 0.0 and vhi <= ny - 2.0:
        # Every pixel's four taps are on the plane (most tiles of a frame):
        # no validity to work out.
        fx, fy = np.floor(u), np.floor(v)
        jx, jy = fx.astype(np.intp), fy.astype(np.intp)
        wx1, wy1 = np.subtract(u, fx, out=fx), np.subtract(v, fy, out=fy)
        wx0, wy0 = 1.0 - wx1, 1.0 - wy1
        inside = None
    else:
        jx, okx, wx0, wx1 = _linear_taps(u, nx)
        jy, oky, wy0, wy1 = _linear_taps(v, ny)
        inside = okx & oky
    base = jy * nx
    base += jx
    # Each tap read at ``base`` from the plane shifted by its offset (a view:
    # no index array per tap).
    taps = ((wy0 * wx0, 0), (wy0 * wx1, 1), (wy1 * wx0, nx), (wy1 * wx1, nx + 1))
    acc = _weighted_sum(data.ravel(), base, taps, squared=False)
    good = np.isfinite(acc)
    if inside is not None:
        good &= inside
    if has_var:
        accv = _weighted_sum(var.ravel(), base, taps, squared=True)
        good &= np.isfinite(accv)
    if good.all():  # (no fill value to place)
        if has_var:
            out_var[...] = accv * sv if sv != 1.0 else accv
        out[...] = acc * sd if sd != 1.0 else acc
        out_mask[...] = False
        return
    if has_var:
        out_var[...] = np.where(good, accv * sv, np.inf)
    out[...] = np.where(good, acc * sd, fill)
    out_mask[...] = ~good


def _weighted_sum(flat, base, taps, squared):
    """
    The sum over ``taps`` ``(weight, offset)`` of each weight (squared for a
    variance) times the value of ``flat`` at ``base + offset``, in the taps'
    order: the compiled kernel's sum (which starts from zero; zero plus the
    first term is the first term).  Indices off the plane are clipped.
    """
    acc = term = None
    for w, off in taps:
        vals = flat[off:].take(base, mode="clip")
        if squared:
            term = np.multiply(w, w, out=term)
            term *= vals
        else:
            term = np.multiply(w, vals, out=term)
        if acc is None:
            acc, term = term, None
        else:
            acc += term
    return acc


def _all_outside(umin, umax, n, order):
    """
    True if no position from ``umin`` to ``umax`` along an axis of ``n``
    pixels has its taps on the plane (`_axis_taps_numpy` would find every
    one outside).
    """
    # (Beyond the bounds `_axis_taps_numpy` tests first, with a pixel to spare.)
    lo, hi = (-1.5, n + 0.5) if order == 0 else (-4.0, n + 3.0)
    return bool(umax < lo or umin > hi)


def _tile_shape(ny_out, nx_out):
    """
    Output tile ``(rows, columns)`` of the NumPy path: square tiles of
    `_NUMPY_TILE` a side, or wider/taller ones of as many pixels when the
    output is narrower than a tile (a thin output still gets few tiles).
    """
    tx = min(_NUMPY_TILE, nx_out)
    ty = min(ny_out, max(_NUMPY_TILE, _NUMPY_BLOCK_PIXELS // tx))
    return ty, tx


def _resample_tiles(data, var, has_var, m, fill, sd, sv, out, out_var, out_mask, order, finite,
                    tile, start, stop):
    """Tiles ``start:stop`` (raster order) of `_resample_numpy`'s output."""
    ny_out, nx_out = out.shape
    ny_in, nx_in = data.shape
    ty, tx = tile
    per_row = -(-nx_out // tx)
    # The row and column terms of the positions, shared by the tiles of a
    # column or row of tiles.
    cols, rows = {}, {}
    for t in range(start, stop):
        y0, x0 = (t // per_row) * ty, (t % per_row) * tx
        ys, xs = slice(y0, min(y0 + ty, ny_out)), slice(x0, min(x0 + tx, nx_out))
        if x0 not in cols:
            xo = np.arange(xs.start, xs.stop, dtype=float)[None, :]
            cols[x0] = (m[0] * xo, m[3] * xo)
        if y0 not in rows:
            yo = np.arange(ys.start, ys.stop, dtype=float)[:, None]
            rows[y0] = (m[1] * yo + m[2], m[4] * yo + m[5])
        # Per pixel the same operations as over whole rows: the same bits.
        u = cols[x0][0] + rows[y0][0]
        v = cols[x0][1] + rows[y0][1]
        bounds = (u.min(), u.max(), v.min(), v.max())
        if _all_outside(*bounds[:2], nx_in, order) or _all_outside(*bounds[2:], ny_in, order):
            # (The corners of a rotated frame: nothing of the source there.)
            out[ys, xs] = fill
            if has_var:
                out_var[ys, xs] = np.inf
            out_mask[ys, xs] = True
            continue
        _interp_numpy(data, var, has_var, u, v, fill, sd, sv, out[ys, xs],
                      out_var[ys, xs] if has_var else None, out_mask[ys, xs], order, finite,
                      bounds)


def _resample_numpy(data, var, has_var, m, fill, sd, sv, out, out_var, out_mask, *, order):
    """
    Same result as the compiled kernel, with NumPy gathers over square tiles of
    the output.

    A tile's taps lie in a compact patch of the source, which stays in the
    CPU's caches, where a band of whole output rows of a rotated frame reads
    a new source row (and memory page) every few pixels: at 4096 x 4096 the
    tiles take a third of the bands' time.  Tiles wholly off the source are
    filled at once, and a tile wholly on it skips the validity tests.  The
    tiles run on the calling thread: split over two threads (NumPy releases
    the GIL in each operation), the many short operations of a tile wait for
    each other's GIL and took as long as one thread, or longer, on a busy
    2-core machine.
    """
    ny_out, nx_out = out.shape
    data = np.ascontiguousarray(data)
    var = np.ascontiguousarray(var) if has_var else var
    # One check of the whole planes spares every tap its NaN guard.
    finite = bool(np.isfinite(data).all()) and (not has_var or bool(np.isfinite(var).all()))
    tile = _tile_shape(ny_out, nx_out)
    n_tiles = -(-ny_out // tile[0]) * -(-nx_out // tile[1])
    _resample_tiles(data, var, has_var, m, fill, sd, sv, out, out_var, out_mask, order, finite,
                    tile, 0, n_tiles)
