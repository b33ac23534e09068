# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""solve_sequence and register_batch(solve='global') (issue 28): against known truth."""

import os

import numpy as np
import pytest
from astropy.nddata import CCDData

import astroalign_nd
from astroalign_nd import find_transform, register_batch, solve_sequence
from astroalign_nd.sequence import Link, solve
from astroalign_nd.cli import main
from astroalign_nd.simulate import (dither_transforms, mosaic_transforms, simulate_pair,
                                    simulate_views)
from astroalign_nd.transforms import as_matrix, fit_transform


def _max_error(t, truth, shape):
    """Largest distance (px) over the frame's corners between two transforms."""
    ny, nx = shape
    c = np.array([[-0.5, -0.5], [nx - 0.5, -0.5], [-0.5, ny - 0.5], [nx - 0.5, ny - 0.5]])
    a, b = as_matrix(t), as_matrix(truth)
    d = c @ a[:2, :2].T + a[:2, 2] - (c @ b[:2, :2].T + b[:2, 2])
    return float(np.max(np.hypot(d[:, 0], d[:, 1])))


def _truth(transforms, i, ref):
    return np.linalg.inv(as_matrix(transforms[ref])) @ as_matrix(transforms[i])


def _catalogs(transforms, shape, n_stars, noise, seed):
    """Star catalogs (brightest first) of frames seeing one field through ``transforms``."""
    rng = np.random.default_rng(seed)
    ny, nx = shape
    mats = [as_matrix(t) for t in transforms]
    corners = np.vstack([np.array([[0, 0], [nx, 0], [0, ny], [nx, ny]]) @ m[:2, :2].T + m[:2, 2]
                         for m in mats])
    lo, hi = corners.min(axis=0) - 5, corners.max(axis=0) + 5
    n = int(n_stars * np.prod(hi - lo) / (nx * ny))
    sky = rng.uniform(lo, hi, (n, 2))
    flux = rng.pareto(1.5, n)
    sky = sky[np.argsort(-flux)]
    out = []
    for m in mats:
        inv = np.linalg.inv(m)
        p = sky @ inv[:2, :2].T + inv[:2, 2]
        inside = (p[:, 0] > 0) & (p[:, 0] < nx - 1) & (p[:, 1] > 0) & (p[:, 1] < ny - 1)
        out.append(p[inside] + rng.normal(0.0, noise, (int(inside.sum()), 2)))
    return out


def _corrupted_link(real, pair, calls=None):
    """``match_link`` with the link of ``pair`` made false (its stars paired 8 px away)."""
    def corrupt(src, dst, config, a, b):
        if calls is not None:
            calls.append((a, b))
        link = real(src, dst, config, a, b)
        if (a, b) == pair and isinstance(link, Link):
            wrong = link.target_points + [8.0, -3.0]
            t = fit_transform(link.source_points, wrong, "similarity")[0]
            link = Link(a, b, t, link.n_matches, link.rms, link.log10_false_alarm,
                        link.source_points, wrong)
        return link
    return corrupt


def test_mosaic_every_tile_from_a_corner():
    """A 3x3 mosaic, 20% overlaps, reference at a corner: every tile within 0.05 px."""
    shape = (256, 256)
    truth = mosaic_transforms((3, 3), shape, overlap=0.2)
    seq = simulate_views(truth, shape, n_stars=500, flux_range=(5e3, 3e5), seed=3)
    sol = solve_sequence(seq.frames, reference=0, n_stars=400)
    assert sol.unsolved == {} and sol.reference == 0
    errors = [_max_error(sol.transforms[i], seq.truth(i, 0), shape) for i in range(9)]
    assert max(errors) < 0.05, errors
    # Tiles 2, 5, 6, 7 and 8 do not overlap tile 0: solved through their neighbours.
    assert not any({0, j} == {k.source, k.target} for k in sol.links for j in (2, 5, 6, 7, 8))
    table = sol.to_table()
    assert list(table["status"][:2]) == ["reference", "solved"]
    assert np.all(table["predicted_error"][1:] > 0) and np.all(table["n_links"] >= 2)
    assert len(sol.links_table()) == len(sol.links)


def test_mosaic_of_catalogs_chooses_the_best_connected_reference():
    shape = (200, 200)
    truth = mosaic_transforms((3, 3), shape, overlap=0.3)
    cats = _catalogs(truth, shape, 150, 0.05, seed=1)
    sol = solve_sequence(cats, transform_type="euclidean")
    assert sol.reference == 4  # the centre tile overlaps all the others
    for i in range(9):
        assert _max_error(sol.transforms[i], _truth(truth, i, 4), shape) < 0.1
    assert "9 of 9 frames solved onto frame 4" in sol.summary()


