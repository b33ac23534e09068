# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
A night's work through the command line: --fill-value, the
reference written with the frames, the summary's transform columns, float32
outputs, one table of exit codes, hints in the command line's own option
names, batch --plot DIR, the union canvas's HISTORY, channels-first cubes,
image files flipped bottom-up, and a demo whose help is true.
"""

import os

import numpy as np
import pytest
from astropy.io import fits
from astropy.nddata import CCDData, StdDevUncertainty
from astropy.table import Table

import astroalign_nd
from astroalign_nd import transform_from_header
from astroalign_nd.cli import main
from astroalign_nd.simulate import simulate_pair

from _helpers import count_calls, run_cli

WORKTREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _write(path, data, **header):
    fits.PrimaryHDU(data, header=fits.Header({"BUNIT": "adu", **header})).writeto(path)
    return str(path)


def _corner_error(t, truth, shape):
    ny, nx = shape
    x = np.array([0.0, nx - 1.0, 0.0, nx - 1.0])
    y = np.array([0.0, 0.0, ny - 1.0, ny - 1.0])
    a, b = np.asarray(t(x, y)), np.asarray(truth(x, y))
    return float(np.max(np.hypot(*(a - b))))


@pytest.fixture(scope="module")
def night(tmp_path_factory):
    """A reference and two frames shifted by tens of pixels (int16, as a camera writes)."""
    d = tmp_path_factory.mktemp("night")
    shape = (160, 200)
    # The pair's source is the reference, its target frame 0; frame 1 is frame 0 without
    # its first 10 rows and 25 columns (its pixel (x, y) is frame 0's (x + 25, y + 10)).
    pair = simulate_pair(shape, n_stars=160, rotation=0.6, translation=(22.0, -12.0),
                         seed=21)
    frame0 = np.round(pair.target).astype(np.int16)
    truth0 = pair.transform.inverse
    m1 = astroalign_nd.transforms.as_matrix(truth0) @ np.array(
        [[1.0, 0.0, 25.0], [0.0, 1.0, 10.0], [0.0, 0.0, 1.0]])
    truth1 = astroalign_nd.transforms.from_matrix(m1, "similarity")
    frames = [(_write(d / "f0.fits", frame0), truth0),
              (_write(d / "f1.fits", frame0[10:, 25:]), truth1)]
    ref = _write(d / "ref.fits", np.round(pair.source).astype(np.int16), OBJECT="HAT")
    return ref, frames, shape


# -- --fill-value, the reference written, the summary ---------------------------------------

def test_union_batch_fill_reference_summary_history(night, tmp_path):
    ref, frames, shape = night
    out, summary = tmp_path / "out", tmp_path / "night.ecsv"
    code, stdout, stderr = run_cli("batch", *[f for f, _ in frames], "-r", ref, "--output-dir",
                                   out, "--canvas", "union", "--fill-value", "0", "--summary",
                                   summary, "--no-progress")
    assert code == 0, stderr
    refout = CCDData.read(out / "ref_reference.fits")
    frame0 = CCDData.read(out / "f0_aligned.fits")
    # The reference on the union canvas, by whole pixels, values kept exactly.
    assert refout.shape == frame0.shape and refout.shape[1] > shape[1] + 15
    x0, y0 = refout.meta["AACNVX0"], refout.meta["AACNVY0"]
    raw = fits.getdata(ref).astype(np.float32)
    np.testing.assert_array_equal(refout.data[-y0:-y0 + shape[0], -x0:-x0 + shape[1]], raw)
    assert refout.meta["AAREFFRM"] is True and refout.data.dtype == ">f4"
    assert refout.mask.sum() == refout.size - raw.size
    for ccd in (refout, frame0):  # --fill-value 0: no NaN; the mask still marks no-data
        assert not np.isnan(ccd.data).any() and ccd.mask.any()
        assert np.all(ccd.data[ccd.mask] == 0)
    # The union frames' HISTORY names the reference and the canvas.
    history = " ".join(" ".join(frame0.meta["HISTORY"]).split())
    assert "union canvas of ref.fits" in history and "grid of shape" not in history
    assert "reference ref.fits: written -> " in stdout
    # The summary: the reference first, then each frame's shift/rotation/scale onto the
    # reference against the truth.
    t = Table.read(summary)
    assert list(t["status"]) == ["reference", "registered", "registered"]
    assert {"shift_x", "shift_y", "rotation", "scale", "rms",
            "log10_false_alarm"} <= set(t.colnames)
    assert t["shift_x"][0] == 0 and t["rotation"][0] == 0 and t["scale"][0] == 1
    for row, (_, truth) in zip(t[1:], frames):
        m = astroalign_nd.transforms.as_matrix(truth)
        assert row["shift_x"] == pytest.approx(m[0, 2], abs=0.1)
        assert row["shift_y"] == pytest.approx(m[1, 2], abs=0.1)
        assert row["rotation"] == pytest.approx(np.degrees(np.arctan2(m[1, 0], m[0, 0])),
                                                abs=0.03)  # 0.1 px over the frame
        assert row["scale"] == pytest.approx(1.0, abs=1e-3)
        assert row["rms"] < 0.5 and row["log10_false_alarm"] < -10


def test_reference_mode_writes_the_reference_and_float32(night, tmp_path):
    """int16 in, float32 out (frames and reference); the reference keeps its own mask."""
    ref, frames, shape = night
    d = tmp_path / "in"
    d.mkdir()
    ccd = CCDData(fits.getdata(ref), unit="adu", mask=np.zeros(shape, bool),
                  uncertainty=StdDevUncertainty(np.full(shape, 3.0, np.float32)))
    ccd.mask[10:20, 30:40] = True
    ccd.write(d / "refm.fits")
    out = tmp_path / "out"
    code, stdout, stderr = run_cli("batch", frames[0][0], "-r", d / "refm.fits", "--output-dir",
                                   out, "--no-progress")
    assert code == 0, stderr
    refout = CCDData.read(out / "refm_reference.fits")
    np.testing.assert_array_equal(refout.mask, ccd.mask)
    np.testing.assert_array_equal(refout.data[~ccd.mask], ccd.data[~ccd.mask])
    assert np.isnan(refout.data[ccd.mask]).all()  # the fill value, as in the frames
    np.testing.assert_allclose(refout.uncertainty.array[~ccd.mask], 3.0)  # its own
    assert refout.meta["AAREFFRM"] is True
    frame = CCDData.read(out / "f0_aligned.fits")
    assert frame.data.dtype == ">f4" == refout.data.dtype
    # Again: the reference exists; --skip-existing keeps it, without it the run refuses.
    code, stdout, _ = run_cli("batch", frames[0][0], "-r", d / "refm.fits", "--output-dir", out,
                              "--skip-existing", "--no-progress")
    assert code == 0 and "skipped" in stdout


def test_float32_is_the_default_in_the_api():
    pair = simulate_pair((128, 128), n_stars=60, rotation=3.0, seed=2)
    ints = np.round(pair.source).astype(np.uint16)
    assert astroalign_nd.register(ints, pair.target).data.dtype == np.float32
    src64 = pair.source.astype(np.float64)
    assert astroalign_nd.register(src64, pair.target).data.dtype == np.float64
    t, _ = astroalign_nd.find_transform(pair.source, pair.target)
    out = astroalign_nd.apply_transform(t, np.round(pair.source).astype(np.int16), pair.target)
    assert out.data.dtype == np.float32 and out.uncertainty is None


# -- exit codes and hints --------------------------------------------------------------------

@pytest.fixture(scope="module")
def sparse(tmp_path_factory):
    """Pairs of a sparse field: one that cannot be registered, one that warns."""
    d = tmp_path_factory.mktemp("sparse")
    out = {}
    # (8 stars were refused until the stars cut by an edge were centroided
    # from their mirror images; they now give a match of 5, with a warning.)
    for name, n in (("none", 6), ("warn", 10)):
        p = simulate_pair((256, 256), n_stars=n, rotation=10.0, seed=0,
                          flux_range=(300, 2000))
        out[name] = (_write(d / f"{name}_s.fits", p.source),
                     _write(d / f"{name}_t.fits", p.target))
    return out


def test_exit_codes(night, sparse, tmp_path):
    ref, frames, _ = night
    # 3: refused, with the hint in the command line's words.
    code, _, err = run_cli("register", *sparse["none"], "-o", tmp_path / "x.fits")
    assert code == 3 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "--n-sources" in err and "n_sources" not in err.replace("--n-sources", "")
    assert not (tmp_path / "x.fits").exists()
    # 2: a usage error, an input given as the output among them.
    code, _, err = run_cli("register", frames[0][0], ref, "-o", ref, "--overwrite")
    assert code == 2 and "input" in err
    assert run_cli("register", frames[0][0], ref)[0] == 2  # no -o
    assert run_cli("register", frames[0][0], ref, "-o", tmp_path / "y.fits",
                   "--fill-value", "zero")[0] == 2
    # 1: a batch with a frame that failed (the refused one); the others are written.
    code, out, _ = run_cli("batch", frames[0][0], sparse["none"][0], "-r", ref, "--output-dir",
                           tmp_path / "b", "--no-progress")
    assert code == 1 and "f0.fits: ok" in out and "FAILED" in out


def test_exit_code_table_in_every_help(capsys):
    for command in ([], ["register"], ["batch"], ["demo"]):
        assert main([*command, "--help"]) == 0
        out = capsys.readouterr().out
        table = out[out.index("exit codes:"):]
        for n in ("0", "1", "2", "3", "130", "143"):
            assert f"\n  {n} " in table
        assert "registration refused" in table


def test_hints_and_plot_warn_once(sparse, tmp_path):
    """register --plot reuses the registration: its warning prints once, in CLI words."""
    pytest.importorskip("matplotlib")
    code, out, err = run_cli("register", *sparse["warn"], "-o", tmp_path / "a.fits", "--plot",
                             tmp_path / "a.png")
    assert code == 0, err
    warnings = [line for line in err.splitlines() if "warning:" in line]
    assert len(warnings) == 1 and "(--n-sources, --nsigma)" in warnings[0]
    assert (tmp_path / "a.png").stat().st_size > 0


# -- batch --plot DIR ------------------------------------------------------------------------

def test_batch_plot_dir_draws_without_searching(night, tmp_path, monkeypatch, capsys):
    pytest.importorskip("matplotlib")
    from astroalign_nd import visualization
    from astroalign_nd.batch import frame

    ref, frames, _ = night
    searches = count_calls(monkeypatch, frame, "find_for_apply")

    def no_search(*args, **kwargs):
        raise AssertionError("the figures searched again")

    monkeypatch.setattr(visualization, "find_transform", no_search)
    plots = tmp_path / "plots"
    for canvas in ("reference", "union"):
        code = main(["batch", *[f for f, _ in frames], "-r", ref, "--output-dir",
                     str(tmp_path / canvas), "--plot", str(plots / canvas), "--canvas",
                     canvas, "--no-progress"])
        assert code == 0, capsys.readouterr()
        names = sorted(p.name for p in (plots / canvas).iterdir())
        assert names == ["f0_aligned.png", "f1_aligned.png", "night_summary.png"]
    assert len(searches) == 4  # one search per frame and run
    # Figures are outputs too: not replaced without --overwrite, checked before any work.
    capsys.readouterr()
    assert main(["batch", frames[0][0], "-r", ref, "--output-dir", str(tmp_path / "again"),
                 "--plot", str(plots / "reference")]) == 2
    assert "already exists" in capsys.readouterr().err and len(searches) == 4


def test_figures_name_the_files_and_the_no_data(night):
    pytest.importorskip("matplotlib")
    from astroalign_nd.visualization import plot_night, plot_registration

    ref, frames, _ = night
    fig = plot_registration(frames[0][0], ref)
    assert fig._suptitle.get_text() == "f0.fits -> ref.fits"
    assert "f0.fits" in fig.axes[0].get_title() and "ref.fits" in fig.axes[1].get_title()
    diff = fig.axes[2]
    assert [t.get_text() for t in diff.get_legend().get_texts()] == ["no data (masked)"]
    result = astroalign_nd.register_batch([f for f, _ in frames] + [np.zeros((64, 64))], ref)
    night_fig = plot_night(result)
    assert "2 of 3 frames registered, 1 failed" in night_fig._suptitle.get_text()
    (x, _), = [line.get_data() for line in night_fig.axes[1].get_lines()[:1]]
    assert len(x) == 3


# -- channels-first cubes and image files ---------------------------------------------------

def test_channels_first_cubes(tmp_path):
    pair = simulate_pair((120, 150), n_stars=90, rotation=6.0, translation=(4.0, -3.0),
                         seed=4)
    gains = np.array([1.0, 0.6, 0.3], np.float32)
    cube_s = pair.source[None] * gains[:, None, None]
    cube_t = pair.target[None] * gains[:, None, None]
    src = _write(tmp_path / "rgb_s.fits", cube_s.astype(np.float32))
    tgt = _write(tmp_path / "rgb_t.fits", cube_t.astype(np.float32))
    one = _write(tmp_path / "one_s.fits", pair.source[None].astype(np.float32))
    for source, n in ((src, 3), (one, 1)):
        out = tmp_path / f"out{n}.fits"
        code, _, err = run_cli("register", source, tgt, "-o", out)
        assert code == 0, err
        ccd = CCDData.read(out)
        assert ccd.shape == (n, 120, 150)  # the input's layout
        t = transform_from_header(ccd.meta)
        assert _corner_error(t, pair.transform, (120, 150)) < 0.2
        good = ~ccd.mask[0]
        for c in range(n):  # every plane resampled alike
            np.testing.assert_allclose(ccd.data[c][good], gains[c] * ccd.data[0][good],
                                       rtol=1e-5, atol=1e-3)
    # The API alike: a (3, ny, nx) array, planes first in and out.
    aligned = astroalign_nd.register(cube_s, cube_t)
    assert aligned.shape == cube_s.shape and aligned.mask.shape == cube_s.shape
    with pytest.raises(ValueError, match=r"\(nchan, ny, nx\)"):
        astroalign_nd.register(np.zeros((5, 60, 60)), cube_t)


def test_image_files_are_read_bottom_up(tmp_path):
    """A PNG that looks like the FITS frame registers as the FITS frame does."""
    skio = pytest.importorskip("skimage.io")
    from astroalign_nd.io.read import FLIP_HISTORY, parse_input

    pair = simulate_pair((160, 160), n_stars=100, rotation=12.0, translation=(5.0, 3.0),
                         seed=8)
    img = np.clip(pair.source, 0, 65535).astype(np.uint16)
    png = tmp_path / "source.png"
    skio.imsave(png, img[::-1], check_contrast=False)  # the top row first, as it is seen
    np.testing.assert_array_equal(parse_input(png).data, img)
    tgt = _write(tmp_path / "target.fits", pair.target)
    out = tmp_path / "out.fits"
    code, _, err = run_cli("register", png, tgt, "-o", out)
    assert code == 0, err
    ccd = CCDData.read(out)
    assert _corner_error(transform_from_header(ccd.meta), pair.transform, (160, 160)) < 0.2
    assert FLIP_HISTORY in list(ccd.meta["HISTORY"])
    assert ccd.data.dtype == ">f4"


# -- the demo --------------------------------------------------------------------------------

def test_demo_help_is_true_and_the_readme_command_runs_twice(tmp_path, capsys):
    from astroalign_nd.cli.demo import DEMO_PAIR

    code, out, _ = run_cli("demo", "--help")
    flat = " ".join(out.split())
    dx, dy = DEMO_PAIR["translation"]
    assert f"rotated by {DEMO_PAIR['rotation']:g} deg" in flat
    assert f"scaled by {DEMO_PAIR['scale']:g}" in flat and f"({dx:g}, {dy:g}) px" in flat
    # What the demo prints is the same transform (about pixel (0, 0)).
    truth = simulate_pair(seed=0, **DEMO_PAIR).transform
    for run in range(2):  # the README's command, twice: the demo's own files are replaced
        code, out, err = run_cli("demo", "--output-dir", tmp_path / "demo_out")
        assert code == 0, err
        tx, ty = truth.translation
        assert f"translation=({tx:.3f}, {ty:.3f}) px" in out.splitlines()[0]
    # A file the demo did not write is kept.
    foreign = tmp_path / "other"
    foreign.mkdir()
    fits.PrimaryHDU(np.zeros((8, 8))).writeto(foreign / "aligned.fits")
    assert main(["demo", "--output-dir", str(foreign)]) == 2
    err = capsys.readouterr().err
    assert "already exists" in err and "--overwrite" in err
    assert not (foreign / "source.fits").exists()


def test_the_docs_exit_code_table_is_the_command_lines():
    """docs/cli.rst shows the table that --help prints (one table for every command)."""
    from astroalign_nd.cli.errors import EXIT_CODES

    page = os.path.join(WORKTREE, "docs", "cli.rst")
    if not os.path.isfile(page):
        pytest.skip("the documentation sources are not here (installed package)")
    with open(page, encoding="utf-8") as fh:
        text = fh.read()
    table = text[text.index(".. _cli-exit-codes:"):text.index("Options\n=======")]
    rows = " ".join(table.split())
    for code, meaning in EXIT_CODES:
        words = " ".join(meaning.replace("--skip-existing", "``--skip-existing``").split())
        assert f"{code} {words}" in rows, code
