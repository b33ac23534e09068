# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Exceptions and warnings raised by astroalign_nd."""

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


class AstroalignWarning(UserWarning):
    """Base class of astroalign_nd's warnings."""


class PoorFitWarning(AstroalignWarning):
    """The fitted transform leaves residuals larger than the centroid noise."""
