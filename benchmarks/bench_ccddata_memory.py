"""
Added memory and time of full CCDData output against bare arrays (issue 16).

For a float32 star field (default 8192x8192, 3,000 stars) each case runs
in a fresh process: load the pair, build the input, warm the tool up on a
small pair, reset the peak resident set size, then time one
``register(source, target)`` and read the peak again.  "added" is the peak
during the call minus the resident size just before it: what the call
costs on top of the inputs it was given.

Cases:

- ``ndarray``: ``register(source_array, target_array)``;
- ``ccddata``: the source as a CCDData with a float32 `StdDevUncertainty`
  and a mask (a bad block and 0.1 % scattered bad pixels): the output has
  data, mask and uncertainty;
- ``astroalign``: ``astroalign.register`` on the arrays, for reference.

The cases alternate over ``--repeats`` rounds; medians are reported, and
the transform error of each output against the simulator's truth.

On a virtual machine whose host takes back the guest's free memory (free
page reporting, as on this project's machines) the first write to a page
the host took back costs a host fault: about 3 ms per MB here, against
about 0.1 ms for a page the guest kernel still holds.  Whether the call's
output pages are of one kind or the other depends on what the machine did
in the seconds before, so the fresh-process time mostly counts new pages
(1.85 times as many for CCDData, its uncertainty plane).  ``--prewarm MB``
touches and frees that much memory in each process just before the timed
call, so that both cases get pages the guest holds, as on a machine
without that reclaim.

Usage::

    python benchmarks/bench_ccddata_memory.py                  # 8192^2, 3 rounds
    python benchmarks/bench_ccddata_memory.py --size 4096 --repeats 5
    python benchmarks/bench_ccddata_memory.py --before /path/to/old/tree
    python benchmarks/bench_ccddata_memory.py --prewarm 1024
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_CHILD = r"""
import json, sys, time, warnings
warnings.filterwarnings("ignore")
import numpy as np
case, path = sys.argv[1], sys.argv[2]


def rss_mb(field):
    for line in open("/proc/self/status"):
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024


d = np.load(path)
src, dst, truth = d["source"], d["target"], d["truth"]
w_src, w_dst = d["warm_source"], d["warm_target"]
if case == "astroalign":
    import astroalign as mod
    mod.register(w_src, w_dst)
    inp = src
