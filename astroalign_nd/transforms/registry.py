# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The transform types by name."""

from __future__ import annotations

from astropy.modeling import Model
from .polynomial import PolynomialTransform
from .projective import ProjectiveTransform
from .linear import (AffineTransform, EuclideanTransform, LinearTransform2D, SimilarityTransform,
                     TranslationTransform)

__all__ = ['TRANSFORM_TYPES', 'LINEAR_TYPES', 'transform_class']

#: The ``transform_type`` names accepted by `~astroalign_nd.find_transform`.
TRANSFORM_TYPES = {
    "translation": TranslationTransform,
    "euclidean": EuclideanTransform,
    "similarity": SimilarityTransform,
    "affine": AffineTransform,
    "projective": ProjectiveTransform,
    "polynomial": PolynomialTransform,
}

#: The linear ones among `TRANSFORM_TYPES` (subclasses of `LinearTransform2D`).
LINEAR_TYPES = ("translation", "euclidean", "similarity", "affine")


def transform_class(transform_type: str | type) -> type[Model]:
    """
    Return the model class for a ``transform_type`` name or class.

    Parameters
    ----------
    transform_type : str or type
        One of ``'translation'``, ``'euclidean'``, ``'similarity'``,
        ``'affine'``, ``'projective'``, ``'polynomial'``, or one of the
        classes themselves.

    Returns
    -------
    cls : type
        A subclass of `LinearTransform2D`, or `ProjectiveTransform` or
        `PolynomialTransform`.

    Raises
    ------
    ValueError
        For any other name or class.

    Examples
    --------
    >>> from astroalign_nd.transforms import transform_class, AffineTransform
    >>> transform_class("Similarity").__name__
    'SimilarityTransform'
    >>> transform_class(AffineTransform) is AffineTransform
    True
    """
    if isinstance(transform_type, type) and issubclass(
            transform_type, (LinearTransform2D, ProjectiveTransform, PolynomialTransform)):
        return transform_type
    if isinstance(transform_type, str) and transform_type.lower() in TRANSFORM_TYPES:
        return TRANSFORM_TYPES[transform_type.lower()]
    raise ValueError(
        f"transform_type must be one of {sorted(TRANSFORM_TYPES)} (or one of their "
        f"classes); got {transform_type!r}."
    )
