# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The public names imported on first use (astroalign_nd._lazy): each is its module's object."""

import importlib
import subprocess
import sys

import pytest

import astroalign_nd
from astroalign_nd import detection, matching, resample, sequence, stacking, transforms
from astroalign_nd._lazy import attach

PACKAGES = [astroalign_nd, detection, matching, resample, sequence, stacking, transforms]


@pytest.mark.parametrize("package", PACKAGES, ids=lambda p: p.__name__)
def test_every_public_name_is_its_modules_object(package):
    for module, names in package._LAZY.items():
        for name in names:
            defined = getattr(importlib.import_module(module, package.__name__), name)
            assert getattr(package, name) is defined, name
            assert name in package.__all__


@pytest.mark.parametrize("package", PACKAGES, ids=lambda p: p.__name__)
def test_dir_lists_the_public_names_and_no_helper_import(package):
    listed = dir(package)
    assert set(package.__all__) <= set(listed)
    assert "importlib" not in listed and "attach" not in listed
    with pytest.raises(AttributeError, match=f"module '{package.__name__}' has no attribute"):
        package.no_such_name


def test_submodules_are_attributes():
    assert astroalign_nd.compat is importlib.import_module("astroalign_nd.compat")
    assert {"compat", "visualization"} <= set(dir(astroalign_nd))


def test_import_loads_no_stage():
    # What keeps `import astroalign_nd` (and the command line's --help) cheap: neither the
    # package nor the transform registry imports astropy.modeling, scipy or a stage.
    code = ("import sys, astroalign_nd, astroalign_nd.transforms.registry; "
            "print(sorted(m for m in ('astropy.modeling', 'scipy', 'photutils', "
            "'astroalign_nd.registration', 'astroalign_nd.transforms.linear') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=60)
    assert out.stdout.strip() == "[]"


def test_a_name_under_two_submodules_is_refused():
    with pytest.raises(ValueError, match="listed under two submodules"):
        attach("astroalign_nd", {".registration": ["register"], ".batch": ["register"]})
    with pytest.raises(ValueError, match="relative"):
        attach("astroalign_nd", {"registration": ["register"]})
