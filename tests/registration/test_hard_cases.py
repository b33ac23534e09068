# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Hard cases and trust (issue 5): solve what astroalign cannot, and never
return a wrong answer.

Every test simulates a pair with a known source -> target transform and
checks the recovered transform over the whole target frame:
``max |T_est(T_true^-1(p)) - p|`` for a grid of target pixels ``p``
(`frame_error`).  The tolerance is 0.1 px where the data allow it, looser
where the centroids themselves are noisy (the reason is given at each).
One seed per case keeps the file fast; ``benchmarks/bench_hard_cases.py``
runs several seeds and compares with astroalign, aafitrans and spalipy.

Three tests are regression tests of failures found while writing this
file and fixed since: 1:3 pixel-scale pairs that ran out of triangle
hypotheses (depth-matched escalation), a 30x sky gradient that made
detection return nothing (sky map now extrapolated at the frame edges),
and a low-SNR fit 1.6 px off without a warning (predicted-error warning).
"""

import warnings

import numpy as np
import pytest
from astropy import units as u

import astroalign_nd
from astroalign_nd import (AffineTransform, AstroalignError, PoorFitWarning,
                           SimilarityTransform, TransformNotFoundError, find_transform,
                           register)
from astroalign_nd.simulate import simulate_field, simulate_pair

from _helpers import frame_error

#: Luminosity function of most cases: enough bright stars to centroid well.
BRIGHT = dict(flux_range=(1e3, 3e5))


def _describe(t):
    q = t.meta.get("quality", {})
    return (f"n_matches={q.get('n_matches')}, rms={q.get('rms', float('nan')):.3f} px, "
            f"log10 FA={q.get('log10_false_alarm', float('nan')):.1f}")


def check_pair(pair, tol, uncertain_ok=False, **options):
    """find_transform on the pair's images; assert the frame error is below tol (px)."""
    with warnings.catch_warnings():
        # A PoorFitWarning here would mean a doubtful answer: fail loudly,
        # unless the case is known to sit at the limit of what the data allow.
        warnings.simplefilter("ignore" if uncertain_ok else "error", PoorFitWarning)
        t, (src, dst) = find_transform(pair.source, pair.target, **options)
    err = frame_error(t, pair.truth_matrix, pair.target.shape)
    assert err < tol, f"{err:.3f} px off over the target frame (limit {tol}); {_describe(t)}"
    # The matched points are really the same stars (within a PSF width).
    x, y = pair.transform(src[:, 0], src[:, 1])
    assert np.median(np.hypot(x - dst[:, 0], y - dst[:, 1])) < 1.0
    return t, err


def _map(model, pts):
    x, y = model(pts[:, 0], pts[:, 1])
    return np.column_stack([x, y])


# -- only 3 or 4 stars in common (catalogs) ------------------------------------------

CAT_TRUTH = SimilarityTransform(scale=0.7, rotation=200.0, translation_x=310.0,
                                translation_y=45.5)


def _few_common_catalogs(n_common, n_src_only, n_dst_only, seed, noise=0.0):
    """Catalogs sharing ``n_common`` stars; the others are unique to each list.

    The lists are shuffled (no brightness order helps), and ``noise`` (px)
    is added to every position of both lists.
    """
    rng = np.random.default_rng(seed)
    common = rng.uniform(0, 500, (n_common, 2))
    src = np.vstack([common, rng.uniform(0, 500, (n_src_only, 2))])
    dst = np.vstack([_map(CAT_TRUTH, common), rng.uniform(0, 500, (n_dst_only, 2))])
    src += rng.normal(0.0, noise, src.shape) if noise else 0.0
    dst += rng.normal(0.0, noise, dst.shape) if noise else 0.0
    return src[rng.permutation(len(src))], dst[rng.permutation(len(dst))]


def test_three_common_stars_catalogs():
    # source = 3 common + 2 unique, target = 3 common + 3 unique; exact positions.
    src, dst = _few_common_catalogs(3, 2, 3, seed=1)
    t, (s, d) = find_transform(src, dst)
    assert frame_error(t, CAT_TRUTH, (512, 512)) < 1e-6
    assert t.meta["quality"]["n_matches"] == 3
    np.testing.assert_allclose(_map(CAT_TRUTH, s), d, atol=1e-6)


