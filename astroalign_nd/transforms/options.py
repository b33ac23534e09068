# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The transform fitted: `ModelConfig` (a type of the registry and its degree),
in the package's checking system (``astroalign_nd.options``).
"""

import dataclasses

from ..options import Unchecked, option
from . import registry

__all__ = ["ModelConfig"]


def _transform_type_help():
    """The help of ``--transform-type``: the registry's types when it is asked for."""
    return (f"model fitted between the images: {', '.join(registry.LINEAR_TYPES)}, or for "
            f"wide fields with distortion {' or '.join(registry.NONLINEAR_TYPES)} (see --degree) "
            "(default: %(default)s)")


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """
    The transform fitted.

    Parameters
    ----------
    transform_type : str or type, optional
        A type of the transform registry (`TRANSFORM_REGISTRY`).
    degree : int, 'auto' or None, optional
        Degree of a 'polynomial' model (None there means 3).

    Examples
    --------
    >>> from astroalign_nd.transforms import ModelConfig
    >>> ModelConfig("polynomial").degree
    3
    """

    transform_type: object = option(
        "similarity", Unchecked(), _transform_type_help,
        flag="--transform-type", metavar="TYPE")
    degree: object = option(
        None, Unchecked(),
        "degree of the polynomial distortion model, 2 to 5, or 'auto' to let an F-test "
        "choose (linear when the images need no distortion); only with --transform-type "
        "polynomial (default: 3)",
        flag="--degree", metavar="N")

    def __post_init__(self):
        object.__setattr__(self, "degree",
                           registry.check_degree(self.transform_type, self.degree))
        # Not a field: derived from transform_type, checked once here.
        object.__setattr__(self, "_nonlinear", registry.is_nonlinear(self.transform_type))
        registry.transform_class(self.linear_type)  # an unknown type: a clear message, first

    @property
    def nonlinear(self):
        """True for a distortion model (grown from a linear match)."""
        return self._nonlinear

    @property
    def linear_type(self):
        """The type of the first, linear match: a distortion model grows from a similarity."""
        return "similarity" if self.nonlinear else self.transform_type
