"""
Speed of astroalign_nd against astroalign, in one run.

Sections
--------
1. Headline: end-to-end ``register(source, target)`` on ndarrays at 1024^2
   and 4096^2, median over repeats, against ``astroalign.register`` on the
   same pairs; the transform error against the simulator's truth too.
2. Peak memory at 4096^2, each tool in a fresh process.
3. Cost of full CCDData output (mask and uncertainty) over ndarray input.
4. Scaling with image size (256^2 to 8192^2) and with star count (300 to
   30,000 at 1024^2).
5. Breakdown by stage.
6. First-call latency in a fresh process, both tools (nothing is compiled at run time).

Usage::

    python benchmarks/bench_speed.py            # everything (~10 min)
    python benchmarks/bench_speed.py --quick    # fewer repeats, no 8192^2

Ratios are what count: the machine is shared and noisy, but both tools
run on the same inputs, interleaved, in the same process.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

warnings.filterwarnings("ignore")


def frame_error(matrix, truth, shape):
    """Max over target pixels p of |T(T_true^-1(p)) - p|, in pixels."""
    ny, nx = shape
    yy, xx = np.mgrid[0:ny:max(1, ny // 32), 0:nx:max(1, nx // 32)]
    p = np.column_stack([xx.ravel(), yy.ravel()]).astype(float)
    inv = np.linalg.inv(truth)
    q = p @ inv[:2, :2].T + inv[:2, 2]
    r = q @ matrix[:2, :2].T + matrix[:2, 2]
    return float(np.max(np.hypot(*(r - p).T)))


def make_pair(size, n_stars, seed, **kw):
    from astroalign_nd.simulate import simulate_pair

    rng = np.random.default_rng(seed)
    return simulate_pair((size, size), n_stars=n_stars, rotation=float(rng.uniform(0, 360)),
                         scale=float(rng.uniform(0.95, 1.05)),
                         translation=tuple(rng.uniform(-0.05, 0.05, 2) * size),
                         noise="gaussian", seed=seed, **kw)


def timed(fn, *args, **kw):
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    return time.perf_counter() - t0, out


def run_ours(src, dst, **kw):
    import astroalign_nd

    return astroalign_nd.register(src, dst, **kw)


def run_aa(src, dst):
    import astroalign

    return astroalign.register(src, dst)


def compare_register(size, n_stars, repeats, seed0=0, with_bicubic=True):
    """Interleaved repeats of both tools on the same pairs."""
    import astroalign
    import astroalign_nd

    ours, ours3, theirs, err_ours, err_aa = [], [], [], [], []
    for r in range(repeats):
        pair = make_pair(size, n_stars, seed0 + r)
        t, _ = timed(run_ours, pair.source, pair.target)
        ours.append(t)
        if with_bicubic:
            t, _ = timed(run_ours, pair.source, pair.target, order="bicubic")
            ours3.append(t)
        t, _ = timed(run_aa, pair.source, pair.target)
        theirs.append(t)
        tr, _ = astroalign_nd.find_transform(pair.source, pair.target)
        err_ours.append(frame_error(tr.matrix, pair.truth_matrix, pair.target.shape))
        try:
            ta, _ = astroalign.find_transform(pair.source, pair.target)
            err_aa.append(frame_error(ta.params, pair.truth_matrix, pair.target.shape))
        except Exception:  # noqa: BLE001
            err_aa.append(np.nan)
    return dict(size=size, n_stars=n_stars, ours=float(np.median(ours)),
                ours_bicubic=float(np.median(ours3)) if ours3 else np.nan,
                astroalign=float(np.median(theirs)),
                err_ours=float(np.median(err_ours)), err_aa=float(np.nanmedian(err_aa)))


_MEM_CHILD = r"""
import json, sys, time, warnings
warnings.filterwarnings("ignore")
import numpy as np
tool, path = sys.argv[1], sys.argv[2]


def rss_peak_mb():
    # VmHWM: the peak resident set size since the last reset (Linux).
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024


def reset_peak():
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # resets VmHWM to the current RSS


d = np.load(path)
src, dst = d["source"], d["target"]
# The warm-up pair comes from the file too, so that neither child imports
# anything but the tool it measures.
w_src, w_dst = d["warm_source"], d["warm_target"]
if tool == "ours":
    import astroalign_nd as mod
else:
    import astroalign as mod
