# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Stacking: register frames onto a reference and combine them.

`stack` registers (through `~astroalign_nd.register_batch`) and combines
(``astroalign_nd.stacking.combine``: sky normalisation, sigma or min/max
clipping, weights, the combined uncertainty, a strip of rows at a time
within a memory limit).  `LiveStack` adds frames one at a time to a
running stack with clipping against it, and `watch_folder` feeds it the
frames that appear in a folder (``astroalign-nd watch``).  `StackConfig`
holds the options of both, each checked once (and the commands' flags).
`frame_quality` measures every frame of a night as it was taken (seeing,
trailing, transparency, sky noise) and gives the weights and the selection
that ``stack(weights='auto', select='auto')`` uses
(``astroalign_nd.stacking.quality``).
The frames are assumed calibrated: stacking does not subtract bias or
dark nor divide by a flat (do that first, e.g. with ccdproc).

The names are imported on first use (``astroalign_nd._lazy``): the command
line builds its flags from `StackConfig` without importing the stages.
"""

from .._lazy import attach

# submodule (relative, as in an import) -> the public names it defines
_LAZY = {
    ".core": ["stack"],
    ".live": ["LiveStack", "watch_folder"],
    ".options": ["StackConfig"],
    ".quality": ["frame_quality"],
}

__getattr__, __dir__, __all__ = attach(__name__, _LAZY)
del attach
