# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Build of the optional compiled kernels; all other metadata is in pyproject.toml.

``astroalign_nd._ckernels`` only speeds up a few loops: `astroalign_nd._kernels`
has NumPy versions of all of them.  So the extension is ``optional``: when it
cannot be built (no C compiler, as on many Windows, macOS and conda machines,
or no Cython in a build without isolation), setuptools warns and the package
installs without it.  Set ``ASTROALIGN_ND_NO_EXTENSION=1`` to skip it on
purpose (CI uses this to test the NumPy kernels on every OS).
"""

import os
import sys

from setuptools import Extension, setup

PYX = os.path.join("astroalign_nd", "_ckernels.pyx")


def _extensions():
    if os.environ.get("ASTROALIGN_ND_NO_EXTENSION", "").strip() not in ("", "0"):
        print("ASTROALIGN_ND_NO_EXTENSION is set: installing the NumPy kernels only",
              file=sys.stderr)
        return []
    try:
        import numpy
        import Cython  # noqa: F401 - setuptools needs it to read the .pyx
    except ImportError as exc:
        # Only without build isolation: pyproject.toml's build requirements have both.
        print(f"{exc.name} is not installed: installing the NumPy kernels only",
              file=sys.stderr)
        return []
    return [Extension("astroalign_nd._ckernels", [PYX], include_dirs=[numpy.get_include()],
                      optional=True)]


setup(ext_modules=_extensions())
