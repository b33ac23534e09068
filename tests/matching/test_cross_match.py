# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""cross_match: every star of two catalogs paired, checked against the simulation's truth."""

import numpy as np
import pytest
from astropy.table import Table

from astroalign_nd import cross_match, TooFewSourcesError, TransformNotFoundError
from astroalign_nd.crossmatch import CrossMatch, read_catalog
from astroalign_nd.matching.allpairs import pair_all, pairing_radius
from astroalign_nd.matching.pairing import resolve_claims
from astroalign_nd.simulate import simulate_catalogs, simulate_pair
from astroalign_nd.transforms import PolynomialTransform, SimilarityTransform

N_STARS = 4000


@pytest.fixture(scope="module")
def cats():
    return simulate_catalogs(N_STARS, rotation=133.0, scale=1.13, seed=7)


def _truth_counts(out, src_ids, dst_ids):
    """(true pairs returned, false pairs returned) of a result, by the simulated ids."""
    a = np.asarray(src_ids)[out.table["source_index"]]
    b = np.asarray(dst_ids)[out.table["target_index"]]
    true = (a == b) & (a >= 0)
    return int(true.sum()), int((~true).sum())


def _grid_error(model, truth, shape=(4096, 4096)):
    """Largest distance (px) between two transforms over a grid on the source frame."""
    gy, gx = np.mgrid[0:shape[0]:33j, 0:shape[1]:33j]
    a = np.column_stack(model(gx.ravel(), gy.ravel()))
    b = np.column_stack(truth(gx.ravel(), gy.ravel()))
    return float(np.hypot(*(a - b).T).max())


def test_pairs_and_transform_against_truth(cats):
    out = cross_match(cats.source, cats.target)
    assert isinstance(out, CrossMatch) and out.converged
    n_true, n_false = _truth_counts(out, cats.source["id"], cats.target["id"])
    assert n_true >= 0.99 * cats.n_true_pairs
    assert n_false <= 0.005 * len(out.table)
    assert _grid_error(out.transform, cats.transform) < 0.02
    assert isinstance(out.transform, SimilarityTransform)
    # A transform 100 times better than the search's own, which saw 400 stars only.
    assert out.match.n_matches < len(out.table) / 5
    assert out.transform.meta["quality"]["n_matches"] == len(out.table)
    # The residual scatter is the simulated noise of both catalogs.
    expected = 0.1 * np.sqrt(1.0 + 1.13 ** 2)
    assert abs(out.sigma - expected) < 0.1 * expected
    t = out.table
    assert np.allclose(np.hypot(t["dx"], t["dy"]), t["residual"])
    assert np.all(t["residual"] <= out.radius)
    assert np.all((t["p_chance"] >= 0) & (t["p_chance"] < 0.05))


def test_unmatched_rows_partition_the_inputs(cats):
    out = cross_match(cats.source, cats.target)
    src = np.concatenate([out.table["source_index"], out.source_unmatched])
    dst = np.concatenate([out.table["target_index"], out.target_unmatched])
    assert np.array_equal(np.sort(src), np.arange(len(cats.source)))
    assert np.array_equal(np.sort(dst), np.arange(len(cats.target)))
    # Each target used once.
    assert len(np.unique(out.table["target_index"])) == len(out.table)


def _photutils_table(cat, x, y, order, drop=()):
    t = Table({"id": np.arange(1, len(cat) + 1), x: cat["x"][order], y: cat["y"][order],
               "flux": cat["flux"][order]}, masked=bool(drop))
    for row in drop:
        t[x].mask[row] = True
    return t


