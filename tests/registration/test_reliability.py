# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Reliability: no hang, no raw exception, no confident wrong answer, bounded
memory, untrusted files validated (issue 12).

The property-based tests (hypothesis) draw related catalogs under every
transform type, which must be recovered within a pixel tolerance or
refused, and unrelated catalogs, which must always be refused (the
properties of resampling, of the header round trip and of the ASDF
converters are in tests/resample and tests/io).
Example counts are kept small so that the file runs in well under 30 s;
``benchmarks/fuzz.py`` runs the long campaign.
"""

import warnings

import numpy as np
import pytest
from astropy.io import fits
from astropy.nddata import CCDData, NDData, StdDevUncertainty
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from astroalign_nd import apply_transform, find_transform, register, transform_from_header
from astroalign_nd import _kernels
from astroalign_nd._kernels import PointGrid
from astroalign_nd.config import OPTIONS, check_option
from astroalign_nd.matching import build_asterisms
from astroalign_nd.exceptions import AstroalignError, AstroalignWarning, TransformNotFoundError
from astroalign_nd.matching import match_triangles
from astroalign_nd.transforms import AffineTransform, SimilarityTransform, TranslationTransform

from _helpers import random_matrix

FAST = settings(max_examples=12, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])
MATCHER = settings(FAST, max_examples=40)
TYPES = ["translation", "euclidean", "similarity", "affine"]
FRAME = 1000.0
CORNERS = np.array([[0.0, 0.0], [FRAME, 0.0], [0.0, FRAME], [FRAME, FRAME]])


def related_pair(seed, transform_type, mirrored, n_true, n_extra, noise, shuffle):
    """Catalogs sharing ``n_true`` stars under a known matrix, plus unrelated ones."""
    rng = np.random.default_rng(seed)
    m = random_matrix(rng, transform_type, mirrored)
    true = rng.uniform(0, FRAME, (n_true, 2))
    moved = true @ m[:2, :2].T + m[:2, 2] + rng.normal(0, noise, (n_true, 2))
    src = np.vstack([true, rng.uniform(0, FRAME, (n_extra, 2))])
    dst = np.vstack([moved, rng.uniform(0, FRAME, (n_extra, 2))])
    if shuffle:
        src, dst = src[rng.permutation(len(src))], dst[rng.permutation(len(dst))]
    return src, dst, m


def corner_error(model, m, n_grid=17):
    """
    Largest error (target px) over a grid of target pixels in the overlap,
    ``max |T_est(T_true^-1(p)) - p|``: where the registered image has data.
    """
    g = np.linspace(0.0, FRAME, n_grid)
    p = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    pre = (p - m[:2, 2]) @ np.linalg.inv(m[:2, :2]).T
    inside = np.all((pre >= 0) & (pre <= FRAME), axis=1)
    if not inside.any():
        p, pre = CORNERS @ m[:2, :2].T + m[:2, 2], CORNERS
    else:
        p, pre = p[inside], pre[inside]
    got = np.column_stack(model(pre[:, 0], pre[:, 1]))
    return float(np.max(np.hypot(*(got - p).T)))


def recovered_or_refused(src, dst, m, transform_type, noise):
    """Return True if recovered, False if refused; fail on a wrong answer."""
    src0, dst0 = src.copy(), dst.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AstroalignWarning)
        try:
            model, _ = find_transform(src, dst, transform_type=transform_type)
        except TransformNotFoundError:
            return False
        finally:
            np.testing.assert_array_equal(src, src0)  # inputs never modified
            np.testing.assert_array_equal(dst, dst0)
    err = corner_error(model, m)
    assert err < 2.0 + 20 * noise, (
        f"wrong answer accepted: corner error {err:.1f} px, "
        f"log10 FA {model.meta['quality']['log10_false_alarm']:.1f}")
    return True


# -- the matcher -------------------------------------------------------------------

@MATCHER
@given(seed=st.integers(0, 2**31), transform_type=st.sampled_from(TYPES),
       mirrored=st.booleans(), n_true=st.integers(8, 90), extra=st.floats(0, 1.2),
       noise=st.sampled_from([0.0, 0.05, 0.3]), shuffle=st.booleans())
def test_related_catalogs_recovered_or_refused(seed, transform_type, mirrored, n_true, extra,
                                               noise, shuffle):
    src, dst, m = related_pair(seed, transform_type, mirrored, n_true, int(extra * n_true),
                               noise, shuffle)
    recovered_or_refused(src, dst, m, transform_type, noise)


@MATCHER
@given(seed=st.integers(0, 2**31), transform_type=st.sampled_from(TYPES),
       n_src=st.integers(3, 150), n_dst=st.integers(3, 150))
def test_unrelated_catalogs_refused(seed, transform_type, n_src, n_dst):
    rng = np.random.default_rng(seed)
    src, dst = rng.uniform(0, FRAME, (n_src, 2)), rng.uniform(0, FRAME, (n_dst, 2))
    with pytest.raises(AstroalignError):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", AstroalignWarning)
            find_transform(src, dst, transform_type=transform_type)


@pytest.mark.parametrize("transform_type", TYPES)
@pytest.mark.parametrize("mirrored", [False, True])
def test_clean_pairs_found_under_every_type(transform_type, mirrored):
    """Refusing is allowed, but not for a clean pair: true solutions are still found."""
    if transform_type == "translation" and mirrored:
        pytest.skip("a translation cannot mirror")
    src, dst, m = related_pair(7, transform_type, mirrored, 60, 20, 0.05, True)
    assert recovered_or_refused(src, dst, m, transform_type, 0.05)


# Seeds of the generator of issue 12 (true points plus as many random ones,
# shuffled) for which the affine fit used to return 6-9 wrong matches at a
# log10 false-alarm of -6 to -8.5.
def _issue12_affine_case(seed):
    r = np.random.default_rng(seed)
    n_true, n_rand = int(r.integers(5, 80)), int(r.integers(0, 80))
    true = r.uniform(0, 1000, (n_true, 2))
    a = np.eye(2) + r.normal(0, 0.2, (2, 2))
    t = r.uniform(-200, 200, 2)
    src = np.vstack([true, r.uniform(0, 1000, (n_rand, 2))])
    dst = np.vstack([true @ a.T + t, r.uniform(0, 1000, (n_rand, 2))])
    src, dst = src[r.permutation(len(src))], dst[r.permutation(len(dst))]
    m = np.eye(3)
    m[:2, :2], m[:2, 2] = a, t
    return src, dst, m


@pytest.mark.parametrize("seed", [15, 102, 137, 170, 216, 218])
def test_affine_chance_matches_not_accepted(seed):
    src, dst, m = _issue12_affine_case(seed)
    recovered_or_refused(src, dst, m, "affine", 0.0)


def test_affine_found_with_shear():
    rng = np.random.default_rng(0)
    true = rng.uniform(0, 1000, (60, 2))
    m = np.array([[1.05, 0.08, 12.0], [-0.03, 0.95, -7.0], [0, 0, 1]])
    dst = true @ m[:2, :2].T + m[:2, 2]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AstroalignWarning)
        model, (s, _) = find_transform(true, dst, transform_type="affine")
    assert len(s) >= 50 and corner_error(model, m) < 0.01


# -- hangs, memory, raw exceptions --------------------------------------------------

PTS = np.random.default_rng(3).uniform(0, 500, (40, 2))


@pytest.mark.parametrize("options, match", [
    (dict(tolerance=0), "tolerance"),
    (dict(tolerance=np.nan), "tolerance"),
    (dict(min_tolerance=-1), "min_tolerance"),
    (dict(invariant_radius=0), "invariant_radius"),
    (dict(n_neighbors=0), "n_neighbors"),
    (dict(n_neighbors=1), "n_neighbors"),
    (dict(n_neighbors=2.5), "n_neighbors"),
    (dict(scale_range=(1,)), "scale_range"),
    (dict(scale_range=(2, 1)), "scale_range"),
    (dict(scale_range="big"), "scale_range"),
    (dict(batch_size=0), "batch_size"),
    (dict(max_hypotheses=-1), "max_hypotheses"),
    (dict(max_false_alarm=0), "max_false_alarm"),
    (dict(max_false_alarm=2), "max_false_alarm"),
    (dict(accept_matches=1), "accept_matches"),
    (dict(fwhm="a"), "fwhm"),
    (dict(nsigma="a"), "nsigma"),
    (dict(peak_max="a"), "peak_max"),
    (dict(bin_factor=0), "bin_factor"),
    (dict(n_sources=2), "n_sources"),
    (dict(max_sources=1.5), "max_sources"),
])
def test_bad_option_named(options, match):
    with pytest.raises((ValueError, TypeError), match=match) as info:
        find_transform(PTS, PTS + 1, **options)
    assert "must be" in str(info.value)


@FAST
@given(name=st.sampled_from(sorted(OPTIONS)),
       value=st.one_of(st.none(), st.booleans(), st.integers(-10, 10**8),
                       st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=3),
                       st.tuples(st.floats(-5, 5)), st.tuples(st.floats(), st.floats()),
                       st.lists(st.integers(-3, 3), max_size=3)))
def test_any_option_value_accepted_or_named(name, value):
    """Every option value is either accepted or refused with a message naming it."""
    try:
        check_option(name, value)
    except (TypeError, ValueError) as exc:
        assert str(exc).startswith(name + " must be")


def test_zero_tolerance_does_not_hang():
    with pytest.raises(ValueError, match="radius"):
        PointGrid(PTS, 0.0)
    grid = PointGrid(np.array([[0.0, 0.0], [1e8, 1e8]]), 1e-3)  # huge span: few cells
    assert grid.nx * grid.ny <= 4_000_001


def test_huge_coordinates_refused():
    with pytest.raises(ValueError, match="pixel coordinates"):
        find_transform(PTS * 1e152, PTS * 1e152 + 1)


def test_triangle_budget_checked_before_allocating():
    with pytest.raises(ValueError, match="triangles"):
        find_transform(PTS, PTS + 1, n_neighbors=16, max_sources=5000)
    # n_neighbors=8, max_sources=5000 fits the budget (it ended in std::bad_alloc).
    rng = np.random.default_rng(0)
    a, b = rng.uniform(0, 2000, (6000, 2)), rng.uniform(0, 2000, (6000, 2))
    with pytest.raises(TransformNotFoundError):
        find_transform(a, b, n_neighbors=8, max_sources=1600)


def test_triangle_pairs_bounded_on_a_lattice():
    grid = np.stack(np.meshgrid(np.arange(40.0), np.arange(40.0)), -1).reshape(-1, 2) * 10
    ast = build_asterisms(grid)
    pairs, dist = match_triangles(ast, ast, 0.1, max_matches=1000)
    assert len(pairs) == 1000 and np.all(np.diff(dist) >= 0)
    # Without a cap, every pair of the ~1.5 10^4 identical triangles would be listed.
    assert len(ast) ** 2 > 10**7


def test_large_unrelated_catalogs_use_brightest_points():
    rng = np.random.default_rng(5)
    a, b = rng.uniform(0, 4000, (50_000, 2)), rng.uniform(0, 4000, (50_000, 2))
    with pytest.raises(TransformNotFoundError, match="gave 1000 sources"):
        find_transform(a, b)


def test_num_threads_zero_refused(monkeypatch):
    monkeypatch.setattr(_kernels, "_ENV_NUM_THREADS", "0")  # as read from the environment
    with pytest.raises(ValueError, match="ASTROALIGN_ND_NUM_THREADS"):
        find_transform(PTS, PTS + 1)


def test_singular_models_refused():
    with pytest.raises(ValueError, match="singular"):
        SimilarityTransform(scale=0).inverse
    line = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [5.0, 5.0]])
    with pytest.raises(ValueError, match="collinear"):
        AffineTransform.from_points(line, line + 3)
    square = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    with pytest.raises(ValueError, match="singular"):
        AffineTransform.from_points(square, line)
    with pytest.raises(ValueError, match="coincide"):
        SimilarityTransform.from_points(np.ones((3, 2)), square[:3])
    # Collinear points still fix a similarity.
    t = SimilarityTransform.from_points(line, 2 * line + 1)
    assert abs(t.scale.value - 2) < 1e-12


def test_quality_missing_keys(tmp_path):
    img = np.random.default_rng(0).normal(size=(32, 32))
    with pytest.raises(ValueError, match="quality lacks"):
        apply_transform(TranslationTransform(1, 2), img, img, quality={"rms": 1.0})


def test_uncertainty_shape_mismatch():
    img = np.zeros((32, 32))
    with pytest.raises(ValueError, match="uncertainty has shape"):
        apply_transform(TranslationTransform(1, 2),
                        NDData(img, uncertainty=StdDevUncertainty(np.ones(32))), img)


def test_damaged_files(tmp_path):
    img = np.random.default_rng(0).normal(size=(32, 32)).astype(np.float32)
    path = tmp_path / "naxis3.fits"
    fits.PrimaryHDU(img).writeto(path)
    raw = path.read_bytes().replace(b"NAXIS   =                    2",
                                    b"NAXIS   =                    3")
    path.write_bytes(raw)
    with pytest.raises(ValueError, match="naxis3.fits"):
        find_transform(path, img)
    for name, head in (("bad.png", b"\x89PNG\r\n\x1a\n"), ("bad.jpg", b"\xff\xd8\xff\xe0")):
        bad = tmp_path / name
        bad.write_bytes(head + b"garbage" * 20)
        with pytest.raises(ValueError, match=name):
            find_transform(bad, img)


# -- work not thrown away at the end ------------------------------------------------

@pytest.fixture(scope="module")
def image_pair():
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((128, 128), n_stars=60, rotation=10.0, seed=1)
    return np.asarray(pair.source), np.asarray(pair.target)


def test_register_with_meta_fits_cannot_hold(image_pair, tmp_path):
    src, dst = image_pair
    meta = {"A": np.nan, "B": np.inf, "C": "caf\u00e9", "D": {"x": 1}, "E": [1, 2],
            "LONGKEYWORD": 3, "F": 1.5}
    with pytest.warns(AstroalignWarning, match="skipped"):
        ccd = register(CCDData(src, unit="adu", meta=meta), dst)
    assert ccd.meta["F"] == 1.5 and ccd.meta["C"] == "caf\\xe9"
    ccd.write(tmp_path / "out.fits")  # the header is a valid FITS header
    assert transform_from_header(fits.getheader(tmp_path / "out.fits")).scale.value > 0


def test_register_non_ascii_file_name(image_pair, tmp_path):
    src, dst = image_pair
    path = tmp_path / "\u00e9toile.fits"
    fits.writeto(path, src)
    ccd = register(path, dst)
    assert "\\xe9toile.fits" in "".join(ccd.meta["HISTORY"])
