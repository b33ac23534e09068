# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Detection and registration on what real frames do to the stars (issue 10).

Each category has a simulated version that always runs (the simulator's
`add_nebulosity`, `add_overscan`, `to_8bit` and `bayer_bin`) and, where a
real frame shows it, a real version that skips when ``../shared/data`` is
absent.  Every registration is checked against the known transform, in
pixels over the overlap.
"""

import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from _helpers import frame_error
from astroalign_nd import PoorFitWarning, find_sources, find_transform
from astroalign_nd.simulate import simulate_pair

from _frame_defects import add_nebulosity, add_overscan, bayer_bin, to_8bit

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
needs_data = pytest.mark.skipif(not (DATA / "real").is_dir() or not (DATA / "field").is_dir(),
                                reason=f"real frames not available (expected {DATA})")


def registers(source, target, truth, tol=0.5, **kw):
    t, _ = find_transform(source, target, **kw)
    err = frame_error(t, truth, np.shape(target)[:2])
    assert err < tol, f"transform off by {err:.3f} px"
    return t


# -- simulated categories (always run) ------------------------------------------------------

@pytest.mark.parametrize("seed", [0, 1])
def test_nebulosity_knots_outshine_stars(seed):
    """Bright extended knots must not set the FWHM (HorseHead, MSX maps)."""
    pair = simulate_pair((400, 400), n_stars=150, fwhm=3.0, rotation=35.0, background=200,
                         flux_range=(2e3, 2e5), seed=seed)
    src = add_nebulosity(pair.source, amplitude=3000.0, seed=10 + seed)
    dst = add_nebulosity(pair.target, amplitude=3000.0, seed=20 + seed)
    for img in (src, dst):
        tab = find_sources(img, n_sources=50)
        assert tab.meta["fwhm"] == pytest.approx(3.0, rel=0.3)
        assert len(tab) >= 30
    registers(src, dst, pair.truth_matrix)


def test_overscan_strips_raw_frame():
    """Strips of bias along three edges (the SAAO raw frame) do not fool the estimate."""
    pair = simulate_pair((300, 320), n_stars=40, fwhm=2.5, rotation=2.0,
                         translation=(6.0, -4.0), background=300, n_cosmic_rays=30,
                         flux_range=(1e3, 1e5), seed=3)
    src = add_overscan(pair.source, width=12, level=10.0, seed=1).astype(np.uint16)
    dst = add_overscan(pair.target, width=12, level=10.0, seed=2).astype(np.uint16)
    a = find_sources(src, n_sources=30)
    b = find_sources(dst, n_sources=30)
    assert a.meta["fwhm"] == pytest.approx(2.5, rel=0.3)
    assert b.meta["fwhm"] == pytest.approx(a.meta["fwhm"], rel=0.25)
    registers(src, dst, pair.truth_matrix)


@pytest.mark.parametrize("quality", [None, 75])
def test_8bit_stretched_bloated_stars(quality):
    """Gamma-stretched 8-bit frames with saturated, bloated stars (JPEG astrophotos)."""
    pair = simulate_pair((400, 500), n_stars=200, fwhm=3.0, rotation=-60.0, scale=0.9,
                         background=100, flux_range=(1e3, 1e6), seed=4)
    src = to_8bit(pair.source, jpeg_quality=quality)
    dst = to_8bit(pair.target, jpeg_quality=quality)
    assert src.dtype == np.uint8 and (src == 255).sum() > 50  # saturated plateaus
    tab = find_sources(src, n_sources=50)
    assert 1.5 < tab.meta["fwhm"] < 8.0
    assert len(tab) >= 30
    registers(src, dst, pair.truth_matrix, tol=1.0)


def test_undersampled_bayer_binned_hot_pixels():
    """A smart telescope's 2x2-binned colour frames: FWHM ~1.4 px, hot pixels, rotation."""
    full = simulate_pair((600, 800), n_stars=80, fwhm=2.8, rotation=25.0, background=400,
                         n_hot_pixels=300, flux_range=(3e3, 3e5), seed=5)
    pair = bayer_bin(full)
    tab = find_sources(pair.source, n_sources=50)
    assert tab.meta["fwhm"] < 2.2
    t = registers(pair.source, pair.target, pair.truth_matrix, tol=0.3)
    assert t.meta["quality"]["n_matches"] >= 15


@pytest.mark.parametrize("seed", [0, 1])
def test_crowded_blends_on_bright_sky(seed):
    """10,000 stars on 256x256 over a bright sky: both frames give the same FWHM."""
    pair = simulate_pair((256, 256), n_stars=10000, fwhm=3.0, rotation=20.0,
                         background=500 + 500 * seed, seed=seed)
    a = find_sources(pair.source)
    b = find_sources(pair.target)
    assert a.meta["fwhm"] == pytest.approx(b.meta["fwhm"], rel=0.2)
    registers(pair.source, pair.target, pair.truth_matrix)


