"""
``register`` at 1024x1024 with detection taken out: what the matching,
the triangles, the resampling and the output building cost (issue 16).

Each frame's detection runs once and is then served from a cache (the same
tables for every copy of the package), so that the rest of ``register`` is
timed on its own, with less noise than the whole call on a shared machine.
With ``--old DIR`` an older astroalign_nd (its ``astroalign_nd`` folder
copied to ``DIR/astroalign_nd_old``, as for ``bench_speed2.py``) runs
interleaved on the same pairs.  Wall time and process CPU time (all
threads) are reported, median and minimum per call.

The pairs are ``bench_speed2.py``'s three workloads (ours, sparse, crowded).

Usage::

    PYTHONPATH=. python benchmarks/bench_speed2_nodetect.py --old /tmp/oldpkg
"""

import argparse
import importlib
import os
import sys
import time
import warnings

import numpy as np

from bench_speed2 import WORKLOADS

warnings.simplefilter("ignore")


def _cache_detection(pkg):
    """Serve ``pkg``'s control-point detection from a cache keyed by the image."""
    reg = importlib.import_module(pkg.__name__ + ".registration")
    real, cache = reg._control_sources, {}

    def cached(img, **kw):
        key = (np.ascontiguousarray(img[::97, ::89]).tobytes(), repr(sorted(kw.items(), key=str)))
        if key not in cache:
            cache[key] = real(img, **kw)
        return cache[key]

    reg._control_sources = cached


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=3, help="pairs per workload")
    ap.add_argument("--repeats", type=int, default=10, help="calls per pair and tool")
    ap.add_argument("--old", help="folder holding astroalign_nd_old/ (an older copy)")
    args = ap.parse_args(argv)

    import astroalign_nd

    tools = {"new": astroalign_nd}
    if args.old:
        sys.path.insert(0, args.old)
        tools["old"] = importlib.import_module("astroalign_nd_old")
    for pkg in tools.values():
        _cache_detection(pkg)
    print(f"astroalign_nd from {os.path.dirname(astroalign_nd.__file__)}; "
          f"load average {os.getloadavg()[0]:.1f}", flush=True)
    for wl, (maker, n_stars, _) in WORKLOADS.items():
        pairs = [maker(1024, n_stars, 1000 * s + 1024 + n_stars) for s in range(args.pairs)]
        for src, dst, _ in pairs:  # warm up, and fill the detection caches
            for pkg in tools.values():
                pkg.register(src, dst)
        wall = {k: [] for k in tools}
        cpu = {k: [] for k in tools}
        for rep in range(args.repeats):
            for src, dst, _ in pairs:
                for k in (list(tools) if rep % 2 == 0 else list(tools)[::-1]):
                    c0, t0 = time.process_time(), time.perf_counter()
                    tools[k].register(src, dst)
                    wall[k].append(time.perf_counter() - t0)
                    cpu[k].append(time.process_time() - c0)
        line = f"1024^2 {wl:>8}, register without detection:"
        for k in tools:
            line += (f" {k} wall {np.median(wall[k]) * 1e3:.2f} ms (min "
                     f"{np.min(wall[k]) * 1e3:.2f}), CPU {np.median(cpu[k]) * 1e3:.2f} ms (min "
                     f"{np.min(cpu[k]) * 1e3:.2f});")
        print(line, flush=True)


if __name__ == "__main__":
    main()
