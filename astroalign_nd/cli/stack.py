# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ``stack`` command: register images onto a reference and combine them."""

import os
import sys
import warnings

from .errors import _PROG, EXIT_FRAMES_FAILED, EXIT_REFUSED, _CLIError, cli_words
from .options import (_add_output, _add_progress, _add_stack_options, _check_input,
                      _check_output_dir, _check_writable, _command_parser, _registration_kwargs,
                      _stack_kwargs)

__all__ = []

HELP = "register images onto a reference and combine them"

DESCRIPTION = """
Register each image onto the reference (-r, default the first image) and combine them into
OUT.fits: sky levels normalised, outliers (cosmic rays, satellite trails) clipped, weighted by
their uncertainty. The frames are assumed calibrated (bias, dark, flat). The header lists every
frame combined and every frame left out, and why. Interrupted (Ctrl-C, SIGTERM), it writes the
partial stack of the frames registered so far (a HISTORY line says so). Exit code: 0 success, 1
some frames left out, 2 usage error, 3 no frame could be registered (or the reference was
refused)."""


def add_parser(sub, reg_opts):
    """Add the ``stack`` subcommand to the subparsers ``sub``."""
    p = _command_parser(sub, "stack", _cmd_stack, HELP, DESCRIPTION, [reg_opts])
    p.add_argument("images", metavar="IMAGES", nargs="+", help="FITS images to stack")
    p.add_argument("-r", "--reference", metavar="REF", default=None,
                   help="the image whose grid the stack is on (default: the first image)")
    _add_output(p, "the stack")
    p.add_argument("--aligned-dir", metavar="DIR", default=None,
                   help="keep the registered frames in DIR (default: a temporary folder)")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="register in N local worker processes")
    _add_progress(p)
    _add_stack_options(p, "stack")
    return p


def _cmd_stack(args):
    from astroalign_nd import AstroalignError
    from astroalign_nd.config import OPTIONS, check_option
    from astroalign_nd.stacking import StackConfig, stack

    images = [_check_input(p) for p in args.images]
    reference = _check_input(args.reference) if args.reference else None
    _check_writable(args.output, args.overwrite, inputs=images + [reference or images[0]])
    if args.aligned_dir is not None:
        _check_output_dir(args.aligned_dir, "--aligned-dir")
    if args.workers < 0:
        raise _CLIError(f"--workers must be 0 or more; got {args.workers}.")
    if not args.memory_limit > 0:
        raise _CLIError(f"--memory-limit must be a number of MB > 0; got {args.memory_limit:g}.")
    progress = args.progress if args.progress is not None else sys.stderr.isatty()
    stack_kwargs, reg_kwargs = _stack_kwargs(args, "stack"), _registration_kwargs(args)
    # A bad option is the one line of the run: checked before the banner.
    StackConfig.from_keywords("stack", dict(stack_kwargs))
    for name, value in reg_kwargs.items():
        if name in OPTIONS:
            check_option(name, value)
    ref_name = os.path.basename(reference or images[0])
    n = len([p for p in images if p != (reference or images[0])])
    print(f"registering {n} frame{'' if n == 1 else 's'} onto {ref_name}, then combining",
          flush=True)
    try:
        with warnings.catch_warnings():
            # Each frame left out is printed below, from the header ("LEFT OUT ...").
            warnings.filterwarnings("ignore", message=".* was left out of the stack: ")
            ccd = stack(images, reference, output=args.output, overwrite=args.overwrite,
                        aligned_dir=args.aligned_dir, workers=args.workers or None,
                        unit=args.unit, progress=progress, callback=_frame_reporter(n),
                        **stack_kwargs, **reg_kwargs)
    except AstroalignError as exc:
        print(f"{_PROG}: registration refused: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM: the frames registered so far
        partial = getattr(exc, "partial_result", None)
        if partial is None:
            print("stopped before any frame but the reference was registered, or while "
                  "combining: nothing written", flush=True)
        else:
            _report(partial, args.output)
        raise
    return _report(ccd, args.output)


def _frame_reporter(n):
    """The stack's callback: each frame's line as its registration ends."""
    from tqdm import tqdm

    done = []

    def report(f):
        done.append(f)
        if f.status == "failed":
            what = f"FAILED ({cli_words(f.error or '')})"
        else:
            q = f.quality or {}
            fig = [f"{q['n_matches']} stars"] if "n_matches" in q else []
            fig += [f"RMS {q['rms']:.3f} px"] if "rms" in q else []
            what = f"registered ({', '.join(fig + [f'{f.seconds:.1f} s'])})"
        # Above the progress bar, if there is one; at once, so a long stack is not silent.
        tqdm.write(f"[{len(done)}/{n}] {f.name}: {what}", file=sys.stdout)
        sys.stdout.flush()

    return report


def _report(ccd, output):
    """Each frame stacked and left out, and the totals, from the stack's header."""
    h = ccd.meta
    for k in range(1, h["NCOMBINE"] + 1):
        if f"IMCMB{k:03d}" in h:
            print(f"stacked {h[f'IMCMB{k:03d}']}")
    for k in range(1, h["NREJECT"] + 1):
        if f"AAREJ{k:03d}" in h:
            print(f"LEFT OUT {cli_words(h[f'AAREJ{k:03d}'])}")
    partial = [line for line in h.get("HISTORY", []) if line.startswith("partial stack")]
    for line in partial:
        print(line)
    print(f"{'partial stack: ' if partial else ''}{h['NCOMBINE']} frames combined, "
          f"{h['NREJECT']} left out; {int(ccd.mask.sum())} px masked (no frame reaches); "
          f"wrote {output}", flush=True)
    return EXIT_FRAMES_FAILED if h["NREJECT"] else 0
