# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Where the commands write: a full disk stops `batch` with one error, a run that fails leaves
no empty folder behind, a folder that cannot be made is one clear line, and `match` keeps
the transform it found.
"""

import errno
import os

import numpy as np
import pytest
from astropy.io import fits
from astropy.nddata import CCDData
from astropy.table import Table
from _helpers import run_cli, write_sequence

import astroalign_nd.io.write as write_mod
from astroalign_nd.io import transform_from_header, write_ccddata
from astroalign_nd.simulate import simulate_catalogs


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    folder = tmp_path_factory.mktemp("frames")
    paths = write_sequence(folder, 5, seed=5)
    blank = str(folder / "blank.fits")
    write_ccddata(CCDData(np.zeros((64, 64), np.float32), unit="adu"), blank)
    return paths, blank


def test_a_full_disk_stops_batch_with_one_error(frames, tmp_path, monkeypatch):
    paths, _ = frames
    real, published = write_mod._PrivateFolder.publish, []

    def publish(self, path, overwrite):  # the disk fills up after two frames
        if len(published) == 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        published.append(path)
        return real(self, path, overwrite)

    monkeypatch.setattr(write_mod._PrivateFolder, "publish", publish)
    out = tmp_path / "aligned"
    code, stdout, err = run_cli("batch", *paths[1:], "-r", paths[0], "--output-dir", out)
    assert code == 2
    assert "FAILED" not in stdout + err and stdout.count(": ok -> ") == 2
    (line,) = err.strip().splitlines()
    assert line.startswith("astroalign-nd: error: the batch stopped at f3.fits: cannot write ")
    assert "the disk is full; free some space or write to another disk" in line
    assert "The 2 frames written before it are complete" in line
    assert "run the batch again with --skip-existing" in line and "skip_existing" not in line
    assert sorted(os.listdir(out)) == ["f1_aligned.fits", "f2_aligned.fits"]


def test_a_failed_run_leaves_no_folder_it_created(frames, tmp_path):
    paths, blank = frames
    out = tmp_path / "night" / "aligned"
    code, _, err = run_cli("batch", paths[1], "-r", blank, "--output-dir", out)
    assert code == 3 and "usable source" in err  # the reference refused: nothing written
    assert not (tmp_path / "night").exists()
    kept = tmp_path / "mine"
    kept.mkdir()  # a folder the user made stays, empty or not
    assert run_cli("batch", paths[1], "-r", blank, "--output-dir", kept)[0] == 3
    assert kept.is_dir()


def test_an_unmakeable_aligned_dir_is_one_clear_line(frames, tmp_path, monkeypatch):
    paths, _ = frames
    args = ["stack", *paths[:2], "-o", tmp_path / "st.fits", "--aligned-dir"]
    code, _, err = run_cli(*args, os.path.join(paths[0], "sub"))
    assert code == 2
    assert err.strip() == (f"astroalign-nd: error: cannot create --aligned-dir "
                           f"{os.path.join(paths[0], 'sub')!r}: a part of the path is a file, "
                           "not a folder; give a folder.")

    def makedirs(path, exist_ok=False):  # a folder the system does not let us create in
        raise PermissionError(errno.EPERM, os.strerror(errno.EPERM), path)

    monkeypatch.setattr(os, "makedirs", makedirs)
    code, _, err = run_cli(*args, tmp_path / "x")
    assert code == 2 and "[Errno" not in err
    assert "cannot create --aligned-dir" in err and "choose a folder you can write to" in err
    assert not (tmp_path / "st.fits").exists()


def test_match_keeps_the_transform_it_found(tmp_path):
    cats = simulate_catalogs(300, seed=2)
    src, dst, out = tmp_path / "s.ecsv", tmp_path / "t.ecsv", tmp_path / "pairs.ecsv"
    cats.source.write(src)
    cats.target.write(dst)
    code, stdout, err = run_cli("match", src, dst, "-o", out)
    assert code == 0, err
    assert "SimilarityTransform rotation=" in stdout and "kept in its AAT* keywords" in stdout
    found = transform_from_header(Table.read(out).meta)  # from the file alone
    xy = np.random.default_rng(0).uniform(0, 1000, (50, 2))
    error = np.hypot(*(np.array(found(*xy.T)) - np.array(cats.transform(*xy.T))))
    assert error.max() < 0.1  # px, over the field
    fits_out = tmp_path / "pairs.fits"
    assert run_cli("match", src, dst, "-o", fits_out)[0] == 0
    assert fits.getheader(fits_out, 1)["AATTYPE"] == "similarity"
    code, stdout, _ = run_cli("match", src, dst, "-o", tmp_path / "pairs.csv")
    assert code == 0 and "not kept by this format: write .ecsv or .fits" in stdout


def test_batch_global_plot_draws_every_frame(frames, tmp_path):
    paths, _ = frames
    plots = tmp_path / "plots"
    code, stdout, err = run_cli("batch", paths[1], "-r", paths[0], "--output-dir",
                                tmp_path / "out", "--global", "--plot", plots)
    assert code == 0, err
    assert sorted(os.listdir(plots)) == ["f1_aligned.png", "night_summary.png"]


def test_residuals_of_an_exact_fit_are_not_magnified():
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.quiver import QuiverKey

    from astroalign_nd import SimilarityTransform
    from astroalign_nd.visualization import plot_residuals

    t = SimilarityTransform(rotation=10.0, translation_x=3.0)
    src = np.random.default_rng(1).uniform(0, 200, (30, 2))
    dst = np.column_stack(t(*src.T)) + 1e-13  # a frame onto itself: rounding only
    ax = plot_residuals(t, (src, dst), shape=(200, 200))
    assert ax.get_title() == "residuals: all below 0.001 px (RMS 0.000 px)"
    assert not [a for a in ax.get_children() if isinstance(a, QuiverKey)]
    # One far star among 0.1 px residuals: the key arrow stays inside its panel.
    dst = np.column_stack(t(*src.T)) + 0.1
    dst[0] += 30.0
    ax = plot_residuals(t, (src, dst), shape=(200, 200))
    (key,) = [a for a in ax.get_children() if isinstance(a, QuiverKey)]
    assert key.U <= 0.1 * 200  # data px: from 0.75 of the width, well inside
