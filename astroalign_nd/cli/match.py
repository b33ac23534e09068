# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ``match`` command: cross-match two star catalogs and write the table of pairs."""

import os
import sys

from ..config import RegistrationConfig
from ..matching import MatchingConfig
from ..options import cli_fields
from ..transforms import ModelConfig
from .errors import _CLIError
from .options import _add_fields, _add_output, _command_parser, _describe

__all__ = []

HELP = "cross-match two star catalogs: every star paired, written as a table"

DESCRIPTION = """
Find the transform from SOURCE to TARGET on their brightest stars, pair every star of SOURCE
with one of TARGET under it, refit the transform on all the pairs until they are stable, and
write the pairs to OUT (source_index and target_index: 0-based rows of the inputs; positions,
residual and chance probability). Catalogs are ECSV files, FITS tables or whitespace-separated
text columns (with a header line naming them, or col1, col2...). The position columns are found
by name (x/y, x_centroid/y_centroid, xcentroid/ycentroid, X_IMAGE/Y_IMAGE...) unless given; a
'flux' column, when there is one, picks the brightest stars for the search."""

#: Output formats by name ending (astropy.table formats).
FORMATS = {".ecsv": "ascii.ecsv", ".fits": "fits", ".fit": "fits", ".csv": "ascii.csv",
           ".txt": "ascii.commented_header", ".dat": "ascii.commented_header"}

#: The configs whose command-line options the search takes.
_CONFIGS = (ModelConfig, RegistrationConfig, MatchingConfig)


def add_parser(sub):
    """Add the ``match`` subcommand to the subparsers ``sub``."""
    p = _command_parser(sub, "match", _cmd_match, HELP, DESCRIPTION)
    p.add_argument("source", metavar="SOURCE", help="catalog whose stars are mapped")
    p.add_argument("target", metavar="TARGET", help="catalog they are mapped onto")
    _add_output(p, "table of the pairs to write: " + ", ".join(FORMATS), metavar="OUT.ecsv")
    cols = p.add_argument_group("catalog columns")
    cols.add_argument("--source-columns", metavar="X,Y", default=None,
                      help="the x and y columns of SOURCE (default: found by name)")
    cols.add_argument("--target-columns", metavar="X,Y", default=None,
                      help="the x and y columns of TARGET (default: found by name)")
    cols.add_argument("--flux", metavar="NAME[,NAME]", default=None,
                      help="flux column(s) whose brightest stars the search uses (default: "
                      "'flux' if present); 'none' for the first rows")
    pairing = p.add_argument_group("pairing")
    pairing.add_argument("--max-radius", type=float, metavar="PX", default=None,
                         help="first and largest pairing radius (default: six times the "
                         "search's residual scatter, at least 0.5 px)")
    pairing.add_argument("--radius", type=float, metavar="PX", default=None,
                         help="a fixed pairing radius (default: set by the fit's residuals)")
    pairing.add_argument("--max-iterations", type=int, metavar="N", default=10,
                         help="pairings at most (default: %(default)s)")
    search = p.add_argument_group("search options", "as in astroalign_nd.find_transform")
    for config in _CONFIGS:
        _add_fields(search, config)
    return p


def _names(value, what):
    if value is None:
        return None
    parts = [v.strip() for v in value.split(",")]
    if len(parts) != 2 or not all(parts):
        raise _CLIError(f"{what} takes two column names separated by a comma (e.g. x,y); got "
                        f"{value!r}.")
    return tuple(parts)


def _output_format(path, inputs, overwrite):
    """The astropy format of the output, after checking it can be written (before any work)."""
    from astroalign_nd.io.write import check_not_input, check_output_path

    suffix = next((s for s in FORMATS if path.lower().endswith(s)), None)
    if suffix is None:
        raise _CLIError(f"output {path!r} must end in one of {', '.join(FORMATS)}.")
    try:
        check_not_input(path, inputs)
        check_output_path(path, overwrite, extensions=tuple(FORMATS))
    except FileExistsError:
        raise _CLIError(f"output file {path!r} already exists; pass --overwrite to replace "
                        "it.") from None
    except ValueError as exc:
        raise _CLIError(str(exc)) from None
    return FORMATS[suffix]


def _cmd_match(args):
    from astroalign_nd.crossmatch import cross_match, read_catalog
    from astroalign_nd.io.write import write_table

    for path in (args.source, args.target):
        if not os.path.isfile(path):
            raise _CLIError(f"input file {path!r} does not exist or is not a file.")
    fmt = _output_format(args.output, (args.source, args.target), args.overwrite)
    source, target = read_catalog(args.source), read_catalog(args.target)
    source_columns = _names(args.source_columns, "--source-columns")
    target_columns = _names(args.target_columns, "--target-columns")
    flux = args.flux  # a column name or two; 'none': the first rows
    if flux is not None:
        parts = [v.strip() for v in flux.split(",")]
        if flux.strip().lower() == "none":
            flux = False
        elif len(parts) == 1:
            flux = parts[0]
        elif len(parts) == 2 and all(parts):
            flux = tuple(parts)
        else:
            raise _CLIError(f"--flux takes a column name or two separated by a comma; got "
                            f"{flux!r}.")
    search = {}  # the search options given (the others: the library's defaults)
    for config in _CONFIGS:
        for name, _, _ in cli_fields(config):
            value = getattr(args, name, None)
            if value is not None:
                search[name] = tuple(value) if isinstance(value, list) else value
    out = cross_match(source, target, source_columns=source_columns,
                      target_columns=target_columns, flux=flux, max_radius=args.max_radius,
                      radius=args.radius, max_iterations=args.max_iterations, **search)
    table = out.table
    table.meta["SOURCE"], table.meta["TARGET"] = str(args.source), str(args.target)
    write_table(table, args.output, format=fmt, overwrite=args.overwrite)
    q = out.transform.meta["quality"]
    # ECSV and FITS keep the table's meta (the transform's AAT* keywords); CSV and text do not.
    kept = ("kept in its AAT* keywords" if fmt in ("ascii.ecsv", "fits") else
            "not kept by this format: write .ecsv or .fits to keep it")
    print(f"{args.output}: {len(table)} pairs of {len(source)} source and {len(target)} "
          f"target rows; RMS {q['rms']:.4f} px, radius {out.radius:.3f} px, "
          f"{out.n_iterations} pairings; {_describe(out.transform)} ({kept})", file=sys.stdout)
    return 0
