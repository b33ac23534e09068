# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Tests of find_transform / find_match on simulated pairs with a known transform."""

import copy
import re

import numpy as np
import pytest
from astropy import units as u
from astropy.io import fits
from astropy.nddata import CCDData, NDData, StdDevUncertainty
from astropy.table import Table

import astroalign_nd
from astroalign_nd import (AffineTransform, AstroalignError, EuclideanTransform,
                           PoorFitWarning, SimilarityTransform, TooFewSourcesError,
                           TransformNotFoundError, TranslationTransform, find_match,
                           find_sources, find_transform)
from astroalign_nd.matching import MatchResult
from astroalign_nd.simulate import simulate_field, simulate_pair

from _helpers import frame_error

BRIGHT = (2e3, 5e5)


@pytest.fixture(scope="module")
def small_pair():
    """A quick 256x256 pair used by the API tests."""
    return simulate_pair((256, 256), n_stars=100, flux_range=BRIGHT, rotation=33.0,
                         translation=(4.3, -2.1), seed=5)


@pytest.fixture(scope="module")
def small_result(small_pair):
    return find_transform(small_pair.source, small_pair.target)


# -- (a) accuracy over the whole target frame ------------------------------------------

@pytest.mark.parametrize("rotation", [0.0, 37.0, 90.0, 180.0, 271.0])
def test_rotations(rotation):
    pair = simulate_pair((512, 512), n_stars=300, flux_range=BRIGHT, rotation=rotation,
                         translation=(6.4, -3.3), seed=11)
    t, (src, dst) = find_transform(pair.source, pair.target)
    assert isinstance(t, SimilarityTransform)
    err = frame_error(t, pair.truth_matrix, pair.target.shape)
    assert err < 0.1, f"rotation {rotation}: {err:.3f} px over the target frame"
    assert t.rotation_deg % 360 == pytest.approx(rotation % 360, abs=0.02) or \
        abs((t.rotation_deg - rotation + 180) % 360 - 180) < 0.02
    assert not t.mirrored
    assert len(src) >= 50


@pytest.mark.parametrize("scale", [0.5, 0.8, 1.25, 2.0])
def test_scales(scale):
    # With scale 2 the target sees a quarter of the source area, and with
    # scale 0.5 the source fills a quarter of the target: only a quarter of
    # each image's stars are common, so use more stars (and control points).
    quarter = scale in (0.5, 2.0)
    n_stars = 1200 if scale == 2.0 else 300
    pair = simulate_pair((512, 512), n_stars=n_stars, flux_range=BRIGHT, rotation=30.0,
                         scale=scale, seed=12)
    t, (src, dst) = find_transform(pair.source, pair.target,
                                   n_sources=100 if quarter else 50)
    err = frame_error(t, pair.truth_matrix, pair.target.shape)
    assert err < 0.1, f"scale {scale}: {err:.3f} px over the target frame"
    assert float(t.scale.value) == pytest.approx(scale, rel=2e-4)
    assert len(src) >= 30


@pytest.mark.parametrize("translation", [(0.3, -0.7), (17.25, -40.5)])
def test_sub_pixel_shifts(translation):
    pair = simulate_pair((512, 512), n_stars=300, flux_range=BRIGHT, rotation=0.0,
                         translation=translation, seed=13)
    t, _ = find_transform(pair.source, pair.target)
    assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.1
    np.testing.assert_allclose(t.translation, pair.truth_matrix[:2, 2], atol=0.05)


def test_random_transform_pair():
    pair = simulate_pair((384, 384), n_stars=200, flux_range=BRIGHT, seed=14)
    t, _ = find_transform(pair.source, pair.target)
    assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.1


def test_outliers_are_rejected():
    pair = simulate_pair((512, 512), n_stars=300, flux_range=BRIGHT, rotation=20.0,
                         scale=0.5, fwhm=4.0, seed=2)
    t, _ = find_transform(pair.source, pair.target)
    err = frame_error(t, pair.truth_matrix, pair.target.shape)
    assert err < 0.1, f"{err:.3f} px over the target frame"


# -- (b) catalogs --------------------------------------------------------------------------

TRUTH = SimilarityTransform(scale=0.7, rotation=200.0, translation_x=310.0,
                            translation_y=45.5)
