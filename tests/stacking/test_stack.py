# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Stacking: astroalign_nd.stack, LiveStack, watch_folder and the stack/watch commands."""

import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from astropy.io import fits
from astropy.nddata import CCDData, StdDevUncertainty

from astroalign_nd import AstroalignWarning, TransformNotFoundError, stack
from astroalign_nd.cli.main import main
from astroalign_nd.io import write_ccddata
from astroalign_nd.simulate import add_satellite_trail, simulate_sequence
from astroalign_nd.stacking import LiveStack, StackConfig, watch_folder
from astroalign_nd.stacking.combine import reject

WORKTREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
POSIX = pytest.mark.skipif(not hasattr(signal, "SIGINT") or os.name != "posix",
                           reason="signals to a subprocess need POSIX")

SIGMA = 10.0  # the frames' known noise


def _with_trail(frame, start, end, amplitude=400.0):
    data = add_satellite_trail(frame.data, start, end, amplitude=amplitude)
    return CCDData(data, unit=frame.unit, uncertainty=frame.uncertainty, meta=frame.meta)


@pytest.fixture(scope="module")
def ten():
    """Ten frames with known Gaussian noise, a drifting sky, cosmic rays and a satellite trail."""
    seq = simulate_sequence((128, 128), n_frames=10, n_stars=80, noise_sigma=SIGMA,
                            sky_drift=0.3, n_cosmic_rays=25, seed=11)
    seq.frames[4] = _with_trail(seq.frames[4], (-5.0, 20.0), (140.0, 110.0))
    return seq


def _deviation(ccd, truth):
    return (np.asarray(ccd.data, float) - truth) / np.asarray(ccd.uncertainty.array, float)


def test_average_uncertainty_is_sigma_over_sqrt_n():
    """No artefacts: the stack's uncertainty on the sky is sigma / sqrt(10), as is its scatter."""
    seq = simulate_sequence((128, 128), n_frames=10, n_stars=80, noise_sigma=SIGMA, seed=5)
    ccd = stack(seq.frames, clip=None)
    sky = (seq.truth < seq.sky[0] + 1.0) & (ccd.flags == 10)
    assert sky.sum() > 5000
    expected = SIGMA / np.sqrt(10)
    assert abs(np.median(ccd.uncertainty.array[sky]) / expected - 1) < 0.10
    scatter = np.std(ccd.data[sky] - seq.truth[sky])
    assert abs(scatter / expected - 1) < 0.10
    assert isinstance(ccd.uncertainty, StdDevUncertainty)
    assert ccd.meta["NCOMBINE"] == 10 and not ccd.mask.any()


def test_clipped_stack_is_within_5_sigma_of_the_truth(ten):
    """Cosmic rays and a satellite trail in single frames do not stay where >= 5 frames overlap."""
    clipped = stack(ten.frames)
    plain = stack(ten.frames, clip=None)
    deep = clipped.flags >= 5
    assert deep.sum() > 0.8 * deep.size
    assert np.max(np.abs(_deviation(clipped, ten.truth)[deep])) < 5.0
    # The check can fail: without clipping the trail and the cosmic rays stay.
    assert np.max(np.abs(_deviation(plain, ten.truth)[deep])) > 20.0
    # The sky is the reference's (offsets measured from the drifting sky levels).
    for k in range(2, 11):
        true_offset = ten.sky[k - 1] - ten.sky[0]
        assert abs(clipped.meta[f"AASKY{k:03d}"] - true_offset) < 0.5
    assert clipped.meta["AANRJ005"] > 200  # the trail's frame lost the trail


@pytest.mark.parametrize("kw", [dict(clip="minmax", nlow=1, nhigh=2),
                                dict(method="median", clip="sigma")])
def test_other_rejections_and_combinations(ten, kw):
    ccd = stack(ten.frames, **kw)
    deep = ccd.flags >= 5
    assert np.max(np.abs(_deviation(ccd, ten.truth)[deep])) < 5.0


def test_sum_is_the_mean_times_n(ten):
    mean = stack(ten.frames[:4])
    total = stack(ten.frames[:4], method="sum")
    np.testing.assert_allclose(total.data, 4 * mean.data, rtol=1e-5)
    np.testing.assert_allclose(total.uncertainty.array, 4 * mean.uncertainty.array, rtol=1e-5)


