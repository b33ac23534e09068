# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
astroalign_nd: register astronomical images by matching star triangles,
natively in astropy (NDData/CCDData in, CCDData out, transforms as astropy
models).

The pipeline, one module per stage: `~astroalign_nd.detection` (sources)
-> `~astroalign_nd.asterisms` (triangles) -> `~astroalign_nd.matching`
(match, verify, refine) -> `~astroalign_nd.transforms` (models) ->
`~astroalign_nd.resample` (pixels) -> `~astroalign_nd.ccddata` (CCDData).
"""

try:
    from ._version import version as __version__
except ImportError:  # running from a source tree that was never built
    __version__ = "0.0.0"

from .exceptions import (AstroalignError, AstroalignWarning, PoorFitWarning,
                         TooFewSourcesError, TransformNotFoundError)
from .detection import find_sources
from .transforms import (AffineTransform, EuclideanTransform, LinearTransform2D,
                         SimilarityTransform, TranslationTransform)
from .registration import Reference, find_match, find_transform, register
from .ccddata import apply_transform
from .batch import register_batch
from .io import transform_from_header, transform_to_header

__all__ = [
    "__version__",
    "AstroalignError", "AstroalignWarning", "PoorFitWarning", "TooFewSourcesError",
    "TransformNotFoundError",
    "find_sources", "find_transform", "find_match", "register", "apply_transform", "Reference", "register_batch",
    "LinearTransform2D", "TranslationTransform", "EuclideanTransform", "SimilarityTransform",
    "AffineTransform",
    "transform_to_header", "transform_from_header",
]
