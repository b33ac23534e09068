"""Detection on the frames real cameras make: edge bands, bad columns, hot pixels, trails."""

import warnings

import numpy as np
import pytest
from astropy.nddata import CCDData

import astroalign_nd as aand
from astroalign_nd.detection import DetectionConfig
from astroalign_nd.detection import find_sources
from astroalign_nd.detection.daofind import control_sources
from astroalign_nd.simulate import (add_satellite_trail, simulate_field, simulate_pair,
                                    simulate_sequence)

from _frame_defects import add_edge_band, simulate_hot_night


def _frame_error(estimate, truth, shape, n=17):
    """Largest error (pixels) of ``estimate`` over the target frame."""
    m_est, m_true = np.asarray(estimate.matrix), np.asarray(truth.matrix)
    ny, nx = shape
    gx, gy = np.meshgrid(np.linspace(-0.5, nx - 0.5, n), np.linspace(-0.5, ny - 0.5, n))
    p = np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
    r = p @ np.linalg.inv(m_true).T @ m_est.T
    return float(np.max(np.hypot(r[:, 0] - p[:, 0], r[:, 1] - p[:, 1])))


def _registration_sources(image):
    table, _ = control_sources(image, mask=None, n_sources=100, n_enough=50,
                               config=DetectionConfig())
    return table


def _n_true(found, stars, radius=1.5):
    """Sources within ``radius`` of a true star."""
    d = np.hypot(np.asarray(found["x"])[:, None] - np.asarray(stars["x"])[None, :],
                 np.asarray(found["y"])[:, None] - np.asarray(stars["y"])[None, :])
    return int(np.sum(d.min(axis=1) < radius)) if len(found) else 0


def _bad_column(image, col, amplitude, seed):
    """A column ``amplitude`` sky sigmas above the sky, with its own Poisson-like noise."""
    rng = np.random.default_rng(seed)
    out = np.array(image, float)
    sig = 1.4826 * np.median(np.abs(out - np.median(out)))
    out[:, col] += sig * (amplitude + np.sqrt(amplitude) * rng.standard_normal(out.shape[0]))
    return out


@pytest.mark.parametrize("edge", ["bottom", "right"])
def test_edge_band_noise_peaks_are_not_sources(edge):
    # A sparse raw frame: its band's noise peaks outnumbered its stars.
    image, stars = simulate_field((1024, 1024), n_stars=30, seed=1)
    banded = add_edge_band(image, edge=edge, amplitude=25.0, decay=1.0, seed=1)
    found = _registration_sources(banded)
    depth = found["y"] if edge == "bottom" else 1023 - found["x"]
    assert np.sum(depth < 5) == 0
    # The stars are still found: as many as without the band, within a few.
    assert _n_true(found, stars) >= _n_true(_registration_sources(image), stars) - 2


def test_bad_column_noise_peaks_are_not_sources():
    pair = simulate_pair((1024, 1024), n_stars=40, seed=2)
    image = _bad_column(pair.source, 300, 15.0, seed=2)
    found = find_sources(image, n_sources=100)
    assert np.sum(np.abs(found["x"] - 300) < 1.5) == 0
    stars = pair.source_stars
    assert _n_true(found, stars) >= _n_true(find_sources(pair.source, n_sources=100), stars) - 2


def test_same_band_on_related_pair_leaves_the_transform():
    pair = simulate_pair((512, 512), n_stars=40, seed=1)
    src = add_edge_band(pair.source, seed=1)
    dst = add_edge_band(pair.target, seed=101)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # quality warnings are not the question here
        plain = aand.find_transform(pair.source, pair.target)[0]
        banded = aand.find_transform(src, dst)[0]
    e0 = _frame_error(plain, pair.transform, pair.target.shape)
    e1 = _frame_error(banded, pair.transform, pair.target.shape)
    assert e0 < 0.3
    assert abs(e1 - e0) <= 0.05


