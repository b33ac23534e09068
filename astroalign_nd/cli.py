# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The ``astroalign-nd`` command-line tool.

Subcommands
-----------
``register SOURCE TARGET -o OUT.fits``
    Register one image onto another and write the aligned image.
``batch TARGET SOURCES... --output-dir DIR``
    Register several images onto one target, going on past failures.
``demo --output-dir DIR``
    Simulate a star-field pair with a known transform, register it and
    report how close the recovered transform is to the truth.

Exit codes: 0 on success, 1 when some frames of a ``batch`` failed, 2 on a
usage or registration error (the message is printed to standard error,
without a traceback).

The package itself is imported lazily, inside the subcommands, so that
``astroalign-nd --help`` stays fast.
"""

import argparse
import os
import sys

__all__ = ["main"]

PROG = "astroalign-nd"

#: Errors reported as ``astroalign-nd: error: <message>`` rather than with a traceback.
_USER_ERRORS = (ValueError, TypeError, OSError)


class CLIError(Exception):
    """A problem with the command line itself (exit code 2)."""


def _expected_errors():
    """The exception classes that are reported without a traceback."""
    from astroalign_nd import AstroalignError

    return (AstroalignError, CLIError) + _USER_ERRORS


# -- argument parsing ------------------------------------------------------------------------


def _registration_options():
    """Options shared by ``register`` and ``batch`` (passed on to `astroalign_nd.register`)."""
    parent = argparse.ArgumentParser(add_help=False)
    group = parent.add_argument_group("registration options")
    group.add_argument(
        "--transform-type",
        default="similarity",
        metavar="TYPE",
        help="model fitted between the images: translation, euclidean, similarity or affine "
        "(default: %(default)s)",
    )
    group.add_argument(
        "--order",
        default="bicubic",
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
        "--unit",
        default=None,
        help="unit of any input FITS file that has no BUNIT keyword (default: adu)",
    )
    return parent


def _build_parser():
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Register (align) astronomical images by matching star triangles. "
        "Inputs are FITS images; outputs are FITS images written as CCDData, "
        "with mask and uncertainty when the inputs have them.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    reg_opts = _registration_options()

    p = sub.add_parser(
        "register",
        parents=[reg_opts],
        help="register SOURCE onto the pixel grid of TARGET",
        description="Register the SOURCE image onto the pixel grid of the TARGET image and "
        "write the aligned image to OUT.",
    )
    p.add_argument("source", metavar="SOURCE", help="FITS image to be transformed")
    p.add_argument("target", metavar="TARGET", help="FITS image that defines the output grid")
    p.add_argument("-o", "--output", required=True, metavar="OUT.fits",
                   help="FITS file to write the aligned image to")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.set_defaults(func=_cmd_register)

    p = sub.add_parser(
        "batch",
        parents=[reg_opts],
        help="register several images onto one target",
        description="Register each SOURCE onto the pixel grid of TARGET, writing "
        "DIR/<name>_aligned.fits for each. A frame that fails is reported and skipped; "
        "the exit code is 1 if any frame failed.",
    )
    p.add_argument("target", metavar="TARGET", help="FITS image that defines the output grid")
    p.add_argument("sources", metavar="SOURCES", nargs="+", help="FITS images to be transformed")
    p.add_argument("--output-dir", required=True, metavar="DIR",
                   help="folder for the aligned images (created if needed)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.set_defaults(func=_cmd_batch)

    p = sub.add_parser(
        "demo",
        help="simulate a pair of star fields, register them and compare with the truth",
        description="Simulate a 512x512 star-field pair related by a known similarity "
        "transform (rotation 17 deg, scale 1.05, shift (12.3, -7.7) px), write "
        "DIR/source.fits and DIR/target.fits, register the source onto the target, write "
        "DIR/aligned.fits and report the error of the recovered transform.",
    )
    p.add_argument("--output-dir", required=True, metavar="DIR",
                   help="folder for source.fits, target.fits and aligned.fits "
                   "(created if needed)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    p.set_defaults(func=_cmd_demo)

    return parser


# -- helpers ---------------------------------------------------------------------------------


def _registration_kwargs(args):
    return dict(
        transform_type=args.transform_type,
        order=args.order,
        conserve_flux=args.conserve_flux,
        n_sources=args.n_sources,
    )


def _check_writable(path, overwrite):
    """Refuse to replace an existing file unless ``overwrite`` is set."""
    if os.path.exists(path) and not overwrite:
        raise CLIError(f"output file {path!r} already exists; pass --overwrite to replace it.")


def _read_image(path, unit=None):
    """
    Read a FITS image as `~astropy.nddata.CCDData`.

    The unit is the file's BUNIT; for a file without one (most raw frames)
    it is ``unit``, or ``adu`` if ``unit`` is None.
    """
    from astropy.nddata import CCDData

    if not os.path.isfile(path):
        raise CLIError(f"input file {path!r} does not exist or is not a file.")
    try:
        return CCDData.read(path, format="fits")
    except ValueError as exc:
        # CCDData refuses a file without BUNIT; anything else is a real error.
        if "unit" not in str(exc).lower():
            raise
        return CCDData.read(path, unit=unit or "adu", format="fits")


def _describe(transform):
    """One-line summary of a transform model."""
    import numpy as np

    parts = [type(transform).__name__]
    scale = getattr(transform, "scale", None)
    rotation = getattr(transform, "rotation", None)
    translation = getattr(transform, "translation", None)
    try:
        if rotation is not None:
            parts.append(f"rotation={np.degrees(float(np.squeeze(rotation))):.4f} deg")
        if scale is not None:
            s = np.atleast_1d(np.squeeze(np.asarray(scale, dtype=float)))
            parts.append("scale=" + ", ".join(f"{v:.5f}" for v in s))
        if translation is not None:
            t = np.ravel(np.asarray(translation, dtype=float))
            parts.append("translation=(" + ", ".join(f"{v:.3f}" for v in t) + ") px")
    except (TypeError, ValueError):
        return repr(transform)
    if len(parts) == 1:
        return repr(transform)
    return " ".join(parts)


def _max_corner_error(recovered, truth, shape):
    """Largest distance (px) between two transforms evaluated at the frame corners."""
    import numpy as np

    ny, nx = shape
    x = np.array([0.0, nx - 1.0, 0.0, nx - 1.0])
    y = np.array([0.0, 0.0, ny - 1.0, ny - 1.0])
    xr, yr = recovered(x, y)
    xt, yt = truth(x, y)
    return float(np.max(np.hypot(np.asarray(xr) - xt, np.asarray(yr) - yt)))


# -- subcommands -----------------------------------------------------------------------------


def _cmd_register(args):
    import astroalign_nd

    _check_writable(args.output, args.overwrite)
    source = _read_image(args.source, args.unit)
    target = _read_image(args.target, args.unit)
    aligned = astroalign_nd.register(source, target, **_registration_kwargs(args))
    aligned.write(args.output, overwrite=args.overwrite)
    print(f"wrote {args.output}")
    return 0


def _batch_output_names(sources, output_dir):
    """``DIR/<stem>_aligned.fits`` for each source, made unique if two stems collide."""
    names, seen = [], {}
    for path in sources:
        stem = os.path.basename(path)
        for ext in (".gz", ".fz", ".fits", ".fit", ".fts"):
            if stem.lower().endswith(ext):
                stem = stem[: -len(ext)]
        count = seen.get(stem, 0)
        seen[stem] = count + 1
        suffix = f"_{count}" if count else ""
        names.append(os.path.join(output_dir, f"{stem}{suffix}_aligned.fits"))
    return names


def _cmd_batch(args):
    import astroalign_nd

    errors = (astroalign_nd.AstroalignError, CLIError) + _USER_ERRORS
    target = _read_image(args.target, args.unit)
    os.makedirs(args.output_dir, exist_ok=True)
    outputs = _batch_output_names(args.sources, args.output_dir)
    kwargs = _registration_kwargs(args)

    failed = []
    for i, (path, out) in enumerate(zip(args.sources, outputs), start=1):
        prefix = f"[{i}/{len(args.sources)}] {path}"
        try:
            _check_writable(out, args.overwrite)
            source = _read_image(path, args.unit)
            aligned = astroalign_nd.register(source, target, **kwargs)
            aligned.write(out, overwrite=args.overwrite)
        except errors as exc:
            failed.append(path)
            print(f"{prefix}: FAILED ({type(exc).__name__}: {exc})", flush=True)
        else:
            print(f"{prefix}: ok -> {out}", flush=True)

    n_ok = len(args.sources) - len(failed)
    print(f"{n_ok} of {len(args.sources)} frames registered, {len(failed)} failed.")
    for path in failed:
        print(f"  failed: {path}")
    return 1 if failed else 0


def _cmd_demo(args):
    import astropy.units as u
    from astropy.nddata import CCDData

    import astroalign_nd
    from astroalign_nd.simulate import simulate_pair

    out_dir = args.output_dir
    paths = {name: os.path.join(out_dir, f"{name}.fits")
             for name in ("source", "target", "aligned")}
    for path in paths.values():
        _check_writable(path, args.overwrite)
    os.makedirs(out_dir, exist_ok=True)

    pair = simulate_pair(
        shape=(512, 512),
        n_stars=300,
        rotation=17.0,
        scale=1.05,
        translation=(12.3, -7.7),
        seed=args.seed,
    )
    source = CCDData(pair.source, unit=u.adu)
    target = CCDData(pair.target, unit=u.adu)
    source.write(paths["source"], overwrite=args.overwrite)
    target.write(paths["target"], overwrite=args.overwrite)

    aligned = astroalign_nd.register(source, target)
    aligned.write(paths["aligned"], overwrite=args.overwrite)

    # register() returns the image only; find the transform again to compare it with the truth.
    found = astroalign_nd.find_transform(source, target)
    recovered = getattr(found, "transform", None)
    if recovered is None:
        recovered = found[0] if isinstance(found, tuple) else found
    error = _max_corner_error(recovered, pair.transform, source.shape)

    print(f"true transform:      {_describe(pair.transform)}")
    print(f"recovered transform: {_describe(recovered)}")
    print(f"max position error over the {source.shape[1]}x{source.shape[0]} frame: "
          f"{error:.4f} px")
    if not error < 1.0:
        print("WARNING: the recovered transform is more than 1 px off the truth somewhere "
              "in the frame.")
    print(f"wrote {paths['source']}")
    print(f"wrote {paths['target']}")
    print(f"wrote {paths['aligned']}")
    return 0


# -- entry point -----------------------------------------------------------------------------


def _error(message):
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def main(argv=None):
    """
    Run the ``astroalign-nd`` command line.

    Parameters
    ----------
    argv : list of str, optional
        The arguments, without the program name. Defaults to ``sys.argv[1:]``.

    Returns
    -------
    int
        The exit code: 0 on success, 1 if some frames of ``batch`` failed,
        2 on a usage or registration error.
    """
    parser = _build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, or argparse's own usage error (code 2)
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)

    if args.version:
        from importlib.metadata import PackageNotFoundError, version

        try:
            print(f"{PROG} {version('astroalign_nd')}")
        except PackageNotFoundError:
            print(f"{PROG} (version unknown: package not installed)")
        return 0
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2

    try:
        errors = _expected_errors()
    except ImportError as exc:
        return _error(f"could not import astroalign_nd: {exc}")
    try:
        return args.func(args)
    except errors as exc:
        return _error(str(exc) or type(exc).__name__)
    except KeyboardInterrupt:
        return _error("interrupted.")


if __name__ == "__main__":
    sys.exit(main())