def test_four_common_stars_catalogs_with_noise():
    # 4 common stars plus 3 and 4 unique ones, all positions with 0.01 px noise.
    src, dst = _few_common_catalogs(4, 3, 4, seed=2, noise=0.01)
    t, (s, d) = find_transform(src, dst)
    assert t.meta["quality"]["n_matches"] == 4
    # 4 stars spread over ~400 px: 0.01 px noise extrapolates to a few 0.01 px.
    err = frame_error(t, CAT_TRUTH, (512, 512))
    assert err < 0.1, f"{err:.3f} px; {_describe(t)}"


# 8 matched stars of a sparse, noisy list: the fit is rightly flagged as uncertain.
@pytest.mark.filterwarnings("ignore::astroalign_nd.PoorFitWarning")
def test_sparse_catalogs_neighbour_escalation():
    # 8 common stars (0.3 px noise) among 22 and 24: solvable with more
    # neighbours per star, which the escalation is meant to try.
    truth = SimilarityTransform(scale=1.0, rotation=0.5 * u.rad, translation_x=100.0,
                                translation_y=-50.0)
    rng = np.random.default_rng(3)
    common = rng.uniform(0, 500, (8, 2))
    src = np.vstack([common + rng.normal(0, 0.3, (8, 2)), rng.uniform(0, 500, (14, 2))])
    dst = np.vstack([_map(truth, common) + rng.normal(0, 0.3, (8, 2)),
                     rng.uniform(0, 500, (16, 2))])
    src, dst = src[rng.permutation(len(src))], dst[rng.permutation(len(dst))]
    # The same call with max_sources=50 succeeds (the escalation then runs).
    t, _ = find_transform(src, dst)
    assert frame_error(t, truth, (512, 512)) < 1.0


def test_three_source_exact_catalogs():
    # Exactly three sources in each list, in a different order.
    src = np.array([[12.0, 30.0], [210.0, 75.0], [95.0, 260.0]])
    dst = _map(CAT_TRUTH, src)[[2, 0, 1]]
    t, _ = find_transform(src, dst)
    assert frame_error(t, CAT_TRUTH, (512, 512)) < 1e-6


# -- pixel-scale ratios with different PSFs ------------------------------------------------

def test_scale_1_to_3():
    # Target pixels 3x larger: the source covers 1/9 of the target frame.
    pair = simulate_pair((768, 768), n_stars=600, scale=1 / 3, rotation=40.0, fwhm=6.0,
                         target_fwhm=2.0, seed=7, **BRIGHT)
    t, _ = check_pair(pair, 0.1)
    assert t.scale == pytest.approx(1 / 3, rel=1e-3)


def test_scale_3_to_1():
    # Source pixels 3x larger: the source centroids (FWHM 2 px, slightly
    # undersampled) are magnified 3x in target pixels, hence 0.3 px.
    pair = simulate_pair((512, 512), n_stars=400, scale=3.0, rotation=-20.0, fwhm=2.0,
                         target_fwhm=5.0, seed=7, **BRIGHT)
    t, _ = check_pair(pair, 0.3)
    assert t.scale == pytest.approx(3.0, rel=1e-3)


def test_scale_1_to_3_depth_mismatch():
    # Regression: this seed raised TransformNotFoundError.  ~20 of the 200
    # control points of each frame are common, but the source's 200
    # brightest reach much fainter stars per unit sky than the target's, so
    # their triangles differed and the hypothesis budget ran out (a
    # depth-matched pair, source 20 brightest vs target 200, is easy).
    pair = simulate_pair((768, 768), n_stars=600, scale=1 / 3, rotation=40.0, fwhm=6.0,
                         target_fwhm=2.0, seed=2, **BRIGHT)
    check_pair(pair, 0.1)


# -- parity and flips ------------------------------------------------------------------------

def test_mirrored_found_by_default():
    pair = simulate_pair((512, 512), n_stars=300, rotation=75.0, mirror=True, seed=7, **BRIGHT)
    t, _ = check_pair(pair, 0.1)
    assert t.mirrored
    assert float(t.parity.value) == -1.0


