# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The registration options of the command line, and their translation to keywords."""

import argparse

# (The registry is light: it names the model classes, imported when they are used.)
from ..transforms.registry import LINEAR_TYPES, NONLINEAR_TYPES

__all__ = []

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
    group.add_argument(
        "--transform-type",
        default="similarity",
        metavar="TYPE",
        help=f"model fitted between the images: {', '.join(LINEAR_TYPES)}, or for wide fields "
        f"with distortion {' or '.join(NONLINEAR_TYPES)} (see --degree) (default: %(default)s)",
    )
    group.add_argument(
        "--degree",
        default=None,
        metavar="N",
        help="degree of the polynomial distortion model, 2 to 5, or 'auto' to let an F-test "
        "choose (linear when the images need no distortion); only with --transform-type "
        "polynomial (default: 3)",
    )
    group.add_argument(
        "--order",
        default="bilinear",
        help="interpolation used to resample the source: nearest-neighbor, bilinear, "
        "biquadratic or bicubic (default: %(default)s)",
    )
    group.add_argument(
        "--conserve-flux",
        action="store_true",
        help="scale the resampled values by the pixel-area change so that total flux is kept",
    )
    group.add_argument(
        "--n-sources",
        type=int,
        default=50,
        metavar="N",
        help="number of brightest sources used to build triangles (default: %(default)s)",
    )
    group.add_argument(
        "--max-sources",
        type=int,
        default=None,
        metavar="N",
        help="if no trustworthy match is found, control points are doubled up to N "
        "(default: 200)",
    )
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
    det.add_argument("--fwhm", type=float, default=None, metavar="PX",
                     help="stellar FWHM in pixels (give it when the estimate fails, e.g. on "
                     "nebulosity)")
    det.add_argument("--nsigma", type=float, default=None, metavar="K",
                     help="detection threshold in background standard deviations")
    det.add_argument("--peak-max", type=float, default=None, metavar="ADU",
                     help="ignore sources whose peak exceeds this value (saturated stars)")
    det.add_argument("--sharpness-range", type=float, nargs=2, default=None,
                     metavar=("LO", "HI"), help="accepted DAOFIND sharpness range")
    det.add_argument("--roundness-range", type=float, nargs=2, default=None,
                     metavar=("LO", "HI"), help="accepted DAOFIND roundness range")
    det.add_argument("--bin-factor", type=int, default=None, metavar="B",
                     help="detect on the image binned BxB (for large, oversampled frames)")


def _add_matching_options(mat):
    """Options passed on to `astroalign_nd.matching.match_points`."""
    mat.add_argument("--tolerance", type=float, default=None, metavar="PX",
                     help="largest distance (px) for a star to count as matched")
    mat.add_argument("--max-false-alarm", type=float, default=None, metavar="P",
                     help="largest false-alarm probability accepted (default: 1e-6)")
    mat.add_argument("--no-mirror", dest="allow_mirror", action="store_false", default=None,
                     help="do not consider mirrored (flipped) solutions")


#: CLI destinations forwarded to find_transform when given (None: the library's default).
_FORWARDED = ("max_sources", "fwhm", "nsigma", "peak_max", "sharpness_range",
              "roundness_range", "bin_factor", "tolerance", "max_false_alarm", "allow_mirror")

# -- helpers ---------------------------------------------------------------------------------


def _registration_kwargs(args):
    kwargs = dict(
        transform_type=args.transform_type,
        order=args.order,
        conserve_flux=args.conserve_flux,
        n_sources=args.n_sources,
        hdu=_hdu(args.hdu),
    )
    if getattr(args, "degree", None) is not None:
        kwargs["degree"] = args.degree
    for name in _FORWARDED:
        value = getattr(args, name, None)
        if value is not None:
            kwargs[name] = tuple(value) if isinstance(value, list) else value
    return kwargs


def _hdu(value):
    """``--hdu 1`` is an index, ``--hdu SCI`` an extension name."""
    if value is None:
        return None
    return int(value) if value.lstrip("-").isdigit() else value
