# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
What does full CCDData output (mask and uncertainty) cost over bare arrays?

Four parts, each one command (``kernel`` when none is named).

``kernel``: time of the resampling step.
For square float32 images (default 1024 and 4096 pixels on a side) this
times, on the same simulated source and the true transform:

(a) ``astroalign_nd.apply_transform`` on an ndarray          -> data + mask
(b) ``astroalign_nd.apply_transform`` on a CCDData with a
    StdDevUncertainty                                        -> data + mask + uncertainty
(b+m) as (b) with an input mask (0.1 % bad pixels)           -> same, mask-checking path
(c) bare ``astroalign_nd.resample.resample(data, matrix, shape)``, no
    variance, no input mask (the compiled kernel alone)
(c+v) ``resample`` with the variance array (kernel cost of the variance)
(d) ``astroalign.apply_transform`` (scikit-image ``warp``, cubic spline)
    for reference

All astroalign_nd calls use bilinear interpolation (the default) and the
parallel kernel.  Each case gets one warm-up call, reported separately as
"first call" (the very first call of the process also pays for lazy
imports), then the median of ``--repeat`` timed calls.

``memory``: added memory and time of a whole ``register`` call.
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

``stages``: where the time goes, stage by stage.
On the star field of ``memory`` (default 8192x8192, 3,000 stars; the
CCDData source has a float32 `StdDevUncertainty` and a mask) each tree
(this one, and ``--before TREE``) runs in its own process, the trees
alternating over ``--rounds``; inside, every case is timed ``--repeat``
times round-robin after a warm-up:

- ``find nd`` / ``find ccd``: `find_transform` (detection and matching);
- ``apply nd`` / ``apply ccd``: `apply_transform` with the found transform;
- ``resample nd``: the bare kernel, data only;
- ``resample std+mask``: the kernel with the standard deviation and the mask.

Minimum and median per case and tree; ``register`` ratio = (find + apply)
CCDData over ndarray, from the minima (the least disturbed by other load).

``meta``: the time of ``register`` for a CCDData source whose ``meta``
holds 0 or ``--keys`` entries (integers, strings, or an astropy Header),
one simulated 256x256 pair, median of ``--repeat`` runs each, and the
output header's size (the cost of carrying a large header through).

Usage::

    PYTHONPATH=. python benchmarks/bench_ccddata.py kernel [--sizes 1024 4096] [--repeat 5]
    python benchmarks/bench_ccddata.py memory                  # 8192^2, 3 rounds
    python benchmarks/bench_ccddata.py memory --size 4096 --repeats 5
    python benchmarks/bench_ccddata.py memory --before /path/to/old/tree
    python benchmarks/bench_ccddata.py memory --prewarm 1024
    python benchmarks/bench_ccddata.py stages [--size 8192] [--before /path/to/old/tree]
    PYTHONPATH=. python benchmarks/bench_ccddata.py meta [--keys 20000] [--repeat 3]