def _sequence_errors(cats, truth, shape):
    sol = solve_sequence(cats, reference=0, all_pairs=5)
    glob = [_max_error(sol.transforms[i], _truth(truth, i, 0), shape)
            for i in range(1, len(cats))]
    pair = [_max_error(find_transform(c, cats[0])[0], _truth(truth, i, 0), shape)
            for i, c in enumerate(cats[1:], 1)]
    return sol, glob, pair


def test_dithered_sequence_against_pairwise():
    """
    A dithered sequence of catalogs whose star lists differ (each frame
    keeps a random half of the stars): the joint solution is better than
    pairwise registration to the reference, which uses only the stars the
    reference shares (with the same stars in every frame, both have the
    same precision: the reference's own centroid errors are in both).
    """
    shape = (256, 256)
    glob, pair = [], []
    for seed in range(2):
        truth = dither_transforms(12, max_shift=40, max_rotation=2, shape=shape, seed=seed)
        cats = _catalogs(truth, shape, 200, 0.1, seed=10 + seed)
        rng = np.random.default_rng(seed)
        cats = [c[rng.random(len(c)) < 0.5] for c in cats]
        sol, g, p = _sequence_errors(cats, truth, shape)
        assert sol.unsolved == {} and not sol.rejected
        glob += g
        pair += p
    assert np.median(glob) < 0.85 * np.median(pair), (np.median(glob), np.median(pair))


#: Frames of the long sequence: enough that the shrinking bias (which grows with the number
#: of frames) fails both of the test's assertions by a wide margin.
N_LONG = 100