TRIANGLE = np.array([[12.0, 30.0], [210.0, 75.0], [95.0, 260.0]])  # scalene


def _map(model, pts):
    x, y = model(pts[:, 0], pts[:, 1])
    return np.column_stack([x, y])


@pytest.mark.parametrize("perm", [(0, 1, 2), (1, 2, 0), (2, 0, 1), (0, 2, 1), (1, 0, 2),
                                  (2, 1, 0)])
def test_three_point_catalogs_exact(perm):
    dst = _map(TRUTH, TRIANGLE)[list(perm)]
    t, (s, d) = find_transform(TRIANGLE, dst)
    np.testing.assert_allclose(_map(t, TRIANGLE), _map(TRUTH, TRIANGLE), atol=1e-6)
    assert frame_error(t, TRUTH, (512, 512)) < 1e-6
    assert len(s) == 3 and len(d) == 3
    np.testing.assert_allclose(_map(t, s), d, atol=1e-6)


def test_three_point_table_catalogs():
    dst = _map(TRUTH, TRIANGLE)
    src_tab = Table({"x": TRIANGLE[:, 0], "y": TRIANGLE[:, 1], "flux": [3.0, 2.0, 1.0]})
    dst_tab = Table({"x": dst[:, 0], "y": dst[:, 1]})
    t, _ = find_transform(src_tab, dst_tab)
    assert frame_error(t, TRUTH, (512, 512)) < 1e-6


def test_table_with_photutils_column_names():
    dst = _map(TRUTH, TRIANGLE)
    src_tab = Table({"x_centroid": TRIANGLE[:, 0], "y_centroid": TRIANGLE[:, 1]})
    dst_tab = Table({"xcentroid": dst[:, 0], "ycentroid": dst[:, 1]})
    t, _ = find_transform(src_tab, dst_tab)
    assert frame_error(t, TRUTH, (512, 512)) < 1e-6


def test_large_catalogs_with_missing_and_extra_stars():
    rng = np.random.default_rng(20)
    src = rng.uniform(0, 1000, size=(150, 2))
    dst = _map(TRUTH, src)
    keep_s = rng.random(150) > 0.2
    keep_d = rng.random(150) > 0.2
    extra = rng.uniform(0, 1000, size=(30, 2))
    t, (s, d) = find_transform(src[keep_s], np.vstack([dst[keep_d], extra]))
    assert frame_error(t, TRUTH, (1000, 1000)) < 1e-6
    assert len(s) >= 60


def test_true_star_tables(small_pair):
    t, _ = find_transform(small_pair.source_stars, small_pair.target_stars)
    assert frame_error(t, small_pair.truth_matrix, small_pair.target.shape) < 1e-6


# -- (c) mirrored pairs --------------------------------------------------------------------

def test_mirrored_pair_found_by_default():
    pair = simulate_pair((384, 384), n_stars=200, flux_range=BRIGHT, rotation=40.0,
                         translation=(3.0, 8.0), mirror=True, seed=21)
    t, _ = find_transform(pair.source, pair.target)
    assert t.mirrored
    assert float(t.parity.value) == -1.0
    assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.1


def test_mirrored_pair_refused_when_mirror_not_allowed():
    pair = simulate_pair((256, 256), n_stars=100, flux_range=BRIGHT, rotation=40.0,
                         mirror=True, seed=22)
    with pytest.raises(TransformNotFoundError):
        find_transform(pair.source, pair.target, allow_mirror=False, max_sources=50)


def test_mirrored_catalog():
    mirrored = SimilarityTransform(scale=1.1, rotation=0.4 * u.rad, translation_x=5.0,
                                   translation_y=7.0, parity=-1)
    rng = np.random.default_rng(23)
    src = rng.uniform(0, 500, size=(40, 2))
    t, _ = find_transform(src, _map(mirrored, src))
    assert t.mirrored
    assert frame_error(t, mirrored, (500, 500)) < 1e-6


# -- (d) every input kind ------------------------------------------------------------------

def _ccd(data):
    return CCDData(data, unit="adu")


