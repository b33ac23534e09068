# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
What the commands share: the registration options and their translation to keywords,
the checks of inputs and outputs, and a transform's one-line summary.
"""

import argparse
import contextlib
import os

# The configs hold no heavy import: --help stays fast.
from ..config import RegistrationConfig
from ..detection import DetectionConfig
from ..matching import MatchingConfig
from ..options import cli_fields, from_cli
from ..resample import ResampleConfig
from ..transforms import ModelConfig
from .errors import HelpFormatter, _CLIError, exit_codes_text

__all__ = []

#: Every config whose fields the command line offers.
_CONFIGS = (ModelConfig, ResampleConfig, RegistrationConfig, DetectionConfig, MatchingConfig)

# -- argument parsing ------------------------------------------------------------------------


def _command_parser(sub, name, func, help, description, parents=()):
    """
    The subparser of the command ``name``, which ``func(args)`` runs: its ``help`` line in
    the list of commands, its ``description`` and the exit codes in its ``--help``.
    """
    parser = sub.add_parser(name, parents=list(parents), help=help, description=description,
                            epilog=exit_codes_text(), formatter_class=HelpFormatter)
    parser.set_defaults(func=func)
    return parser


def _add_output(parser, help, flags=("-o", "--output"), metavar="OUT.fits"):
    """The command's one output file, required, and ``--overwrite`` to replace it."""
    parser.add_argument(*flags, required=True, metavar=metavar, help=help)
    parser.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")


def _add_progress(parser):
    """``--progress`` and ``--no-progress`` (default None: when standard error is a terminal)."""
    parser.add_argument("--progress", dest="progress", action="store_true", default=None,
                        help="show a progress bar (default: when standard error is a terminal)")
    parser.add_argument("--no-progress", dest="progress", action="store_false",
                        help="never show a progress bar")


def _registration_options():
    """Options shared by ``register`` and ``batch`` (passed on to `astroalign_nd.register`)."""
    parent = argparse.ArgumentParser(add_help=False)
    group = parent.add_argument_group("registration options")
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
    _add_fields(parent.add_argument_group(
        "detection options", "as in astroalign_nd.find_sources; by default estimated from "
        "each image"), DetectionConfig)
    _add_fields(parent.add_argument_group(
        "matching options", "as in astroalign_nd.matching.match_points"), MatchingConfig)
    return parent


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
    # --hdu 1 is an index, --hdu SCI an extension name.
    hdu = args.hdu
    kwargs = dict(hdu=int(hdu) if hdu is not None and hdu.lstrip("-").isdigit() else hdu)
    for name in _FIELDS:
        value = getattr(args, name, None)
        if value is not None:
            kwargs[name] = tuple(value) if isinstance(value, list) else value
    return kwargs


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


#: The folders the command created, outermost first: removed at its end if still empty
#: (a run that failed leaves no empty folder behind).
_CREATED = []


def _check_output_dir(path, what="--output-dir"):
    """Create the folder ``path`` if needed (noted in `_CREATED`), and check it is writable."""
    from astroalign_nd.io.write import make_output_dir

    try:
        _CREATED.extend(make_output_dir(path, what))
    except OSError as exc:
        raise _CLIError(str(exc)) from None


@contextlib.contextmanager
def _empty_folders_removed():
    """Remove, at the end of the command, the folders it created and left empty."""
    from astroalign_nd.io.write import remove_empty_dirs

    try:
        yield
    finally:
        remove_empty_dirs(_CREATED)
        _CREATED.clear()


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
