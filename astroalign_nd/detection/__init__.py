# Licensed under a 3-clause BSD style license - see LICENSE.rst

"""Stage 1 of the method: find the brightest point sources of an image.

Only the ~50 brightest stars are needed as control points, so full-frame
work is avoided (it dominates the cost of a naive DAOStarFinder run on a
4k frame):

1. noise is measured on a subsample of pixel differences (robust to
   background gradients and to stars);
2. the image is binned (~300 px across), each block dropping its brightest
   pixel, which removes hot pixels and most cosmic-ray hits; after a
   coarse block-median sky is subtracted, a compiled local-maximum search
   finds candidate peaks, ranked by flux (the only full-frame passes);
   a row or column that stands out from the lines next to it (the
   decaying band along a raw frame's first rows, a bad column) has its
   excess subtracted and its candidates judged against its own noise
   (``detection.lines``), so that its noise peaks are not
   stars;
3. full-resolution cutouts around the candidates are tiled into one
   mosaic, and `~photutils.detection.DAOStarFinder` measures every
   candidate there (given their positions) with the full-resolution FWHM
   and its sharpness and roundness limits, after single-pixel spikes (hot
   pixels, cosmic-ray hits beside a star) are replaced by their
   neighbours; sources whose shape is unlike
   the population's (hot pixels, cosmic-ray tracks) or whose
   matched-filter signal-to-noise (against the noise a sum of pixels
   really has: resampled frames' noise is correlated) is below the
   threshold are dropped;
4. centroids are refined with an iterative Gaussian-windowed centroid
   (the estimator of SExtractor's ``XWIN_IMAGE``), vectorised over all
   stars, which is more precise than DAOFIND's marginal fits.

Stars wider than ~10 px (defocused frames, digitised plates) are measured
on a binned copy instead, where they are well sampled and cheap.

Other detectors are finders: subclasses of `SourceFinderBase` (the
interface of photutils' ``StarFinderBase``: configured once, called as
``finder(data, mask=None)``, returning a table of ``x``, ``y``, ``flux``).
`DAOSourceFinder` is the pipeline above as a finder;
`SegmentationFinder` is astroalign's criterion (connected pixels above a
threshold).  ``find_sources(image, finder=...)`` runs any of them, and so
do `~astroalign_nd.registration.find_transform`, ``register``,
``Reference`` and ``register_batch`` (``finder=``).  A new detector is one
module: a subclass that implements `SourceFinderBase.find_stars`.

Names are imported on first use (``astroalign_nd._lazy``): reading the
options class (`DetectionConfig`) does not import the stage.
"""

from .._lazy import attach

# submodule (relative, as in an import) -> the public names it defines
_LAZY = {
    ".daofind": ["find_sources", "DAOSourceFinder"],
    ".background": ["estimate_noise"],
    ".fwhm": ["estimate_fwhm"],
    ".base": ["SourceFinderBase"],
    ".segmentation": ["SegmentationFinder"],
    ".options": ["DetectionConfig"],
}

__getattr__, __dir__, __all__ = attach(__name__, _LAZY)
del attach
