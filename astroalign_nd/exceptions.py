# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Exceptions and warnings raised by astroalign_nd."""

from __future__ import annotations

import os
import sys
import warnings

from astropy.utils.exceptions import AstropyUserWarning

__all__ = [
    "AstroalignError",
    "TooFewSourcesError",
    "TransformNotFoundError",
    "AstroalignWarning",
    "PoorFitWarning",
]


class AstroalignError(Exception):
    """Base class of every registration failure raised by astroalign_nd."""


class TooFewSourcesError(AstroalignError, ValueError):
    """An image or catalog gave fewer sources than a transform needs."""


class TransformNotFoundError(AstroalignError):
    """No transform was found, or none could be trusted.

    The message reports how many sources each image gave, how many
    triangle matches were tried and the best inlier count, so that the user
    can tell a sparse field from an unrelated pair.
    """


class AstroalignWarning(AstropyUserWarning):
    """Base class of astroalign_nd's warnings (an astropy user warning)."""


class PoorFitWarning(AstroalignWarning):
    """The fitted transform leaves residuals larger than the centroid noise."""


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def _stacklevel():
    """
    The stacklevel of the first frame outside astroalign_nd.

    So that a warning points at the caller's line, however deep in the
    pipeline it is raised (a fixed stacklevel is right for one call path
    only).
    """
    frame = sys._getframe(2)  # the caller of warn()
    level = 2
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(
            _PACKAGE_DIR):
        frame = frame.f_back
        level += 1
    return level


def warn(message: str, category: type[Warning] = AstroalignWarning) -> None:
    """`warnings.warn` pointing at the user's line that called astroalign_nd."""
    warnings.warn(message, category, stacklevel=_stacklevel())
