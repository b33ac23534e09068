# Licensed under a 3-clause BSD style license - see LICENSE.rst
#
# Sphinx configuration for astroalign_nd, built on sphinx-astropy's v3 configuration
# (pydata-sphinx-theme). Everything it needs comes from pip (pip install -e ".[docs]"; no
# pandoc), and it executes every notebook tutorial. Build with:
#
#     python -m sphinx -W -b html docs docs/_build/html
#
# Links to other projects' documentation (intersphinx) need their inventories, downloaded
# at build time. They are fetched only when ASTROALIGN_ND_INTERSPHINX=1 is set (or on Read
# the Docs), so that an offline build is quiet:
#
#     ASTROALIGN_ND_INTERSPHINX=1 python -m sphinx -W -b html docs docs/_build/html
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

# The tutorials are notebooks stored as text (MyST markdown, docs/tutorials/*.md), run by
# myst-nb at every build: no outputs are stored, so none can go stale, and no program
# outside pip (nbsphinx needs pandoc) is needed.
extensions.append("myst_nb")  # noqa: F405
# The command-line reference (cli.rst) is generated from the parser itself.
extensions.append("sphinxarg.ext")  # noqa: F405
nb_execution_mode = "force"
nb_execution_timeout = 300
nb_execution_raise_on_error = True
nb_execution_show_tb = True
# Run in a temporary folder, so that files the tutorials write do not land in docs/.
nb_execution_in_temp = True
# Anything a tutorial prints to stderr (a warning) fails the build under -W.
nb_output_stderr = "warn"
nb_merge_streams = True
# The kernels inherit this environment: an MPLBACKEND set for the tests (tox and CI set
# agg) would stop IPython from using its inline backend, and the figures would be lost.
os.environ.pop("MPLBACKEND", None)
myst_enable_extensions = ["dollarmath", "colon_fence"]

# Class pages list inherited members too (rotation_deg, matrix, from_points of the
# transforms, and what astropy's Model gives them), as astropy's own documentation does.
automodsumm_inherited_members = True
# Types are given in the numpydoc Parameters/Returns sections; the annotations would repeat
# them in the signatures, with names (np.ndarray, CCDData under TYPE_CHECKING) that do not
# resolve.
autodoc_typehints = "none"

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


def _documented_name(name):
    """Where the top-level name ``astroalign_nd.<name>`` is documented (api.rst)."""
    import astroalign_nd

    for module, names in astroalign_nd._LAZY.items():
        if name in names:
            return f"astroalign_nd{module}.{name}"
    module = getattr(getattr(astroalign_nd, name, None), "__module__", None)
    if name in astroalign_nd.__all__ and module and module.startswith("astroalign_nd."):
        return f"{module}.{name}"
    return None


def _resolve_package_names(app, env, node, contnode):
    """
    Resolve references to names that are documented under another of their names.

    Each public name is documented once, in the module that defines it (api.rst), so
    ``astroalign_nd.register`` points to ``astroalign_nd.registration.register``.  A short
    name in a docstring (```plan_outputs```) is looked up in its module's parent packages,
    as for ``astroalign_nd.io.header``'s names, documented under ``astroalign_nd.io``.
    """
    target = node["reftarget"]
    if node.get("refdomain") == "std" and node.get("reftype") == "ref":
        # astropy's docstrings (inherited members of Model) link to labels of astropy's
        # documentation, as "astropy:label": offline, show their text without a link.
        project = target.partition(":")[0]
        if not app.config.intersphinx_mapping and project in _EXTERNAL_PACKAGES:
            return contnode
        return None
    if node.get("refdomain") != "py":
        return None
    candidates = []
    if target.startswith("astroalign_nd."):
        candidates.append(target)
    else:
        module = node.get("py:module") or ""
        while module.startswith("astroalign_nd"):
            candidates.append(f"{module}.{target}")
            module = module.rpartition(".")[0]
    domain = env.get_domain("py")
    for candidate in candidates:
        head, _, rest = candidate[len("astroalign_nd."):].partition(".")
        documented = _documented_name(head)
        if documented:
            candidate = documented + ("." + rest if rest else "")
        if candidate == target:
            continue
        found = domain.resolve_xref(env, node["refdoc"], app.builder, node["reftype"],
                                    candidate, node, contnode)
        if found is not None:
            return found
    return None


def _offline_nitpick(app, config):
    """Ignore references to other projects when intersphinx is off (offline builds)."""
    if not config.intersphinx_mapping:
        config.nitpick_ignore_regex = list(config.nitpick_ignore_regex) + _EXTERNAL_IGNORE


def setup(app):
    # After sphinx_astropy.ext.intersphinx_toggle (priority 500), which may clear the mapping.
    app.connect("config-inited", _offline_nitpick, priority=900)
    app.connect("missing-reference", _resolve_package_names)
