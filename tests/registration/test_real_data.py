# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
find_transform on REAL image pairs (../shared/data/real, see its README.txt).

The reference values are astroalign's estimates quoted in the README, not
ground truth, so the comparisons with them are loose; the HAT-P-32 sequence
is also checked for self-consistency (T_jk o T_ij = T_ik), which needs no
truth at all.
"""

import functools
from pathlib import Path

import numpy as np
import pytest

from astroalign_nd import SimilarityTransform, find_sources, find_transform

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "real"
PAIRS = DATA / "pairs"

pytestmark = pytest.mark.skipif(
    not PAIRS.is_dir(),
    reason=f"real test images not available (expected the directory {PAIRS})")


def frame_error(m_est, m_ref, shape, n=15):
    """Largest distance (pixels) between two transforms over a frame of ``shape``."""
    ny, nx = shape
    gx, gy = np.meshgrid(np.linspace(-0.5, nx - 0.5, n), np.linspace(-0.5, ny - 0.5, n))
    p = np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
    d = p @ np.asarray(m_est).T - p @ np.asarray(m_ref).T
    return float(np.max(np.hypot(d[:, 0], d[:, 1])))


def angle_diff(a, b):
    """Difference of two angles in degrees, wrapped to [-180, 180)."""
    return (a - b + 180.0) % 360.0 - 180.0


# -- M44 plates (1910 -> 1975) -------------------------------------------------------------

M44 = PAIRS / "m44_plates"
M44_1910 = M44 / "m44-1910-04-01.jpg"
M44_1975 = M44 / "m44-1975-01-18.jpg"


def test_m44_fwhm_estimate():
    """The plates' stars are >= 10 px wide at half maximum (even unsaturated ones)."""
    from skimage.io import imread

    for path in (M44_1910, M44_1975):
        tab = find_sources(imread(path), n_sources=50)
        assert tab.meta["fwhm"] > 8.0, f"{path.name}: fwhm estimate {tab.meta['fwhm']}"


# digitised plates 65 years apart: wide stars, proper motions.
@pytest.mark.filterwarnings("ignore::astroalign_nd.PoorFitWarning")
def test_m44_plates():
    # Read through the path: the package reads JPEG files itself.
    t, (src, dst) = find_transform(M44_1910, M44_1975)
    q = t.meta["quality"]
    assert q["n_matches"] >= 20
    assert len(src) == q["n_matches"]
    assert float(t.scale.value) == pytest.approx(0.952, abs=0.005)
    # The README's estimate was made on the files' rows top first; JPEG files are read
    # bottom-up (row 0 = the bottom, as in FITS), y -> 2999 - y in both plates: the
    # rotation changes sign and the shift is that of the flipped frames.
    flip = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 2999.0], [0.0, 0.0, 1.0]])
    readme = SimilarityTransform(scale=0.952, rotation=-0.12, translation_x=-72.8,
                                 translation_y=242.7).matrix
    expected = flip @ readme @ flip
    assert angle_diff(t.rotation_deg, 0.12) == pytest.approx(0.0, abs=0.1)
    np.testing.assert_allclose(t.translation, expected[:2, 2], atol=3.0)
    assert not t.mirrored


# -- HAT-P-32 sequence (5 MicroObservatory frames) -----------------------------------------

HATP32 = sorted((PAIRS / "exotic_hatp32_microobservatory").glob("*.FITS"))
HATP32_SHAPE = (500, 650)
# README estimates for (reference -> frame j): rotation (deg), shift (px).
HATP32_README = {
    1: (-0.12, (-56.9, 41.7)),
    2: (-0.25, (-130.7, 62.2)),
    3: (-0.41, (-216.6, 58.0)),
    4: (-0.58, (-275.3, 23.2)),
}
PAIRS_IJ = [(i, j) for i in range(5) for j in range(i + 1, 5)]
TRIPLETS = [(i, j, k) for i in range(5) for j in range(i + 1, 5) for k in range(j + 1, 5)]


@functools.lru_cache(maxsize=None)
def _hatp32(i, j):
    """find_transform(frame i -> frame j), computed once; exceptions are kept."""
    try:
        return find_transform(HATP32[i], HATP32[j])
    except Exception as exc:  # reported by the tests that need this pair
        return exc


def _hatp32_ok(i, j):
    res = _hatp32(i, j)
    if isinstance(res, Exception):
        pytest.fail(f"find_transform(frame {i} -> frame {j}) failed: "
                    f"{type(res).__name__}: {res}")
    return res


def test_hatp32_files_present():
    assert len(HATP32) == 5, [p.name for p in HATP32]


@pytest.mark.parametrize("i, j", PAIRS_IJ)
def test_hatp32_pair(i, j):
    t, (src, dst) = _hatp32_ok(i, j)
    q = t.meta["quality"]
    assert q["n_matches"] >= 20
    assert q["rms"] < 0.5
    assert float(t.scale.value) == pytest.approx(1.0, abs=1e-3)  # README: < 0.05 %
    assert not t.mirrored


@pytest.mark.parametrize("j", sorted(HATP32_README))
def test_hatp32_reference_pairs_match_readme(j):
    t, _ = _hatp32_ok(0, j)
    rot, shift = HATP32_README[j]
    assert angle_diff(t.rotation_deg, rot) == pytest.approx(0.0, abs=0.1)
    np.testing.assert_allclose(t.translation, shift, atol=2.0)


@pytest.mark.parametrize("i, j, k", TRIPLETS)
def test_hatp32_consistency(i, j, k):
    """T_jk o T_ij == T_ik to < 0.3 px over the frame."""
    t_ij = _hatp32_ok(i, j)[0].matrix
    t_jk = _hatp32_ok(j, k)[0].matrix
    t_ik = _hatp32_ok(i, k)[0].matrix
    err = frame_error(t_jk @ t_ij, t_ik, HATP32_SHAPE)
    assert err < 0.3, f"T_{j}{k} o T_{i}{j} differs from T_{i}{k} by {err:.3f} px"


# -- JWST NIRCam F200W pair (already on a common grid) -------------------------------------

JWST = sorted((PAIRS / "jwst_a2744_f200w").glob("*.fits"))


def test_jwst_identity_translation():
    t, _ = find_transform(JWST[0], JWST[1], transform_type="translation")
    assert np.hypot(*t.translation) < 0.2


def test_jwst_identity():
    assert len(JWST) == 2
    t, (src, dst) = find_transform(JWST[0], JWST[1])
    q = t.meta["quality"]
    assert q["n_matches"] >= 20
    err = frame_error(t.matrix, np.eye(3), (900, 900))
    # Real galaxies measured at two depths: centroids differ by ~0.1 px, so
    # "identity" holds to a few tenths of a pixel, not to simulation level
    # (astroalign's own estimate is 0.4 px away).
    assert err < 0.3, (
        f"identity expected: the transform is {err:.3f} px from it over the frame "
        f"(scale {float(t.scale.value):.6f}, rotation {t.rotation_deg:.4f} deg, "
        f"shift {t.translation.round(3)}, {q['n_matches']} matches, rms {q['rms']:.3f})")
