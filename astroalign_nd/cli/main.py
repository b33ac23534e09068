# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The ``astroalign-nd`` command: the top-level parser, the dispatch to each command's
module, and the errors, signals and exit codes every command shares.
"""

import argparse
import contextlib
import sys
from .errors import (_PROG, _USER_ERRORS, HelpFormatter as _HelpFormatter, _CLIError, _error,
                     cli_words, exit_code, exit_codes_text)
from . import batch, demo, match, register, stack, watch
from .options import _empty_folders_removed, _registration_options

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
    # One module per command, each with its parser and its body; in --help's order.
    for command in (register, batch, stack, watch):
        command.add_parser(sub, reg_opts)
    demo.add_parser(sub)
    match.add_parser(sub)
    return parser


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
        # The exception classes reported without a traceback.
        from astroalign_nd import AstroalignError

        errors = (AstroalignError, _CLIError) + _USER_ERRORS
    except ImportError as exc:
        return _error(f"could not import astroalign_nd: {exc}")
    import warnings

    def one_line_warning(message, category, filename, lineno, file=None, line=None):
        print(f"{_PROG}: warning: {cli_words(str(message))}", file=sys.stderr)

    old_showwarning = warnings.showwarning
    warnings.showwarning = one_line_warning
    try:
        with _interrupt_signals(), _empty_folders_removed():
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
