# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The segmentation finder: astroalign's detection criterion, with photutils.

Sources are groups of connected pixels above a threshold in noise units,
after a background map is subtracted, as astroalign documents its
``detection_sigma`` and ``min_area`` (astroalign uses sep; this finder uses
`photutils.segmentation`).  It is the second detector of
`~astroalign_nd.compat`, tried where the DAOStarFinder pipeline finds no
trusted match (a matched filter can be misled where the noise is
correlated: smoothed or compressed images), and a finder for
`~astroalign_nd.detection.find_sources` (``finder=``).
"""

import numbers
import warnings

import numpy as np
from astropy.table import Table
from astropy.utils.exceptions import AstropyWarning

from .base import SourceFinderBase, _empty_sources

__all__ = ["SegmentationFinder"]


class SegmentationFinder(SourceFinderBase):
    """
    Sources as groups of connected pixels above a threshold (segmentation).

    A background map (boxes of ``box_size`` pixels) is subtracted; sources
    are groups of at least ``min_area`` connected pixels above ``nsigma``
    times the background's standard deviation (the median of its map);
    positions are the segments' centroids, fluxes their background-
    subtracted sums (`photutils.segmentation.SourceCatalog`).

    Parameters
    ----------
    nsigma : float, optional
        Detection threshold in units of the background noise (default 5,
        astroalign's ``detection_sigma``).
    min_area : int, optional
        Minimum number of connected pixels of a source (default 5,
        astroalign's ``min_area``).
    box_size : int, optional
        Box of the background map, pixels.  By default 64, or half the
        image's smaller side where that is less (at least 8).

    Notes
    -----
    The output table has the columns ``x``, ``y`` and ``flux``, brightest
    first; its ``meta`` holds ``noise`` (the background's standard
    deviation) and ``nsigma``.  It finds hot pixels and cosmic rays of
    ``min_area`` pixels or more as sources (the DAOStarFinder pipeline of
    `~astroalign_nd.detection.find_sources` rejects them by their shape).

    Examples
    --------
    The stars of a simulated frame, each within a fraction of a pixel of a
    true star:

    >>> import numpy as np
    >>> from scipy.spatial import cKDTree
    >>> from astroalign_nd.detection import SegmentationFinder
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> sources = SegmentationFinder(nsigma=5.0)(pair.source)
    >>> sources.colnames
    ['x', 'y', 'flux']
    >>> truth = np.column_stack([pair.source_stars["x"], pair.source_stars["y"]])
    >>> dist, _ = cKDTree(truth).query(np.column_stack([sources["x"], sources["y"]])[:30])
    >>> bool(np.median(dist) < 0.2)
    True
    """

    def __init__(self, nsigma=5.0, min_area=5, box_size=None):
        if isinstance(nsigma, (bool, np.bool_)) or not isinstance(nsigma, numbers.Real) \
                or not (np.isfinite(nsigma) and nsigma > 0):
            raise ValueError(f"nsigma must be a positive number; got {nsigma!r}.")
        self.nsigma = nsigma
        self.min_area = _positive_int(min_area, "min_area")
        self.box_size = None if box_size is None else _positive_int(box_size, "box_size")

    def find_stars(self, data, mask=None):
        """
        The segments of a checked image (see `SourceFinderBase.find_stars`).

        Parameters
        ----------
        data : 2-D float ndarray
        mask : 2-D bool ndarray or None

        Returns
        -------
        sources : `~astropy.table.Table`
            ``x``, ``y``, ``flux``, brightest (largest segment flux) first.
        """
        data = np.array(data, dtype=float)
        bad = ~np.isfinite(data)
        if mask is not None:
            bad |= np.asarray(mask, dtype=bool)
        if bad.all():
            return _empty_sources()
        data[bad] = np.median(data[~bad])
        box = self.box_size or int(max(8, min(64, min(data.shape) // 2)))
        from photutils.background import Background2D
        from photutils.segmentation import SourceCatalog, detect_sources

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", AstropyWarning)
            try:
                bkg = Background2D(data, box, mask=bad if bad.any() else None)
            except ValueError:  # too few unmasked pixels per box
                return _empty_sources()
            sub = data - bkg.background
            rms = float(bkg.background_rms_median)
            if not np.isfinite(rms) or rms <= 0:
                return _empty_sources()
            segm = detect_sources(sub, self.nsigma * rms, n_pixels=self.min_area,
                                  mask=bad if bad.any() else None)
            if segm is None:
                return _empty_sources()
            cat = SourceCatalog(sub, segm, mask=bad if bad.any() else None)
            x, y = np.asarray(cat.x_centroid, float), np.asarray(cat.y_centroid, float)
            flux = np.asarray(cat.segment_flux, float)
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(flux)
        order = np.argsort(-flux[ok], kind="stable")
        out = Table({"x": x[ok][order], "y": y[ok][order], "flux": flux[ok][order]})
        out.meta.update(noise=rms, nsigma=float(self.nsigma))
        return out


def _positive_int(value, name):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) \
            or value < 1:
        raise ValueError(f"{name} must be a positive integer; got {value!r}.")
    return int(value)
