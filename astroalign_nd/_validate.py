# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Checks of inputs shared by the stages: star positions and counts.

A leaf module: it imports no other module of the package, so that every
stage can use it.  The options' accepted ranges are the fields of each
stage's config, in the package's one checking system
(``astroalign_nd.options``).
"""

import numbers

import numpy as np

__all__ = ["check_count", "check_points", "MAX_TRIANGLES", "MAX_COORDINATE"]

#: Largest number of triangles built for one image (about 100 bytes each
#: with their invariants and k-d tree): larger requests get a ValueError
#: instead of exhausting memory.
MAX_TRIANGLES = 2_000_000

#: Largest absolute pixel coordinate accepted in a catalog.  Squared
#: distances of larger numbers lose all precision (and overflow near 1e154).
MAX_COORDINATE = 1e9


def check_count(value, name, lo=3):
    """A star count: an integer >= ``lo`` (3 by default: a triangle), named in the message."""
    message = f"{name} must be an integer >= {lo} (a triangle needs 3 stars); got {value!r}."
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(message)
    if int(value) < lo:
        raise ValueError(message)
    return int(value)


def check_points(pts, name, *, max_coordinate=MAX_COORDINATE):
    """
    An (N, 2) array of finite pixel positions, within `MAX_COORDINATE`.

    The one check of point lists: catalogs, and the pairs the models are
    fitted to (``max_coordinate=None``: no limit).

    Returns
    -------
    points : (N, 2) float ndarray
    """
    try:
        arr = np.asarray(pts, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"the {name} positions must be an (N, 2) array of numbers.") from None
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"the {name} positions must be an (N, 2) array; got shape "
                         f"{arr.shape}.")
    if arr.size and not np.all(np.isfinite(arr)):
        raise ValueError(f"the {name} positions must be finite; drop the rows holding NaN or "
                         "infinity.")
    if max_coordinate is not None and arr.size and np.max(np.abs(arr)) > max_coordinate:
        raise ValueError(
            f"the {name} positions must be pixel coordinates within +/-{max_coordinate:g}; "
            f"the largest is {np.max(np.abs(arr)):g}. Convert them to pixels first.")
    return arr
