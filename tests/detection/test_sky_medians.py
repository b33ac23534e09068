# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The detector's sky figures against their definitions: every shortcut
(bounds that decide without a median, one sort for both middle values,
column-wise expansion) gives the value of the plain computation with
`numpy.median`, bit for bit.
"""

import numpy as np
import pytest
from scipy.ndimage import median_filter

from astroalign_nd.detection.background import (_background_map, _interp_weights,
                                                _local_background, estimate_noise)
from astroalign_nd.detection.lines import _BINNED_EXCESS, _BINNED_WINDOW, _bright_lines


def _lines_by_definition(resid, noise):
    """Any row or column whose median exceeds the running median of 7 lines by the limit."""
    for level in (np.median(resid, axis=1), np.median(resid, axis=0)):
        level = level.astype(resid.dtype)
        trend = median_filter(level, size=_BINNED_WINDOW, mode="reflect")
        with np.errstate(invalid="ignore"):
            if np.any(level - trend > _BINNED_EXCESS * noise):
                return True
    return False


def _residual(rng, shape, kind):
    r = rng.normal(0.0, 1.0, shape).astype(np.float32)
    ny, nx = shape
    if kind == "row":
        r[rng.integers(ny)] += rng.uniform(5.0, 8.0)  # near the limit: either answer
    elif kind == "column":
        r[:, rng.integers(nx)] += 10.0
    elif kind == "band":
        r[:rng.integers(1, 6)] += rng.uniform(-10.0, 12.0)
    elif kind == "nebula":  # smooth structure over many lines
        r += np.cumsum(rng.normal(0.0, 2.0, ny))[:, None].astype(np.float32)
    elif kind == "stars":
        r[rng.random(shape) < 0.3] += 40.0
    elif kind == "nan":
        r[rng.random(shape) < 0.02] = np.nan
    elif kind == "quantised":
        r = np.round(r).astype(np.float32)
    return r


@pytest.mark.parametrize("kind", ["plain", "row", "column", "band", "nebula", "stars", "nan",
                                  "quantised"])
def test_bright_lines_as_defined(kind):
    rng = np.random.default_rng(abs(hash(kind)) % 2**32)
    answers = []
    for _ in range(60):
        resid = _residual(rng, tuple(rng.integers(16, 90, 2)), kind)
        for noise in (1.0, 0.7, 1.5):
            want = _lines_by_definition(resid, noise)
            assert _bright_lines(resid, noise) == want
            answers.append(want)
    if kind in ("column", "plain"):  # a 10-sigma column is found; white noise has none
        assert all(answers) if kind == "column" else not any(answers)


def _map_by_definition(binned, box):
    """Block medians, expanded bilinearly in float64 with whole-frame gathers."""
    ny, nx = binned.shape
    by, bx = max(1, ny // box), max(1, nx // box)
    cy, cx = ny // by, nx // bx
    blocks = binned[: by * cy, : bx * cx].reshape(by, cy, bx, cx).swapaxes(1, 2)
    bkg = np.median(blocks.reshape(by, bx, -1), axis=2).astype(binned.dtype)
    ky, wy0, wy1 = _interp_weights(ny, by, cy)
    kx, wx0, wx1 = _interp_weights(nx, bx, cx)
    b64 = bkg.astype(float)
    rows = np.repeat(b64[:1], ny, axis=0) if by == 1 else (
        wy0[:, None] * b64[ky] + wy1[:, None] * b64[ky + 1])
    if bx == 1:
        return np.repeat(rows[:, :1], nx, axis=1).astype(np.float32), bkg
    return (wx0 * rows[:, kx] + wx1 * rows[:, kx + 1]).astype(np.float32), bkg


@pytest.mark.parametrize("shape,box", [((320, 180), 43), ((250, 325), 64), ((40, 300), 64),
                                       ((300, 40), 64), ((37, 29), 4)])
def test_background_map_as_defined(shape, box):
    rng = np.random.default_rng(shape[0])
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    binned = (rng.normal(500.0, 20.0, shape) + 0.3 * xx - 0.7 * yy + 1e-3 * xx * yy).astype(
        np.float32)
    got, got_bkg = _background_map(binned, box)
    want, want_bkg = _map_by_definition(binned, box)
    assert got.dtype == np.float32 and got.shape == shape
    assert got.tobytes() == want.tobytes()
    assert got_bkg.tobytes() == want_bkg.tobytes()
    # The gradient is followed: the map is within a few counts of the true sky.
    sky = 500.0 + 0.3 * xx - 0.7 * yy + 1e-3 * xx * yy
    assert np.median(np.abs(got - sky)) < 8.0


def _tile_medians_by_definition(cut, bad, r_in, offset):
    n, size, _ = cut.shape
    g = np.arange(size) - size // 2
    outer = (g[:, None] ** 2 + g[None, :] ** 2) >= r_in**2
    out = np.zeros(n)
    for i in range(n):
        vals = cut[i][outer & ~bad[i]]
        if offset is not None:
            vals = vals - offset[i]
        out[i] = np.median(vals) if vals.size else 0.0
    return out


@pytest.mark.parametrize("source", ["float32", "float64", "quantised"])
@pytest.mark.parametrize("with_offset", [False, True])
def test_local_background_as_defined(source, with_offset):
    rng = np.random.default_rng(7)
    n, size = 60, 15
    cut = rng.normal(100.0, 5.0, (n, size, size))
    if source == "float32":
        cut = cut.astype(np.float32).astype(float)
    elif source == "quantised":
        cut = np.round(cut / 4.0)
    bad = np.zeros(cut.shape, bool)
    bad[:5, :, :4] = True  # tiles at an edge ...
    bad[5:10] = rng.random((5, size, size)) < 0.3  # ... and under a mask
    bad[10] = True  # nothing good: 0
    cut[bad] = 0.0
    offset = rng.normal(100.0, 5.0, n) if with_offset else None
    got = _local_background(cut, bad, 4.5, offset=offset)
    want = _tile_medians_by_definition(cut, bad, 4.5, offset)
    assert got.tobytes() == want.tobytes()
    assert got[10] == 0.0
    # The sky of the tiles (100, or 0 less the offset) is found.
    sky = np.delete(got + (0 if offset is None else offset), 10)
    assert np.all(np.abs(sky - (25.0 if source == "quantised" else 100.0)) < 2.0)


def _noise_by_definition(data):
    step = max(1, data.size // 50_000)
    rows = data[::step]
    sigmas = []
    for lag in (1, 3):
        diff = (rows[:, lag:] - rows[:, :-lag]).ravel()
        diff = diff[np.isfinite(diff)]
        sigma = 1.4826 * np.median(np.abs(diff - np.median(diff))) / np.sqrt(2.0)
        sigmas.append(sigma if sigma > 0 else np.std(diff) / np.sqrt(2.0))
    return float(max(sigmas))


@pytest.mark.parametrize("kind", ["white", "quantised", "flat", "correlated"])
def test_estimate_noise_as_defined(kind):
    rng = np.random.default_rng(3)
    data = rng.normal(1000.0, 10.0, (300, 400)).astype(np.float32)
    if kind == "quantised":  # many equal differences
        data = np.round(data / 12.0).astype(np.float32)
    elif kind == "flat":  # a mostly flat sky: the standard deviation's figure
        data = np.full((300, 400), 50.0, np.float32)
        data[rng.random(data.shape) < 0.05] += 5.0
    elif kind == "correlated":  # neighbours share noise: lag 3 sees more
        data = (data[:, 1:] + data[:, :-1]).astype(np.float32) / 2
    assert estimate_noise(data) == _noise_by_definition(data)
    if kind == "white":
        assert estimate_noise(data) == pytest.approx(10.0, rel=0.05)


def _correlation_by_definition(data, noise, k=2, max_side=256):
    ny, nx = data.shape
    y0, x0 = max(0, (ny - max_side) // 2), max(0, (nx - max_side) // 2)
    crop = data[y0:y0 + max_side, x0:x0 + max_side].astype(np.float64)
    cy, cx = (crop.shape[0] // k) * k, (crop.shape[1] // k) * k
    with np.errstate(invalid="ignore"):  # (inf - inf: dropped)
        blocks = crop[:cy, :cx].reshape(cy // k, k, cx // k, k).sum(axis=(1, 3))
        diff = np.diff(blocks, axis=1).ravel()
    diff = diff[np.isfinite(diff)]
    sigma = 1.4826 * np.median(np.abs(diff - np.median(diff))) / np.sqrt(2.0)
    factor = float(sigma / (k * noise))
    return factor if factor > 1.08 else 1.0


@pytest.mark.parametrize("kind", ["white", "smoothed", "quantised", "holes"])
def test_correlated_noise_as_defined(kind):
    from astroalign_nd.detection.background import _correlated_noise_factor

    rng = np.random.default_rng(11)
    data = rng.normal(200.0, 10.0, (300, 300))
    if kind == "smoothed":  # resampled: neighbours share their noise
        data = (data + np.roll(data, 1, axis=0) + np.roll(data, 1, axis=1)) / 3.0
    elif kind == "quantised":  # many equal block differences
        data = np.round(data / 15.0)
    elif kind == "holes":
        data[rng.random(data.shape) < 0.01] = np.nan
        data[:40, :40] = np.inf
    data = data.astype(np.float32)
    noise = estimate_noise(data)
    got = _correlated_noise_factor(data, None, noise)
    assert got == _correlation_by_definition(data, noise)
    if kind == "white":
        assert got == 1.0
    elif kind == "smoothed":
        assert got > 1.15
