# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The public options, checked in one place.

Every option of `~astroalign_nd.find_transform` (and of the functions it
calls) has one entry in `OPTIONS`: its kind and accepted range.
`check_options` checks the options it is given against that table and
returns them normalised (``float``/``int``/``tuple``), so that a bad value
gives one message that names the option and the accepted range, before any
work is done, instead of an error from deep inside numpy.
"""

import math
import numbers

import numpy as np

__all__ = ["OPTIONS", "check_options", "check_option", "check_count", "check_points",
           "MAX_TRIANGLES", "MAX_COORDINATE"]

#: Largest number of triangles built for one image (about 100 bytes each
#: with their invariants and k-d tree): larger requests get a ValueError
#: instead of exhausting memory.
MAX_TRIANGLES = 2_000_000

#: Largest absolute pixel coordinate accepted in a catalog.  Squared
#: distances of larger numbers lose all precision (and overflow near 1e154).
MAX_COORDINATE = 1e9


class _Real:
    """A real number in an interval (each bound open or closed)."""

    def __init__(self, lo=None, hi=None, *, lo_open=False, hi_open=False, none=False,
                 unit="", infinite=False):
        self.lo, self.hi, self.lo_open, self.hi_open = lo, hi, lo_open, hi_open
        self.none, self.unit, self.infinite = none, unit, infinite

    def describe(self):
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {self.lo:g}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {self.hi:g}")
        text = ("a number" if self.infinite else "a finite number") + (
            " " + " and ".join(parts) if parts else "")
        if self.unit:
            text += f" ({self.unit})"
        return text + (" or None" if self.none else "")

    def _in_range(self, v):
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        if self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi):
            return False
        return True

    #: The accepted type (bools are refused).
    _kind = numbers.Real

    def _is_none(self, value):
        """True for an accepted None; TypeError for another None or a value of another type."""
        if value is None:
            if self.none:
                return True
            raise TypeError
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, self._kind):
            raise TypeError
        return False

    def convert(self, value):
        if self._is_none(value):
            return None
        v = float(value)
        if math.isnan(v) or (math.isinf(v) and not self.infinite) or not self._in_range(v):
            raise ValueError
        return v


class _Int(_Real):
    """An integer in a closed interval."""

    def describe(self):
        text = super().describe().replace("a finite number", "an integer")
        text = text.replace("a number", "an integer")
        return text

    _kind = numbers.Integral

    def convert(self, value):
        if self._is_none(value):
            return None
        v = int(value)
        if not self._in_range(v):
            raise ValueError
        return v


class _Pair:
    """An increasing pair ``(lo, hi)`` of numbers, each checked by ``item``."""

    def __init__(self, item, *, none=True, strict=False):
        self.item, self.none, self.strict = item, none, strict

    def describe(self):
        order = "lo < hi" if self.strict else "lo <= hi"
        return (f"a pair (lo, hi) with {order}, each {self.item.describe()}"
                + (", or None" if self.none else ""))

    def convert(self, value):
        if value is None:
            if self.none:
                return None
            raise TypeError
        if isinstance(value, (str, bytes)) or not np.iterable(value):
            raise TypeError
        items = list(value)
        if len(items) != 2:
            raise ValueError
        lo, hi = (self.item.convert(v) for v in items)
        if lo > hi or (self.strict and lo == hi):
            raise ValueError
        return (lo, hi)


class _Bool:
    def describe(self):
        return "True or False"

    def convert(self, value):
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
        raise TypeError


#: Every public option: how it is checked.
OPTIONS = {
    # matching
    "tolerance": _Real(0, 1e6, lo_open=True, unit="pixels"),
    "min_tolerance": _Real(0, 1e6, lo_open=True, unit="pixels"),
    "invariant_radius": _Real(0, 10, lo_open=True),
    "n_neighbors": _Int(2, 16),
    "allow_mirror": _Bool(),
    "scale_range": _Pair(_Real(0, lo_open=True)),
    "max_false_alarm": _Real(0, 1, lo_open=True),
    "accept_matches": _Int(3, None),
    "batch_size": _Int(1, 1_000_000),
    "max_hypotheses": _Int(1, 10_000_000),
    # detection
    "fwhm": _Real(0, 1e4, lo_open=True, none=True, unit="pixels"),
    "nsigma": _Real(0, 1e6, lo_open=True, none=True),
    "peak_max": _Real(none=True),
    "bin_factor": _Int(1, 1024, none=True),
    # Sharpness has no lower limit by default (saturated stars): -inf is allowed.
    "sharpness_range": _Pair(_Real(infinite=True), none=True),
    "roundness_range": _Pair(_Real(infinite=True), none=True),
    "refine_centroids": _Bool(),
    # counts of stars
    "n_sources": _Int(3, 1_000_000),
    "max_sources": _Int(3, 1_000_000),
}


def check_option(name, value):
    """
    Check one option against `OPTIONS`; return it normalised.

    Raises
    ------
    TypeError, ValueError
        Naming the option and the accepted values.
    """
    spec = OPTIONS[name]
    try:
        return spec.convert(value)
    except (TypeError, ValueError) as exc:
        kind = type(exc) if type(exc) in (TypeError, ValueError) else ValueError
        raise kind(f"{name} must be {spec.describe()}; got {value!r}.") from None


def check_count(value, name, lo=3):
    """A star count: an integer >= ``lo`` (3 by default: a triangle), named in the message."""
    try:
        return _Int(lo, None).convert(value)
    except (TypeError, ValueError) as exc:
        raise type(exc)(f"{name} must be an integer >= {lo} (a triangle needs 3 stars); got "
                        f"{value!r}.") from None


def check_options(options):
    """
    Check a dict of options (unknown names are left to the caller).

    Returns
    -------
    options : dict
        The same keys, values normalised.
    """
    return {k: (check_option(k, v) if k in OPTIONS else v) for k, v in options.items()}


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
