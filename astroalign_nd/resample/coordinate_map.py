# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Non-linear transforms as a coordinate map: the output-to-input pixel positions, band by band."""

import numpy as np
from astropy.modeling import Model
from .._kernels import run_split
from ..transforms import ProjectiveTransform
from ..transforms._matrix import as_3x3, is_singular
from ..transforms.convert import as_matrix
from .interpolation import _interp_numpy

__all__ = []


def _parse_matrix(matrix, what="resample", shape_in=None):
    """
    The 3x3 source -> target matrix of an affine transform as float64, or, for
    a non-linear one, a `_CoordinateMap` (``what`` names the caller for errors;
    ``shape_in``, the source's ``(ny, nx)``, is the domain of a polynomial
    model that has none).
    """
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
    m = as_3x3(m)
    # cos(90 deg) is 6e-17, not 0: snap such round-off to the integer, or an exact
    # quarter turn maps edge pixels a hair outside the source and masks them.
    near = np.abs(m - np.round(m)) < 1e-12
    m[near] = np.round(m[near])
    singular = ValueError(
        "matrix is singular (it cannot be inverted); pass the matrix of a valid "
        "source->target transform.")
    if is_singular(m):
        raise singular
    if not np.allclose(m[2], [0.0, 0.0, 1.0]):
        # A homography: resampled through its (exact) inverse as a coordinate map.
        return _nonlinear(_CoordinateMap.from_homography(m), what)
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


# The Jacobian argument of the coordinate-map kernel when there is none.
_DUMMY_MAP = np.zeros((1, 1))


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
            run_split(job.kernels.map_rows, r1 - r0,
                      (job.data[c], job.var_plane(c), job.has_var, job.kind, job.okind,
                       job.bad8, job.has_mask, xs, ys, _DUMMY_MAP if jac is None else jac,
                       jac is not None, job.order, job.fill, 1.0, job.out[c, r0:r1], ov,
                       job.masks[c, r0:r1].view(np.uint8)),
                      min_per_thread=job.rows_per_thread, parallel=job.parallel)
