# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
How stars are found: `DetectionConfig`, the options of
`~astroalign_nd.find_sources` (each default, range, message and flag once,
in the package's checking system, ``astroalign_nd.options``).
"""

import dataclasses

import numpy as np

from ..options import AnyCallable, Bool, Int, Pair, Real, check_fields, option

__all__ = ["DetectionConfig"]


@dataclasses.dataclass(frozen=True)
class DetectionConfig:
    """
    How stars are found (the options of `~astroalign_nd.find_sources`).

    Parameters
    ----------
    fwhm : float, optional
        Stellar FWHM in pixels; estimated from each image when None.
    nsigma : float, optional
        Detection threshold in noise units; None: registration's adaptive
        threshold (a deep pass, of which the sources above 5 sigma are kept
        when there are enough); `~astroalign_nd.find_sources` alone uses 5.
    peak_max : float, optional
        Sources whose peak is above this are dropped (saturated stars).
    sharpness_range, roundness_range : (float, float) or None, optional
        DAOStarFinder's limits.
    bin_factor : int, optional
        Binning of the candidate pass; by default about 320 binned pixels
        across.
    refine_centroids : bool, optional
        Refine the centroids with a Gaussian-windowed centroid.
    finder : `~astroalign_nd.detection.SourceFinderBase` or callable, optional
        Another detector instead of the DAOStarFinder pipeline (see
        `~astroalign_nd.find_sources`).

    Raises
    ------
    TypeError, ValueError
        For a value out of its range: the message names the option and the
        accepted values.

    Examples
    --------
    >>> from astroalign_nd.detection import DetectionConfig
    >>> DetectionConfig(fwhm=3).fwhm
    3.0
    >>> DetectionConfig(fwhm=-1)
    Traceback (most recent call last):
    ...
    ValueError: fwhm must be a finite number > 0 and <= 10000 (pixels) or None; got -1.
    """

    fwhm: float | None = option(
        None, Real(0, 1e4, lo_open=True, none=True, unit="pixels"),
        "stellar FWHM in pixels (give it when the estimate fails, e.g. on nebulosity)",
        flag="--fwhm", type=float, metavar="PX")
    nsigma: float | None = option(
        None, Real(0, 1e6, lo_open=True, none=True),
        "detection threshold in background standard deviations",
        flag="--nsigma", type=float, metavar="K")
    peak_max: float | None = option(
        None, Real(none=True),
        "ignore sources whose peak exceeds this value (saturated stars)",
        flag="--peak-max", type=float, metavar="ADU")
    # Sharpness has no lower limit by default (saturated stars): -inf is allowed.
    sharpness_range: tuple | None = option(
        (-np.inf, 1.0), Pair(Real(infinite=True), none=True),
        "accepted DAOFIND sharpness range",
        flag="--sharpness-range", type=float, nargs=2, metavar=("LO", "HI"), cli_default=None)
    roundness_range: tuple | None = option(
        (-1.0, 1.0), Pair(Real(infinite=True), none=True),
        "accepted DAOFIND roundness range",
        flag="--roundness-range", type=float, nargs=2, metavar=("LO", "HI"), cli_default=None)
    bin_factor: int | None = option(
        None, Int(1, 1024, none=True),
        "detect on the image binned BxB (for large, oversampled frames)",
        flag="--bin-factor", type=int, metavar="B")
    refine_centroids: bool = option(True, Bool(), "refine the centroids")
    # Another detector instead of the DAOStarFinder pipeline (the API's; no command-line flag).
    finder: object = option(None, AnyCallable(), "another source finder")

    def __post_init__(self):
        check_fields(self)
