# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
astroalign_nd: register astronomical images by matching star triangles,
natively in astropy (NDData/CCDData in, CCDData out, transforms as astropy
models).

The pipeline, one subpackage per stage: `~astroalign_nd.detection` (sources)
-> `~astroalign_nd.matching` (triangles; match, verify, refine) ->
`~astroalign_nd.transforms` (models, fits, model selection) ->
`~astroalign_nd.resample` (pixels, and CCDData in and out).
`~astroalign_nd.registration` strings them together; `~astroalign_nd.io`
reads and writes, `~astroalign_nd.batch` runs many frames,
`~astroalign_nd.sequence` solves them together and
`~astroalign_nd.stacking` stacks them.

Code written for astroalign 2.6 runs on this package's engine with
``from astroalign_nd import compat as aa`` (`astroalign_nd.compat`).

Public names are imported on first use (``astroalign_nd._lazy``), so that
``import astroalign_nd`` (and the command line's ``--help``) stays fast.
"""

try:
    from ._version import version as __version__
except ImportError:  # running from a source tree that was never built
    __version__ = "0.0.0"

from .exceptions import (AstroalignError, AstroalignWarning, PoorCoverageError, PoorFitWarning,
                         SlowKernelsWarning, TooFewSourcesError, TransformNotFoundError)
from ._lazy import attach

# submodule (relative, as in an import) -> the public names it defines
_LAZY = {
    ".detection": ["find_sources"],
    ".registration": ["find_transform", "find_match", "register", "Reference"],
    ".crossmatch": ["cross_match"],
    ".resample": ["apply_transform"],
    ".batch": ["register_batch"],
    ".stacking": ["stack", "frame_quality"],
    ".sequence": ["solve_sequence"],
    ".transforms": ["LinearTransform2D", "TranslationTransform", "EuclideanTransform",
                    "SimilarityTransform", "AffineTransform", "ProjectiveTransform",
                    "PolynomialTransform"],
    ".io": ["transform_to_header", "transform_from_header"],
    "._settings": ["conf"],
    # True when the optional compiled kernels are built (False: their NumPy versions run).
    "._kernels": ["HAVE_COMPILED"],
}

__getattr__, __dir__, _lazy_names = attach(__name__, _LAZY, submodules=("compat", "visualization"))

__all__ = [
    "__version__",
    "AstroalignError", "AstroalignWarning", "PoorFitWarning", "TooFewSourcesError",
    "TransformNotFoundError", "PoorCoverageError", "SlowKernelsWarning",
    *_lazy_names,
]
del attach, _lazy_names