def test_strips_give_the_same_stack(ten):
    """A small memory limit (many strips) changes nothing."""
    whole = stack(ten.frames[:5])
    strips = stack(ten.frames[:5], memory_limit=5 * 128 * 64 * 7)
    np.testing.assert_array_equal(whole.data, strips.data)
    np.testing.assert_array_equal(whole.uncertainty.array, strips.uncertainty.array)


def test_masked_pixels_are_excluded_per_pixel(ten):
    """A frame's masked (NaN) pixels leave the others to make the pixel: never masked."""
    frames = list(ten.frames[:5])
    f = frames[2]
    data = f.data.copy()
    data[40:60, 40:60] = np.nan
    mask = np.zeros(data.shape, bool)
    mask[40:60, 40:60] = True
    frames[2] = CCDData(data, mask=mask, unit=f.unit, uncertainty=f.uncertainty)
    ccd = stack(frames)
    assert not ccd.mask.any() and np.isfinite(ccd.data).all()
    dx, dy = ten.shifts[2]
    inner = (slice(int(42 + dy), int(58 + dy)), slice(int(42 + dx), int(58 + dx)))
    assert np.all(ccd.flags[inner] == 4)  # four frames made those pixels
    assert np.max(np.abs(_deviation(ccd, ten.truth)[inner])) < 5.0
    assert np.isnan(f.data).sum() == 0  # the caller's frame is unchanged


def test_union_canvas_masks_only_where_no_frame_reaches(ten):
    ccd = stack(ten.frames[:4], canvas="union")
    ny, nx = ten.truth.shape
    x0 = int(min(0, ten.shifts[:4, 0].min()))
    y0 = int(min(0, ten.shifts[:4, 1].min()))
    assert ccd.shape == (ny + int(ten.shifts[:4, 1].max()) - y0,
                         nx + int(ten.shifts[:4, 0].max()) - x0)
    reach = np.zeros(ccd.shape, bool)
    for dx, dy in ten.shifts[:4]:
        r, c = int(dy) - y0, int(dx) - x0
        reach[r:r + ny, c:c + nx] = True
    # Registered shifts are within a fraction of a pixel of the truth: edges may move by one.
    assert np.all(~ccd.mask[1:-1, 1:-1] | ~reach[1:-1, 1:-1] | _near_edge(reach)[1:-1, 1:-1])
    assert np.all(ccd.mask | reach | _near_edge(reach))
    assert abs(int(ccd.mask.sum()) - int((~reach).sum())) < 2 * sum(ccd.shape) * 4
    assert np.array_equal(ccd.mask, ccd.flags == 0)


def _near_edge(reach):
    """Pixels within one pixel of the edge of ``reach``."""
    edge = np.zeros_like(reach)
    for axis in (0, 1):
        for step in (1, -1):
            edge |= reach != np.roll(reach, step, axis=axis)
    return edge


def test_header_lists_frames_used_and_left_out(ten):
    frames = [ten.frames[0], np.zeros((64, 64), np.float32), ten.frames[1]]
    with pytest.warns(AstroalignWarning, match="frame1 was left out of the stack: "
                      "TooFewSourcesError"):  # never silently
        ccd = stack(frames)
    h = ccd.meta
    assert h["NCOMBINE"] == 2 and h["NREJECT"] == 1
    assert h["IMCMB001"] == "frame0 (reference)" and h["IMCMB002"] == "frame2"
    assert h["AAREJ001"].startswith("frame1: TooFewSourcesError")


def test_given_weights_and_reference_not_among_frames(ten):
    ref, a, b = ten.frames[:3]
    ccd = stack([a, b], reference=ref, weights=[1.0, 0.0, 1.0], clip=None)
    assert ccd.meta["NCOMBINE"] == 3 and ccd.meta["AAWGT002"] == 0.0
    # Weight 0 for the first frame: the stack is the mean of the reference and b.
    only = stack([b], reference=ref, clip=None, weights=None)
    np.testing.assert_allclose(ccd.data, only.data, rtol=1e-5, atol=1e-3)


def test_nothing_registered_is_refused(ten):
    with pytest.raises(TransformNotFoundError, match="no frame could be registered"):
        stack([ten.frames[0], np.zeros((64, 64), np.float32)])


