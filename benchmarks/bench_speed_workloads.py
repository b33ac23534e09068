"""
``register`` speed on two independent workloads, astroalign_nd against
astroalign (and optionally an older astroalign_nd), interleaved in one run.

Workloads, each at 1024x1024 and 4096x4096, float32:

- ``ours``: `astroalign_nd.simulate.simulate_pair` (1000 stars at 1024^2,
  3000 at 4096^2, Gaussian noise), as in ``bench_speed.py``;
- ``sparse`` and ``crowded``: a second, independent simulator built on
  photutils (`photutils.datasets.make_model_image` with a Moffat PSF,
  ``beta = 3``), 300 and 10,000 stars in the source frame, power-law
  fluxes, sky 300 counts, Poisson noise plus a read noise of 5 counts, the
  target frame with a different seeing; the stars lie on a sky larger than
  either frame, so that each frame holds stars the other does not.

Every pair has a random similarity transform (rotation uniform in
[0, 360) degrees, scale uniform in [0.95, 1.05], shift within 5% of the
size) about the frame centre, known exactly: the transform error of every
tool is measured against it (the largest distance over the target frame
between where the true and the estimated transforms put a pixel).

For each workload it prints the median ``register`` time of each tool over
``--repeats`` pairs (the tools interleaved on each pair), the ratio to
astroalign, the median process CPU time (all threads: less sensitive to
other jobs on a shared machine, but it counts astroalign_nd's second
thread), the transform errors, and astroalign_nd's stage breakdown inside
``register`` (detection, asterisms, matching, resampling, the rest), timed by
wrapping the stage functions of the package.

``--old DIR`` adds an older astroalign_nd: copy its ``astroalign_nd``
folder (with the compiled extension) to ``DIR/astroalign_nd_old``.

``--no-detect``: ``register`` at 1024x1024 with detection taken out, what
the matching, the triangles, the resampling and the output building cost.
Each frame's detection runs once and is then served from a cache (the same
tables for every copy of the package), so that the rest of ``register`` is
timed on its own, with less noise than the whole call on a shared machine;
``--pairs`` pairs per workload, each called ``--repeats`` times (default 10)
per tool, the tools (this one and ``--old``) alternating.  Wall time and
process CPU time (all threads) are reported, median and minimum per call.

``--hard`` adds the pairs where the search does not stop at its first
attempt, timed with ``find_transform`` against astroalign's on the same
pair (per pair: the ratio of the two times):

- ``refused 8-bit``: two unrelated sparse 8-bit frames
  (``simulate_trust_case`` of tests/_frame_defects.py, 'sparse_8bit', seeds s
  and s + 100), which every tool must refuse;
- ``refused 1024``: two unrelated 1024x1024 fields of 300 stars;
- ``small overlap 2048``: a 2048x2048 pair of 3000 stars shifted by
  (1400, 1100) px, so that the brightest stars of each frame lie mostly
  outside the overlap and the first attempt fails.

The summary then gives the ratio to astroalign over every pair, solved
(the workloads and the small overlap) and refused separately: median,
90th percentile and worst.

Usage::

    PYTHONPATH=. python benchmarks/bench_speed_workloads.py --repeats 5 [--old /tmp/oldpkg] [--hard]
    PYTHONPATH=. python benchmarks/bench_speed_workloads.py --no-detect [--old /tmp/oldpkg]
    PYTHONPATH=. python benchmarks/bench_speed_workloads.py --workloads ours --numpy-kernels

``--numpy-kernels`` (or ``--no-extension``) adds astroalign_nd with its
compiled loops turned off (``conf.use_compiled = False``: the NumPy loops an
install without a C compiler runs, the same results), and prints their time
over the compiled loops' (the cost `~astroalign_nd.exceptions.SlowKernelsWarning`
states); with ``--old``, the older copy's NumPy loops as well (``oldnumpy``).
Run from an install without the compiled loops, every astroalign_nd line is
the NumPy loops' (the header says whether they are built).
"""

import argparse
import contextlib
import functools
import importlib
import os
import sys
import time
import warnings

import numpy as np

from bench_speed import frame_error  # noqa: E402  (the same error as bench_speed's)

warnings.simplefilter("ignore")