def _kind(kind, image, tmp_path, name):
    if kind == "ndarray":
        return image
    if kind == "masked":
        return np.ma.MaskedArray(image, mask=np.zeros(image.shape, bool))
    if kind == "nddata":
        return NDData(image)
    if kind == "ccddata":
        return _ccd(image)
    if kind in ("fits-path", "fits-str"):
        path = tmp_path / f"{name}.fits"
        fits.writeto(path, image, overwrite=True)
        return path if kind == "fits-path" else str(path)
    if kind == "primary-hdu":
        return fits.PrimaryHDU(image)
    if kind == "image-hdu":
        return fits.ImageHDU(image)
    if kind == "hdulist":
        return fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(image)])
    if kind == "catalog-table":
        return find_sources(image, n_sources=150)
    if kind == "catalog-array":
        tab = find_sources(image, n_sources=150)
        return np.column_stack([tab["x"], tab["y"]])
    if kind == "reference":
        return astroalign_nd.Reference(image)
    raise AssertionError(kind)


IMAGE_KINDS = ["ndarray", "masked", "nddata", "ccddata", "fits-path", "fits-str",
               "primary-hdu", "hdulist", "reference"]


@pytest.mark.parametrize("kind", IMAGE_KINDS)
def test_image_input_kinds_give_identical_results(kind, small_pair, small_result, tmp_path):
    src = _kind(kind, small_pair.source, tmp_path, "src")
    dst = _kind(kind, small_pair.target, tmp_path, "dst")
    t, _ = find_transform(src, dst)
    np.testing.assert_allclose(t.matrix, small_result[0].matrix, rtol=0, atol=1e-9)


@pytest.mark.parametrize("kind", ["catalog-table", "catalog-array"])
def test_catalog_input_kinds(kind, small_pair, tmp_path):
    src = _kind(kind, small_pair.source, tmp_path, "src")
    dst = _kind(kind, small_pair.target, tmp_path, "dst")
    t, _ = find_transform(src, dst)
    assert frame_error(t, small_pair.truth_matrix, small_pair.target.shape) < 0.1


@pytest.mark.parametrize("src_kind, dst_kind", [("ndarray", "catalog-table"),
                                                ("catalog-array", "ccddata"),
                                                ("fits-path", "nddata")])
def test_mixed_input_kinds(src_kind, dst_kind, small_pair, tmp_path):
    src = _kind(src_kind, small_pair.source, tmp_path, "src")
    dst = _kind(dst_kind, small_pair.target, tmp_path, "dst")
    t, _ = find_transform(src, dst)
    assert frame_error(t, small_pair.truth_matrix, small_pair.target.shape) < 0.1


def test_png_path(small_pair, tmp_path):
    skio = pytest.importorskip("skimage.io")
    paths = []
    for name, img in (("s", small_pair.source), ("t", small_pair.target)):
        p = tmp_path / f"{name}.png"
        # Image files hold the top row first; they are read bottom-up (row 0 = the bottom,
        # as in FITS): the file holds the array's rows in reverse.
        skio.imsave(p, np.clip(img, 0, 65535).astype(np.uint16)[::-1], check_contrast=False)
        paths.append(p)
    t, _ = find_transform(*paths)
    assert frame_error(t, small_pair.truth_matrix, small_pair.target.shape) < 0.1


def test_masks_are_honoured(small_pair):
    """Sources in masked regions (mask, NaN) are not used as control points."""
    src = np.ma.MaskedArray(small_pair.source, mask=np.zeros((256, 256), bool))
    src.mask[:, :100] = True
    tgt = small_pair.target.copy()
    tgt[:80, :] = np.nan
    t, (s, d) = find_transform(src, tgt)
    assert frame_error(t, small_pair.truth_matrix, small_pair.target.shape) < 0.1
    assert np.all(s[:, 0] > 99.5)
    assert np.all(d[:, 1] > 79.5)


def test_ccddata_mask_is_honoured(small_pair):
    mask = np.zeros((256, 256), bool)
    mask[128:, :] = True
    src = CCDData(small_pair.source, unit="adu", mask=mask)
    t, (s, d) = find_transform(src, small_pair.target)
    assert np.all(s[:, 1] < 127.5)
    assert frame_error(t, small_pair.truth_matrix, small_pair.target.shape) < 0.1