@pytest.mark.parametrize("kw, err, match", [
    (dict(method="mean"), ValueError, "method must be one of"),
    (dict(clip="extrema"), ValueError, "clip must be one of"),
    (dict(normalize="median"), ValueError, "normalize must be one of"),
    (dict(sigma=-1.0), ValueError, "sigma must be a finite number > 0; got -1.0."),
    (dict(sigma="3"), TypeError, "sigma must be a finite number > 0; got '3'."),
    (dict(sigma_low=0), ValueError, "sigma_low must be a finite number > 0 or None"),
    (dict(nlow=-1), ValueError, "nlow must be an integer >= 0"),
    (dict(maxiters=0), ValueError, "maxiters must be an integer >= 1"),
    (dict(memory_limit=0), ValueError, r"memory_limit must be a finite number > 0 \(bytes\)"),
    (dict(gain=0.0), ValueError, "gain must be a finite number > 0"),
    (dict(weights=[1.0]), ValueError, "one finite number >= 0 per frame"),
    (dict(weights=[1.0, -1.0]), ValueError,
     "weights must be 'variance' or 'auto' or None or a sequence"),
    (dict(weights="snr"), ValueError, "weights must be 'variance'"),
    (dict(canvas="full"), ValueError, "canvas must be one of"),
    (dict(n_start=4), TypeError, "n_start: not an option of stack"),
])
def test_bad_arguments(ten, kw, err, match):
    with pytest.raises(err, match=match):
        stack(ten.frames[:2], **kw)


def test_bad_frames_and_outputs(ten, tmp_path):
    with pytest.raises(ValueError, match="frames is empty"):
        stack([])
    with pytest.raises(TypeError, match="single path"):
        stack(str(tmp_path / "a.fits"))
    with pytest.raises(ValueError, match="2-D image"):
        stack([np.zeros((32, 32, 3))])
    paths = []
    for k in range(2):
        paths.append(str(tmp_path / f"f{k}.fits"))
        write_ccddata(ten.frames[k], paths[-1])
    with pytest.raises(ValueError, match="is the input"):
        stack(paths, output=paths[1], overwrite=True)
    out = tmp_path / "stack.fits"
    out.write_bytes(b"keep")
    with pytest.raises(FileExistsError):
        stack(paths, output=out)
    assert out.read_bytes() == b"keep"
    stack(paths, output=out, overwrite=True)
    back = CCDData.read(out)
    assert back.meta["IMCMB001"] == "f0.fits (reference)" and back.uncertainty is not None


def test_frames_without_uncertainty(ten):
    """Gain and read noise, else the sky noise, give the uncertainty."""
    bare = [CCDData(f.data, unit="adu") for f in ten.frames[:4]]
    measured = stack(bare, clip=None)
    sky = (ten.truth < ten.sky[0] + 1.0) & (measured.flags == 4)
    # Interpolation lowers the registered frames' noise a little: within 15%.
    assert abs(np.median(measured.uncertainty.array[sky]) / (SIGMA / 2) - 1) < 0.15
    poisson = stack(bare, clip=None, gain=2.0, read_noise=4.0)
    expected = np.sqrt(ten.sky[0] / 2.0 + 4.0) / 2  # four frames of sky/gain + (rn/gain)^2
    assert abs(np.median(poisson.uncertainty.array[sky]) / expected - 1) < 0.10


# -- live stacking ---------------------------------------------------------------------------


def test_live_stack_clips_against_the_running_stack(ten):
    """A trail early (in the frames held) and one late (against the running stack) both go."""
    frames = list(ten.frames)
    frames[1] = _with_trail(frames[1], (130.0, 0.0), (0.0, 127.0))
    live = LiveStack(frames[0])
    for k, frame in enumerate(frames[1:], start=1):
        live.add(frame, name=f"f{k}")
    ccd = live.result()
    deep = ccd.flags >= 5
    assert np.max(np.abs(_deviation(ccd, ten.truth)[deep])) < 5.0
    assert ccd.meta["NCOMBINE"] == 10 and live.used[0] == "reference"
    plain = LiveStack(frames[0], clip=None)
    for frame in frames[1:]:
        plain.add(frame)
    assert np.max(np.abs(_deviation(plain.result(), ten.truth)[deep])) > 20.0


def test_reject_keeps_a_pixel_whose_values_would_all_go():
    x = np.array([[[0.0]], [[100.0]]])
    keep = reject(x, np.ones_like(x), np.ones(x.shape, bool),
                  StackConfig(clip="minmax", nlow=1, nhigh=1))
    assert keep.all()


def _write_frames(seq, folder, n):
    paths = []
    for k in range(n):
        p = os.path.join(folder, f"frame{k:02d}.fits")
        write_ccddata(seq.frames[k], p)
        paths.append(p)
    return paths


