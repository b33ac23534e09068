# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The one checking system of the package's options: each option's default,
accepted values, message and command-line flag, declared once.

Every stage's options are a frozen dataclass whose fields are made by
`option` (its default, its accepted values as a check object, its help text
and, with a ``flag``, how the command line spells it); the dataclass's
``__post_init__`` calls `check_fields`, so that constructing it checks and
normalises every value and a bad one gives one message naming the option
and its range, before any work.  The command line's flags and help are
generated from the same fields (`cli_fields`, `from_cli`).

The configs: `~astroalign_nd.detection.DetectionConfig`,
`~astroalign_nd.matching.MatchingConfig`, `~astroalign_nd.transforms.ModelConfig`,
`~astroalign_nd.resample.ResampleConfig`,
`~astroalign_nd.config.RegistrationConfig` and
`~astroalign_nd.stacking.StackConfig`.

A check object has ``describe()`` (the accepted values, as the message
says them: "a finite number > 0") and ``convert(value)`` (the normalised
value; TypeError or ValueError, without a message, for a refused one);
one with a ``choices`` tuple gets them as the flag's choices (None spelled
``none``).  This module imports no other module of the package: every
stage may use it.
"""

import dataclasses
import math
import numbers

import numpy as np

__all__ = ["Real", "Int", "Pair", "Bool", "Choice", "AnyCallable", "Unchecked", "option",
           "check_fields", "convert", "check_values", "fields_of", "cli_fields", "from_cli",
           "astroalign_advice"]


# -- accepted values ---------------------------------------------------------------------------


class Real:
    """
    A real number in an interval (each bound open or closed).

    Examples
    --------
    >>> from astroalign_nd.options import Real
    >>> check = Real(0, 1e4, lo_open=True, none=True, unit="pixels")
    >>> check.describe()
    'a finite number > 0 and <= 10000 (pixels) or None'
    >>> check.convert(3)
    3.0
    """

    def __init__(self, lo=None, hi=None, *, lo_open=False, hi_open=False, none=False,
                 unit="", infinite=False):
        self.lo, self.hi, self.lo_open, self.hi_open = lo, hi, lo_open, hi_open
        self.none, self.unit, self.infinite = none, unit, infinite

    def describe(self):
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {self.lo:g}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {self.hi:g}")
        text = ("a number" if self.infinite else "a finite number") + (
            " " + " and ".join(parts) if parts else "")
        if self.unit:
            text += f" ({self.unit})"
        return text + (" or None" if self.none else "")

    def _in_range(self, v):
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        if self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi):
            return False
        return True

    #: The accepted type (bools are refused).
    _kind = numbers.Real

    def _is_none(self, value):
        """True for an accepted None; TypeError for another None or a value of another type."""
        if value is None:
            if self.none:
                return True
            raise TypeError
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, self._kind):
            raise TypeError
        return False

    def convert(self, value):
        if self._is_none(value):
            return None
        v = float(value)
        if math.isnan(v) or (math.isinf(v) and not self.infinite) or not self._in_range(v):
            raise ValueError
        return v


class Int(Real):
    """
    An integer in a closed interval.

    Examples
    --------
    >>> from astroalign_nd.options import Int
    >>> Int(1, None).describe(), Int(1, None).convert(3)
    ('an integer >= 1', 3)
    """

    def describe(self):
        text = super().describe().replace("a finite number", "an integer")
        text = text.replace("a number", "an integer")
        return text

    _kind = numbers.Integral

    def convert(self, value):
        if self._is_none(value):
            return None
        v = int(value)
        if not self._in_range(v):
            raise ValueError
        return v


class Pair:
    """
    An increasing pair ``(lo, hi)`` of numbers, each checked by ``item``.

    Examples
    --------
    >>> from astroalign_nd.options import Pair, Real
    >>> Pair(Real(0, lo_open=True)).convert([0.5, 2])
    (0.5, 2.0)
    """

    def __init__(self, item, *, none=True, strict=False):
        self.item, self.none, self.strict = item, none, strict

    def describe(self):
        order = "lo < hi" if self.strict else "lo <= hi"
        return (f"a pair (lo, hi) with {order}, each {self.item.describe()}"
                + (", or None" if self.none else ""))

    def convert(self, value):
        if value is None:
            if self.none:
                return None
            raise TypeError
        if isinstance(value, (str, bytes)) or not np.iterable(value):
            raise TypeError
        items = list(value)
        if len(items) != 2:
            raise ValueError
        lo, hi = (self.item.convert(v) for v in items)
        if lo > hi or (self.strict and lo == hi):
            raise ValueError
        return (lo, hi)


class Bool:
    """
    True or False (numbers are refused).

    Examples
    --------
    >>> from astroalign_nd.options import Bool, convert
    >>> convert("allow_mirror", Bool(), 1)
    Traceback (most recent call last):
    ...
    TypeError: allow_mirror must be True or False; got 1.
    """

    def describe(self):
        return "True or False"

    def convert(self, value):
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
        raise TypeError


class Choice:
    """
    One of ``choices`` (None among them: the option can be switched off).

    Its ``choices`` are also the command-line flag's (None spelled ``none``).

    Examples
    --------
    >>> from astroalign_nd.options import Choice, convert
    >>> convert("clip", Choice(("sigma", "minmax", None)), "extrema")
    Traceback (most recent call last):
    ...
    ValueError: clip must be one of 'sigma', 'minmax', None; got 'extrema'.
    """

    def __init__(self, choices):
        self.choices = tuple(choices)

    def describe(self):
        return f"one of {', '.join(map(repr, self.choices))}"

    def convert(self, value):
        if isinstance(value, str) or value is None:
            if value in self.choices:
                return value
            raise ValueError
        raise TypeError


class AnyCallable:
    """
    Any callable, or None: a source finder (``finder(data, mask=None)``) by default.

    Parameters
    ----------
    what : str, optional
        What the callable is called with, for the message.

    Examples
    --------
    >>> from astroalign_nd.options import AnyCallable, convert
    >>> AnyCallable().convert(None) is None
    True
    >>> convert("callback", AnyCallable("a function of one FrameResult"), 3)
    Traceback (most recent call last):
    ...
    TypeError: callback must be a function of one FrameResult or None; got 3.
    """

    def __init__(self, what="a source finder (callable as finder(data, mask=None))"):
        self.what = what

    def describe(self):
        return f"{self.what} or None"

    def convert(self, value):
        if value is None or callable(value):
            return value
        raise TypeError


class Unchecked:
    """
    Any value: checked where it is used (e.g. a transform type, by the transform registry).

    Examples
    --------
    >>> from astroalign_nd.options import Unchecked
    >>> Unchecked().convert("similarity")
    'similarity'
    """

    def convert(self, value):
        return value


# -- fields ------------------------------------------------------------------------------------


def option(default, check, help="", *, auto=False, used_by=None, **cli):
    """
    A config field: its default, accepted values and help, once.

    Parameters
    ----------
    default
        The option's default.
    check
        Its accepted values: an object with ``describe()`` and
        ``convert(value)`` (`Real`, `Int`, `Pair`, `Bool`, `Choice`...), or
        None where the config's ``__post_init__`` checks it itself.
    help : str or callable, optional
        The command line's help (``{default}`` in it is replaced by the
        default; a callable gives the text when asked).
    auto : bool, optional
        None is accepted too, and means that the caller chooses (``check``
        itself refuses None).
    used_by : tuple of str, optional
        Which of the config's users take the option (e.g. ``("stack",)``
        of `~astroalign_nd.stacking.StackConfig`; None: all of them).
    **cli
        With a ``flag``, how the command line spells it: ``metavar``,
        ``type``, ``nargs``, ``action`` and ``choices`` as argparse takes
        them, ``cli_default`` (the flag's default when it is not the
        field's; None leaves the option to the library) and ``scale`` (the
        library's value is the flag's times ``scale``, e.g. MB to bytes).

    Examples
    --------
    A config of two options, one of them on the command line:

    >>> import dataclasses
    >>> from astroalign_nd.options import Int, Real, check_fields, cli_fields, option
    >>> @dataclasses.dataclass(frozen=True)
    ... class DemoConfig:
    ...     width: float = option(2.0, Real(0, lo_open=True), "width (default: {default})",
    ...                           flag="--width", type=float)
    ...     rounds: int = option(3, Int(1, 10))
    ...     def __post_init__(self):
    ...         check_fields(self)
    >>> DemoConfig(width=3).width
    3.0
    >>> DemoConfig(rounds=0)
    Traceback (most recent call last):
    ...
    ValueError: rounds must be an integer >= 1 and <= 10; got 0.
    >>> [(name, flag, kw["help"]) for name, flag, kw in cli_fields(DemoConfig)]
    [('width', '--width', 'width (default: 2)')]
    """
    return dataclasses.field(default=default, metadata={
        "check": check, "help": help, "auto": auto, "used_by": used_by, "cli": cli})


def check_fields(config):
    """
    Check and normalise every field of ``config`` (a frozen dataclass), in place.

    A config's ``__post_init__`` calls it (see `option`'s example).

    Examples
    --------
    >>> from astroalign_nd.detection import DetectionConfig
    >>> from astroalign_nd.options import check_fields
    >>> cfg = DetectionConfig(fwhm=3)
    >>> check_fields(cfg)  # what construction did: the values, normalised
    >>> cfg.fwhm, cfg.roundness_range
    (3.0, (-1.0, 1.0))
    """
    for f in dataclasses.fields(config):
        check = f.metadata.get("check")
        if check is not None and not (f.metadata["auto"] and getattr(config, f.name) is None):
            object.__setattr__(config, f.name, convert(f.name, check,
                                                       getattr(config, f.name)))


def convert(name, check, value):
    """
    ``value`` checked and normalised by ``check``.

    Raises
    ------
    TypeError, ValueError
        ``"<name> must be <accepted values>; got <value>."``

    Examples
    --------
    >>> from astroalign_nd.options import Real, convert
    >>> convert("sigma", Real(0, lo_open=True), 3)
    3.0
    >>> convert("sigma", Real(0, lo_open=True), -1)
    Traceback (most recent call last):
    ...
    ValueError: sigma must be a finite number > 0; got -1.
    """
    try:
        return check.convert(value)
    except (TypeError, ValueError) as exc:
        raise type(exc)(f"{name} must be {check.describe()}; got {value!r}.") from None


def fields_of(config_class, user=None):
    """
    The fields of ``config_class`` that ``user`` takes (all of them for None).

    Examples
    --------
    >>> from astroalign_nd.options import fields_of
    >>> from astroalign_nd.stacking import StackConfig
    >>> [f.name for f in fields_of(StackConfig, "live")][:3]
    ['clip', 'sigma', 'sigma_low']
    """
    return tuple(f for f in dataclasses.fields(config_class)
                 if user is None or f.metadata.get("used_by") is None
                 or user in f.metadata["used_by"])


def cli_fields(config_class, user=None):
    """
    The fields of ``config_class`` that the command line offers, in order:
    ``(name, flag, argparse keywords)``.

    The argparse keywords hold the type, metavar, action, choices, the
    default (None for options left to the library when not given) and the
    help, whose ``{default}`` is the field's default.  ``user``: only the
    fields it takes (see `option`).

    Examples
    --------
    >>> from astroalign_nd.detection import DetectionConfig
    >>> from astroalign_nd.options import cli_fields
    >>> name, flag, kwargs = cli_fields(DetectionConfig)[0]
    >>> name, flag, kwargs["type"], kwargs["default"]
    ('fwhm', '--fwhm', <class 'float'>, None)
    """
    found = []
    for f in fields_of(config_class, user):
        cli = dict(f.metadata.get("cli", {}))
        if "flag" not in cli:
            continue
        flag, scale = cli.pop("flag"), cli.pop("scale", None)
        default = f.default if scale is None else f.default / scale
        kwargs = dict(default=cli.pop("cli_default", default), dest=f.name, **cli)
        choices = getattr(f.metadata["check"], "choices", None)
        if choices is not None and "choices" not in kwargs and "action" not in kwargs:
            kwargs["choices"] = tuple("none" if c is None else c for c in choices)
            kwargs["default"] = "none" if kwargs["default"] is None else kwargs["default"]
        text = f.metadata["help"]
        text = text() if callable(text) else text
        # A float default as ``1e-6``, not ``1e-06``.
        shown = (f"{f.default:g}".replace("e-0", "e-").replace("e+0", "e+")
                 if isinstance(f.default, float) else str(f.default))
        kwargs["help"] = text.replace("{default}", shown)
        found.append((f.name, flag, kwargs))
    return found


def from_cli(config_class, name, value):
    """
    The library's value of option ``name`` given ``value`` on the command line
    (``none`` is None, a list a tuple, a scaled value multiplied).

    Examples
    --------
    >>> from astroalign_nd.options import from_cli
    >>> from astroalign_nd.stacking import StackConfig
    >>> from_cli(StackConfig, "clip", "none"), from_cli(StackConfig, "memory_limit", 100.0)
    (None, 100000000.0)
    """
    f = next(f for f in dataclasses.fields(config_class) if f.name == name)
    if getattr(f.metadata["check"], "choices", None) is not None and value == "none":
        return None
    if isinstance(value, list):
        return tuple(value)
    scale = f.metadata["cli"].get("scale")
    return value if scale is None or value is None else value * scale


def check_values(config_class, values):
    """
    ``values`` with each of ``config_class``'s options checked and normalised
    by its field (other names are left to the caller).

    For a function that takes a stage's options as keywords without building
    its config (`~astroalign_nd.matching.match_points`).

    Examples
    --------
    >>> from astroalign_nd.matching import MatchingConfig
    >>> from astroalign_nd.options import check_values
    >>> check_values(MatchingConfig, {"n_neighbors": 6, "seed": 1})
    {'n_neighbors': 6, 'seed': 1}
    >>> check_values(MatchingConfig, {"n_neighbors": 1})
    Traceback (most recent call last):
    ...
    ValueError: n_neighbors must be an integer >= 2 and <= 16; got 1.
    """
    checks = {f.name: f.metadata["check"] for f in dataclasses.fields(config_class)}
    return {k: v if checks.get(k) is None else convert(k, checks[k], v)
            for k, v in values.items()}


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
    >>> from astroalign_nd.options import astroalign_advice
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
