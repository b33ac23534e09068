# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Projective and polynomial models grown from the linear match (model_selection)."""

import warnings

import numpy as np
import pytest
from astropy.nddata import NDData

from astroalign_nd import find_match, find_transform, register, transform_from_header
from astroalign_nd.exceptions import PoorCoverageError, PoorFitWarning
from astroalign_nd.matching import fit_nonlinear
from astroalign_nd.simulate import simulate_pair
from astroalign_nd.transforms import (LinearTransform2D, PolynomialTransform, ProjectiveTransform,
                                      check_degree, fit_transform)

from _helpers import run_cli

N = 1024
HALF = 0.5 * np.hypot(N, N)


def _wide_pair(corner=5.0, seed=3, n=N, n_stars=1500, tilt=None, k2=0.0, **kw):
    """A wide-field pair: barrel (corner > 0 px inward) or pincushion (corner < 0)."""
    half = 0.5 * np.hypot(n, n)
    dist = {"k1": -corner / half - k2, "k2": k2}
    if tilt is not None:
        dist["tilt"] = tilt
    kw.setdefault("rotation", 7.0)
    kw.setdefault("translation", (20.0, -13.0))
    return simulate_pair((n, n), n_stars=n_stars, seed=seed, distortion=dist, noise="gaussian",
                         flux_range=(2000.0, 3e5), **kw)


def _frame_error(model, pair, n_grid=41):
    """Max and RMS distance (px) between ``model`` and the truth on a grid over the frame."""
    ny, nx = pair.source.shape
    gx, gy = np.meshgrid(np.linspace(-0.5, nx - 0.5, n_grid), np.linspace(-0.5, ny - 0.5, n_grid))
    tx, ty = pair.truth_map(gx.ravel(), gy.ravel())
    mx, my = model(gx.ravel(), gy.ravel())
    err = np.hypot(np.asarray(mx) - tx, np.asarray(my) - ty)
    return float(err.max()), float(np.sqrt(np.mean(err ** 2)))


def _best_affine(pair):
    """The least-squares affine fit of the true star positions: the best linear model."""
    m = pair.matched_stars()
    lin, _, _ = fit_transform(np.column_stack([m["x_source"], m["y_source"]]),
                              np.column_stack([m["x_target"], m["y_target"]]), "affine")
    return lin


@pytest.mark.parametrize("corner, degree", [(5.0, 3), (8.0, "auto"), (-3.0, "auto")])
def test_polynomial_recovers_radial_distortion(corner, degree):
    pair = _wide_pair(corner)
    assert abs(pair.meta["corner_shift"] - abs(corner)) < 0.5
    with warnings.catch_warnings():
        warnings.simplefilter("error", PoorFitWarning)
        t, (src, dst) = find_transform(pair.source, pair.target, transform_type="polynomial",
                                       degree=degree)
    assert isinstance(t, PolynomialTransform)
    q = t.meta["quality"]
    assert q["model"] == "polynomial" and q["degree"] >= 3  # r**3 needs cubic terms
    err_max, err_rms = _frame_error(t, pair)
    assert err_max < 0.1, err_max  # over the whole frame, corners included
    assert err_rms < 0.03
    # The best linear model leaves pixels at the corners.
    assert _frame_error(_best_affine(pair), pair)[0] > 0.4 * abs(corner)
    # The matched points are many more than the linear match's control points.
    assert len(src) == q["n_matches"] > 500
    assert q["predicted_error_max"] < 0.1
    assert 0 < q["predicted_error_rms"] <= q["predicted_error_max"]
    assert q["model_selection"]["coverage"]["occupancy"] == 1.0