def test_meridian_flip_180():
    pair = simulate_pair((512, 512), n_stars=300, rotation=180.0, translation=(3.2, -4.7),
                         seed=7, **BRIGHT)
    t, _ = check_pair(pair, 0.1)
    assert not t.mirrored
    assert abs(((t.rotation_deg + 180.0) % 360.0) - 180.0) == pytest.approx(180.0, abs=0.02)


# -- partial overlap, missing stars, artifacts ----------------------------------------------

def test_overlap_25_percent():
    # A (256, 256) shift of a 512 x 512 frame: the frames share one quarter.
    pair = simulate_pair((512, 512), n_stars=600, rotation=5.0, translation=(256.0, 256.0),
                         seed=7, **BRIGHT)
    check_pair(pair, 0.1)


def test_half_missing_and_transients():
    # Half the stars removed independently from each frame, and 150 extra
    # (often bright) transients in the target.
    pair = simulate_pair((512, 512), n_stars=300, rotation=30.0, missing_fraction=0.5,
                         n_transients=150, seed=7, **BRIGHT)
    check_pair(pair, 0.1)


def test_hot_pixels_and_cosmic_rays():
    pair = simulate_pair((512, 512), n_stars=300, rotation=30.0, n_hot_pixels=500,
                         n_cosmic_rays=200, seed=7, **BRIGHT)
    check_pair(pair, 0.1)


def test_crowded_field():
    # 30,000 stars in 1024 x 1024 (noise='gaussian' only keeps the simulation fast).
    pair = simulate_pair((1024, 1024), n_stars=30_000, rotation=30.0, flux_range=(300, 3e5),
                         noise="gaussian", seed=7)
    check_pair(pair, 0.1)


# -- PSF, sky and detector ------------------------------------------------------------------

def test_fwhm_2_against_9():
    # The FWHM 9 px target centroids each star to ~0.1-0.3 px only (flux
    # spread over 4.5^2 times more sky), and 4 parameters are extrapolated
    # to the frame corners: 0.5 px.
    pair = simulate_pair((512, 512), n_stars=300, rotation=30.0, fwhm=2.0, target_fwhm=9.0,
                         seed=7, **BRIGHT)
    check_pair(pair, 0.5)


def test_strong_background_gradient():
    # Sky from 100 to 1100 counts across the frame diagonal.
    pair = simulate_pair((512, 512), n_stars=300, rotation=30.0, gradient=10.0, seed=7,
                         **BRIGHT)
    check_pair(pair, 0.1)


def test_very_strong_background_gradient():
    # Regression: sky from 100 to 3100 counts gave TooFewSourcesError.  The
    # detection sky map was held constant beyond the outer block centres;
    # the ramp left near the bright corner gave wide spurious candidates,
    # the image was taken for a wide-PSF one and nothing was found.
    pair = simulate_pair((512, 512), n_stars=300, rotation=30.0, gradient=30.0, seed=7,
                         **BRIGHT)
    check_pair(pair, 0.1)


def test_saturated_stars():
    # Clipped at 5000 counts: every star brighter than ~6e4 is flat-topped.
    pair = simulate_pair((512, 512), n_stars=300, rotation=30.0, saturation=5000.0, seed=7,
                         **BRIGHT)
    check_pair(pair, 0.1)


def test_low_signal_to_noise():
    # Faint stars (flux 150-5000) on a 1000-count sky: a dozen stars reach
    # SNR ~10-25, centroids are good to a few 0.1 px, so 0.6 px over the
    # frame (astroalign fails 5 of 6 such seeds).  At flux 100-3000 only a
    # handful of stars are detectable and the outcome is a coin flip; the
    # test below checks that it is then never silently wrong.
    pair = simulate_pair((512, 512), n_stars=300, rotation=30.0, flux_range=(150, 5000),
                         background=1000.0, seed=7)
    # ~0.3 px predicted 1-sigma error: the package may rightly warn here.
    t, _ = check_pair(pair, 0.6, uncertain_ok=True)
    assert t.meta["quality"]["n_matches"] >= 5


