"""
Where full CCDData output costs time: the stages of ``register``, ndarray against CCDData.

On the float32 star field of ``bench_ccddata_memory.py`` (default 8192x8192,
3,000 stars; the CCDData source has a float32 `StdDevUncertainty` and a mask)
each tree (this one, and ``--before TREE``) runs in its own process, the
trees alternating over ``--rounds``; inside, every case is timed
``--repeat`` times round-robin after a warm-up:

- ``find nd`` / ``find ccd``: `find_transform` (detection and matching);
- ``apply nd`` / ``apply ccd``: `apply_transform` with the found transform;
- ``resample nd``: the bare kernel, data only;
- ``resample std+mask``: the kernel with the standard deviation and the mask.

Minimum and median per case and tree; ``register`` ratio = (find + apply)
CCDData over ndarray, from the minima (the least disturbed by other load).

Usage::

    python benchmarks/bench_ccddata_stages.py [--size 8192] [--before /path/to/old/tree]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_CHILD = r"""
import json, sys, time, warnings
warnings.filterwarnings("ignore")
import numpy as np
import astroalign_nd as aa
from astroalign_nd.resample import resample
from astropy.nddata import CCDData, StdDevUncertainty
d = np.load(sys.argv[1])
src, dst = d["source"], d["target"]
repeat = int(sys.argv[2])
mask = np.zeros(src.shape, bool)
mask[10:20, 10:400] = True
rng = np.random.default_rng(1)
mask.flat[rng.choice(mask.size, mask.size // 1000, replace=False)] = True
sigma = np.sqrt(np.abs(src) + np.float32(25.0)).astype(np.float32)
inp = CCDData(src, unit="adu", mask=mask, uncertainty=StdDevUncertainty(sigma))
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=8192)
    ap.add_argument("--stars", type=int, default=3000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--before", default=None)
    args = ap.parse_args(argv)
    sys.path.insert(0, HERE)
    from astroalign_nd.simulate import simulate_pair

    n = args.size
    pair = simulate_pair((n, n), n_stars=args.stars, rotation=17.0, scale=1.01,
                         translation=(0.03 * n, -0.02 * n), noise="gaussian", seed=3)
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
                res = subprocess.run([sys.executable, "-c", _CHILD, path, str(args.repeat)],
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


if __name__ == "__main__":
    main()