@pytest.mark.parametrize("seed", range(4))
def test_paper_worked_example(seed):
    """The astroalign paper's example: 10 stars, 200x200 -> 300x300, scale 1.5, 30 deg."""
    pair = simulate_pair((200, 200), target_shape=(300, 300), n_stars=10, fwhm=4.71,
                         target_fwhm=3.53, flux_range=(200, 500), background=0.5,
                         read_noise=0.71, noise="gaussian", gain=1e6, scale=1.5,
                         rotation=-30.0, seed=seed)
    # Six to eight matched stars: an answer up to 1 px off over the frame must
    # say so (seed 1: 0.97 px off, bound 2.7 px); a precise one must not.
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", PoorFitWarning)
        t = registers(pair.source, pair.target, pair.truth_matrix, tol=1.0)
    err = frame_error(t, pair.truth_matrix, np.shape(pair.target))
    warned = any(issubclass(w.category, PoorFitWarning) for w in seen)
    assert t.meta["quality"]["error_bound"] >= err
    assert warned == (t.meta["quality"]["error_bound"] > 1.0)
    if err > 0.5:
        assert warned, f"{err:.2f} px off without a warning"


def test_sparse_eight_stars():
    """Eight stars (DECam stamps): solved, with a fine error."""
    pair = simulate_pair((256, 256), n_stars=8, fwhm=4.0, rotation=-170.0, scale=0.9,
                         background=300, flux_range=(5e3, 5e4), seed=7)
    registers(pair.source, pair.target, pair.truth_matrix)


def test_unrelated_sparse_fields_refused():
    from astroalign_nd.exceptions import AstroalignError

    a = simulate_pair((256, 256), n_stars=12, fwhm=3.0, seed=8).source
    b = simulate_pair((256, 256), n_stars=12, fwhm=3.0, seed=9).source
    with pytest.raises(AstroalignError):
        find_transform(a, b)


def test_correlated_noise_does_not_add_noise_detections():
    """An upsampled (resampled) frame has correlated noise; its noise is not underestimated."""
    from astroalign_nd.detection import estimate_noise

    rng = np.random.default_rng(0)
    white = rng.normal(100.0, 10.0, (300, 300))
    smooth = ndimage.zoom(white, 1.4, order=3)[:300, :300]
    # The pixels of the zoomed frame scatter by ~8.5; neighbours differ much less.
    assert estimate_noise(smooth) == pytest.approx(np.std(smooth), rel=0.15)
    assert estimate_noise(white) == pytest.approx(10.0, rel=0.05)


def test_wide_stars_estimated_on_binned_copy_without_runaway():
    """Defocused (FWHM 24 px) stars: measured on a binned copy, estimate stays sane."""
    pair = simulate_pair((1024, 1024), n_stars=60, fwhm=24.0, rotation=10.0,
                         flux_range=(1e6, 1e7), seed=11)
    tab = find_sources(pair.source, n_sources=30)
    assert 14.0 < tab.meta["fwhm"] < 40.0
    assert len(tab) >= 20


# -- the same categories on real frames (skip without ../shared/data) -----------------------

def _load(path):
    from astroalign_nd.io.read import parse_input

    return np.asarray(parse_input(str(path)).detection_image, dtype=np.float32)


def _similarity(rot, scale, shape, shift=(0.0, 0.0)):
    ny, nx = shape
    c = np.array([(nx - 1) / 2.0, (ny - 1) / 2.0])
    a = np.deg2rad(rot)
    r = scale * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    m = np.eye(3)
    m[:2, :2] = r
    m[:2, 2] = c - r @ c + shift
    return m


def _warp(img, m, seed=0):
    """The frame seen through m, holes filled with sky and noise of its own level."""
    inv = np.linalg.inv(m)
    bad = ~np.isfinite(img)
    med = float(np.median(img[~bad]))
    out = ndimage.affine_transform(np.where(bad, med, img).astype(np.float64),
                                   inv[:2, :2][::-1, ::-1], offset=inv[:2, 2][::-1], order=3,
                                   mode="constant", cval=np.nan)
    hole = ~np.isfinite(out)
    d = np.diff(img[::4].astype(np.float64), axis=1).ravel()
    d = d[np.isfinite(d)]
    sig = 1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2)
    out[hole] = med + sig * np.random.default_rng(seed).standard_normal(hole.sum())
    return out.astype(np.float32)


