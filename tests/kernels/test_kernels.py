# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The compiled detection and matching loops against their NumPy twins."""

import os
import shutil
import subprocess
import sysconfig

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from astroalign_nd import SimilarityTransform, conf
from astroalign_nd import _kernels as k
from astroalign_nd import resample as rs


@pytest.fixture
def numpy_only(monkeypatch):
    """Run the body with the NumPy versions of the kernels."""
    def use_numpy():
        monkeypatch.setattr(conf, "use_compiled", False)
    return use_numpy


@pytest.fixture(params=[1, 3])
def threads(request, monkeypatch):
    monkeypatch.setattr(conf, "num_threads", request.param)
    return request.param


def test_compiled_module_is_built():
    # CI installs the package, so the compiled module must be there: without it
    # everything silently runs on the slower NumPy path.  Except where it was installed
    # without the extension on purpose (.ci/run's no-compiler step, tox -e test-nocompiler).
    if os.environ.get("ASTROALIGN_ND_NO_EXTENSION", "").strip() not in ("", "0"):
        pytest.skip("installed without the compiled extension (ASTROALIGN_ND_NO_EXTENSION)")
    if not k.HAVE_COMPILED and not _c_compiler_works():
        # A user's machine without a C compiler: the install skipped the extension,
        # as it should, and the NumPy kernels run (the rest of the suite checks them).
        pytest.skip("no working C compiler here, so the extension was not built")
    assert k.HAVE_COMPILED


