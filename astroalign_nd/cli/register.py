# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ``register`` command: one image onto the pixel grid of another."""

from .errors import HelpFormatter, _CLIError, exit_codes_text
from .options import _check_input, _check_writable, _describe, _registration_kwargs

__all__ = []

HELP = "register SOURCE onto the pixel grid of TARGET"

DESCRIPTION = ("Register the SOURCE image onto the pixel grid of the TARGET image and "
               "write the aligned image to OUT.")


def add_parser(sub, reg_opts):
    """Add the ``register`` subcommand to the subparsers ``sub``."""
    p = sub.add_parser("register", parents=[reg_opts], help=HELP, description=DESCRIPTION,
                       epilog=exit_codes_text(), formatter_class=HelpFormatter)
    p.set_defaults(func=_cmd_register)
    p.add_argument("source", metavar="SOURCE",
                   help="image to be transformed (FITS, or JPEG/PNG/TIFF)")
    p.add_argument("target", metavar="TARGET", help="image that defines the output grid")
    p.add_argument("-o", "--output", required=True, metavar="OUT.fits",
                   help="FITS file to write the aligned image to")
    p.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    p.add_argument("--plot", metavar="PLOT.png", default=None,
                   help="also write a diagnostic figure (matched stars, invariants, residuals, "
                   "difference image; needs matplotlib)")
    return p


def _cmd_register(args):
    import astroalign_nd
    from astroalign_nd.io import write_output
    from astroalign_nd.registration import register_and_match

    _check_writable(args.output, args.overwrite, inputs=(args.source, args.target))
    if args.plot:  # before the work: matplotlib missing or PLOT existing stops here
        from astroalign_nd.io.write import check_not_input
        from astroalign_nd.visualization import check_plot_path, save_diagnostic_figure

        try:
            check_not_input(args.plot, (args.source, args.target, args.output))
        except ValueError as exc:
            raise _CLIError(str(exc)) from None
        check_plot_path(args.plot, args.overwrite)
    kwargs = _registration_kwargs(args)
    aligned, match = register_and_match(_check_input(args.source), _check_input(args.target),
                                        unit=args.unit, **kwargs)
    write_output(aligned, args.output, overwrite=args.overwrite)
    q = aligned.meta
    print(f"{_describe(astroalign_nd.transform_from_header(q))}; {q['AATNMAT']} matched "
          f"stars, RMS {q['AATRMS']:.3f} px")
    print(f"wrote {args.output}")
    if args.plot:
        # The match just found: the figure does not search again (nor warn twice).
        points = (match.source_points, match.target_points)
        print("wrote " + save_diagnostic_figure(args.plot, args.source, args.target, aligned,
                                                overwrite=args.overwrite, hdu=kwargs["hdu"],
                                                transform=match.transform, points=points))
    return 0
