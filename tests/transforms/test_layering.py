# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The package's layering, read from its source: the transforms are the
foundation (they import no other stage), and the transform types are named
in one place, the registry.
"""

import ast
import pathlib

import astroalign_nd
from astroalign_nd.transforms import TRANSFORM_REGISTRY

PACKAGE = pathlib.Path(astroalign_nd.__file__).parent

#: What the transforms may import from the rest of the package: its leaves.
FOUNDATION = {"exceptions", "_validate", "_kernels", "_ckernels", "options"}


def _imports(path):
    """(line, absolute module name) of every package import in ``path``, functions too."""
    module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    if path.name == "__init__.py":
        module = package
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            yield node.lineno, name
            if not node.module:  # ``from . import x``: x is a module
                for alias in node.names:
                    yield node.lineno, f"{name}.{alias.name}"


def test_transforms_import_no_other_stage():
    bad = []
    for path in sorted((PACKAGE / "transforms").glob("*.py")):
        for line, name in _imports(path):
            parts = name.split(".")
            if parts[0] != "astroalign_nd" or len(parts) == 1:
                continue
            if parts[1] != "transforms" and parts[1] not in FOUNDATION:
                bad.append(f"transforms/{path.name}:{line} imports {name}")
    assert not bad, "the transforms must not build on another stage:\n" + "\n".join(bad)


def test_the_options_machinery_is_a_leaf():
    """Every stage checks its options with ``astroalign_nd.options``: it imports none of them."""
    assert [name for _, name in _imports(PACKAGE / "options.py")
            if name.startswith("astroalign_nd")] == []


def _type_name_lists(path, names):
    """(line, values) of each literal tuple, list, set or dict (its keys) holding
    2+ type names."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, (ast.Tuple, ast.List, ast.Set, ast.Dict)):
            elts = node.keys if isinstance(node, ast.Dict) else node.elts
            values = [e.value for e in elts
                      if isinstance(e, ast.Constant) and isinstance(e.value, str)]
            if sum(v in names for v in values) >= 2:
                yield node.lineno, values


def test_type_names_are_listed_by_the_registry_only():
    names = set(TRANSFORM_REGISTRY)
    registry = PACKAGE / "transforms" / "registry.py"
    found = [f"{path.relative_to(PACKAGE)}:{line}: {values}"
             for path in sorted(PACKAGE.rglob("*.py")) if path != registry
             for line, values in _type_name_lists(path, names)]
    assert not found, ("lists of transform type names outside the registry (derive them from "
                       "astroalign_nd.transforms.registry):\n" + "\n".join(found))


def test_the_checks_can_fail(tmp_path):
    # The scan finds a hand-written list, and the import walk a stage's import.
    sample = tmp_path / "sample.py"
    sample.write_text("KINDS = ('similarity', 'affine')\nOK = ('similarity', 'other')\n"
                      "K = {'translation': 2, 'euclidean': 3}\n")
    assert list(_type_name_lists(sample, set(TRANSFORM_REGISTRY))) == [
        (1, ["similarity", "affine"]), (3, ["translation", "euclidean"])]
    selection = PACKAGE / "transforms" / "selection.py"
    assert "astroalign_nd.transforms.fitting" in {n for _, n in _imports(selection)}
