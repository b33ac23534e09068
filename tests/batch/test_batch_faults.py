# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""A batch under faults: dead workers, SIGTERM / SIGINT, retried dask tasks."""

import multiprocessing
import os
import queue
import signal
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table

import astroalign_nd.batch.frame as frame_mod
from astroalign_nd.io.writers import FITSWriter
from astroalign_nd import register_batch
from astroalign_nd.io.write import write_ccddata
from astroalign_nd.simulate import draw_fluxes, simulate_image

POSIX = pytest.mark.skipif(os.name != "posix", reason="POSIX signals and fork")
WORKTREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SHAPE = (128, 128)
N_FRAMES = 12


@pytest.fixture(scope="module")
def night(tmp_path_factory):
    """A reference and 12 shifted frames (f00.fits ... f11.fits) of one star field."""
    folder = tmp_path_factory.mktemp("night")
    rng = np.random.default_rng(5)
    n = 250
    x, y = rng.uniform(0, 200, n), rng.uniform(0, 200, n)
    flux = draw_fluxes(n, flux_range=(2e3, 2e5), seed=6)

    def write(name, corner, seed):
        data = simulate_image(SHAPE, x - corner[0], y - corner[1], flux, seed=seed)
        path = str(folder / name)
        fits.PrimaryHDU(data.astype(np.float32), header=fits.Header({"BUNIT": "adu"})
                        ).writeto(path)
        return path

    ref = write("ref.fits", (36.0, 36.0), 1)
    paths = [write(f"f{k:02d}.fits", (36.0 + 0.7 * k - 4, 36.0 + 4 - 0.6 * k), 10 + k)
             for k in range(N_FRAMES)]
    return ref, paths


def _outputs(folder):
    """The FITS files in ``folder`` (hidden temporary files aside)."""
    return sorted(p for p in os.listdir(folder) if not p.startswith("."))


def _kill_self():
    os.kill(os.getpid(), signal.SIGKILL)


def _first_time(marker):
    """True the first time it is called with ``marker`` (a file), in any process."""
    try:
        os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


# -- a worker that dies (the out-of-memory killer) -------------------------------------------


@POSIX
def test_a_killed_worker_does_not_end_the_batch(tmp_path, night):
    """SIGKILL to a worker from outside: its frames are retried, every frame is registered."""
    ref, paths = night
    out = tmp_path / "out"
    killed = []

    def kill_a_worker(res):
        if not killed:
            workers = multiprocessing.active_children()
            assert workers
            os.kill(workers[0].pid, signal.SIGKILL)
            killed.append(workers[0].pid)

    result = register_batch(paths, ref, output_dir=out, workers=2, callback=kill_a_worker)
    assert killed
    assert result.summary() == f"{N_FRAMES} of {N_FRAMES} frames registered"
    assert [f.status for f in result.frames] == ["registered"] * N_FRAMES
    assert _outputs(out) == sorted(os.path.basename(f.output) for f in result.frames)
    assert not multiprocessing.active_children()  # the pools are gone


@POSIX
def test_a_frame_that_kills_its_worker_fails_alone(tmp_path, night, monkeypatch):
    """
    f01 kills its worker once, just after writing its output: the retry
    recognises that complete output and reports the frame registered.
    f10 kills its worker whenever it runs: it alone fails, with the reason.
    """
    ref, paths = night
    out = tmp_path / "out"
    real_find, real_write = frame_mod.find_for_apply, FITSWriter.write

    def find(source, *args, **kwargs):
        if str(source).endswith("f10.fits"):
            _kill_self()
        return real_find(source, *args, **kwargs)

    def write(self, ccd, path, **kwargs):
        real_write(self, ccd, path, **kwargs)
        if path.endswith("f01_aligned.fits") and _first_time(str(tmp_path / "f01.died")):
            _kill_self()  # complete output, result never sent back

    # fork: the workers inherit these
    monkeypatch.setattr(frame_mod, "find_for_apply", find)
    monkeypatch.setattr(FITSWriter, "write", write)
    result = register_batch(paths, ref, output_dir=out, workers=2)
    assert result.summary().startswith(f"{N_FRAMES - 1} of {N_FRAMES} frames registered, "
                                       "1 failed\n  FAILED f10.fits: RuntimeError: a worker "
                                       "process died while registering this frame, also when "
                                       "it was retried alone")
    (bad,) = result.failed
    assert "SIGKILL" in bad.error and "out-of-memory" in bad.error
    assert (tmp_path / "f01.died").exists()
    assert result.frames[1].status == "registered"
    assert result.frames[1].quality["n_matches"] >= 10
    # the summary matches the files
    assert _outputs(out) == sorted(os.path.basename(f.output) for f in result.frames if f.ok)
    assert not multiprocessing.active_children()


