# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ``batch`` command: several images onto one target, going on past failures."""

import dataclasses
import os
import sys
from .errors import _CLIError, cli_words
from .options import (_add_progress, _check_input, _check_output_dir, _command_parser,
                      _registration_kwargs)

__all__ = []

HELP = "register several images onto one target"

DESCRIPTION = """
Register each SOURCE onto TARGET, writing DIR/<name>_aligned.fits for each and the reference
itself on the same grid as DIR/<target name>_reference.fits (to stack it with the rest), and
print each frame's line as soon as it is done. Give the target with -r/--reference (sources
first, as in register and in the Python API register_batch(sources, target)); without -r, the
first image is the target (the older form 'batch TARGET SOURCES...'). A frame that fails is
reported and the others go on; the exit code is 1 if any frame failed."""


def add_parser(sub, reg_opts):
    """Add the ``batch`` subcommand to the subparsers ``sub``."""
    p = _command_parser(sub, "batch", _cmd_batch, HELP, DESCRIPTION, [reg_opts])
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
    p.add_argument("--global", dest="solve", action="store_const", const="global",
                   default="pairwise",
                   help="solve every frame's transform together (solve_sequence): frames "
                   "linked to each other, one least-squares solution over all their stars; "
                   "for mosaics and long drifts")
    p.add_argument("--summary", metavar="FILE.ecsv", default=None,
                   help="write one row per frame (name, status, matches, RMS, false alarm, "
                   "shift, rotation, scale, seconds, error), the reference's first, to this "
                   "ECSV (or .csv) table")
    p.add_argument("--plot", metavar="DIR", default=None,
                   help="also write a diagnostic figure of each frame registered "
                   "(DIR/<name>_aligned.png: matched stars, invariants, residuals, "
                   "difference image; from the match found, no new search) and the night's "
                   "summary (DIR/night_summary.png: drift, rotation, RMS and matched stars "
                   "against frame), once the batch is done; needs matplotlib")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="run the frames in N local worker processes (default: one after the "
                   "other in this process)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run the frames on this dask.distributed scheduler "
                   "(e.g. tcp://host:8786)")
    _add_progress(p)

    return p


def _frame_line(f):
    if f.status == "failed":
        return f"{f.name}: FAILED ({cli_words(f.error or '')})"
    if f.status == "reference":
        return f"{f.name}: written -> {f.output}"
    q = f.quality or {}
    fig = []
    if "n_matches" in q:
        fig.append(f"{q['n_matches']} stars")
    if "rms" in q:
        fig.append(f"RMS {q['rms']:.3f} px")
    if "log10_false_alarm" in q:
        fig.append(f"log10 FA {q['log10_false_alarm']:.1f}")
    if "n_links" in q:  # solve='global'
        fig.append(f"{q['n_links']} links, predicted error {q['predicted_error']:.3f} px")
    what = "ok" if f.status == "registered" else "skipped (complete output there)"
    if not f.quality and f.status == "skipped":  # the reference, kept
        return f"{f.name}: {what} -> {f.output}"
    return f"{f.name}: {what} -> {f.output} ({', '.join(fig)}; {f.seconds:.1f} s)"


def _batch_frames(args):
    """``(target, sources)`` of ``batch``, from -r/--reference or the older form."""
    from ..io.write import same_file

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
    kept = [src for src in sources if not same_file(src, target)]
    if len(kept) < len(sources):
        # Registered onto itself it would be written twice (as _aligned and _reference), and
        # counted twice by whatever stacks the folder.
        print(f"the reference {os.path.basename(target)} is among the images: it is written "
              "once, as the reference", flush=True)
    return target, kept


def _check_batch_options(args, target, sources):
    """
    Refuse, before any work, options that cannot run or outputs that cannot be written;
    one error up front when outputs of an earlier run are there (rather than one failure
    per frame), naming the two ways on.
    """
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
    if args.overwrite or args.skip_existing:
        return
    from astroalign_nd.batch import plan_outputs
    from astroalign_nd.batch.reference import reference_output

    outputs, _ = plan_outputs(sources, args.output_dir, protected=[target])
    there = [p for p in outputs + [reference_output(target, args.output_dir)]
             if os.path.lexists(p)]
    if there:
        raise _CLIError(f"{len(there)} of the outputs exist in {args.output_dir} (e.g. "
                        f"{os.path.basename(there[0])}): pass --skip-existing to register only "
                        "the frames without one, or --overwrite to replace them.")


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


def _write_summary(result, path, reference=None):
    """
    The per-frame table of a batch, the reference's row first (when it was
    written), as ECSV (or CSV by the extension).
    """
    from astroalign_nd.io.write import write_table

    fmt = "ascii.ecsv" if path.lower().endswith(".ecsv") else "ascii.csv"
    table = result.to_table()
    if reference is not None:  # its row first
        from astropy.table import vstack

        from astroalign_nd.batch import BatchResult

        if reference.ok:  # written, or kept (--skip-existing): the row says what it is
            reference = dataclasses.replace(reference, status="reference")
        ref = BatchResult([reference], canvas_shape=result.canvas_shape,
                          canvas_offset=result.canvas_offset).to_table()
        table = vstack([ref, table], metadata_conflicts="silent")
        table.meta.update(result.to_table().meta)
    write_table(table, path, format=fmt, overwrite=True)
    print(f"wrote {path}")