def test_auto_degree_reports_its_tests():
    pair = _wide_pair(6.0, seed=5)
    result = find_match(pair.source, pair.target, transform_type="polynomial", degree="auto")
    info = result.extra["model_selection"]
    assert info["selection"] == "F-test, BIC and blocked cross-validation"
    names = [(c["model"], c["degree"]) for c in info["candidates"]]
    assert names[:3] == [("similarity", 1), ("affine", 1), ("polynomial", 2)]
    chosen = [c for c in info["candidates"] if c["chosen"]]
    assert len(chosen) == 1 and chosen[0]["degree"] == info["degree"] >= 3
    cubic = [c for c in info["candidates"] if c["degree"] == 3][0]
    assert cubic["p_value"] < 1e-10  # the cubic terms earn their place
    assert all(c["bic"] > cubic["bic"] for c in info["candidates"] if c["degree"] < 3)
    assert isinstance(result.extra["linear_transform"], LinearTransform2D)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_auto_chooses_linear_without_distortion(seed):
    pair = simulate_pair((512, 512), n_stars=600, seed=seed, rotation=25.0, scale=1.02,
                         translation=(5.0, 3.0), flux_range=(1000.0, 3e5))
    t, _ = find_transform(pair.source, pair.target, transform_type="polynomial",
                          degree="auto")
    assert isinstance(t, LinearTransform2D)
    q = t.meta["quality"]
    assert q["model"] == "similarity" and q["degree"] == 1
    assert _frame_error(t, pair)[0] < 0.05


def test_projective_recovers_tilt():
    pair = _wide_pair(0.0, seed=7, tilt=(0.01, -0.005))
    assert pair.meta["corner_shift"] > 4.0
    t, _ = find_transform(pair.source, pair.target, transform_type="projective")
    assert isinstance(t, ProjectiveTransform)
    assert t.meta["quality"]["model"] == "projective"
    assert _frame_error(t, pair)[0] < 0.1
    assert _frame_error(_best_affine(pair), pair)[0] > 1.0


def test_thirty_percent_wrong_pairs():
    rng = np.random.default_rng(11)
    n = 500
    src = rng.uniform(-0.5, 4095.5, (n, 2))
    half = 0.5 * np.hypot(4096, 4096)

    def truth(p):
        u = (p - 2047.5) / half
        r2 = (u ** 2).sum(axis=1)[:, None]
        return 2047.5 + (u * (1 - 0.003 * r2 - 0.0005 * r2 ** 2)) * half + [15.0, -8.0]

    dst = truth(src) + rng.normal(0, 0.05, (n, 2))
    bad = rng.choice(n, int(0.3 * n), replace=False)
    # Wrong pairs: each source star paired with another star's target position
    # (plus a little jitter), as a mismatch would.
    dst[bad] = truth(src[rng.permutation(bad)]) + rng.normal(0, 2.0, (len(bad), 2))
    frame = (-0.5, 4095.5, -0.5, 4095.5)
    fit = fit_nonlinear(src, dst, np.array([[1, 0, 15.0], [0, 1, -8.0], [0, 0, 1]]),
                        degree="auto", pairs_given=True, tolerance=20.0, source_frame=frame)
    good = np.setdiff1d(np.arange(n), bad)
    assert set(fit.source_index) <= set(good)
    assert len(fit.source_index) > 0.95 * len(good)
    g = np.stack(np.meshgrid(np.linspace(-0.5, 4095.5, 33), np.linspace(-0.5, 4095.5, 33)),
                 -1).reshape(-1, 2)
    err = np.hypot(*(np.column_stack(fit.transform(*g.T)) - truth(g)).T)
    assert err.max() < 0.1


def test_coverage_refused_and_warned():
    rng = np.random.default_rng(2)
    src = rng.uniform(0, 1000, (400, 2))
    src = src[(src[:, 0] < 500) & (src[:, 1] < 500)]  # one quadrant of the frame only
    dst = src + [3.0, 4.0] + rng.normal(0, 0.05, src.shape)
    frame = (-0.5, 999.5, -0.5, 999.5)
    shift = np.array([[1.0, 0.0, 3.0], [0.0, 1.0, 4.0], [0.0, 0.0, 1.0]])
    with pytest.raises(PoorCoverageError, match="do not cover the frame"):
        fit_nonlinear(src, dst, shift, degree=4, pairs_given=True, source_frame=frame)
    # 'auto' keeps to what the stars support instead of refusing, and says
    # that it could not look for a distortion.
    with pytest.warns(PoorFitWarning, match="no polynomial could be tested"):
        fit = fit_nonlinear(src, dst, shift, degree="auto", pairs_given=True,
                            source_frame=frame)
    assert fit.info["degrees_tested"] == [1]
    assert fit.info["model"] == "affine"
    assert max(c["degree"] for c in fit.info["candidates"]) < 4
    # Too few stars per term for degree 5.
    few = rng.uniform(0, 1000, (40, 2))
    with pytest.raises(PoorCoverageError, match="stars per term"):
        fit_nonlinear(few, few + 1.0, np.eye(3), degree=5, pairs_given=True,
                      source_frame=frame)


