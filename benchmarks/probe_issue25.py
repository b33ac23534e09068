"""
Issue 25's twelve failure cases, run against one or more source trees.

Each case runs in a fresh process with ``PYTHONPATH`` set to the tree, through
the public API and the command line only (names that exist before and after
the package's re-layout), and prints one line: the case, the tree, ``good`` or
``BAD``, and what a user sees.  Run it against the code before the fixes and
after them to compare::

    git worktree add /tmp/old d1d808a --detach   # plus the built extension
    python benchmarks/probe_issue25.py --tree /tmp/old --tree .

Usage::

    python benchmarks/probe_issue25.py [--tree DIR ...] [--case N ...]

The signal and worker cases need POSIX (fork, SIGKILL, SIGTERM); case 5
needs dask.distributed.  Case 10 takes about 40 s on the old code.
"""

import argparse
import contextlib
import io
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# -- helpers (run inside the probed tree's process) -------------------------------------------


def _cli(*args, cwd=None, timeout=300):
    proc = subprocess.run([sys.executable, "-m", "astroalign_nd.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=timeout,
                          env=os.environ)
    return proc.returncode, proc.stdout, proc.stderr


def _last(text):
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1].strip() if lines else ""


def _pair(folder, shape=(128, 128)):
    from astropy.nddata import CCDData

    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair(shape, n_stars=60, rotation=10.0, seed=3)
    src, dst = os.path.join(folder, "s.fits"), os.path.join(folder, "t.fits")
    CCDData(pair.source.astype(np.float32), unit="adu").write(src)
    CCDData(pair.target.astype(np.float32), unit="adu").write(dst)
    return src, dst


def _night(folder, n_frames=12):
    from astropy.io import fits

    from astroalign_nd.simulate import draw_fluxes, simulate_image

    rng = np.random.default_rng(5)
    n = 250
    x, y = rng.uniform(0, 200, n), rng.uniform(0, 200, n)
    flux = draw_fluxes(n, flux_range=(2e3, 2e5), seed=6)

    def write(name, corner, seed):
        data = simulate_image((128, 128), x - corner[0], y - corner[1], flux, seed=seed)
        path = os.path.join(folder, name)
        fits.PrimaryHDU(data.astype(np.float32),
                        header=fits.Header({"BUNIT": "adu"})).writeto(path)
        return path

    ref = write("ref.fits", (36.0, 36.0), 1)
    paths = [write(f"f{k:02d}.fits", (32.0 + 0.7 * k, 40.0 - 0.6 * k), 10 + k)
             for k in range(n_frames)]
    return ref, paths


def _hidden(folder):
    return [p for p in os.listdir(folder) if p.startswith(".")]


def _visible(folder):
    return sorted(p for p in os.listdir(folder) if not p.startswith("."))


# -- the cases ---------------------------------------------------------------------------------


def case1(tmp):
    """A temporary file swapped for a link while 10 frames of 1000x1000 are written."""
    from astropy.nddata import CCDData

    from astroalign_nd.io.write import write_ccddata

    folder = os.path.join(tmp, "shared")
    os.mkdir(folder)
    bait = os.path.join(tmp, "attacker.txt")
    with open(bait, "wb") as f:
        f.write(b"attacker")
    stop, swaps = threading.Event(), [0]

    def attack():
        n = 0
        while not stop.is_set():
            for name in os.listdir(folder):
                if "aat-tmp" not in name or name.endswith(".moved"):
                    continue
                path = os.path.join(folder, name)
                n += 1
                try:
                    if os.path.isdir(path) and not os.path.islink(path):
                        os.rename(path, f"{path}.{n}.moved")
                        os.mkdir(path)
                        for inner in ("part.fits", "part"):
                            os.symlink(bait, os.path.join(path, inner))
                    elif not os.path.islink(path):
                        os.unlink(path)
                        os.symlink(bait, path)
                    swaps[0] += 1
                except OSError:
                    pass

    thread = threading.Thread(target=attack, daemon=True)
    thread.start()
    data = np.arange(1000 * 1000, dtype=np.float32).reshape(1000, 1000)
    written = refused = links = 0
    errors = set()
    try:
        for i in range(10):
            out = os.path.join(folder, f"frame{i}.fits")
            try:
                write_ccddata(CCDData(data, unit="adu"), out)
                written += 1
            except OSError as exc:
                refused += 1
                errors.add(f"{type(exc).__name__}: {exc}"[:90])
            links += os.path.islink(out)
    finally:
        stop.set()
        thread.join(10)
    with open(bait, "rb") as f:
        hijacked = f.read() != b"attacker"
    good = not hijacked and links == 0 and swaps[0] > 0
    return good, (f"{swaps[0]} swaps; {written} written, {refused} refused, {links} outputs "
                  f"are links, attacker's file {'WRITTEN INTO' if hijacked else 'untouched'}"
                  + (f"; e.g. {sorted(errors)[0]}" if errors else ""))