def _interrupted_summary(result, exc):
    """
    The summary of an interrupted batch: the frames not done in one line
    (the --summary table lists each), the frames that failed one per line.
    """
    not_done = [f for f in result.failed if (f.error or "").startswith("Interrupted: ")]
    failed = [f for f in result.failed if f not in not_done]
    why = str(exc) or type(exc).__name__
    line = f"{len(result.succeeded)} of {len(result.frames)} frames registered"
    if result.skipped:
        line += f", {len(result.skipped)} skipped (complete output already there)"
    if failed:
        line += f", {len(failed)} failed"
    line += (f"; interrupted ({why}): {len(not_done)} not done. Run the same command with "
             "--skip-existing to finish.")
    return cli_words("\n".join([line] + [f"  FAILED {f.name}: {f.error}" for f in failed]))


def _cmd_batch(args):
    import astroalign_nd

    target, sources = _batch_frames(args)
    _check_batch_options(args, target, sources)
    plots = _check_plot_dir(args, target, sources) if args.plot is not None else None
    progress = args.progress if args.progress is not None else sys.stderr.isatty()
    client = None
    client_class = None
    if args.scheduler:
        try:
            from dask.distributed import Client as client_class
        except ImportError:
            raise _CLIError("--scheduler needs dask.distributed: "
                            "pip install 'astroalign_nd[dask]'") from None

    n = len(sources)
    if args.canvas == "union":
        print(f"union canvas: finding the {n} transforms first, then resampling", flush=True)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=n, unit="frame", file=sys.stderr)
    interrupted = None
    try:
        if args.scheduler:
            client = client_class(args.scheduler)
        result = astroalign_nd.register_batch(
            sources, target, output_dir=args.output_dir, overwrite=args.overwrite,
            skip_existing=args.skip_existing, canvas=args.canvas, client=client,
            workers=args.workers or None, callback=_frame_reporter(n, bar), unit=args.unit,
            solve=args.solve, **_registration_kwargs(args))
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM: the workers are stopped
        result = getattr(exc, "partial_result", None)
        if result is None:
            raise
        interrupted = exc
    finally:
        if bar is not None:
            bar.close()
        if client is not None:
            client.close()
    if interrupted is not None:  # what was done, in the log and the summary; then the exit code
        print(_interrupted_summary(result, interrupted))
        if args.summary is not None:
            _write_summary(result, args.summary)
        raise interrupted
    if args.canvas == "union":
        ny, nx = result.canvas_shape
        print(f"canvas: {nx}x{ny} px, pixel (0, 0) at reference pixel "
              f"{tuple(int(v) for v in result.canvas_offset)}")
    reference = _write_reference(args, target, result)
    print(cli_words(result.summary()))
    if args.summary is not None:
        _write_summary(result, args.summary, reference)
    if args.plot is not None:
        _batch_figures(args, target, result, plots)
    return 1 if result.failed or reference.status == "failed" else 0


def _write_reference(args, target, result):
    """The reference on the output grid, next to the frames (a line, and the summary's row)."""
    from astroalign_nd.batch import write_reference

    kwargs = _registration_kwargs(args)
    options = dict(hdu=kwargs["hdu"], unit=args.unit)
    if "fill_value" in kwargs:
        options["fill_value"] = kwargs["fill_value"]
    reference = write_reference(target, result, args.output_dir, overwrite=args.overwrite,
                                skip_existing=args.skip_existing, **options)
    print(f"reference {_frame_line(reference)}", flush=True)
    return reference


#: The night summary figure of ``batch --plot DIR``.
_NIGHT_FIGURE = "night_summary.png"


def _check_plot_dir(args, target, sources):
    """
    Before any work: matplotlib there, DIR usable, and no figure to be
    written already there (unless --overwrite; --skip-existing keeps them).
    Returns the figure of each planned output, by output path.
    """
    from astroalign_nd.batch import plan_outputs
    from astroalign_nd.visualization import check_plot_path

    _check_output_dir(args.plot, "--plot")
    outputs, _ = plan_outputs(sources, args.output_dir, protected=[target])
    plots = {}  # each output's figure: its name, ending in .png
    for out in outputs:
        stem = os.path.basename(out)
        for ext in (".fits.gz", ".fits", ".fit", ".fts"):
            if stem.lower().endswith(ext):
                stem = stem[: -len(ext)]
                break
        plots[out] = os.path.join(args.plot, stem + ".png")
    for path in [*plots.values(), os.path.join(args.plot, _NIGHT_FIGURE)]:
        if os.path.exists(path) and args.skip_existing and not args.overwrite:
            continue
        try:
            check_plot_path(path, args.overwrite)
        except FileExistsError:
            raise _CLIError(f"figure {path!r} already exists; pass --overwrite to replace "
                            "it (or --skip-existing to keep it).") from None
    return plots


def _batch_figures(args, target, result, plots):
    """A figure for each frame registered in this run (no new search), and the night's."""
    from astroalign_nd.batch.frame import shifted_transform
    from astroalign_nd.visualization import save_diagnostic_figure, save_night_figure

    hdu = _registration_kwargs(args)["hdu"]
    for f in result.frames:
        path = plots.get(f.output)
        if f.status != "registered" or f.points is None or path is None:
            continue
        # The figure compares on the reference's grid: a union canvas's frame is
        # resampled again there (from the transform found, not a new search).
        union = args.canvas == "union"
        transform = shifted_transform(f.transform, result.canvas_offset, sign=+1) if union \
            else f.transform
        aligned = None if union else f.output
        if isinstance(getattr(transform, "meta", None), dict) and f.quality:
            transform.meta.setdefault("quality", f.quality)  # for the figure's text
        try:
            save_diagnostic_figure(path, f.source, target, aligned, overwrite=True, hdu=hdu,
                                   transform=transform, points=f.points)
        except (ValueError, TypeError, OSError) as exc:
            print(f"{f.name}: no figure ({cli_words(str(exc))})")
            continue
        print(f"wrote {path}")
    night = os.path.join(args.plot, _NIGHT_FIGURE)
    print("wrote " + save_night_figure(night, result, overwrite=True))