def test_coverage_refused_on_masked_image():
    pair = _wide_pair(5.0, seed=4)
    mask = np.zeros(pair.source.shape, bool)
    mask[:, 300:] = True  # stars only in the left 30% of the source
    src = NDData(pair.source, mask=mask)
    with pytest.raises(PoorCoverageError, match="lower degree"):
        find_transform(src, pair.target, transform_type="polynomial", degree=5)


def test_model_class_accepted():
    pair = _wide_pair(4.0, seed=12)
    t, _ = find_transform(pair.source, pair.target, transform_type=PolynomialTransform,
                          degree=3)
    assert isinstance(t, PolynomialTransform) and _frame_error(t, pair)[0] < 0.1


def test_degree_checked():
    assert check_degree("polynomial", "3") == 3
    with pytest.raises(ValueError, match="transform_type='polynomial' only"):
        find_transform(np.zeros((32, 32)), np.zeros((32, 32)), degree=3)
    with pytest.raises(ValueError, match="Degree 1 is transform_type='affine'"):
        check_degree("polynomial", 1)
    with pytest.raises(TypeError, match="integer from 2 to 5 or 'auto'"):
        check_degree("polynomial", 2.5)
    with pytest.raises(ValueError, match="projective"):
        fit_nonlinear(np.zeros((5, 2)), np.zeros((5, 2)), np.eye(3), transform_type="affine")


def test_catalogs():
    pair = _wide_pair(5.0, seed=8)
    src = pair.source_stars
    dst = pair.target_stars
    t, (s, d) = find_transform(src, dst, transform_type="polynomial", degree=3)
    assert isinstance(t, PolynomialTransform)
    # Exact positions: the model is right to the centroid precision (none here).
    r = np.hypot(*(np.column_stack(t(*s.T)) - d).T)
    assert np.median(r) < 1e-3
    assert _frame_error(t, pair)[0] < 0.05


def _register_or_skip(pair, **kw):
    try:
        return register(pair.source, pair.target, **kw)
    except (TypeError, ValueError, NotImplementedError) as exc:
        if "not an affine transform" in str(exc):
            pytest.skip(f"resample does not take non-linear models yet (issue 18c): {exc}")
        raise


def test_register_polynomial():
    from astroalign_nd import find_sources
    from scipy.spatial import cKDTree

    pair = _wide_pair(6.0, seed=9)
    ccd = _register_or_skip(pair, transform_type="polynomial", degree="auto")
    assert ccd.shape == pair.target.shape
    found = find_sources(np.nan_to_num(ccd.data), n_sources=300)
    d, _ = cKDTree(np.column_stack([pair.target_stars["x"], pair.target_stars["y"]])).query(
        np.column_stack([found["x"], found["y"]]))
    near = d < 2.0
    assert near.sum() > 200
    assert np.median(d[near]) < 0.15  # stars land where the target has them


def test_cli_polynomial(tmp_path):
    from astropy.io import fits

    # The command line's plumbing: a smaller frame than the model tests' is enough.
    pair = _wide_pair(5.0, seed=10, n=512, n_stars=600)
    fits.writeto(tmp_path / "src.fits", pair.source)
    fits.writeto(tmp_path / "tgt.fits", pair.target)
    out = tmp_path / "out.fits"
    code, _, err = run_cli("register", tmp_path / "src.fits", tmp_path / "tgt.fits", "-o", out,
                           "--transform-type", "polynomial", "--degree", "auto")
    assert code == 0, err
    t = transform_from_header(fits.getheader(out))
    assert isinstance(t, PolynomialTransform) and t.degree >= 3
    assert _frame_error(t, pair)[0] < 0.2


def test_cli_degree_checked(tmp_path):
    from astropy.io import fits

    pair = simulate_pair((128, 128), n_stars=40, seed=1)
    fits.writeto(tmp_path / "src.fits", pair.source)
    fits.writeto(tmp_path / "tgt.fits", pair.target)
    code, _, err = run_cli("register", tmp_path / "src.fits", tmp_path / "tgt.fits",
                           "-o", tmp_path / "o2.fits", "--degree", "7",
                           "--transform-type", "polynomial")
    assert code == 2 and "degree must be an integer from 2 to 5" in err


