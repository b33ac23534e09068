# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The global solution of many frames: `solve_sequence` registers a night or a
mosaic as one, every frame's transform to the reference solved together
(a bundle adjustment).

``links`` matches pairs of frames (each a `Link`, found by the trusted
search of `~astroalign_nd.find_match`) round by round until the frames are
connected; ``adjust`` holds the joint least squares (the link adjustment
and the bundle adjustment, on each transform type's parameter layer);
``solve`` strings them together into a `SequenceSolution`.
`~astroalign_nd.register_batch` uses it with ``solve='global'``.

The names are imported on first use (``astroalign_nd._lazy``).
"""

from .._lazy import attach

# submodule (relative, as in an import) -> the public names it defines
_LAZY = {
    ".solve": ["solve_sequence", "SequenceSolution"],
    ".links": ["Link"],
}

__getattr__, __dir__, __all__ = attach(__name__, _LAZY)
del attach
