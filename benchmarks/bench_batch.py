"""
Throughput and memory of a night of frames.

A simulated night: one reference and N frames of 2048x2048 (the same star
field, each frame turned by up to 1.5 degrees and shifted by up to 40 px),
written as FITS files in a temporary folder.  Each configuration runs in a
fresh child process, on the same files:

* ``astroalign_nd``: ``register_batch(paths, reference, output_dir=...)``
  with 1 process, and with ``workers=2`` local processes;
* ``astroalign``: a loop of ``fits.getdata`` -> ``astroalign.register`` ->
  ``fits.writeto`` over the same files, in 1 process and in a pool of 2.

Reported: frames per second (wall clock, reading and writing included), the
ratio against astroalign in the same configuration, the worst transform
error against the truth, and the peak resident memory (``ru_maxrss``) of the
main process and of the largest worker for 10 and for N frames.

Usage::

    python benchmarks/bench_batch.py             # 50 frames (~3 min on 2 cores)
    python benchmarks/bench_batch.py --frames 20 # fewer
"""

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

warnings.filterwarnings("ignore")

SIZE = 2048
N_STARS = 1500


def make_night(folder, n, seed=0):
    """Write ref.fits and frame_000.fits...; return their paths and true matrices."""
    from astropy.io import fits

    from astroalign_nd.simulate import draw_fluxes, simulate_image

    rng = np.random.default_rng(seed)
    pad = 150
    area = (SIZE + 2 * pad) ** 2 / SIZE**2
    m = int(N_STARS * area)
    sx, sy = rng.uniform(-pad, SIZE + pad, m), rng.uniform(-pad, SIZE + pad, m)
    flux = draw_fluxes(m, seed=seed + 1)
    c = (SIZE - 1) / 2.0

    def frame(k, rot_deg, dx, dy):
        # frame pixel = R (sky - c) + c + shift; the truth maps frame -> reference (= sky)
        a = np.radians(rot_deg)
        r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        xy = (np.column_stack([sx, sy]) - c) @ r.T + c + [dx, dy]
        img = simulate_image((SIZE, SIZE), xy[:, 0], xy[:, 1], flux, seed=seed + 10 + k)
        fwd = np.eye(3)
        fwd[:2, :2] = r
        fwd[:2, 2] = c + np.array([dx, dy]) - r @ [c, c]
        return img, np.linalg.inv(fwd)

    paths, truths = [], []
    img, _ = frame(-1, 0.0, 0.0, 0.0)
    ref = os.path.join(folder, "ref.fits")
    fits.PrimaryHDU(img, header=fits.Header({"BUNIT": "adu"})).writeto(ref)
    for k in range(n):
        img, truth = frame(k, rng.uniform(-1.5, 1.5), *rng.uniform(-40, 40, 2))
        p = os.path.join(folder, f"frame_{k:03d}.fits")
        fits.PrimaryHDU(img, header=fits.Header({"BUNIT": "adu"})).writeto(p)
        paths.append(p)
        truths.append(truth)
    return ref, paths, truths


def frame_error(matrix, truth):
    """Max over a grid of frame pixels of |T(p) - T_true(p)| (reference pixels)."""
    g = np.linspace(0, SIZE - 1, 9)
    xx, yy = np.meshgrid(g, g)
    p = np.column_stack([xx.ravel(), yy.ravel(), np.ones(xx.size)])
    return float(np.max(np.hypot(*((p @ matrix.T - p @ truth.T)[:, :2]).T)))


# -- child processes: one configuration each -------------------------------------------------


def _aa_one(args):
    import astroalign
    from astropy.io import fits

    src, ref_path, out = args
    ref = _aa_one.ref if getattr(_aa_one, "path", None) == ref_path else None
    if ref is None:
        ref = _aa_one.ref = fits.getdata(ref_path).astype(np.float32)
        _aa_one.path = ref_path
    data = fits.getdata(src).astype(np.float32)  # native byte order, as sep needs
    try:
        t, _ = astroalign.find_transform(data, ref)
        reg, footprint = astroalign.apply_transform(t, data, ref)
    except Exception as exc:  # noqa: BLE001 - count as failed
        print(f"astroalign failed on {src}: {exc}", file=sys.stderr)
        return None
    fits.writeto(out, reg.astype(np.float32), overwrite=True)
    return np.array(t.params)


def run_astroalign(ref, paths, out_dir, workers):
    # find_transform + apply_transform is astroalign.register, keeping the matrix for scoring
    jobs = [(p, ref, os.path.join(out_dir, os.path.basename(p))) for p in paths]
    if workers == 1:
        return [_aa_one(j) for j in jobs]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
        return list(pool.map(_aa_one, jobs))


def run_nd(ref, paths, out_dir, workers):
    import astroalign_nd

    result = astroalign_nd.register_batch(paths, ref, output_dir=out_dir,
                                          workers=workers if workers > 1 else None)
    return [f.transform.matrix if f.ok else None for f in result.frames]