def _night(seed, n_frames=10, trail_frame=3):
    """Simulated night: 200 stars, sky sigma 10, shifts within 5 px, 300 single hot
    pixels at 50 sigma per frame and a 3-px wide 30-sigma trail across one frame."""
    seq = simulate_sequence((256, 256), n_frames=n_frames, n_stars=200, max_shift=5,
                            noise_sigma=10.0, seed=seed)
    rng = np.random.default_rng(seed + 999)
    frames = []
    for k, f in enumerate(seq.frames):
        d = np.array(f.data, float)
        d.flat[rng.integers(0, d.size, 300)] += 500.0
        if k == trail_frame:
            y0, y1 = rng.uniform(0, 255, 2)
            d = add_satellite_trail(d, (-10, y0), (266, y1), width=3.0, amplitude=300.0)
        frames.append(CCDData(d.astype(np.float32), unit="adu", uncertainty=f.uncertainty))
    return seq, frames


def test_hot_pixels_are_not_sources():
    image, stars = simulate_field((256, 256), n_stars=100, seed=4)
    rng = np.random.default_rng(4)
    hot = np.array(image, float)
    idx = rng.integers(0, hot.size, 300)
    hot.flat[idx] += 50 * 11.2
    found = find_sources(hot, n_sources=100, nsigma=3.0)
    hy, hx = np.unravel_index(idx, hot.shape)
    d = np.hypot(found["x"][:, None] - hx[None, :], found["y"][:, None] - hy[None, :]).min(1)
    truth = np.column_stack([stars["x"], stars["y"]])
    dt = np.hypot(found["x"][:, None] - truth[None, :, 0],
                  found["y"][:, None] - truth[None, :, 1]).min(1)
    # Every source on a hot pixel is a star there too.
    assert np.all(dt[d < 1.0] < 1.5)


def test_trail_pieces_are_not_sources():
    image, stars = simulate_field((256, 256), n_stars=200, flux_range=(300, 5e3), seed=0)
    y0, y1 = 60.0, 190.0
    trailed = add_satellite_trail(image, (-10, y0), (266, y1), width=3.0, amplitude=336.0)
    found = _registration_sources(trailed)

    def off_line(x, y):
        return np.abs((np.asarray(y) - y0) * 276 - (np.asarray(x) + 10) * (y1 - y0)) / np.hypot(
            276, y1 - y0)

    truth = np.column_stack([stars["x"], stars["y"]])
    on = off_line(found["x"], found["y"]) < 2.5
    dt = np.hypot(found["x"][:, None] - truth[None, :, 0],
                  found["y"][:, None] - truth[None, :, 1]).min(1)
    assert np.all(dt[on] < 1.5)  # a source on the trail is a star on it


def test_night_with_hot_pixels_and_a_trail_registers_every_frame():
    # Seed 10: frames 2 and 3 (3 with the trail) were 0.10 and 0.11 px off.
    _assert_every_frame_within(*_night(10, n_frames=4), 0.1)


@pytest.mark.parametrize("seed", [4, 14])
def test_hot_night_registers_every_frame(seed):
    # Nights 4 and 14 each had a frame 0.13-0.15 px off: hot pixels beside
    # faint stars pulled their centroids.
    _assert_every_frame_within(*simulate_hot_night(seed)[:2], 0.1)


