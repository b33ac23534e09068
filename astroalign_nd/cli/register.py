# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ``register`` command: one image onto the pixel grid of another."""

from .errors import _CLIError
from .options import (_add_output, _check_input, _check_writable, _command_parser, _describe,
                      _registration_kwargs)

__all__ = []

HELP = "register SOURCE onto the pixel grid of TARGET"

DESCRIPTION = """
Register the SOURCE image onto the pixel grid of the TARGET image and write the aligned image
to OUT."""


def add_parser(sub, reg_opts):
    """Add the ``register`` subcommand to the subparsers ``sub``."""
    p = _command_parser(sub, "register", _cmd_register, HELP, DESCRIPTION, [reg_opts])
    p.add_argument("source", metavar="SOURCE",
                   help="image to be transformed (FITS, or JPEG/PNG/TIFF)")
    p.add_argument("target", metavar="TARGET", help="image that defines the output grid")
    _add_output(p, "FITS file to write the aligned image to")
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
