# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The ``astroalign-nd`` command-line tool.

Subcommands
-----------
``register SOURCE TARGET -o OUT.fits``
    Register one image onto another and write the aligned image.
``batch SOURCES... -r TARGET --output-dir DIR``
    Register several images onto one target, going on past failures
    (``batch TARGET SOURCES...``, the older form, still works).
``demo --output-dir DIR``
    Simulate a star-field pair with a known transform, register it and
    report how close the recovered transform is to the truth.

Exit codes: 0 on success (frames skipped by ``--skip-existing`` included), 1
when some frames of a ``batch`` failed, 2 on a usage or registration error or
any other error, out of memory included (one line on standard error, without
a traceback).

The package itself is imported lazily, inside the subcommands, so that
``astroalign-nd --help`` stays fast.
"""

import argparse
import os
import sys

__all__ = ["main"]

_PROG = "astroalign-nd"

#: Errors reported as ``astroalign-nd: error: <message>`` rather than with a traceback.
_USER_ERRORS = (ValueError, TypeError, OSError)


class _CLIError(Exception):
    """A problem with the command line itself (exit code 2)."""


def _expected_errors():
    """The exception classes that are reported without a traceback."""
    from astroalign_nd import AstroalignError

    return (AstroalignError, _CLIError) + _USER_ERRORS


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
        help="model fitted between the images: translation, euclidean, similarity, affine, "
        "or for wide fields with distortion projective or polynomial (see --degree) "
        "(default: %(default)s)",
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


def _build_parser():
    parser = argparse.ArgumentParser(
        prog=_PROG,
        description="Register (align) astronomical images by matching star triangles. "
        "Inputs are FITS images; outputs are FITS images written as CCDData, "
        "with mask and uncertainty when the inputs have them.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    reg_opts = _registration_options()
    _add_register_command(sub, reg_opts)
    _add_batch_command(sub, reg_opts)
    _add_demo_command(sub)
    return parser


#: Each subcommand's line in ``astroalign-nd --help`` and its own --help description.
_COMMANDS = {
    "register": (
        "register SOURCE onto the pixel grid of TARGET",
        "Register the SOURCE image onto the pixel grid of the TARGET image and "
        "write the aligned image to OUT."),
    "batch": (
        "register several images onto one target",
        "Register each SOURCE onto TARGET, writing DIR/<name>_aligned.fits for "
        "each, and print each frame's line as soon as it is done. Give the target with "
        "-r/--reference (sources first, as in register and in the Python API "
        "register_batch(sources, target)); without -r, the first image is the target (the "
        "older form 'batch TARGET SOURCES...'). A frame that fails is reported and the "
        "others go on; the exit code is 1 if any frame failed."),
    "demo": (
        "simulate a pair of star fields, register them and compare with the truth",
        "Simulate a 512x512 star-field pair related by a known similarity "
        "transform (rotation 17 deg, scale 1.05, shift (12.3, -7.7) px), write "
        "DIR/source.fits and DIR/target.fits, register the source onto the target, write "
        "DIR/aligned.fits and report the error of the recovered transform."),
}


def _add_command(sub, name, func, parents=()):
    """The subparser of the subcommand ``name``, which ``main`` runs through ``func``."""
    help_line, description = _COMMANDS[name]
    p = sub.add_parser(name, parents=list(parents), help=help_line, description=description)
    p.set_defaults(func=func)
    return p


def _add_register_command(sub, reg_opts):
    p = _add_command(sub, "register", _cmd_register, [reg_opts])
    p.add_argument("source", metavar="SOURCE",
                   help="image to be transformed (FITS, or JPEG/PNG/TIFF)")
    p.add_argument("target", metavar="TARGET", help="image that defines the output grid")
    p.add_argument("-o", "--output", required=True, metavar="OUT.fits",
                   help="FITS file to write the aligned image to")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--plot", metavar="PLOT.png", default=None,
                   help="also write a diagnostic figure (matched stars, invariants, residuals, "
                   "difference image; needs matplotlib)")


def _add_batch_command(sub, reg_opts):
    p = _add_command(sub, "batch", _cmd_batch, [reg_opts])
    p.add_argument("images", metavar="SOURCES", nargs="+",
                   help="images to be transformed (FITS, or JPEG/PNG/TIFF); without "
                   "-r/--reference, the first one is the target")
    p.add_argument("-r", "--reference", metavar="TARGET", default=None,
                   help="image that defines the output grid")
    p.add_argument("--output-dir", required=True, metavar="DIR",
                   help="folder for the aligned images (created if needed)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--skip-existing", action="store_true",
                   help="resume: keep complete outputs already in DIR and report those frames "
                   "as skipped")
    p.add_argument("--canvas", choices=("reference", "union"), default="reference",
                   help="output grid: the reference's (default), or 'union', a grid holding "
                   "every frame (for dithered and mosaic sets)")
    p.add_argument("--summary", metavar="FILE.ecsv", default=None,
                   help="write one row per frame (name, status, matches, RMS, false alarm, "
                   "seconds, error) to this ECSV (or .csv) table")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="run the frames in N local worker processes (default: one after the "
                   "other in this process)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run the frames on this dask.distributed scheduler "
                   "(e.g. tcp://host:8786)")
    p.add_argument("--progress", dest="progress", action="store_true", default=None,
                   help="show a progress bar (default: when standard error is a terminal)")
    p.add_argument("--no-progress", dest="progress", action="store_false",
                   help="never show a progress bar")


def _add_demo_command(sub):
    p = _add_command(sub, "demo", _cmd_demo)
    p.add_argument("--output-dir", required=True, metavar="DIR",
                   help="folder for source.fits, target.fits and aligned.fits "
                   "(created if needed)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")


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


def _check_writable(path, overwrite):
    """Refuse, before any work, a path that cannot take the output."""
    from astroalign_nd.io.write import check_output_path

    try:
        check_output_path(path, overwrite)
    except FileExistsError:
        raise _CLIError(f"output file {path!r} already exists; pass --overwrite to replace "
                        "it.") from None


def _check_output_dir(path):
    from astroalign_nd.io.write import _check_writable_dir

    if os.path.exists(path) and not os.path.isdir(path):
        raise _CLIError(f"--output-dir {path!r} is a file, not a folder.")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as exc:
        raise _CLIError(f"cannot create output folder {path!r}: {exc.strerror or exc}.") from None
    _check_writable_dir(path)


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
    from astroalign_nd.io.write import write_ccddata

    _check_writable(args.output, args.overwrite)
    if args.plot:  # before the work: matplotlib missing or PLOT existing stops here
        from astroalign_nd.visualization import _check_plot_path, save_diagnostic_figure

        _check_plot_path(args.plot, args.overwrite)
    aligned = astroalign_nd.register(_check_input(args.source), _check_input(args.target),
                                     unit=args.unit, **_registration_kwargs(args))
    write_ccddata(aligned, args.output, overwrite=args.overwrite, hdu_flags="FLAGS")
    q = aligned.meta
    print(f"{_describe(astroalign_nd.transform_from_header(q))}; {q['AATNMAT']} matched "
          f"stars, RMS {q['AATRMS']:.3f} px")
    print(f"wrote {args.output}")
    if args.plot:
        print("wrote " + save_diagnostic_figure(args.plot, args.source, args.target, aligned,
                                                overwrite=args.overwrite,
                                                **_registration_kwargs(args)))
    return 0


def _frame_line(f):
    if f.status == "failed":
        return f"{f.name}: FAILED ({f.error})"
    q = f.quality or {}
    fig = []
    if "n_matches" in q:
        fig.append(f"{q['n_matches']} stars")
    if "rms" in q:
        fig.append(f"RMS {q['rms']:.3f} px")
    if "log10_false_alarm" in q:
        fig.append(f"log10 FA {q['log10_false_alarm']:.1f}")
    what = "ok" if f.status == "registered" else "skipped (complete output there)"
    return f"{f.name}: {what} -> {f.output} ({', '.join(fig)}; {f.seconds:.1f} s)"


def _batch_frames(args):
    """``(target, sources)`` of ``batch``, from -r/--reference or the older form."""
    if args.reference is not None:
        target, sources = args.reference, list(args.images)
    else:
        if len(args.images) < 2:
            raise _CLIError("give the target with -r/--reference TARGET, or as the first of "
                            "at least two images ('batch TARGET SOURCES...').")
        target, sources = args.images[0], list(args.images[1:])
    _check_input(target)
    for src in sources:
        _check_input(src)
    return target, sources


def _check_batch_options(args):
    """Refuse, before any work, options that cannot run or outputs that cannot be written."""
    if args.workers < 0:
        raise _CLIError(f"--workers must be 0 or more; got {args.workers}.")
    if args.scheduler and args.workers:
        raise _CLIError("give --workers (local processes) or --scheduler (a dask.distributed "
                        "cluster), not both.")
    _check_output_dir(args.output_dir)
    if args.summary is not None:
        from astroalign_nd.io.write import check_output_path

        try:
            check_output_path(args.summary, args.overwrite or args.skip_existing,
                              extensions=(".ecsv", ".csv"))
        except FileExistsError:
            raise _CLIError(f"summary file {args.summary!r} already exists; pass --overwrite "
                            "(or --skip-existing) to replace it.") from None


def _dask_client_class():
    try:
        from dask.distributed import Client
    except ImportError:
        raise _CLIError("--scheduler needs dask.distributed: "
                        "pip install 'astroalign_nd[dask]'") from None
    return Client


def _frame_reporter(n, bar):
    """The batch's callback: print each frame's line as it finishes (above the bar, if any)."""
    done = []

    def report(f):
        # Printed as each frame finishes; a night's log is useful while it runs.
        done.append(f)
        line = f"[{len(done)}/{n}] {_frame_line(f)}"
        if bar is not None:
            bar.write(line, file=sys.stdout)
            sys.stdout.flush()
            bar.update(1)
        else:
            print(line, flush=True)

    return report


def _write_summary(result, path):
    """The per-frame table of a batch, as ECSV (or CSV by the extension)."""
    from astroalign_nd.io.write import atomic_write

    fmt = "ascii.ecsv" if path.lower().endswith(".ecsv") else "ascii.csv"
    with atomic_write(path, overwrite=True) as tmp:
        result.to_table().write(tmp, format=fmt, overwrite=True)
    print(f"wrote {path}")


def _cmd_batch(args):
    import astroalign_nd

    target, sources = _batch_frames(args)
    _check_batch_options(args)
    progress = args.progress if args.progress is not None else sys.stderr.isatty()
    client = None
    client_class = _dask_client_class() if args.scheduler else None

    n = len(sources)
    if args.canvas == "union":
        print(f"union canvas: finding the {n} transforms first, then resampling", flush=True)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=n, unit="frame", file=sys.stderr)
    try:
        if args.scheduler:
            client = client_class(args.scheduler)
        result = astroalign_nd.register_batch(
            sources, target, output_dir=args.output_dir, overwrite=args.overwrite,
            skip_existing=args.skip_existing, canvas=args.canvas, client=client,
            workers=args.workers or None, callback=_frame_reporter(n, bar), unit=args.unit,
            **_registration_kwargs(args))
    finally:
        if bar is not None:
            bar.close()
        if client is not None:
            client.close()
    if args.canvas == "union":
        ny, nx = result.canvas_shape
        print(f"canvas: {nx}x{ny} px, pixel (0, 0) at reference pixel "
              f"{tuple(int(v) for v in result.canvas_offset)}")
    print(result.summary())
    if args.summary is not None:
        _write_summary(result, args.summary)
    return 1 if result.failed else 0


def _cmd_demo(args):
    import astropy.units as u
    from astropy.nddata import CCDData

    import astroalign_nd
    from astroalign_nd.io.write import write_ccddata
    from astroalign_nd.simulate import simulate_pair

    out_dir = args.output_dir
    paths = {name: os.path.join(out_dir, f"{name}.fits")
             for name in ("source", "target", "aligned")}
    _check_output_dir(out_dir)
    for path in paths.values():
        _check_writable(path, args.overwrite)

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
    write_ccddata(source, paths["source"], overwrite=args.overwrite)
    write_ccddata(target, paths["target"], overwrite=args.overwrite)

    aligned = astroalign_nd.register(source, target)
    write_ccddata(aligned, paths["aligned"], overwrite=args.overwrite)

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
    print(f"{_PROG}: error: {message}", file=sys.stderr)
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
            print(f"{_PROG} {version('astroalign_nd')}")
        except PackageNotFoundError:
            print(f"{_PROG} (version unknown: package not installed)")
        return 0
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2

    try:
        errors = _expected_errors()
    except ImportError as exc:
        return _error(f"could not import astroalign_nd: {exc}")
    import warnings

    def one_line_warning(message, category, filename, lineno, file=None, line=None):
        print(f"{_PROG}: warning: {message}", file=sys.stderr)

    old_showwarning = warnings.showwarning
    warnings.showwarning = one_line_warning
    try:
        return args.func(args)
    except errors as exc:
        return _error(str(exc) or type(exc).__name__)
    except MemoryError as exc:
        return _error(f"out of memory{': ' + str(exc) if str(exc) else ''}; try a smaller "
                      "--max-sources or --n-sources, --bin-factor, or fewer --workers.")
    except KeyboardInterrupt:
        return _error("interrupted.")
    except Exception as exc:  # noqa: BLE001 - never a traceback on the command line
        return _error(f"{type(exc).__name__}: {exc}")
    finally:
        warnings.showwarning = old_showwarning


if __name__ == "__main__":
    sys.exit(main())
