# Licensed under a 3-clause BSD style license - see LICENSE.rst
#
# Sphinx configuration for astroalign_nd, built on sphinx-astropy's v3 configuration
# (pydata-sphinx-theme). Build with:
#
#     sphinx-build -W -b html docs docs/_build/html
#
# Links to other projects' documentation (intersphinx) need their inventories, downloaded
# at build time. They are fetched only when ASTROALIGN_ND_INTERSPHINX=1 is set (or on Read
# the Docs), so that an offline build is quiet:
#
#     ASTROALIGN_ND_INTERSPHINX=1 sphinx-build -W -b html docs docs/_build/html
#
# ``-D disable_intersphinx=1`` (sphinx_astropy.ext.intersphinx_toggle) turns them off again.

import datetime
import os
import sys
import tomllib
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _installed_version
from pathlib import Path

try:
    from sphinx_astropy.conf.v3 import *  # noqa: F401, F403
except ImportError:
    print("ERROR: building the documentation needs sphinx-astropy: "
          'pip install -e ".[docs]"')
    sys.exit(1)

# -- Project information ---------------------------------------------------------------------

with open(Path(__file__).parent.parent / "pyproject.toml", "rb") as _f:
    _pyproject = tomllib.load(_f)["project"]

project = _pyproject["name"]
author = _pyproject["authors"][0]["name"]
copyright = f"2026-{datetime.datetime.now().year}, {author}"

try:
    release = _installed_version(project)
except PackageNotFoundError:
    print(f"ERROR: {project} must be installed to build its documentation: "
          'pip install -e ".[docs]"')
    sys.exit(1)
# The short X.Y version.
version = ".".join(release.split(".")[:2])

# -- General configuration -------------------------------------------------------------------

exclude_patterns.append("_templates")  # noqa: F405
exclude_patterns.append("**.ipynb_checkpoints")  # noqa: F405

# The notebook tutorials are stored with their outputs (see tutorials/make_*.py, which
# builds and executes them); the documentation build only renders them.
extensions.append("nbsphinx")  # noqa: F405
nbsphinx_execute = "never"
nbsphinx_allow_errors = False

# Every cross-reference must resolve (build with -W).
nitpicky = True
nitpick_ignore = [
    # numpydoc type words that are not objects
    ("py:class", "array-like"),
    ("py:class", "array_like"),
    ("py:class", "path-like"),
    ("py:class", "optional"),
    ("py:class", "callable"),
]

# python, numpy, scipy, matplotlib and astropy come from sphinx_astropy.conf.v3.
intersphinx_mapping.update(  # noqa: F405
    {
        "photutils": ("https://photutils.readthedocs.io/en/stable/", None),
        "ccdproc": ("https://ccdproc.readthedocs.io/en/stable/", None),
        "reproject": ("https://reproject.readthedocs.io/en/stable/", None),
        "skimage": ("https://scikit-image.org/docs/stable/", None),
        "asdf": ("https://asdf.readthedocs.io/en/stable/", None),
        "dask": ("https://docs.dask.org/en/stable/", None),
        "distributed": ("https://distributed.dask.org/en/stable/", None),
    }
)

_INTERSPHINX = os.environ.get(
    "ASTROALIGN_ND_INTERSPHINX", "1" if os.environ.get("READTHEDOCS") else "0"
).strip().lower() not in ("", "0", "false", "no")
if not _INTERSPHINX:
    intersphinx_mapping.clear()  # noqa: F405

# Without the inventories, references to other projects cannot resolve: keep nitpicky
# for this package's own references only.
_EXTERNAL_PACKAGES = ("python", "numpy", "scipy", "matplotlib", "astropy", "photutils",
                      "ccdproc", "reproject", "skimage", "asdf", "asdf_astropy", "dask",
                      "distributed", "tqdm")
_EXTERNAL_REGEX = r"(%s)(\..*)?" % "|".join(_EXTERNAL_PACKAGES)
_EXTERNAL_IGNORE = [
    (r"py:.*", _EXTERNAL_REGEX),
    # Python builtins and numpydoc type words
    (r"py:.*", r"(int|float|str|bool|dict|list|tuple|type|object|bytes|complex|slice"
               r"|None|True|False|Exception|ValueError|TypeError|UserWarning"
               r"|ndarray|iterable|sequence|function|class)"),
]


# -- Options for HTML output -----------------------------------------------------------------

html_title = f"{project} v{release}"
htmlhelp_basename = project + "doc"
html_static_path = []

# -- Options for LaTeX / man output ----------------------------------------------------------

latex_documents = [("index", project + ".tex", project + " Documentation", author, "manual")]
man_pages = [("index", project.lower(), project + " Documentation", [author], 1)]

# -- Extension hooks -------------------------------------------------------------------------


def _offline_nitpick(app, config):
    """Ignore references to other projects when intersphinx is off (offline builds)."""
    if not config.intersphinx_mapping:
        config.nitpick_ignore_regex = list(config.nitpick_ignore_regex) + _EXTERNAL_IGNORE


def setup(app):
    # After sphinx_astropy.ext.intersphinx_toggle (priority 500), which may clear the mapping.
    app.connect("config-inited", _offline_nitpick, priority=900)
