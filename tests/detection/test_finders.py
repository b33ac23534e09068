# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The source-finder interface: a new detector is one subclass of
`SourceFinderBase`, and the entry points run it (``finder=``).
"""

import numpy as np
import pytest
from astropy.table import Table
from scipy import ndimage
from scipy.spatial import cKDTree

import astroalign_nd
from astroalign_nd import compat
from astroalign_nd.batch import register_batch
from astroalign_nd.detection import (DAOSourceFinder, SegmentationFinder, SourceFinderBase,
                                     find_sources)
from astroalign_nd.simulate import simulate_field, simulate_pair

from _helpers import frame_error


class PeakFinder(SourceFinderBase):
    """A toy detector: local maxima of the 3x3-smoothed image, 3x3 centroids."""

    def __init__(self, nsigma=10.0):
        self.nsigma = nsigma

    def find_stars(self, data, mask=None):
        good = np.ones(data.shape, bool) if mask is None else ~mask
        sky = np.median(data[good])
        noise = 1.4826 * np.median(np.abs(data[good] - sky))
        sub = np.where(good, data - sky, 0.0)
        smooth = ndimage.uniform_filter(sub, 3)
        peak = (smooth == ndimage.maximum_filter(smooth, 5)) & (smooth > self.nsigma * noise / 3)
        peak[:2], peak[-2:], peak[:, :2], peak[:, -2:] = False, False, False, False
        y, x = np.nonzero(peak)
        d = np.arange(-1, 2)
        win = sub[y[:, None, None] + d[None, :, None], x[:, None, None] + d[None, None, :]]
        flux = win.sum(axis=(1, 2))
        return Table({"x": x + (win.sum(axis=1) * d).sum(axis=1) / flux,
                      "y": y + (win.sum(axis=2) * d).sum(axis=1) / flux, "flux": flux})


@pytest.fixture(scope="module")
def pair():
    return simulate_pair((256, 256), n_stars=150, rotation=30.0, translation=(5.0, -3.0),
                         seed=11)


def _truth_distance(table, stars):
    truth = np.column_stack([stars["x"], stars["y"]])
    return cKDTree(truth).query(np.column_stack([table["x"], table["y"]]))[0]


def test_a_new_finder_is_one_subclass(pair):
    found = PeakFinder()(pair.source)
    assert found.colnames == ["x", "y", "flux"] and len(found) > 20
    assert np.all(np.diff(found["flux"]) <= 0)  # brightest first
    assert np.median(_truth_distance(found[:30], pair.source_stars)) < 0.5  # a crude centroid
    # find_sources runs it, keeping the n_sources brightest.
    top = find_sources(pair.source, n_sources=10, finder=PeakFinder())
    np.testing.assert_array_equal(top["x"], found["x"][:10])
    assert top.meta["fwhm_source"] == "finder"


def test_the_entry_points_run_a_finder(pair, tmp_path):
    t, _ = astroalign_nd.find_transform(pair.source, pair.target, finder=PeakFinder())
    assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.5
    ref = astroalign_nd.Reference(pair.target, finder=PeakFinder())
    t2, _ = astroalign_nd.find_transform(pair.source, ref, finder=PeakFinder())
    np.testing.assert_allclose(t2.matrix, t.matrix)
    ccd = astroalign_nd.register(pair.source, pair.target, finder=PeakFinder())
    assert ccd.shape == pair.target.shape
    out = register_batch([pair.source], pair.target, output_dir=tmp_path, finder=PeakFinder())
    assert [f.status for f in out.frames] == ["registered"]
    assert frame_error(out.frames[0].transform, pair.truth_matrix, pair.target.shape) < 0.5


def test_a_finder_replaces_the_pipeline_options(pair):
    with pytest.raises(TypeError, match="fwhm.*configure its DAOStarFinder pipeline"):
        find_sources(pair.source, finder=PeakFinder(), fwhm=3.0)
    with pytest.raises(TypeError, match="nsigma"):
        astroalign_nd.find_transform(pair.source, pair.target, finder=PeakFinder(), nsigma=4.0)
    with pytest.raises(TypeError, match="finder must be a source finder"):
        astroalign_nd.Reference(pair.target, finder="daofind")
    # Left at their defaults, the pipeline's options are no error.
    assert len(find_sources(pair.source, finder=PeakFinder(), nsigma=5.0, fwhm=None)) > 0


def test_finder_contract_checks_its_output(pair):
    class NoTable(SourceFinderBase):
        def find_stars(self, data, mask=None):
            return np.zeros((3, 2))

    class NoFlux(SourceFinderBase):
        def find_stars(self, data, mask=None):
            return Table({"x": [1.0], "y": [2.0]})

    class Nothing(SourceFinderBase):
        def find_stars(self, data, mask=None):
            return None

    with pytest.raises(TypeError, match="returned ndarray"):
        NoTable()(pair.source)
    with pytest.raises(ValueError, match="no column flux"):
        NoFlux()(pair.source)
    assert len(Nothing()(pair.source)) == 0 and Nothing()(pair.source).colnames == [
        "x", "y", "flux"]
    with pytest.raises(TypeError):
        SourceFinderBase()  # abstract: find_stars is the contract


def test_finders_get_non_finite_pixels_masked():
    seen = {}

    class Spy(SourceFinderBase):
        def find_stars(self, data, mask=None):
            seen["mask"] = mask
            return Table({"x": [1.0, 2.0, 3.0], "y": [0.0, 1.0, np.nan],
                          "flux": [1.0, 5.0, 9.0]})

    img = np.ones((16, 16))
    img[3, 4] = np.nan
    user = np.zeros((16, 16), bool)
    user[0, 0] = True
    out = Spy()(img, mask=user)
    assert seen["mask"][3, 4] and seen["mask"][0, 0] and seen["mask"].sum() == 2
    assert list(out["x"]) == [2.0, 1.0]  # brightest first, the NaN position dropped
    Spy()(np.ones((16, 16)))
    assert seen["mask"] is None


def test_photutils_finders_plug_in(pair):
    from photutils.detection import DAOStarFinder

    found = find_sources(pair.source, n_sources=20,
                         finder=DAOStarFinder(threshold=50.0, fwhm=3.0))
    assert {"x", "y", "flux"} <= set(found.colnames) and len(found) == 20
    assert np.median(_truth_distance(found, pair.source_stars)) < 0.3


def test_dao_finder_is_find_sources(pair):
    finder = DAOSourceFinder(n_sources=25, nsigma=8.0)
    a, b = finder(pair.source), find_sources(pair.source, n_sources=25, nsigma=8.0)
    assert a.colnames == b.colnames and a.meta == b.meta
    for c in a.colnames:
        np.testing.assert_array_equal(a[c], b[c])
    c = find_sources(pair.source, n_sources=25, finder=finder)
    np.testing.assert_array_equal(c["x"], b["x"])
    with pytest.raises(TypeError, match="unexpected option"):
        DAOSourceFinder(min_area=5)
    assert finder.nsigma == 8.0 and DAOSourceFinder().nsigma == 5.0


def test_segmentation_finds_the_stars_of_a_simulated_frame():
    image, stars = simulate_field((384, 384), n_stars=150, seed=3)
    found = SegmentationFinder(nsigma=5.0)(image)
    assert np.all(np.diff(found["flux"]) <= 0)
    truth = np.column_stack([stars["x"], stars["y"]])
    # Every bright, isolated star is found within 0.5 px (blends and faint
    # stars aside, which a segmentation merges or misses).
    tree = cKDTree(truth)
    isolated = (tree.query(truth, k=2)[0][:, 1] > 10) & (np.asarray(stars["flux"]) > 2000)
    isolated &= np.all((truth > 8) & (truth < 376), axis=1)
    assert isolated.sum() >= 5
    dist = cKDTree(np.column_stack([found["x"], found["y"]])).query(truth[isolated])[0]
    assert np.all(dist < 0.5), dist
    assert np.median(_truth_distance(found, stars)) < 0.2


def test_segmentation_finder_options():
    for bad in (dict(nsigma=0), dict(nsigma=np.nan), dict(min_area=0), dict(box_size=2.5),
                dict(nsigma=True)):
        with pytest.raises(ValueError):
            SegmentationFinder(**bad)
    assert len(SegmentationFinder()(np.zeros((32, 32)))) == 0  # no noise: nothing
    masked = np.ones((32, 32), bool)
    assert len(SegmentationFinder()(np.ones((32, 32)), mask=masked)) == 0
    assert "min_area=5" in repr(SegmentationFinder())


def test_compat_detects_with_the_segmentation_finder(pair):
    pts = compat._find_sources(pair.source, detection_sigma=4, min_area=3)
    found = SegmentationFinder(nsigma=4, min_area=3)(pair.source)
    np.testing.assert_array_equal(pts, np.column_stack([found["x"], found["y"]]))