else:
    import astroalign_nd as mod
    from astropy.nddata import CCDData, StdDevUncertainty
    mod.register(w_src, w_dst)
    if case == "ccddata":
        mask = np.zeros(src.shape, bool)
        mask[10:20, 10:400] = True
        rng = np.random.default_rng(1)
        mask.flat[rng.choice(mask.size, mask.size // 1000, replace=False)] = True
        sigma = np.sqrt(np.abs(src) + np.float32(25.0)).astype(np.float32)
        inp = CCDData(src, unit="adu", mask=mask, uncertainty=StdDevUncertainty(sigma))
        # Warm the CCDData path too (its first call imports a little more).
        mod.register(CCDData(w_src, unit="adu", mask=np.zeros(w_src.shape, bool),
                             uncertainty=StdDevUncertainty(np.ones_like(w_src))), w_dst)
    else:
        inp = src
del w_src, w_dst, d
prewarm = int(sys.argv[3])
if prewarm:
    # Touch and free that much memory: the pages the call gets next are then
    # ones the guest kernel already holds (see --prewarm).
    np.ones(prewarm << 18, np.float32)
import ctypes, gc
gc.collect()
ctypes.CDLL("libc.so.6").malloc_trim(0)  # return freed heap to the OS, for every case
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")  # resets VmHWM to the current RSS
before = rss_mb("VmRSS")
t0 = time.perf_counter()
out = mod.register(inp, dst)
t = time.perf_counter() - t0
peak = rss_mb("VmHWM")
if case == "astroalign":
    m = mod.find_transform(src, dst)[0].params
    extra = ""
else:
    from astroalign_nd.io import transform_from_header
    m = transform_from_header(out.meta).matrix
    extra = dict(dtype=str(out.data.dtype), mask=out.mask is not None,
                 uncertainty=type(out.uncertainty).__name__,
                 unc_dtype=str(out.uncertainty.array.dtype) if out.uncertainty is not None
                 else "")
ny, nx = dst.shape
yy, xx = np.mgrid[0:ny:ny // 32, 0:nx:nx // 32]
p = np.column_stack([xx.ravel(), yy.ravel(), np.ones(xx.size)])
q = p @ np.linalg.inv(truth).T @ m.T
err = float(np.max(np.hypot(*(q[:, :2] - p[:, :2]).T)))
print(json.dumps(dict(before=before, added=peak - before, time=t, err=err, extra=extra,
                      file=mod.__file__)))
"""


def run(case, path, tree, prewarm=0):
    env = dict(os.environ, PYTHONPATH=tree)
    res = subprocess.run([sys.executable, "-c", _CHILD, case, path, str(prewarm)],
                         capture_output=True,
                         text=True, timeout=600, env=env, cwd=tree)
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        raise RuntimeError(f"{case} failed:\n{res.stderr[-2000:]}")
    return json.loads(lines[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=8192)
    ap.add_argument("--stars", type=int, default=3000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-astroalign", action="store_true")
    ap.add_argument("--before", default=None,
                    help="a source tree holding an older astroalign_nd, measured too")
    ap.add_argument("--prewarm", type=int, default=0, metavar="MB",
                    help="touch and free this many MB in each process just before the "
                         "timed call (e.g. 1024).  On a virtual machine whose host takes "
                         "back the guest's free memory (free page reporting), the first "
                         "write to such a page costs a host fault (here ~3 ms per MB, "
                         "against ~0.1 with the guest's own pages), so without it the time "
                         "of a fresh process mostly counts how many new pages it writes")
    args = ap.parse_args(argv)
    sys.path.insert(0, HERE)
    from astroalign_nd.simulate import simulate_pair

    n = args.size
    pair = simulate_pair((n, n), n_stars=args.stars, rotation=17.0, scale=1.01,
                         translation=(0.03 * n, -0.02 * n), noise="gaussian", seed=3)
    warm = simulate_pair((512, 512), n_stars=300, rotation=5.0, noise="gaussian", seed=4)
    src = np.asarray(pair.source, np.float32)
    dst = np.asarray(pair.target, np.float32)
    cases = [("ndarray", HERE), ("ccddata", HERE)]
    if args.before:
        tree = os.path.abspath(args.before)
        cases += [("ndarray", tree), ("ccddata", tree)]
    if not args.no_astroalign:
        cases.append(("astroalign", HERE))
    print(f"{n}x{n} float32, {args.stars} stars; {os.cpu_count()} CPUs; load average "
          f"{os.getloadavg()[0]:.1f}; {args.repeats} rounds; "
          f"input plane {src.nbytes / 2**20:.0f} MB; prewarm {args.prewarm} MB")
    res = {c: [] for c in cases}
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "pair.npz")
        np.savez(path, source=src, target=dst, truth=pair.truth_matrix,
                 warm_source=warm.source.astype(np.float32),
                 warm_target=warm.target.astype(np.float32))
        for r in range(args.repeats):
            for c in cases[r % len(cases):] + cases[:r % len(cases)]:
                res[c].append(run(c[0], path, c[1], args.prewarm))
    print(f"\n{'case':>10} {'tree':>8} {'added MB':>9} {'time s':>7} {'err px':>8}  output")
    med = {}
    for c in cases:
        rows = res[c]
        med[c] = dict(added=float(np.median([x["added"] for x in rows])),
                      time=float(np.median([x["time"] for x in rows])))
        tree = "" if c[0] == "astroalign" else ("after" if c[1] == HERE else "before")
        print(f"{c[0]:>10} {tree:>8} {med[c]['added']:>9.0f} {med[c]['time']:>7.3f} "
              f"{rows[0]['err']:>8.4f}  {rows[0]['extra']}")
    for tree, label in ((HERE, "after"),) + (((os.path.abspath(args.before), "before"),)
                                             if args.before else ()):
        if ("ccddata", tree) in med:
            a, b = med[("ndarray", tree)], med[("ccddata", tree)]
            print(f"{label}: CCDData/ndarray time {b['time'] / a['time']:.2f}, "
                  f"added memory {b['added'] / a['added']:.2f}")
    if ("astroalign", HERE) in med:
        aa = med[("astroalign", HERE)]
        for c in cases:
            if c[0] != "astroalign":
                print(f"{c[0]:>10} {'after' if c[1] == HERE else 'before'} / astroalign: "
                      f"time {med[c]['time'] / aa['time']:.3f}")
    print("raw:", json.dumps({f"{c[0]}@{'after' if c[1] == HERE else 'before'}": res[c]
                              for c in cases}))


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"({time.perf_counter() - t0:.0f} s)")
