# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The frames' geometry: overlap, bounding boxes and grids of test points."""

import functools
import numpy as np
from ..transforms import apply_matrix

__all__ = []


@functools.lru_cache(maxsize=32)
def _grid_points(frame, n_grid):
    """An ``n_grid`` x ``n_grid`` grid of points over a frame (read-only, kept:
    a search asks for the same few grids again and again)."""
    x0, x1, y0, y1 = frame
    xx, yy = np.meshgrid(np.linspace(x0, x1, n_grid), np.linspace(y0, y1, n_grid))
    grid = np.column_stack([xx.ravel(), yy.ravel()])
    grid.flags.writeable = False
    return grid


def _frame_grid(frame, n_grid):
    return _grid_points(tuple(float(v) for v in frame), n_grid)


def _frame_area_fraction(m, src_frame, dst_frame, n_grid=48):
    """Overlap of the source frame mapped into the target frame (fraction, area)."""
    (x0, x1, y0, y1) = dst_frame
    inv = np.linalg.inv(m)
    q = apply_matrix(inv, _frame_grid(dst_frame, n_grid))
    sx0, sx1, sy0, sy1 = src_frame
    inside = (q[:, 0] >= sx0) & (q[:, 0] <= sx1) & (q[:, 1] >= sy0) & (q[:, 1] <= sy1)
    frac = inside.mean()
    return frac, frac * (x1 - x0) * (y1 - y0)


def _overlap_box(m, src_frame, dst_frame, n_grid=24):
    """Bounding box (x0, x1, y0, y1) in the target of the source frame's footprint there."""
    grid = _frame_grid(dst_frame, n_grid)
    inside = grid[_in_frame(apply_matrix(np.linalg.inv(m), grid), src_frame)]
    if len(inside) == 0:
        return dst_frame
    (ox0, oy0), (ox1, oy1) = inside.min(axis=0), inside.max(axis=0)
    return (ox0, ox1, oy0, oy1)


def _in_frame(pts, frame):
    x0, x1, y0, y1 = frame
    return (pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1)


def _bbox(pts):
    x0, y0 = pts.min(axis=0)
    x1, y1 = pts.max(axis=0)
    pad = 0.5
    return (x0 - pad, x1 + pad, y0 - pad, y1 + pad)
