# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The command line's errors and their exit codes."""

import sys

__all__ = []

_PROG = "astroalign-nd"

#: Errors reported as ``astroalign-nd: error: <message>`` rather than with a traceback.
_USER_ERRORS = (ValueError, TypeError, OSError)


class _CLIError(Exception):
    """A problem with the command line itself (exit code 2)."""


def _expected_errors():
    """The exception classes that are reported without a traceback."""
    from astroalign_nd import AstroalignError

    return (AstroalignError, _CLIError) + _USER_ERRORS

# -- entry point -----------------------------------------------------------------------------


def _error(message):
    print(f"{_PROG}: error: {message}", file=sys.stderr)
    return 2
