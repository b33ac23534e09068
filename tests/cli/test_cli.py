# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The astroalign-nd command line: batch streaming, resume, summary, options and errors."""

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest
from astropy import units as u
from astropy.io import fits
from astropy.nddata import CCDData
from astropy.table import Table

import astroalign_nd
from astroalign_nd import transform_from_header
from astroalign_nd.cli import main
from astroalign_nd.simulate import simulate_pair

from _helpers import count_calls

WORKTREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _write(path, data):
    fits.PrimaryHDU(np.asarray(data, np.float32), header=fits.Header({"BUNIT": "adu"})
                    ).writeto(path)
    return str(path)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    pair = simulate_pair((192, 192), n_stars=120, rotation=4.0, translation=(6.3, -4.1),
                         seed=5)
    ref = _write(d / "ref.fits", pair.target)
    srcs = [_write(d / f"s{k}.fits", np.rot90(pair.source, k)) for k in range(3)]
    return ref, srcs, pair


def test_batch_streams_lines_as_frames_finish(files, tmp_path, capsys, monkeypatch):
    """Frame 1's line is on stdout before frame 2 is even started."""
    import astroalign_nd.batch.runners as batch

    ref, srcs, _ = files
    seen_when_starting = []
    real = batch._run

    def spy(job, cfg):
        seen_when_starting.append(capsys.readouterr().out)
        return real(job, cfg)

    monkeypatch.setattr(batch, "_run", spy)
    code = main(["batch", *srcs, "-r", ref, "--output-dir", str(tmp_path)])
    rest = capsys.readouterr().out
    assert code == 0
    out = "".join(seen_when_starting) + rest
    assert seen_when_starting[0] == ""
    assert seen_when_starting[1].startswith("[1/3] s0.fits: ok ->")
    assert "[2/3] s1.fits: ok" in seen_when_starting[2]
    assert "3 of 3 frames registered" in out
    # no progress bar when stderr is not a terminal
    assert "frame/s" not in capsys.readouterr().err


def test_batch_old_and_new_argument_forms_agree(files, tmp_path, capsys):
    ref, srcs, _ = files
    assert main(["batch", ref, *srcs[:2], "--output-dir", str(tmp_path / "old"),
                 "--no-progress"]) == 0
    assert main(["batch", *srcs[:2], "--reference", ref, "--output-dir",
                 str(tmp_path / "new")]) == 0
    for name in ("s0_aligned.fits", "s1_aligned.fits"):
        a = CCDData.read(tmp_path / "old" / name)
        b = CCDData.read(tmp_path / "new" / name)
        assert np.array_equal(a.data, b.data, equal_nan=True)
    capsys.readouterr()
    assert main(["batch", ref, "--output-dir", str(tmp_path / "x")]) == 2
    assert "--reference" in capsys.readouterr().err


