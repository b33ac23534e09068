# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ``stack`` and ``watch`` commands: register and combine; live stacking of a folder."""

import contextlib
import os
import sys
import warnings

from .commands import _check_input, _check_writable
from .errors import _PROG, HelpFormatter, _CLIError, cli_words, exit_codes_text
from .options import _registration_kwargs

__all__ = []

#: Exit codes of ``stack`` and ``watch`` besides 0 (success) and 2 (usage error).
_SOME_FAILED, _REFUSED = 1, 3

_STACK_HELP = (
    "register images onto a reference and combine them",
    "Register each image onto the reference (-r, default the first image) and combine "
    "them into OUT.fits: sky levels normalised, outliers (cosmic rays, satellite trails) "
    "clipped, weighted by their uncertainty. The frames are assumed calibrated (bias, dark, "
    "flat). The header lists every frame combined and every frame left out, and why. Exit "
    "code: 0 success, 1 some frames left out, 2 usage error, 3 no frame could be "
    "registered (or the reference was refused).")
_WATCH_HELP = (
    "live stacking: stack the FITS frames that appear in a folder",
    "Watch FOLDER (polling every --interval seconds) and add each new FITS frame, once "
    "completely written, to a running stack on the reference's grid, with clipping against "
    "the running stack; OUT.fits is rewritten atomically after each frame (a reader never "
    "sees part of a file). Stops on Ctrl-C (exit 130), SIGTERM (143; Ctrl-Break on "
    "Windows), after --max-frames frames or --timeout seconds without a new frame. Exit "
    "code 1 if some frames failed (they are listed, and the watch goes on).")


def _add_combine_options(p):
    g = p.add_argument_group("combination options", "as in astroalign_nd.stack")
    g.add_argument("--combine", choices=("average", "median", "sum"), default="average",
                   help="how the frames are combined (default: %(default)s)")
    g.add_argument("--clip", choices=("sigma", "minmax", "none"), default="sigma",
                   help="rejection before combining (default: %(default)s)")
    g.add_argument("--sigma", type=float, default=3.0,
                   help="sigma clipping's limit, both sides (default: %(default)s)")
    g.add_argument("--sigma-low", type=float, default=None, help="its low limit")
    g.add_argument("--sigma-high", type=float, default=None, help="its high limit")
    g.add_argument("--maxiters", type=int, default=3, help="sigma clipping rounds at most")
    g.add_argument("--nlow", type=int, default=1, help="minmax: lowest values dropped")
    g.add_argument("--nhigh", type=int, default=1, help="minmax: highest values dropped")
    _add_sky_options(g)
    g.add_argument("--weights", choices=("variance", "none"), default="variance",
                   help="frame weights: inverse median variance (default), or equal")
    g.add_argument("--memory-limit", type=float, default=512.0, metavar="MB",
                   help="working memory of the combination, MB (default: %(default)s)")


def _add_sky_options(g):
    g.add_argument("--normalize", choices=("offset", "scale", "none"), default="offset",
                   help="bring each frame's sky to the reference's (default: %(default)s)")
    g.add_argument("--gain", type=float, default=None,
                   help="electrons per count, for frames without an uncertainty")
    g.add_argument("--read-noise", type=float, default=None,
                   help="read noise in electrons, with --gain")


def add_stack_commands(sub, reg_opts):
    """The ``stack`` and ``watch`` subparsers."""
    p = sub.add_parser("stack", parents=[reg_opts], help=_STACK_HELP[0],
                       description=_STACK_HELP[1], epilog=exit_codes_text(),
                       formatter_class=HelpFormatter)
    p.set_defaults(func=_cmd_stack)
    p.add_argument("images", metavar="IMAGES", nargs="+", help="FITS images to stack")
    p.add_argument("-r", "--reference", metavar="REF", default=None,
                   help="the image whose grid the stack is on (default: the first image)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.fits", help="the stack")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--canvas", choices=("reference", "union"), default="reference",
                   help="the stack's grid: the reference's (default) or the union of frames")
    p.add_argument("--aligned-dir", metavar="DIR", default=None,
                   help="keep the registered frames in DIR (default: a temporary folder)")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="register in N local worker processes")
    p.add_argument("--progress", dest="progress", action="store_true", default=None,
                   help="show a progress bar (default: when standard error is a terminal)")
    p.add_argument("--no-progress", dest="progress", action="store_false",
                   help="never show a progress bar")
    _add_combine_options(p)
    w = sub.add_parser("watch", parents=[reg_opts], help=_WATCH_HELP[0],
                       description=_WATCH_HELP[1], epilog=exit_codes_text(),
                       formatter_class=HelpFormatter)
    w.set_defaults(func=_cmd_watch)
    w.add_argument("folder", metavar="FOLDER", help="folder to watch for new FITS frames")
    w.add_argument("-r", "--reference", metavar="REF", required=True,
                   help="reference image: the stack's grid and first frame")
    w.add_argument("--stack", required=True, metavar="OUT.fits", help="the running stack")
    w.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    w.add_argument("--interval", type=float, default=2.0, help="seconds between polls (default 2)")
    w.add_argument("--max-frames", type=int, default=None, help="stop after N new frames")
    w.add_argument("--timeout", type=float, default=None,
                   help="stop after this many seconds without a new frame")
    w.add_argument("--sigma", type=float, default=3.0,
                   help="clipping against the running stack, in sigma (default: %(default)s)")
    w.add_argument("--no-clip", action="store_true", help="no clipping")
    _add_sky_options(w)