def _assert_every_frame_within(seq, frames, tol):
    """Every frame registered onto the first within ``tol`` px of its true transform."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = aand.register_batch(frames[1:], frames[0])
    assert all(f.ok for f in res.frames)
    errors = [_frame_error(f.transform, seq.transforms[k], frames[0].shape)
              for k, f in enumerate(res.frames, start=1)]
    assert max(errors) < tol


def _off_line(x, y, ends):
    (x0, y0), (x1, y1) = ends
    return np.abs((np.asarray(y) - y0) * (x1 - x0) - (np.asarray(x) - x0) * (y1 - y0)) / np.hypot(
        x1 - x0, y1 - y0)


@pytest.mark.parametrize("seed", [0, 3])
def test_trail_pieces_of_a_night_frame_are_not_sources(seed):
    # The trail frame of a night, with and without its trail: a source on
    # the trail is one the frame has without it (a star on the trail).
    _, frames, k, ends = simulate_hot_night(seed)
    _, plain, _, _ = simulate_hot_night(seed, trail=False)
    found = _registration_sources(frames[k])
    clean = _registration_sources(plain[k])
    on = _off_line(found["x"], found["y"], ends) < 2.5
    d = np.hypot(np.asarray(found["x"])[on, None] - np.asarray(clean["x"])[None, :],
                 np.asarray(found["y"])[on, None] - np.asarray(clean["y"])[None, :])
    assert np.all(d.min(axis=1) < 1.0)
    # The trail took no star's place: as many sources off the trail as without it.
    off = _off_line(clean["x"], clean["y"], ends) >= 2.5
    assert np.sum(~on) >= np.sum(off) - 3


@pytest.mark.parametrize("fwhm", [2.0, 3.0, 5.0])
def test_despike_leaves_stars(fwhm):
    # Stars of the frame's FWHM, centred on a pixel (their sharpest) and off
    # it, at every brightness, with Poisson noise: no pixel of theirs is
    # taken for a spike.
    from astroalign_nd.detection.candidates import _despike
    from astroalign_nd.simulate import render_stars

    rng = np.random.default_rng(int(fwhm * 10))
    n, half, sky, read = 400, 8, 100.0, 10.0
    noise = np.sqrt(sky + read**2)
    cut = np.zeros((n, 2 * half + 1, 2 * half + 1))
    dx = np.where(np.arange(n) % 2 == 0, 0.0, rng.uniform(-0.5, 0.5, n))
    dy = np.where(np.arange(n) % 2 == 0, 0.0, rng.uniform(-0.5, 0.5, n))
    flux = 10 ** rng.uniform(2.0, 6.5, n)
    for i in range(n):
        render_stars(cut[i].shape, [half + dx[i]], [half + dy[i]], [flux[i]], fwhm=fwhm,
                     out=cut[i])
    cut = rng.poisson(cut + sky) - sky + rng.normal(0.0, read, cut.shape)
    bad = np.zeros(cut.shape, bool)
    assert np.array_equal(_despike(cut, bad, noise, fwhm), cut)
    # A hot pixel at 50 sigma beside each star (3 px from its centre) is
    # replaced, and nothing else.
    hot = cut.copy()
    hot[:, half, half + 3] += 50 * noise
    out = _despike(hot, bad, noise, fwhm)
    others = np.ones(cut.shape[1:], bool)
    others[half, half + 3] = False
    assert np.array_equal(out[:, others], hot[:, others])
    faint = flux < 3e3  # where the hot pixel outshines the star's light by far
    assert np.all(np.abs(out[faint, half, half + 3] - cut[faint, half, half + 3]) < 5 * noise)


def test_despike_paths_agree(monkeypatch):
    # The neighbours' maximum gathered per pixel (few pixels above the noise)
    # and over the whole stack (a bright plate): the same cutouts, bit for
    # bit, with spikes, bad pixels and the tiles' borders.
    from astroalign_nd.detection import candidates

    rng = np.random.default_rng(5)
    noise = 10.0
    for level in (0.0, 80.0):  # few pixels above 5 sigma, then most of them
        cut = rng.normal(level, noise, (60, 15, 15))
        bad = rng.random(cut.shape) < 0.02
        spikes = rng.integers(0, cut.size, 40)
        cut.flat[spikes] += 100 * noise
        cut.flat[rng.integers(0, cut.size, 20)] = np.nan  # no good neighbour count
        bad |= np.isnan(cut)
        cut[bad] = 0.0
        out = {}
        for frac in (0, 10**9):
            monkeypatch.setattr(candidates, "_WHOLE_STACK_FRACTION", frac)
            out[frac] = candidates._despike(cut, bad, noise, 3.0)
        assert np.array_equal(out[0], out[10**9])
        changed = out[0] != cut
        was_spike = np.zeros(cut.shape, bool)
        was_spike.flat[spikes] = True
        # The spikes are replaced (but those on bad pixels), and nothing else.
        assert changed.sum() >= 30 and not (changed & ~was_spike).any()
        assert np.all(np.abs(out[0][changed] - level) < 6 * noise)


def test_spike_replacement_is_numpys_nanmedian():
    # A spike's replacement, the median of its good neighbours: np.nanmedian's
    # values, bit for bit (zeros of either sign, odd and even counts).
    from astroalign_nd.detection.candidates import _nanmedian_columns

    rng = np.random.default_rng(7)
    for trial in range(200):
        a = np.round(rng.normal(0, 4, (8, 25)) / (2 if trial % 2 else 0.01))
        a[rng.random(a.shape) < 0.2] = -0.0
        a[rng.random(a.shape) < rng.uniform(0, 0.9)] = np.nan
        a[rng.integers(0, 8, 25), np.arange(25)] = rng.normal(0, 4, 25)  # one good at least
        want, got = np.nanmedian(a, axis=0), _nanmedian_columns(a)
        assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))


def test_undersampled_frame_is_not_despiked(monkeypatch):
    # Stars of 1.2 px FWHM are nearly spikes themselves: such a frame is
    # measured without despiking, and its stars are all found.
    import astroalign_nd.detection.candidates as candidates
    import astroalign_nd.detection.daofind as daofind

    def refuse(*args, **kwargs):
        raise AssertionError("an undersampled frame was despiked")

    for module in (candidates, daofind):
        monkeypatch.setattr(module, "_despike", refuse)
    image, stars = simulate_field((256, 256), n_stars=60, fwhm=1.2, flux_range=(3e3, 3e5),
                                  seed=2)
    found = find_sources(image, n_sources=100)
    assert found.meta["fwhm"] < 2.0
    assert _n_true(found, stars, radius=0.5) >= 55


def test_trails_are_found_only_where_a_trail_is():
    # Every night's trail is found, along its true line; no other frame has one,
    # nor a crowded cluster field (stars line up by chance there).
    from astroalign_nd.detection.background import estimate_noise
    from astroalign_nd.detection.candidates import _binned_candidates, _recenter
    from astroalign_nd.detection.trails import find_trails

    def trails(image):
        noise = estimate_noise(image)
        cand = _recenter(image, None, _binned_candidates(image, None, 2, noise, 3.0, 180),
                         2, None)
        return find_trails(cand["x"], cand["y"], image, None, noise)

    for seed in (0, 5):
        _, frames, k, ends = simulate_hot_night(seed)
        found = [trails(frame) for frame in frames]
        assert [len(f) for f in found] == [int(i == k) for i in range(len(frames))]
        (x0, y0), (x1, y1) = ends
        t = np.linspace(0.0, 1.0, 11)
        assert np.all(found[k][0].distance(x0 + t * (x1 - x0), y0 + t * (y1 - y0)) < 0.5)
    crowded, _ = simulate_field((512, 512), n_stars=4000, seed=3)
    assert trails(crowded) == []


@pytest.mark.parametrize("seed", [1, 4])
def test_cosmic_ray_heavy_raw_frame_measured_at_the_stars_width(seed):
    # 150 cosmic rays and 50 hot pixels on 60-120 stars of 2.5-3.5 px: the
    # cosmic rays' widths spread over 0.7-2.6 px and outnumber the stars,
    # which share one width closely.  Detection measures at the stars'
    # width, so their centroids are right (at 1.0 px, the cosmic rays'
    # width, they came out ~1 px off and the transform 0.35-0.40 px off).
    from scipy.spatial import cKDTree

    from astroalign_nd import Reference, find_transform
    from _frame_defects import simulate_trust_case

    pair = simulate_trust_case("resampled_copy", seed=seed)
    ref = Reference(pair.source)
    pts = ref.stars(50)[0]
    assert 2.3 <= ref.fwhm <= 3.7
    truth = np.column_stack([np.asarray(pair.source_stars["x"]),
                             np.asarray(pair.source_stars["y"])])
    dist, _ = cKDTree(truth).query(pts)
    assert np.median(dist) < 0.15
    t, _ = find_transform(pair.source, pair.target)
    yy, xx = np.mgrid[0:512:64, 0:512:64]
    grid = np.column_stack([xx.ravel(), yy.ravel()]).astype(float)
    m = np.asarray(pair.truth_matrix)
    expect = grid @ m[:2, :2].T + m[:2, 2]
    got = grid @ t.matrix[:2, :2].T + t.matrix[:2, 2]
    assert np.max(np.hypot(*(got - expect).T)) < 0.1
