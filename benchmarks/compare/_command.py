"""
The command line the compare scripts share: ``--out FILE`` records the results,
``--compare OLD NEW`` reports the ones that differ (exit status 1 if any does).
"""

import argparse


def run_command(argv, doc, record, compare, options=()):
    """
    Parse ``argv`` and record or compare; return the exit status.

    Parameters
    ----------
    argv : list of str or None
        The arguments (`sys.argv` when None).
    doc : str
        The script's docstring: its first paragraph is the description.
    record : callable
        ``record(out, **extra)``: compute the results and write them to ``out``;
        ``extra`` holds the values of ``options``, by their destination names.
    compare : callable
        ``compare(old, new)``: print the differences, return how many (or a truthy
        value when there are any).
    options : sequence of (tuple, dict)
        Further options: the arguments and keywords of ``add_argument``.
    """
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--out", help="write the results to this file")
    ap.add_argument("--compare", nargs=2, metavar=("OLD", "NEW"),
                    help="report the differences between two result files")
    for flags, kwargs in options:
        ap.add_argument(*flags, **kwargs)
    args = vars(ap.parse_args(argv))
    old_new, out = args.pop("compare"), args.pop("out")
    if old_new:
        return 1 if compare(*old_new) else 0
    if not out:
        ap.error("pass --out FILE or --compare OLD NEW")
    record(out, **args)
    return 0
