# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Conversions between the models, 3x3 matrices, scikit-image and astropy.modeling."""

from __future__ import annotations

from typing import Any
import numpy as np
from astropy.modeling import Model
from .polynomial import PolynomialTransform
from .projective import ProjectiveTransform
from .linear import (AffineTransform, EuclideanTransform, LinearTransform2D, SimilarityTransform,
                     TranslationTransform)
from ._matrix import apply_matrix
from .registry import transform_class

__all__ = ['as_matrix', 'from_matrix', 'to_skimage', 'from_skimage', 'to_astropy_affine',
           'from_astropy_affine']

# -- interoperability ----------------------------------------------------------


def as_matrix(transform: Any) -> np.ndarray:
    """
    The 3x3 homogeneous matrix of any supported transform.

    Accepts the package's models, a 3x3 or 2x3 array, a scikit-image
    geometric transform (anything with a ``params`` matrix) or an astropy
    `~astropy.modeling.projections.AffineTransformation2D`.

    Examples
    --------
    >>> from astropy.modeling.models import Shift
    >>> from astroalign_nd.transforms import SimilarityTransform, as_matrix
    >>> as_matrix(SimilarityTransform(scale=2.0, translation_x=5.0)).round(12)
    array([[2., 0., 5.],
           [0., 2., 0.],
           [0., 0., 1.]])
    >>> as_matrix(Shift(1.0) & Shift(-2.0))  # any affine astropy model
    array([[ 1.,  0.,  1.],
           [ 0.,  1., -2.],
           [ 0.,  0.,  1.]])
    """
    from astropy.modeling.projections import AffineTransformation2D

    if isinstance(transform, LinearTransform2D):
        return transform.matrix
    if isinstance(transform, AffineTransformation2D):
        m = np.eye(3)
        m[:2, :2] = transform.matrix.value
        m[:2, 2] = transform.translation.value
        return m
    if isinstance(transform, Model):
        if transform.n_inputs == 2 and transform.n_outputs == 2:
            # Any other linear 2-D model: probe it on three points and check linearity.
            pts = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1000.0, 1000.0]])
            xo, yo = transform(pts[:, 0], pts[:, 1])
            xo, yo = np.asarray(xo, float), np.asarray(yo, float)
            m = np.eye(3)
            m[:2, 2] = [xo[0], yo[0]]
            m[:2, :2] = [[xo[1] - xo[0], xo[2] - xo[0]], [yo[1] - yo[0], yo[2] - yo[0]]]
            pred = apply_matrix(m, pts[3:4])[0]
            if np.allclose(pred, [xo[3], yo[3]], rtol=1e-9, atol=1e-6):
                return m
            raise ValueError(f"{type(transform).__name__} is not an affine transform.")
        raise TypeError("an astropy model used as a transform must have 2 inputs and 2 outputs.")
    if (isinstance(transform, tuple) and len(transform) == 2
            and isinstance(transform[0], (Model, np.ndarray))):
        raise TypeError(
            "got a (transform, (source_points, target_points)) tuple, as find_transform "
            "returns; pass its first element: transform, _ = find_transform(...)."
        )
    params = getattr(transform, "params", transform)
    try:
        m = np.asarray(params, dtype=float)
    except (TypeError, ValueError):
        m = None
    if m is not None and m.shape == (2, 3):
        m = np.vstack([m, [0.0, 0.0, 1.0]])
    if m is None or m.shape != (3, 3):
        raise TypeError(
            "transform must be an astroalign_nd transform, an astropy model, a scikit-image "
            f"geometric transform or a 3x3 matrix; got {type(transform).__name__}."
        )
    return m


