# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The diagnostic plots (astroalign_nd.visualization): the artists they draw, on Agg."""

import doctest
import os
import sys

import numpy as np
import pytest
from astropy.io import fits
from astropy.nddata import CCDData

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import PathCollection  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.image import AxesImage  # noqa: E402
from matplotlib.quiver import Quiver  # noqa: E402
from astropy.visualization import ImageNormalize, ZScaleInterval  # noqa: E402

import astroalign_nd  # noqa: E402
from astroalign_nd import visualization as vis  # noqa: E402
from astroalign_nd.matching import build_asterisms  # noqa: E402
from astroalign_nd.cli import main  # noqa: E402
from astroalign_nd.simulate import simulate_pair  # noqa: E402


@pytest.fixture(scope="module")
def pair():
    return simulate_pair((256, 256), n_stars=120, rotation=25.0, translation=(8.0, -5.0),
                         seed=3)


@pytest.fixture(scope="module")
def fit(pair):
    transform, points = astroalign_nd.find_transform(pair.source, pair.target)
    aligned = astroalign_nd.apply_transform(transform, pair.source, pair.target)
    return transform, points, aligned


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def _scatters(ax):
    return [c for c in ax.collections if isinstance(c, PathCollection)]


def test_match_colors_distinct():
    colors = vis.match_colors(200)
    assert colors.shape == (200, 4)
    assert len(np.unique(np.round(colors, 6), axis=0)) == 200
    assert np.all((colors >= 0) & (colors <= 1))
    with pytest.raises(ValueError, match="non-negative integer"):
        vis.match_colors(-1)


def test_plot_matches_shares_colours(pair, fit):
    _, (src, dst), _ = fit
    source_copy = pair.source.copy()
    ax_s, ax_t = vis.plot_matches(pair.source, pair.target, (src, dst))
    assert ax_s.figure is ax_t.figure
    colours = []
    for ax, pts in ((ax_s, src), (ax_t, dst)):
        images = [a for a in ax.get_children() if isinstance(a, AxesImage)]
        assert len(images) == 1
        assert images[0].get_array().shape == pair.source.shape
        (sc,) = _scatters(ax)
        np.testing.assert_allclose(sc.get_offsets(), pts)
        colours.append(sc.get_edgecolors())
    assert len(src) >= 10
    assert colours[0].shape == (len(src), 4)
    np.testing.assert_array_equal(colours[0], colours[1])  # same star, same colour
    assert len(np.unique(colours[0], axis=0)) == len(src)  # one colour per star
    np.testing.assert_array_equal(pair.source, source_copy)  # the input is left alone


def test_plot_matches_on_given_axes_and_catalogs(fit):
    _, (src, dst), _ = fit
    fig, axes = plt.subplots(1, 2)
    out = vis.plot_matches(src, dst, (src[:5], dst[:5]), axes=axes)
    assert tuple(out) == tuple(axes)
    for ax in axes:  # catalogs: stars only, no image
        assert not [a for a in ax.get_children() if isinstance(a, AxesImage)]
        assert len(_scatters(ax)[0].get_offsets()) == 5


def test_plot_matches_masked_pixels_shown_as_bad(pair, fit):
    _, points, _ = fit
    mask = np.zeros(pair.source.shape, bool)
    mask[:20] = True
    ccd = CCDData(pair.source, unit="adu", mask=mask)
    ax_s, _ = vis.plot_matches(ccd, pair.target, points)
    shown = [a for a in ax_s.get_children() if isinstance(a, AxesImage)][0].get_array()
    assert np.all(np.ma.getmaskarray(shown)[:20] | np.isnan(np.ma.getdata(shown)[:20]))
    assert np.isfinite(ccd.data).all()


@pytest.mark.parametrize("bad, exc, match", [
    (np.zeros((5, 2)), TypeError, "source_points, target_points"),
    ((np.zeros((5, 2)), np.zeros((4, 2))), ValueError, "pair up"),
    ((np.zeros((5, 3)), np.zeros((5, 3))), ValueError, r"\(N, 2\)"),
    ((["a", "b"], np.zeros((2, 2))), TypeError, r"\(N, 2\) array"),
])
def test_plot_matches_bad_points(pair, bad, exc, match):
    with pytest.raises(exc, match=match):
        vis.plot_matches(pair.source, pair.target, bad)


def test_plot_invariants_triangles_and_boundary(fit):
    _, (src, dst), _ = fit
    ax = vis.plot_invariants(src, dst)
    sc_src, sc_dst = _scatters(ax)
    n_tri = len(build_asterisms(src))
    assert n_tri > 3 * len(src)
    assert len(sc_src.get_offsets()) == n_tri
    assert len(sc_dst.get_offsets()) == len(build_asterisms(dst))
    for sc in (sc_src, sc_dst):
        x, y = np.asarray(sc.get_offsets()).T
        assert np.all(x >= 1) and np.all(y >= 1)
        # The triangle inequality: every triangle lies on or under y = 1/(x - 1).
        assert np.all(y <= 1.0 / (x - 1.0) * (1 + 1e-9))
    (line,) = ax.get_lines()
    lx, ly = line.get_data()
    np.testing.assert_allclose(ly, 1.0 / (lx - 1.0))
    ast = build_asterisms(src)
    np.testing.assert_allclose(sc_src.get_offsets(), np.exp(ast.invariants))
    # The matched stars' triangles fall on their counterparts: the same three stars in
    # the target give nearly the same ratios.
    p = dst[ast.triangles]
    side = np.sort(np.hypot(*np.moveaxis(p - np.roll(p, 1, axis=1), 2, 0)), axis=1)
    target_ratios = np.column_stack([side[:, 2] / side[:, 1], side[:, 1] / side[:, 0]])
    log_error = np.abs(np.log(target_ratios) - ast.invariants)
    assert np.median(log_error) < 0.02


