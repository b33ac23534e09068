# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Storing transforms in files.

* FITS headers: `transform_to_header` / `transform_from_header` write and
  read a linear 2-D transform as ``AAT*`` keywords.
* ASDF: any transform, alone or inside an astropy compound model, through
  the extension in ``astroalign_nd.io.asdf`` (registered with asdf by entry
  points when the package is installed).
"""

from .header import transform_from_header, transform_to_header
from .write import atomic_write, write_ccddata

__all__ = ["transform_to_header", "transform_from_header", "atomic_write", "write_ccddata"]