def _none(value):
    return None if value == "none" else value


def _cmd_stack(args):
    from astroalign_nd import AstroalignError
    from astroalign_nd.stacking import stack

    images = [_check_input(p) for p in args.images]
    reference = _check_input(args.reference) if args.reference else None
    _check_writable(args.output, args.overwrite, inputs=images + [reference or images[0]])
    if args.workers < 0:
        raise _CLIError(f"--workers must be 0 or more; got {args.workers}.")
    if not args.memory_limit > 0:
        raise _CLIError(f"--memory-limit must be a number of MB > 0; got {args.memory_limit:g}.")
    progress = args.progress if args.progress is not None else sys.stderr.isatty()
    ref_name = os.path.basename(reference or images[0])
    n = len([p for p in images if p != (reference or images[0])])
    print(f"registering {n} frame{'' if n == 1 else 's'} onto {ref_name}, then combining",
          flush=True)
    try:
        with warnings.catch_warnings():
            # Each frame left out is printed below, from the header ("LEFT OUT ...").
            warnings.filterwarnings("ignore", message=".* was left out of the stack: ")
            ccd = stack(images, reference, method=args.combine, clip=_none(args.clip),
                        sigma=args.sigma, sigma_low=args.sigma_low, sigma_high=args.sigma_high,
                        maxiters=args.maxiters, nlow=args.nlow, nhigh=args.nhigh,
                        normalize=_none(args.normalize), weights=_none(args.weights),
                        gain=args.gain, read_noise=args.read_noise, canvas=args.canvas,
                        memory_limit=args.memory_limit * 1e6, output=args.output,
                        overwrite=args.overwrite, aligned_dir=args.aligned_dir,
                        workers=args.workers or None, unit=args.unit, progress=progress,
                        **_registration_kwargs(args))
    except AstroalignError as exc:
        print(f"{_PROG}: registration refused: {exc}", file=sys.stderr)
        return _REFUSED
    h = ccd.meta
    for k in range(1, h["NCOMBINE"] + 1):
        if f"IMCMB{k:03d}" in h:
            print(f"stacked {h[f'IMCMB{k:03d}']}")
    for k in range(1, h["NREJECT"] + 1):
        if f"AAREJ{k:03d}" in h:
            print(f"LEFT OUT {cli_words(h[f'AAREJ{k:03d}'])}")
    print(f"{h['NCOMBINE']} frames combined, {h['NREJECT']} left out; "
          f"{int(ccd.mask.sum())} px masked (no frame reaches); wrote {args.output}")
    return _SOME_FAILED if h["NREJECT"] else 0


class _Break(KeyboardInterrupt):
    """Ctrl-Break, ended as SIGTERM ends the command (exit 143): ``main`` reads ``signum``."""

    def __init__(self, signum):
        super().__init__("SIGTERM (Ctrl-Break)")
        self.signum = signum


@contextlib.contextmanager
def _break_signal():
    """Windows: Ctrl-Break (what a parent can send a child) stops the watch as SIGTERM does."""
    import signal
    import threading

    brk = getattr(signal, "SIGBREAK", None)
    if brk is None or threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        raise _Break(getattr(signal, "SIGTERM", 15))

    old = signal.signal(brk, stop)
    try:
        yield
    finally:
        signal.signal(brk, old)


def _cmd_watch(args):
    from astroalign_nd import AstroalignError
    from astroalign_nd.stacking import watch_folder

    reference = _check_input(args.reference)
    if not os.path.isdir(args.folder):
        raise _CLIError(f"FOLDER {args.folder!r} does not exist or is not a folder.")
    _check_writable(args.stack, args.overwrite, inputs=[reference])
    kwargs = _registration_kwargs(args)
    if not (args.interval > 0 and args.interval < float("inf")):
        raise _CLIError(f"--interval must be a number of seconds > 0; got {args.interval:g}.")
    if args.timeout is not None and not args.timeout >= 0:
        raise _CLIError(f"--timeout must be a number of seconds >= 0; got {args.timeout:g}.")
    if args.max_frames is not None and args.max_frames < 1:
        raise _CLIError(f"--max-frames must be 1 or more; got {args.max_frames}.")

    def report(path, error):
        if error:
            print(f"FAILED {os.path.basename(path)}: {cli_words(error)}", file=sys.stderr,
                  flush=True)
        else:
            print(f"added {os.path.basename(path)}", flush=True)

    print(f"watching {args.folder} every {args.interval:g} s; reference "
          f"{os.path.basename(os.fspath(reference))}; the stack goes to {args.stack} after "
          "each frame (Ctrl-C to stop)", flush=True)

    try:
        with _break_signal():
            live = watch_folder(
                args.folder, reference, args.stack, interval=args.interval,
                max_frames=args.max_frames, timeout=args.timeout, overwrite=args.overwrite,
                callback=report, sigma=None if args.no_clip else args.sigma,
                normalize=_none(args.normalize), gain=args.gain, read_noise=args.read_noise,
                unit=args.unit, **kwargs)
    except AstroalignError as exc:  # the reference itself (no stars...)
        print(f"{_PROG}: registration refused: {exc}", file=sys.stderr)
        return _REFUSED
    except KeyboardInterrupt:
        print(f"stopped; the stack is in {args.stack}", flush=True)
        raise
    n = len(live.used)
    print(f"{n} frame{'' if n == 1 else 's'} stacked, {len(live.rejected)} failed; wrote "
          f"{args.stack}")
    return _SOME_FAILED if live.rejected else 0