def test_plot_invariants_too_few_points():
    ax = vis.plot_invariants(np.array([[0.0, 0.0], [1.0, 5.0]]))
    assert len(_scatters(ax)[0].get_offsets()) == 0
    assert len(ax.get_lines()) == 1


def test_plot_residuals_arrows(pair, fit):
    transform, (src, dst), _ = fit
    ax = vis.plot_residuals(transform, (src, dst), scale=50.0, shape=pair.target.shape)
    (q,) = [c for c in ax.collections if isinstance(c, Quiver)]
    assert q.N == len(src)
    xt, yt = transform(src[:, 0], src[:, 1])
    np.testing.assert_allclose(q.U, 50.0 * (dst[:, 0] - xt))
    np.testing.assert_allclose(q.V, 50.0 * (dst[:, 1] - yt))
    np.testing.assert_allclose(q.get_offsets(), dst)
    rms = np.sqrt(np.mean((dst[:, 0] - xt) ** 2 + (dst[:, 1] - yt) ** 2))
    assert rms < 0.5
    assert f"RMS {rms:.3f} px" in ax.get_title()
    np.testing.assert_array_equal(q.get_facecolors(), vis.match_colors(len(src)))
    with pytest.raises(TypeError, match="transform model"):
        vis.plot_residuals("similarity", (src, dst))
    with pytest.raises(ValueError, match="positive"):
        vis.plot_residuals(transform, (src, dst), scale=-1.0)


def test_plot_difference_zscale(pair, fit):
    """Centred (median 0) on a scale symmetric about 0, zscale-wide; no-data in the legend."""
    _, _, aligned = fit
    ax = vis.plot_difference(aligned, pair.target)
    (im,) = [a for a in ax.get_children() if isinstance(a, AxesImage)]
    assert isinstance(im.norm, ImageNormalize)
    assert im.norm.vmin == pytest.approx(-im.norm.vmax) and im.norm.vmax > 0
    expected = np.where(aligned.mask, np.nan, aligned.data) - pair.target
    expected -= np.nanmedian(expected)
    lo, hi = ZScaleInterval().get_limits(expected[np.isfinite(expected)])
    assert im.norm.vmax == pytest.approx(max(abs(lo), abs(hi)))
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["no data (masked)"]
    shown = np.ma.filled(np.ma.asarray(im.get_array(), dtype=float), np.nan)
    np.testing.assert_allclose(shown, expected, equal_nan=True)
    assert len(ax.figure.axes) == 2  # the image and its colour bar
    # Well registered: the stars cancel, the difference is noise-like.
    good = np.isfinite(expected)
    assert np.nanpercentile(np.abs(expected[good]), 99.9) < 0.2 * pair.target.max()


def test_plot_difference_wrong_grid(pair):
    with pytest.raises(ValueError, match="target's pixel grid"):
        vis.plot_difference(pair.source[:200], pair.target)
    with pytest.raises(TypeError, match="not catalogs"):
        vis.plot_difference(np.zeros((10, 2)), pair.target)


def test_plot_registration_one_figure(pair, fit):
    transform, points, aligned = fit
    fig = vis.plot_registration(pair.source, pair.target, transform, points, aligned)
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 7
    ax_s, ax_t, ax_d, ax_i, ax_r, ax_q = fig.axes[:6]
    n = len(points[0])
    c_s, c_t = (_scatters(ax)[0].get_edgecolors() for ax in (ax_s, ax_t))
    (q,) = [c for c in ax_r.collections if isinstance(c, Quiver)]
    np.testing.assert_array_equal(c_s, c_t)
    np.testing.assert_array_equal(q.get_facecolors(), c_s)  # arrows in the stars' colours
    assert q.N == n
    assert len(_scatters(ax_i)) == 2 and len(ax_i.get_lines()) == 1
    assert len([a for a in ax_d.get_children() if isinstance(a, AxesImage)]) == 1
    text = ax_q.texts[0].get_text()
    assert f"matched stars: {n}" in text
    assert "SimilarityTransform" in text
    with pytest.raises(TypeError, match="together"):
        vis.plot_registration(pair.source, pair.target, transform)


def test_plot_registration_finds_what_is_missing(pair):
    fig = Figure()
    out = vis.plot_registration(pair.source, pair.target, fig=fig, order="nearest-neighbor")
    assert out is fig
    assert len(fig.axes) == 7
    assert "matched stars" in fig.axes[5].texts[0].get_text()


