# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
What the commands share: the registration options and their translation to keywords,
the checks of inputs and outputs, and a transform's one-line summary.
"""

import argparse
import os

# The configs hold no heavy import: --help stays fast.
from ..config import (DetectionConfig, MatchingConfig, ModelConfig, RegistrationConfig,
                      ResampleConfig)
from ..options import cli_fields, from_cli
from .errors import _CLIError

__all__ = []

#: Every config whose fields the command line offers.
_CONFIGS = (ModelConfig, ResampleConfig, RegistrationConfig, DetectionConfig, MatchingConfig)

# -- argument parsing ------------------------------------------------------------------------


def _registration_options():
    """Options shared by ``register`` and ``batch`` (passed on to `astroalign_nd.register`)."""
    parent = argparse.ArgumentParser(add_help=False)
    _add_model_options(parent.add_argument_group("registration options"))
    _add_detection_options(parent.add_argument_group(
        "detection options", "as in astroalign_nd.find_sources; by default estimated from "
        "each image"))
    _add_matching_options(parent.add_argument_group(
        "matching options", "as in astroalign_nd.matching.match_points"))
    return parent


def _add_model_options(group):
    """The model, resampling and input options of a registration."""
    for config in (ModelConfig, ResampleConfig, RegistrationConfig):
        _add_fields(group, config)
    group.add_argument(
        "--unit",
        default=None,
        help="unit of any input FITS file that has no BUNIT keyword (default: adu)",
    )
    group.add_argument(
        "--hdu",
        default=None,
        metavar="HDU",
        help="FITS extension to read, an index or a name (default: the first one with "
        "image data); MASK, UNCERT and FLAGS extensions are read as CCDData.read does",
    )


def _add_detection_options(det):
    """Options passed on to `astroalign_nd.find_sources` (None: estimated from each image)."""
    _add_fields(det, DetectionConfig)


def _add_matching_options(mat):
    """Options passed on to `astroalign_nd.matching.match_points`."""
    _add_fields(mat, MatchingConfig)


def _add_fields(group, config, user=None):
    """
    The command-line options of ``config``'s fields (those ``user`` takes): flags, types,
    defaults and help.
    """
    for _, flag, kwargs in cli_fields(config, user):
        group.add_argument(flag, **kwargs)


def _add_stack_options(parser, user):
    """The stacking options that ``user`` ('stack' or 'live') takes, as one group of flags."""
    from ..stacking import StackConfig

    _add_fields(parser.add_argument_group("combination options", "as in astroalign_nd.stack"),
                StackConfig, user)


def _stack_kwargs(args, user):
    """The stacking options given on the command line, as the library's keywords."""
    from ..stacking import StackConfig

    return {name: from_cli(StackConfig, name, getattr(args, name))
            for name, _, _ in cli_fields(StackConfig, user)}


#: The config fields the command line offers, by name (the keywords of `register`).
_FIELDS = tuple(name for config in _CONFIGS for name, _, _ in cli_fields(config))

# -- helpers ---------------------------------------------------------------------------------


def _registration_kwargs(args):
    """`register`'s keyword arguments: every option given (None: the library's default)."""
    kwargs = dict(hdu=_hdu(args.hdu))
    for name in _FIELDS:
        value = getattr(args, name, None)
        if value is not None:
            kwargs[name] = tuple(value) if isinstance(value, list) else value
    return kwargs


def _hdu(value):
    """``--hdu 1`` is an index, ``--hdu SCI`` an extension name."""
    if value is None:
        return None
    return int(value) if value.lstrip("-").isdigit() else value


# -- input and output checks -----------------------------------------------------------------


def _check_writable(path, overwrite, inputs=()):
    """Refuse, before any work, a path that cannot take the output (or is an input)."""
    from astroalign_nd.io.write import check_not_input, check_output_path
    from astroalign_nd.io.writers import output_suffixes

    try:
        check_not_input(path, inputs)
    except ValueError as exc:
        raise _CLIError(str(exc)) from None
    try:
        check_output_path(path, overwrite, extensions=output_suffixes())
    except FileExistsError:
        raise _CLIError(f"output file {path!r} already exists; pass --overwrite to replace "
                        "it.") from None


def _check_output_dir(path):
    from astroalign_nd.io.write import check_output_dir

    if os.path.exists(path) and not os.path.isdir(path):
        raise _CLIError(f"--output-dir {path!r} is a file, not a folder.")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as exc:
        raise _CLIError(f"cannot create output folder {path!r}: {exc.strerror or exc}.") from None
    check_output_dir(path)


def _check_input(path):
    if not os.path.isfile(path):
        raise _CLIError(f"input file {path!r} does not exist or is not a file.")
    return path


def _describe(transform):
    """One-line summary of a transform model."""
    import numpy as np

    parts = [type(transform).__name__]
    scale = getattr(transform, "scale", None)
    rotation = getattr(transform, "rotation", None)
    translation = getattr(transform, "translation", None)
    try:
        if rotation is not None:
            # Parameters hold degrees (astropy's convention); float() of a
            # Parameter raises on astropy 8, so read its value.
            value = getattr(rotation, "value", rotation)
            parts.append(f"rotation={float(np.squeeze(value)):.4f} deg")
        if scale is not None:
            s = np.atleast_1d(np.squeeze(np.asarray(getattr(scale, "value", scale),
                                                    dtype=float)))
            parts.append("scale=" + ", ".join(f"{v:.5f}" for v in s))
        if translation is not None:
            t = np.ravel(np.asarray(translation, dtype=float))
            parts.append("translation=(" + ", ".join(f"{v:.3f}" for v in t) + ") px")
    except (TypeError, ValueError):
        return repr(transform)
    if len(parts) == 1:
        return repr(transform)
    return " ".join(parts)