"""

import argparse
import gc
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

#: The repository root: the tree measured in the fresh processes (``memory``, ``stages``).
HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _time_once(fn):
    gc.collect()
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _time_cases(cases, repeat):
    """First-call time, then ``repeat`` rounds over all cases (round-robin, so that
    a change of machine load hits every case alike); median and min per case."""
    first = [_time_once(fn) for _, fn in cases]
    times = [[] for _ in cases]
    for _ in range(repeat):
        for i, (_, fn) in enumerate(cases):
            times[i].append(_time_once(fn))
    return [(label, f, float(np.median(t)), float(np.min(t)))
            for (label, _), f, t in zip(cases, first, times)]


def bench_size(n, repeat):
    import astroalign
    from astropy.nddata import CCDData, StdDevUncertainty

    import astroalign_nd as aa
    from astroalign_nd.resample import resample
    from astroalign_nd.simulate import simulate_pair
    from astroalign_nd.transforms import to_skimage

    t0 = time.perf_counter()
    pair = simulate_pair((n, n), n_stars=int(1000 * (n / 1024) ** 2), rotation=17.0,
                         scale=1.02, translation=(12.3, -7.7), noise="gaussian", seed=1,
                         dtype=np.float32)
    t_sim = time.perf_counter() - t0
    src, tgt, t = pair.source, pair.target, pair.transform
    assert src.dtype == np.float32
    sigma = np.sqrt(np.maximum(src, 0.0) + 25.0).astype(np.float32)
    ccd = CCDData(src, unit="adu", uncertainty=StdDevUncertainty(sigma))
    rng = np.random.default_rng(0)
    bad = rng.random(src.shape) < 1e-3
    ccd_m = CCDData(src, unit="adu", uncertainty=StdDevUncertainty(sigma), mask=bad)
    var = sigma.astype(np.float32) ** 2
    sk = to_skimage(t)

    cases = [
        ("(a) apply_transform ndarray: data+mask", lambda: aa.apply_transform(t, src, tgt)),
        ("(b) apply_transform CCDData+StdDev: full",
         lambda: aa.apply_transform(t, ccd, tgt)),
        ("(b+m) as (b) + input mask (0.1% bad)", lambda: aa.apply_transform(t, ccd_m, tgt)),
        ("(c) resample(data) kernel only", lambda: resample(src, t.matrix, tgt.shape,
                                                            order="bilinear")),
        ("(c+v) resample(data, variance)", lambda: resample(src, t.matrix, tgt.shape,
                                                            order="bilinear", variance=var)),
        ("(d) astroalign.apply_transform", lambda: astroalign.apply_transform(sk, src, tgt)),
    ]
    return t_sim, _time_cases(cases, repeat)


def kernel(args):
    """The ``kernel`` part."""
    from astroalign_nd._kernels import num_threads

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"astroalign_nd threads {num_threads()}, "
          f"cpus {os.cpu_count()}, load average {load:.2f}; median (and min) of "
          f"{args.repeat} round-robin calls after one warm-up call\n")
    for n in args.sizes:
        t_sim, rows = bench_size(n, args.repeat)
        ref = {label[:4]: med for label, _, med, _ in rows}
        data_only = ref["(a) "]
        full = ref["(b) "]
        print(f"{n}x{n} float32 (simulate_pair, noise='gaussian': {t_sim:.2f} s)")
        print(f"  {'case':42s} {'first call':>11s} {'median':>9s} {'min':>9s} "
              f"{'Mpix/s':>7s} {'/ (a)':>6s}")
        for label, first, med, best in rows:
            print(f"  {label:42s} {first:10.3f}s {med:8.3f}s {best:8.3f}s "
                  f"{n * n / med / 1e6:7.1f} {med / data_only:6.2f}")
        print(f"  full CCDData / data-only = (b)/(a) = {full / data_only:.2f}; "
              f"(a)/(c) wrapper overhead = {data_only / ref['(c) ']:.2f}; "
              f"(b)/(d) vs astroalign = {full / ref['(d) ']:.2f}")
        best = {label[:4]: b for label, _, _, b in rows}
        print(f"  by min: (b)/(a) = {best['(b) '] / best['(a) ']:.2f}; "
              f"(a)/(c) = {best['(a) '] / best['(c) ']:.2f}; "
              f"(b)/(d) = {best['(b) '] / best['(d) ']:.2f}\n")


def field(n, n_stars):
    """The star field of ``memory`` and ``stages`` (this tree's simulator)."""
    sys.path.insert(0, HERE)
    from astroalign_nd.simulate import simulate_pair

    return simulate_pair((n, n), n_stars=n_stars, rotation=17.0, scale=1.01,
                         translation=(0.03 * n, -0.02 * n), noise="gaussian", seed=3)


# The masked CCDData both child scripts measure: a bad block and 0.1 % scattered bad
# pixels, a float32 standard deviation of a Poisson-like noise.
_MASKED_CCDDATA = r"""
def masked_ccddata(src):
    from astropy.nddata import CCDData, StdDevUncertainty
    mask = np.zeros(src.shape, bool)
    mask[10:20, 10:400] = True
    rng = np.random.default_rng(1)
    mask.flat[rng.choice(mask.size, mask.size // 1000, replace=False)] = True
    sigma = np.sqrt(np.abs(src) + np.float32(25.0)).astype(np.float32)
    return CCDData(src, unit="adu", mask=mask, uncertainty=StdDevUncertainty(sigma)), mask, sigma
"""

_MEMORY_CHILD = r"""
import json, sys, time, warnings
warnings.filterwarnings("ignore")
import numpy as np
""" + _MASKED_CCDDATA + r"""
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
        inp, _, _ = masked_ccddata(src)
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


def run_memory_child(case, path, tree, prewarm=0):
    env = dict(os.environ, PYTHONPATH=tree)
    res = subprocess.run([sys.executable, "-c", _MEMORY_CHILD, case, path, str(prewarm)],
                         capture_output=True,
                         text=True, timeout=600, env=env, cwd=tree)
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        raise RuntimeError(f"{case} failed:\n{res.stderr[-2000:]}")
    return json.loads(lines[-1])


def memory(args):
    """The ``memory`` part."""
    t0 = time.perf_counter()
    n = args.size
    pair = field(n, args.stars)
    from astroalign_nd.simulate import simulate_pair

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
                res[c].append(run_memory_child(c[0], path, c[1], args.prewarm))
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

    print(f"({time.perf_counter() - t0:.0f} s)")


_STAGES_CHILD = r"""
import json, sys, time, warnings
warnings.filterwarnings("ignore")
import numpy as np
""" + _MASKED_CCDDATA + r"""
import astroalign_nd as aa
from astroalign_nd.resample import resample
d = np.load(sys.argv[1])
src, dst = d["source"], d["target"]
repeat = int(sys.argv[2])
inp, mask, sigma = masked_ccddata(src)
t0 = aa.find_transform(src, dst)[0]
m = t0.matrix
cases = {
    "find nd": lambda: aa.find_transform(src, dst),
    "find ccd": lambda: aa.find_transform(inp, dst),
    "apply nd": lambda: aa.apply_transform(t0, src, dst),
    "apply ccd": lambda: aa.apply_transform(t0, inp, dst),
    "resample nd": lambda: resample(src, m, dst.shape),
    "resample std+mask": lambda: resample(src, m, dst.shape, variance=sigma, mask=mask,
                                          _variance_kind="stddev"),
}
for f in cases.values():
    f()
res = {k: [] for k in cases}
for _ in range(repeat):
    for k, f in cases.items():
        t = time.perf_counter()
        out = f()
        res[k].append(time.perf_counter() - t)
        del out
print(json.dumps(dict(times=res, file=aa.__file__)))
"""


def stages(args):
    """The ``stages`` part."""
    n = args.size
    pair = field(n, args.stars)
    trees = [("after", HERE)] + ([("before", os.path.abspath(args.before))]
                                 if args.before else [])
    print(f"{n}x{n} float32, {args.stars} stars; {os.cpu_count()} CPUs; load average "
          f"{os.getloadavg()[0]:.1f}; {args.rounds} rounds x {args.repeat} calls per tree")
    times = {label: {} for label, _ in trees}
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "pair.npz")
        np.savez(path, source=np.asarray(pair.source, np.float32),
                 target=np.asarray(pair.target, np.float32))
        for r in range(args.rounds):
            for label, tree in trees[r % len(trees):] + trees[:r % len(trees)]:
                res = subprocess.run([sys.executable, "-c", _STAGES_CHILD, path,
                                      str(args.repeat)],
                                     capture_output=True, text=True, timeout=900, cwd=tree,
                                     env=dict(os.environ, PYTHONPATH=tree))
                lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
                if not lines:
                    raise RuntimeError(f"{label} failed:\n{res.stderr[-2000:]}")
                for k, v in json.loads(lines[-1])["times"].items():
                    times[label].setdefault(k, []).extend(v)
    for label, _ in trees:
        t = times[label]
        print(f"\n{label}:")
        for k, v in t.items():
            print(f"  {k:18s} min {min(v):7.3f} s  median {np.median(v):7.3f} s")
        nd = min(t["find nd"]) + min(t["apply nd"])
        ccd = min(t["find ccd"]) + min(t["apply ccd"])
        print(f"  register (find + apply, minima): ndarray {nd:.3f} s, CCDData {ccd:.3f} s, "
              f"ratio {ccd / nd:.2f}")
    print("raw:", json.dumps(times))


def meta(args):
    """The ``meta`` part: ``register`` time with 0 or ``--keys`` entries in the meta."""
    from astropy.io import fits
    from astropy.nddata import CCDData

    from astroalign_nd import register
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((256, 256), n_stars=150, rotation=20.0, seed=2)
    n, repeat = args.keys, args.repeat
    metas = {"no meta": {}, f"{n} int keys": {f"KEY{i:05d}": i for i in range(n)},
             f"{n} str keys": {f"KEY{i:05d}": f"value {i}" for i in range(n)},
             f"{n}-card Header": fits.Header([(f"KEY{i:05d}", i) for i in range(n)])}
    for name, meta in metas.items():
        times = []
        for _ in range(repeat):
            src = CCDData(pair.source, unit="adu", meta=meta)
            t0 = time.perf_counter()
            out = register(src, pair.target)
            times.append(time.perf_counter() - t0)
        print(f"{name:>20s}: {statistics.median(times):6.2f} s  ({len(out.meta)} cards)")


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0].startswith("-") and argv[0] not in ("-h", "--help"):
        argv = ["kernel", *argv]
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parts = parser.add_subparsers(dest="part", required=True)
    ap = parts.add_parser("kernel", help="time of the resampling step, ndarray and CCDData")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096])
    ap.add_argument("--repeat", type=int, default=5)
    ap = parts.add_parser("memory", help="added memory and time of register, fresh processes")
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
    ap = parts.add_parser("stages", help="the stages of register, ndarray against CCDData")
    ap.add_argument("--size", type=int, default=8192)
    ap.add_argument("--stars", type=int, default=3000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--before", default=None)
    ap = parts.add_parser("meta", help="register time with a large meta")
    ap.add_argument("--keys", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    return {"kernel": kernel, "memory": memory, "stages": stages, "meta": meta}[args.part](args)


if __name__ == "__main__":
    raise SystemExit(main())