# -- (e) determinism -----------------------------------------------------------------------

def test_deterministic(small_pair, small_result):
    t2, (s2, d2) = find_transform(small_pair.source, small_pair.target)
    t1, (s1, d1) = small_result
    np.testing.assert_array_equal(t1.matrix, t2.matrix)
    np.testing.assert_array_equal(s1, s2)
    np.testing.assert_array_equal(d1, d2)
    assert t1.meta["quality"]["rms"] == t2.meta["quality"]["rms"]


# -- (f) the caller's data is untouched ----------------------------------------------------

def test_caller_arrays_untouched(small_pair):
    src = small_pair.source.copy()
    src[5:15, 5:15] = np.nan
    tgt = np.ma.MaskedArray(small_pair.target.copy(), mask=np.zeros((256, 256), bool))
    tgt.mask[200:, 200:] = True
    src0, tgt0, mask0 = src.copy(), tgt.data.copy(), tgt.mask.copy()
    find_transform(src, tgt)
    np.testing.assert_array_equal(src, src0)
    np.testing.assert_array_equal(tgt.data, tgt0)
    np.testing.assert_array_equal(tgt.mask, mask0)


def test_caller_ccddata_untouched(small_pair):
    mask = np.zeros((256, 256), bool)
    mask[:20] = True
    src = CCDData(small_pair.source.copy(), unit="adu", mask=mask,
                  uncertainty=StdDevUncertainty(np.full((256, 256), 11.0, np.float32)),
                  meta={"OBJECT": "sim", "EXPTIME": 30.0})
    tgt = CCDData(small_pair.target.copy(), unit="adu")
    src0, tgt0 = copy.deepcopy(src), copy.deepcopy(tgt)
    find_transform(src, tgt)
    for new, old in ((src, src0), (tgt, tgt0)):
        np.testing.assert_array_equal(new.data, old.data)
        assert new.unit == old.unit
        assert dict(new.meta) == dict(old.meta)
        if old.mask is None:
            assert new.mask is None
        else:
            np.testing.assert_array_equal(new.mask, old.mask)
        if old.uncertainty is not None:
            np.testing.assert_array_equal(new.uncertainty.array, old.uncertainty.array)
            assert type(new.uncertainty) is type(old.uncertainty)


def test_caller_catalog_untouched():
    src = Table({"x": TRIANGLE[:, 0].copy(), "y": TRIANGLE[:, 1].copy()})
    dst_arr = _map(TRUTH, TRIANGLE)
    src0, dst0 = src.copy(), dst_arr.copy()
    find_transform(src, dst_arr)
    np.testing.assert_array_equal(dst_arr, dst0)
    for c in ("x", "y"):
        np.testing.assert_array_equal(src[c], src0[c])


# -- (g) failures --------------------------------------------------------------------------

def test_unrelated_fields_raise():
    a, _ = simulate_field((256, 256), n_stars=80, flux_range=BRIGHT, seed=31)
    b, _ = simulate_field((256, 256), n_stars=80, flux_range=BRIGHT, seed=32)
    # max_sources=50: no escalation, which would only make this test slower
    with pytest.raises(TransformNotFoundError) as info:
        find_transform(a, b, max_sources=50)
    assert isinstance(info.value, AstroalignError)
    msg = str(info.value)
    m = re.search(r"source gave (\d+) sources and the\s+target (\d+)", msg)
    assert m, msg
    assert int(m.group(1)) > 10 and int(m.group(2)) > 10
    assert re.search(r"(\d+) triangle matches", msg), msg
    m = re.search(r"best with (\d+) inliers", msg)
    assert m, msg


def test_blank_image_raises_too_few_sources(small_pair):
    blank = np.full((256, 256), 100.0, dtype=np.float32)
    for src, dst in ((blank, small_pair.target), (small_pair.source, blank)):
        with pytest.raises(TooFewSourcesError) as info:
            find_transform(src, dst)
        assert isinstance(info.value, AstroalignError)
        assert isinstance(info.value, ValueError)
        assert "at least 3" in str(info.value)


def test_pure_noise_raises(small_pair):
    noise = np.random.default_rng(33).normal(100.0, 10.0, (256, 256))
    with pytest.raises(AstroalignError):
        find_transform(noise, small_pair.target)


