# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""One mutual nearest-neighbour pairing (`astroalign_nd.matching.pairing.mutual_matches`)."""

import numpy as np
from scipy.spatial import cKDTree

from astroalign_nd.matching.pairing import mutual_matches
from astroalign_nd.matching import grow


# -- one mutual nearest-neighbour pairing --------------------------------------------------

def test_mutual_matches_resolves_conflicts_and_ties():
    targets = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    tree = cKDTree(targets)
    # Sources 0 and 2 are equally near target 0: the lower index keeps it; source 1 is
    # nearer target 1 than source 3; source 4 is beyond the tolerance.
    pred = np.array([[0.5, 0.0], [10.1, 0.0], [-0.5, 0.0], [10.6, 0.0], [30.0, 0.0]])
    si, dj = mutual_matches(pred, tree, 1.0)
    assert si.tolist() == [0, 1] and dj.tolist() == [0, 1]
    assert np.all(np.diff(si) > 0)  # by source index
    empty = mutual_matches(np.zeros((0, 2)), tree, 1.0)
    assert [a.tolist() for a in empty] == [[], []]
    none = mutual_matches(pred + 100.0, tree, 1.0)
    assert [a.tolist() for a in none] == [[], []]


def test_distortion_stage_pairs_through_mutual_matches():
    rng = np.random.default_rng(2)
    dst = rng.uniform(0, 500, (60, 2))
    pairs = grow._Pairs(dst + 0.1, dst, given=False)
    si, dj = pairs.pair(dst + 0.1, np.arange(60), 1.0)
    assert np.array_equal(si, dj) and len(si) == 60
