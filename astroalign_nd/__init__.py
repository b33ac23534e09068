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

# name -> submodule that defines it
_LAZY = {
    "find_sources": "detection",
    "find_transform": "registration",
    "find_match": "registration",
    "register": "registration",
    "cross_match": "crossmatch",
    "Reference": "registration",
    "apply_transform": "resample",
    "register_batch": "batch",
    "stack": "stacking",
    "frame_quality": "stacking",
    "solve_sequence": "sequence",
    "LinearTransform2D": "transforms",
    "TranslationTransform": "transforms",
    "EuclideanTransform": "transforms",
    "SimilarityTransform": "transforms",
    "AffineTransform": "transforms",
    "ProjectiveTransform": "transforms",
    "PolynomialTransform": "transforms",
    "transform_to_header": "io",
    "transform_from_header": "io",
    "conf": "_settings",
    # True when the optional compiled kernels are built (False: their NumPy versions run).
    "HAVE_COMPILED": "_kernels",
}

__all__ = [
    "__version__",
    "AstroalignError", "AstroalignWarning", "PoorFitWarning", "TooFewSourcesError",
    "TransformNotFoundError", "PoorCoverageError", "SlowKernelsWarning",
    *_LAZY,
]


# Submodules reachable as attributes without an explicit import, imported on first use
# (matplotlib stays optional: visualization imports it only when a plot is drawn).
_SUBMODULES = ("compat", "visualization")

__getattr__, __dir__ = attach(__name__, _LAZY, _SUBMODULES)
del attach