def _c_compiler_works():
    """Whether the C compiler Python's build would use ($CC, else sysconfig's) runs."""
    cc = (os.environ.get("CC") or sysconfig.get_config_var("CC") or "").split()
    exe = shutil.which(cc[0]) if cc else None
    if exe is None:
        return False
    try:
        return subprocess.run([exe, "--version"], capture_output=True, timeout=30).returncode == 0
    except (OSError, subprocess.SubprocessError):
        return False


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("b", [2, 3, 4])
def test_bin_despike_matches_numpy(numpy_only, threads, dtype, b):
    rng = np.random.default_rng(1)
    img = rng.normal(100, 10, (203, 157)).astype(dtype)
    img[5, 7] = np.nan
    img[50, 60] = np.inf
    img[100, 100] = 1e6  # a hot pixel: dropped as its block's maximum
    mask = np.zeros(img.shape, bool)
    mask[20:23, 30:33] = True
    before = img.copy()
    fast = k.bin_despike(img, b, mask=mask, fill=3.0)
    fast_nomask = k.bin_despike(img, b)
    numpy_only()
    slow = k.bin_despike(img, b, mask=mask, fill=3.0)
    slow_nomask = k.bin_despike(img, b)
    assert fast.shape == (203 // b, 157 // b) and fast.dtype == np.float32
    assert_allclose(fast, slow, rtol=1e-6)
    assert_allclose(fast_nomask, slow_nomask, rtol=1e-6)
    assert fast[100 // b, 100 // b] < 200  # the hot pixel is gone
    assert_array_equal(img, before)  # the input is not touched


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("b", [2, 5, 26])
def test_bin_despike_mask_is_fill(threads, dtype, b):
    # A masked pixel counts exactly as a pixel holding ``fill`` (the compiled
    # loop tests a block row's mask bytes at once, then pixel by pixel).
    rng = np.random.default_rng(3)
    img = rng.normal(100, 10, (260, 313)).astype(dtype)
    img[rng.random(img.shape) < 0.01] = np.nan
    mask = rng.random(img.shape) < 0.003
    mask[40:45, 7:190] = True
    mask[:, -1] = True  # in the cropped edge only
    filled = np.where(mask, dtype(-7.5), img)
    assert_array_equal(k.bin_despike(img, b, mask=mask, fill=-7.5),
                       k.bin_despike(filled, b, fill=-7.5))


def test_bin_despike_splits_only_large_frames(monkeypatch):
    # A small frame is binned in the calling thread (waking another costs
    # more); split over threads, a frame gives the same values, bit for bit.
    if not k.HAVE_COMPILED:
        pytest.skip("the NumPy binning runs in one thread")
    img = np.random.default_rng(4).normal(100, 10, (600, 400)).astype(np.float32)
    monkeypatch.setattr(conf, "num_threads", 2)
    chunks = []
    real = k.run_split

    def recorded(fn, n, args, min_per_thread=1, **kw):
        out = real(fn, n, args, min_per_thread=min_per_thread, **kw)
        chunks.append(len(out))
        return out

    monkeypatch.setattr(k, "run_split", recorded)
    alone = k.bin_despike(img, 2)
    monkeypatch.setattr(k, "_BIN_PIXELS_PER_THREAD", 1)
    split = k.bin_despike(img, 2)
    assert chunks == [1, 2]
    assert_array_equal(alone, split)


def test_bin_despike_read_only_and_strided_input():
    img = np.arange(64 * 64, dtype=np.float64).reshape(64, 64)
    view = img[::2, ::2]  # not contiguous
    view.flags.writeable = False
    out = k.bin_despike(view, 2)
    # Each 2x2 block of the view holds v, v+2, v+128, v+130: the mean of the
    # three smallest is v + 130/3.
    v = view[::2, ::2][:16, :16]
    assert_allclose(out, v + 130.0 / 3.0, rtol=1e-6)


def test_peak_candidates_match_numpy(numpy_only):
    rng = np.random.default_rng(2)
    img = rng.normal(0, 1, (120, 90)).astype(np.float32)
    img[40, 40] = img[40, 41] = 50.0  # a tie: the first in raster order wins
    fast = k.peak_candidates(img, 2.0, 10_000, border=2)
    numpy_only()
    slow = k.peak_candidates(img, 2.0, 10_000, border=2)
    assert len(fast[0]) > 10
    assert_array_equal(fast[0], slow[0])
    assert_array_equal(fast[1], slow[1])
    assert_allclose(fast[2], slow[2], rtol=1e-6)
    # Brightest first; the tie keeps only (40, 40).
    assert (fast[0][0], fast[1][0]) == (40, 40)
    assert not np.any((fast[0] == 40) & (fast[1] == 41))
    assert np.all(fast[0] >= 2) and np.all(fast[0] < 118)


def test_count_inliers_matches_kdtree(numpy_only, threads):
    rng = np.random.default_rng(3)
    pts = rng.uniform(0, 1000, (400, 2))
    src = rng.uniform(0, 1000, (300, 2))
    # Hypotheses: random similarity transforms, plus the truth for half of src.
    mats = np.tile(np.eye(3), (500, 1, 1))
    ang = rng.uniform(0, 2 * np.pi, 500)
    mats[:, 0, 0] = mats[:, 1, 1] = np.cos(ang)
    mats[:, 0, 1] = -np.sin(ang)
    mats[:, 1, 0] = np.sin(ang)
    mats[:, :2, 2] = rng.uniform(-50, 50, (500, 2))
    src[:150] = pts[:150] + rng.normal(0, 0.5, (150, 2))
    mats[0] = np.eye(3)
    grid = k.PointGrid(pts, 3.0)
    fast = k.count_inliers(mats, src, grid)
    numpy_only()
    slow = k.count_inliers(mats, src, grid)
    assert_array_equal(fast, slow)
    assert fast[0] >= 150  # the identity finds the 150 planted matches


def test_count_inliers_ignores_nan_and_far_points():
    grid = k.PointGrid(np.array([[0.0, 0.0], [10.0, 10.0]]), 1.0)
    src = np.array([[0.2, 0.1], [np.nan, 0.0], [1e12, -1e12], [10.5, 9.5]])
    assert_array_equal(k.count_inliers(np.eye(3)[None], src, grid), [2])


def test_two_nearest_matches_kdtree(numpy_only, threads):
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(5)
    pts = rng.uniform(0, 500, (3000, 2))
    pts[:20] = pts[20:40] + rng.normal(0, 0.2, (20, 2))  # close pairs: two candidates
    grid = k.PointGrid(pts, 2.5, max_cells=1500)
    query = np.vstack([rng.uniform(-20, 520, (200_000, 2)),  # (threads split the work)
                       pts[:100] + rng.normal(0, 0.3, (100, 2))])
    assert k.HAVE_COMPILED == (getattr(k._ckernels, "two_nearest_range", None) is not None)
    d, j = k.two_nearest(query, grid, workers=-1)
    dk, jk = cKDTree(grid.points).query(query, k=2, distance_upper_bound=2.5)
    assert_array_equal(j, jk)
    assert_allclose(d, dk, rtol=1e-12)
    assert np.isfinite(d[:, 1]).sum() > 100  # second neighbours were found
    numpy_only()
    ds, js = k.two_nearest(query, grid)
    assert_array_equal(js, jk)
    assert_allclose(ds, dk, rtol=1e-12)


def test_two_nearest_far_nan_and_crowded_queries():
    grid = k.PointGrid(np.array([[0.0, 0.0], [10.0, 10.0], [10.5, 10.0]]), 1.0)
    query = np.array([[0.2, 0.1], [np.nan, 0.0], [1e12, -1e12], [10.1, 10.0], [-np.inf, 5.0]])
    d, j = k.two_nearest(query, grid)
    assert_array_equal(j, [[0, 3], [3, 3], [3, 3], [1, 2], [3, 3]])
    assert_allclose(d[0], [np.hypot(0.2, 0.1), np.inf])
    assert_allclose(d[3], [0.1, 0.4])
    assert np.all(np.isinf(d[[1, 2, 4]]))
    # A dense cluster in a wide field: looked up through a k-d tree, the same answer.
    rng = np.random.default_rng(6)
    pts = np.vstack([rng.normal(500, 1, (2000, 2)), rng.uniform(0, 1000, (100, 2))])
    crowded = k.PointGrid(pts, 0.5, max_cells=4 * len(pts))
    assert k._crowded(crowded)
    from scipy.spatial import cKDTree
    query = pts + rng.normal(0, 0.05, pts.shape)
    d, j = k.two_nearest(query, crowded)
    dk, jk = cKDTree(crowded.points).query(query, k=2, distance_upper_bound=0.5)
    assert_array_equal(j, jk)


def test_threads_work_after_fork():
    # A forked worker (multiprocessing, dask's nanny) must not wait on its
    # parent's thread pool, which does not exist in the child.
    import multiprocessing as mp

    from astroalign_nd.resample import resample

    img = np.random.default_rng(4).normal(size=(400, 400))
    resample(img, np.eye(3), img.shape)  # the parent's pool now exists
    ctx = mp.get_context("fork")
    with ctx.Pool(1) as pool:
        res = pool.apply_async(_resample_in_child, (img,))
        out = res.get(timeout=60)
    assert_array_equal(out, resample(img, np.eye(3), img.shape)[0])


def _resample_in_child(img):
    from astroalign_nd.resample import resample

    return resample(img, np.eye(3), img.shape)[0]


@pytest.mark.parametrize("shape, axis", [((49, 1849), 1), ((150, 300), 1), ((300, 150), 0),
                                         ((5000,), 0), ((5001,), None), ((7, 7, 48), 2),
                                         ((50001,), None), ((50000,), 0)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_fast_median_is_numpy_median(shape, axis, dtype):
    from astroalign_nd._kernels import median as _median

    x = np.random.default_rng(7).normal(size=shape).astype(dtype)
    x.flat[::17] = 3.0  # ties
    before = x.copy()
    expected = np.median(x, axis=axis)
    got = _median(x, axis=axis)
    assert np.asarray(got).dtype == np.asarray(expected).dtype
    assert_array_equal(got, expected)
    assert_array_equal(x, before)


@pytest.mark.parametrize("case", ["clustered", "ties", "two_levels", "tiny_spread"])
def test_fast_median_bracket_edge_cases(case):
    # Samples long enough for the bracketed selection, with values that
    # defeat a subsample's bracket: the result must still be numpy's.
    from astroalign_nd._kernels import median as _median

    rng = np.random.default_rng(3)
    n = 20_001 if case == "ties" else 20_000
    if case == "clustered":  # half the values equal, the rest far on both sides
        x = np.concatenate([np.full(n // 2, 5.0), rng.normal(0, 100, n // 2)])
        rng.shuffle(x)
    elif case == "ties":
        x = rng.integers(0, 3, n).astype(float)
    elif case == "two_levels":  # the middle pair straddles a gap
        x = np.concatenate([np.zeros(n // 2), np.ones(n // 2)])[rng.permutation(n)]
    else:
        x = 1.0 + rng.normal(0, 1e-7, n)
    for a in (x, x[::-1], np.sort(x), x.astype(np.float32)):
        got = _median(a)
        assert np.asarray(got).dtype == a.dtype
        assert_array_equal(got, np.median(a))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_finite_sample_compiled_matches_numpy(dtype):
    # The fill value's sample of a masked or NaN frame: the finite, unmasked
    # pixels of data[::step, ::step], in order, from the compiled loop and
    # from NumPy, on contiguous and strided arrays.
    import astroalign_nd
    from astroalign_nd._kernels import finite_sample as _finite_sample

    rng = np.random.default_rng(5)
    d = rng.normal(size=(61, 47)).astype(dtype)
    d.flat[rng.integers(0, d.size, 40)] = np.nan
    d.flat[rng.integers(0, d.size, 5)] = np.inf
    m = rng.random(d.shape) < 0.05
    for arr, mask in ((d, None), (d, m), (d[:, ::-1], m[:, ::-1]), (d.T, m.T)):
        for step in (1, 3, 4):
            got = _finite_sample(arr, mask, step)
            with astroalign_nd.conf.set_temp("use_compiled", False):
                ref = _finite_sample(arr, mask, step)
            assert got.dtype == arr.dtype
            assert_array_equal(got, ref)
            assert np.isfinite(got).all()
            if mask is not None:
                assert got.size <= np.count_nonzero(~mask[::step, ::step])


@pytest.mark.parametrize("n", [1, 2, 7, 1000, 20_000, 20_001])
@pytest.mark.parametrize("compiled", [True, False])
def test_median_nan_and_small_samples_as_numpy(n, compiled):
    # The one median of detection and matching: numpy's value for short and
    # long 1-D samples, a NaN anywhere making it NaN, as np.median does.
    import astroalign_nd
    from astroalign_nd._kernels import median

    x = np.random.default_rng(n).normal(size=n)
    with astroalign_nd.conf.set_temp("use_compiled", compiled):
        for a in (x, x.astype(np.float32)):
            got = median(a)
            assert np.asarray(got).dtype == a.dtype
            assert_array_equal(got, np.median(a))
            b = a.copy()
            b[n // 3] = np.nan
            assert np.isnan(median(b)) and np.isnan(np.median(b))
            assert_array_equal(a, x.astype(a.dtype))  # input untouched


# -- one switch for the compiled code ------------------------------------------------------

def test_one_compiled_switch(monkeypatch):
    assert not hasattr(rs.core, "_USE_COMPILED")
    img = np.random.default_rng(1).normal(size=(40, 40))
    m = SimilarityTransform(scale=1.1, rotation=20.0, translation_x=3.0).matrix
    fast = rs.resample(img, m, (40, 40), order="bicubic", variance=np.abs(img))
    used = []
    numpy_path = rs.core._resample_numpy
    monkeypatch.setattr(rs.core, "_resample_numpy", lambda *a, **k: used.append(1)
                        or numpy_path(*a, **k))
    with conf.set_temp("use_compiled", False):
        assert k.compiled_kernels() is None
        slow = rs.resample(img, m, (40, 40), order="bicubic", variance=np.abs(img))
    assert used and all(np.array_equal(a, b, equal_nan=True) for a, b in zip(fast, slow))
    assert k.compiled_kernels() is (k._ckernels if k.HAVE_COMPILED else None)


def test_missing_compiled_loops_warn_once_with_cost_and_wheel(monkeypatch):
    # As after an install without a C compiler: the NumPy loops run, and the
    # first registration says so, with what it costs and how to get a wheel.
    import warnings

    from astroalign_nd import register
    from astroalign_nd.exceptions import SlowKernelsWarning
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((160, 160), n_stars=60, rotation=20.0, translation=(5.0, -3.0),
                         seed=4)
    compiled = register(pair.source, pair.target) if k.HAVE_COMPILED else None
    monkeypatch.setattr(k, "HAVE_COMPILED", False)
    monkeypatch.setattr(k, "_WARNED_SLOW", False)
    assert k.compiled_kernels() is None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(3):
            out = register(pair.source, pair.target)
    slow = [w for w in caught if issubclass(w.category, SlowKernelsWarning)]
    assert len(slow) == 1
    text = str(slow[0].message)
    assert "pip install --only-binary astroalign_nd astroalign_nd" in text
    assert "times as long" in text and "1024x1024" in text and "4096x4096" in text
    assert out.data.shape == pair.target.shape
    if compiled is not None:  # the same registration, to the bit
        assert_array_equal(out.data, compiled.data)
        assert_array_equal(out.mask, compiled.mask)


@pytest.mark.parametrize("n_iter", [1, 3, 10])
def test_mirrored_windowed_centroid_matches_numpy_and_finds_edge_stars(numpy_only, n_iter):
    # Gaussian stars cut by a tile's edge (a column band of bad pixels): the
    # centroid from the mirrored star is at the true centre, and the compiled
    # step and the NumPy one give the same positions (to rounding: their sums
    # run in another order), stars that stop early and those that go on alike.
    rng = np.random.default_rng(n_iter)
    n, size = 12, 21
    yy, xx = np.mgrid[:size, :size]
    cx, cy = rng.uniform(4, 8, n), rng.uniform(8, 12, n)
    sigma = rng.uniform(1.2, 2.0, n)
    cut = 1e4 * np.exp(-0.5 * ((xx - cx[:, None, None]) ** 2 + (yy - cy[:, None, None]) ** 2)
                       / sigma[:, None, None] ** 2)
    bad = np.zeros(cut.shape, bool)
    bad[:, :, :3] = True  # beyond the frame's edge
    bad[:3, 15, 15] = True  # and a masked pixel far from the star
    x0, y0 = cx + rng.uniform(-0.7, 0.7, n), cy + rng.uniform(-0.7, 0.7, n)
    fast = k.mirrored_windowed_centroid(cut, bad, x0, y0, sigma, n_iter=n_iter)
    numpy_only()
    slow = k.mirrored_windowed_centroid(cut, bad, x0, y0, sigma, n_iter=n_iter)
    assert_allclose(fast[0], slow[0], rtol=0, atol=1e-12)
    assert_allclose(fast[1], slow[1], rtol=0, atol=1e-12)
    if n_iter == 10:
        assert_allclose(fast[0], cx, atol=0.02)
        assert_allclose(fast[1], cy, atol=0.02)


@pytest.mark.skipif(not k.HAVE_COMPILED, reason="the compiled extension is not built")
@pytest.mark.parametrize("size", [1, 2, 5, 13, 21, 32])
def test_mirrored_windowed_centroid_compiled_is_numpy_to_the_bit(size):
    # The compiled loop runs the NumPy version's operations in the same order
    # (with its compiled windowed step): the same floats, on noisy stars near
    # and beyond the cutouts' edges, cut by edge bands and masked pixels,
    # float32 and float64 cutouts, a NaN pixel, and stars still moving when
    # the steps run out.
    rng = np.random.default_rng(size)
    n = 40
    yy, xx = np.mgrid[:size, :size]
    cx, cy = rng.uniform(-1, size, n), rng.uniform(-1, size, n)
    sigma = rng.uniform(0.8, 3.0, n)
    cut = 1e3 * np.exp(-0.5 * ((xx - cx[:, None, None]) ** 2 + (yy - cy[:, None, None]) ** 2)
                       / sigma[:, None, None] ** 2) + rng.normal(0, 5, (n, size, size))
    bad = rng.random(cut.shape) < 0.05
    e = size // 3
    bad[: n // 3, :, :e] = True  # left edge
    bad[n // 3: 2 * n // 3, size - e:, :] = True  # top edge
    bad[-1] = False  # none bad: plain windowed steps
    cut[-2, 0, 0] = np.nan
    x0, y0 = cx + rng.normal(0, 0.7, n), cy + rng.normal(0, 0.7, n)
    orig = cut.copy(), bad.copy(), x0.copy(), y0.copy()
    last = None
    for dtype in (np.float64, np.float32):
        c = cut.astype(dtype)
        for n_iter in (1, 2, 10):
            got = k.mirrored_windowed_centroid(c, bad, x0, y0, sigma, n_iter=n_iter)
            ref = k._mirrored_windowed_centroid_numpy(c, bad, x0.copy(), y0.copy(), sigma,
                                                      n_iter, True)
            assert_array_equal(got[0], ref[0])
            assert_array_equal(got[1], ref[1])
            assert np.isfinite(got[0][:-2]).all() and np.isfinite(got[1][:-2]).all()
            if n_iter == 2:
                last = got
        if size > 2:  # some stars had not converged after 2 steps
            assert np.any(np.abs(last[0] - got[0]) > 1e-3)
    for a, b in zip(orig, (cut, bad, x0, y0)):
        assert_array_equal(a, b)  # inputs untouched


@pytest.mark.skipif(not k.HAVE_COMPILED, reason="the compiled extension is not built")
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_extract_cutouts_compiled_is_numpy_to_the_bit(dtype):
    # Cutouts of a frame with NaN, infinite and masked pixels, centred in,
    # at and beyond its edges, from a contiguous frame and a reversed view:
    # the same values and bad pixels with and without the compiled loop.
    from astroalign_nd.detection.candidates import _extract_cutouts

    rng = np.random.default_rng(7)
    frame = rng.normal(100.0, 10.0, (61, 47)).astype(dtype)
    frame[rng.random(frame.shape) < 0.02] = np.nan
    frame[rng.random(frame.shape) < 0.01] = np.inf
    mask = rng.random(frame.shape) < 0.05
    orig = frame.copy(), mask.copy()
    xc = np.concatenate([rng.integers(-4, 51, 40), [0, 46, -3, 50]])
    yc = np.concatenate([rng.integers(-4, 65, 40), [0, 60, 64, -4]])
    for data, m in ((frame, None), (frame, mask), (frame[::-1], mask[:, ::-1])):
        for half in (1, 6, 14):
            fast = _extract_cutouts(data, m, xc, yc, half, 0.0)
            with conf.set_temp("use_compiled", False):
                ref = _extract_cutouts(data, m, xc, yc, half, 0.0)
            assert_array_equal(fast[1], ref[1])
            assert_array_equal(fast[0].view(np.int64), ref[0].view(np.int64))
            assert fast[1].any() and not fast[1].all()
    assert_array_equal(frame, orig[0])
    assert_array_equal(mask, orig[1])
