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
    p.add_argument("source", metavar="SOURCE",
                   help="image to be transformed (FITS, or JPEG/PNG/TIFF)")
    p.add_argument("target", metavar="TARGET", help="image that defines the output grid")
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
    p.add_argument("target", metavar="TARGET", help="image that defines the output grid")
    p.add_argument("sources", metavar="SOURCES", nargs="+",
                   help="images to be transformed (FITS, or JPEG/PNG/TIFF)")
    p.add_argument("--output-dir", required=True, metavar="DIR",
                   help="folder for the aligned images (created if needed)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run the frames on this dask.distributed scheduler "
                   "(e.g. tcp://host:8786)")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="start a local dask.distributed cluster of N worker processes "
                   "(default: run in this process)")
    p.add_argument("--progress", action="store_true", help="show a progress bar")
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
        hdu=_hdu(args.hdu),
    )


def _hdu(value):
    """``--hdu 1`` is an index, ``--hdu SCI`` an extension name."""
    if value is None:
        return None
    return int(value) if value.lstrip("-").isdigit() else value


def _check_writable(path, overwrite):
    """Refuse to replace an existing file unless ``overwrite`` is set."""
    if os.path.exists(path) and not overwrite:
        raise CLIError(f"output file {path!r} already exists; pass --overwrite to replace it.")


def _check_input(path):
    if not os.path.isfile(path):
        raise CLIError(f"input file {path!r} does not exist or is not a file.")
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
    aligned = astroalign_nd.register(_check_input(args.source), _check_input(args.target),
                                     unit=args.unit, **_registration_kwargs(args))
    aligned.write(args.output, overwrite=args.overwrite, hdu_flags="FLAGS")
    q = aligned.meta
    print(f"{_describe(astroalign_nd.transform_from_header(q))}; {q['AATNMAT']} matched "
          f"stars, RMS {q['AATRMS']:.3f} px")
    print(f"wrote {args.output}")
    return 0


def _cmd_batch(args):
    import astroalign_nd

    _check_input(args.target)
    client = cluster = None
    if args.scheduler or args.workers:
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise CLIError("--scheduler/--workers need dask.distributed: "
                           "pip install 'astroalign_nd[dask]'") from None
        if args.scheduler:
            client = Client(args.scheduler)
        else:
            cluster = LocalCluster(n_workers=args.workers, threads_per_worker=1,
                                   dashboard_address=None)
            client = Client(cluster)
    try:
        kwargs = _registration_kwargs(args)
        result = astroalign_nd.register_batch(
            args.sources, args.target, output_dir=args.output_dir, overwrite=args.overwrite,
            client=client, progress=args.progress, unit=args.unit, **kwargs)
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    for i, f in enumerate(result.frames, start=1):
        prefix = f"[{i}/{len(result.frames)}] {args.sources[i - 1]}"
        if f.ok:
            print(f"{prefix}: ok -> {f.output} ({f.quality['n_matches']} stars, "
                  f"RMS {f.quality['rms']:.3f} px)")
        else:
            print(f"{prefix}: FAILED ({f.error})")
    print(result.summary())
    return 1 if result.failed else 0


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

    # The registered frame records how it was made: rebuild the transform.
    recovered = astroalign_nd.transform_from_header(aligned.meta)
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