def test_two_point_catalog_raises():
    with pytest.raises(TooFewSourcesError):
        find_transform(TRIANGLE[:2], _map(TRUTH, TRIANGLE))


def test_exception_hierarchy():
    assert issubclass(TooFewSourcesError, AstroalignError)
    assert issubclass(TooFewSourcesError, ValueError)
    assert issubclass(TransformNotFoundError, AstroalignError)


@pytest.mark.parametrize("bad", ["homography", "similarity2", 3, None])
def test_bad_transform_type(bad):
    with pytest.raises(ValueError):
        find_transform(TRIANGLE, _map(TRUTH, TRIANGLE), transform_type=bad)


def test_unknown_keyword():
    with pytest.raises(TypeError, match="unexpected keyword"):
        find_transform(TRIANGLE, _map(TRUTH, TRIANGLE), n_sorces=30)
    with pytest.raises(TypeError):
        find_match(TRIANGLE, _map(TRUTH, TRIANGLE), foo=1)


def test_every_detection_and_matching_option_is_routed_and_checked():
    """The routed options follow the signatures, and each has a range check."""
    import inspect

    from astroalign_nd import registration
    from astroalign_nd.config import OPTIONS
    from astroalign_nd.detection import find_sources

    det = set(inspect.signature(find_sources).parameters) - {"image", "mask", "n_sources"}
    assert set(registration._DETECT_KEYS) == det
    assert {"tolerance", "n_neighbors", "max_hypotheses"} <= set(registration._MATCH_KEYS)
    assert set(registration._DETECT_KEYS + registration._MATCH_KEYS) <= set(OPTIONS)


def test_refine_centroids_reaches_detection(small_pair):
    t, _ = find_transform(small_pair.source, small_pair.target, refine_centroids=False)
    assert frame_error(t, small_pair.truth_matrix, small_pair.target.shape) < 0.5
    ref = astroalign_nd.Reference(small_pair.target, refine_centroids=False)
    assert ref.detect_options == {"refine_centroids": False}
    with pytest.raises(TypeError, match="refine_centroids must be True or False"):
        find_transform(small_pair.source, small_pair.target, refine_centroids="no")


@pytest.mark.parametrize("kwargs, exc", [
    (dict(n_sources=2), ValueError),
    (dict(n_sources=10.5), TypeError),
    (dict(n_sources="50"), TypeError),
    (dict(max_sources=0), ValueError),
])
def test_bad_counts(kwargs, exc):
    with pytest.raises(exc):
        find_transform(TRIANGLE, _map(TRUTH, TRIANGLE), **kwargs)


@pytest.mark.parametrize("bad, exc", [
    (None, TypeError),
    ({"x": 1}, TypeError),
    (np.zeros(50), ValueError),
    (np.zeros((4, 4)), ValueError),
    (np.full((32, 32), "a"), TypeError),
    ("/nonexistent/file.fits", FileNotFoundError),
    (Table({"a": [1.0, 2.0, 3.0], "b": [1.0, 2.0, 3.0]}), ValueError),
])
def test_bad_inputs(bad, exc, small_pair):
    with pytest.raises(exc):
        find_transform(bad, small_pair.target)


# -- (h) quality ---------------------------------------------------------------------------

def test_quality_meta(small_pair, small_result):
    t, (s, d) = small_result
    q = t.meta["quality"]
    for key in ("n_matches", "rms", "covariance", "log10_false_alarm"):
        assert key in q
    assert q["n_matches"] == len(s) == len(d)
    assert q["n_matches"] >= 40
    # rms is the RMS distance of the matched pairs under the fitted transform
    rms = np.sqrt(np.mean(np.sum((_map(t, s) - d) ** 2, axis=1)))
    assert q["rms"] == pytest.approx(rms, rel=1e-6, abs=1e-9)
    assert 0 < q["rms"] < 0.2
    cov = np.asarray(q["covariance"])
    assert cov.shape == (4, 4)
    assert np.all(np.isfinite(cov)) and np.all(np.diag(cov) > 0)
    assert q["log10_false_alarm"] < -6
    # the matched points really are pairs of the same stars
    np.testing.assert_allclose(_map(small_pair.transform, s), d, atol=1.0)


