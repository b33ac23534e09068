# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ``astroalign-nd`` command: its parser and entry point."""

import argparse
import contextlib
import sys
from .errors import (_PROG, HelpFormatter as _HelpFormatter, _error, _expected_errors, cli_words,
                     exit_code, exit_codes_text)
from .commands import _cmd_batch, _cmd_demo, _cmd_register, demo_description
from .match import add_match_command
from .options import _registration_options
from .stack import add_stack_commands

__all__ = ['main', 'build_parser']


def build_parser():
    """
    The ``astroalign-nd`` argument parser, with every subcommand and option.

    The documentation's command-line reference is generated from it.

    Returns
    -------
    parser : `argparse.ArgumentParser`
    """
    parser = argparse.ArgumentParser(
        prog=_PROG, formatter_class=_HelpFormatter, epilog=exit_codes_text(),
        description="Register (align) astronomical images by matching star triangles. "
        "Inputs are FITS images; outputs are FITS images written as CCDData, "
        "with mask and uncertainty when the inputs have them.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    reg_opts = _registration_options()
    _add_register_command(sub, reg_opts)
    _add_batch_command(sub, reg_opts)
    add_stack_commands(sub, reg_opts)
    _add_demo_command(sub)
    add_match_command(sub)
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
        "each and the reference itself on the same grid as DIR/<target name>_reference.fits "
        "(to stack it with the rest), and print each frame's line as soon as it is done. "
        "Give the target with -r/--reference (sources first, as in register and in the Python API "
        "register_batch(sources, target)); without -r, the first image is the target (the "
        "older form 'batch TARGET SOURCES...'). A frame that fails is reported and the "
        "others go on; the exit code is 1 if any frame failed."),
    "demo": (
        "simulate a pair of star fields, register them and compare with the truth",
        demo_description()),
}


def _add_command(sub, name, func, parents=()):
    """The subparser of the subcommand ``name``, which ``main`` runs through ``func``."""
    help_line, description = _COMMANDS[name]
    p = sub.add_parser(name, parents=list(parents), help=help_line, description=description,
                       epilog=exit_codes_text(), formatter_class=_HelpFormatter)
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
    p.add_argument("--progress", dest="progress", action="store_true", default=None,
                   help="show a progress bar (default: when standard error is a terminal)")
    p.add_argument("--no-progress", dest="progress", action="store_false",
                   help="never show a progress bar")


def _add_demo_command(sub):
    p = _add_command(sub, "demo", _cmd_demo)
    p.add_argument("--output-dir", required=True, metavar="DIR",
                   help="folder for source.fits, target.fits and aligned.fits "
                   "(created if needed)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace existing files that an earlier demo did not write")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")


_SIGINT = 2  # signal.SIGINT, the same number on every platform


class _Terminated(KeyboardInterrupt):
    """
    SIGTERM, raised like Ctrl-C's KeyboardInterrupt: the same clean-up runs
    (workers stopped, temporary files removed, the partial summary written).
    """

    def __init__(self, signum):
        super().__init__(_signal_name(signum))
        self.signum = signum


def _signal_name(signum):
    import signal

    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


@contextlib.contextmanager
def _interrupt_signals():
    """
    SIGTERM (where the platform has it) raises `_Terminated`; the first
    SIGTERM or SIGINT only: a second one while the batch stops (within a few
    seconds) must not cut the clean-up short.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set in the main thread
        return
    fired = []

    def interrupt(signum, frame):
        if fired:
            return
        fired.append(signum)
        if signum == _SIGINT:
            raise KeyboardInterrupt(_signal_name(signum))
        raise _Terminated(signum)

    old = {}
    for name in ("SIGTERM", "SIGINT"):
        signum = getattr(signal, name, None)
        if signum is None:
            continue
        current = signal.getsignal(signum)
        # Keep an ignored SIGINT ignored (nohup, a background job) and a caller's own handler.
        if name == "SIGINT" and current is not signal.default_int_handler:
            continue
        if name == "SIGTERM" and current not in (signal.SIG_DFL, None):
            continue
        old[signum] = signal.signal(signum, interrupt)
    try:
        yield
    finally:
        for signum, handler in old.items():
            signal.signal(signum, handler)


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
        2 on a usage error (or any error other than these), 3 when the
        registration is refused (no trustworthy transform), 130 when
        interrupted (SIGINT, Ctrl-C) and 143 when terminated (SIGTERM);
        ``batch`` stops its workers and prints (and writes, with
        ``--summary``) what was done.  See :ref:`cli-exit-codes`.
    """
    parser = build_parser()
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
        print(f"{_PROG}: warning: {cli_words(str(message))}", file=sys.stderr)

    old_showwarning = warnings.showwarning
    warnings.showwarning = one_line_warning
    try:
        with _interrupt_signals():
            return args.func(args)
    except errors as exc:
        return _error(str(exc) or type(exc).__name__, exit_code(exc))
    except MemoryError as exc:
        return _error(f"out of memory{': ' + str(exc) if str(exc) else ''}; try a smaller "
                      "--max-sources or --n-sources, --bin-factor, or fewer --workers.")
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", _SIGINT)
        print(f"{_PROG}: interrupted ({_signal_name(signum)}).", file=sys.stderr)
        return 128 + signum  # the shell's convention: 130 for SIGINT, 143 for SIGTERM
    except Exception as exc:  # noqa: BLE001 - never a traceback on the command line
        return _error(f"{type(exc).__name__}: {exc}")
    finally:
        warnings.showwarning = old_showwarning
