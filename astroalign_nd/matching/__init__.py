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

# name -> submodule that defines it
_LAZY = {
    "MatchResult": "result",
    "match_points": "search",
    "search_tolerance": "search",
    "bounding_frame": "geometry",
    "overlap_counts": "geometry",
    "chance_pairs_log10": "geometry",
    "match_triangles": "triangles",
    "hypothesis_matrices": "triangles",
    "Asterisms": "asterisms",
    "build_asterisms": "asterisms",
    "check_triangle_budget": "asterisms",
    "fit_nonlinear": "grow",
    "extend_match": "grow",
    "MatchingConfig": "options",
    "DEFAULT_TOLERANCE": "options",
    "DEFAULT_NEIGHBORS": "options",
}

__all__ = list(_LAZY)

__getattr__, __dir__ = attach(__name__, _LAZY)
del attach
