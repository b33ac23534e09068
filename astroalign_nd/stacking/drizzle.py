# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Drizzle's core, fed by the registration's transforms: the pixel map of a frame
onto a finer output grid, and an accumulator that adds frames one at a time.

The drizzling itself is the `drizzle` package's (``drizzle.resample.Drizzle``,
Fruchter & Hook 2002): this module only turns a frame's transform into
drizzle's *pixel map*, builds the per-pixel weights, and keeps the output
planes (value, variance through drizzle's squared-weight path, weight and the
number of frames reaching each pixel).  `~astroalign_nd.stack` (``drizzle=``)
and the live stack use it one frame at a time; a colour (Bayer) stack calls it
once per colour, with a weight map that is zero on the other colours' pixels.

Grids
-----
Pixel centres are at integers (0-based, ``x`` along columns), as everywhere in
the package.  The output grid is the reference's grid (or the union canvas,
whose pixel ``(0, 0)`` is at reference pixel ``offset``) cut into
``scale x scale`` finer pixels: reference (canvas) position ``c`` lands on
output position ``scale * (c + 0.5) - 0.5``, so output pixel ``j`` covers
reference positions ``(j - 0.5) / scale - 0.5 ... (j + 0.5) / scale - 0.5``
(`output_shape` gives the output's shape).

Units
-----
The output holds counts per *output* pixel (flux conserving): a star's
aperture sum on the output equals its sum on the input frames, and a flat sky
of ``b`` counts per input pixel becomes ``b / scale**2`` per output pixel
(divided also by the area of a frame pixel on the reference grid, for a
transform that changes the pixel scale).  The variance follows, in counts
squared.
"""

from __future__ import annotations

import numbers
import warnings
from dataclasses import dataclass

import numpy as np
from astropy.modeling import Model
from astropy.wcs import Sip
from drizzle.resample import Drizzle, blot_image

from ..batch.canvas import canvas_wcs
from ..exceptions import warn
from ..transforms import ProjectiveTransform
from ..transforms.convert import as_matrix
from .options import DRIZZLE_KERNELS

__all__ = ["DRIZZLE_KERNELS", "check_drizzle_options", "output_shape", "pixel_map",
           "pixel_area", "weight_map", "blot_mask", "scaled_wcs", "DrizzleAccumulator",
           "DrizzlePlanes", "on_output_grid", "coverage_report", "MAX_EMPTY_FRACTION",
           "MAX_WEIGHT_SPREAD"]

#: Input pixels per band when a transform is evaluated on a frame's grid (a few MB).
_BAND_PIXELS = 1 << 20


def check_drizzle_options(scale, pixfrac=1.0, kernel="square"):
    """
    Drizzle's options, checked: refused with what to pass instead.

    Parameters
    ----------
    scale : float
        Output pixels per reference pixel, along each axis (> 0; 2 halves
        the pixels' size).
    pixfrac : float, optional
        The linear fraction of an input pixel its value is dropped onto
        (0 < pixfrac <= 1).
    kernel : str, optional
        One of `DRIZZLE_KERNELS`.

    Returns
    -------
    scale, pixfrac : float
    kernel : str

    Raises
    ------
    TypeError, ValueError

    Examples
    --------
    >>> from astroalign_nd.stacking.drizzle import check_drizzle_options
    >>> check_drizzle_options(2, 0.7, "square")
    (2.0, 0.7, 'square')
    """
    for name, value in (("scale", scale), ("pixfrac", pixfrac)):
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise TypeError(f"drizzle's {name} must be a number; got {type(value).__name__}.")
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"drizzle's scale must be a finite number > 0 (output pixels per "
                         f"reference pixel, e.g. 2); got {scale!r}.")
    if not (np.isfinite(pixfrac) and 0 < pixfrac <= 1):
        raise ValueError(f"pixfrac must be in (0, 1] (the linear fraction of an input pixel "
                         f"its value is dropped onto, e.g. 0.7); got {pixfrac!r}.")
    if kernel not in DRIZZLE_KERNELS:
        raise ValueError(f"kernel must be one of {', '.join(map(repr, DRIZZLE_KERNELS))}; got "
                         f"{kernel!r}.")
    return float(scale), float(pixfrac), kernel


def output_shape(shape, scale):
    """
    The output grid's ``(ny, nx)`` for a reference (or canvas) grid of ``shape``.

    Examples
    --------
    >>> from astroalign_nd.stacking.drizzle import output_shape
    >>> output_shape((1080, 1920), 2)
    (2160, 3840)
    """
    return tuple(max(1, int(round(n * float(scale)))) for n in shape)


def _mapper(transform):
    """``f(x, y) -> (x', y')`` of a frame -> reference transform (None: identity)."""
    if transform is None:
        return lambda x, y: (x, y)
    if isinstance(transform, ProjectiveTransform):
        return lambda x, y: transform(x, y)
    try:
        m = np.asarray(as_matrix(transform), dtype=float)
    except (TypeError, ValueError):
        if not (isinstance(transform, Model) and transform.n_inputs == 2
                and transform.n_outputs == 2):
            raise TypeError(f"transform must be a frame -> reference transform (a model of "
                            f"astroalign_nd.transforms, a 2-in 2-out astropy model or a 3x3 "
                            f"matrix); got {type(transform).__name__}.") from None
        return lambda x, y: transform(x, y)  # a distortion: the model itself
    if not np.allclose(m[2], [0.0, 0.0, 1.0]):
        return ProjectiveTransform(matrix=m)

    def affine(x, y):
        return (m[0, 0] * x + m[0, 1] * y + m[0, 2], m[1, 0] * x + m[1, 1] * y + m[1, 2])
    return affine


def pixel_map(transform, shape, scale=1.0, offset=(0, 0)):
    """
    Where each pixel of a frame lands on the drizzle's output grid: drizzle's
    ``pixmap``.

    The frame's transform is evaluated at every pixel centre of the frame
    (band by band), then the reference position is put on the output grid
    (see the module's Grids).

    Parameters
    ----------
    transform : model, (3, 3) ndarray or None
        The frame's pixels -> the reference's pixels, as
        `~astroalign_nd.find_transform` and `~astroalign_nd.register_batch`
        (``canvas='reference'``) return it: any registered type of
        `astroalign_nd.transforms` (polynomial distortion included), any
        2-in 2-out astropy model, a 3x3 matrix; None for the reference itself.
    shape : (ny, nx)
        The frame's shape.
    scale : float, optional
        Output pixels per reference pixel (default 1: the reference's grid).
    offset : (x0, y0), optional
        Reference pixel coordinates of the output grid's origin before
        scaling: ``(0, 0)`` for the reference's grid, the canvas's ``offset``
        for a union canvas (`~astroalign_nd.batch.union_canvas`).

    Returns
    -------
    pixmap : (ny, nx, 2) float64 ndarray
        ``pixmap[..., 0]`` the output x, ``pixmap[..., 1]`` the output y of
        each frame pixel; NaN where the transform gives none.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import TranslationTransform
    >>> from astroalign_nd.stacking.drizzle import pixel_map
    >>> pm = pixel_map(TranslationTransform(translation_x=1.0), (2, 3), scale=2)
    >>> pm[0, 0], pm[1, 2]
    (array([2.5, 0.5]), array([6.5, 2.5]))
    """
    ny, nx = (int(n) for n in shape)
    f = _mapper(transform)
    s = float(scale)
    pm = np.empty((ny, nx, 2))
    x = np.arange(nx, dtype=float)
    rows = max(1, _BAND_PIXELS // max(nx, 1))
    for r0 in range(0, ny, rows):
        r1 = min(ny, r0 + rows)
        yy, xx = np.broadcast_arrays(np.arange(r0, r1, dtype=float)[:, None], x[None, :])
        xo, yo = f(xx, yy)
        pm[r0:r1, :, 0] = s * (np.asarray(xo, dtype=float) - offset[0] + 0.5) - 0.5
        pm[r0:r1, :, 1] = s * (np.asarray(yo, dtype=float) - offset[1] + 0.5) - 0.5
    return pm


def pixel_area(pixmap):
    """
    The median area of a frame pixel on the output grid, in output pixels
    (``scale**2`` for a shift or rotation): from the pixel map's Jacobian.

    Examples
    --------
    >>> from astroalign_nd.stacking.drizzle import pixel_map, pixel_area
    >>> round(pixel_area(pixel_map(None, (8, 8), scale=2)), 6)
    4.0
    """
    step = max(1, min(pixmap.shape[:2]) // 64)
    p = pixmap[::step, ::step]
    if min(p.shape[:2]) < 2:
        return float(np.nan)
    dx = (p[:, 1:] - p[:, :-1])[:-1] / step
    dy = (p[1:, :] - p[:-1, :])[:, :-1] / step
    det = np.abs(dx[..., 0] * dy[..., 1] - dx[..., 1] * dy[..., 0])
    det = det[np.isfinite(det)]
    return float(np.median(det)) if det.size else float(np.nan)


def weight_map(data, mask=None, variance=None, *, weight=1.0, saturation=None):
    """
    A frame's per-pixel weights: ``weight`` where the pixel is good, 0 where not.

    A pixel is bad where ``mask`` is True, its value or variance is not
    finite (or the variance is negative), or its value is at or above
    ``saturation``.  The frame's weight should come from its sky noise (as
    `~astroalign_nd.stack`'s ``weights='variance'``: the inverse of its
    median variance), never from a per-pixel variance that includes the
    stars' own photon noise (that would make stars look sharper and lose
    flux).  A colour (Bayer) stack multiplies the result by the colour's
    0/1 pattern.

    Parameters
    ----------
    data : 2-D ndarray
    mask : 2-D bool ndarray, optional
        True = bad.
    variance : 2-D ndarray, optional
    weight : float, optional
        The frame's weight (default 1).
    saturation : float, optional
        Values at or above are bad.

    Returns
    -------
    weights : 2-D float32 ndarray
    """
    data = np.asarray(data)
    good = np.isfinite(data)
    if mask is not None:
        good &= ~np.asarray(mask, dtype=bool)
    if variance is not None:
        v = np.asarray(variance)
        with np.errstate(invalid="ignore"):
            good &= np.isfinite(v) & (v >= 0)
    if saturation is not None:
        with np.errstate(invalid="ignore"):
            good &= ~(data >= saturation)
    return np.where(good, np.float32(weight), np.float32(0.0))


def blot_mask(flags, pixmap):
    """
    A mask on the output grid carried back onto a frame (drizzle's
    ``blot_image``): a frame pixel is flagged when any output pixel its
    position interpolates between (bilinearly) is.

    This is how the rejection of a stack reaches the frames before they are
    drizzled: ``flags`` marks the outliers of one frame found on the
    reference's grid, ``pixmap`` is that frame's `pixel_map` at scale 1.

    Parameters
    ----------
    flags : 2-D bool ndarray
        On the grid ``pixmap`` maps to.
    pixmap : (ny, nx, 2) ndarray
        The frame's `pixel_map` onto that grid.

    Returns
    -------
    mask : (ny, nx) bool ndarray
        True on the frame's pixels that touch a flagged pixel.
    """
    flags = np.asarray(flags, dtype=bool)
    if not flags.any():
        return np.zeros(pixmap.shape[:2], dtype=bool)
    pm = np.where(np.isfinite(pixmap), pixmap, -1e6)  # no position: outside, not flagged
    out = blot_image(flags.astype(np.float32), pm, fillval=0.0, interp="linear")
    return out > 1e-6


@dataclass
class DrizzlePlanes:
    """
    The output of a drizzle (`DrizzleAccumulator.planes`).

    Attributes
    ----------
    value : 2-D float64 ndarray
        Counts per output pixel; NaN where no input reached.
    variance : 2-D float64 ndarray
        Its variance, through drizzle's squared-weight path; NaN where no
        input reached.
    weight : 2-D float32 ndarray
        Drizzle's output weight (the sum of the weights times the overlaps).
    count : 2-D int16 ndarray
        The number of frames that reached each output pixel with a weight > 0.
    """

    value: np.ndarray
    variance: np.ndarray
    weight: np.ndarray
    count: np.ndarray


class DrizzleAccumulator:
    """
    A drizzle to which frames are added one at a time.

    It holds only the output planes (value, variance, weight: float32; the
    frame count: int16), about 14 bytes per output pixel; each frame is
    dropped as it is added.

    Parameters
    ----------
    shape : (ny, nx)
        The output grid (`output_shape` of the reference's or canvas's shape).
    scale : float
        Output pixels per reference pixel (the scale of the frames' pixel maps).
    pixfrac : float, optional
        Linear fraction of an input pixel its value is dropped onto (default 1).
    kernel : str, optional
        One of `DRIZZLE_KERNELS` (default 'square').

    Examples
    --------
    Four frames of a flat sky of 100 counts, dithered by half pixels, at
    scale 2: 25 counts per output pixel (flux conserved).

    >>> import numpy as np
    >>> from astroalign_nd.stacking.drizzle import (DrizzleAccumulator, pixel_map,
    ...                                             weight_map, output_shape)
    >>> acc = DrizzleAccumulator(output_shape((16, 16), 2), 2, pixfrac=0.7)
    >>> for dx, dy in [(0, 0), (0.5, 0), (0, 0.5), (0.5, 0.5)]:
    ...     frame = np.full((16, 16), 100.0)
    ...     m = np.array([[1, 0, dx], [0, 1, dy], [0, 0, 1.0]])
    ...     n_used = acc.add(frame, pixel_map(m, frame.shape, 2), weight_map(frame),
    ...                      variance=np.full((16, 16), 4.0))
    >>> out = acc.planes()
    >>> float(np.nanmedian(out.value)), int(out.count.max())
    (25.0, 4)
    """

    def __init__(self, shape, scale, pixfrac=1.0, kernel="square"):
        self.scale, self.pixfrac, self.kernel = check_drizzle_options(scale, pixfrac, kernel)
        self.shape = tuple(int(n) for n in shape)
        self._count = np.zeros(self.shape, dtype=np.int16)
        self._driz = Drizzle(kernel=self.kernel, out_shape=self.shape, fillval=0.0,
                             out_img2=[np.zeros(self.shape, dtype=np.float32)],
                             disable_ctx=True)
        self.n_frames = 0

    def add(self, data, pixmap, weights, variance=None, *, iscale=None):
        """
        Drizzle one frame onto the output.

        Parameters
        ----------
        data : 2-D ndarray
            The frame, normalised (on the reference's sky and unit, as the
            stack normalises it).
        pixmap : (ny, nx, 2) ndarray
            Its `pixel_map` onto the output grid, at this accumulator's scale.
        weights : 2-D ndarray
            Its per-pixel weights (`weight_map`; 0 = not used: masked, NaN,
            saturated, rejected, or another colour's pixel).
        variance : 2-D ndarray, optional
            Its per-pixel variance (it may include the stars' photon noise:
            it is propagated, not used as a weight).  Without it the output
            variance is 0.
        iscale : float, optional
            The factor applied to the values (and its square to the
            variance); default ``1 / pixel_area(pixmap)``, which conserves
            flux.

        Returns
        -------
        n_used : int
            The frame's pixels that landed on the output with a weight > 0.
        """
        data = np.asarray(data)
        if data.ndim != 2 or pixmap.shape != data.shape + (2,):
            raise ValueError(f"pixmap must have shape {data.shape + (2,)} (the frame's shape "
                             f"and 2), from pixel_map(transform, frame.shape); got "
                             f"{pixmap.shape}.")
        w = np.array(weights, dtype=np.float32)
        if w.shape != data.shape:
            raise ValueError(f"weights must have the frame's shape {data.shape}; got "
                             f"{w.shape}.")
        ok = (w > 0) & np.isfinite(data) & np.all(np.isfinite(pixmap), axis=2)
        var = None
        if variance is not None:
            var = np.asarray(variance)
            with np.errstate(invalid="ignore"):
                ok &= np.isfinite(var) & (var >= 0)
            var = np.where(ok, var, 0.0).astype(np.float32)
        w[~ok] = 0.0
        # Unused pixels hold zeros (drizzle multiplies them by their zero weight: no NaN).
        d = np.where(ok, data, 0.0).astype(np.float32)
        pm = np.where(np.isfinite(pixmap), pixmap, -1e6)
        if iscale is None:
            iscale = 1.0 / pixel_area(pixmap)
        before = self._driz.out_wht.copy()
        self._driz.add_image(d, exptime=1.0, pixmap=pm, data2=[var], weight_map=w,
                             pixfrac=self.pixfrac, in_units="cps", iscale=float(iscale),
                             pixel_scale_ratio=self.scale)
        self._count += self._driz.out_wht > before
        self.n_frames += 1
        return int(ok.sum())

    def planes(self):
        """
        The output so far (copies: adding more frames does not change them).

        Returns
        -------
        planes : `DrizzlePlanes`
        """
        wht = self._driz.out_wht.copy()
        empty = ~(wht > 0)
        value = np.where(empty, np.nan, self._driz.out_img)
        variance = np.where(empty, np.nan, self._driz.out_img2[0])
        return DrizzlePlanes(value=value.astype(np.float64), variance=variance.astype(np.float64),
                             weight=wht, count=self._count.copy())


def scaled_wcs(wcs, scale, shape, offset=(0, 0)):
    """
    The reference's WCS on the drizzle's output grid (SIP distortion too).

    The grid is first shifted to the canvas (``offset``), then cut into
    ``scale`` finer pixels with astropy's WCS slicing (its reference pixel,
    pixel scale and distortion tables); the SIP polynomials, which slicing
    leaves in the reference's pixels, are rescaled to the finer pixels
    (``A_p_q`` times ``scale ** (1 - p - q)``, and their inverse alike).

    Parameters
    ----------
    wcs : `~astropy.wcs.WCS` or None
        The reference's celestial WCS.
    scale : float
        Output pixels per reference pixel.
    shape : (ny, nx)
        The output's shape (the WCS's ``pixel_shape``).
    offset : (x0, y0), optional
        Reference pixel coordinates of the canvas's pixel ``(0, 0)``.

    Returns
    -------
    wcs : `~astropy.wcs.WCS` or None

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.wcs import WCS
    >>> from astroalign_nd.stacking.drizzle import scaled_wcs
    >>> w = WCS(naxis=2)
    >>> w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    >>> w.wcs.cd = [[-1e-3, 0.0], [0.0, 1e-3]]
    >>> w.wcs.crpix = [50.0, 40.0]
    >>> fine = scaled_wcs(w, 2.0, (160, 200))
    >>> # reference pixel (10, 20) is output pixel (2 * 10.5 - 0.5, 2 * 20.5 - 0.5)
    >>> np.allclose(w.pixel_to_world_values(10, 20), fine.pixel_to_world_values(20.5, 40.5))
    True
    """
    if wcs is None:
        return None
    w = canvas_wcs(wcs, offset, [max(1, int(round(n / float(scale)))) for n in shape])
    if w.wcs.has_cd():  # slicing scales CDELT: the linear part as PC and CDELT
        cd = w.wcs.cd.copy()
        del w.wcs.cd
        w.wcs.pc, w.wcs.cdelt = cd, [1.0] * len(cd)
    step = 1.0 / float(scale)
    view = [slice(None)] * (w.naxis - 2) + [slice(0, None, step)] * 2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NAXIS not updated for a non-integer step: set below
        out = w.slice(tuple(view))
    if out.sip is not None:
        def rescaled(c):
            if c is None:
                return None
            p, q = np.indices(c.shape)
            return c * float(scale) ** (1.0 - p - q)
        out.sip = Sip(rescaled(out.sip.a), rescaled(out.sip.b), rescaled(out.sip.ap),
                      rescaled(out.sip.bp), out.wcs.crpix[:2])
    out.pixel_shape = (int(shape[1]), int(shape[0]))
    return out


#: Above these, `coverage_report` warns: the fraction of empty output pixels among those
#: the frames reach, and the relative spread of the weight where every frame reaches.
MAX_EMPTY_FRACTION, MAX_WEIGHT_SPREAD = 0.001, 0.3


def on_output_grid(plane, scale, shape):
    """
    A plane of the reference's (canvas's) grid seen on the output grid: each
    output pixel takes the value of the reference pixel its centre lies in.
    """
    s = float(scale)
    rows = np.clip(np.floor((np.arange(shape[0]) + 0.5) / s).astype(int), 0,
                   plane.shape[0] - 1)
    cols = np.clip(np.floor((np.arange(shape[1]) + 0.5) / s).astype(int), 0,
                   plane.shape[1] - 1)
    return plane[np.ix_(rows, cols)]


def coverage_report(planes, coverage, n_frames, scale, *, pixfrac=None, warn_user=True):
    """
    How well the frames fill the output: the fraction of empty output pixels
    and the uniformity of the weight, with a warning that says what to change.

    Parameters
    ----------
    planes : `DrizzlePlanes`
    coverage : 2-D int ndarray
        The number of frames reaching each pixel of the reference's (canvas's)
        grid (a stack's ``flags``): where the frames are.
    n_frames : int
        The frames drizzled.
    scale : float
    pixfrac : float, optional
        Named in the warning.
    warn_user : bool, optional
        Warn (`~astroalign_nd.exceptions.AstroalignWarning`) when the output
        has holes (more than `MAX_EMPTY_FRACTION` of the pixels the frames
        reach) or a grid pattern (the weight's relative spread where every
        frame reaches above `MAX_WEIGHT_SPREAD`).

    Returns
    -------
    empty_fraction : float
        Output pixels no input reached, among those inside the frames.
    weight_spread : float
        Standard deviation over mean of the output weight where every frame
        reaches (NaN if there is no such pixel): 0 is perfectly uniform.
    """
    shape = planes.weight.shape
    inside = on_output_grid(np.asarray(coverage) > 0, scale, shape)
    n_inside = int(inside.sum())
    empty = float((inside & (planes.count == 0)).sum() / n_inside) if n_inside else 0.0
    interior = on_output_grid(np.asarray(coverage) >= n_frames, scale, shape)
    w = planes.weight[interior]
    spread = float(np.std(w) / np.mean(w)) if w.size and np.mean(w) > 0 else float("nan")
    if warn_user and (empty > MAX_EMPTY_FRACTION or spread > MAX_WEIGHT_SPREAD):
        what = []
        if empty > MAX_EMPTY_FRACTION:
            what.append(f"{100 * empty:.2g}% of the output pixels inside the frames got no "
                        "data (holes, masked)")
        if spread > MAX_WEIGHT_SPREAD:
            what.append(f"the output weight varies by {100 * spread:.0f}% from pixel to pixel "
                        "(a grid pattern)")
        pf = "" if pixfrac is None else f" (now {pixfrac:g})"
        warn(f"drizzle at scale {scale:g} from {n_frames} frames: {' and '.join(what)}; raise "
             f"pixfrac toward 1{pf}, use a smaller scale, or stack more frames with more "
             "dither between them.")
    return empty, spread
