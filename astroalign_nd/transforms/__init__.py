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
``selection`` chooses among them (model selection) for the matching's
`~astroalign_nd.matching.fit_nonlinear` and `~astroalign_nd.matching.extend_match`.
Each type's parameters, design matrix and matrix conversions are its
parameter layer (``layers``; the model class's ``layer``), which every
solver of the package fits.

This subpackage imports no other stage (detection, matching, resample,
batch, stacking, io, the command line): they build on it.

The types by name are the entries of `TRANSFORM_REGISTRY`
(`register_transform_type` adds one); every list of names derives from it.

The modules, bottom up: ``_matrix`` (matrix and point helpers, a leaf),
``layers`` (the parameter layer's base), ``linear``, ``projective`` and
``polynomial`` (the models and their layers), ``registry``
(the types by name), ``fitting`` and ``convert``, and ``selection``
(model selection for distortion).  Names are imported on first use
(``astroalign_nd._lazy``), so that reading the registry's names
(``astroalign-nd --help``) stays cheap.
"""

from .._lazy import attach

# submodule (relative, as in an import) -> the public names it defines
_LAZY = {
    ".linear": ["LinearTransform2D", "TranslationTransform", "EuclideanTransform",
                "SimilarityTransform", "AffineTransform"],
    ".projective": ["ProjectiveTransform"],
    ".polynomial": ["PolynomialTransform"],
    ".registry": ["TransformType", "HeaderHooks", "TRANSFORM_REGISTRY", "TRANSFORM_TYPES",
                  "LINEAR_TYPES", "NONLINEAR_TYPES", "register_transform_type",
                  "unregister_transform_type", "transform_class", "transform_type_of",
                  "check_degree"],
    ".options": ["ModelConfig"],
    ".fitting": ["fit_transform", "checked_weights"],
    ".convert": ["as_matrix", "from_matrix", "to_skimage", "from_skimage", "to_astropy_affine",
                 "from_astropy_affine"],
    "._matrix": ["apply_matrix"],
    ".selection": ["DistortionFit"],
    ".layers": ["ParameterLayer"],
}

__getattr__, __dir__, __all__ = attach(__name__, _LAZY)
del attach