def test_covariance_matches_actual_error(small_pair, small_result):
    t = small_result[0]
    sig = np.sqrt(np.diag(t.meta["quality"]["covariance"]))
    truth = small_pair.transform
    # translation of the fitted model vs truth, in units of its predicted error
    diff = np.abs(t.translation - np.asarray(truth.matrix)[:2, 2])
    assert np.all(diff < 6 * sig[2:] + 1e-3)


def test_find_match_returns_match_result(small_pair, small_result):
    r = find_match(small_pair.source, small_pair.target)
    assert isinstance(r, MatchResult)
    np.testing.assert_array_equal(r.transform.matrix, small_result[0].matrix)
    assert r.n_matches == len(r.source_index) == len(r.target_index)
    assert r.residuals.shape == (r.n_matches, 2)
    assert r.n_source >= r.n_matches and r.n_target >= r.n_matches
    assert r.n_triangle_matches >= 1 and r.n_hypotheses >= 1
    np.testing.assert_array_equal(r.source_points, small_result[1][0])
    np.testing.assert_array_equal(r.target_points, small_result[1][1])
    assert r.n_sources_used == 50 and r.model_misfit >= 0 and r.predicted_error > 0
    # The dict of earlier versions still reads and writes the same fields.
    np.testing.assert_array_equal(r.extra["source_points"], small_result[1][0])
    assert r.extra["n_sources_used"] == 50
    r.extra.update(n_sources_used=7, note="kept")
    assert r.n_sources_used == 7 and r.extra["note"] == "kept" and "note" in dict(r.extra)


def test_match_points_takes_the_search_context():
    """The escalation's context (control points, earlier trials, prebuilt
    triangles) is public in match_points, but not an option of find_transform."""
    from astroalign_nd.matching import build_asterisms, match_points

    src = np.random.default_rng(3).uniform(0, 500, (40, 2))
    dst = _map(TRUTH, src)
    r = match_points(src, dst)
    assert r.n_sources_used is None and r.source_points.shape == (r.n_matches, 2)
    np.testing.assert_array_equal(r.target_points, dst[r.target_index])
    # Control points: triangles of the first 12 only, every star refined.
    ctl = match_points(src, dst, n_control=12,
                       source_asterisms=build_asterisms(src[:12]),
                       target_asterisms=build_asterisms(dst[:12]))
    assert ctl.n_matches == 40 and ctl.n_hypotheses <= r.n_hypotheses
    # Earlier trials count in the false-alarm probability.
    later = match_points(src, dst, prior_trials=10**6)
    assert later.log10_false_alarm > r.log10_false_alarm
    for name, value in (("n_control", 10), ("prior_trials", 5), ("source_asterisms", None)):
        with pytest.raises(TypeError, match="unexpected keyword"):
            find_transform(src, dst, **{name: value})


# -- (i) transform types -------------------------------------------------------------------

def test_translation_type():
    pair = simulate_pair((384, 384), n_stars=200, flux_range=BRIGHT,
                         translation=(12.3, -7.6), seed=41)
    t, _ = find_transform(pair.source, pair.target, transform_type="translation")
    assert type(t) is TranslationTransform
    assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.1
    np.testing.assert_allclose(t.translation, [12.3, -7.6], atol=0.05)


def test_euclidean_type():
    pair = simulate_pair((384, 384), n_stars=200, flux_range=BRIGHT, rotation=63.0,
                         translation=(-5.5, 2.25), seed=42)
    t, _ = find_transform(pair.source, pair.target, transform_type="euclidean")
    assert type(t) is EuclideanTransform
    assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.1
    assert t.rotation_deg == pytest.approx(63.0, abs=0.02)


def test_similarity_type_by_class():
    pair = simulate_pair((384, 384), n_stars=200, flux_range=BRIGHT, rotation=-20.0,
                         scale=1.1, seed=43)
    t, _ = find_transform(pair.source, pair.target, transform_type=SimilarityTransform)
    assert type(t) is SimilarityTransform
    assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.1


