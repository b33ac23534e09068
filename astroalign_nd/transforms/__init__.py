# Licensed under a 3-clause BSD style license - see LICENSE.rst

"""Geometric transforms between the pixel grids of two images.

Every transform is an `astropy.modeling.Model` with two inputs and two
outputs, ``(x, y) -> (x', y')``, mapping *source* pixel coordinates to
*target* pixel coordinates (0-based, ``x`` along columns, as photutils and
astropy use them).  They compose with any other astropy model
(``Shift(1) & Shift(2) | SimilarityTransform(...)``), have an analytic
``inverse``, and expose the attributes that scikit-image and astroalign
users know: ``params`` / ``matrix`` (3x3 homogeneous matrix), ``scale``,
``rotation`` and ``translation``.

Angles are in degrees, counter-clockwise, as in astropy's
`~astropy.modeling.rotations.Rotation2D`; an angle can also be given as a
`~astropy.units.Quantity` (``rotation=0.3 * u.rad``), which is converted to
degrees.  (scikit-image's transforms use radians: `to_skimage` and
`from_skimage` convert through the matrix.)

Mirrored (reflected) transforms are represented, not rejected: the
rotation-like models carry a fixed ``parity`` parameter, +1 for a proper
transform and -1 for one that includes a reflection of the y axis *before*
the rotation.  Any other value of ``parity`` is refused.

To refit a transform on matched positions of your own (astropy's fitters
do not fit models with two outputs), use ``from_points`` with optional
weights, or `fit_transform` for the parameter covariance too.

The non-linear models, `ProjectiveTransform` (a homography) and
`PolynomialTransform` (SIP-style distortion), live beside the linear ones;
`fit_nonlinear` and `extend_match` choose among them (model selection).

The modules, bottom up: ``_matrix`` (matrix and point helpers, a leaf),
``linear``, ``projective`` and ``polynomial`` (the models), ``registry``
(the types by name), ``fitting`` and ``convert``, and ``selection``
(model selection for distortion).
"""

from .linear import (LinearTransform2D, TranslationTransform, EuclideanTransform,
                     SimilarityTransform, AffineTransform)
from .projective import ProjectiveTransform
from .polynomial import PolynomialTransform
from .registry import TRANSFORM_TYPES, LINEAR_TYPES, transform_class
from .fitting import fit_transform
from .convert import (as_matrix, from_matrix, to_skimage, from_skimage, to_astropy_affine,
                      from_astropy_affine)
from .selection import NONLINEAR_TYPES, check_degree, fit_nonlinear, extend_match, DistortionFit

__all__ = [
    'LinearTransform2D',
    'TranslationTransform',
    'EuclideanTransform',
    'SimilarityTransform',
    'AffineTransform',
    'ProjectiveTransform',
    'PolynomialTransform',
    'TRANSFORM_TYPES',
    'LINEAR_TYPES',
    'transform_class',
    'fit_transform',
    'as_matrix',
    'from_matrix',
    'to_skimage',
    'from_skimage',
    'to_astropy_affine',
    'from_astropy_affine',
    'NONLINEAR_TYPES',
    'check_degree',
    'fit_nonlinear',
    'extend_match',
    'DistortionFit',
]
