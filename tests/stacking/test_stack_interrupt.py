# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Ctrl-C and SIGTERM in `stack` and `watch`: what was done is written, and accounted for."""

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from astropy.io import fits
from _helpers import run_cli, write_sequence

import astroalign_nd.stacking.core as stack_core
from astroalign_nd import stack

WORKTREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
POSIX = pytest.mark.skipif(os.name != "posix", reason="signals to a subprocess need POSIX")


@pytest.fixture(scope="module")
def six(tmp_path_factory):
    return write_sequence(tmp_path_factory.mktemp("frames"), 6, seed=8)


def _stopped_after(monkeypatch, n):
    """
    Ctrl-C once ``n`` frames are registered: a real SIGINT to this process (POSIX), the
    command line's handler raising it; elsewhere the KeyboardInterrupt it raises.
    """
    real = stack_core.register_batch

    def register_batch(*args, callback=None, **kwargs):
        done, stack_callback = [], callback

        def callback(frame):
            if stack_callback is not None:  # the stack's own (the command line's lines)
                stack_callback(frame)
            done.append(frame)
            if len(done) == n:
                if os.name == "posix":
                    os.kill(os.getpid(), signal.SIGINT)
                    time.sleep(1.0)  # the handler raises at the next chance
                raise KeyboardInterrupt("SIGINT")

        return real(*args, callback=callback, **kwargs)

    monkeypatch.setattr(stack_core, "register_batch", register_batch)


def test_ctrl_c_in_stack_writes_the_partial_stack(six, tmp_path, monkeypatch):
    out = tmp_path / "st.fits"
    _stopped_after(monkeypatch, 2)
    code, stdout, err = run_cli("stack", *six, "-o", out, "--no-progress")
    assert code == 130, err
    assert "interrupted (SIGINT)" in err and "Traceback" not in err
    h = fits.getheader(out)
    assert h["NCOMBINE"] == 3 and h["NREJECT"] == 0  # the reference and two frames
    assert [h[f"IMCMB{k:03d}"] for k in (2, 3)] == ["f1.fits", "f2.fits"]
    history = [line for line in h["HISTORY"] if line.startswith("partial stack")]
    assert history == ["partial stack (interrupted): 3 of 6 frames stacked, 3 not registered"]
    assert history[0] in stdout
    assert "stacked f2.fits" in stdout and "partial stack: 3 frames combined" in stdout
    # The partial stack is a real stack: each frame's stars where the reference has them.
    ref = fits.getdata(six[0])
    data = fits.getdata(out)
    bright = ref > np.percentile(ref, 99.5)
    assert np.corrcoef(ref[bright], data[bright])[0, 1] > 0.95


def test_the_api_raises_with_the_partial_stack(six, tmp_path, monkeypatch):
    _stopped_after(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt) as info:
        stack(six[:4], output=tmp_path / "st.fits")
    partial = info.value.partial_result
    assert partial.meta["NCOMBINE"] == 2
    assert fits.getheader(tmp_path / "st.fits")["NCOMBINE"] == 2


def test_stopped_before_any_frame_writes_nothing(six, tmp_path, monkeypatch):
    def register_batch(*args, **kwargs):
        raise KeyboardInterrupt("SIGINT")

    monkeypatch.setattr(stack_core, "register_batch", register_batch)
    code, stdout, err = run_cli("stack", *six[:3], "-o", tmp_path / "st.fits", "--no-progress")
    assert code == 130 and "nothing written" in stdout
    assert not (tmp_path / "st.fits").exists()


def _watch(folder, ref, out, *extra):
    return run_cli("watch", folder, "-r", ref, "--stack", out, "--interval", "0.05", *extra)


@POSIX
def test_a_signal_while_a_frame_is_added_waits_for_its_line(six, tmp_path, monkeypatch):
    """
    SIGINT landing while a frame goes into the running stack: the frame is added whole
    and its "added" line printed before the watch stops (the header, the data and the
    console agree).
    """
    import astroalign_nd.stacking.live as live_mod

    watched = tmp_path / "in"
    watched.mkdir()
    for p in six[1:3]:
        os.link(p, watched / os.path.basename(p))
    real_add, calls = live_mod._Running.add, []

    def add(self, *args):
        calls.append(1)
        if len(calls) == 3:  # the reference, f1, then f2: the signal comes mid-way
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # Python runs the handler at the next chance
        return real_add(self, *args)

    monkeypatch.setattr(live_mod._Running, "add", add)
    out = tmp_path / "live.fits"
    code, stdout, err = _watch(watched, six[0], out)
    assert code == 130, err
    h = fits.getheader(out)
    assert h["NCOMBINE"] == 3 and h["IMCMB003"] == "f2.fits"
    assert stdout.count("added ") == 2 and "added f2.fits" in stdout
    assert "stopped: 3 frames stacked, 0 failed" in stdout


