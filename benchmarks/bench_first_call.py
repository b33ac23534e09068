"""
First call in a fresh process, astroalign_nd against astroalign (issue 16).

What a command-line user feels on every command: start Python, import the
tool, read two FITS files and register one onto the other.  Each repeat
starts one fresh interpreter per tool, the tools alternating, so that both
see the same machine load; medians over the repeats.

Phases, timed inside the child:

- ``read``: ``from astropy.io import fits`` and ``fits.getdata`` of both
  frames (the same code for both tools);
- ``import``: ``import astroalign_nd`` / ``import astroalign``;
- ``register``: the first ``register`` call, with every import it triggers;
- ``second``: a second ``register`` on the same pair (no imports left);

and ``wall``, the whole child process as the parent saw it.

The transforms are compared too: the largest distance, over the target
frame, between where astroalign_nd and astroalign send a pixel (there is no
ground truth for a real pair).

Usage::

    python benchmarks/bench_first_call.py                 # 7 repeats
    python benchmarks/bench_first_call.py --repeats 11
    python benchmarks/bench_first_call.py --before /path/to/old/tree

``--before`` adds a third tool: astroalign_nd imported from another source
tree (a checkout of an older commit), to measure a change in one run.
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

DATA = "/work/shared/data/real/pairs/exotic_hatp32_microobservatory"
PAIR = ("HATP-32171220013343.FITS", "HATP-32171220031812.FITS")
HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

_CHILD = r"""
import sys, time
t0 = time.perf_counter()
import json, warnings
warnings.filterwarnings("ignore")
from astropy.io import fits
a = fits.getdata(sys.argv[2])
b = fits.getdata(sys.argv[3])
t1 = time.perf_counter()
if sys.argv[1] == "astroalign":
    import astroalign as mod
else:
    import astroalign_nd as mod
t2 = time.perf_counter()
out = mod.register(a, b)
t3 = time.perf_counter()
mod.register(a, b)
t4 = time.perf_counter()
if sys.argv[1] == "astroalign":
    m = mod.find_transform(a, b)[0].params
else:
    m = mod.find_transform(a, b)[0].matrix
print(json.dumps(dict(read=t1 - t0, imp=t2 - t1, register=t3 - t2, second=t4 - t3,
                      total=t3 - t0, file=mod.__file__, matrix=[list(r) for r in m])))
"""


def run_child(tool, src, dst, pythonpath):
    # ``python -c`` puts the working directory first on sys.path: run in the tree measured.
    env = dict(os.environ)
    env["PYTHONPATH"] = pythonpath
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", _CHILD, tool, src, dst], capture_output=True,
                         text=True, timeout=300, env=env, cwd=pythonpath)
    wall = time.perf_counter() - t0
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        raise RuntimeError(f"{tool} child failed:\n{res.stderr[-2000:]}")
    out = json.loads(lines[-1])
    out["wall"] = wall
    return out


def frame_distance(m1, m2, shape):
    """Max over a grid of target pixels of |T1^-1(p) - T2^-1(p)|, in pixels."""
    ny, nx = shape
    yy, xx = np.mgrid[0:ny:16, 0:nx:16]
    p = np.column_stack([xx.ravel(), yy.ravel(), np.ones(xx.size)])
    q1 = p @ np.linalg.inv(m1).T
    q2 = p @ np.linalg.inv(m2).T
    return float(np.max(np.hypot(*(q1[:, :2] - q2[:, :2]).T)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--before", default=None,
                    help="a source tree holding an older astroalign_nd, measured as 'before'")
    args = ap.parse_args(argv)
    if not os.path.isdir(DATA):
        sys.exit(f"the HAT-P-32 frames are not in {DATA}")
    src, dst = (os.path.join(DATA, f) for f in PAIR)
    tools = [("astroalign_nd", HERE), ("astroalign", HERE)]
    if args.before:
        tools.append(("before", os.path.abspath(args.before)))
    print(f"{os.cpu_count()} CPUs; load average {os.getloadavg()[0]:.1f}; "
          f"{args.repeats} repeats; pair {PAIR[0]} -> {PAIR[1]}")
    rows = {name: [] for name, _ in tools}
    for r in range(args.repeats):
        # Rotate the order so that no tool always runs first after a pause.
        for name, path in tools[r % len(tools):] + tools[:r % len(tools)]:
            tool = "astroalign" if name == "astroalign" else "astroalign_nd"
            rows[name].append(run_child(tool, src, dst, path))
    for name, _ in tools:
        print(f"  {name}: {rows[name][0]['file']}")
    shape = np.asarray(__import__("astropy.io.fits", fromlist=["getdata"]).getdata(dst)).shape
    keys = ("read", "imp", "register", "second", "total", "wall")
    med = {name: {k: float(np.median([x[k] for x in rows[name]])) for k in keys}
           for name, _ in tools}
    print(f"\n{'median (s)':>14} " + " ".join(f"{k:>9}" for k in keys))
    for name, _ in tools:
        print(f"{name:>14} " + " ".join(f"{med[name][k]:>9.3f}" for k in keys))
    aa = med["astroalign"]
    for name, _ in tools:
        if name != "astroalign":
            r = med[name]
            print(f"{name:>14} / astroalign: first register {r['register'] / aa['register']:.2f}, "
                  f"read+import+register {r['total'] / aa['total']:.2f}, "
                  f"process wall {r['wall'] / aa['wall']:.2f}")
    print("\nper-repeat ratio ours/astroalign of read+import+register: "
          + " ".join(f"{o['total'] / a['total']:.2f}"
                     for o, a in zip(rows["astroalign_nd"], rows["astroalign"])))
    d = frame_distance(np.array(rows["astroalign_nd"][0]["matrix"]),
                       np.array(rows["astroalign"][0]["matrix"]), shape)
    print(f"transform agreement with astroalign: max {d:.3f} px over the target frame")
    if args.before:
        d = frame_distance(np.array(rows["astroalign_nd"][0]["matrix"]),
                           np.array(rows["before"][0]["matrix"]), shape)
        print(f"transform agreement with 'before': max {d:.2e} px over the target frame")


if __name__ == "__main__":
    main()
