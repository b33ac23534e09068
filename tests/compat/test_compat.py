# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Tests of `astroalign_nd.compat`, astroalign 2.6's API on the astroalign_nd engine.

astroalign's own suite runs against it in tests/astroalign_suite; these check
recovered transforms against the simulations' truth, the transform and input
types, the footprint, and the advice the main API gives for astroalign's
keywords.
"""

import inspect
import warnings

import numpy as np
import pytest
from astropy.nddata import CCDData, NDData
from numpy.testing import assert_allclose, assert_array_equal
from skimage import transform as sktf

import astroalign_nd
from astroalign_nd import (PoorFitWarning, TooFewSourcesError, TransformNotFoundError,
                           compat as aa)
from astroalign_nd.simulate import simulate_pair
from astroalign_nd.transforms import from_matrix

from _helpers import frame_error


@pytest.fixture(scope="module")
def pair():
    return simulate_pair((256, 256), n_stars=100, flux_range=(2e3, 5e5), rotation=33.0,
                         scale=1.05, translation=(4.3, -2.1), seed=5)


@pytest.fixture(scope="module")
def found(pair):
    return aa.find_transform(pair.source, pair.target)


# -- find_transform -------------------------------------------------------------------

def test_find_transform_recovers_truth(pair, found):
    t, (src, dst) = found
    assert type(t) is sktf.SimilarityTransform
    assert frame_error(t.params, pair.truth_matrix, pair.target.shape) < 0.1
    assert t.scale == pytest.approx(1.05, abs=1e-3)
    assert np.degrees(t.rotation) == pytest.approx(33.0, abs=0.05)
    # The matched points are what the transform maps onto each other.
    assert src.shape == dst.shape and src.shape[1] == 2 and len(src) >= 20
    assert np.median(np.hypot(*(t(src) - dst).T)) < 0.2


def test_transform_works_as_astroalign_s(pair, found):
    t, (src, dst) = found
    # skimage's API: params, translation, inverse, matrix_transform, calls on (N, 2).
    assert_allclose(t.params[:2, 2], t.translation)
    assert_allclose(t.inverse(t(src)), src, atol=1e-9)
    assert_allclose(aa.matrix_transform(src, t.params), t(src))
    # estimate_transform is skimage's, as in astroalign.
    est = aa.estimate_transform("similarity", src, dst)
    assert frame_error(est.params, pair.truth_matrix, pair.target.shape) < 0.2


def test_find_transform_inputs_agree(pair, found):
    # NDData, CCDData, masked arrays and (channels-last) RGB all give the same answer.
    t0 = found[0].params
    for wrap in (NDData, lambda a: CCDData(a, unit="adu"), np.ma.MaskedArray,
                 lambda a: np.repeat(a[..., None], 3, axis=2)):
        t, _ = aa.find_transform(wrap(pair.source), wrap(pair.target))
        assert frame_error(t.params, t0, pair.target.shape) < 1e-6


def test_find_transform_catalogs():
    rng = np.random.default_rng(1)
    src = rng.uniform(0, 500, (40, 2))
    truth = sktf.SimilarityTransform(scale=0.9, rotation=0.4, translation=(30, -12))
    dst = truth(src)[::-1] + rng.normal(0, 0.05, (40, 2))  # reordered, noisy
    t, (s, d) = aa.find_transform([tuple(p) for p in src], dst)
    assert frame_error(t.params, truth.params, (500, 500)) < 0.1
    assert len(s) == 40


def test_mirrored_pair_gives_affine(tmp_path):
    pair = simulate_pair((256, 256), n_stars=120, flux_range=(2e3, 5e5), rotation=40.0,
                         mirror=True, seed=3)
    t, _ = aa.find_transform(pair.source, pair.target)
    # A skimage similarity cannot hold a reflection.
    assert type(t) is sktf.AffineTransform
    assert np.linalg.det(t.params[:2, :2]) < 0
    assert frame_error(t.params, pair.truth_matrix, pair.target.shape) < 0.15


def test_hot_pixels_and_cosmic_rays():
    pair = simulate_pair((256, 256), n_stars=80, rotation=10.0, n_hot_pixels=300,
                         n_cosmic_rays=50, seed=3)
    t, _ = aa.find_transform(pair.source, pair.target)
    assert frame_error(t.params, pair.truth_matrix, pair.target.shape) < 0.2


def test_sparse_field():
    pair = simulate_pair((256, 256), n_stars=30, rotation=-20.0, scale=1.3, seed=3)
    # 11 matched stars at 0.58 px RMS: the answer (0.33 px off) says that it
    # can be up to 1.4 px off (3 sigma), which is astroalign_nd's warning.
    with pytest.warns(PoorFitWarning, match="uncertain"):
        t, _ = aa.find_transform(pair.source, pair.target)
    assert frame_error(t.params, pair.truth_matrix, pair.target.shape) < 0.5


def test_few_star_catalogs_follow_astroalign_s_rule():
    # Four stars measured to 0.3 px: too few for the false-alarm test, so
    # astroalign's acceptance rule decides.
    src = np.array([[100.0, 150.0], [120.0, 200.0], [400.0, 200.0], [400.0, 320.0]])
    truth = sktf.SimilarityTransform(rotation=0.8, translation=(300.0, -40.0))
    dst = truth(src) + np.random.default_rng(0).normal(0.0, 0.3, (4, 2))
    t, (s, d) = aa.find_transform(src, dst[[2, 0, 3, 1]])
    assert frame_error(t.params, truth.params, (512, 512)) < 0.5
    assert len(s) == 4
    # One star of four off: 3 of 4 agree, below MIN_MATCHES_FRACTION.
    bad = dst.copy()
    bad[3] += 40.0
    with pytest.raises(aa.MaxIterError, match="astroalign's rule"):
        aa.find_transform(src, bad)
    # Three stars of three: astroalign accepts its single triangle.
    t, (s, d) = aa.find_transform(src[:3], dst[:3])
    assert frame_error(t.params, truth.params, (512, 512)) < 1.0
    assert len(s) == 3


def test_uncertain_few_star_fit_warns_only_when_accepted():
    src = np.array([[100.0, 150.0], [120.0, 200.0], [400.0, 200.0], [400.0, 320.0],
                    [250.0, 400.0]])
    truth = sktf.SimilarityTransform(rotation=0.8, translation=(300.0, -40.0))
    dst = truth(src) + np.random.default_rng(0).normal(0.0, 1.0, (5, 2))
    with pytest.warns(PoorFitWarning, match="uncertain"):
        t, (s, d) = aa.find_transform(src, dst)
    assert frame_error(t.params, truth.params, (512, 512)) < 3.0
    # Two stars of five off: rejected, and the rejected candidate's warning is not shown.
    bad = dst.copy()
    bad[[1, 3]] += 40.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(aa.MaxIterError, match=r"3 of the \d stars"):
            aa.find_transform(src, bad)


def test_errors():
    rng = np.random.default_rng(2)
    with pytest.raises(aa.MaxIterError) as info:
        aa.find_transform(rng.uniform(0, 500, (30, 2)), rng.uniform(0, 500, (30, 2)))
    # astroalign's exception, and ours.
    assert isinstance(info.value, RuntimeError)
    assert isinstance(info.value, TransformNotFoundError)
    with pytest.raises(ValueError):  # fewer than 3 stars, as astroalign
        aa.find_transform([(1.0, 2.0), (5.0, 1.0)], [(1.0, 2.0), (5.0, 1.0)])
    with pytest.raises(TypeError, match="Input type for source not supported"):
        aa.find_transform("not an image", np.zeros((64, 64)))
    with pytest.raises(TypeError, match="Input type for target not supported"):
        aa.find_transform(np.zeros((64, 64)), {"a": 1})
    with pytest.raises(ValueError, match="max_control_points"):
        aa.find_transform(np.zeros((64, 64)), np.zeros((64, 64)), max_control_points=2)
    with pytest.raises(TooFewSourcesError):  # an empty frame
        aa.find_transform(np.zeros((64, 64)), np.zeros((64, 64)))
    with pytest.raises(ValueError, match="mask of the image's shape"):
        aa.find_transform(NDData(np.zeros((64, 64)), mask=np.zeros((32, 32), bool)),
                          np.zeros((64, 64)))
    ident = sktf.SimilarityTransform()
    with pytest.raises(TypeError, match="image of numbers"):
        aa.apply_transform(ident, "not an image", np.zeros((8, 8)))
    with pytest.raises(TypeError, match="transform must be"):
        aa.apply_transform((ident, (None, None)), np.zeros((8, 8)), np.zeros((8, 8)))


def test_constants_are_read_at_call_time(monkeypatch, pair, found):
    monkeypatch.setattr(aa, "NUM_NEAREST_NEIGHBORS", 2)
    with pytest.raises(ValueError, match="NUM_NEAREST_NEIGHBORS"):
        aa.find_transform(pair.source, pair.target)
    monkeypatch.setattr(aa, "NUM_NEAREST_NEIGHBORS", 6)
    monkeypatch.setattr(aa, "PIXEL_TOL", 1.5)
    t, _ = aa.find_transform(pair.source, pair.target)
    assert frame_error(t.params, pair.truth_matrix, pair.target.shape) < 0.1


# -- apply_transform and register ---------------------------------------------------

def test_register_round_trip(pair, found):
    aligned, footprint = aa.register(pair.source, pair.target)
    assert type(aligned) is np.ndarray and aligned.dtype == pair.source.dtype == np.float32
    assert footprint.dtype == bool and footprint.shape == pair.target.shape == aligned.shape
    ref, _ = aa.apply_transform(found[0], pair.source, pair.target)
    assert_allclose(aligned, ref)
    # The registered source looks like the target where it has information.
    inside = ~footprint
    corr = np.corrcoef(aligned[inside], pair.target[inside])[0, 1]
    assert corr > 0.9
    # Outside the source: the source's median, as astroalign fills it.
    assert_allclose(aligned[footprint], np.median(pair.source))


def test_footprint_is_the_mapped_source_frame(pair):
    t = sktf.SimilarityTransform(matrix=pair.truth_matrix)
    _, footprint = aa.apply_transform(t, pair.source, pair.target)
    ny, nx = pair.target.shape
    yy, xx = np.mgrid[:ny, :nx]
    back = t.inverse(np.column_stack([xx.ravel(), yy.ravel()])).reshape(ny, nx, 2)
    sx, sy = back[..., 0], back[..., 1]
    sny, snx = pair.source.shape
    # Well inside the source: information; outside it: none.  The bicubic
    # kernel needs its 4x4 support inside, so a 2-pixel band in between.
    well_inside = (sx >= 2) & (sx <= snx - 3) & (sy >= 2) & (sy <= sny - 3)
    outside = (sx < -0.5) | (sx > snx - 0.5) | (sy < -0.5) | (sy > sny - 0.5)
    assert not footprint[well_inside].any()
    assert footprint[outside].all()
    assert footprint.sum() < outside.sum() + 4 * (nx + ny) * 2


@pytest.mark.parametrize("make", [
    lambda m: sktf.SimilarityTransform(matrix=m),
    lambda m: sktf.AffineTransform(matrix=m),
    lambda m: sktf.ProjectiveTransform(matrix=m),
    lambda m: from_matrix(m),
    lambda m: m,
], ids=["skimage-similarity", "skimage-affine", "skimage-projective", "astroalign_nd", "matrix"])
def test_apply_transform_accepts_transforms(pair, make):
    m = pair.truth_matrix
    ref, ref_fp = aa.apply_transform(sktf.SimilarityTransform(matrix=m), pair.source,
                                     pair.target)
    out, fp = aa.apply_transform(make(m), pair.source, pair.target)
    assert_allclose(out, ref, atol=1e-9)
    assert_array_equal(fp, ref_fp)


@pytest.mark.parametrize("dtype, out_dtype", [
    (np.float32, np.float32), (np.float64, np.float64), (np.int32, np.float64),
    (np.uint8, np.float64), (np.uint16, np.float64)])
def test_apply_transform_dtypes(dtype, out_dtype):
    # As astroalign's warp returns them.
    img = (np.arange(256) % 200).reshape(16, 16).astype(dtype)
    out, fp = aa.apply_transform(sktf.EuclideanTransform(translation=(1.5, 0.3)), img, img)
    assert out.dtype == out_dtype and fp.dtype == bool
    assert out.min() >= 0 and out.max() <= 199  # clipped to the input's range


def test_apply_transform_euclidean_shift_is_exact():
    img = np.arange(64.0).reshape(8, 8)
    out, fp = aa.apply_transform(sktf.EuclideanTransform(translation=(2, 1)), img, img)
    assert_array_equal(out[1:, 2:], img[:-1, :-2])
    assert fp[0].all() and fp[:, :2].all() and not fp[1:, 2:].any()


def test_rotation_by_90_degrees_lands_on_pixel_centres():
    # cos(pi/2) = 6e-17 in floating point: the pixels must still be copied exactly.
    img = np.arange(16.0).reshape(4, 4)
    t = sktf.SimilarityTransform(rotation=np.pi / 2, translation=(3, 0))
    out, fp = aa.apply_transform(t, img, img)
    assert not fp.any()
    assert_array_equal(out, np.rot90(img, -1))


def test_propagate_mask_and_fill_value():
    img = np.arange(100.0).reshape(10, 10)
    mask = np.zeros((10, 10), bool)
    mask[5, 5] = True
    nd = NDData(img, mask=mask)
    t = sktf.EuclideanTransform(translation=(1, 0))
    out, fp = aa.apply_transform(t, nd, nd)
    assert not fp[5, 6] and out[5, 6] == 55.0  # no propagation by default
    out, fp = aa.apply_transform(t, nd, nd, propagate_mask=True)
    assert fp[5, 6] and fp.sum() == 10 + 1  # first column, and the masked pixel
    assert out[5, 6] == 55.0  # astroalign keeps the value unless fill_value is given
    out, fp = aa.apply_transform(t, nd, nd, fill_value=-1.0, propagate_mask=True)
    assert_array_equal(out[fp], -1.0)
    assert (out[~fp] >= 0).all()


def test_nan_pixels_are_in_the_footprint():
    img = np.arange(100.0).reshape(10, 10)
    img[4, 4] = np.nan
    out, fp = aa.apply_transform(sktf.EuclideanTransform(translation=(0.5, 0.0)), img, img)
    assert np.isfinite(out).all()
    # Bicubic taps floor(x)-1 .. floor(x)+2: the NaN reaches 4 output pixels of its row.
    # (Columns 0, 1 and 9 lack the kernel's support: the frame's edge.)
    assert fp[4, 3:7].all() and not fp[4, 2] and not fp[4, 7:9].any()
    assert not fp[3, 2:9].any() and not fp[5, 2:9].any()


def test_inputs_are_not_modified(pair):
    src = pair.source.copy()
    mask = np.zeros(src.shape, bool)
    mask[10:20, 10:20] = True
    ccd = CCDData(src, mask=mask, unit="adu")
    aa.register(ccd, pair.target, fill_value=0.0, propagate_mask=True)
    assert_array_equal(ccd.data, pair.source)
    assert_array_equal(ccd.mask, mask)


def test_rgb_register_keeps_channels(pair):
    rgb_src = np.dstack([pair.source, 2 * pair.source, 3 * pair.source])
    rgb_dst = np.dstack([pair.target] * 3)
    out, fp = aa.register(rgb_src, rgb_dst)
    assert out.shape == rgb_dst.shape and fp.shape == pair.target.shape
    assert_allclose(out[~fp][:, 1], 2 * out[~fp][:, 0], rtol=1e-6)


def test_find_sources_helper(pair):
    pts = aa._find_sources(pair.source)
    truth = np.column_stack([pair.source_stars["x"], pair.source_stars["y"]])
    d = np.min(np.hypot(*(pts[:, None, :] - truth[None, :, :]).transpose(2, 0, 1)), axis=1)
    assert pts.shape[1] == 2 and len(pts) >= 30
    assert np.mean(d < 1.0) > 0.9


# -- the API itself ---------------------------------------------------------------------

def test_signatures_are_astroalign_s():
    expected = {
        "find_transform": "(source, target, max_control_points=50, detection_sigma=5, "
                          "min_area=5)",
        "apply_transform": "(transform, source, target, fill_value=None, "
                           "propagate_mask=False)",
        "register": "(source, target, fill_value=None, propagate_mask=False, "
                    "max_control_points=50, detection_sigma=5, min_area=5)",
    }
    for name, sig in expected.items():
        params = inspect.signature(getattr(aa, name)).parameters.values()
        got = "(" + ", ".join(str(p.replace(annotation=inspect.Parameter.empty))
                              for p in params) + ")"
        assert got == sig
    assert set(aa.__all__) == {"MIN_MATCHES_FRACTION", "MaxIterError", "NUM_NEAREST_NEIGHBORS",
                               "PIXEL_TOL", "apply_transform", "estimate_transform",
                               "find_transform", "matrix_transform", "register"}
    assert (aa.PIXEL_TOL, aa.MIN_MATCHES_FRACTION, aa.NUM_NEAREST_NEIGHBORS) == (2, 0.8, 5)


def test_signatures_match_installed_astroalign():
    real = pytest.importorskip("astroalign")
    # The vendored suite's alias must not leak into the rest of the session.
    assert real is not aa
    assert set(real.__all__) == set(aa.__all__)
    for name in ("find_transform", "apply_transform", "register"):
        ours = inspect.signature(getattr(aa, name)).parameters
        theirs = inspect.signature(getattr(real, name)).parameters
        assert [(p.name, p.default, p.kind) for p in ours.values()] == \
            [(p.name, p.default, p.kind) for p in theirs.values()]


def test_compat_is_an_attribute_of_the_package():
    import importlib

    assert importlib.import_module("astroalign_nd").compat is aa
    assert "compat" in dir(astroalign_nd)


@pytest.mark.parametrize("keyword, value, hint", [
    ("max_control_points", 30, "n_sources"),
    ("detection_sigma", 3, "nsigma"),
    ("min_area", 5, "no equivalent"),
    ("propagate_mask", True, "mask always holds"),
])
def test_main_api_names_our_equivalents(pair, keyword, value, hint):
    for func in (astroalign_nd.find_transform, astroalign_nd.register,
                 lambda s, t, **kw: astroalign_nd.Reference(s, **kw),
                 lambda s, t, **kw: astroalign_nd.register_batch([s], t, **kw)):
        with pytest.raises(TypeError, match=hint) as info:
            func(pair.source, pair.target, **{keyword: value})
        assert keyword in str(info.value) and "compat" in str(info.value)


def test_unknown_keyword_without_astroalign_advice(pair):
    with pytest.raises(TypeError) as info:
        astroalign_nd.find_transform(pair.source, pair.target, not_a_keyword=1)
    assert "not_a_keyword" in str(info.value) and "astroalign" not in str(info.value)


def test_apply_transform_names_astroalign_keyword():
    """The main API's apply_transform says what to use instead of propagate_mask."""
    from astroalign_nd import apply_transform
    from astroalign_nd.transforms import SimilarityTransform

    img = np.ones((16, 16), np.float32)
    with pytest.raises(TypeError, match="propagate_mask.*mask always holds"):
        apply_transform(SimilarityTransform(), img, img, propagate_mask=True)