def test_a_retry_recognises_only_its_own_output(tmp_path, night, monkeypatch):
    """
    At the ``_run`` level: a retry (same job, after the first attempt
    wrote) reports its output registered; an output from before the batch
    still refuses the frame, and the output is deterministic.
    """
    import astroalign_nd.batch.runners as runners
    from astroalign_nd.batch.frame import _Job, _run
    from astroalign_nd.batch.runners import _queued

    ref, paths = night
    out = tmp_path / "out"
    first = register_batch(paths[:1], ref, output_dir=out)
    output = first.frames[0].output
    job_id = fits.getval(output, "AABATCH")
    # an output of an earlier run is not this batch's: refused as before
    again = register_batch(paths[:1], ref, output_dir=out)
    assert "FileExistsError" in again.frames[0].error
    # same inputs, same header: the batch identity is a digest, not a random run id
    other = register_batch(paths[:1], ref, output_dir=tmp_path / "other")
    assert fits.getval(other.frames[0].output, "AABATCH") == job_id

    # the configuration of a batch, to run one of its jobs by hand
    captured = {}

    def spy(job, cfg):
        captured["cfg"] = cfg
        return _run(job, cfg)

    monkeypatch.setattr(runners, "_run", spy)
    register_batch(paths[1:2], ref, output_dir=tmp_path / "retry")
    monkeypatch.undo()
    cfg = captured["cfg"]
    target = str(tmp_path / "retry2" / "f01_aligned.fits")
    os.makedirs(os.path.dirname(target))
    job = _Job(0, paths[1], "f01.fits", target)
    _queued(job, None)  # sent out: nothing there yet
    res1 = _run(job, cfg)
    res2 = _run(job, cfg)  # the retry finds the first attempt's output
    assert (res1.status, res2.status) == ("registered", "registered"), res2.error
    assert np.allclose(res1.transform.matrix, res2.transform.matrix, atol=1e-9)
    # a file that was there when the frame was sent out is not the retry's own
    job = _Job(0, paths[1], "f01.fits", target)
    _queued(job, None)
    assert "FileExistsError" in _run(job, cfg).error
    # nor a registered frame written there since by someone else
    os.remove(target)
    job = _Job(0, paths[1], "f01.fits", target)
    _queued(job, None)
    write_ccddata(register_batch(paths[1:2], ref).frames[0].ccd, target)
    assert "FileExistsError" in _run(job, cfg).error


# -- SIGTERM and SIGINT on the command line --------------------------------------------------

_SLOW_CLI = textwrap.dedent("""
    import signal, sys, time
    import astroalign_nd.batch.frame as frame

    # As a terminal runs the command: Ctrl-C raises KeyboardInterrupt, also when the test
    # runs as a background job (the shell then leaves SIGINT ignored for its children,
    # and the command keeps an ignored SIGINT ignored, as under nohup).
    signal.signal(signal.SIGINT, signal.default_int_handler)

    real = frame.find_for_apply

    def slow(*args, **kwargs):  # a long night: the signal comes mid-batch
        time.sleep(0.4)
        return real(*args, **kwargs)

    frame.find_for_apply = slow  # the forked workers inherit it
    from astroalign_nd.cli.main import main

    sys.exit(main(sys.argv[1:]))
""")


def _reader(stream):
    """Lines of ``stream`` as a queue (None at EOF): reads never block the test."""
    lines = queue.Queue()

    def read():
        for line in iter(stream.readline, b""):
            lines.put(line.decode())
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    return lines


def _alive(pids):
    import psutil

    alive = []
    for pid in pids:
        try:
            if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                alive.append(pid)
        except psutil.NoSuchProcess:
            pass
    return alive


