# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Stacking: register frames onto a reference and combine them.

`stack` registers (through `~astroalign_nd.register_batch`) and combines
(``astroalign_nd.stacking.combine``: sky normalisation, sigma or min/max
clipping, weights, the combined uncertainty, a strip of rows at a time
within a memory limit).  `LiveStack` adds frames one at a time to a
running stack with clipping against it, and `watch_folder` feeds it the
frames that appear in a folder (``astroalign-nd watch``).  The frames are
assumed calibrated: stacking does not subtract bias or dark nor divide by
a flat (do that first, e.g. with ccdproc).
"""

from .core import stack
from .live import LiveStack, watch_folder

__all__ = ["stack", "LiveStack", "watch_folder"]