def case2(tmp):
    """register s.fits t.fits -o t.fits --overwrite."""
    src, dst = _pair(tmp)
    before = open(dst, "rb").read()
    code, _, err = _cli("register", src, dst, "-o", dst, "--overwrite")
    kept = open(dst, "rb").read() == before
    return kept and code == 2, f"exit {code}; target {'kept' if kept else 'REPLACED'}; " \
                               f"stderr: {_last(err)[:150]!r}"


def case3(tmp):
    """--workers 2, one worker SIGKILLed from outside after the first frame."""
    import multiprocessing

    from astroalign_nd import register_batch

    ref, paths = _night(tmp)
    out = os.path.join(tmp, "out")
    killed = []

    def kill_one(res):
        if not killed:
            workers = multiprocessing.active_children()
            os.kill(workers[0].pid, signal.SIGKILL)
            killed.append(workers[0].pid)

    result = register_batch(paths, ref, output_dir=out, workers=2, callback=kill_one)
    ok_files = sorted(os.path.basename(f.output) for f in result.frames if f.ok)
    matches = _visible(out) == ok_files
    first = result.summary().splitlines()[0]
    good = first == "12 of 12 frames registered" and matches and not _hidden(out)
    return good, (f"{first!r}; summary {'matches' if matches else 'DOES NOT match'} the files; "
                  f"{len(_hidden(out))} temp files left; "
                  f"{len(multiprocessing.active_children())} workers left")


_SLOW_CLI = """
import sys, time
try:
    import astroalign_nd.batch.frame as mod
    name = "find_for_apply"
except ImportError:
    import astroalign_nd.batch as mod
    name = "_find_for_apply"
real = getattr(mod, name)

def slow(*args, **kwargs):  # a long night: the signal comes mid-batch
    time.sleep(0.4)
    return real(*args, **kwargs)

setattr(mod, name, slow)  # the forked workers inherit it
try:
    from astroalign_nd.cli.main import main
except ImportError:
    from astroalign_nd.cli import main
sys.exit(main(sys.argv[1:]))
"""


def _alive(pids):
    alive = []
    for pid in pids:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().split(")")[-1].split()[0] != "Z":
                    alive.append(pid)
        except OSError:
            pass
    return alive


def _children(pid):
    kids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    if int(f.read().split(")")[-1].split()[1]) == pid:
                        kids.append(int(entry))
            except OSError:
                pass
    return kids


def case4(tmp):
    """SIGTERM to `batch --workers 2` (stdout a pipe, as with | tee) after the first frame."""
    import queue

    ref, paths = _night(tmp)
    out, summary = os.path.join(tmp, "out"), os.path.join(tmp, "night.ecsv")
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_CLI, "batch", *paths, "-r", ref,
                             "--output-dir", out, "--workers", "2", "--summary", summary,
                             "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    lines = queue.Queue()
    threading.Thread(target=lambda: [lines.put(ln) for ln in iter(proc.stdout.readline, b"")]
                     + [lines.put(None)], daemon=True).start()
    kids = []
    try:
        lines.get(timeout=60)
        kids = _children(proc.pid)
        t0 = time.monotonic()
        os.kill(proc.pid, signal.SIGTERM)
        eof = None
        while eof is None and time.monotonic() - t0 < 15:
            try:
                if lines.get(timeout=0.5) is None:
                    eof = time.monotonic() - t0
            except queue.Empty:
                pass
        code = proc.wait(timeout=10)
        time.sleep(1.0)
        alive = _alive(kids)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        for pid in _alive(kids):  # orphans hold stderr open: end them before reading it
            os.kill(pid, signal.SIGKILL)
        proc.wait()
    err = proc.stderr.read().decode()
    n_out = len(_visible(out)) if os.path.isdir(out) else 0
    recorded = "no summary file"
    if os.path.exists(summary):
        from astropy.table import Table

        table = Table.read(summary)
        recorded = f"summary: {int(np.sum(table['ok']))} ok of {len(table)} rows"
    good = code == 143 and not alive and eof is not None and recorded.startswith("summary")
    return good, (f"exit {code}; {len(alive)} of {len(kids)} workers alive 1 s later; stdout "
                  + (f"closed after {eof:.1f} s" if eof is not None else "STILL OPEN after 15 s")
                  + f"; {n_out} outputs, {recorded}; stderr: {_last(err)[:80]!r}")


