# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ``stack`` command: register images onto a reference and combine them."""

import os
import sys
import warnings

from .errors import (_PROG, EXIT_FRAMES_FAILED, EXIT_REFUSED, HelpFormatter, _CLIError, cli_words,
                     exit_codes_text)
from .options import (_add_sky_options, _check_input, _check_writable, _none,
                      _registration_kwargs)

__all__ = []

HELP = "register images onto a reference and combine them"

DESCRIPTION = (
    "Register each image onto the reference (-r, default the first image) and combine "
    "them into OUT.fits: sky levels normalised, outliers (cosmic rays, satellite trails) "
    "clipped, weighted by their uncertainty. The frames are assumed calibrated (bias, dark, "
    "flat). The header lists every frame combined and every frame left out, and why. Exit "
    "code: 0 success, 1 some frames left out, 2 usage error, 3 no frame could be "
    "registered (or the reference was refused).")


def add_parser(sub, reg_opts):
    """Add the ``stack`` subcommand to the subparsers ``sub``."""
    p = sub.add_parser("stack", parents=[reg_opts], help=HELP,
                       description=DESCRIPTION, epilog=exit_codes_text(),
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
    _add_colour_options(p)
    return p


def _add_colour_options(p):
    g = p.add_argument_group(
        "colour (Bayer) frames",
        "raw frames of a one-shot-colour camera: registered on a grey version, then "
        "demosaiced and stacked per colour, or Bayer-drizzled (--drizzle); OUT is an RGB "
        "cube (3 planes)")
    g.add_argument("--bayer", metavar="PATTERN", type=str.upper, default=None,
                   choices=("AUTO", "RGGB", "BGGR", "GRBG", "GBRG"),
                   help="the frames' Bayer pattern (the colours of the first 2x2 cell), or "
                        "auto: each frame's BAYERPAT (XBAYROFF, YBAYROFF, ROWORDER)")
    g.add_argument("--demosaic", choices=("Menon2007", "Malvar2004", "bilinear"),
                   default="Menon2007", help="colour-demosaicing's method (default: "
                                             "%(default)s)")
    g.add_argument("--drizzle", type=float, default=None, metavar="SCALE",
                   help="Bayer drizzle at SCALE output pixels per input pixel (e.g. 2) "
                        "instead of demosaicing")
    g.add_argument("--pixfrac", type=float, default=0.7,
                   help="drizzle's drop size, a fraction of a pixel (default: %(default)s; "
                        "toward 1 for Bayer frames or few frames)")
    g.add_argument("--kernel", default="square",
                   help="drizzle's kernel (default: %(default)s)")


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
                        bayer=None if args.bayer is None else args.bayer.replace(
                            "AUTO", "auto"), demosaic=args.demosaic, drizzle=args.drizzle,
                        pixfrac=args.pixfrac, kernel=args.kernel,
                        **_registration_kwargs(args))
    except AstroalignError as exc:
        print(f"{_PROG}: registration refused: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    h = ccd.meta
    for k in range(1, h["NCOMBINE"] + 1):
        if f"IMCMB{k:03d}" in h:
            print(f"stacked {h[f'IMCMB{k:03d}']}")
    for k in range(1, h["NREJECT"] + 1):
        if f"AAREJ{k:03d}" in h:
            print(f"LEFT OUT {cli_words(h[f'AAREJ{k:03d}'])}")
    print(f"{h['NCOMBINE']} frames combined, {h['NREJECT']} left out; "
          f"{int(ccd.mask.sum())} px masked (no frame reaches); wrote {args.output}")
    return EXIT_FRAMES_FAILED if h["NREJECT"] else 0
