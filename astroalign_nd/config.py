# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The options of a registration: `RegistrationConfig`, the stages' options
put together, and the views of every option by name.

Each stage's options are a frozen dataclass in that stage, in the
package's one checking system (``astroalign_nd.options``: each option's
default, range, message and command-line flag once):
`~astroalign_nd.detection.DetectionConfig` (how stars are found),
`~astroalign_nd.matching.MatchingConfig` (how the triangles are matched
and the match verified), `~astroalign_nd.transforms.ModelConfig` (the
transform fitted), `~astroalign_nd.resample.ResampleConfig` (how the
source's pixels are resampled) and `~astroalign_nd.stacking.StackConfig`
(how frames are stacked).  `RegistrationConfig` holds the first three and
the numbers of control points; `split_options` sorts keywords among the
stages, and `OPTIONS` is a view of the checks, by option name.

`~astroalign_nd.find_transform`, `~astroalign_nd.register`,
`~astroalign_nd.register_batch`, `~astroalign_nd.Reference` and
`~astroalign_nd.find_sources` take the options as keywords and build these
configs once; the stages trust them.

These are the options of each call.  The package's runtime settings
(threads, compiled code) are ``astroalign_nd.conf``, an astropy
configuration namespace (``astroalign_nd/_settings.py``).
"""

import dataclasses

from .detection.options import DetectionConfig
from .matching.options import MatchingConfig
from .options import Int, Unchecked, astroalign_advice, check_fields, convert, option
from .transforms.options import ModelConfig

__all__ = ["RegistrationConfig", "OPTIONS", "check_option", "split_options"]


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


# -- views -------------------------------------------------------------------------------------


#: Every checked option and how it is checked (a view of the configs' fields).
OPTIONS = {f.name: f.metadata["check"]
           for cls in (MatchingConfig, DetectionConfig, RegistrationConfig)
           for f in dataclasses.fields(cls)
           if not isinstance(f.metadata.get("check"), (type(None), Unchecked))}


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