def child(tool, ref, paths_file, workers):
    with open(paths_file) as fh:
        paths = json.load(fh)
    import astroalign  # noqa: F401 - imports outside the timing
    import astroalign_nd
    from astroalign_nd import batch  # noqa: F401

    astroalign_nd.find_sources  # noqa: B018 - resolve the lazy import
    out_dir = tempfile.mkdtemp(dir=os.path.dirname(ref), prefix=f"out_{tool}_")
    fn = run_nd if tool == "nd" else run_astroalign
    t0 = time.perf_counter()
    mats = fn(ref, paths, out_dir, workers)
    elapsed = time.perf_counter() - t0
    n_files = len(os.listdir(out_dir))
    shutil.rmtree(out_dir)
    self_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    kids_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    print(json.dumps(dict(elapsed=elapsed, n_files=n_files, self_mb=self_kb / 1024,
                          worker_mb=kids_kb / 1024,
                          mats=[None if m is None else np.asarray(m).tolist() for m in mats])))


def run_child(tool, ref, paths, workers, folder):
    pf = os.path.join(folder, f"paths_{len(paths)}.json")
    with open(pf, "w") as fh:
        json.dump(paths, fh)
    env = dict(os.environ)
    env.pop("ASTROALIGN_ND_NUM_THREADS", None)
    r = subprocess.run([sys.executable, __file__, "--child", tool, ref, pf, str(workers)],
                       capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-3000:])
    return json.loads(r.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        tool, ref, pf, workers = args.child
        child(tool, ref, pf, int(workers))
        return

    import astroalign
    import astroalign_nd

    n = args.frames
    folder = tempfile.mkdtemp(prefix="bench_batch_")
    try:
        t0 = time.perf_counter()
        ref, paths, truths = make_night(folder, n)
        print(f"astroalign_nd {astroalign_nd.__version__}, astroalign {astroalign.__version__}; "
              f"{os.cpu_count()} CPUs")
        print(f"{n} frames of {SIZE}x{SIZE} float32 ({N_STARS} stars in the frame), simulated "
              f"and written in {time.perf_counter() - t0:.0f} s")
        print("load average before the timings: %.2f %.2f %.2f\n" % os.getloadavg())
        rows = {}
        # interleaved so that machine load affects both tools alike
        for workers in (1, 2):
            for tool in ("astroalign", "nd"):
                res = run_child(tool, ref, paths, workers, folder)
                errs = [frame_error(np.asarray(m), t) for m, t in zip(res["mats"], truths)
                        if m is not None]
                res["n_ok"] = len(errs)
                res["max_err"] = max(errs) if errs else np.nan
                res["median_err"] = float(np.median(errs)) if errs else np.nan
                rows[tool, workers] = res
                print(f"  done: {tool:10s} workers={workers}: {res['elapsed']:.1f} s", flush=True)
        print("load average after the timings: %.2f %.2f %.2f" % os.getloadavg())
        print(f"\nThroughput, {n} frames (read FITS, register, write FITS; wall clock)")
        print(f"{'tool':14s} {'workers':>7s} {'seconds':>8s} {'frames/s':>9s} {'vs aa':>6s} "
              f"{'ok':>5s} {'files':>5s} {'median err':>10s} {'max err':>8s}")
        for workers in (1, 2):
            for tool in ("astroalign", "nd"):
                r = rows[tool, workers]
                fps = n / r["elapsed"]
                ratio = fps / (n / rows["astroalign", workers]["elapsed"])
                name = "astroalign_nd" if tool == "nd" else "astroalign"
                print(f"{name:14s} {workers:7d} {r['elapsed']:8.1f} {fps:9.2f} {ratio:5.2f}x "
                      f"{r['n_ok']:5d} {r['n_files']:5d} {r['median_err']:8.3f}px "
                      f"{r['max_err']:6.3f}px")

        print("\nPeak resident memory (ru_maxrss), 1 process unless noted")
        print(f"{'tool':14s} {'frames':>6s} {'main MB':>8s} {'worker MB':>9s}")
        mem = {}
        for m in sorted({min(10, n), n}):
            for tool in ("astroalign", "nd"):
                if m == n:
                    r = rows[tool, 1]
                else:
                    r = run_child(tool, ref, paths[:m], 1, folder)
                mem[tool, m] = r
                name = "astroalign_nd" if tool == "nd" else "astroalign"
                print(f"{name:14s} {m:6d} {r['self_mb']:8.0f} {'-':>9s}")
        for tool in ("astroalign", "nd"):
            r = rows[tool, 2]
            name = "astroalign_nd" if tool == "nd" else "astroalign"
            print(f"{name:14s} {n:6d} {r['self_mb']:8.0f} {r['worker_mb']:9.0f}  (2 workers)")
        if n > 10:
            for tool in ("astroalign", "nd"):
                grow = mem[tool, n]["self_mb"] - mem[tool, 10]["self_mb"]
                name = "astroalign_nd" if tool == "nd" else "astroalign"
                print(f"{name} memory growth from 10 to {n} frames: {grow:+.0f} MB "
                      f"({grow / (n - 10):+.2f} MB per frame)")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