@pytest.mark.parametrize("names", [("x_centroid", "y_centroid"), ("xcentroid", "ycentroid")])
def test_photutils_tables_in_rows_of_the_input(cats, names):
    rng = np.random.default_rng(3)
    o_src, o_dst = rng.permutation(len(cats.source)), rng.permutation(len(cats.target))
    src = _photutils_table(cats.source, *names, o_src, drop=(5, 17))
    dst = _photutils_table(cats.target, *names, o_dst)
    before = src.copy(), dst.copy()
    out = cross_match(src, dst)  # shuffled rows: the flux column picks the brightest
    n_true, n_false = _truth_counts(out, cats.source["id"][o_src], cats.target["id"][o_dst])
    assert n_true >= 0.99 * cats.n_true_pairs - 2 and n_false <= 0.005 * len(out.table)
    assert {5, 17} <= set(out.source_unmatched)
    # The positions in the table are those of the rows it names.
    assert np.array_equal(out.table["x_source"], src[names[0]][out.table["source_index"]])
    assert np.array_equal(out.table["y_target"], dst[names[1]][out.table["target_index"]])
    for table, copy in zip((src, dst), before):  # the caller's tables are untouched
        assert table.colnames == copy.colnames and all(
            np.array_equal(table[c], copy[c]) for c in table.colnames)
        assert np.array_equal(np.ma.getmaskarray(table[names[0]]),
                              np.ma.getmaskarray(copy[names[0]]))


def test_columns_named_by_the_user_and_arrays(cats):
    src = Table({"RA_PIX": cats.source["x"], "DEC_PIX": cats.source["y"]})
    dst = np.column_stack([cats.target["x"], cats.target["y"]])  # brightest first
    out = cross_match(src, dst, source_columns=("RA_PIX", "DEC_PIX"))
    n_true, _ = _truth_counts(out, cats.source["id"], cats.target["id"])
    assert n_true >= 0.99 * cats.n_true_pairs


def test_given_transform_skips_the_search(cats):
    truth = cats.transform
    start = SimilarityTransform(scale=truth.scale.value * 1.0002,
                                rotation=truth.rotation.value + 0.01,
                                translation_x=truth.translation_x.value + 0.4,
                                translation_y=truth.translation_y.value - 0.3)
    out = cross_match(cats.source, cats.target, transform=start)
    assert out.match is None
    n_true, n_false = _truth_counts(out, cats.source["id"], cats.target["id"])
    assert n_true >= 0.99 * cats.n_true_pairs and n_false <= 0.005 * len(out.table)
    assert _grid_error(out.transform, truth) < 0.02
    # A matrix works as well; too far a start pairs nothing and says so.
    out_m = cross_match(cats.source, cats.target, transform=start.matrix, transform_type="affine")
    assert _grid_error(out_m.transform, truth) < 0.03
    wrong = SimilarityTransform(rotation=truth.rotation.value + 20.0)
    with pytest.raises((TransformNotFoundError, TooFewSourcesError), match="pairs within"):
        cross_match(cats.source, cats.target, transform=wrong)


def test_deterministic(cats):
    a = cross_match(cats.source, cats.target)
    b = cross_match(cats.source, cats.target)
    assert all(np.array_equal(a.table[c], b.table[c]) for c in a.table.colnames)
    assert np.array_equal(a.transform.parameters, b.transform.parameters)


def test_polynomial_auto_degree_on_all_pairs():
    cats = simulate_catalogs(3000, rotation=20.0, scale=1.0, seed=11)
    dist = PolynomialTransform(degree=3, crpix=(2048.0, 2048.0), A_3_0=-4e-10, B_0_3=-4e-10,
                               A_1_2=-4e-10, B_2_1=-4e-10)  # ~5 px at the corners
    x, y = dist(cats.target["x"] - 0.0, cats.target["y"])
    target = cats.target.copy()
    target["x"], target["y"] = x, y
    truth = cats.transform | dist
    out = cross_match(cats.source, target, transform_type="polynomial", degree="auto")
    assert isinstance(out.transform, PolynomialTransform)
    assert out.transform.meta["quality"]["degree"] == 3
    n_true, n_false = _truth_counts(out, cats.source["id"], target["id"])
    assert n_true >= 0.99 * cats.n_true_pairs and n_false <= 0.005 * len(out.table)
    assert _grid_error(out.transform, truth) < 0.05