_DIE_AFTER_WRITE = """
import os, signal
try:
    from astroalign_nd.io.writers import FITSWriter as owner
    attr = "write"
except ImportError:
    import astroalign_nd.batch as owner
    attr = "write_ccddata"
_real = getattr(owner, attr)

def _write(*args, **kwargs):
    _real(*args, **kwargs)
    path = str(args[-1] if attr == "write_ccddata" else args[2])
    if path.endswith({name!r}):
        try:
            os.close(os.open({marker!r}, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return
        os.kill(os.getpid(), signal.SIGKILL)  # the output is complete; the result is lost

setattr(owner, attr, _write)
"""


def case5(tmp):
    """A dask worker SIGKILLed right after writing f02's output; dask retries the task."""
    try:
        import dask.distributed as distributed
    except ImportError:
        return True, "skipped: no dask.distributed"
    from astroalign_nd import register_batch

    ref, paths = _night(tmp, 4)
    out, marker = os.path.join(tmp, "out"), os.path.join(tmp, "died")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None, silence_logs=50) as cluster:
        with distributed.Client(cluster) as client:
            client.run(exec, _DIE_AFTER_WRITE.format(name="f02_aligned.fits", marker=marker), {})
            result = register_batch(paths, ref, output_dir=out, client=client)
    text = result.summary().replace("\n", " | ")
    good = os.path.exists(marker) and result.summary() == "4 of 4 frames registered"
    return good, f"{text[:160]!r}; {len(_visible(out))} outputs on disk"


