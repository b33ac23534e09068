# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ``watch`` command: live stacking of the FITS frames that appear in a folder."""

import contextlib
import os
import sys

from .errors import _PROG, EXIT_FRAMES_FAILED, EXIT_REFUSED, _CLIError, cli_words
from .options import (_add_output, _add_stack_options, _check_input, _check_writable,
                      _command_parser, _registration_kwargs, _stack_kwargs)

__all__ = []

HELP = "live stacking: stack the FITS frames that appear in a folder"

DESCRIPTION = """
Watch FOLDER (polling every --interval seconds) and add each new FITS frame, once completely
written, to a running stack on the reference's grid, with clipping against the running stack;
OUT.fits is rewritten atomically after each frame (a reader never sees part of a file). Stops
on Ctrl-C (exit 130), SIGTERM (143; Ctrl-Break on Windows), after --max-frames frames or
--timeout seconds without a new frame. Exit code 1 if some frames failed (they are listed, and
the watch goes on)."""


def add_parser(sub, reg_opts):
    """Add the ``watch`` subcommand to the subparsers ``sub``."""
    w = _command_parser(sub, "watch", _cmd_watch, HELP, DESCRIPTION, [reg_opts])
    w.add_argument("folder", metavar="FOLDER", help="folder to watch for new FITS frames")
    w.add_argument("-r", "--reference", metavar="REF", required=True,
                   help="reference image: the stack's grid and first frame")
    _add_output(w, "the running stack", flags=["--stack"])
    w.add_argument("--interval", type=float, default=2.0, help="seconds between polls (default 2)")
    w.add_argument("--max-frames", type=int, default=None, help="stop after N new frames")
    w.add_argument("--timeout", type=float, default=None,
                   help="stop after this many seconds without a new frame")
    _add_stack_options(w, "live")
    # The stack command's --clip none, as watch has always spelled it.
    w.add_argument("--no-clip", dest="clip", action="store_const", const="none",
                   help="no clipping against the running stack (--clip none)")
    return w


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
                callback=report, unit=args.unit, **_stack_kwargs(args, "live"), **kwargs)
    except AstroalignError as exc:  # the reference itself (no stars...)
        print(f"{_PROG}: registration refused: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except KeyboardInterrupt as exc:
        live = getattr(exc, "partial_result", None)
        if live is None:  # stopped while the reference was prepared
            print("stopped before the first stack was written", flush=True)
        else:
            print(f"stopped: {_totals(live)}; the stack is in {args.stack}", flush=True)
        raise
    print(f"{_totals(live)}; wrote {args.stack}")
    return EXIT_FRAMES_FAILED if live.rejected else 0


def _totals(live):
    """The frames stacked and failed: as the stack's NCOMBINE and NREJECT count them."""
    n = len(live.used)
    return f"{n} frame{'' if n == 1 else 's'} stacked, {len(live.rejected)} failed"
