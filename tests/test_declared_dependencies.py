# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
What the package imports is what it declares: a module imported when the package's modules
load is a dependency (``pip install .`` brings it), one imported inside a function at least an
optional extra; and the conda recipe runs on the same dependencies as pyproject.toml.
"""

import ast
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: Import names whose distribution is named otherwise.
DISTRIBUTIONS = {"skimage": "scikit-image", "colour_demosaicing": "colour-demosaicing"}


def _requirements(reqs):
    """``{distribution: floor}`` of requirement strings (``name[extra]>=floor``)."""
    out = {}
    for req in reqs:
        name, floor = re.match(r"([A-Za-z0-9_.-]+)(?:\[[^\]]*\])?\s*(?:>=\s*([\w.]+))?",
                               req).groups()
        out[name.lower().replace("_", "-")] = floor
    return out


def _imports():
    """Third-party distributions imported: (at module level, anywhere)."""
    top, anywhere = set(), set()
    for path in (ROOT / "astroalign_nd").rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module]
            else:
                continue
            for name in names:
                root = name.split(".")[0]
                if root in sys.stdlib_module_names or root == "astroalign_nd":
                    continue
                dist = DISTRIBUTIONS.get(root, root).lower().replace("_", "-")
                anywhere.add(dist)
                if node in tree.body:
                    top.add(dist)
    return top, anywhere


def test_every_import_is_declared():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    required = _requirements(project["dependencies"])
    optional = _requirements([r for extra in project["optional-dependencies"].values()
                              for r in extra])
    top, anywhere = _imports()
    assert "numpy" in top and "tqdm" in anywhere  # the scan sees the package's imports
    assert top - set(required) == set(), "imported at load time but not a dependency"
    assert anywhere - set(required) - set(optional) == set(), "imported but not declared"


def test_the_conda_recipe_runs_on_the_same_dependencies():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    text = (ROOT / "recipe" / "meta.yaml").read_text(encoding="utf-8")
    run = re.search(r"\n  run:\n((?:    - .*\n)+)", text).group(1)
    recipe = _requirements(line.strip()[2:].replace(" ", "") for line in run.splitlines()
                           if line.strip()[2:] != "python")
    assert recipe == _requirements(project["dependencies"])