def test_a_frame_being_registered_at_the_stop_is_named(six, tmp_path, monkeypatch):
    import astroalign_nd.stacking.live as live_mod

    watched = tmp_path / "in"
    watched.mkdir()
    for p in six[1:4]:
        os.link(p, watched / os.path.basename(p))
    real = live_mod.LiveStack._registered

    def registered(self, frame, name):
        if frame.endswith("f2.fits"):
            raise KeyboardInterrupt("SIGTERM")
        return real(self, frame, name)

    monkeypatch.setattr(live_mod.LiveStack, "_registered", registered)
    out = tmp_path / "live.fits"
    code, stdout, err = _watch(watched, six[0], out)
    assert code == 130, err
    h = fits.getheader(out)
    why = "not stacked: the watch was stopped (SIGTERM) before it was registered"
    assert (h["NCOMBINE"], h["NREJECT"]) == (2, 2)
    assert [h["AAREJ001"], h["AAREJ002"]] == [f"f2.fits: {why}", f"f3.fits: {why}"]
    assert f"FAILED f3.fits: {why}" in err
    assert "stopped: 2 frames stacked, 2 failed" in stdout


_CLI = "import sys\nfrom astroalign_nd.cli.main import main\nsys.exit(main(sys.argv[1:]))\n"


def _start(args, tmp_path):
    env = dict(os.environ, PYTHONPATH=WORKTREE + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out, err = open(tmp_path / "out.txt", "wb"), open(tmp_path / "err.txt", "wb")
    with out, err:
        return subprocess.Popen([sys.executable, "-c", _CLI, *map(str, args)], stdout=out,
                                stderr=err, env=env, start_new_session=True)


def _wait_for(what, proc, tmp_path, seconds=120):
    deadline = time.monotonic() + seconds
    while not what():
        assert proc.poll() is None and time.monotonic() < deadline, \
            (tmp_path / "err.txt").read_text()
        time.sleep(0.05)


def _ended(proc):
    try:
        return proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)


@POSIX
def test_sigterm_in_watch_accounts_for_a_frame_still_being_written(six, tmp_path):
    watched = tmp_path / "in"
    watched.mkdir()
    out = tmp_path / "live.fits"
    with open(six[2], "rb") as fh:
        content = fh.read()
    stop, capped = threading.Event(), threading.Event()

    def camera():  # still writing the next frame, a little at a time
        size = 2880
        while not stop.wait(0.05):
            size = min(size + 200, len(content) - 100)
            if size == len(content) - 100:
                capped.set()
            with open(watched / "f2.fits", "wb") as fh:
                fh.write(content[:size])

    proc = _start(["watch", watched, "-r", six[0], "--stack", out, "--interval", "0.05"],
                  tmp_path)
    writer = threading.Thread(target=camera)
    writer.start()
    try:
        os.link(six[1], watched / "f1.fits")
        _wait_for(lambda: "added f1.fits" in (tmp_path / "out.txt").read_text(), proc,
                  tmp_path)
        time.sleep(0.3)
    finally:
        proc.send_signal(signal.SIGTERM)
        code = _ended(proc)
        stop.set()
        writer.join()
    stdout, err = (tmp_path / "out.txt").read_text(), (tmp_path / "err.txt").read_text()
    assert code == 143 and "interrupted (SIGTERM)" in err and "Traceback" not in err, err
    h = fits.getheader(out)
    assert (h["NCOMBINE"], h["NREJECT"]) == (2, 1)
    if not capped.is_set():  # (a loaded machine: else it stood still and was given up)
        assert h["AAREJ001"] == ("f2.fits: not stacked: the watch was stopped (SIGTERM) "
                                 "before it was completely written")
    assert f"FAILED {h['AAREJ001']}" in err
    assert "stopped: 2 frames stacked, 1 failed" in stdout
