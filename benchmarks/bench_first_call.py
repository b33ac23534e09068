"""
First call in a fresh process, astroalign_nd against astroalign.

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

Variants (``--variant``), each timed the same way:

- ``ndarray`` (the default): both tools read with ``fits.getdata`` and
  register the arrays (astroalign_nd returns a CCDData);
- ``ccddata``: astroalign_nd reads both frames with ``CCDData.read`` (so the
  ``read`` phase imports astropy.nddata) and registers the CCDData frames,
  as a ccdproc user would; astroalign reads with ``fits.getdata`` as before;
- ``compat``: ``astroalign_nd.compat.register`` (astroalign's return type:
  an ndarray and its footprint) against ``astroalign.register``.

Bytecode: an installed package has its ``.pyc`` files (pip compiles them,
and Python writes them on first import), astroalign's included.  A source
tree run with ``PYTHONDONTWRITEBYTECODE`` set (as on this machine) has none,
and every fresh process compiles astroalign_nd's ~13,000 lines again.
``--compile`` compiles the measured trees first (``compileall``, into their
``__pycache__`` folders, which git ignores), so that both tools are timed as
installed; the header line says whether each tree has its bytecode.

``--floor`` adds a child that, in place of the register phase, only imports
``astropy.modeling``: the transforms are astropy models, and that import
(which brings astropy.nddata, astropy.table, astropy.coordinates,
astropy.wcs and scipy.sparse) is a cost no change inside astroalign_nd can
remove.

``--breakdown`` then times, in fresh processes again, the first call's
imports one package at a time in the order the call meets them, the call
itself once they are done, and a second call (ndarray input).

The transforms are compared too: the largest distance, over the target
frame, between where astroalign_nd and astroalign send a pixel (there is no
ground truth for a real pair).

Usage::

    python benchmarks/bench_first_call.py                 # 7 repeats
    python benchmarks/bench_first_call.py --repeats 11
    python benchmarks/bench_first_call.py --before /path/to/old/tree
    python benchmarks/bench_first_call.py --variant ccddata --compile --floor
    python benchmarks/bench_first_call.py --compile --breakdown

``--before`` adds a third tool: astroalign_nd imported from another source
tree (a checkout of an older commit), to measure a change in one run.
"""

import argparse
import compileall
import glob
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
tool, variant = sys.argv[1], sys.argv[4]
from astropy.io import fits
if tool == "astroalign_nd" and variant == "ccddata":
    from astropy.nddata import CCDData
    a = CCDData.read(sys.argv[2], unit="adu")
    b = CCDData.read(sys.argv[3], unit="adu")
else:
    a = fits.getdata(sys.argv[2])
    b = fits.getdata(sys.argv[3])
t1 = time.perf_counter()
if tool == "floor":
    import astropy as mod
    t2 = time.perf_counter()
    import astropy.modeling
    t3 = t4 = time.perf_counter()
    print(json.dumps(dict(read=t1 - t0, imp=t2 - t1, register=t3 - t2, second=t4 - t3,
                          total=t3 - t0, file=astropy.modeling.__file__, matrix=None)))
    sys.exit(0)
if tool == "astroalign":
    import astroalign as mod
elif variant == "compat":
    from astroalign_nd import compat as mod
else:
    import astroalign_nd as mod
t2 = time.perf_counter()
out = mod.register(a, b)
t3 = time.perf_counter()
mod.register(a, b)
t4 = time.perf_counter()
T = mod.find_transform(a, b)[0]
m = T.params if hasattr(T, "params") else T.matrix
print(json.dumps(dict(read=t1 - t0, imp=t2 - t1, register=t3 - t2, second=t4 - t3,
                      total=t3 - t0, file=mod.__file__, matrix=[list(r) for r in m])))