def test_image_against_catalog():
    pair = simulate_pair((512, 512), n_stars=250, rotation=40.0, seed=4)
    out = cross_match(pair.source, pair.target_stars)
    assert out.source_catalog is not None and out.target_catalog is None
    # Detected stars paired with the target's true positions (by nearest true source star).
    det = np.column_stack([out.source_catalog["x"], out.source_catalog["y"]])
    truth = np.column_stack([pair.source_stars["x"], pair.source_stars["y"]])
    near = np.argmin(np.hypot(*(det[:, None, :] - truth[None]).transpose(2, 0, 1)), axis=1)
    ids = np.asarray(pair.source_stars["id"])[near][out.table["source_index"]]
    assert np.mean(ids == pair.target_stars["id"][out.table["target_index"]]) > 0.99
    assert len(out.table) >= 0.7 * len(out.source_catalog)
    assert _grid_error(out.transform, pair.transform, (512, 512)) < 0.15


def test_bad_inputs(cats):
    good = cats.target
    with pytest.raises(TypeError, match="None"):
        cross_match(None, good)
    with pytest.raises(ValueError, match="no column"):
        cross_match(cats.source, good, source_columns=("u", "v"))
    with pytest.raises(TypeError, match="two column names"):
        cross_match(cats.source, good, source_columns="x")
    with pytest.raises(ValueError, match="position columns"):
        cross_match(Table({"a": [1.0, 2.0, 3.0]}), good)
    with pytest.raises(ValueError, match="flux column"):
        cross_match(cats.source, good, flux="mag")
    with pytest.raises(TypeError, match="flux must be"):
        cross_match(cats.source, good, flux=3)
    with pytest.raises(ValueError, match="max_radius"):
        cross_match(cats.source, good, max_radius=-1.0)
    with pytest.raises(TypeError, match="radius"):
        cross_match(cats.source, good, radius="1")
    with pytest.raises(ValueError, match="max_iterations"):
        cross_match(cats.source, good, max_iterations=0)
    with pytest.raises(TypeError, match="transform must be"):
        cross_match(cats.source, good, transform="identity")
    with pytest.raises(ValueError, match="3x3"):
        cross_match(cats.source, good, transform=np.eye(4))
    with pytest.raises(ValueError, match="at least 3"):
        cross_match(np.array([[1.0, 2.0], [np.nan, 1.0]]), good)
    with pytest.raises(TypeError, match="unexpected keyword"):
        cross_match(cats.source, good, max_control_points=50)
    with pytest.raises(TypeError, match="names the columns of a Table"):
        cross_match(np.zeros((10, 2)), good, source_columns=("x", "y"))
    with pytest.raises(TypeError, match="must hold numbers"):
        cross_match(np.array([["a", "b"]] * 5), good)
    rng = np.random.default_rng(0)
    with pytest.raises(TransformNotFoundError):
        cross_match(rng.uniform(0, 4096, (300, 2)), rng.uniform(0, 4096, (300, 2)))


def test_read_catalog_formats(tmp_path, cats):
    t = cats.source[:50]
    t.write(tmp_path / "a.ecsv")
    t.write(tmp_path / "a.fits")
    np.savetxt(tmp_path / "a.txt", np.column_stack([t["x"], t["y"], t["flux"]]))
    t.write(tmp_path / "b.txt", format="ascii.basic")
    for name in ("a.ecsv", "a.fits", "b.txt"):
        back = read_catalog(tmp_path / name)
        assert np.allclose(back["x"], t["x"]) and np.allclose(back["flux"], t["flux"])
    assert np.allclose(read_catalog(tmp_path / "a.txt")["col2"], t["y"])
    with pytest.raises(ValueError, match="not found"):
        read_catalog(tmp_path / "missing.ecsv")
    (tmp_path / "bad.ecsv").write_text("not a table\n1 2 3 4\n")
    with pytest.raises(ValueError, match="could not read"):
        read_catalog(tmp_path / "bad.ecsv")


def test_catalog_paths_in_the_api(tmp_path, cats):
    cats.source.write(tmp_path / "s.ecsv")
    cats.target.write(tmp_path / "t.fits")
    out = cross_match(tmp_path / "s.ecsv", str(tmp_path / "t.fits"))
    n_true, _ = _truth_counts(out, cats.source["id"], cats.target["id"])
    assert n_true >= 0.99 * cats.n_true_pairs


