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
import pkgutil

import pytest

#: The modules documented in docs/api.rst.  compat's names are astroalign
#: 2.6's API, documented on the migration page rather than in the API
#: reference: their examples are run, but not required of every name.
#: A subpackage (one stage of the method) counts as one: its modules' examples together.
MODULES = [
    "detection", "matching", "transforms", "resample",
    "registration", "crossmatch", "config", "options", "batch", "stacking", "simulate",
    "exceptions",
    "io.header",
    "io.write",
    "visualization", "compat",
]

FLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _import(name):
    if name == "visualization":
        matplotlib = pytest.importorskip("matplotlib")
        matplotlib.use("Agg")  # no window, whatever the user's backend
    return importlib.import_module(f"astroalign_nd.{name}")


def _modules(module):
    """The module, and every module of it if it is a package."""
    found = [module]
    for info in pkgutil.iter_modules(getattr(module, "__path__", [])):
        if info.name != "__main__":
            found.append(importlib.import_module(f"{module.__name__}.{info.name}"))
    return found


@pytest.mark.parametrize("name", MODULES)
def test_examples_pass(name, tmp_path, monkeypatch, capsys):
    module = _import(name)
    # An example that writes a file must not leave it in the working folder.
    monkeypatch.chdir(tmp_path)
    failed = attempted = 0
    for part in _modules(module):
        f, a = doctest.testmod(part, optionflags=FLAGS, report=True)
        failed, attempted = failed + f, attempted + a
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
        if not getattr(obj, "__module__", "").startswith(module.__name__):
            continue  # re-exported from another stage: its example lives where it is defined
        if ">>>" not in (inspect.getdoc(obj) or ""):
            missing.append(attr)
    assert missing == [], f"no example in the docstring of: {', '.join(missing)}"