def test_watch_folder_in_process(ten, tmp_path):
    src, watched = tmp_path / "src", tmp_path / "watched"
    src.mkdir()
    watched.mkdir()
    paths = _write_frames(ten, str(src), 4)
    for p in paths[1:]:
        shutil.copy(p, watched)
    (watched / "notes.txt").write_text("not a frame")
    (watched / "broken.fits").write_bytes(b"SIMPLE  =                    T" + b" " * 50)
    out = watched / "stack.fits"
    seen = []
    live = watch_folder(watched, paths[0], out, interval=0.05, timeout=0.5,
                        callback=lambda p, e: seen.append((os.path.basename(p), e)))
    assert [n for n, e in seen] == ["frame01.fits", "frame02.fits", "frame03.fits",
                                    "broken.fits"]  # a file left out is named too
    assert seen[-1][1] == "not a complete FITS file"
    assert live.rejected == [("broken.fits", "not a complete FITS file")]
    h = fits.getheader(out)
    assert h["NCOMBINE"] == 4 and h["IMCMB001"] == "frame00.fits (reference)"
    assert h["AAREJ001"] == "broken.fits: not a complete FITS file"
    with pytest.raises(FileExistsError):
        watch_folder(watched, paths[0], out, timeout=0.1)
    with pytest.raises(ValueError, match="is the input"):
        watch_folder(watched, paths[0], paths[0], overwrite=True, timeout=0.1)
    with pytest.raises(ValueError, match="interval"):
        watch_folder(watched, paths[0], tmp_path / "x.fits", interval=0)


def _read_stack(path):
    """NCOMBINE of the stack file, checking that every data block is there."""
    with fits.open(path) as hdul:
        for hdu in hdul:
            if hdu.data is not None:
                np.asarray(hdu.data).sum()
        return hdul[0].header["NCOMBINE"]


#: The command as a terminal runs it: Ctrl-C raises KeyboardInterrupt, even when the test
#: process (a worker pool of an earlier test) left SIGINT ignored for its children.
_TERMINAL_CLI = (
    "import signal, sys\n"
    "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
    "from astroalign_nd.cli.main import main\n"
    "sys.exit(main(sys.argv[1:]))\n")


def _copy_and_read(paths, watched, out, proc, errlog):
    """Copy the frames in one by one, reading the stack back all the while."""
    deadline = time.monotonic() + 90
    while not out.exists():
        assert time.monotonic() < deadline and proc.poll() is None, errlog.read_text()
        time.sleep(0.05)
    counts = []
    for k, p in enumerate(paths[1:], start=2):
        part = watched / (os.path.basename(p) + ".part")
        shutil.copy(p, part)  # written under another name, then renamed in
        os.replace(part, watched / os.path.basename(p))
        while True:  # a reader sees a complete stack at every moment
            counts.append(_read_stack(out))
            if counts[-1] == k:
                break
            assert time.monotonic() < deadline and proc.poll() is None, errlog.read_text()
            time.sleep(0.02)
    return counts


@POSIX
def test_watch_command_live_and_sigint(ten, tmp_path):
    """
    Frames copied in one by one are picked up; the stack file is valid at
    every moment a reader looks; SIGINT ends the watch with the stack written.
    """
    src, watched = tmp_path / "src", tmp_path / "watched"
    src.mkdir()
    watched.mkdir()
    paths = _write_frames(ten, str(src), 5)
    out = watched / "stack.fits"
    env = dict(os.environ, PYTHONPATH=WORKTREE + os.pathsep + os.environ.get("PYTHONPATH", ""))
    log, errlog = tmp_path / "out.txt", tmp_path / "err.txt"
    with open(log, "wb") as fo, open(errlog, "wb") as fe:
        proc = subprocess.Popen(
            [sys.executable, "-c", _TERMINAL_CLI, "watch", str(watched), "-r", paths[0],
             "--stack", str(out), "--interval", "0.1"], stdout=fo, stderr=fe, env=env)
        try:
            counts = _copy_and_read(paths, watched, out, proc, errlog)
            proc.send_signal(signal.SIGINT)
            code = proc.wait(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=30)
    err, stdout = errlog.read_text(), log.read_text()
    assert counts == sorted(counts) and counts[-1] == 5, (counts, err)
    assert code == 130, err
    assert "interrupted (SIGINT)" in err and "Traceback" not in err
    assert stdout.count("added ") == 4
    assert _read_stack(out) == 5
    assert not [p for p in os.listdir(watched) if p.startswith(".")]  # no temporary left