def test_resolve_claims_and_radius():
    si, dj = resolve_claims(np.array([0, 1, 2, 3]), np.array([4, 4, 9, 4]),
                            np.array([0.5, 0.2, 0.1, 0.2]))
    assert si.tolist() == [1, 2] and dj.tolist() == [4, 9]  # tie at 0.2: lowest index
    # The radius stays within 3 and 5 sigmas, and shrinks as the field crowds.
    sparse = pairing_radius(0.1, 1e-6, 1000, 100)
    crowded = pairing_radius(0.1, 1.0, 1000, 1000)
    assert sparse == pytest.approx(0.5) and crowded == pytest.approx(0.3)


def test_pair_all_requeries_moved_predictions():
    # Targets on a lattice 1 px apart: a start 0.45 px off pairs every source with the
    # wrong neighbour first; the refits must follow, querying the moved sources again.
    g = np.arange(0, 60, 1.0)
    src = np.column_stack([a.ravel() for a in np.meshgrid(g, g)]) * 3.0
    truth = SimilarityTransform(scale=1.0, rotation=0.0, translation_x=0.3)
    dst = np.column_stack(truth(*src.T))
    out = pair_all(src, dst, SimilarityTransform(translation_x=0.0), tolerance=2.0)
    assert len(out.source_index) == len(src)
    assert np.array_equal(out.source_index, out.target_index)
    assert np.allclose(out.transform.translation_x.value, 0.3)


def test_cli_match_writes_the_pairs_safely(tmp_path, cats, capsys):
    from astroalign_nd.cli.main import main

    src, dst, out = tmp_path / "src.ecsv", tmp_path / "dst.txt", tmp_path / "pairs.fits"
    cats.source.write(src)
    np.savetxt(dst, np.column_stack([cats.target["x"], cats.target["y"], cats.target["flux"]]))
    args = [str(src), str(dst), "-o", str(out), "--target-columns", "col1,col2",
            "--flux", "flux,col3"]
    assert main(["match", *args]) == 0
    pairs = Table.read(out)
    ids = cats.source["id"][pairs["source_index"]] == cats.target["id"][pairs["target_index"]]
    assert ids.sum() >= 0.99 * cats.n_true_pairs
    assert "pairs of" in capsys.readouterr().out
    before = out.read_bytes()
    assert main(["match", *args]) == 2  # no overwrite without --overwrite
    assert "--overwrite" in capsys.readouterr().err and out.read_bytes() == before
    assert main(["match", *args, "--overwrite"]) == 0
    src_bytes = src.read_bytes()
    assert main(["match", str(src), str(dst), "-o", str(src), "--overwrite",
                 "--target-columns", "col1,col2"]) == 2  # an input is never an output
    assert "destroy" in capsys.readouterr().err and src.read_bytes() == src_bytes
    assert main(["match", str(src), str(dst), "-o", str(tmp_path / "p.png")]) == 2
    assert main(["match", str(src), str(dst), "-o", str(tmp_path / "p.ecsv"),
                 "--target-columns", "col1"]) == 2
    assert "two column names" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["translation", "euclidean", "affine"])
def test_every_linear_type_refitted_as_itself(kind):
    truth = SimilarityTransform(scale=1.0, rotation=0.0 if kind == "translation" else 25.0,
                                translation_x=40.0, translation_y=-15.0)
    rng = np.random.default_rng(2)
    src = rng.uniform(0, 2048, (2000, 2))
    dst = np.column_stack(truth(*src.T)) + rng.normal(0, 0.1, src.shape)
    start = SimilarityTransform(scale=1.0, rotation=truth.rotation.value + 0.01,
                                translation_x=40.5, translation_y=-15.3)
    out = cross_match(src, dst, transform=start, transform_type=kind)
    assert type(out.transform).__name__.lower().startswith(kind)
    assert len(out.table) >= 0.995 * len(src)  # (the radius's Rayleigh tail is lost)
    # (Two of these stars lie 0.15 px apart: the noise may swap them.)
    assert np.sum(out.table["source_index"] != out.table["target_index"]) <= 2
    assert _grid_error(out.transform, truth, (2048, 2048)) < 0.02