def case6(tmp):
    """An RA---TAN-SIP source registered onto a target without WCS (a known similarity)."""
    from astropy.nddata import CCDData
    from astropy.wcs import WCS, Sip

    from astroalign_nd import SimilarityTransform, apply_transform

    ny, nx = 300, 400
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN-SIP", "DEC--TAN-SIP"]
    w.wcs.crval, w.wcs.crpix = [150.0, 2.0], [180.0, 140.0]
    w.wcs.cd = np.array([[-1.0, 0.05], [0.03, 1.0]]) / 3600.0
    a, b = np.zeros((4, 4)), np.zeros((4, 4))
    a[2, 0], a[1, 1], a[0, 2], a[3, 0] = 2e-5, -1e-5, 3e-6, 1e-8
    b[0, 2], b[2, 1], b[1, 1] = 2e-5, -1e-8, 5e-6
    w.sip = Sip(a, b, None, None, w.wcs.crpix)
    w.pixel_shape = (nx, ny)
    t = SimilarityTransform(rotation=12.0, scale=1.03, translation_x=15.0, translation_y=-8.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = apply_transform(t, CCDData(np.zeros((ny, nx)), unit="adu", wcs=w),
                              np.zeros((ny, nx)))
    yy, xx = np.mgrid[0:ny:20j, 0:nx:20j]
    q = np.column_stack([xx.ravel(), yy.ravel()])
    p = np.column_stack(t.inverse(q[:, 0], q[:, 1]))
    s1, s2 = w.all_pix2world(p, 0), out.wcs.all_pix2world(q, 0)
    d = np.hypot((s1[:, 0] - s2[:, 0]) * np.cos(np.radians(s1[:, 1])), s1[:, 1] - s2[:, 1])
    err = float(d.max() * 3600.0)
    return err < 0.01, (f"output ctype {out.wcs.wcs.ctype[0]}, sky error {err:.2g} px, "
                        f"{len(caught)} warnings")


def case7(tmp):
    """An all-NaN StdDevUncertainty on a good source frame."""
    from astropy.nddata import CCDData, StdDevUncertainty

    from astroalign_nd import apply_transform, find_transform
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((256, 256), n_stars=150, rotation=20.0, seed=2)
    s = pair.source.astype(np.float32)
    t, _ = find_transform(s, pair.target)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = apply_transform(t, CCDData(s, unit="adu",
                                         uncertainty=StdDevUncertainty(np.full_like(s, np.nan))),
                              pair.target)
    plain = apply_transform(t, CCDData(s, unit="adu"), pair.target)
    nan = float(np.isnan(out.data).mean())
    same = np.array_equal(out.data, plain.data, equal_nan=True)
    msgs = [str(c.message)[:90] for c in caught]
    return same, (f"data {100 * nan:.0f}% NaN (without uncertainty "
                  f"{100 * float(np.isnan(plain.data).mean()):.0f}%), "
                  f"masked {100 * float(out.mask.mean()):.0f}%; warnings: {msgs}")


def case8(tmp):
    """register -o with a 200-character output name."""
    src, dst = _pair(tmp)
    out = os.path.join(tmp, "n" * 195 + ".fits")
    code, _, err = _cli("register", src, dst, "-o", out)
    there = os.path.exists(out)
    return code == 0 and there, (f"exit {code}; output {'written' if there else 'MISSING'}; "
                                 f"{len(_hidden(tmp))} temp left"
                                 + (f"; stderr: {_last(err)[:120]!r}" if code else ""))


def case9(tmp):
    """A FITS file cut in half: register() and a batch."""
    from astropy.nddata import CCDData

    from astroalign_nd import register, register_batch
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((256, 256), n_stars=150, rotation=20.0, seed=2)
    path = os.path.join(tmp, "cut.fits")
    CCDData(pair.source.astype(np.float32), unit="adu").write(path)
    raw = open(path, "rb").read()
    open(path, "wb").write(raw[: len(raw) // 2])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a user's default: astropy's warning is not the error
        try:
            register(path, pair.target)
            api = "no error"
        except Exception as exc:  # the point: which one
            api = f"{type(exc).__name__}: {exc}"
        res = register_batch([path], pair.target, output_dir=os.path.join(tmp, "out"))
    batch = res.frames[0].error or res.frames[0].status
    good = api.startswith("ValueError") and "cut.fits" in api and "cut.fits" in batch
    return good, f"API {api[:110]!r}; batch {batch[:80]!r}"


def case10(tmp):
    """register a CCDData whose meta has 20,000 keys."""
    from astropy.nddata import CCDData

    from astroalign_nd import register
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((256, 256), n_stars=150, rotation=20.0, seed=2)
    t0 = time.perf_counter()
    register(CCDData(pair.source, unit="adu"), pair.target)
    plain = time.perf_counter() - t0
    meta = {f"KEY{i:05d}": i for i in range(20000)}
    t0 = time.perf_counter()
    out = register(CCDData(pair.source, unit="adu", meta=meta), pair.target)
    large = time.perf_counter() - t0
    return large < 2.0, f"{large:.2f} s with 20,000 keys ({plain:.2f} s without), " \
                        f"{len(out.meta)} cards out"


def case11(tmp):
    """Big-endian float64 input against native: data, uncertainty and matrix."""
    from astropy.nddata import CCDData, StdDevUncertainty

    from astroalign_nd import find_transform, register
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((256, 256), n_stars=150, rotation=20.0, seed=2)
    s, t = pair.source.astype(np.float64), pair.target.astype(np.float64)
    std = np.sqrt(np.abs(s)) + 1.0
    a = register(CCDData(s, unit="adu", uncertainty=StdDevUncertainty(std)), t)
    b = register(CCDData(s.astype(">f8"), unit="adu",
                         uncertainty=StdDevUncertainty(std.astype(">f8"))), t.astype(">f8"))
    m1, _ = find_transform(s, t)
    m2, _ = find_transform(s.astype(">f8"), t.astype(">f8"))
    dd = float(np.nanmax(np.abs(a.data - b.data)))
    dm = float(np.max(np.abs(m1.matrix - m2.matrix)))
    same = (np.array_equal(a.data, b.data, equal_nan=True)
            and np.array_equal(a.uncertainty.array, b.uncertainty.array, equal_nan=True)
            and dm == 0.0)
    return same, f"{'bit-identical' if same else 'DIFFERENT'}: data max diff {dd:.2g}, " \
                 f"matrix max diff {dm:.2g}"


def case12(tmp):
    """An ASDF transform file edited to parity: 0 / parity: 5 / scale: [1, 2]."""
    import asdf

    from astroalign_nd import SimilarityTransform

    try:
        from astroalign_nd.io import read_transform
    except ImportError:
        read_transform = None
    seen = []
    for bad in ("parity: 0", "parity: 5", "scale: [1, 2]"):
        path = os.path.join(tmp, f"t{len(seen)}.asdf")
        asdf.AsdfFile({"transform": SimilarityTransform(scale=1.01, rotation=3.0)}
                      ).write_to(path)
        key = bad.split(":")[0]
        lines = open(path, "rb").read().decode("latin-1").split("\n")
        for i, line in enumerate(lines):
            if line.strip().startswith(f"{key}:"):
                lines[i] = line[: len(line) - len(line.lstrip())] + bad
                break
        open(path, "wb").write("\n".join(lines).encode("latin-1"))
        if read_transform is not None:
            try:
                got = type(read_transform(path)).__name__
            except ValueError as exc:
                got = f"ValueError: {exc}"
        else:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                with asdf.open(path) as af:
                    got = (f"asdf.open gives {type(af.tree['transform']).__name__}, "
                           f"{len(caught)} warnings")
        seen.append(f"{bad}: {got}")
    good = all("ValueError" in s for s in seen)
    how = "read_transform" if read_transform else "no read_transform;"
    return good, f"{how} " + " || ".join(s[:140] for s in seen)


def extras(tmp):
    """The temporary name's length for a 200-character output, read/write_transform."""
    from astroalign_nd.io.write import atomic_write

    name = os.path.join(tmp, "x" * 200 + ".fits")
    try:
        with atomic_write(name) as part:
            open(part, "wb").close()
            seen = f"temporary {part!r} ({len(os.path.basename(part))} chars)"
    except OSError as exc:
        seen = f"{type(exc).__name__}: {str(exc)[-60:]}"
    import astroalign_nd.io as aio
    has = all(hasattr(aio, n) for n in ("read_transform", "write_transform"))
    return "part" in seen and has, f"{seen}; io.read_transform/write_transform: " \
                                   f"{'yes' if has else 'missing'}"


CASES = {1: case1, 2: case2, 3: case3, 4: case4, 5: case5, 6: case6, 7: case7, 8: case8,
         9: case9, 10: case10, 11: case11, 12: case12, 13: extras}


def _one(n):
    with tempfile.TemporaryDirectory() as tmp:
        # the commands run here import the probed tree (PYTHONPATH), not one in the folder
        os.chdir(tmp)
        with contextlib.redirect_stderr(io.StringIO()):
            try:
                good, text = CASES[n](tmp)
            except Exception as exc:  # a probe reports, it does not stop
                good, text = False, f"probe error {type(exc).__name__}: {str(exc)[:200]}"
    print(json.dumps([bool(good), text]))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", action="append", help="source tree to probe (default: this one)")
    ap.add_argument("--case", type=int, action="append", help="case number (13: extras)")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        return _one(args.one)
    trees = args.tree or [HERE]
    for n in args.case or sorted(CASES):
        for tree in trees:
            env = dict(os.environ, PYTHONPATH=os.path.abspath(tree))
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, os.path.abspath(__file__), "--one", str(n)],
                                  capture_output=True, text=True, env=env, timeout=900)
            try:
                good, text = json.loads(proc.stdout.strip().splitlines()[-1])
            except (IndexError, ValueError):
                good, text = False, f"probe crashed: {_last(proc.stderr)[:200]}"
            label = "extras" if n == 13 else f"case {n:2d}"
            print(f"{label}  {os.path.basename(os.path.abspath(tree)):>8s}  "
                  f"{'good' if good else 'BAD ':4s}  ({time.perf_counter() - t0:5.1f} s)  {text}",
                  flush=True)


if __name__ == "__main__":
    main()
