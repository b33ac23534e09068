# Licensed under a 3-clause BSD style license - see LICENSE.rst
#
# Sphinx configuration for astroalign_nd, built on sphinx-astropy's v3 configuration
# (pydata-sphinx-theme). Build with:
#
#     sphinx-build -W -b html docs docs/_build/html
#
# Offline, add ``-D disable_intersphinx=1`` (sphinx_astropy.ext.intersphinx_toggle).

import datetime
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
    }
)

# -- Options for HTML output -----------------------------------------------------------------

html_title = f"{project} v{release}"
htmlhelp_basename = project + "doc"
html_static_path = []

# -- Options for LaTeX / man output ----------------------------------------------------------

latex_documents = [("index", project + ".tex", project + " Documentation", author, "manual")]
man_pages = [("index", project.lower(), project + " Documentation", [author], 1)]