def test_low_signal_to_noise_never_silently_wrong():
    # Regression: with this seed the right 7 stars are matched but the fit
    # is ~1.5 px off at the frame corners (as the covariance says); it was
    # returned without a warning.  More than 1 px off must warn or raise.
    pair = simulate_pair((512, 512), n_stars=300, rotation=30.0, flux_range=(100, 3000),
                         background=1000.0, seed=3)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            t, _ = find_transform(pair.source, pair.target)
        except AstroalignError:
            return  # refusing is fine
    err = frame_error(t, pair.truth_matrix, pair.target.shape)
    warned = any(issubclass(w.category, astroalign_nd.AstroalignWarning) for w in caught)
    assert err < 1.0 or warned, f"{err:.2f} px off without a warning; {_describe(t)}"


@pytest.mark.parametrize("shape, target_shape, rotation", [
    ((300, 900), None, 8.0),         # wide frames
    ((300, 900), (900, 300), 90.0),  # landscape onto portrait
])
def test_rectangular_frames(shape, target_shape, rotation):
    pair = simulate_pair(shape, target_shape=target_shape, n_stars=300, rotation=rotation,
                         seed=7, **BRIGHT)
    check_pair(pair, 0.1)


# -- a slight affine shear -------------------------------------------------------------------

def _shear_pair():
    # Rotation 20 deg and a 3% shear about the frame centre, plus a shift.
    c, s = np.cos(0.35), np.sin(0.35)
    lin = np.array([[c, -s], [s, c]]) @ np.array([[1.0, 0.03], [0.0, 1.0]])
    m = np.eye(3)
    m[:2, :2] = lin
    ctr = np.array([255.5, 255.5])
    m[:2, 2] = ctr - lin @ ctr + [5.3, -2.1]
    return simulate_pair((512, 512), n_stars=300, transform=m, seed=7, **BRIGHT)


def test_affine_shear_fitted_with_affine():
    pair = _shear_pair()
    t, _ = check_pair(pair, 0.1, transform_type="affine")
    assert type(t) is AffineTransform


def test_affine_shear_never_silent_with_similarity():
    # A similarity cannot represent the shear (several px off at the corners):
    # it must warn or refuse, never return silently.
    pair = _shear_pair()
    try:
        with pytest.warns(PoorFitWarning):
            t, _ = find_transform(pair.source, pair.target)
    except AstroalignError:
        return
    assert frame_error(t, pair.truth_matrix, pair.target.shape) > 1.0


# -- trust ------------------------------------------------------------------------------

@pytest.mark.parametrize("n_stars, seed", [(10, 0), (15, 1), (20, 2)])
def test_unrelated_sparse_fields_raise(n_stars, seed):
    a, _ = simulate_field((256, 256), n_stars=n_stars, seed=1000 + seed, **BRIGHT)
    b, _ = simulate_field((256, 256), n_stars=n_stars, seed=2000 + seed, **BRIGHT)
    with pytest.raises(TransformNotFoundError):
        t, _ = find_transform(a, b)
        pytest.fail(f"unrelated fields gave a transform: {t!r}; {_describe(t)}")


def test_quality_is_exposed():
    pair = simulate_pair((384, 384), n_stars=150, rotation=30.0, translation=(4.0, -3.0),
                         seed=7, **BRIGHT)
    t, (src, dst) = find_transform(pair.source, pair.target)
    q = t.meta["quality"]
    assert isinstance(q["n_matches"], int) and q["n_matches"] == len(src) == len(dst) >= 20
    assert 0.0 < q["rms"] < 0.3
    cov = np.asarray(q["covariance"])
    assert cov.shape == (4, 4) and np.all(np.isfinite(cov)) and np.all(np.diag(cov) > 0)
    np.testing.assert_allclose(cov, cov.T, rtol=1e-8, atol=1e-12)
    assert q["log10_false_alarm"] < -6

    ccd = register(pair.source, pair.target)
    hdr = ccd.header
    for key in ("AATNMAT", "AATRMS", "AATLFA"):
        assert key in hdr, f"{key} missing from the registered header"
    assert hdr["AATNMAT"] == q["n_matches"]
    assert hdr["AATRMS"] == pytest.approx(q["rms"], abs=1e-5)
    assert hdr["AATLFA"] == pytest.approx(q["log10_false_alarm"], abs=1e-2)
