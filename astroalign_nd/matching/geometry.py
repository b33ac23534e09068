# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The frames' geometry: overlap, bounding boxes and grids of test points."""

import functools
import numpy as np
from scipy.special import betainc
from ..transforms import apply_matrix

__all__ = ["bounding_frame", "overlap_counts", "chance_pairs_log10"]


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


def bounding_frame(points):
    """
    The frame ``(x0, x1, y0, y1)`` of a star list: its bounding box, half a
    pixel wider on every side.

    `match_points` takes it as a list's frame when none is given (a
    catalog has no image extent).

    Parameters
    ----------
    points : (N, 2) ndarray
        Positions (x, y), at least one.

    Returns
    -------
    frame : tuple of 4 floats

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.matching import bounding_frame
    >>> [float(v) for v in bounding_frame(np.array([[1.0, 2.0], [5.0, 3.0]]))]
    [0.5, 5.5, 1.5, 3.5]
    """
    x0, y0 = points.min(axis=0)
    x1, y1 = points.max(axis=0)
    pad = 0.5
    return (x0 - pad, x1 + pad, y0 - pad, y1 + pad)


def overlap_counts(matrix, source_points, target_points, source_frame, target_frame):
    """
    How many stars of each list lie in the overlap of the two frames.

    Parameters
    ----------
    matrix : (3, 3) ndarray
        The source-to-target pixel matrix (affine).
    source_points, target_points : (N, 2), (M, 2) ndarray
        The two star lists (x, y).
    source_frame, target_frame : (x0, x1, y0, y1)
        The extent of each frame (see `bounding_frame` for a catalog's).

    Returns
    -------
    n_source, n_target : int
        The source stars that ``matrix`` maps into the target frame, and
        the target stars that its inverse maps into the source frame.

    Examples
    --------
    A shift by 50 pixels: the right half of the source frame overlaps the
    target frame.

    >>> import numpy as np
    >>> from astroalign_nd.matching import overlap_counts
    >>> shift = np.array([[1.0, 0.0, -50.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    >>> stars = np.array([[10.0, 10.0], [60.0, 20.0], [90.0, 50.0]])
    >>> overlap_counts(shift, stars, stars, (0, 100, 0, 100), (0, 100, 0, 100))
    (2, 1)
    """
    n_source = int(np.sum(_in_frame(apply_matrix(matrix, source_points), target_frame)))
    n_target = int(np.sum(_in_frame(apply_matrix(np.linalg.inv(matrix), target_points),
                                    source_frame)))
    return n_source, n_target


def chance_pairs_log10(matrix, source_points, target_points, n_pairs, radius, source_frame,
                       target_frame):
    """
    How likely ``n_pairs`` pairs are by chance under a transform that was
    predicted, not searched (so no trials factor).

    Each source star in the overlap falls within ``radius`` of one of the
    target stars there with probability ``p = n_target * pi * radius**2 /
    area``; the figure is the binomial tail P(X >= n_pairs), as the
    search's false-alarm figure takes it over the stars past its triangle.

    Parameters
    ----------
    matrix : (3, 3) ndarray
        The source-to-target pixel matrix.
    source_points, target_points : (N, 2), (M, 2) ndarray
        The two star lists (x, y).
    n_pairs : int
        The pairs found under ``matrix``.
    radius : float
        The pairing radius (pixels).
    source_frame, target_frame : (x0, x1, y0, y1)
        The extent of each frame (see `bounding_frame` for a catalog's).

    Returns
    -------
    log10_probability : float
        At most 0, at least -300.
    n_source : int
        The source stars in the overlap (at least ``n_pairs``).

    Examples
    --------
    Ten of twenty stars paired within 0.5 px in a 100 x 100 frame cannot
    be chance; one pair can.

    >>> import numpy as np
    >>> from astroalign_nd.matching import chance_pairs_log10
    >>> stars = np.random.default_rng(1).uniform(0, 100, (20, 2))
    >>> frame = (0, 100, 0, 100)
    >>> log_p, n = chance_pairs_log10(np.eye(3), stars, stars, 10, 0.5, frame, frame)
    >>> bool(log_p < -15), n
    (True, 20)
    >>> bool(chance_pairs_log10(np.eye(3), stars, stars, 1, 0.5, frame, frame)[0] > -2)
    True
    """
    _, area = _frame_area_fraction(matrix, source_frame, target_frame)
    n_source, n_target = overlap_counts(matrix, source_points, target_points, source_frame,
                                        target_frame)
    n_source = max(n_source, n_pairs)  # a pair may sit just off an edge
    if area <= 0 or n_pairs <= 0:
        return 0.0, n_source
    p = min(1.0, max(n_target, 1) * np.pi * radius ** 2 / area)
    tail = betainc(n_pairs, n_source - n_pairs + 1, p) if p < 1 else 1.0
    return (float(max(np.log10(tail), -300.0)) if tail > 0 else -300.0), n_source
