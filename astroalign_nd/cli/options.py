# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The registration options of the command line, and their translation to keywords."""

import argparse

# The configs hold no heavy import: --help stays fast.
from ..config import (DetectionConfig, MatchingConfig, ModelConfig, RegistrationConfig,
                      ResampleConfig, cli_fields)

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


def _add_fields(group, config):
    """The command-line options of ``config``'s fields: flags, types, defaults and help."""
    for _, flag, kwargs in cli_fields(config):
        group.add_argument(flag, **kwargs)


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
