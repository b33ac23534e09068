# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Frame quality: the measures against the truth, the weights, the selection with its
reasons (stack, live stack), normalisation by the stars, and the noise of the frames as
taken."""

import warnings

import numpy as np
import pytest
from astropy.table import Table

from astroalign_nd import AstroalignWarning, frame_quality, stack
from astroalign_nd.simulate import simulate_image, simulate_night, simulate_sequence
from astroalign_nd.stacking import LiveStack
from astroalign_nd.stacking.quality import (FrameMeasures, SelectionError, quality_weights,
                                            select_frames, star_shapes, transparency)


@pytest.fixture(scope="module")
def night():
    # Six frames: the reference (2.5 px), one at 40% transparency, one trailed to
    # elongation 3; bright stars enough to register every frame.
    return simulate_night((256, 256), n_frames=6, n_cloudy=1, n_trailed=1, n_satellite=0,
                          n_stars=160, n_faint=9, fwhm_range=(2.2, 4.5), seed=11)


@pytest.fixture(scope="module")
def night_table(night):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return frame_quality(night.frames, select="auto")


def test_star_shapes_recover_fwhm_and_trailing():
    x, y = [20.3, 60.7], [30.6, 31.2]
    round_ = simulate_image((64, 96), x, y, [1e5, 1e5], fwhm=4.0, noise=False)
    fwhm, elong = star_shapes(round_, x, y, fwhm_guess=3.0)
    assert np.allclose(fwhm, np.hypot(4.0, 2.3548 / np.sqrt(12)), atol=0.05)  # pixelised
    assert np.allclose(elong, 1.0, atol=0.01)
    # Trailed: the Gaussian of sigma s smeared over L = sqrt(12 (E^2 - 1)) s is E:1.
    s = 3.0 / 2.3548
    trailed = simulate_image((64, 96), x, y, [1e5, 1e5], fwhm=3.0, noise=False,
                             trail=(np.sqrt(12 * 8) * s, 30.0))
    _, elong = star_shapes(trailed, x, y, fwhm_guess=3.0)
    assert np.all((elong > 2.6) & (elong < 3.6))


def test_transparency_is_the_stars_flux_ratio():
    rng = np.random.default_rng(3)
    x, y = rng.uniform(20, 236, 60), rng.uniform(20, 236, 60)
    flux = rng.uniform(3e3, 3e4, 60)
    ref = simulate_image((256, 256), x, y, flux, fwhm=2.5, background=200.0, seed=1)
    # Cloud: 60% of the light, stars and sky; worse seeing; a shift.
    img = simulate_image((256, 256), x - 3.4, y + 2.2, 0.6 * flux, fwhm=5.0,
                         background=120.0, seed=2)
    from astroalign_nd.stacking.quality import measure_frame
    m_ref, m = measure_frame(ref), measure_frame(img)
    assert abs(m.fwhm - 5.0) < 0.25 and abs(m_ref.fwhm - 2.5) < 0.2
    pts = np.column_stack([x, y])
    t, n = transparency(img, ref, pts + [-3.4, 2.2], pts, m, m_ref)
    assert n >= 20 and abs(t - 0.6) < 0.6 * 0.02


def test_frame_quality_table_against_the_truth(night, night_table):
    t, meta = night_table, night.meta
    assert len(t) == 6 and t["name"][0] == "frame0" and np.isfinite(t["time"]).all()
    good = ~meta["trailed"]
    assert np.allclose(t["transparency"][good], meta["transparency"][good], rtol=0.05)
    assert np.allclose(t["fwhm"][good], meta["fwhm"][good], rtol=0.1)
    k = int(np.flatnonzero(meta["trailed"])[0])
    assert t["elongation"][k] > 2.5 and np.all(t["elongation"][good] < 1.3)
    assert not t["used"][k] and t["reason"][k].startswith("trailed")
    # Every other frame used; the reference's weight is 1 and the cloudy frame's ~0.16x
    # that of a frame of the same seeing.
    c = int(np.flatnonzero(meta["cloudy"])[0])
    assert t["used"][[i for i in range(6) if i not in (k, c)]].all()
    assert t["weight"][0] == 1.0 and (t["rms"][good][1:] < 0.3).all()


def test_weights_formula_and_selection_rules():
    t = Table({"name": list("abcdef"), "fwhm": [3.0, 3.1, 2.9, 6.0, 3.0, 3.2],
               "elongation": [1.05, 1.1, 1.05, 1.1, 3.0, 1.1],
               "transparency": [1.0, 0.99, 1.0, 1.0, 1.0, 0.3],
               "n_stars": [100, 95, 98, 60, 80, 30], "sky_noise": [10.0] * 6,
               "star_ratio": [1.0, 0.95, 0.98, 0.6, 0.8, 0.3]})
    w = quality_weights(t)
    assert np.allclose(w, [1.0, (3 / 3.1) ** 2 * 0.99 ** 2, (3 / 2.9) ** 2, 0.25, 1.0,
                           0.09 * (3 / 3.2) ** 2])
    t["weight"] = w
    reasons = select_frames(t, "auto")
    assert reasons[4].startswith("trailed") and "transparency" in reasons[5]
    # Seeing twice the rest of a steady night's is an outlier of it.
    assert reasons[:3] == [None] * 3 and "outlier of the night: FWHM 6" in reasons[3]
    reasons = select_frames(t, None, max_fwhm=5.0, min_stars=50)
    assert reasons[3] == "fwhm 6.00 px > max_fwhm 5" and "min_stars 50" in reasons[5]
    assert select_frames(t, 0.5).count(None) == 3  # the best half by weight, the reference in
    with pytest.raises(SelectionError, match="relax max_fwhm .it left out 5"):
        select_frames(t, None, max_fwhm=2.0)


def test_stack_auto_weights_selection_and_header(night):
    with pytest.warns(AstroalignWarning, match=r"frame\d was left out of the stack: trailed"):
        ccd = stack(night.frames, weights="auto", max_elongation=2.0, normalize="stars")
    h = ccd.meta
    k = int(np.flatnonzero(night.meta["trailed"])[0])
    c = int(np.flatnonzero(night.meta["cloudy"])[0])
    assert h["NCOMBINE"] == 5 and h["AAREJ001"].startswith(f"frame{k}: trailed")
    assert "astroalign_nd stack: 5 of 6 frames used" in str(h["HISTORY"])
    names = [h[f"IMCMB{i:03d}"] for i in range(1, 6)]
    j = names.index(f"frame{c}") + 1
    # normalize='stars': the cloudy frame scaled by 1 / 0.4; its weight 0.4^2 times the
    # reference's over the ratios of their PSF areas and sky variances; its measures in
    # the header.
    assert abs(h[f"AASCL{j:03d}"] * 0.4 - 1) < 0.05
    assert abs(h[f"AATRN{j:03d}"] - 0.4) < 0.02 and h["AAFWH001"] == pytest.approx(
        2.58, abs=0.1)
    clear = [i for i in range(1, 6) if i != j]
    expect = 0.16 * (h["AAFWH001"] / h[f"AAFWH{j:03d}"] * h["AANOI001"]
                     / h[f"AANOI{j:03d}"]) ** 2
    assert h[f"AAWGT{j:03d}"] == pytest.approx(expect, rel=0.15)
    assert all(h[f"AAWGT{i:03d}"] > 0.2 for i in clear)


def test_selection_that_leaves_too_few_names_the_limit(night):
    with pytest.raises(SelectionError, match="relax max_fwhm"):
        stack(night.frames[:3], max_fwhm=1.0)


def test_noise_and_weights_of_the_frames_as_taken():
    # Equal-quality frames with sub-pixel shifts and no uncertainty: the unresampled
    # reference weighs as much as the resampled frames (their smoothed noise does not
    # count), and the stack's uncertainty is the scatter of block means of (stack - truth)
    # (the noise that apertures see, correlated by the interpolation).
    seq = simulate_sequence((192, 192), n_frames=5, n_stars=80, integer_shifts=False,
                            uncertainty=False, noise_sigma=10.0, seed=5)
    ccd = stack(seq.frames)
    w = np.array([ccd.meta[f"AAWGT{i:03d}"] for i in range(1, 6)])
    assert abs(w[0] / np.median(w[1:]) - 1) < 0.1
    resid = np.asarray(ccd.data, float) - seq.truth
    unc = float(np.median(ccd.uncertainty.array[16:-16, 16:-16]))
    blocks = resid[16:176, 16:176].reshape(40, 4, 40, 4).mean(axis=(1, 3))
    scatter = 4 * 1.4826 * np.median(np.abs(blocks - np.median(blocks)))
    assert abs(unc / scatter - 1) < 0.1
    assert abs(unc - 10.0 / np.sqrt(5)) < 0.5


def test_clipping_keeps_the_sharp_frames_stars():
    # Seeing from 2 to 5 px: plain sigma clipping rejects the cores of the sharpest
    # frame's stars (far above the others' at the same pixel); the star allowance does not.
    x = np.array([40.3, 90.6, 140.2, 60.5, 120.8])
    y = np.array([50.4, 110.7, 60.3, 150.1, 140.6])
    rng = np.random.default_rng(99)
    xs = np.concatenate([x, rng.uniform(10, 180, 60)])
    ys = np.concatenate([y, rng.uniform(10, 180, 60)])
    flux = np.concatenate([np.full(5, 2e5), rng.uniform(3e3, 3e4, 60)])
    frames = [simulate_image((192, 192), xs, ys, flux, fwhm=fwhm, background=100.0, seed=k)
              for k, fwhm in enumerate([3.0, 2.0, 3.5, 4.0, 5.0, 4.5])]
    sharp = stack(frames, weights=None)
    plain = stack(frames, weights=None, star_tolerance=0)
    n_sharp, n_plain = sharp.meta["AANRJ002"], plain.meta["AANRJ002"]
    assert n_plain > 50 and n_sharp < n_plain / 5
    # The stack's peaks: the sharp frame's cores are in.
    peak = [float(np.max(np.asarray(c.data)[int(y[0]) - 3:int(y[0]) + 4,
                                            int(x[0]) - 3:int(x[0]) + 4])) for c in (sharp, plain)]
    assert peak[0] > 1.05 * peak[1]


def test_live_stack_leaves_out_a_bad_arriving_frame(night):
    live = LiveStack(night.frames[0], weights="auto", select="auto", name="ref")
    c = int(np.flatnonzero(night.meta["cloudy"])[0])
    order = [i for i in range(1, 6) if not night.meta["trailed"][i] and i != c] + [c]
    for i in order[:-1]:
        assert live.add(night.frames[i], name=f"f{i}") is None
    with pytest.warns(AstroalignWarning, match=f"f{c} was left out of the live stack: "
                      "outlier of the night: transparency"):
        why = live.add(night.frames[c], name=f"f{c}")
    assert why.startswith("outlier of the night") and live.rejected[-1] == (f"f{c}", why)
    q = live.quality
    assert list(q["used"]) == [True] * (len(order)) + [False] and f"f{c}" not in live.used
    assert live.result().meta["NREJECT"] == 1


def test_bad_quality_options():
    frames = [np.zeros((8, 8))] * 3
    for kw, what in ((dict(select="best"), "select must be"),
                     (dict(select=1.5), "select must be"), (dict(max_fwhm=-1), "max_fwhm"),
                     (dict(min_stars=2.5), "min_stars"), (dict(weights="snr"), "weights")):
        with pytest.raises((ValueError, TypeError), match=what):
            stack(frames, **kw)
    assert isinstance(FrameMeasures.__doc__, str)