@pytest.mark.parametrize("seed", [0, 2])
def test_auto_not_fooled_by_systematic_centroid_errors(seed):
    # 2000 stars, dense at the centre and sparse at the corners, through an
    # 8 px pincushion (a cubic map), with centroid errors that are heavy-tailed
    # and slightly systematic (a 0.05 px pattern across the frame), as on real
    # frames.  The F-test and BIC accept degree 5 (about 1 px off at the
    # corners); the blocked cross-validation keeps degree 3.
    n = 4096
    half = 0.5 * np.hypot(n, n)

    def truth(p):
        u = (p - (n - 1) / 2.0) / half
        return p + 8.0 * u * (u ** 2).sum(1)[:, None]

    rng = np.random.default_rng(seed)
    src = rng.normal((n - 1) / 2.0, n / 4.5, (3000, 2))
    src = src[(src >= 0).all(1) & (src <= n - 1).all(1)][:2000]
    pattern = 0.05 * np.sin(2 * np.pi * src[:, 0] / 3000.0 + 1.0) * np.cos(
        2 * np.pi * src[:, 1] / 2500.0)
    dst = truth(src) + np.column_stack([pattern, -pattern]) + 0.03 * rng.standard_t(3, src.shape)
    err = np.full(len(src), 0.03)
    fit = fit_nonlinear(src, dst, np.eye(3), degree="auto", pairs_given=True, tolerance=15.0,
                        source_frame=(-0.5, n - 0.5, -0.5, n - 0.5), source_errors=err,
                        target_errors=err)
    info = fit.info
    assert (info["model"], info["degree"]) == ("polynomial", 3), info["candidates"]
    d5 = [c for c in info["candidates"] if c["degree"] == 5][0]
    assert d5["p_value"] < 1e-4  # the tests alone would have taken degree 5
    assert info["selection"] == "F-test, BIC and blocked cross-validation"
    g = np.stack(np.meshgrid(np.linspace(0, n - 1, 33), np.linspace(0, n - 1, 33)), -1)
    g = g.reshape(-1, 2)
    mx, my = fit.transform(g[:, 0], g[:, 1])
    t = truth(g)
    assert np.hypot(mx - t[:, 0], my - t[:, 1]).max() < 0.3


def test_projective_from_few_pairs():
    # Fewer pairs than the growth stage needs to switch to the homography
    # (32): the projective fit must start from the affine growth model, not
    # index its 6 parameters as 8 (it raised IndexError).
    rng = np.random.default_rng(4)
    src = rng.uniform(0, 1000, (24, 2))
    h = np.array([[1.01, 0.02, 5.0], [-0.015, 0.99, -3.0], [2e-5, -1e-5, 1.0]])
    p = np.column_stack([src, np.ones(len(src))]) @ h.T
    dst = p[:, :2] / p[:, 2:] + rng.normal(0, 0.03, src.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PoorFitWarning)
        fit = fit_nonlinear(src, dst, np.eye(3), transform_type="projective", pairs_given=True,
                            tolerance=20.0, source_frame=(-0.5, 999.5, -0.5, 999.5))
    assert isinstance(fit.transform, ProjectiveTransform)
    mx, my = fit.transform(src[:, 0], src[:, 1])
    assert np.hypot(mx - dst[:, 0], my - dst[:, 1]).max() < 0.2


def test_reference_stars_at_a_given_fwhm():
    from astroalign_nd import Reference

    pair = simulate_pair((256, 256), n_stars=80, seed=2, fwhm=3.0)
    ref = Reference(pair.target)
    pts, _, _ = ref.stars(20)
    free = ref.detection_fwhm(20)
    assert free is not None and abs(free - 3.0) < 1.0
    pts6, _, _ = ref.stars(20, fwhm=6.0)
    assert ref.detection_fwhm(20) == free  # cached apart
    assert ref.fwhm == free  # the estimate stays the frame's FWHM
    assert ref.stars(20, fwhm=6.0)[0] is pts6
    assert ref.stars(20)[0] is pts
    # A FWHM fixed by the caller's options wins.
    fixed = Reference(pair.target, fwhm=3.0)
    assert fixed.stars(20, fwhm=6.0)[0] is fixed.stars(20)[0]