mod.register(w_src, w_dst)  # imports and compiled kernels loaded first
del w_src, w_dst, d
import ctypes, gc
gc.collect()
ctypes.CDLL("libc.so.6").malloc_trim(0)  # return freed heap to the OS, for both tools
reset_peak()
before = rss_peak_mb()
t0 = time.perf_counter(); out = mod.register(src, dst); t = time.perf_counter() - t0
peak = rss_peak_mb()
print(json.dumps({"before_mb": before, "peak_mb": peak, "time": t}))
"""


def peak_memory(size, n_stars, seed=0):
    pair = make_pair(size, n_stars, seed)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "pair.npz")
        warm = make_pair(512, 300, seed + 1000)
        np.savez(path, source=pair.source, target=pair.target,
                 warm_source=warm.source, warm_target=warm.target)
        out = {}
        for tool in ("ours", "astroalign"):
            res = subprocess.run([sys.executable, "-c", _MEM_CHILD, tool, path],
                                 capture_output=True, text=True, timeout=900)
            line = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else "{}"
            out[tool] = json.loads(line) if line.startswith("{") else {"error": res.stderr[-500:]}
    return out


def ccddata_cost(size, n_stars, repeats):
    import astroalign_nd
    from astropy.nddata import CCDData, StdDevUncertainty

    plain, full = [], []
    for r in range(repeats):
        pair = make_pair(size, n_stars, 100 + r)
        mask = np.zeros(pair.source.shape, bool)
        mask[10:20, 10:400] = True  # a bad column block
        ccd = CCDData(pair.source, unit="adu", mask=mask,
                      uncertainty=StdDevUncertainty(np.sqrt(np.abs(pair.source) + 25.0)))
        ref = astroalign_nd.Reference(pair.target)
        t, _ = timed(astroalign_nd.register, pair.source, ref)
        plain.append(t)
        t, _ = timed(astroalign_nd.register, ccd, ref)
        full.append(t)
    return float(np.median(plain)), float(np.median(full))


def stage_breakdown(size, n_stars, repeats):
    import astroalign_nd
    from astroalign_nd.io.read import parse_input
    from astroalign_nd.matching.search import match_control_points, search_tolerance
    from astroalign_nd.registration import Reference
    from astroalign_nd.resample import apply_transform, resample

    rows = {k: [] for k in ("parse", "detect source", "detect target", "match",
                            "resample (bilinear)", "CCDData assembly", "total register")}
    for r in range(repeats):
        pair = make_pair(size, n_stars, 200 + r)
        t, (src) = timed(parse_input, pair.source, "source")
        t2, dst = timed(parse_input, pair.target, "target")
        rows["parse"].append(t + t2)
        rs, rt = Reference(src), Reference(dst)
        t, (sp, se, sf) = timed(rs.stars, 50)
        rows["detect source"].append(t)
        t, (dp, de, df) = timed(rt.stars, 50)
        rows["detect target"].append(t)
        t, res = timed(match_control_points, sp, dp, source_frame=sf, target_frame=df,
                       source_errors=se, target_errors=de, n_control=50,
                       tolerance=search_tolerance(rt.fwhm))
        rows["match"].append(t)
        t, _ = timed(resample, pair.source, res.transform.matrix, pair.target.shape,
                     order="bilinear")
        rows["resample (bilinear)"].append(t)
        t, _ = timed(apply_transform, res.transform, src, dst)
        rows["CCDData assembly"].append(max(t - rows["resample (bilinear)"][-1], 0.0))
        t, _ = timed(astroalign_nd.register, pair.source, pair.target)
        rows["total register"].append(t)
    return {k: float(np.median(v)) for k, v in rows.items()}


_FIRST_CALL = r"""
import sys, time, warnings
warnings.filterwarnings("ignore")
import numpy as np
d = np.load(sys.argv[2])
src, dst = d["source"], d["target"]
t0 = time.perf_counter()
if sys.argv[1] == "ours":
    import astroalign_nd as mod
else:
    import astroalign as mod