REAL_CASES = [
    ("real/singles/HorseHead.fits", 30.0, 1.0),        # nebulosity
    ("real/singles/HorseHead.fits", -170.0, 1.4),
    ("real/singles/a8280271.fits", 2.0, 1.0),          # raw frame, overscan, cosmic rays
    ("field/gc_MSX_E.fits.gz", 75.0, 1.1),             # extended emission
    ("field/anet_sdss.jpg", 120.0, 0.7),               # 8-bit JPEG
    ("real/singles/tetra3_2019-07-29T204726_Alt60_Azi135_Try1.tiff", 2.0, 1.0),
    ("field/seestar_m94_n1a.fits.gz", 30.0, 1.0),      # undersampled, hot pixels
    ("field/decam_DEC-OBS18a.mini.fits", -170.0, 1.4),  # 8 stars
    ("real/singles/gc_2mass_k.fits", 30.0, 1.0),        # crowded
]


@needs_data
@pytest.mark.parametrize("path,rot,scale", REAL_CASES)
def test_real_frame_against_warped_copy(path, rot, scale):
    img = _load(DATA / path)
    m = _similarity(rot, scale, img.shape, (7.0, -5.0))
    registers(img, _warp(img, m), m, tol=1.0)


@needs_data
def test_real_frame_whose_filled_outside_outshines_its_stars():
    """A star tracker's vignetted frame shrunk and rotated: the outside, filled
    at the frame's median sky, stands above its darker edges, and its noise
    peaks outrank most stars among the candidates.  Detection still finds
    the stars, at their width (before: 27 sources at 9.3 px)."""
    img = _load(DATA / "real/singles/tetra3_2019-07-29T204726_Alt60_Azi135_Try1.tiff")
    m = _similarity(120.0, 0.7, img.shape, (7.0, -5.0))
    a = find_sources(img, n_sources=100, nsigma=3.0)
    b = find_sources(_warp(img, m), n_sources=100, nsigma=3.0)
    assert b.meta["fwhm"] == pytest.approx(a.meta["fwhm"], rel=0.3)
    assert len(b) >= 50
    registers(img, _warp(img, m), m, tol=1.0)


@needs_data
@pytest.mark.parametrize("path", [
    "real/singles/HorseHead.fits",
    pytest.param("real/singles/a8280271.fits", marks=pytest.mark.xfail(
        strict=True, reason="known gap: two populations (4 bloated stars of ~8 px, faint "
        "1.6-2 px stars and cosmic rays); the scale search picks 8 px on the frame and 1.6 px "
        "on its rotated copy")),
    "field/gc_MSX_E.fits.gz", "field/anet_sdss.jpg"])
def test_real_frame_and_rotated_copy_give_the_same_list(path):
    """One frame and a copy rotated by 2 degrees: nearly the same FWHM and sources."""
    img = _load(DATA / path)
    m = _similarity(2.0, 1.0, img.shape)
    a = find_sources(img, n_sources=30)
    b = find_sources(_warp(img, m), n_sources=30)
    assert a.meta["fwhm"] == pytest.approx(b.meta["fwhm"], rel=0.35)
    assert len(a) >= 8 and len(b) >= 0.5 * len(a)
    # Most of a's stars are found again, where the transform puts them.
    pa = np.column_stack([a["x"], a["y"]]) @ m[:2, :2].T + m[:2, 2]
    pb = np.column_stack([b["x"], b["y"]])
    d = np.min(np.hypot(pa[:, None, 0] - pb[None, :, 0], pa[:, None, 1] - pb[None, :, 1]),
               axis=1)
    assert np.mean(d < 1.5) >= 0.6


@needs_data
def test_real_seestar_loop_closure():
    """Three Seestar subs of M94: T_bc o T_ab = T_ac to a fraction of a pixel."""
    f = DATA / "field"
    a, b, c = (_load(f / f"seestar_m94_{k}.fits.gz") for k in ("n1a", "n1b", "n2a"))
    tab = find_transform(a, b)[0].matrix
    tbc = find_transform(b, c)[0].matrix
    tac = find_transform(a, c)[0].matrix
    ny, nx = a.shape
    yy, xx = np.mgrid[0:ny:16, 0:nx:16]
    q = np.column_stack([xx.ravel(), yy.ravel(), np.ones(xx.size)])
    d = q @ (np.asarray(tbc) @ np.asarray(tab)).T - q @ np.asarray(tac).T
    assert np.max(np.hypot(d[:, 0], d[:, 1])) < 0.4


def test_too_few_sources_advice_names_fwhm():
    """The refusal says what detection saw and what to pass (fwhm, nsigma, a catalog)."""
    from astroalign_nd.exceptions import TooFewSourcesError

    noise = np.random.default_rng(0).normal(100.0, 5.0, (128, 128)).astype(np.float32)
    with pytest.raises(TooFewSourcesError, match=r"FWHM of .* px.*fwhm=.*nsigma"):
        find_transform(noise, noise)