def from_matrix(matrix: Any, transform_type: str | type | None = None) -> LinearTransform2D:
    """
    Build a package transform from a 3x3 (or 2x3) matrix.

    With ``transform_type=None`` the simplest class that represents the
    matrix exactly is chosen (translation, then euclidean, similarity, affine);
    a projective matrix (last row not ``[0, 0, 1]``) needs
    ``transform_type='projective'``.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import from_matrix
    >>> t = from_matrix([[1.0, 0.0, 3.0], [0.0, 1.0, 4.0], [0.0, 0.0, 1.0]])
    >>> type(t).__name__, t.translation.tolist()
    ('TranslationTransform', [3.0, 4.0])
    >>> s = from_matrix(np.array([[0.0, -2.0, 0.0], [2.0, 0.0, 0.0]]))  # 2x3 is fine
    >>> type(s).__name__, round(float(s.scale.value), 12), round(s.rotation_deg, 12)
    ('SimilarityTransform', 2.0, 90.0)
    >>> type(from_matrix(np.eye(3), "affine")).__name__
    'AffineTransform'
    """
    if transform_type is not None:
        cls = transform_class(transform_type)
        if cls is PolynomialTransform:
            raise ValueError(
                "a matrix does not define a PolynomialTransform (its distortion terms); build "
                "one with PolynomialTransform(...) or PolynomialTransform.from_points.")
        if isinstance(matrix, ProjectiveTransform):
            return cls.from_matrix(matrix.matrix)  # as_matrix refuses non-affine models
        return cls.from_matrix(as_matrix(matrix))
    m = as_matrix(matrix)
    for cls in (TranslationTransform, EuclideanTransform, SimilarityTransform):
        try:
            return cls.from_matrix(m)
        except ValueError:
            continue
    return AffineTransform.from_matrix(m)


def to_skimage(transform: Any) -> Any:
    """
    Convert to the matching `skimage.transform` geometric transform.

    A mirrored transform becomes a `skimage.transform.AffineTransform`
    (scikit-image's similarity and euclidean classes cannot hold a
    reflection).  scikit-image angles are in radians.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import SimilarityTransform, to_skimage
    >>> t = SimilarityTransform(scale=1.5, rotation=90.0, translation_x=2.0)
    >>> sk = to_skimage(t)
    >>> type(sk).__name__, bool(np.isclose(sk.rotation, np.pi / 2))
    ('SimilarityTransform', True)
    >>> bool(np.allclose(sk([[1.0, 0.0]]), np.column_stack(t(1.0, 0.0))))
    True
    """
    from skimage import transform as sktf

    m = as_matrix(transform)
    if isinstance(transform, (TranslationTransform, EuclideanTransform)) and not transform.mirrored:
        return sktf.EuclideanTransform(matrix=m)
    if isinstance(transform, SimilarityTransform) and not transform.mirrored:
        return sktf.SimilarityTransform(matrix=m)
    # skimage's similarity/euclidean classes cannot hold a reflection.
    return sktf.AffineTransform(matrix=m)


def from_skimage(sk_transform: Any,
                 transform_type: str | type | None = None) -> LinearTransform2D:
    """
    Convert a scikit-image geometric transform (anything with ``params``).

    ``transform_type`` is as in `from_matrix` (default: the simplest class
    that represents the matrix).

    Examples
    --------
    >>> import numpy as np
    >>> from skimage.transform import EuclideanTransform as SkEuclidean
    >>> from astroalign_nd.transforms import from_skimage
    >>> t = from_skimage(SkEuclidean(rotation=np.pi / 6, translation=(1.0, 2.0)))
    >>> type(t).__name__, round(t.rotation_deg, 9)
    ('EuclideanTransform', 30.0)
    """
    return from_matrix(np.asarray(sk_transform.params, dtype=float), transform_type)


def to_astropy_affine(transform: Any) -> Model:
    """
    Convert to `astropy.modeling.projections.AffineTransformation2D`.

    Examples
    --------
    >>> from astroalign_nd.transforms import TranslationTransform, to_astropy_affine
    >>> a = to_astropy_affine(TranslationTransform(translation_x=2.0, translation_y=3.0))
    >>> type(a).__name__, a(1.0, 1.0)
    ('AffineTransformation2D', (3.0, 4.0))
    """
    from astropy.modeling.projections import AffineTransformation2D

    m = as_matrix(transform)
    return AffineTransformation2D(matrix=m[:2, :2], translation=m[:2, 2])


def from_astropy_affine(model: Model,
                        transform_type: str | type | None = None) -> LinearTransform2D:
    """
    Convert an `~astropy.modeling.projections.AffineTransformation2D`.

    ``transform_type`` is as in `from_matrix` (default: the simplest class
    that represents the matrix).

    Examples
    --------
    >>> from astropy.modeling.projections import AffineTransformation2D
    >>> from astroalign_nd.transforms import from_astropy_affine
    >>> a = AffineTransformation2D(matrix=[[2.0, 0.0], [0.0, 2.0]], translation=[1.0, 0.0])
    >>> t = from_astropy_affine(a)
    >>> type(t).__name__, float(t.scale.value)
    ('SimilarityTransform', 2.0)
    """
    return from_matrix(as_matrix(model), transform_type)