"""


# --breakdown: the first register's imports one package at a time, in the order the call
# meets them, then the call itself (every import done) and a second call.
_BREAKDOWN_CHILD = r"""
import sys, time, json, warnings
warnings.filterwarnings("ignore")
from astropy.io import fits
a = fits.getdata(sys.argv[2])
b = fits.getdata(sys.argv[3])
stages = []
t = time.perf_counter()
def lap(name):
    global t
    now = time.perf_counter()
    stages.append((name, now - t))
    t = now
if sys.argv[1] == "astroalign":
    import scipy.spatial; lap("scipy.spatial")
    import scipy.ndimage; lap("scipy.ndimage")
    import skimage.transform; skimage.transform.warp; lap("skimage.transform")
    import sep; lap("sep")
    import astroalign as mod; lap("astroalign")
else:
    import scipy.spatial; lap("scipy.spatial")
    import astropy.modeling; lap("astropy.modeling (+nddata, table, coordinates, wcs)")
    import scipy.ndimage; lap("scipy.ndimage")
    import astroalign_nd as mod
    from astroalign_nd import registration
    from astroalign_nd.resample import nddata
    from astroalign_nd.transforms import selection
    lap("astroalign_nd modules")
    import photutils.detection; lap("photutils.detection")
mod.register(a, b); lap("first register, imports done")
mod.register(a, b); lap("second register")
print(json.dumps(stages))
"""


def run_breakdown(tool, src, dst, pythonpath):
    env = dict(os.environ)
    env["PYTHONPATH"] = pythonpath
    res = subprocess.run([sys.executable, "-c", _BREAKDOWN_CHILD, tool, src, dst],
                         capture_output=True, text=True, timeout=300, env=env, cwd=pythonpath)
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("[")]
    if not lines:
        raise RuntimeError(f"{tool} breakdown child failed:\n{res.stderr[-2000:]}")
    return json.loads(lines[-1])


def breakdown(src, dst, repeats):
    """Print the median and least time of each stage of the first call, both tools."""
    rows = {"astroalign_nd": [], "astroalign": []}
    for r in range(repeats):
        for tool in (("astroalign_nd", "astroalign") if r % 2 == 0
                     else ("astroalign", "astroalign_nd")):
            rows[tool].append(run_breakdown(tool, src, dst, HERE))
    print("\nbreakdown of the first call, after the read (s):")
    for tool, runs in rows.items():
        print(f"  {tool}{'':<40} median      min")
        for i, (name, _) in enumerate(runs[0]):
            v = [run[i][1] for run in runs]
            print(f"    {name:<52} {np.median(v):6.3f}   {min(v):6.3f}")
        tot = [sum(x for _, x in run[:-1]) for run in runs]
        print(f"    {'imports + first register':<52} {np.median(tot):6.3f}   {min(tot):6.3f}")


def bytecode_state(tree):
    """'compiled' if every astroalign_nd module of ``tree`` has a current .pyc, else a count."""
    import importlib.util

    missing = 0
    sources = glob.glob(os.path.join(tree, "astroalign_nd", "**", "*.py"), recursive=True)
    for src in sources:
        pyc = importlib.util.cache_from_source(src)
        if not os.path.exists(pyc) or os.path.getmtime(pyc) < os.path.getmtime(src):
            missing += 1
    return "compiled" if not missing else f"{missing} of {len(sources)} modules without bytecode"


def run_child(tool, src, dst, pythonpath, variant="ndarray"):
    # ``python -c`` puts the working directory first on sys.path: run in the tree measured.
    env = dict(os.environ)
    env["PYTHONPATH"] = pythonpath
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", _CHILD, tool, src, dst, variant],
                         capture_output=True, text=True, timeout=300, env=env,
                         cwd=pythonpath)
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
    ap.add_argument("--variant", choices=("ndarray", "ccddata", "compat"), default="ndarray",
                    help="what astroalign_nd reads and calls (see the module docstring)")
    ap.add_argument("--compile", action="store_true",
                    help="compile the measured trees' bytecode first, as an install would")
    ap.add_argument("--floor", action="store_true",
                    help="add a child that only imports astropy.modeling after the read")
    ap.add_argument("--breakdown", action="store_true",
                    help="also time the first call's imports package by package (ndarray)")
    args = ap.parse_args(argv)
    if not os.path.isdir(DATA):
        sys.exit(f"the HAT-P-32 frames are not in {DATA}")
    src, dst = (os.path.join(DATA, f) for f in PAIR)
    tools = [("astroalign_nd", HERE), ("astroalign", HERE)]
    if args.before:
        tools.append(("before", os.path.abspath(args.before)))
    if args.floor:
        tools.append(("floor", HERE))
    trees = sorted({path for name, path in tools if name not in ("astroalign", "floor")})
    if args.compile:
        for tree in trees:
            # py_compile writes the .pyc files even under PYTHONDONTWRITEBYTECODE.
            compileall.compile_dir(os.path.join(tree, "astroalign_nd"), quiet=1)
    print(f"{os.cpu_count()} CPUs; load average {os.getloadavg()[0]:.1f}; "
          f"{args.repeats} repeats; variant {args.variant}; pair {PAIR[0]} -> {PAIR[1]}")
    for tree in trees:
        print(f"  bytecode of {tree}: {bytecode_state(tree)}")
    rows = {name: [] for name, _ in tools}
    for r in range(args.repeats):
        # Rotate the order so that no tool always runs first after a pause.
        for name, path in tools[r % len(tools):] + tools[:r % len(tools)]:
            tool = name if name in ("astroalign", "floor") else "astroalign_nd"
            rows[name].append(run_child(tool, src, dst, path, args.variant))
    for name, _ in tools:
        print(f"  {name}: {rows[name][0]['file']}")
    shape = np.asarray(__import__("astropy.io.fits", fromlist=["getdata"]).getdata(dst)).shape
    keys = ("read", "imp", "register", "second", "total", "wall")
    med = {name: {k: float(np.median([x[k] for x in rows[name]])) for k in keys}
           for name, _ in tools}
    print(f"\n{'median (s)':>14} " + " ".join(f"{k:>9}" for k in keys))
    for name, _ in tools:
        print(f"{name:>14} " + " ".join(f"{med[name][k]:>9.3f}" for k in keys))
    # The least of the repeats: the machine's load only ever adds time.
    print(f"{'min (s)':>14} " + " ".join(f"{k:>9}" for k in keys))
    for name, _ in tools:
        print(f"{name:>14} " + " ".join(f"{min(x[k] for x in rows[name]):>9.3f}" for k in keys))
    if args.floor:
        print("  (floor: 'register' is only `import astropy.modeling`, after the same read)")
    aa = med["astroalign"]
    for name, _ in tools:
        if name != "astroalign":
            r = med[name]
            print(f"{name:>14} / astroalign: first register {r['register'] / aa['register']:.2f}, "
                  f"read+import+register {r['total'] / aa['total']:.2f}, "
                  f"process wall {r['wall'] / aa['wall']:.2f}")
    for name, _ in tools:
        if name == "astroalign":
            continue
        pairs = list(zip(rows[name], rows["astroalign"]))
        print(f"\nper-repeat ratio {name}/astroalign, read+import+register: "
              + " ".join(f"{o['total'] / a['total']:.2f}" for o, a in pairs))
        print(f"per-repeat ratio {name}/astroalign, first register: "
              + " ".join(f"{o['register'] / a['register']:.2f}" for o, a in pairs))
    d = frame_distance(np.array(rows["astroalign_nd"][0]["matrix"]),
                       np.array(rows["astroalign"][0]["matrix"]), shape)
    print(f"\ntransform agreement with astroalign: max {d:.3f} px over the target frame")
    if args.before:
        d = frame_distance(np.array(rows["astroalign_nd"][0]["matrix"]),
                           np.array(rows["before"][0]["matrix"]), shape)
        print(f"transform agreement with 'before': max {d:.2e} px over the target frame")
    if args.breakdown:
        breakdown(src, dst, args.repeats)


if __name__ == "__main__":
    main()
