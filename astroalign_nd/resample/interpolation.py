# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Interpolation orders and the NumPy interpolation kernels (the compiled ones' fallback)."""

import numpy as np

# The orders' table and their check are resample.options' (ORDERS, order_index).
__all__ = []

# Output pixels per block of the NumPy path: its dozen temporaries then stay
# in the CPU's cache (a block of 2**14 pixels runs twice as fast as one of 2**18).
_NUMPY_BLOCK_PIXELS = 1 << 14

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
                  finite=False):
    """
    The compiled kernel's interpolation at source positions ``(u, v)`` (NaN: outside).

    The same taps, weights and summation order as the compiled kernel, so the
    same bits.  ``finite`` says the planes hold no NaN or infinity: then a tap
    of zero weight adds zero, and the guards that keep its NaN out are skipped.
    """
    ny, nx = data.shape
    if finite and order == 1:
        return _bilinear_finite(data, var, has_var, u, v, fill, sd, sv, out, out_var, out_mask)
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
    """`_axis_taps_numpy` for order 1, unclipped: first tap, validity, the 2 weights."""
    ok = (u > -3.0) & (u < n + 2.0)
    fl = np.floor(np.where(ok, u, 0.0))
    f = u - fl
    i = fl.astype(np.intp)
    w0 = 1.0 - f
    # Only taps with nonzero weight must lie inside the image.
    ok &= (w0 == 0.0) | ((i >= 0) & (i <= n - 1))
    ok &= (f == 0.0) | ((i >= -1) & (i <= n - 2))
    return i, ok, w0, f


def _bilinear_finite(data, var, has_var, u, v, fill, sd, sv, out, out_var, out_mask):
    """
    `_interp_numpy` at order 1 on planes without NaN or infinity: the same
    taps, weights and sums, with fewer passes.  Taps off the plane are read
    clipped (any finite value): their weight is zero, or the pixel is outside.
    """
    ny, nx = data.shape
    jx, okx, wx0, wx1 = _linear_taps(u, nx)
    jy, oky, wy0, wy1 = _linear_taps(v, ny)
    inside = okx & oky
    base = jy * nx + jx
    taps = ((wy0 * wx0, base), (wy0 * wx1, base + 1), (wy1 * wx0, base + nx),
            (wy1 * wx1, base + (nx + 1)))
    acc = _weighted_sum(data.ravel(), taps, squared=False)
    good = inside & np.isfinite(acc)
    if has_var:
        accv = _weighted_sum(var.ravel(), taps, squared=True)
        good &= np.isfinite(accv)
        out_var[...] = np.where(good, accv * sv, np.inf)
    out[...] = np.where(good, acc * sd, fill)
    out_mask[...] = ~good


def _weighted_sum(flat, taps, squared):
    """
    The sum over ``taps`` of each weight (squared for a variance) times the
    tap's value of ``flat``, in the taps' order: the compiled kernel's sum
    (which starts from zero; zero plus the first term is the first term).
    """
    acc = term = None
    for w, idx in taps:
        vals = flat.take(idx, mode="clip")
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


def _resample_numpy(data, var, has_var, m, fill, sd, sv, out, out_var, out_mask, *, order):
    """Same result as the compiled kernel, with NumPy gathers over blocks of rows."""
    ny_out, nx_out = out.shape
    block = max(1, _NUMPY_BLOCK_PIXELS // max(nx_out, 1))
    xo = np.arange(nx_out, dtype=float)[None, :]
    data = np.ascontiguousarray(data)
    var = np.ascontiguousarray(var) if has_var else var
    # One check of the whole planes spares every tap its NaN guard.
    finite = bool(np.isfinite(data).all()) and (not has_var or bool(np.isfinite(var).all()))
    for y0 in range(0, ny_out, block):
        yo = np.arange(y0, min(y0 + block, ny_out), dtype=float)[:, None]
        sl = slice(y0, y0 + len(yo))
        u = m[0] * xo + (m[1] * yo + m[2])
        v = m[3] * xo + (m[4] * yo + m[5])
        _interp_numpy(data, var, has_var, u, v, fill, sd, sv, out[sl],
                      out_var[sl] if has_var else None, out_mask[sl], order, finite)