def random_similarity(size, rng):
    """A 3x3 source-to-target pixel matrix: rotation and scale about the centre, a shift."""
    theta = np.deg2rad(rng.uniform(0.0, 360.0))
    s = rng.uniform(0.95, 1.05)
    shift = rng.uniform(-0.05, 0.05, 2) * size
    c = (size - 1) / 2.0
    a = s * np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    m = np.eye(3)
    m[:2, :2] = a
    m[:2, 2] = np.array([c, c]) + shift - a @ np.array([c, c])
    return m


def _render(size, x, y, flux, alpha, rng, sky=300.0, read_noise=5.0):
    from astropy.table import Table
    from photutils.datasets import make_model_image
    from photutils.psf import MoffatPSF

    half = int(np.ceil(6 * alpha))
    inside = (x > -half) & (x < size + half) & (y > -half) & (y < size + half)
    tab = Table({"x_0": x[inside], "y_0": y[inside], "flux": flux[inside],
                 "alpha": np.full(inside.sum(), alpha), "beta": np.full(inside.sum(), 3.0)})
    img = make_model_image((size, size), MoffatPSF(), tab, model_shape=(2 * half + 1,) * 2)
    img = rng.poisson(img + sky).astype(np.float64) + rng.normal(0.0, read_noise, img.shape)
    return img.astype(np.float32)


def photutils_pair(size, n_stars, seed):
    """A pair from the second simulator: (source, target, truth 3x3)."""
    rng = np.random.default_rng(seed)
    truth = random_similarity(size, rng)
    # Stars on a sky 1.5 times the frame on a side, n_stars of them in the source frame.
    lo, hi = -0.25 * size, 1.25 * size
    n_sky = int(round(n_stars * ((hi - lo) / size) ** 2))
    xs, ys = rng.uniform(lo, hi, n_sky), rng.uniform(lo, hi, n_sky)
    flux = 300.0 * (1.0 + rng.pareto(1.3, n_sky))  # a power law of fluxes
    xt, yt = (truth @ np.vstack([xs, ys, np.ones(n_sky)]))[:2]
    src = _render(size, xs, ys, flux, rng.uniform(2.2, 2.8), rng)
    dst = _render(size, xt, yt, flux, rng.uniform(2.2, 3.4), rng)
    return src, dst, truth


def ours_pair(size, n_stars, seed):
    from astroalign_nd.simulate import simulate_pair

    rng = np.random.default_rng(seed)
    pair = simulate_pair((size, size), n_stars=n_stars, rotation=float(rng.uniform(0, 360)),
                         scale=float(rng.uniform(0.95, 1.05)),
                         translation=tuple(rng.uniform(-0.05, 0.05, 2) * size),
                         noise="gaussian", seed=seed)
    return (np.asarray(pair.source, np.float32), np.asarray(pair.target, np.float32),
            np.asarray(pair.truth_matrix, float))


WORKLOADS = {  # name -> (maker, stars at 1024^2, stars at 4096^2)
    "ours": (ours_pair, 1000, 3000),
    "sparse": (photutils_pair, 300, 300),
    "crowded": (photutils_pair, 10000, 10000),
}


def refused_8bit(seed):
    """Two unrelated sparse 8-bit frames: (source, target, None)."""
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    sys.path.insert(0, os.path.join(repo, "tests"))  # _frame_defects
    from _frame_defects import simulate_trust_case

    return (simulate_trust_case("sparse_8bit", seed=seed).source,
            simulate_trust_case("sparse_8bit", seed=seed + 100).target, None)


def refused_1024(seed):
    """Two unrelated 1024x1024 fields of 300 stars: (source, target, None)."""
    from astroalign_nd.simulate import simulate_field

    return (simulate_field((1024, 1024), n_stars=300, seed=seed)[0],
            simulate_field((1024, 1024), n_stars=300, seed=seed + 10_000)[0], None)


def small_overlap_2048(seed):
    """A 2048x2048 pair overlapping in a corner: the first attempt fails."""
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((2048, 2048), n_stars=3000, rotation=5.0,
                         translation=(1400.0, 1100.0), seed=seed)
    return (np.asarray(pair.source, np.float32), np.asarray(pair.target, np.float32),
            np.asarray(pair.truth_matrix, float))


HARD = {"refused 8-bit": refused_8bit, "refused 1024": refused_1024,
        "small overlap 2048": small_overlap_2048}