t_import = time.perf_counter() - t0
t0 = time.perf_counter(); mod.register(src, dst); t1 = time.perf_counter() - t0
t0 = time.perf_counter(); mod.register(src, dst); t2 = time.perf_counter() - t0
print(f"{t_import:.3f} {t1:.3f} {t2:.3f}")
"""


def first_call():
    """Import, first and second ``register`` at 1024^2 in a fresh process, per tool."""
    pair = make_pair(1024, 1000, 5)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "pair.npz")
        np.savez(path, source=pair.source, target=pair.target)
        for tool in ("ours", "astroalign"):
            res = subprocess.run([sys.executable, "-c", _FIRST_CALL, tool, path],
                                 capture_output=True, text=True, timeout=900)
            vals = res.stdout.split()
            out[tool] = tuple(float(v) for v in vals) if len(vals) == 3 else (np.nan,) * 3
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description="astroalign_nd vs astroalign: speed")
    ap.add_argument("--quick", action="store_true", help="fewer repeats, no 8192^2")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--sections", default="1,2,3,4,5,6")
    args = ap.parse_args(argv)
    rep = args.repeats or (3 if args.quick else 5)
    sections = set(args.sections.split(","))
    import astroalign_nd

    # Warm up both tools (imports, lazily loaded modules).
    warm = make_pair(512, 300, 999)
    run_ours(warm.source, warm.target)
    run_ours(warm.source, warm.target, order="bicubic")
    run_aa(warm.source, warm.target)
    print(f"astroalign_nd {astroalign_nd.__version__}; {os.cpu_count()} CPUs; "
          f"load average {os.getloadavg()[0]:.1f}")

    if "1" in sections:
        print("\n## 1. Headline: register(source, target), ndarray in, median of", rep)
        print(f"{'size':>6} {'stars':>6} {'ours (s)':>9} {'ours bicubic':>13} "
              f"{'astroalign':>11} {'ratio':>7} {'ratio bicubic':>14} {'err ours px':>12} "
              f"{'err aa px':>10}")
        for size, n in ((1024, 1000), (4096, 3000)):
            r = compare_register(size, n, rep if size <= 1024 else max(2, rep - 2))
            print(f"{size:>6} {n:>6} {r['ours']:>9.3f} {r['ours_bicubic']:>13.3f} "
                  f"{r['astroalign']:>11.3f} {r['ours'] / r['astroalign']:>7.3f} "
                  f"{r['ours_bicubic'] / r['astroalign']:>14.3f} {r['err_ours']:>12.4f} "
                  f"{r['err_aa']:>10.4f}", flush=True)

    if "2" in sections:
        print("\n## 2. Peak memory at 4096^2 (fresh process each; VmHWM reset before the call)")
        m = peak_memory(4096, 3000)
        for tool, v in m.items():
            if "peak_mb" in v:
                print(f"{tool:>11}: peak RSS during register {v['peak_mb']:.0f} MB, "
                      f"{v['peak_mb'] - v['before_mb']:.0f} MB above the {v['before_mb']:.0f} MB "
                      f"held before it (inputs, imports); register {v['time']:.2f} s")
            else:
                print(f"{tool:>11}: failed {v}")

    if "3" in sections:
        print("\n## 3. Full CCDData output (mask + StdDev uncertainty) vs ndarray, "
              "reference prepared once")
        for size in (1024, 4096):
            plain, full = ccddata_cost(size, 1000 if size <= 1024 else 3000,
                                       rep if size <= 1024 else 2)
            print(f"{size:>6}: ndarray {plain:.3f} s, CCDData+mask+uncertainty {full:.3f} s, "
                  f"ratio {full / plain:.2f}", flush=True)

    if "4" in sections:
        print("\n## 4a. Scaling with size (1000 stars per 1024^2, capped 3000), median of",
              max(1, rep - 2))
        sizes = [256, 512, 1024, 2048, 4096] + ([] if args.quick else [8192])
        print(f"{'size':>6} {'ours':>8} {'astroalign':>11} {'ratio':>7}")
        for size in sizes:
            n = int(min(3000, max(300, 1000 * (size / 1024) ** 2)))
            r = compare_register(size, n, 1 if size >= 8192 else max(1, rep - 2),
                                 with_bicubic=False)
            print(f"{size:>6} {r['ours']:>8.3f} {r['astroalign']:>11.3f} "
                  f"{r['ours'] / r['astroalign']:>7.3f}", flush=True)
        print("\n## 4b. Scaling with star count at 1024^2")
        print(f"{'stars':>6} {'ours':>8} {'astroalign':>11} {'ratio':>7} {'err ours':>9} "
              f"{'err aa':>7}")
        for n in (300, 1000, 3000, 10000, 30000):
            r = compare_register(1024, n, max(1, rep - 2), with_bicubic=False)
            print(f"{n:>6} {r['ours']:>8.3f} {r['astroalign']:>11.3f} "
                  f"{r['ours'] / r['astroalign']:>7.3f} {r['err_ours']:>9.4f} "
                  f"{r['err_aa']:>7.4f}", flush=True)

    if "5" in sections:
        print("\n## 5. Breakdown by stage (s, median)")
        for size, n in ((1024, 1000), (4096, 3000)):
            b = stage_breakdown(size, n, max(1, rep - 2))
            print(f"{size}^2: " + ", ".join(f"{k} {v:.3f}" for k, v in b.items()), flush=True)

    if "6" in sections:
        print("\n## 6. First call in a fresh process (1024^2): import, 1st register, 2nd")
        for tool, t in first_call().items():
            print(f"{tool:>11}: import {t[0]:.2f} s, first {t[1]:.2f} s, second {t[2]:.2f} s",
                  flush=True)


if __name__ == "__main__":
    main()