def test_save_diagnostic_figure(pair, fit, tmp_path):
    transform, points, aligned = fit
    path = tmp_path / "diag.png"
    out = vis.save_diagnostic_figure(path, pair.source, pair.target, aligned,
                                     transform=transform, points=points, dpi=40)
    assert out == str(path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="overwrite"):
        vis.save_diagnostic_figure(path, pair.source, pair.target, aligned)
    assert path.read_bytes() == before
    vis.save_diagnostic_figure(path, pair.source, pair.target, aligned, overwrite=True,
                               transform=transform, points=points, dpi=50)
    assert path.read_bytes() != before
    with pytest.raises(ValueError, match="must end in one of"):
        vis.save_diagnostic_figure(tmp_path / "diag.fits", pair.source, pair.target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["diag.png"]  # no temporary left


def test_missing_matplotlib_message(monkeypatch, fit):
    _, points, _ = fit
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(ImportError, match="pip install matplotlib"):
        vis.plot_invariants(points[0])


def test_every_plot_has_an_example_that_calls_it():
    # The examples themselves run in tests/test_docstring_examples.py (once: they draw).
    parser = doctest.DocTestParser()
    for name in vis.__all__:
        obj = getattr(vis, name)
        if callable(obj):
            examples = parser.get_examples(obj.__doc__ or "")
            assert any(f"{name}(" in e.source for e in examples), name


def _write(path, data):
    fits.PrimaryHDU(np.asarray(data, np.float32), header=fits.Header({"BUNIT": "adu"})
                    ).writeto(path)
    return str(path)


def test_cli_register_plot(pair, tmp_path, capsys):
    src = _write(tmp_path / "src.fits", pair.source)
    tgt = _write(tmp_path / "tgt.fits", pair.target)
    out, plot = tmp_path / "out.fits", tmp_path / "check.png"
    assert main(["register", src, tgt, "-o", str(out), "--plot", str(plot)]) == 0
    assert f"wrote {plot}" in capsys.readouterr().out
    assert plot.read_bytes()[:4] == b"\x89PNG"
    # An existing plot is refused before any work, unless --overwrite.
    out.unlink()
    before = plot.read_bytes()
    assert main(["register", src, tgt, "-o", str(out), "--plot", str(plot)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert not out.exists() and plot.read_bytes() == before
    assert main(["register", src, tgt, "-o", str(tmp_path / "x.fits"), "--plot",
                 str(tmp_path / "check.txt")]) == 2
    assert "must end in one of" in capsys.readouterr().err
    assert main(["register", src, tgt, "-o", str(out), "--plot", str(plot),
                 "--overwrite"]) == 0


def test_cli_register_plot_without_matplotlib(pair, tmp_path, capsys, monkeypatch):
    src = _write(tmp_path / "src.fits", pair.source)
    tgt = _write(tmp_path / "tgt.fits", pair.target)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    out = tmp_path / "out.fits"
    assert main(["register", src, tgt, "-o", str(out), "--plot",
                 str(tmp_path / "p.png")]) == 2
    assert "pip install matplotlib" in capsys.readouterr().err
    assert not out.exists()  # stopped before the work


def test_lazy_submodule_does_not_import_matplotlib():
    """``astroalign_nd.visualization`` is there on first use; matplotlib only when drawing."""
    import subprocess

    code = ("import sys, astroalign_nd; v = astroalign_nd.visualization; "
            "assert v.__name__ == 'astroalign_nd.visualization'; "
            "assert 'visualization' in dir(astroalign_nd); "
            "assert 'matplotlib' not in sys.modules, 'matplotlib imported'")
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    done = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert astroalign_nd.visualization is vis


def test_plot_frame_quality_marks_the_frames_left_out():
    pytest.importorskip("matplotlib")
    from astropy.table import Table

    from astroalign_nd.visualization import plot_frame_quality

    t = Table({"name": ["a", "b", "c", "d"], "time": [60000.0, 60000.01, 60000.02, 60000.03],
               "fwhm": [3.0, 3.4, 6.0, 3.1], "fwhm_spread": [0.1, 0.1, 0.3, 0.1],
               "elongation": [1.05, 1.1, 3.0, 1.0], "transparency": [1.0, 0.98, 0.9, 0.4],
               "sky_noise": [10.0, 10.2, 10.1, 7.0], "weight": [1.0, 0.8, 0.1, 0.2],
               "used": [True, True, False, False], "reason": ["", "", "trailed: 3", "cloud"]})
    fig = plot_frame_quality(t)
    assert len(fig.axes) == 5 and fig.axes[-1].get_xlabel() == "hours from the first frame"
    # Each panel: the line, the used frames and the red crosses of the two left out.
    crosses = [ln for ln in fig.axes[1].lines if ln.get_color() == "red"]
    assert len(crosses) == 1 and list(crosses[0].get_ydata()) == [3.0, 1.0]
    assert "2 left out" in fig._suptitle.get_text()
    with pytest.raises(TypeError, match="frame_quality's table"):
        plot_frame_quality(Table({"name": ["a"]}))