def test_batch_resume_summary_and_exit_codes(files, tmp_path, capsys):
    ref, srcs, pair = files
    out, summary = tmp_path / "out", tmp_path / "night.ecsv"
    missing = str(tmp_path / "nope.fits")
    assert main(["batch", *srcs[:2], "-r", ref, "--output-dir", str(out)]) == 0
    capsys.readouterr()
    # a rerun without --skip-existing is refused up front, naming both ways on (exit 2)...
    assert main(["batch", *srcs, "-r", ref, "--output-dir", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--skip-existing" in err and "--overwrite" in err
    assert not (out / "s2_aligned.fits").exists()  # nothing done
    # ...with it, they are skipped and the run succeeds
    code = main(["batch", *srcs, "-r", ref, "--output-dir", str(out), "--skip-existing",
                 "--summary", str(summary)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "s0.fits: skipped" in text and "s2.fits: ok" in text
    assert "1 of 3 frames registered, 2 skipped" in text
    t = Table.read(summary)
    # The reference first (kept from the first run: on the same grid), then the frames.
    assert list(t["name"]) == ["ref.fits", "s0.fits", "s1.fits", "s2.fits"]
    assert list(t["status"]) == ["reference", "skipped", "skipped", "registered"]
    assert "ref.fits: skipped (complete output there) -> " in text
    t = t[1:]
    assert set(t.colnames) >= {"name", "status", "n_matches", "rms", "log10_false_alarm",
                               "seconds", "error"}
    assert np.all(t["n_matches"] >= 10) and np.all(t["rms"] < 1)
    # the summary is not replaced without --overwrite/--skip-existing: checked before any work
    assert main(["batch", *srcs, "-r", ref, "--output-dir", str(tmp_path / "o2"),
                 "--summary", str(summary)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert not (tmp_path / "o2").exists() or not os.listdir(tmp_path / "o2")
    # an input that does not exist is a usage error
    assert main(["batch", srcs[0], missing, "-r", ref, "--output-dir", str(out)]) == 2


def test_batch_union_canvas_and_workers(files, tmp_path, capsys):
    ref, srcs, _ = files
    code = main(["batch", *srcs, "-r", ref, "--output-dir", str(tmp_path), "--canvas", "union",
                 "--workers", "2"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "canvas:" in text
    shapes = {CCDData.read(tmp_path / f"s{k}_aligned.fits").shape for k in range(3)}
    assert len(shapes) == 1 and shapes.pop() != (192, 192)


def test_detection_options_are_forwarded(files, tmp_path, monkeypatch, capsys):
    import astroalign_nd.detection.daofind as detection

    ref, srcs, _ = files
    calls = []
    real = detection._detect  # the detection of checked options (a config)

    def spy(image, mask, n_sources, config, nsigma, *cache):
        calls.append(dict(dataclasses.asdict(config), nsigma=nsigma))
        return real(image, mask, n_sources, config, nsigma, *cache)

    monkeypatch.setattr(detection, "_detect", spy)
    assert main(["register", srcs[0], ref, "-o", str(tmp_path / "a.fits"), "--fwhm", "3.1",
                 "--nsigma", "4", "--max-sources", "100", "--roundness-range", "-1", "1"]) == 0
    assert calls and all(c["fwhm"] == 3.1 and c["nsigma"] == 4.0 for c in calls)
    assert all(tuple(c["roundness_range"]) == (-1.0, 1.0) for c in calls)
    calls.clear()
    assert main(["batch", *srcs[:2], "-r", ref, "--output-dir", str(tmp_path / "b"),
                 "--fwhm", "2.8", "--peak-max", "1e6"]) == 0
    assert len(calls) >= 3 and all(c["fwhm"] == 2.8 and c["peak_max"] == 1e6 for c in calls)


@pytest.mark.parametrize("out, message", [
    ("aligned", "must end in"),
    (".", "is a folder"),
    ("notadir/x.fits", "is not a folder"),
    ("nowhere/x.fits", "does not exist"),
])
def test_register_checks_output_before_work(files, tmp_path, monkeypatch, capsys, out,
                                            message):
    ref, srcs, _ = files
    (tmp_path / "notadir").write_text("a file")
    monkeypatch.chdir(tmp_path)

    def never(*args, **kwargs):
        raise AssertionError("registration ran before the output path was checked")

    monkeypatch.setattr(astroalign_nd.registration, "register_and_match", never)
    assert main(["register", srcs[0], ref, "-o", out]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.skipif(os.name != "posix", reason="needs POSIX permissions")
def test_register_unwritable_folder(files, tmp_path, capsys):
    ref, srcs, _ = files
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    # root may write anywhere; /proc refuses new files even to root
    folder = "/proc" if os.geteuid() == 0 else str(ro)
    if folder == "/proc" and not os.path.isdir(folder):
        pytest.skip("no /proc to stand for an unwritable folder")
    try:
        for command in (["register", srcs[0], ref, "-o", os.path.join(folder, "x.fits")],
                        ["batch", srcs[0], "-r", ref, "--output-dir", folder]):
            assert main(command) == 2
            err = capsys.readouterr().err
            assert "cannot write" in err and len(err.strip().splitlines()) == 1
    finally:
        ro.chmod(0o700)


@pytest.mark.parametrize("exc", [MemoryError(), IndexError("index 7 is out of bounds"),
                                 KeyError("NAXIS3")])
def test_every_error_is_one_line(files, tmp_path, monkeypatch, capsys, exc):
    ref, srcs, _ = files

    def boom(*args, **kwargs):
        raise exc

    monkeypatch.setattr(astroalign_nd.registration, "register_and_match", boom)
    assert main(["register", srcs[0], ref, "-o", str(tmp_path / "x.fits")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert err.startswith("astroalign-nd: error:")
    if isinstance(exc, MemoryError):
        assert "out of memory" in err
    assert not (tmp_path / "x.fits").exists()


def test_cli_subprocess_exit_codes(files, tmp_path):
    """Through a real process: streaming to a pipe, and exit code 2 without traceback."""
    ref, srcs, _ = files
    env = dict(os.environ, PYTHONPATH=WORKTREE + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "astroalign_nd.cli"]
    r = subprocess.run(cmd + ["register", srcs[0], ref, "-o", str(tmp_path)],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "is a folder" in r.stderr
    r = subprocess.run(cmd + ["batch", srcs[0], "-r", ref, "--output-dir", str(tmp_path)],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("[1/1] s0.fits: ok ->")
    assert "frame/s" not in r.stderr  # no progress bar on a pipe


def test_batch_on_a_dask_scheduler(files, tmp_path, capsys):
    """--scheduler ADDRESS: the documented way to a dask.distributed cluster."""
    distributed = pytest.importorskip("dask.distributed")
    ref, srcs, _ = files
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=":0") as cluster:  # any free port
        code = main(["batch", *srcs, "-r", ref, "--output-dir", str(tmp_path),
                     "--scheduler", cluster.scheduler_address, "--canvas", "union"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "3 of 3 frames registered" in text
    assert len({CCDData.read(tmp_path / f"s{k}_aligned.fits").shape for k in range(3)}) == 1


# -- register and demo (moved from test_ccddata.py) -----------------------------------------

def test_cli_demo_and_overwrite(tmp_path, capsys):
    assert main(["demo", "--output-dir", str(tmp_path)]) == 0
    aligned = tmp_path / "aligned.fits"
    assert aligned.is_file()
    ccd = CCDData.read(aligned)
    assert ccd.shape == (512, 512)
    assert ccd.mask is not None
    assert "AATTYPE" in ccd.meta
    first = capsys.readouterr()
    assert "max position error" in first.out

    # Since issue 29 the demo replaces the files an earlier demo wrote (the README's
    # command runs again); a file it did not write is refused without --overwrite.
    assert main(["demo", "--output-dir", str(tmp_path)]) == 0
    assert "max position error" in capsys.readouterr().out
    CCDData(np.zeros((8, 8)), unit="adu").write(aligned, overwrite=True)
    mtime = aligned.stat().st_mtime_ns
    code = main(["demo", "--output-dir", str(tmp_path)])
    second = capsys.readouterr()
    assert code == 2
    assert "already exists" in second.err and "--overwrite" in second.err
    assert "Traceback" not in second.err + second.out
    assert aligned.stat().st_mtime_ns == mtime

    assert main(["demo", "--output-dir", str(tmp_path), "--overwrite"]) == 0
    assert CCDData.read(aligned).shape == (512, 512)


def test_cli_register_fits(tmp_path, capsys):
    # A small pair with a generic similarity transform (rotation, shift, scale).
    pair = simulate_pair((160, 160), n_stars=80, rotation=17.0, scale=1.05,
                         translation=(3.3, -2.1), flux_range=(2e3, 2e5), seed=11)
    src, tgt, out = tmp_path / "src.fits", tmp_path / "tgt.fits", tmp_path / "out.fits"
    fits.PrimaryHDU(pair.source, header=fits.Header({"OBJECT": "cli"})).writeto(src)  # no BUNIT
    fits.PrimaryHDU(pair.target).writeto(tgt)
    assert main(["register", str(src), str(tgt), "-o", str(out)]) == 0
    ccd = CCDData.read(out)
    assert ccd.shape == pair.target.shape
    assert ccd.unit == u.adu
    assert ccd.meta["OBJECT"] == "cli"
    t = transform_from_header(ccd.meta)
    ms = pair.matched_stars()
    xt, yt = t(ms["x_source"], ms["y_source"])
    assert np.max(np.hypot(xt - ms["x_target"], yt - ms["y_target"])) < 0.1
    capsys.readouterr()
    # again without --overwrite: a clean error
    assert main(["register", str(src), str(tgt), "-o", str(out)]) != 0
    err = capsys.readouterr().err
    assert "already exists" in err and "Traceback" not in err
    assert main(["register", str(src), str(tgt), "-o", str(out), "--overwrite",
                 "--unit", "electron", "--conserve-flux"]) == 0
    assert CCDData.read(out).unit == u.electron


def test_register_plot_registers_once(files, tmp_path, monkeypatch):
    """The figure takes the match just found: one search, so its warnings print once."""
    pytest.importorskip("matplotlib")
    from astroalign_nd import registration

    ref, srcs, _ = files
    calls = count_calls(monkeypatch, registration, "find_match_from_config")
    assert main(["register", srcs[0], ref, "-o", str(tmp_path / "a.fits"),
                 "--plot", str(tmp_path / "a.png")]) == 0
    assert len(calls) == 1 and (tmp_path / "a.png").stat().st_size > 0