@POSIX
@pytest.mark.parametrize("signame, code, group", [("SIGTERM", 143, False),
                                                  ("SIGINT", 130, True)])
def test_signal_stops_the_workers_and_writes_the_summary(tmp_path, night, signame, code,
                                                         group):
    """
    SIGTERM to the main process (a scheduler, ``timeout``), or SIGINT to the
    whole process group (Ctrl-C): no process outlives the command, stdout
    closes (``| tee`` ends), the summary lists what was done, the exit code
    is 128 + the signal.
    """
    psutil = pytest.importorskip("psutil")
    ref, paths = night
    out, summary = tmp_path / "out", tmp_path / "night.ecsv"
    env = dict(os.environ, PYTHONPATH=WORKTREE + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen(
        [sys.executable, "-c", _SLOW_CLI, "batch", *paths, "-r", ref, "--output-dir", str(out),
         "--workers", "2", "--summary", str(summary), "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, start_new_session=True)
    children = []
    try:
        lines = _reader(proc.stdout)
        line = lines.get(timeout=60)
        assert line is not None and line.startswith("[1/12]"), line
        children = [c.pid for c in psutil.Process(proc.pid).children(recursive=True)]
        assert len(children) >= 2  # the two workers
        if group:
            os.killpg(proc.pid, getattr(signal, signame))
        else:
            os.kill(proc.pid, getattr(signal, signame))
        rest = []
        deadline = time.monotonic() + 20
        while True:  # stdout reaches EOF: no worker holds it open
            line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            if line is None:
                break
            rest.append(line)
        assert proc.wait(timeout=20) == code
        err = proc.stderr.read().decode()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
        for pid in _alive(children):  # orphans of a failed test must not linger
            os.kill(pid, signal.SIGKILL)
        proc.stdout.close()
        proc.stderr.close()
    assert not _alive(children)
    assert f"interrupted ({signame})" in err
    assert "Traceback" not in err, err
    table = Table.read(summary)
    assert len(table) == N_FRAMES
    done = sorted(os.path.basename(o) for o, ok in zip(table["output"], table["ok"]) if ok)
    assert 1 <= len(done) < N_FRAMES
    assert _outputs(out) == done  # the summary matches the files
    assert all(e.startswith(f"Interrupted: not done: the batch was stopped ({signame})")
               for e, ok in zip(table["error"], table["ok"]) if not ok)
    assert any(f"of {N_FRAMES} frames registered" in r for r in rest)
    time.sleep(1.0)
    assert _outputs(out) == done  # and no one writes on
    assert not [p for p in os.listdir(out) if p.startswith(".")]  # no temporary left


# -- dask retries ----------------------------------------------------------------------------

_DIE_AFTER_WRITE = """
import os, signal
from astroalign_nd.io.writers import FITSWriter

_real = FITSWriter.write

def _write(self, ccd, path, **kwargs):
    _real(self, ccd, path, **kwargs)
    if path.endswith({name!r}):
        try:
            os.close(os.open({marker!r}, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return
        os.kill(os.getpid(), signal.SIGKILL)  # the output is complete; the result is lost

FITSWriter.write = _write
"""


@POSIX
def test_dask_retry_after_a_worker_dies_recognises_its_output(tmp_path, night):
    """A dask worker process killed (SIGKILL) right after writing a frame: the retried task
    finds that complete output and reports the frame registered."""
    distributed = pytest.importorskip("dask.distributed")
    ref, paths = night
    paths = paths[:4]
    out = tmp_path / "out"
    marker = str(tmp_path / "died")
    # ":0": any free port (None means dask's 8787, which another cluster may hold)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0", silence_logs=50) as cluster:
        with distributed.Client(cluster) as client:
            # own globals: exec in a function would keep the names local to that call
            client.run(exec, _DIE_AFTER_WRITE.format(name="f02_aligned.fits", marker=marker), {})
            result = register_batch(paths, ref, output_dir=out, client=client)
    assert os.path.exists(marker)  # a worker did die
    assert result.summary() == f"{len(paths)} of {len(paths)} frames registered"
    assert _outputs(out) == sorted(os.path.basename(f.output) for f in result.frames)
