# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The options of a registration, each with its default, range and message once.

The stages' options are frozen dataclasses: `DetectionConfig` (how stars
are found), `MatchingConfig` (how the triangles are matched and the match
verified), `ModelConfig` (the transform fitted), `ResampleConfig` (how the
source's pixels are resampled); `RegistrationConfig` holds the first three
and the numbers of control points.  Each field holds, as its metadata, its
accepted values and its help text: constructing a config checks every
value (``__post_init__``) and normalises it (``float``/``int``/``tuple``), so
that a bad value gives one message naming the option and its range before
any work is done.  The command line's options and help are generated from
the same fields (``astroalign_nd.options.cli_fields``).  `OPTIONS` is a view of the
checks, by option name.

`~astroalign_nd.find_transform`, `~astroalign_nd.register`,
`~astroalign_nd.register_batch`, `~astroalign_nd.Reference` and
`~astroalign_nd.find_sources` take the options as keywords, as before, and
build these configs once; the stages trust them.

Runtime settings (threads, compiled code) are ``astroalign_nd.conf``'s.
"""

import dataclasses
import numbers

import numpy as np

from .options import (AnyCallable, Bool, Int, Pair, Real, Unchecked, check_fields, convert,
                      option)

# The transform registry is imported where a model option is checked, not here: every
# stage reads this module (detection too), and the transforms are a later stage.


# The resampler's interpolation orders and methods, the one table of them.
ORDERS = {"nearest-neighbor": 0, "bilinear": 1, "biquadratic": 2, "bicubic": 3}
METHODS = ("interpolate", "exact")


def order_index(order):
    """
    The interpolation order as an integer 0-3.

    Parameters
    ----------
    order : str or int
        One of the names in `ORDERS` or an integer from 0 to 3.

    Raises
    ------
    ValueError
        For any other value, naming the accepted ones.
    """
    if isinstance(order, str):
        if order in ORDERS:
            return ORDERS[order]
        if order.strip() in ("0", "1", "2", "3"):  # as the command line gives it
            return int(order)
    elif isinstance(order, numbers.Integral) and not isinstance(order, bool):
        if 0 <= int(order) <= 3:
            return int(order)
    raise ValueError(f"order must be one of {list(ORDERS)} or an integer 0-3; got {order!r}.")


def check_method(method):
    """Raise ValueError unless ``method`` is one of `METHODS`."""
    if method not in METHODS:
        raise ValueError(f"method must be 'interpolate' or 'exact'; got {method!r}.")


__all__ = ["DetectionConfig", "MatchingConfig", "ModelConfig", "ResampleConfig",
           "RegistrationConfig", "OPTIONS", "check_option", "split_options",
           "astroalign_advice", "DEFAULT_TOLERANCE", "DEFAULT_NEIGHBORS"]

#: `~astroalign_nd.matching.match_points`' matching radius (pixels); a
#: registration's search widens it for wide stars (`MatchingConfig`'s ``tolerance``).
DEFAULT_TOLERANCE = 3.0

#: Neighbours per star of `~astroalign_nd.matching.match_points`' triangles;
#: a registration tries 6 and 8 for sparse lists (`MatchingConfig`'s ``n_neighbors``).
DEFAULT_NEIGHBORS = 4


# -- the stages' options ----------------------------------------------------------------------


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
    >>> from astroalign_nd.config import DetectionConfig
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


@dataclasses.dataclass(frozen=True)
class MatchingConfig:
    """
    How the triangles are matched and a match verified (the settings of
    `~astroalign_nd.matching.match_points`).

    Parameters
    ----------
    tolerance : float, optional
        Matching radius (target pixels) while searching.  None: a
        registration's search uses the larger of `DEFAULT_TOLERANCE` and
        half the target stars' FWHM.
    min_tolerance : float, optional
        Smallest radius the refinement may shrink to.
    invariant_radius : float, optional
        Radius of triangle matches in (log) invariant space.
    n_neighbors : int, optional
        Neighbours per star of the triangles.  None: `DEFAULT_NEIGHBORS`,
        and a registration tries more for sparse star lists.
    allow_mirror : bool, optional
        Consider mirrored solutions.
    scale_range : (float, float), optional
        Allowed source-to-target scale.
    max_false_alarm : float, optional
        Largest accepted probability that the match is chance.
    accept_matches : int, optional
        Early acceptance once a hypothesis has this many matched stars.
    batch_size, max_hypotheses : int, optional
        Hypotheses scored per batch, and at most in total.

    Examples
    --------
    >>> from astroalign_nd.config import MatchingConfig
    >>> cfg = MatchingConfig(tolerance=2)
    >>> cfg.tolerance, cfg.max_false_alarm
    (2.0, 1e-06)
    >>> sorted(cfg.match_kwargs())[:3]
    ['accept_matches', 'allow_mirror', 'batch_size']
    """

    tolerance: float | None = option(
        None, Real(0, 1e6, lo_open=True, unit="pixels"), auto=True,
        help="largest distance (px) for a star to count as matched",
        flag="--tolerance", type=float, metavar="PX")
    min_tolerance: float = option(0.5, Real(0, 1e6, lo_open=True, unit="pixels"))
    invariant_radius: float = option(0.1, Real(0, 10, lo_open=True))
    n_neighbors: int | None = option(None, Int(2, 16), auto=True)
    scale_range: tuple | None = option(None, Pair(Real(0, lo_open=True)))
    max_false_alarm: float = option(
        1e-6, Real(0, 1, lo_open=True),
        "largest false-alarm probability accepted (default: {default})",
        flag="--max-false-alarm", type=float, metavar="P", cli_default=None)
    allow_mirror: bool = option(
        True, Bool(), "do not consider mirrored (flipped) solutions",
        flag="--no-mirror", action="store_false", cli_default=None)
    accept_matches: int = option(10, Int(3, None))
    batch_size: int = option(512, Int(1, 1_000_000))
    max_hypotheses: int = option(20_000, Int(1, 10_000_000))

    def __post_init__(self):
        check_fields(self)

    def match_kwargs(self):
        """
        The keywords of `~astroalign_nd.matching.match_points` (its defaults
        for the fields left to the search: ``tolerance``, ``n_neighbors``).
        """
        kwargs = dataclasses.asdict(self)
        if kwargs["tolerance"] is None:
            kwargs["tolerance"] = DEFAULT_TOLERANCE
        if kwargs["n_neighbors"] is None:
            kwargs["n_neighbors"] = DEFAULT_NEIGHBORS
        return kwargs


def _registry():
    """The transform registry (`astroalign_nd.transforms.registry`), on first use."""
    from .transforms import registry

    return registry


def _transform_type_help():
    """The help of ``--transform-type``: the registry's types when it is asked for."""
    reg = _registry()
    return (f"model fitted between the images: {', '.join(reg.LINEAR_TYPES)}, or for wide "
            f"fields with distortion {' or '.join(reg.NONLINEAR_TYPES)} (see --degree) "
            "(default: %(default)s)")


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """
    The transform fitted.

    Parameters
    ----------
    transform_type : str or type, optional
        A type of the transform registry (``astroalign_nd.transforms``).
    degree : int, 'auto' or None, optional
        Degree of a 'polynomial' model (None there means 3).

    Examples
    --------
    >>> from astroalign_nd.config import ModelConfig
    >>> ModelConfig("polynomial").degree
    3
    """

    transform_type: object = option(
        "similarity", Unchecked(), lambda: _transform_type_help(),
        flag="--transform-type", metavar="TYPE")
    degree: object = option(
        None, Unchecked(),
        "degree of the polynomial distortion model, 2 to 5, or 'auto' to let an F-test "
        "choose (linear when the images need no distortion); only with --transform-type "
        "polynomial (default: 3)",
        flag="--degree", metavar="N")

    def __post_init__(self):
        reg = _registry()
        object.__setattr__(self, "degree", reg.check_degree(self.transform_type, self.degree))
        # Not a field: derived from transform_type, checked once here.
        object.__setattr__(self, "_nonlinear", reg.is_nonlinear(self.transform_type))
        reg.transform_class(self.linear_type)  # an unknown type: a clear message, first

    @property
    def nonlinear(self):
        """True for a distortion model (grown from a linear match)."""
        return self._nonlinear

    @property
    def linear_type(self):
        """The type of the first, linear match: a distortion model grows from a similarity."""
        return "similarity" if self.nonlinear else self.transform_type


@dataclasses.dataclass(frozen=True)
class ResampleConfig:
    """
    How the source's pixels are resampled (options of `~astroalign_nd.apply_transform`).

    Examples
    --------
    >>> from astroalign_nd.config import ResampleConfig
    >>> ResampleConfig(order="bicubic").order
    'bicubic'
    >>> ResampleConfig(order="cubic")
    Traceback (most recent call last):
    ...
    ValueError: order must be one of ['nearest-neighbor', 'bilinear', 'biquadratic', \
'bicubic'] or an integer 0-3; got 'cubic'.
    """

    order: object = option(
        "bilinear", None,
        "interpolation used to resample the source: nearest-neighbor, bilinear, "
        "biquadratic or bicubic (default: %(default)s)",
        flag="--order")
    conserve_flux: bool = option(
        False, None,
        "scale the resampled values by the pixel-area change so that total flux is kept",
        flag="--conserve-flux", action="store_true")
    fill_value: float = option(
        np.nan, None,
        "value written to output pixels that have no data (outside the source's footprint, "
        "or masked); the mask marks them whatever the value. Give 0 to stack the frames "
        "with tools that do not read the mask (default: {default})",
        flag="--fill-value", type=float, metavar="VALUE", cli_default=None)
    method: str = option("interpolate", None)
    parallel: bool = option(True, None)
    add_keyword: bool = option(True, None)

    def __post_init__(self):
        # Not a field (apply_transform takes the fields as keywords): derived from order.
        object.__setattr__(self, "_order_index", order_index(self.order))
        check_method(self.method)

    @property
    def order_index(self):
        """The interpolation order as an integer 0-3."""
        return self._order_index


@dataclasses.dataclass(frozen=True)
class RegistrationConfig:
    """
    Everything a registration's search uses: detection, matching, the model
    and the numbers of control points.

    Parameters
    ----------
    n_sources : int, optional
        Brightest sources used as control points.
    max_sources : int, optional
        If no trustworthy match is found, the control points are doubled up
        to this (raised to ``n_sources`` if smaller).
    detection, matching, model : optional
        The stages' configs.

    Examples
    --------
    >>> from astroalign_nd.config import RegistrationConfig
    >>> cfg = RegistrationConfig.from_keywords(fwhm=3.5, tolerance=2)
    >>> cfg.detection.fwhm, cfg.matching.tolerance, cfg.n_sources
    (3.5, 2.0, 50)
    >>> RegistrationConfig.from_keywords(fwhmm=3)
    Traceback (most recent call last):
    ...
    TypeError: unexpected keyword argument(s) ['fwhmm']; ...
    """

    n_sources: int = option(
        50, Int(3, 1_000_000),
        "number of brightest sources used to build triangles (default: %(default)s)",
        flag="--n-sources", type=int, metavar="N")
    max_sources: int = option(
        200, Int(3, 1_000_000),
        "if no trustworthy match is found, control points are doubled up to N "
        "(default: {default})",
        flag="--max-sources", type=int, metavar="N", cli_default=None)
    detection: DetectionConfig = dataclasses.field(default_factory=DetectionConfig)
    matching: MatchingConfig = dataclasses.field(default_factory=MatchingConfig)
    model: ModelConfig = dataclasses.field(default_factory=ModelConfig)

    def __post_init__(self):
        check_fields(self)
        object.__setattr__(self, "max_sources", max(self.max_sources, self.n_sources))

    @classmethod
    def from_keywords(cls, *, transform_type="similarity", degree=None, n_sources=50,
                      max_sources=200, **options):
        """
        The config of `~astroalign_nd.find_transform`'s keyword arguments.

        Raises
        ------
        TypeError
            For a keyword that no stage accepts (with what to pass instead
            of an astroalign keyword).
        TypeError, ValueError
            For a value out of its range.
        """
        model = ModelConfig(transform_type, degree)
        counts = dict(n_sources=n_sources, max_sources=max_sources)
        det, mat = split_options(options)
        return cls(**counts, detection=DetectionConfig(**det),
                   matching=MatchingConfig(**mat), model=model)


def _names(config_class):
    return tuple(f.name for f in dataclasses.fields(config_class))


def split_options(options, *, accept=("detection", "matching"), caller=None):
    """
    ``options`` split into (detection options, matching options).

    Raises
    ------
    TypeError
        For a name that none of the ``accept``-ed stages takes; the
        message lists what they accept (``caller`` names the function).

    Examples
    --------
    >>> from astroalign_nd.config import split_options
    >>> split_options({"fwhm": 3, "tolerance": 2})
    ({'fwhm': 3}, {'tolerance': 2})
    """
    det_keys, mat_keys = _names(DetectionConfig), _names(MatchingConfig)
    known = (det_keys if "detection" in accept else ()) + (
        mat_keys if "matching" in accept else ())
    unknown = set(options) - set(known)
    if unknown:
        if caller is not None:
            accepted = f"{caller} accepts the detection options {list(det_keys)} and hdu."
        else:
            accepted = (f"detection accepts {list(det_keys)} and matching accepts "
                        f"{list(mat_keys)}.")
        raise TypeError(f"unexpected keyword argument(s) {sorted(unknown)}; {accepted}"
                        f"{astroalign_advice(unknown)}")
    return ({k: v for k, v in options.items() if k in det_keys},
            {k: v for k, v in options.items() if k in mat_keys})


#: astroalign's keywords -> what to use here (see docs/migration.rst).
_ASTROALIGN_ADVICE = {
    "max_control_points": "pass n_sources=<number of brightest stars used as control points> "
                          "(the search escalates up to max_sources)",
    "detection_sigma": "pass nsigma=<detection threshold in noise units> (adaptive if not "
                       "given)",
    "min_area": "pass nothing (no equivalent: detection rejects hot pixels and cosmic rays by "
                "their shape), or fwhm=<the stars' width in pixels> if it is misjudged",
    "propagate_mask": "pass nothing: the returned CCDData's mask always holds the source's "
                      "mask (resampled) and the pixels outside the source",
}


def astroalign_advice(unknown):
    """
    What to pass instead of the astroalign keywords among ``unknown`` ('' if none).

    Examples
    --------
    >>> from astroalign_nd.config import astroalign_advice
    >>> astroalign_advice({"detection_sigma"}).startswith(
    ...     " Instead of astroalign's detection_sigma, pass nsigma=")
    True
    >>> astroalign_advice({"fwhmm"})
    ''
    """
    advice = "".join(f" Instead of astroalign's {k}, {_ASTROALIGN_ADVICE[k]}."
                     for k in sorted(unknown) if k in _ASTROALIGN_ADVICE)
    if advice:
        advice += (" Or keep astroalign's API and return values with "
                   "'from astroalign_nd import compat as aa'.")
    return advice


# -- views -------------------------------------------------------------------------------------


def _checks():
    table = {}
    for cls in (MatchingConfig, DetectionConfig, RegistrationConfig):
        for f in dataclasses.fields(cls):
            check = f.metadata.get("check")
            if check is not None and not isinstance(check, Unchecked):
                table[f.name] = check
    return table


#: Every checked option and how it is checked (a view of the configs' fields).
OPTIONS = _checks()


def check_option(name, value):
    """
    Check one option against its config field; return it normalised.

    Raises
    ------
    TypeError, ValueError
        Naming the option and the accepted values.

    Examples
    --------
    >>> from astroalign_nd.config import check_option
    >>> check_option("n_sources", 40)
    40
    >>> check_option("tolerance", 0)
    Traceback (most recent call last):
    ...
    ValueError: tolerance must be a finite number > 0 and <= 1e+06 (pixels); got 0.
    """
    return convert(name, OPTIONS[name], value)


def check_options(options):
    """
    Check a dict of options against `OPTIONS` (unknown names are left to the caller).

    Returns
    -------
    options : dict
        The same keys, values normalised.
    """
    return {k: (check_option(k, v) if k in OPTIONS else v) for k, v in options.items()}
