# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The union canvas: one output grid that holds every frame."""

from __future__ import annotations

import numpy as np
from ..transforms.convert import as_matrix
from .results import FrameResult
from .frame import shifted_transform

__all__ = ['union_canvas']

#: Refuse canvases larger than this many pixels (about 1 GB per float32 frame).
_MAX_CANVAS_PIXELS = 2**28


def _valid_margin(resample):
    """
    How far inside the frame's edge pixel centres the resampling is valid
    (see `~astroalign_nd.resample.resample`): a frame's pixels count from
    ``margin`` to ``n - 1 - margin``; -0.5 for nearest-neighbour, 0 for
    bilinear, 0.5 for biquadratic and 1 for bicubic interpolation (and for
    ``method='exact'``, -0.5), from the `~astroalign_nd.resample.ResampleConfig` ``resample``.
    """
    if resample.method == "exact":
        return -0.5
    return (resample.order_index - 1) / 2.0


def union_canvas(transforms, shapes, reference_shape, margin=0.0):
    """
    The smallest grid, aligned with the reference's pixels, that holds the
    reference and every frame mapped into it.

    Like reproject's ``find_optimal_celestial_wcs``, but from the fitted
    transforms and without resampling the reference: the canvas is the
    reference's grid shifted by whole pixels and enlarged.

    Parameters
    ----------
    transforms : list of models
        Source-to-reference transforms.
    shapes : list of (ny, nx)
        The source frames' shapes.
    reference_shape : (ny, nx)
    margin : float, optional
        Source positions ``margin <= x <= nx - 1 - margin`` can be
        resampled (0 for bilinear interpolation, which needs the pixels on
        both sides); canvas pixels beyond would be masked in every frame.

    Returns
    -------
    shape : (ny, nx)
        Canvas shape.
    offset : (x0, y0)
        Reference pixel coordinates of canvas pixel ``(0, 0)`` (integers,
        so that the reference's pixels fall exactly on canvas pixels).

    Examples
    --------
    A 100 x 100 frame shifted by 50.5 pixels in x and -20 in y from a
    100 x 100 reference:

    >>> import numpy as np
    >>> from astroalign_nd.batch import union_canvas
    >>> shift = np.array([[1.0, 0.0, 50.5], [0.0, 1.0, -20.0], [0.0, 0.0, 1.0]])
    >>> union_canvas([shift], [(100, 100)], (100, 100))
    ((120, 150), (0, -20))
    """
    ny, nx = reference_shape
    xs, ys = [0.0, nx - 1.0], [0.0, ny - 1.0]
    for t, (h, w) in zip(transforms, shapes):
        m = as_matrix(t)
        lo_x, hi_x, lo_y, hi_y = margin, w - 1.0 - margin, margin, h - 1.0 - margin
        cx = np.array([lo_x, hi_x, lo_x, hi_x])
        cy = np.array([lo_y, lo_y, hi_y, hi_y])
        xs.extend(m[0, 0] * cx + m[0, 1] * cy + m[0, 2])
        ys.extend(m[1, 0] * cx + m[1, 1] * cy + m[1, 2])
    # Canvas pixel centres inside the mapped frames: a pixel whose centre is
    # outside all of them would be masked in every frame.
    eps = 1e-6
    x0, x1 = int(np.ceil(min(xs) - eps)), int(np.floor(max(xs) + eps))
    y0, y1 = int(np.ceil(min(ys) - eps)), int(np.floor(max(ys) + eps))
    return (y1 - y0 + 1, x1 - x0 + 1), (x0, y0)


def canvas_wcs(wcs, offset, shape):
    """The reference's WCS on a canvas: its reference pixel shifted by ``offset``."""
    if wcs is None:
        return None
    w = wcs.deepcopy()
    w.wcs.crpix = [w.wcs.crpix[0] - offset[0], w.wcs.crpix[1] - offset[1]]
    w.pixel_shape = (shape[1], shape[0])
    return w


def _union_grid(found, reference_shape, margin):
    """The union canvas of the frames found (`union_canvas`), refused if too large."""
    if not found:
        return tuple(reference_shape), (0, 0)
    order_ = sorted(found)
    shape, offset = union_canvas([found[i].transform for i in order_],
                                 [found[i].shape for i in order_], reference_shape,
                                 margin=margin)
    if shape[0] * shape[1] > _MAX_CANVAS_PIXELS:
        area = {i: np.prod(union_canvas([found[i].transform], [found[i].shape],
                                        reference_shape, margin=margin)[0]) for i in found}
        worst = max(area, key=area.get)
        raise ValueError(
            f"the union canvas would be {shape[1]}x{shape[0]} pixels, more than "
            f"{_MAX_CANVAS_PIXELS}: some frames land very far from the reference (the "
            f"farthest is {found[worst].name}, transform {found[worst].transform!r}). "
            "Leave such frames out, or use canvas='reference'.")
    return shape, offset


def _kept_on_canvas(res, shape, offset, overwrite):
    """
    A skipped frame's result if its output lies on this canvas, a failure
    if it lies on another and may not be replaced, or None to redo it.
    """
    if tuple(res._grid[0]) == tuple(shape) and tuple(res._grid[1]) == tuple(offset):
        res.transform = shifted_transform(res.transform, offset, sign=-1)
        return res
    if not overwrite:
        return FrameResult(
            name=res.name, status="failed", source=res.source,
            error=f"FileExistsError: {res.output} was registered onto another "
            "canvas (the set of frames changed); pass overwrite=True (or "
            "--overwrite) to redo it.")
    return None
