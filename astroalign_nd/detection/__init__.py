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
3. full-resolution cutouts around the candidates are tiled into one
   mosaic, and `~photutils.detection.DAOStarFinder` measures every
   candidate there (given their positions) with the full-resolution FWHM
   and its sharpness and roundness limits; sources whose shape is unlike
   the population's (hot pixels, cosmic-ray tracks) or whose
   matched-filter signal-to-noise is below the threshold are dropped;
4. centroids are refined with an iterative Gaussian-windowed centroid
   (the estimator of SExtractor's ``XWIN_IMAGE``), vectorised over all
   stars, which is more precise than DAOFIND's marginal fits.

Stars wider than ~10 px (defocused frames, digitised plates) are measured
on a binned copy instead, where they are well sampled and cheap.
"""

from .daofind import find_sources
from .background import estimate_noise
from .fwhm import estimate_fwhm

__all__ = ['find_sources', 'estimate_noise', 'estimate_fwhm']
