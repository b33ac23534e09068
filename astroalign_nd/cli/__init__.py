# Licensed under a 3-clause BSD style license - see LICENSE.rst

"""The ``astroalign-nd`` command-line tool.

Subcommands
-----------
``register SOURCE TARGET -o OUT.fits``
    Register one image onto another and write the aligned image.
``batch SOURCES... -r TARGET --output-dir DIR``
    Register several images onto one target, going on past failures
    (``batch TARGET SOURCES...``, the older form, still works).
``stack IMAGES... -o OUT.fits``
    Register images onto a reference and combine them.
``watch FOLDER -r REF --stack OUT.fits``
    Live stacking: add each FITS frame that appears in a folder.
``demo --output-dir DIR``
    Simulate a star-field pair with a known transform, register it and
    report how close the recovered transform is to the truth.
``match SOURCE TARGET -o OUT.ecsv``
    Cross-match two star catalogs: every star paired, written as a table.

Exit codes, the same for every command (``--help`` lists them too): 0 on
success (frames skipped by ``--skip-existing`` included), 1 when some frames
of a ``batch`` failed, 2 on a usage error (an input given as the output
included) or any other error, out of memory included, 3 when the
registration is refused (no trustworthy transform found), 130 and 143 when
interrupted by SIGINT (Ctrl-C) and SIGTERM.  Errors are one line on standard
error, without a traceback, and their hints name the command line's options
(``--n-sources``), not the Python keywords.

The package itself is imported lazily, inside the subcommands, so that
``astroalign-nd --help`` stays fast.
"""

from .main import main

__all__ = ['main']