def test_affine_type():
    truth = AffineTransform(a11=1.01, a12=0.02, a21=-0.01, a22=0.99,
                            translation_x=-10.0, translation_y=12.0)
    pair = simulate_pair((384, 384), n_stars=200, flux_range=BRIGHT, transform=truth,
                         seed=44)
    t, _ = find_transform(pair.source, pair.target, transform_type="affine")
    assert type(t) is AffineTransform
    assert frame_error(t, pair.truth_matrix, pair.target.shape) < 0.1
    # a similarity cannot represent the shear, and says so
    with pytest.warns(PoorFitWarning):
        s, _ = find_transform(pair.source_stars, pair.target_stars)
    assert frame_error(s, pair.truth_matrix, pair.target.shape) > 1.0


@pytest.mark.parametrize("inputs, seed", [("images", 44), ("catalogs", 45)])
def test_affine_type_strong_shear(inputs, seed):
    truth = AffineTransform(a11=1.05, a12=0.08, a21=-0.03, a22=0.97,
                            translation_x=-10.0, translation_y=12.0)
    pair = simulate_pair((384, 384), n_stars=200, flux_range=BRIGHT, transform=truth,
                         seed=seed)
    if inputs == "images":
        src, dst, tol = pair.source, pair.target, 0.1
    else:
        src, dst, tol = pair.source_stars, pair.target_stars, 1e-6
    t, _ = find_transform(src, dst, transform_type="affine")
    assert type(t) is AffineTransform
    err = frame_error(t, pair.truth_matrix, pair.target.shape)
    assert err < tol, (f"{err:.3f} px off; n_matches={t.meta['quality']['n_matches']}, "
                       f"rms={t.meta['quality']['rms']:.2f}")


@pytest.mark.parametrize("transform_type, cls", [("translation", TranslationTransform),
                                                 ("euclidean", EuclideanTransform),
                                                 ("similarity", SimilarityTransform),
                                                 ("affine", AffineTransform)])
def test_transform_types_on_catalogs(transform_type, cls):
    truth = {"translation": TranslationTransform(3.5, -8.25),
             "euclidean": EuclideanTransform(rotation=2.0 * u.rad, translation_x=300.0,
                                             translation_y=20.0),
             "similarity": TRUTH,
             "affine": AffineTransform(a11=1.1, a12=0.1, a21=-0.05, a22=0.9,
                                       translation_x=4.0, translation_y=3.0)}[transform_type]
    rng = np.random.default_rng(45)
    src = rng.uniform(0, 400, size=(40, 2))
    t, _ = find_transform(src, _map(truth, src), transform_type=transform_type)
    assert type(t) is cls
    assert frame_error(t, truth, (400, 400)) < 1e-6


def test_blank_image_message_does_not_invent_a_star_width(small_pair):
    # A constant frame has no stellar width: the advice must not quote "0.0 px".
    blank = np.full((256, 256), 100.0, dtype=np.float32)
    with pytest.raises(TooFewSourcesError, match="looks like a star") as info:
        find_transform(blank, small_pair.target)
    assert "0.0 px" not in str(info.value)


@pytest.mark.parametrize("n_threads", [1, 2])
def test_both_frames_detected_at_once_same_result_and_errors(small_pair, n_threads):
    # With two threads the target's stars are detected beside the source's:
    # the transform must be the same to the bit, errors must name the frame
    # that failed (the source first, as when detecting one after the other),
    # and the caller's warning filters must be left as they were.
    import warnings

    with astroalign_nd.conf.set_temp("num_threads", 1):
        ref, _ = find_transform(small_pair.source, small_pair.target)
    filters = list(warnings.filters)
    with astroalign_nd.conf.set_temp("num_threads", n_threads):
        t, _ = find_transform(small_pair.source, small_pair.target)
        assert warnings.filters == filters
        np.testing.assert_array_equal(t.matrix, ref.matrix)
        assert frame_error(t, small_pair.truth_matrix, small_pair.target.shape) < 0.1
        blank = np.full((256, 256), 100.0, dtype=np.float32)
        for src, dst, role in ((blank, small_pair.target, "source"),
                               (small_pair.source, blank, "target"), (blank, blank, "source")):
            with pytest.raises(TooFewSourcesError, match=f"the {role} gave"):
                find_transform(src, dst)
        assert warnings.filters == filters