def run_hard(tools, astroalign, repeats, seed):
    """
    ``find_transform`` of each tool and of astroalign on the hard pairs:
    {case: {tool: [(seconds, error px or None if refused), ...]}}.
    """
    out = {}
    for case, maker in HARD.items():
        out[case] = {k: [] for k in (*tools, "astroalign")}
        for r in range(repeats):
            src, dst, truth = maker(seed + r)
            for k in out[case]:
                t0 = time.perf_counter()
                try:
                    if k == "astroalign":
                        m = astroalign.find_transform(src, dst)[0].params
                    else:
                        m = tools[k].find_transform(src, dst)[0].matrix
                    err = frame_error(m, truth, dst.shape) if truth is not None else np.inf
                except Exception:  # noqa: BLE001 - a refusal is recorded
                    err = None
                out[case][k].append((time.perf_counter() - t0, err))
        line = f"{case:>20}: " + ", ".join(
            f"{k} {np.median([t for t, _ in v]):.3f} s "
            f"({sum(e is None for _, e in v)} refused)" for k, v in out[case].items())
        print(line, flush=True)
    return out


def _spread(ratios):
    """'median m, p90 p, worst w (n pairs)' of a list of time ratios."""
    if not ratios:
        return "no pairs"
    r = np.asarray(ratios)
    return (f"median {np.median(r):.2f}, p90 {np.percentile(r, 90):.2f}, worst {r.max():.2f} "
            f"({len(r)} pairs)")


STAGES = ("detect", "asterisms", "match", "resample")


#: (the module that calls a stage, the module where the stage's function lives, its name,
#: the stage).  The caller imports the function by name, so the caller's binding is the one
#: wrapped (found by identity: an older tree, ``--old``, may bind it under another name).
STAGE_FUNCTIONS = ((".registration", ".detection.daofind", "control_sources", "detect"),
                   (".registration", ".matching.asterisms", "build_asterisms", "asterisms"),
                   (".matching", ".matching.asterisms", "build_asterisms", "asterisms"),
                   (".registration", ".matching.search", "match_control_points", "match"),
                   (".resample.nddata", ".resample.core", "resample", "resample"))


class StageTimer:
    """Time astroalign_nd's stages inside ``register`` by wrapping its stage functions."""

    def __init__(self, pkg):
        self.pkg = pkg
        self.t = dict.fromkeys(STAGES, 0.0)
        self.depth = dict.fromkeys(STAGES, 0)
        self.patches = []
        for caller, home, name, stage in STAGE_FUNCTIONS:
            try:
                mod = importlib.import_module(pkg + caller)
                fn = getattr(importlib.import_module(pkg + home), name)
            except (ImportError, AttributeError):
                continue
            for bound, value in list(vars(mod).items()):
                if value is fn:
                    self.patches.append((mod, bound, fn, stage))

    def _wrap(self, fn, stage):
        @functools.wraps(fn)
        def inner(*a, **k):
            self.depth[stage] += 1
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                self.depth[stage] -= 1
                if self.depth[stage] == 0:  # recursion (binned detection) counted once
                    self.t[stage] += time.perf_counter() - t0
        return inner

    def __enter__(self):
        self.t = dict.fromkeys(STAGES, 0.0)
        for mod, name, fn, stage in self.patches:
            setattr(mod, name, self._wrap(fn, stage))
        return self

    def __exit__(self, *exc):
        for mod, name, fn, _ in self.patches:
            setattr(mod, name, fn)

    def split(self, total):
        out = dict(self.t)
        out["match"] -= out["asterisms"]  # the matcher builds the asterisms
        out["other"] = total - sum(self.t[s] for s in ("detect", "match", "resample"))
        return out


class NumpyKernels:
    """
    astroalign_nd with every compiled loop turned off (detection, matching and resampling):
    what an install without a C compiler runs.
    """

    def __init__(self, mod):
        self.mod = mod
        self.__name__ = mod.__name__

    @contextlib.contextmanager
    def _off(self):
        # Older trees (--old): the resampler had its own switch; now conf.use_compiled is the one.
        resample = importlib.import_module(self.mod.__name__ + ".resample")
        old = getattr(resample, "_USE_COMPILED", None)
        if old is not None:
            resample._USE_COMPILED = False
        try:
            with self.mod.conf.set_temp("use_compiled", False):
                yield
        finally:
            if old is not None:
                resample._USE_COMPILED = old

    def register(self, *args, **kwargs):
        with self._off():
            return self.mod.register(*args, **kwargs)

    def find_transform(self, *args, **kwargs):
        with self._off():
            return self.mod.find_transform(*args, **kwargs)


