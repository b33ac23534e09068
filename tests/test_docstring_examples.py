# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Every docstring example of the package runs and gives the output it shows.

One test per module of the API reference (docs/api.rst), so that the
README's ``python -m pytest tests`` checks the examples as well as the
docs build does.
"""

import doctest
import importlib
import inspect

import pytest

#: The modules documented in docs/api.rst.  compat's names are astroalign
#: 2.6's API, documented on the migration page rather than in the API
#: reference: their examples are run, but not required of every name.
MODULES = [
    "detection", "asterisms", "matching", "transforms", "nonlinear", "resample", "ccddata",
    "registration", "batch", "simulate", "exceptions", "io.header", "io.write",
    "visualization", "compat",
]

FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _import(name):
    if name == "visualization":
        matplotlib = pytest.importorskip("matplotlib")
        matplotlib.use("Agg")  # no window, whatever the user's backend
    return importlib.import_module(f"astroalign_nd.{name}")


@pytest.mark.parametrize("name", MODULES)
def test_examples_pass(name, tmp_path, monkeypatch, capsys):
    module = _import(name)
    # An example that writes a file must not leave it in the working folder.
    monkeypatch.chdir(tmp_path)
    failed, attempted = doctest.testmod(module, optionflags=FLAGS, report=True)
    report = capsys.readouterr().out
    if name == "visualization":
        import matplotlib.pyplot as plt
        plt.close("all")
    assert attempted > 0, f"astroalign_nd.{name} has no docstring example"
    assert failed == 0, f"{failed} of {attempted} examples failed:\n{report}"
    assert list(tmp_path.iterdir()) == [], "an example left files behind"


@pytest.mark.parametrize("name", [m for m in MODULES if m != "compat"])
def test_every_public_name_has_an_example(name):
    """The issue's "a numpydoc example for every public function and class"."""
    module = _import(name)
    missing = []
    for attr in getattr(module, "__all__", []):
        obj = getattr(module, attr)
        if not (inspect.isclass(obj) or inspect.isfunction(obj)):
            continue  # constants are documented in their module's text
        if getattr(obj, "__module__", None) != module.__name__:
            continue  # re-exported: its example lives where it is defined
        if ">>>" not in (inspect.getdoc(obj) or ""):
            missing.append(attr)
    assert missing == [], f"no example in the docstring of: {', '.join(missing)}"
