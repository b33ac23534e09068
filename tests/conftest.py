# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Shared pytest configuration for the astroalign_nd tests."""

# doctestplus collects every .py file for doctests; do not import this one as a test module
# (it would clash with docs/conftest.py, both being named "conftest").
collect_ignore = ["conftest.py"]

try:
    import matplotlib
except ImportError:
    pass
else:
    matplotlib.use("Agg")


def pytest_configure(config):
    # Versions shown in the header by pytest-astropy-header (astropy_header = true in
    # pyproject.toml).
    try:
        from pytest_astropy_header.display import PYTEST_HEADER_MODULES
    except ImportError:
        return
    PYTEST_HEADER_MODULES.clear()
    PYTEST_HEADER_MODULES.update(
        {
            "numpy": "numpy",
            "scipy": "scipy",
            "astropy": "astropy",
            "photutils": "photutils",
            "ccdproc": "ccdproc",
            "reproject": "reproject",
            "scikit-image": "skimage",
            "asdf": "asdf",
        }
    )
