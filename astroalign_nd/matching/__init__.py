# Licensed under a 3-clause BSD style license - see LICENSE.rst

"""Stage 3 of the method: match triangles, verify, refine.

1. Triangles of the two images whose invariants lie within ``radius`` of
   each other (a k-d tree query) become candidate matches, best first.
2. Each match proposes a similarity transform from its 3 vertex pairs
   (closed form, vectorised over all matches; the match's orientation
   tells whether it is mirrored).
3. Hypotheses are scored in batches by how many source stars land within
   ``tolerance`` pixels of a target star.  This is RANSAC with early
   acceptance, but deterministic: hypotheses come in order of invariant
   distance instead of at random.
4. A promising hypothesis is refined: cross-match every star under it,
   least-squares fit of the requested model, tighten the matching radius
   to the residual scatter, repeat.
5. It is accepted only if the number of matched stars is very unlikely to
   be chance (a binomial false-alarm probability, with a trials factor for
   every hypothesis tried, in the spirit of astrometry.net's odds test).

For wide fields, `extend_match` grows the linear match into a distortion
model over many more stars (``grow``); ``allpairs`` pairs every star of two
catalogs under a model (the engine of `~astroalign_nd.cross_match`).

Names are imported on first use (``astroalign_nd._lazy``): reading the
options class (`MatchingConfig`) does not import the stage.
"""

from .._lazy import attach

# submodule (relative, as in an import) -> the public names it defines
_LAZY = {
    ".result": ["MatchResult"],
    ".search": ["match_points", "search_tolerance"],
    ".geometry": ["bounding_frame", "overlap_counts", "chance_pairs_log10"],
    ".triangles": ["match_triangles", "hypothesis_matrices"],
    ".asterisms": ["Asterisms", "build_asterisms", "check_triangle_budget"],
    ".grow": ["fit_nonlinear", "extend_match"],
    ".options": ["MatchingConfig", "DEFAULT_TOLERANCE", "DEFAULT_NEIGHBORS"],
}

__getattr__, __dir__, __all__ = attach(__name__, _LAZY)
del attach
