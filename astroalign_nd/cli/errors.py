# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The command line's errors, its exit codes, and its hints in its own option names."""

import argparse
import re
import sys
import textwrap

from ..config import RegistrationConfig
from ..detection import DetectionConfig
from ..matching import MatchingConfig
from ..options import cli_fields
from ..resample import ResampleConfig
from ..stacking.options import StackConfig
from ..transforms import ModelConfig

__all__ = []

_PROG = "astroalign-nd"

#: Errors reported as ``astroalign-nd: error: <message>`` rather than with a traceback.
_USER_ERRORS = (ValueError, TypeError, OSError)

#: The exit codes of every command, and what each means (``--help`` and the docs show it).
EXIT_OK, EXIT_FRAMES_FAILED, EXIT_USAGE, EXIT_REFUSED = 0, 1, 2, 3
EXIT_CODES = (
    (EXIT_OK, "success (batch: every frame registered, or skipped by --skip-existing)"),
    (EXIT_FRAMES_FAILED, "batch, stack, watch: some frames failed (each is reported; the "
     "others were written or stacked)"),
    (EXIT_USAGE, "usage error: a bad option or value, an input that cannot be read, an "
     "output that cannot be written or that is one of the inputs, or any other error"),
    (EXIT_REFUSED, "registration refused: no trustworthy transform (too few stars, no "
     "match, or a match that does not pass the checks); nothing was written"),
    (130, "interrupted (SIGINT, Ctrl-C); batch and watch write what was done, stack "
     "writes the partial stack of the frames registered so far"),
    (143, "terminated (SIGTERM); the same as 130"),
)


def exit_codes_text():
    """The table of exit codes as ``--help`` prints it (the epilog of every command)."""
    return "exit codes:\n" + "\n".join(f"  {code:<4d} {text}" for code, text in EXIT_CODES)


class HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, except that the exit-code table keeps one line per code."""

    def _fill_text(self, text, width, indent):
        if not text.startswith("exit codes:"):
            return super()._fill_text(text, width, indent)
        lines = text.splitlines()
        return "\n".join([indent + lines[0]] + [
            textwrap.fill(line.strip(), width, initial_indent=indent + "  ",
                          subsequent_indent=indent + " " * 7) for line in lines[1:]])


class _CLIError(Exception):
    """A problem with the command line itself (exit code 2)."""


def exit_code(exc):
    """3 for a refused registration (an `~astroalign_nd.AstroalignError`), else 2."""
    from astroalign_nd import AstroalignError

    return EXIT_REFUSED if isinstance(exc, AstroalignError) else EXIT_USAGE

# -- hints in the command line's words -------------------------------------------------------


#: Keywords without an underscore that are not also common words ("order", "degree").
_PLAIN_KEYWORDS = ("fwhm", "nsigma", "tolerance", "hdu", "nlow", "nhigh")


def _flags():
    """The library's keyword -> the command line's option, for every option it offers."""
    flags = {"hdu": "--hdu", "unit": "--unit", "aligned_dir": "--aligned-dir",
             "output_dir": "--output-dir", "skip_existing": "--skip-existing"}
    for config in (ModelConfig, ResampleConfig, RegistrationConfig, DetectionConfig,
                   MatchingConfig, StackConfig):
        for name, flag, kwargs in cli_fields(config):
            if kwargs.get("action") != "store_false":  # --no-mirror: not the keyword's name
                flags[name] = flag
    return flags


_OPTION_FLAGS = _flags()
#: The keywords named anywhere: those that are not also common words ("order", "sigma").
_FLAGS = {k: v for k, v in _OPTION_FLAGS.items() if "_" in k or k in _PLAIN_KEYWORDS}
#: A keyword as a word (not inside another name or option), with ``=value`` if given.
_KEYWORD = re.compile(r"(?<![\w\-.'\"])(" + "|".join(sorted(_FLAGS, key=len, reverse=True))
                      + r")\b(=)?")
#: Any option's keyword where a check names it ("sigma must be ...").
_CHECKED = re.compile(r"(?<![\w\-.'\"])("
                      + "|".join(sorted(_OPTION_FLAGS, key=len, reverse=True)) + r") must be ")
#: Any option's keyword given a value ("use canvas='reference'", "pass select=None").
_ASSIGNED = re.compile(r"(?<![\w\-.'\"])("
                       + "|".join(sorted(_OPTION_FLAGS, key=len, reverse=True))
                       + r")=(?:'(\w+)'|(?=[\w<]))")


def cli_words(message):
    """
    ``message`` with the library's keywords as the command line's options.

    The library's hints name its keywords (``try more sources
    (n_sources)``, ``pass fwhm=<width>``); printed by the command line,
    they name its options (``--n-sources``, ``--fwhm <width>``).

    Examples
    --------
    >>> from astroalign_nd.cli.errors import cli_words
    >>> cli_words("try more sources (n_sources), or pass fwhm=<their width>.")
    'try more sources (--n-sources), or pass --fwhm <their width>.'
    >>> cli_words("method must be one of 'average', 'median', 'sum'; got 'mean'.")
    "--combine must be one of 'average', 'median', 'sum'; got 'mean'."
    >>> cli_words("use canvas='reference', or pass select=None.")
    'use --canvas reference, or pass --select none.'
    """
    # The command line has no None (leave the option out) and no overwrite=True: a keyword
    # given with its flag ("skip_existing=True (--skip-existing)") is the flag alone.
    message = re.sub(r"\b\w+=True \((?:or )?(--[\w-]+)\)", r"\1", message)
    message = _CHECKED.sub(lambda m: _OPTION_FLAGS[m.group(1)] + " must be ", message)
    message = re.sub(r"\b(\w+)=True\b", lambda m: _OPTION_FLAGS.get(m.group(1), m.group(0)),
                     message)
    message = _ASSIGNED.sub(lambda m: f"{_OPTION_FLAGS[m.group(1)]} {m.group(2) or ''}", message)
    message = _KEYWORD.sub(lambda m: _FLAGS[m.group(1)] + (" " if m.group(2) else ""), message)
    message = re.sub(r",? or None\b", "", message)
    message = re.sub(r"\bNone\b", "none", message)  # a choice switched off: --clip none
    return re.sub(r"(--[\w-]+)  ", r"\1 ", message)

# -- entry point -----------------------------------------------------------------------------


def _error(message, code=EXIT_USAGE):
    print(f"{_PROG}: error: {cli_words(message)}", file=sys.stderr)
    return code