def _cache_detection(pkg):
    """Serve ``pkg``'s control-point detection from a cache keyed by the image."""
    reg = importlib.import_module(pkg.__name__ + ".registration")
    real = importlib.import_module(pkg.__name__ + ".detection.daofind").control_sources
    cache = {}

    def cached(img, **kw):
        key = (np.ascontiguousarray(img[::97, ::89]).tobytes(), repr(sorted(kw.items(), key=str)))
        if key not in cache:
            cache[key] = real(img, **kw)
        return cache[key]

    for bound, value in list(vars(reg).items()):  # registration's binding (see STAGE_FUNCTIONS)
        if value is real:
            setattr(reg, bound, cached)


def no_detect(tools, n_pairs, repeats):
    """``register`` at 1024^2 with each frame's detection served from a cache."""
    for pkg in tools.values():
        _cache_detection(pkg)
    for wl, (maker, n_stars, _) in WORKLOADS.items():
        pairs = [maker(1024, n_stars, 1000 * s + 1024 + n_stars) for s in range(n_pairs)]
        for src, dst, _ in pairs:  # warm up, and fill the detection caches
            for pkg in tools.values():
                pkg.register(src, dst)
        wall = {k: [] for k in tools}
        cpu = {k: [] for k in tools}
        for rep in range(repeats):
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=None,
                    help="pairs per workload (calls per pair with --no-detect; "
                    "default 5, 10 with --no-detect)")
    ap.add_argument("--no-detect", action="store_true",
                    help="time register at 1024^2 with detection served from a cache")
    ap.add_argument("--pairs", type=int, default=3, help="pairs per workload (--no-detect)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096])
    ap.add_argument("--workloads", nargs="+", default=list(WORKLOADS))
    ap.add_argument("--old", help="folder holding astroalign_nd_old/ (an older copy)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--numpy-kernels", "--no-extension", action="store_true",
                    help="also time astroalign_nd with its NumPy kernels (no compiled loops, "
                    "as installed without a C compiler), and their cost over the compiled ones")
    ap.add_argument("--hard", action="store_true",
                    help="also time refused pairs and a pair whose first attempt fails")
    args = ap.parse_args(argv)

    import astroalign_nd

    tools = {"new": astroalign_nd}
    if args.old:
        sys.path.insert(0, args.old)
        tools["old"] = importlib.import_module("astroalign_nd_old")
    if args.no_detect:
        print(f"astroalign_nd from {os.path.dirname(astroalign_nd.__file__)}; "
              f"load average {os.getloadavg()[0]:.1f}", flush=True)
        return no_detect(tools, args.pairs, args.repeats or 10)
    args.repeats = args.repeats or 5

    import astroalign

    if args.numpy_kernels:
        tools["numpy"] = NumpyKernels(astroalign_nd)
        if args.old:  # the older copy's NumPy loops too, in the same run
            tools["oldnumpy"] = NumpyKernels(tools["old"])
    timers = {k: StageTimer(m.__name__) for k, m in tools.items()}
    built = importlib.import_module("astroalign_nd._kernels").HAVE_COMPILED
    print(f"astroalign_nd from {os.path.dirname(astroalign_nd.__file__)} (compiled loops "
          f"{'built' if built else 'NOT built: new runs the NumPy loops'}); "
          f"astroalign {astroalign.__version__}; {os.cpu_count()} CPUs; "
          f"load average {os.getloadavg()[0]:.1f}", flush=True)

    # Warm up every tool (imports, compiled kernels).
    w = photutils_pair(512, 300, 12345)
    for m in (*tools.values(), astroalign):
        m.register(w[0], w[1])

    names = list(tools) + ["astroalign"]
    summary = []
    numpy_cost = []  # (size, workload, NumPy loops' time over the compiled loops')
    # Per pair, each tool's time over astroalign's: solved pairs and refusals apart.
    solved_ratios = {k: [] for k in tools}
    refused_ratios = {k: [] for k in tools}
    for size in args.sizes:
        for wl in args.workloads:
            maker, n1, n4 = WORKLOADS[wl]
            n = n1 if size <= 1024 else n4
            times = {k: [] for k in names}
            cpu = {k: [] for k in names}  # process CPU time, all threads: less load-sensitive
            errs = {k: [] for k in names}
            stages = {k: [] for k in tools}
            for r in range(args.repeats):
                src, dst, truth = maker(size, n, args.seed + 1000 * r + size + n)
                for k in names:  # interleaved on the same pair
                    c0 = time.process_time()
                    if k == "astroalign":
                        t0 = time.perf_counter()
                        try:
                            astroalign.register(src, dst)
                        except Exception:  # noqa: BLE001 - a failure is recorded
                            pass
                        times[k].append(time.perf_counter() - t0)
                        cpu[k].append(time.process_time() - c0)
                        continue
                    with timers[k] as st:
                        t0 = time.perf_counter()
                        tools[k].register(src, dst)
                        dt = time.perf_counter() - t0
                    times[k].append(dt)
                    cpu[k].append(time.process_time() - c0)
                    stages[k].append(st.split(dt))
                # Errors against the truth (not timed).
                for k in names:
                    try:
                        if k == "astroalign":
                            m = astroalign.find_transform(src, dst)[0].params
                        else:
                            m = tools[k].find_transform(src, dst)[0].matrix
                        errs[k].append(frame_error(m, truth, dst.shape))
                    except Exception:  # noqa: BLE001
                        errs[k].append(np.inf)
            for k in tools:
                solved_ratios[k] += [a / b for a, b in zip(times[k], times["astroalign"])]
            med = {k: float(np.median(v)) for k, v in times.items()}
            line = f"{size:>5}^2 {wl:>8} ({n:>5} stars): " + ", ".join(
                f"{k} {med[k]:.3f} s" for k in names)
            line += " | ratio to astroalign: " + ", ".join(
                f"{k} {med[k] / med['astroalign']:.3f}" for k in tools)
            print(line)
            mc = {k: float(np.median(v)) for k, v in cpu.items()}
            ratios = ", ".join(f"{k} {mc[k] / mc['astroalign']:.3f}" for k in tools)
            print("      CPU time: " + ", ".join(f"{k} {mc[k]:.3f} s" for k in names)
                  + " | ratio: " + ratios)
            print("      median error px: " + ", ".join(
                f"{k} {np.median(errs[k]):.4f} (max {np.max(errs[k]):.4f})" for k in names))
            for k in tools:
                st = {s: float(np.median([d[s] for d in stages[k]])) for s in stages[k][0]}
                print(f"      stages {k:>3}: "
                      + ", ".join(f"{s} {v * 1e3:.0f} ms" for s, v in st.items()))
            print(flush=True)
            summary.append((size, wl, {k: med[k] / med["astroalign"] for k in tools}))
            if "numpy" in tools:
                numpy_cost.append((size, wl, med["numpy"] / med["new"]))
                if "oldnumpy" in tools:
                    numpy_cost.append((size, wl + " old", med["oldnumpy"] / med["old"]))

    if args.hard:
        # (The NumPy kernels are timed on the workloads only.)
        compiled = {k: m for k, m in tools.items() if not k.endswith("numpy")}
        hard = run_hard(compiled, astroalign, args.repeats, args.seed)
        for case, res in hard.items():
            for k in compiled:
                for (t, err), (ta, _) in zip(res[k], res["astroalign"]):
                    (refused_ratios if err is None else solved_ratios)[k].append(t / ta)
        print()

    print("Summary, ratio of register time to astroalign's (target: <= 0.25 at 1024^2, "
          "<= 0.10 at 4096^2):")
    for size, wl, rat in summary:
        print(f"  {size:>5}^2 {wl:>8}: " + ", ".join(f"{k} {v:.3f}" for k, v in rat.items()))
    if numpy_cost:
        print("NumPy loops' register time over the compiled loops' (SlowKernelsWarning's figure):")
        for size, wl, r in numpy_cost:
            print(f"  {size:>5}^2 {wl:>8}: {r:.2f}")
    print("Per pair, time over astroalign's in the same run:")
    for k in tools:
        print(f"  {k:>6} solved:  {_spread(solved_ratios[k])}")
        print(f"  {k:>6} refused: {_spread(refused_ratios[k])}")


if __name__ == "__main__":
    main()
