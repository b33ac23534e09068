# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Resampling of a source image onto the pixel grid of a target image.

`resample` interpolates a source image at the positions of the target
pixels, given the *source -> target* pixel transform: the 3x3 homogeneous
matrix of an affine transform (the ``matrix`` of the transforms in
`astroalign_nd.transforms`), or any 2-in 2-out model (projective,
polynomial, an astropy compound model...) that has an ``inverse``.
In the same pass it propagates a per-pixel variance image and a bad-pixel
mask, so the three outputs are always consistent with each other.

`resample_exact` does the same through `reproject.reproject_exact`
(flux-conserving spherical-polygon overlap), which is slower but exact for
the drizzle-like "how much of each source pixel falls into each target
pixel" question.

Conventions
-----------
Pixel coordinates are 0-based with pixel centres at integers, ``x`` along
columns and ``y`` along rows, as everywhere in this package.  For an
output (target) pixel ``(x', y')`` the source position is
``(x, y) = A^-1 ((x', y') - t)`` where ``A`` and ``t`` are the linear part and
the translation of ``matrix``.

Non-linear transforms
---------------------
A model that is not affine (or a projective 3x3 matrix) is resampled
through a *coordinate map*: the source position of every target pixel,
computed one band of output rows at a time (``_MAP_BAND_PIXELS`` pixels, a
few MB) and shared by all channels.  The model's ``inverse`` gives the first
guess; the forward model checks it, and positions whose round trip misses by
more than 1e-6 px (a fitted inverse, as SIP's AP/BP terms are) get Newton
steps on the forward model, at most 4: the first with the Jacobian of the
inverse map from differences between neighbouring target pixels (no model
evaluation), the next ones with the forward model's, by finite differences.  A
position still off by more than 1e-4 px (no source position: outside the
region where the model can be inverted), or NaN, gives a masked output
pixel.  The compiled kernel then interpolates data, variance and mask from
the map with the same kernels, footprint and mask rules as below.  A linear
model always takes the affine path (same bits as its matrix).

Interpolation kernels
---------------------
All kernels are separable (``w_ij = wy_i * wx_j``), local and interpolating
(a source position on a pixel centre returns that pixel's value exactly):

``'nearest-neighbor'`` (0)
    The pixel at ``floor(x + 0.5)`` (ties round up).
``'bilinear'`` (1)
    Linear interpolation between the 2 pixels ``floor(x)``, ``floor(x) + 1``.
``'biquadratic'`` (2)
    Dodgson's (1997) interpolating quadratic kernel on the 3 pixels around
    ``c = floor(x + 0.5)``: with ``t = x - c`` in ``[-0.5, 0.5)`` the weights
    of pixels ``c - 1, c, c + 1`` are ``t (t - 1/2)``, ``1 - 2 t^2``,
    ``t (t + 1/2)``.  It reproduces constants and straight lines.
``'bicubic'`` (3)
    Keys (1981) cubic convolution with ``a = -0.5`` on the 4 pixels
    ``floor(x) - 1 ... floor(x) + 2`` (third-order accurate, interpolating;
    *not* the B-spline of `scipy.ndimage`, which is not local).

Footprint and mask rules
------------------------
A source pixel is *used* by an output pixel when its weight is nonzero
(so a position exactly on a pixel centre uses that single pixel for every
order, and bilinear at ``x = 2.5`` uses two pixels whatever the order of
the other axis).  An output pixel is *bad* -- ``mask_out`` True, data set to
``fill_value``, variance set to ``+inf`` -- when

* any pixel it would use lies outside the source image (so near the edges
  the valid region shrinks by the kernel half-width: for bilinear a source
  position must satisfy ``0 <= x <= nx - 1``; for nearest-neighbour the
  whole pixel area ``-0.5 <= x <= nx - 0.5`` is accepted);
* any pixel it uses is flagged in ``mask``, or is NaN/inf in ``data`` (any
  channel: the mask is shared by all channels) or in ``variance``.  A
  bicubic kernel therefore spreads one bad source pixel to up to 4x4 output
  pixels (3x3 for biquadratic, 2x2 for bilinear, 1 for nearest, at
  magnification 1);
* the interpolated value or variance is not finite (overflow).

(Internally masked pixels are set to NaN and an output pixel is bad exactly
when its weighted sum is not finite, which implements the two rules above.)

Variance
--------
``variance_out = sum_ij w_ij**2 var_ij``: exact for the variance of each
output pixel given independent input pixels.  Resampling however makes
neighbouring *output* pixels correlated (they share input pixels), and this
covariance is not returned: summing ``variance_out`` over a large aperture
underestimates the variance of the aperture sum, at unit scale and averaged
over sub-pixel phases by a factor ~2.25 for bilinear, ~1.6 for biquadratic
and ~1.5 for bicubic (1 for nearest-neighbour, which copies pixels).

Flux conservation
-----------------
By default (``conserve_flux=False``) the output is a *surface brightness*
resampling: a flat sky of 100 counts/pixel stays 100.  With
``conserve_flux=True`` the output is multiplied by ``1 / |det A|`` (the
ratio target-pixel area / source-pixel area, measured in source pixels) so
that total counts are preserved: a transform that magnifies by ``s``
spreads each star over ``s**2`` more pixels, each holding ``1 / s**2`` of
the counts.  The variance is multiplied by ``1 / det(A)**2``.  Through a
coordinate map the factor is the local ``|det|`` of the map's Jacobian
(central differences between neighbouring target pixels), pixel by pixel.
"""

import numbers
from dataclasses import dataclass

import numpy as np

from ._kernels import HAVE_COMPILED, _ckernels, run_split

__all__ = ["ORDERS", "resample", "resample_exact"]

#: Interpolation orders by name (the names reproject and ccdproc use).
ORDERS = {"nearest-neighbor": 0, "bilinear": 1, "biquadratic": 2, "bicubic": 3}

# Set to False (e.g. by a test's monkeypatch) to force the pure-NumPy path.
_USE_COMPILED = True

# Output rows per thread, at least: below ~256x256 output pixels one thread does
# it all (waking a second one costs more than the work).
_MIN_PIXELS_PER_THREAD = 1 << 15

# Output pixels per block of the NumPy path: keeps its temporaries to tens of MB.
_NUMPY_BLOCK_PIXELS = 1 << 18


# -- kernel weights (NumPy path; the compiled kernels in _ckernels.pyx are the same) --

def _linear_weights(f):
    return 1.0 - f, f, 0.0 * f, 0.0 * f


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


def _interp_numpy(data, var, has_var, u, v, fill, sd, sv, out, out_var, out_mask, order):
    """The compiled kernel's interpolation at source positions ``(u, v)`` (NaN: outside)."""
    ny, nx = data.shape
    jx, okx, wx = _axis_taps_numpy(u, nx, order)
    jy, oky, wy = _axis_taps_numpy(v, ny, order)
    inside = okx & oky
    acc = np.zeros(inside.shape)
    accv = np.zeros(inside.shape)
    for ky in range(order + 1):
        rows = np.clip(jy + ky, 0, ny - 1)
        for kx in range(order + 1):
            cols = np.clip(jx + kx, 0, nx - 1)
            # Taps with zero weight along an axis are not used (the compiled
            # kernel skips them), so their NaNs must not leak in.
            use = inside & (wy[ky] != 0.0) & (wx[kx] != 0.0)
            w = wy[ky] * wx[kx]
            acc += np.where(use, w * data[rows, cols], 0.0)
            if has_var:
                accv += np.where(use, w * w * var[rows, cols], 0.0)
    good = inside & np.isfinite(acc) & np.isfinite(accv)
    out[...] = np.where(good, acc * sd, fill)
    if has_var:
        out_var[...] = np.where(good, accv * sv, np.inf)
    out_mask[...] = ~good


def _resample_numpy(data, var, has_var, m, fill, sd, sv, out, out_var, out_mask, *, order):
    """Same result as the compiled kernel, with NumPy gathers over blocks of rows."""
    ny_out, nx_out = out.shape
    block = max(1, _NUMPY_BLOCK_PIXELS // max(nx_out, 1))
    xo = np.arange(nx_out, dtype=float)[None, :]
    for y0 in range(0, ny_out, block):
        yo = np.arange(y0, min(y0 + block, ny_out), dtype=float)[:, None]
        sl = slice(y0, y0 + len(yo))
        u = m[0] * xo + (m[1] * yo + m[2])
        v = m[3] * xo + (m[4] * yo + m[5])
        _interp_numpy(data, var, has_var, u, v, fill, sd, sv, out[sl],
                      out_var[sl] if has_var else None, out_mask[sl], order)


# -- input checking --------------------------------------------------------------

def _parse_order(order):
    if isinstance(order, str):
        key = order.lower()
        if key in ORDERS:
            return ORDERS[key]
    elif isinstance(order, numbers.Integral) and not isinstance(order, bool):
        if 0 <= int(order) <= 3:
            return int(order)
    raise ValueError(
        f"order must be one of {list(ORDERS)} or an integer 0-3; got {order!r}."
    )


def _parse_matrix(matrix, what="resample", shape_in=None):
    """
    The 3x3 source -> target matrix of an affine transform as float64, or, for
    a non-linear one, a `_CoordinateMap` (``what`` names the caller for errors;
    ``shape_in``, the source's ``(ny, nx)``, is the domain of a polynomial
    model that has none).
    """
    from astropy.modeling import Model

    from .transforms import ProjectiveTransform, _as_3x3, as_matrix

    if isinstance(matrix, _CoordinateMap):  # already parsed (by apply_transform)
        return _nonlinear(matrix, what)
    if isinstance(matrix, ProjectiveTransform):
        matrix = matrix.matrix  # affine or not, exactly (the homography path)
    elif not isinstance(matrix, np.ndarray) and (
        hasattr(matrix, "params") or hasattr(matrix, "n_inputs")
    ):
        # A package/astropy/scikit-image transform rather than a bare matrix.
        try:
            matrix = as_matrix(matrix)
        except ValueError:
            if not isinstance(matrix, Model):
                raise
            return _nonlinear(_CoordinateMap.from_model(matrix, shape_in), what)
    try:
        m = np.array(matrix, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(
            "matrix must be a 3x3 (or 2x3) array of numbers, e.g. transform.matrix; "
            f"got {type(matrix).__name__}."
        ) from None
    m = _as_3x3(m)
    # cos(90 deg) is 6e-17, not 0: snap such round-off to the integer, or an exact
    # quarter turn maps edge pixels a hair outside the source and masks them.
    near = np.abs(m - np.round(m)) < 1e-12
    m[near] = np.round(m[near])
    singular = ValueError(
        "matrix is singular (it cannot be inverted); pass the matrix of a valid "
        "source->target transform.")
    if not np.allclose(m[2], [0.0, 0.0, 1.0]):
        # A homography: resampled through its (exact) inverse as a coordinate map.
        if abs(np.linalg.det(m)) < 1e-300 or np.linalg.cond(m) > 1e15:
            raise singular
        return _nonlinear(_CoordinateMap.from_homography(m), what)
    lin = m[:2, :2]
    if np.linalg.det(lin) == 0.0 or np.linalg.cond(lin) > 1e12:
        raise singular
    return m


def _nonlinear(cmap, what):
    if what == "resample_exact":
        raise ValueError(
            f"resample_exact handles affine transforms only (reproject_exact needs straight "
            f"pixel edges); this {cmap.name} is not affine. Use resample (or apply_transform "
            "with method='interpolate'), which resamples any model through its coordinate map.")
    return cmap


# Coordinate maps (non-linear models): output pixels per band of map, and
# the accuracy asked of the source positions (pixels).
_MAP_BAND_PIXELS = 1 << 16
_NEWTON_STEPS = 4
_NEWTON_STOP = 1e-6     # all positions this close: no further step
_MAP_TOL = 1e-4         # positions further than this from solving f(x) = x' are bad
_NEWTON_STEP_PX = 1e-3  # finite-difference step of the Jacobian


class _CoordinateMap:
    """
    Target -> source pixel positions for a non-linear source -> target map.

    The inverse gives the first guess; the forward map checks it, and Newton
    steps (finite-difference Jacobian of the forward map) polish positions
    whose round trip misses by more than ``_NEWTON_STOP`` px (a fitted,
    approximate inverse, such as SIP's AP/BP terms).  Positions still off by
    more than ``_MAP_TOL`` px (no source position there) come back as NaN.
    """

    def __init__(self, forward, inverse, name):
        self.forward, self.inverse, self.name = forward, inverse, name

    @classmethod
    def from_homography(cls, m):
        inv = np.linalg.inv(m)

        def apply(h, x, y, check=False):
            w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                xo = (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / w
                yo = (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / w
            if check:
                # A target pixel whose source lies beyond the horizon (the
                # forward map's denominator <= 0) has no source position.
                ws = m[2, 0] * xo + m[2, 1] * yo + m[2, 2]
                xo[~(ws > 0)] = np.nan
            return xo, yo

        return cls(lambda x, y: apply(m, x, y), lambda x, y: apply(inv, x, y, True),
                   "projective matrix")

    @classmethod
    def from_model(cls, model, shape_in=None):
        name = f"{type(model).__name__} model"
        if model.n_inputs != 2 or model.n_outputs != 2:
            raise TypeError(
                f"the transform must map (x, y) to (x, y) (2 inputs, 2 outputs); this {name} "
                f"has {model.n_inputs} inputs and {model.n_outputs} outputs.")
        if getattr(model, "domain", False) is None and shape_in is not None:
            # A PolynomialTransform without the domain its inverse is fitted
            # over: the source frame is that domain.
            model = model.copy()
            model.domain = (0.0, shape_in[1] - 1.0, 0.0, shape_in[0] - 1.0)
        try:
            inverse = model.inverse
        except NotImplementedError as exc:
            raise ValueError(
                f"this {name} has no inverse, which resampling needs (the source position of "
                "each target pixel); give it one, even approximate (model.inverse = ...): "
                f"Newton steps on the model polish it.{' (' + str(exc) + ')' if str(exc) else ''}"
            ) from None

        def call(f):
            def run(x, y):
                xo, yo = f(x, y)
                return np.asarray(xo, dtype=float), np.asarray(yo, dtype=float)
            return run

        return cls(call(model), call(inverse), name)

    def __call__(self, xo, yo, grid=False):
        """
        Source positions ``(x, y)`` of target positions ``(xo, yo)`` (same shape).

        With ``grid`` True, ``(xo, yo)`` are 2-D and spaced by one pixel
        (columns along x, rows along y): the first Newton step then takes
        the inverse map's Jacobian from differences between neighbouring
        positions, which costs no evaluation of the model.
        """
        shape = np.shape(xo)
        xo, yo = np.ravel(xo), np.ravel(yo)
        x, y = self.inverse(xo, yo)
        x = np.array(x, dtype=float).ravel()  # own copies, polished in place
        y = np.array(y, dtype=float).ravel()
        gjac = None
        if grid and len(shape) == 2 and min(shape) >= 3:
            # d(x, y)/d(x', y') of the (approximate) inverse, second order.
            with np.errstate(invalid="ignore"):
                gjac = [np.gradient(a.reshape(shape), axis=k, edge_order=2).ravel()
                        for a in (x, y) for k in (1, 0)]
        idx = None  # the positions still being polished (None: all)
        h = _NEWTON_STEP_PX
        for step in range(_NEWTON_STEPS + 1):
            if idx is None:
                xs, ys, tx, ty = x, y, xo, yo
            else:
                xs, ys, tx, ty = x[idx], y[idx], xo[idx], yo[idx]
            fx, fy = (np.ravel(a) for a in self.forward(xs, ys))
            rx, ry = fx - tx, fy - ty
            r2 = rx * rx + ry * ry
            with np.errstate(invalid="ignore"):
                if step == _NEWTON_STEPS:
                    # Still missing by more than _MAP_TOL: no source position here.
                    lost = ~(r2 <= _MAP_TOL**2)
                else:
                    lost = np.isnan(r2)  # the model gives no value
                    todo = np.flatnonzero(r2 > _NEWTON_STOP**2)
            if lost.any():
                x[np.flatnonzero(lost) if idx is None else idx[lost]] = np.nan
            if step == _NEWTON_STEPS or len(todo) == 0:
                break
            if len(todo) < len(r2):
                idx = todo if idx is None else idx[todo]
                xs, ys, fx, fy, rx, ry = (a[todo] for a in (xs, ys, fx, fy, rx, ry))
            if step == 0 and gjac is not None:
                # The first step with the grid's Jacobian of the inverse map.
                g = gjac if idx is None else [a[idx] for a in gjac]
                with np.errstate(invalid="ignore"):
                    dx = g[0] * rx + g[1] * ry
                    dy = g[2] * rx + g[3] * ry
                fd = np.flatnonzero(~(np.isfinite(dx) & np.isfinite(dy)))  # NaN neighbours
            else:
                dx, dy, fd = np.empty_like(rx), np.empty_like(rx), slice(None)
            if not isinstance(fd, np.ndarray) or fd.size:
                # Newton step, the forward map's Jacobian by finite differences.
                xf, yf, rxf, ryf, fxf, fyf = (a[fd] for a in (xs, ys, rx, ry, fx, fy))
                fxx, fyx = (np.ravel(a) for a in self.forward(xf + h, yf))
                fxy, fyy = (np.ravel(a) for a in self.forward(xf, yf + h))
                j11, j21, j12, j22 = fxx - fxf, fyx - fyf, fxy - fxf, fyy - fyf  # (times h)
                with np.errstate(divide="ignore", invalid="ignore"):
                    det = (j11 * j22 - j12 * j21) / h
                    dx[fd] = (j22 * rxf - j12 * ryf) / det
                    dy[fd] = (j11 * ryf - j21 * rxf) / det
            if idx is None:
                x -= dx
                y -= dy
            else:
                x[idx] = xs - dx
                y[idx] = ys - dy
        y[np.isnan(x)] = np.nan
        return x.reshape(shape), y.reshape(shape)

    def band(self, r0, r1, nx_out, jacobian=False):
        """
        Source positions of output rows ``r0:r1`` (C-contiguous float64) and,
        if ``jacobian``, ``|det|`` of the map's Jacobian there (central
        differences over neighbouring output pixels): the local ratio of
        target to source pixel area that ``conserve_flux`` applies.
        """
        pad = 1 if jacobian else 0
        yo, xo = np.mgrid[r0 - pad:r1 + pad, -pad:nx_out + pad].astype(float)
        x, y = self(xo, yo, grid=True)
        if not jacobian:
            return x, y, None
        with np.errstate(invalid="ignore"):
            jac = np.abs((x[1:-1, 2:] - x[1:-1, :-2]) * (y[2:, 1:-1] - y[:-2, 1:-1])
                         - (x[2:, 1:-1] - x[:-2, 1:-1]) * (y[1:-1, 2:] - y[1:-1, :-2])) / 4.0
        x = np.ascontiguousarray(x[1:-1, 1:-1])
        y = np.ascontiguousarray(y[1:-1, 1:-1])
        x[~np.isfinite(jac)] = np.nan  # no flux factor: no valid output pixel
        return x, y, jac


def _inverse_coefficients(m):
    """Coefficients ``(a, b, c, d, e, f)`` of target -> source: x = a x' + b y' + c."""
    (a, b), (c, d) = m[:2, :2]
    det = a * d - b * c
    # Analytic 2x2 inverse: exact for identities, integer shifts and flips.
    ai = np.array([[d, -b], [-c, a]]) / det
    t = -(ai @ m[:2, 2])
    return np.array([ai[0, 0], ai[0, 1], t[0], ai[1, 0], ai[1, 1], t[1]]), abs(det)


def _parse_shape_out(shape_out, nchan):
    try:
        shape = tuple(int(s) for s in shape_out)
        if any(s != t for s, t in zip(shape, shape_out)):
            raise ValueError
    except (TypeError, ValueError):
        raise TypeError(
            f"shape_out must be a tuple of integers (ny, nx); got {shape_out!r}."
        ) from None
    if len(shape) == 3 and nchan is not None and shape[2] == nchan:
        shape = shape[:2]
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(
            f"shape_out must be the (ny, nx) shape of the target image; got {shape_out!r}."
        )
    return shape


def _prepare(data, variance, mask, shape_out, keep_var_dtype=False):
    """
    Check the inputs.

    Returns channel-first contiguous ``(nchan, ny, nx)`` data and variance (the
    kernels work on one C-contiguous 2-D channel at a time), the 2-D bad-pixel
    mask, the output shape, whether the input was multichannel and the dtype.
    """
    if isinstance(data, np.ma.MaskedArray):
        mask = np.ma.getmaskarray(data) if mask is None else (
            np.asarray(mask, bool) | np.ma.getmaskarray(data)
        )
        data = data.data
    arr = np.asarray(data)
    if arr.dtype.kind not in "biuf":
        raise TypeError(
            f"data must be a real numeric array; got dtype {arr.dtype}. Convert it, "
            "e.g. np.asarray(data, dtype=float)."
        )
    if arr.ndim not in (2, 3):
        raise ValueError(
            "data must be a 2-D image (ny, nx) or a channels-last 3-D array "
            f"(ny, nx, nchan); got an array of shape {arr.shape}."
        )
    if arr.size == 0:
        # (The compiled kernels index the first pixel: there must be one.)
        raise ValueError(f"data is empty (shape {arr.shape}); pass an image with pixels.")
    # float32 (either byte order) in -> float32 out; anything else runs in float64.
    dtype = np.float32 if arr.dtype.kind == "f" and arr.dtype.itemsize == 4 else np.float64
    multichannel = arr.ndim == 3

    def channels_first(a, keep_dtype=False):
        return np.ascontiguousarray(np.moveaxis(a, -1, 0) if multichannel else a[None],
                                    dtype=None if keep_dtype else dtype)

    data_cf = channels_first(arr)
    var_cf = None
    if variance is not None:
        var = np.asarray(variance)
        if multichannel and var.shape == arr.shape[:2]:
            var = np.broadcast_to(var[..., None], arr.shape)  # same variance per channel
        if var.shape != arr.shape:
            raise ValueError(
                f"variance must have the same shape as data {arr.shape}; got {var.shape}."
            )
        # (A standard deviation or inverse variance keeps its type: it is
        # converted band by band, see `resample`.)
        var_cf = channels_first(var, keep_var_dtype and var.dtype.kind in "biuf")
    bad = None
    if mask is not None:
        mk = np.asarray(mask)
        if mk.shape == arr.shape and multichannel:
            mk = mk.any(axis=-1)  # one mask for all channels
        if mk.shape != arr.shape[:2]:
            raise ValueError(
                f"mask must have the image shape {arr.shape[:2]} (True = bad pixel); "
                f"got {mk.shape}."
            )
        bad = np.ascontiguousarray(mk, dtype=bool)
    shape = _parse_shape_out(shape_out, arr.shape[2] if multichannel else None)
    return data_cf, var_cf, bad, shape, multichannel, dtype


def _parse_fill(fill_value):
    try:
        return float(fill_value)
    except (TypeError, ValueError):
        raise TypeError(
            f"fill_value must be a number (e.g. np.nan or 0); got {fill_value!r}."
        ) from None


#: How `resample` reads its ``variance`` plane (the compiled kernels' ``var_kind``).
_VARIANCE_KINDS = {"variance": 0, "stddev": 1, "inverse": 2}

# The Jacobian argument of the coordinate-map kernel when there is none.
_DUMMY_MAP = np.zeros((1, 1))


def _run_affine(data, var, has_var, kind, okind, bad8, has_mask, coeffs, order, fill, sd, sv,
                out, out_var, mask, rows_per_thread, parallel, start, n):
    """Output rows ``start:start + n`` of one channel, on the compiled affine kernels."""
    if order == 1:
        kernel, extra = _ckernels.bilinear_rows, (fill, sd, sv)
    else:
        kernel, extra = _ckernels.resample_rows, (order, fill, sd, sv)
    run_split(kernel, n, (data, var, has_var, kind, okind, bad8, has_mask, coeffs) + extra
              + (out, out_var, mask.view(np.uint8)),
              min_per_thread=rows_per_thread, parallel=parallel, start=start)


# Output pixels per band when working planes are made band by band (see `resample`).
_BAND_PIXELS = 1 << 22


def _to_variance(arr, kind, dtype, out=None):
    """Variance from a standard deviation ('stddev'), inverse variance ('inverse') or itself."""
    if kind == "variance":
        return np.asarray(arr, dtype)
    if out is None:
        out = np.empty(np.shape(arr), dtype)
    # Computed in the input's own type, then stored as ``dtype`` (as
    # astropy's represent_as followed by a cast would).
    if kind == "stddev":
        return np.square(arr, out=out, casting="unsafe")
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.divide(1.0, arr, out=out, casting="unsafe")


def _from_variance(var, okind):
    """In place: a variance plane to a standard deviation (1) or inverse variance (2)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        if okind == 1:
            np.sqrt(var, out=var)
        else:
            np.divide(1.0, var, out=var)


def _bands(coeffs, shape_out, ny, order):
    """
    Bands of output rows ``(r0, r1)`` with the source rows ``(s0, s1)`` they read.

    The source rows cover every tap of every output pixel in the band (the
    affine map's extremes are at the band's corners) with a margin, so that
    the kernel, given only those rows, finds each tap where the full image
    has it; where the band reaches the image's edge it stops there, as the
    image does.
    """
    ny_out, nx_out = shape_out
    step = max(16, _BAND_PIXELS // max(nx_out, 1))
    margin = 4 + order
    out = []
    for r0 in range(0, ny_out, step):
        r1 = min(r0 + step, ny_out)
        v = [coeffs[3] * x + coeffs[4] * y + coeffs[5]
             for x in (0.0, nx_out - 1.0) for y in (float(r0), r1 - 1.0)]
        s0 = min(max(int(np.floor(min(v))) - margin, 0), ny - 1)
        s1 = max(min(int(np.ceil(max(v))) + margin + 1, ny), s0 + 1)
        out.append((r0, r1, s0, s1))
    return out


@dataclass
class _Job:
    """
    The working planes of one `resample` call and what the kernels are told.

    ``data`` and ``var`` are channels first; ``kind`` and ``okind`` the
    kernels' ``var_kind`` of the variance plane read and written; ``bad8``
    the mask as bytes (a dummy when ``has_mask`` is False); ``dummy`` the
    tiny typed array the compiled kernels take for an absent plane.
    """

    data: np.ndarray
    var: np.ndarray | None
    variance_kind: str
    kind: int
    okind: int
    bad8: np.ndarray
    has_mask: bool
    compiled: bool
    convert: bool
    order: int
    fill: float
    sd: float
    parallel: bool
    out: np.ndarray
    out_var: np.ndarray | None
    masks: np.ndarray
    dummy: np.ndarray
    rows_per_thread: int

    @classmethod
    def make(cls, data_cf, var_cf, bad, shape, dtype, variance_kind, output_kind, is_map, order,
             fill, sd, parallel):
        """The planes and flags, with what the chosen kernels need converted first."""
        nc = data_cf.shape[0]
        has_var = var_cf is not None
        if bad is not None and not bad.any():
            bad = None
        kind = _VARIANCE_KINDS[variance_kind] if has_var else 0
        # The variance output may be stored as a standard deviation or an inverse
        # variance (``_output_kind``, for apply_transform's uncertainty classes):
        # the kernels convert each pixel as they store it, saving a pass.
        okind = _VARIANCE_KINDS[output_kind] if has_var else 0
        compiled = _USE_COMPILED and HAVE_COMPILED
        if not compiled and (kind or bad is not None):
            # NumPy path: whole-frame working copies (it is the slow path anyway).
            if kind:
                var_cf = _to_variance(var_cf, variance_kind, dtype)
            if bad is not None:
                data_cf = np.where(bad, np.array(np.nan, dtype), data_cf)
            kind, bad = 0, None
        # The compiled kernel squares a standard deviation or inverts an inverse
        # variance tap by tap, and reads the mask, so that no working copy of a
        # plane is made -- unless the uncertainty's type differs from the data's
        # (then the variance is made in the data's type: band by band on the
        # affine path, once on the coordinate-map path).
        convert = has_var and var_cf.dtype != dtype
        if convert and is_map:
            var_cf, kind, convert = _to_variance(var_cf, variance_kind, dtype), 0, False
        # The compiled kernel needs typed arrays even for absent inputs/outputs: tiny dummies.
        return cls(data=data_cf, var=var_cf, variance_kind=variance_kind, kind=kind,
                   okind=okind,
                   bad8=np.empty((1, 1), np.uint8) if bad is None else bad.view(np.uint8),
                   has_mask=bad is not None, compiled=compiled, convert=convert, order=order,
                   fill=fill, sd=sd, parallel=parallel,
                   out=np.empty((nc,) + shape, dtype=dtype),
                   out_var=np.empty((nc,) + shape, dtype=dtype) if has_var else None,
                   masks=np.empty((nc,) + shape, dtype=bool), dummy=np.empty((1, 1), dtype),
                   rows_per_thread=max(1, _MIN_PIXELS_PER_THREAD // shape[1]))

    @property
    def has_var(self):
        return self.var is not None

    def var_plane(self, c):
        """Channel ``c`` of the variance, or the dummy."""
        return self.var[c] if self.has_var else self.dummy

    def finish(self, multichannel):
        """``(data, variance, mask)`` in the caller's layout, the mask shared by all channels."""
        out, out_var, has_var = self.out, self.out_var, self.has_var
        if has_var and self.okind and not self.compiled:
            _from_variance(out_var, self.okind)
        mask_out = self.masks[0]
        if out.shape[0] > 1:
            # The mask applies to all channels: a pixel bad in one is bad in all.
            mask_out = self.masks.any(axis=0)
            out[:, mask_out] = self.fill
            if has_var:
                out_var[:, mask_out] = 0.0 if self.okind == 2 else np.inf
        if multichannel:
            out = np.ascontiguousarray(np.moveaxis(out, 0, -1))
            out_var = None if out_var is None else np.ascontiguousarray(
                np.moveaxis(out_var, 0, -1))
        else:
            out = out[0]
            out_var = None if out_var is None else out_var[0]
        return out, out_var, mask_out


def _resample_map(job, cmap, conserve_flux):
    """Through a coordinate map: source positions (and flux factors) band by band."""
    # One band of output rows at a time, shared by all channels: a few MB
    # whatever the frame size.
    nc, ny_out, nx_out = job.out.shape
    step = max(1, _MAP_BAND_PIXELS // nx_out)
    for r0 in range(0, ny_out, step):
        r1 = min(r0 + step, ny_out)
        xs, ys, jac = cmap.band(r0, r1, nx_out, jacobian=conserve_flux)
        for c in range(nc):
            ov = job.out_var[c, r0:r1] if job.has_var else job.dummy
            if not job.compiled:
                sdk = 1.0 if jac is None else jac
                _interp_numpy(job.data[c], job.var[c] if job.has_var else None, job.has_var,
                              xs, ys, job.fill, sdk, sdk * sdk if jac is not None else 1.0,
                              job.out[c, r0:r1], ov, job.masks[c, r0:r1], job.order)
                continue
            run_split(_ckernels.map_rows, r1 - r0,
                      (job.data[c], job.var_plane(c), job.has_var, job.kind, job.okind,
                       job.bad8, job.has_mask, xs, ys, _DUMMY_MAP if jac is None else jac,
                       jac is not None, job.order, job.fill, 1.0, job.out[c, r0:r1], ov,
                       job.masks[c, r0:r1].view(np.uint8)),
                      min_per_thread=job.rows_per_thread, parallel=job.parallel)


def _resample_affine_bands(job, coeffs):
    """Affine, compiled, with the variance converted into the data's type band by band."""
    # Working variance (a standard deviation squared, or an inverse variance
    # inverted, into the data's type) one band of output rows at a time, for
    # the source rows that band reads: a scratch of a fraction of a frame
    # instead of a whole-frame copy.
    bands = _bands(coeffs, job.out.shape[1:], job.data.shape[1], job.order)
    scratch = np.empty((max(s1 - s0 for _, _, s0, s1 in bands), job.data.shape[2]),
                       job.out.dtype)
    sd = job.sd
    for c in range(job.out.shape[0]):
        for r0, r1, s0, s1 in bands:
            v = _to_variance(job.var[c, s0:s1], job.variance_kind, job.out.dtype,
                             out=scratch[:s1 - s0])
            band_coeffs = coeffs.copy()
            band_coeffs[5] -= s0  # source row s0 is row 0 of the band
            _run_affine(job.data[c, s0:s1], v, True, 0, job.okind,
                        job.bad8[s0:s1] if job.has_mask else job.bad8, job.has_mask,
                        band_coeffs, job.order, job.fill, sd, sd * sd, job.out[c],
                        job.out_var[c], job.masks[c], job.rows_per_thread, job.parallel, r0,
                        r1 - r0)


def _resample_affine(job, coeffs):
    """Affine: each channel's rows on the compiled kernels (or the NumPy ones)."""
    sd = job.sd
    for c in range(job.out.shape[0]):
        outs = (job.out[c], job.out_var[c] if job.has_var else job.dummy)
        if not job.compiled:
            args = (job.data[c], job.var_plane(c), job.has_var, coeffs)
            _resample_numpy(*args, job.fill, sd, sd * sd, *outs, job.masks[c], order=job.order)
            continue
        _run_affine(job.data[c], job.var_plane(c), job.has_var, job.kind, job.okind, job.bad8,
                    job.has_mask, coeffs, job.order, job.fill, sd, sd * sd, *outs, job.masks[c],
                    job.rows_per_thread, job.parallel, 0, job.out.shape[1])


# -- public API ------------------------------------------------------------------

def resample(data, matrix, shape_out, *, order="bilinear", variance=None, mask=None,
             fill_value=np.nan, conserve_flux=False, parallel=True, _variance_kind="variance",
             _output_kind="variance"):
    """
    Resample an image onto the target pixel grid, with variance and mask.

    Parameters
    ----------
    data : array-like, shape (ny, nx) or (ny, nx, nchan)
        The source image; 3-D input is channels-last (e.g. RGB) and every
        channel is resampled with the same weights.  float32 data is
        processed and returned as float32, anything else as float64.  A
        `numpy.ma.MaskedArray` contributes its mask to ``mask``.
    matrix : (3, 3) or (2, 3) array-like, or transform
        The *source -> target* pixel transform: a homogeneous matrix, e.g.
        ``transform.matrix`` of an `astroalign_nd.transforms` model, or the
        model itself, a scikit-image transform, or any astropy model with 2
        inputs and 2 outputs.  An affine transform must be invertible; a
        non-linear one (a projective matrix or model, a polynomial model, a
        compound model...) is resampled through its coordinate map and
        needs an ``inverse`` (an approximate one is polished by Newton
        steps on the model; see the module docstring).
    shape_out : tuple of int
        ``(ny, nx)`` of the target grid.
    order : {'nearest-neighbor', 'bilinear', 'biquadratic', 'bicubic'} or int, optional
        Interpolation kernel, or its order 0-3.  See the module docstring
        for the exact kernels.  Default ``'bilinear'``.
    variance : array-like, optional
        Variance of ``data``, same shape (for multichannel data an
        ``(ny, nx)`` variance applies to every channel).  Propagated as
        ``sum(w**2 * var)``; see Notes.
    mask : array-like of bool, shape (ny, nx), optional
        True for bad source pixels; applies to every channel (a 3-D mask is
        reduced with ``any`` over channels).  NaN/inf pixels of ``data`` or
        ``variance`` are treated as masked without being listed here.
    fill_value : float, optional
        Value of masked output pixels in ``data_out`` (default NaN).
    conserve_flux : bool, optional
        If True, scale the result by ``1 / |det A|`` (``A`` the linear part
        of ``matrix``; for a non-linear transform, the local Jacobian
        determinant of its inverse) so that total counts, not surface
        brightness, are preserved; variance is scaled by the square.
        Default False.
    parallel : bool, optional
        Split the output rows over threads (default True): as many as the
        CPUs this process may use, or ``ASTROALIGN_ND_NUM_THREADS`` if set in
        the environment; small outputs use one.  The result does not depend
        on it.

    Returns
    -------
    data_out : ndarray, shape ``shape_out`` (+ ``(nchan,)``)
        The resampled image.
    variance_out : ndarray or None
        The propagated variance (``+inf`` where masked), or None if no
        ``variance`` was given.
    mask_out : ndarray of bool, shape ``shape_out``
        True where the output is bad: outside the source footprint (the
        whole kernel support must be inside the image), or using a masked,
        NaN or inf source pixel with nonzero weight.

    Raises
    ------
    ValueError
        For a matrix that is not 3x3/2x3 or singular, a non-linear model
        without an ``inverse``, data that is not 2-D or 3-D, an unknown
        ``order``, or mismatched shapes.
    TypeError
        For non-numeric data, matrix, shape_out or fill_value.

    Notes
    -----
    The variance formula is exact for each output pixel when the input
    pixels are independent, but resampling correlates neighbouring output
    pixels and that covariance is not returned (summing ``variance_out``
    over an aperture underestimates the variance of the sum).

    The computation runs in a compiled (Cython) kernel that produces data,
    variance and mask in one pass over the output, reading the mask and the
    uncertainty plane as they are (no working copies); a NumPy implementation
    of the same kernels gives the same results, more slowly, if the
    compiled module is missing.  Threads never share an output pixel, so
    the result is deterministic and the same for any number of threads.
    `resample` may be called from several threads at once.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.resample import resample
    >>> image = np.arange(16.0).reshape(4, 4)
    >>> shift = np.array([[1.0, 0, 1], [0, 1, 0], [0, 0, 1]])  # one pixel along +x
    >>> out, var, bad = resample(image, shift, (4, 4), order="bicubic")
    >>> out[1]
    array([nan,  4.,  5.,  6.])
    >>> bad[1]
    array([ True, False, False, False])
    """
    order = _parse_order(order)
    m = _parse_matrix(matrix, shape_in=np.shape(data)[:2])
    cmap = m if isinstance(m, _CoordinateMap) else None
    if _variance_kind not in _VARIANCE_KINDS or _output_kind not in _VARIANCE_KINDS:
        raise ValueError(f"unknown _variance_kind {_variance_kind!r} or _output_kind "
                         f"{_output_kind!r}")
    data_cf, var_cf, bad, shape, multichannel, dtype = _prepare(
        data, variance, mask, shape_out, keep_var_dtype=_variance_kind != "variance")
    fill = _parse_fill(fill_value)
    if cmap is None:
        coeffs, det = _inverse_coefficients(m)
        sd = 1.0 / det if conserve_flux else 1.0
    else:
        sd = 1.0  # the flux factor is the map's local Jacobian, pixel by pixel
    job = _Job.make(data_cf, var_cf, bad, shape, dtype, _variance_kind, _output_kind,
                    cmap is not None, order, fill, sd, parallel)
    if cmap is not None:
        _resample_map(job, cmap, conserve_flux)
    elif job.compiled and job.convert:
        _resample_affine_bands(job, coeffs)
    else:
        _resample_affine(job, coeffs)
    return job.finish(multichannel)


# Pixel scale (deg) of the synthetic target WCS of `resample_exact`.  Measured
# trade-off: overlap areas lose precision for tiny pixels (coincident edges give
# coverage errors ~1e-8 at 1e-6 deg, ~1e-10 at 1e-4 deg), while the curvature of
# the TAN projection grows with field size (~3e-8 relative for 10^4 pixels at
# 1e-4 deg).
_EXACT_PIXEL_SCALE = 1e-4
# Coverage tolerance of `resample_exact`, far above those numerical errors.
_EXACT_TOL = 1e-6


def _exact_wcs_pair(m, shape_out):
    """Two TAN WCSs whose pixel grids are related exactly by the affine ``m``."""
    from astropy.wcs import WCS

    # Tangent point at the target centre; both WCSs share the projection, so
    # source pixel -> sky -> target pixel is exactly the affine map, and the
    # gnomonic projection maps straight pixel edges to the great circles that
    # reproject's polygon clipping assumes.
    c_t = (np.array(shape_out[::-1], dtype=float) - 1.0) / 2.0
    cd_t = np.diag([-_EXACT_PIXEL_SCALE, _EXACT_PIXEL_SCALE])
    lin, t = m[:2, :2], m[:2, 2]
    # q = CD_t (p_t - c_t) = CD_t (A p_s + t - c_t) = (CD_t A)(p_s - c_s).
    c_s = np.linalg.solve(lin, c_t - t)
    wcss = []
    for cd, crpix in ((cd_t @ lin, c_s), (cd_t, c_t)):
        w = WCS(naxis=2)
        w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
        w.wcs.crval = [0.0, 0.0]
        w.wcs.cd = cd
        w.wcs.crpix = crpix + 1.0  # FITS pixels are 1-based
        wcss.append(w)
    return wcss


def resample_exact(data, matrix, shape_out, *, variance=None, mask=None,
                   fill_value=np.nan, conserve_flux=False, parallel=False):
    """
    Flux-conserving resampling by exact pixel overlap, through reproject.

    Each target pixel receives the area-weighted mean of the source pixels
    it overlaps (`reproject.reproject_exact`, spherical polygon
    intersection), i.e. drizzling with ``pixfrac = 1``.  The affine
    ``matrix`` is encoded in two synthetic gnomonic (TAN) WCSs with the same
    tangent point, so the sky round trip is exactly the affine map.

    Parameters
    ----------
    data, matrix, shape_out, variance, mask, fill_value, conserve_flux
        As in `resample`, but the transform must be affine.
    parallel : bool or int, optional
        Passed to `reproject.reproject_exact`.

    Returns
    -------
    data_out, variance_out, mask_out
        As in `resample`.  ``mask_out`` is True where the target pixel is not
        entirely covered by the source image (coverage below
        ``1 - 1e-6``), or overlaps a bad source pixel by more than ``1e-6``
        of its area.

    Raises
    ------
    ValueError
        For a non-linear (projective, polynomial...) transform: its pixel
        edges are not straight, which the overlap computation needs; use
        `resample` (``apply_transform(method='interpolate')``) instead.

    Notes
    -----
    reproject returns surface brightness (the overlap-weighted *mean*);
    with ``conserve_flux=True`` it is multiplied by the pixel area ratio
    ``1 / |det A|`` to give counts, as in `resample`.

    The variance is pushed through the same weighted mean, giving
    ``sum(p_k var_k)`` with ``p_k`` the fractional overlaps, instead of the
    exact ``sum(p_k**2 var_k)`` that reproject cannot provide.  Because
    ``p_k <= 1`` this is an upper bound, equal to the exact value when a
    target pixel lies inside a single source pixel (strong magnification)
    and too large by up to the number of overlapped source pixels when
    shrinking the image.  As in `resample`, correlations between output
    pixels are not returned.

    This is ~1000 times slower than `resample`: about 20 s per megapixel
    on one core of the development machine.

    Examples
    --------
    Halving the pixel scale: with ``conserve_flux=True`` the 16 counts of a
    4x4 block stay 16 counts, spread over the 2x2 pixels it now covers.

    >>> import numpy as np
    >>> from astroalign_nd.resample import resample_exact
    >>> image = np.zeros((8, 8))
    >>> image[2:6, 2:6] = 1.0
    >>> half = np.array([[0.5, 0, 0], [0, 0.5, 0], [0, 0, 1]])
    >>> out, var, bad = resample_exact(image, half, (4, 4), conserve_flux=True)
    >>> round(float(np.nansum(out)), 6)
    16.0
    >>> bad[0]  # the first row and column are only partly covered
    array([ True,  True,  True,  True])
    >>> out.shape, out.dtype, var is None
    ((4, 4), dtype('float64'), True)
    """
    try:
        from reproject import reproject_exact
    except ImportError:  # an optional dependency: say how to get it
        raise ImportError('resample_exact needs reproject: pip install "astroalign_nd[exact]" '
                          "(or conda install -c conda-forge reproject).") from None

    m = _parse_matrix(matrix, "resample_exact")
    data_cf, var_cf, bad, shape, multichannel, dtype = _prepare(data, variance, mask,
                                                                shape_out)
    fill = _parse_fill(fill_value)
    nc = data_cf.shape[0]
    finite = np.isfinite(data_cf).all(axis=0)
    if var_cf is not None:
        finite &= np.isfinite(var_cf).all(axis=0)
    bad = ~finite if bad is None else (bad | ~finite)

    # One stack (data channels, variance channels, bad fraction) so that reproject
    # computes the overlap geometry once for all layers; bad pixels are zeroed
    # because reproject lets a NaN poison every pixel it touches.
    layers = [np.where(bad, 0.0, data_cf)]
    if var_cf is not None:
        layers.append(np.where(bad, 0.0, var_cf))
    layers.append(bad[None].astype(float))
    stack = np.concatenate(layers)

    wcs_in, wcs_out = _exact_wcs_pair(m, shape)
    res, footprint = reproject_exact(
        (stack, wcs_in), wcs_out, shape_out=(len(stack),) + shape, parallel=parallel
    )
    cover = footprint[0]
    with np.errstate(invalid="ignore"):
        mask_out = (cover < 1.0 - _EXACT_TOL) | ~(res[-1] <= _EXACT_TOL)

    scale = 1.0 / abs(np.linalg.det(m[:2, :2])) if conserve_flux else 1.0
    out = res[:nc] * scale
    out[:, mask_out] = fill
    out_var = None
    if var_cf is not None:
        out_var = res[nc:2 * nc] * scale**2
        out_var[:, mask_out] = np.inf
    if multichannel:
        out = np.moveaxis(out, 0, -1)
        out_var = None if out_var is None else np.moveaxis(out_var, 0, -1)
    else:
        out = out[0]
        out_var = None if out_var is None else out_var[0]
    out = np.ascontiguousarray(out, dtype=dtype)
    out_var = None if out_var is None else np.ascontiguousarray(out_var, dtype=dtype)
    return out, out_var, mask_out