@pytest.mark.parametrize("kind", ["similarity", "affine"])
def test_long_sequence_is_not_shrunk(kind):
    """
    100 frames that all see the same stars: the joint solution is as
    precise as pairwise registration (the reference's centroid errors are
    in both), however many frames there are.  Residuals fitted in the
    common frame rather than in each frame's own pixels shrank every frame
    but the reference (a bias that grows with the number of frames): 0.009
    px at the corners here (0.018 px with 200 frames), and the errors grew
    to 1.17 times the pairwise ones (1.8 times with 200 frames).
    """
    shape = (256, 256)
    truth = dither_transforms(N_LONG, max_shift=40, max_rotation=2, shape=shape, seed=7)
    rng = np.random.default_rng(8)
    sky = rng.uniform(0, 256, (300, 2))
    cats = []
    for t in truth:
        inv = np.linalg.inv(as_matrix(t))
        cats.append(sky @ inv[:2, :2].T + inv[:2, 2] + rng.normal(0.0, 0.05, sky.shape))
    sol = solve_sequence(cats, reference=0, transform_type=kind)
    # Pairwise registration to the reference matches all 300 stars of these catalogs, so its
    # transform is the least-squares fit on them (to 1e-12 px): checked on a few frames, and
    # fitted directly on the others (99 searches would take most of the test's time).
    ref = astroalign_nd.Reference(cats[0])
    for i in (1, N_LONG // 2, N_LONG - 1):
        pw, (matched, _) = find_transform(cats[i], ref, transform_type=kind)
        assert len(matched) == 300
        np.testing.assert_allclose(as_matrix(pw), as_matrix(fit_transform(cats[i], cats[0],
                                                                          kind)[0]), atol=1e-9)
    glob, pair, shift = [], [], []
    corners = np.array([[0.0, 0.0], [255.0, 0.0], [0.0, 255.0], [255.0, 255.0]])
    for i in range(1, N_LONG):
        true = _truth(truth, i, 0)
        pw = fit_transform(cats[i], cats[0], kind)[0]
        glob.append(_max_error(sol.transforms[i], true, shape))
        pair.append(_max_error(pw, true, shape))
        # Where the frame's corners land, global against pairwise, radially:
        # a shrinking solution puts them all inside the pairwise ones.
        g = corners @ as_matrix(sol.transforms[i])[:2, :2].T + as_matrix(sol.transforms[i])[:2, 2]
        p = corners @ as_matrix(pw)[:2, :2].T + as_matrix(pw)[:2, 2]
        centre = p.mean(axis=0)
        shift.append(np.mean(np.hypot(*(g - centre).T) - np.hypot(*(p - centre).T)))
    assert np.median(glob) < 1.05 * np.median(pair), (np.median(glob), np.median(pair))
    assert abs(np.mean(shift)) < 0.002, np.mean(shift)  # px; the shrinking gave -0.009


def test_false_link_is_rejected_and_reported(monkeypatch):
    shape = (256, 256)
    truth = dither_transforms(8, max_shift=30, shape=shape, seed=4)
    cats = _catalogs(truth, shape, 120, 0.05, seed=5)
    monkeypatch.setattr(solve, "match_link", _corrupted_link(solve.match_link, (2, 5)))
    sol = solve_sequence(cats, reference=0)
    assert [(k.source, k.target) for k in sol.rejected] == [(2, 5)]
    assert sol.rejected[0].misfit > 5 and "disagrees" in sol.rejected[0].reason
    assert "REJECTED link 2->5" in sol.summary()
    for i in range(8):
        assert _max_error(sol.transforms[i], _truth(truth, i, 0), shape) < 0.1


def test_guided_hub_links_and_a_false_chain_link(monkeypatch):
    """
    A sequence past ``all_pairs``: the hub links predicted through a
    neighbour are verified, not searched (one search per chain link and the
    first hub link), and a wrong chain link still fails its guided
    successor, is searched again, rejected and reported.
    """
    shape = (256, 256)
    truth = dither_transforms(10, max_shift=30, shape=shape, seed=6)
    cats = _catalogs(truth, shape, 120, 0.05, seed=7)
    calls = []
    monkeypatch.setattr(solve, "match_link",
                        _corrupted_link(solve.match_link, (4, 5), calls))
    sol = solve_sequence(cats, reference=0, all_pairs=4)
    chain = [(i, i + 1) for i in range(9)]
    # The chain, then the hub links the prediction could not give: 5's
    # (predicted through the false chain link 4 -> 5).
    assert calls[:9] == chain and sorted(calls[9:]) == [(5, 0)], calls
    assert [(k.source, k.target) for k in sol.rejected] == [(4, 5)]
    assert len(sol.links) == 9 + 8 and sol.unsolved == {}
    for i in range(10):
        assert _max_error(sol.transforms[i], _truth(truth, i, 0), shape) < 0.1


def test_unconnected_and_failed_frames_are_reported():
    shape = (200, 200)
    truth = mosaic_transforms((1, 2), shape, overlap=0.4)
    cats = _catalogs(truth, shape, 120, 0.05, seed=2)
    far = cats[0] + [5000.0, 0.0]  # another field: no star in common
    rng = np.random.default_rng(3)
    alone = rng.uniform(0, 200, (60, 2))
    sol = solve_sequence([cats[0], cats[1], alone, far[:2]], reference=0)
    assert sol.transforms[1] is not None
    assert sol.transforms[2] is None and "no trusted link" in sol.unsolved[2]
    assert sol.transforms[3] is None and "TooFewSourcesError" in sol.unsolved[3]
    assert np.isnan(sol.predicted_errors[2])
    assert list(sol.to_table()["status"]) == ["reference", "solved", "unsolved", "unsolved"]


def test_large_set_uses_the_sparse_graph():
    shape = (200, 200)
    truth = dither_transforms(14, max_shift=25, shape=shape, seed=7)
    cats = _catalogs(truth, shape, 100, 0.05, seed=8)
    sol = solve_sequence(cats, reference=3, all_pairs=4, n_hubs=1)
    # The chain and one hub (the reference): 13 + 12 links, not 91.
    assert len(sol.links) <= 25 and sol.unsolved == {}
    for i in range(14):
        assert _max_error(sol.transforms[i], _truth(truth, i, 3), shape) < 0.1


def test_bad_arguments():
    cats = [np.zeros((5, 2))] * 2
    with pytest.raises(ValueError, match="transform_type"):
        solve_sequence(cats, transform_type="polynomial")
    with pytest.raises(ValueError, match="reference"):
        solve_sequence(cats, reference=5)
    with pytest.raises(ValueError, match="reference must be"):
        solve_sequence(cats, reference=np.ones((3, 2)))
    with pytest.raises(ValueError, match="empty"):
        solve_sequence([])
    with pytest.raises(ValueError, match="all_pairs"):
        solve_sequence(cats, all_pairs=1)
    with pytest.raises(ValueError, match="solve"):
        register_batch([np.zeros((8, 8))], np.zeros((8, 8)), solve="joint")


def test_register_batch_global(tmp_path):
    shape = (200, 200)
    truth = mosaic_transforms((2, 2), shape, overlap=0.3)
    seq = simulate_views(truth, shape, n_stars=150, seed=3)
    frames = [f.copy() for f in seq.frames]
    res = register_batch(seq.frames[1:], seq.frames[0], solve="global", canvas="union",
                         output_dir=tmp_path)
    assert [f.status for f in res.frames] == ["registered"] * 3
    assert res.solution is not None and res.solution.reference == 3
    # Tile 3 (diagonal) is registered onto tile 0 with the union canvas' offset.
    t3 = as_matrix(res.frames[2].transform)
    t3[:2, 2] += res.canvas_offset
    assert _max_error(t3, seq.truth(3, 0), shape) < 0.3
    assert res.canvas_shape == (340, 340)
    table = res.to_table()
    assert "n_links" in table.colnames and np.all(table["n_links"] == 2)
    assert "predicted error" in res.summary()
    assert sorted(os.listdir(tmp_path)) == [f"frame{i}_aligned.fits" for i in range(3)]
    assert all(np.array_equal(a, b) for a, b in zip(frames, seq.frames))  # inputs untouched
    again = register_batch(seq.frames[1:], seq.frames[0], solve="global", canvas="union",
                           output_dir=tmp_path, skip_existing=True)
    assert [f.status for f in again.frames] == ["skipped"] * 3
    assert astroalign_nd.solve_sequence is solve_sequence


def test_links_as_dask_tasks():
    distributed = pytest.importorskip("dask.distributed")
    shape = (200, 200)
    truth = dither_transforms(14, max_shift=25, shape=shape, seed=7)
    cats = _catalogs(truth, shape, 100, 0.05, seed=8)
    here = solve_sequence(cats, reference=3, all_pairs=4, n_hubs=1)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as client:
        there = solve_sequence(cats, reference=3, all_pairs=4, n_hubs=1, client=client)
    assert there.attempts == [] and len(there.links) == len(here.links)
    for a, b in zip(here.transforms, there.transforms):
        assert np.allclose(as_matrix(a), as_matrix(b), atol=1e-9)


def test_cli_batch_global(tmp_path, capsys):
    shape = (200, 200)
    seq = simulate_views(mosaic_transforms((1, 3), shape, overlap=0.3), shape, n_stars=150,
                         seed=3)
    paths = []
    for i, f in enumerate(seq.frames):
        paths.append(str(tmp_path / f"t{i}.fits"))
        CCDData(f, unit="adu").write(paths[-1])
    code = main(["batch", *paths[1:], "-r", paths[0], "--output-dir", str(tmp_path / "out"),
                 "--global", "--canvas", "union", "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0 and "global solution: 2 links" in out
    # Tile 2 does not overlap tile 0: registered through tile 1.
    assert "t2.fits: 1 links, predicted error" in out
    assert sorted(os.listdir(tmp_path / "out")) == ["t0_reference.fits", "t1_aligned.fits",
                                                    "t2_aligned.fits"]


def test_frames_from_files_in_workers(tmp_path):
    """Files detected and linked in 2 local processes: their pixels let go, the same solution."""
    from astropy.io import fits

    shape = (160, 160)
    truth = dither_transforms(5, max_shift=15, max_rotation=1, shape=shape, seed=4)
    seq = simulate_views(truth, shape, n_stars=120, seed=5)
    paths = []
    for i, f in enumerate(seq.frames):
        paths.append(str(tmp_path / f"f{i}.fits"))
        fits.writeto(paths[-1], f)
    here = solve_sequence(paths, reference=0)
    there = solve_sequence(paths, reference=0, workers=2)
    assert there.unsolved == {} and len(there.links) == len(here.links)
    for i in range(5):
        assert np.allclose(as_matrix(here.transforms[i]), as_matrix(there.transforms[i]),
                           atol=1e-9)
        assert _max_error(there.transforms[i], seq.truth(i, 0), shape) < 0.1
    with pytest.raises(ValueError, match="workers"):
        solve_sequence(paths, workers=-1)


def test_dense_and_sparse_factors_agree(monkeypatch):
    """The normal matrix factored dense (a fully coupled sequence) or sparse: one solution."""
    from astroalign_nd.sequence import adjust

    shape = (200, 200)
    truth = dither_transforms(8, max_shift=20, shape=shape, seed=2)
    cats = _catalogs(truth, shape, 100, 0.05, seed=3)
    dense = solve_sequence(cats, reference=0)
    monkeypatch.setattr(adjust, "_DENSE_FILL", 2.0)  # never dense
    sparse = solve_sequence(cats, reference=0)
    for i in range(8):
        assert np.allclose(as_matrix(dense.transforms[i]), as_matrix(sparse.transforms[i]),
                           atol=1e-8)
        # Entries that nearly cancel (1e-11 beside a diagonal of 1e-4) differ in their rounding:
        # compared to the covariance's own scale.
        cov = dense.covariances[i]
        assert np.allclose(cov, sparse.covariances[i], rtol=1e-6, atol=1e-8 * np.abs(cov).max())
        assert _max_error(dense.transforms[i], _truth(truth, i, 0), shape) < 0.1


def test_one_frame_is_its_own_reference():
    """A sequence of one frame: the identity, with no error and no link."""
    pair = simulate_pair((128, 128), n_stars=50, seed=1)
    sol = solve_sequence([pair.target])
    assert sol.reference == 0 and not sol.links and not sol.unsolved
    np.testing.assert_allclose(as_matrix(sol.transforms[0]), np.eye(3), atol=0)
    assert sol.predicted_errors[0] == 0