def test_watch_command_max_frames(ten, tmp_path, capsys):
    paths = _write_frames(ten, str(tmp_path), 3)
    out = tmp_path / "live.fits"
    code = main(["watch", str(tmp_path), "-r", paths[0], "--stack", str(out),
                 "--interval", "0.05", "--max-frames", "2"])
    assert code == 0
    assert "3 frames stacked, 0 failed" in capsys.readouterr().out
    assert main(["watch", str(tmp_path), "-r", paths[0], "--stack", str(out),
                 "--max-frames", "1"]) == 2  # exists, no --overwrite


def test_stack_command(ten, tmp_path, capsys):
    paths = _write_frames(ten, str(tmp_path), 3)
    blank = str(tmp_path / "blank.fits")
    write_ccddata(CCDData(np.zeros((64, 64), np.float32), unit="adu"), blank)
    out = str(tmp_path / "stack.fits")
    assert main(["stack", *paths, "-o", out]) == 0
    printed = capsys.readouterr().out
    assert "3 frames combined, 0 left out; 0 px masked" in printed
    # Each frame's line as its registration ends, before the combining's summary.
    lines = printed.splitlines()
    for k in (1, 2):
        line = next(i for i, s in enumerate(lines) if f"frame0{k}.fits: registered (" in s)
        assert lines[line].startswith(("[1/2] ", "[2/2] ")) and " stars, RMS " in lines[line]
        assert line < next(i for i, s in enumerate(lines) if "frames combined" in s)
    assert main(["stack", *paths, "-o", out]) == 2  # exists
    assert main(["stack", *paths, "-o", paths[1], "--overwrite"]) == 2  # an input
    assert main(["stack", *paths, blank, "-o", out, "--overwrite", "--clip", "minmax"]) == 1
    assert "LEFT OUT blank.fits: TooFewSourcesError" in capsys.readouterr().out
    assert main(["stack", paths[0], blank, "-o", out, "--overwrite"]) == 3
    assert main(["stack", *paths, "-o", out, "--overwrite", "--sigma", "-2"]) == 2
    h = fits.getheader(out)
    assert [h[f"IMCMB{k:03d}"] for k in (1, 2, 3)] == ["frame00.fits (reference)",
                                                       "frame01.fits", "frame02.fits"]


def test_callback_gets_each_frame_as_it_is_registered(ten):
    """``stack(callback=...)``: every frame's result, with its true transform (0.25 px:
    faint stars under cosmic rays, the affine fit's error reaches about 0.15 px at the corners)."""
    frames = [ten.frames[0], ten.frames[1], ten.frames[2], np.zeros((128, 128))]
    got = []
    with pytest.warns(AstroalignWarning, match="frame3 was left out"):
        stack(frames, callback=got.append, clip=None)
    assert sorted(f.name for f in got) == ["frame1", "frame2", "frame3"]
    yy, xx = np.mgrid[0:128:16, 0:128:16].astype(float)
    for f in got:
        if f.name == "frame3":
            assert f.status == "failed" and "TooFewSourcesError" in f.error
            continue
        k = int(f.name[-1])
        assert f.status == "registered" and f.quality["n_matches"] >= 10
        found, truth = f.transform(xx, yy), ten.transforms[k](xx, yy)
        assert np.max(np.hypot(found[0] - truth[0], found[1] - truth[1])) < 0.25


def test_write_with_retry_waits_for_a_viewer(monkeypatch, tmp_path):
    """Windows: a viewer holding the stack open makes the rename fail for a while."""
    import astroalign_nd.stacking.live as live_mod

    real, calls = live_mod.write_output, []

    def busy(ccd, path, overwrite=False):
        calls.append(path)
        if len(calls) < 3:
            raise PermissionError("the file is open in another program")
        real(ccd, path, overwrite=overwrite)

    monkeypatch.setattr(live_mod, "write_output", busy)
    monkeypatch.setattr(live_mod, "_RETRY_SECONDS", 0.01)
    path = str(tmp_path / "stack.fits")
    live_mod.write_with_retry(CCDData(np.ones((4, 4)), unit="adu"), path)
    assert len(calls) == 3 and os.path.isfile(path)
    calls.clear()
    monkeypatch.setattr(live_mod, "write_output", lambda *a, **k: (_ for _ in ()).throw(
        PermissionError("still open")))
    with pytest.raises(PermissionError, match="still open"):
        live_mod.write_with_retry(CCDData(np.ones((4, 4)), unit="adu"), path, tries=2)
