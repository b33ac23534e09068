"""
Hard registration cases: astroalign_nd against astroalign,
aafitrans and spalipy on the same simulated inputs.

For every category and seed one pair is simulated (astroalign_nd.simulate,
known source -> target transform), and each method registers it:

* astroalign_nd: ``find_transform(source, target)`` (``transform_type=
  'affine'`` for the sheared case);
* astroalign: ``astroalign.find_transform(source, target)`` (images or
  catalogs as given; similarity only);
* aafitrans: ``aafitrans.find_transform(src_xy, dst_xy)`` on coordinate
  lists.  For images these are the 100 brightest detections of
  ``astroalign_nd.find_sources`` (aafitrans then keeps its default 50
  control points), so detection time is included in its time;
  ``ttype='affine'`` for the sheared case;
* spalipy: ``Spalipy(source, template_data=target, min_n_match=10)``
  (its own sep detection; ``min_n_match`` lowered from its default 100,
  which would reject every field with fewer than 100 detections), quads,
  affine fit and its default cubic-spline correction; the resampling step
  is skipped and the mapping it would resample with (affine + spline) is
  evaluated.  For catalogs it gets detection tables.
* spalipy-affine: the same with ``spline_order=0`` (its affine fit only:
  on these undistorted pairs the spline fitted to a few tens of matches
  often adds more error than it removes).

Accuracy of a returned transform: the largest distance, in target pixels,
between the true and the estimated position over a grid of target pixels
(every 8th pixel) that receive source data, ``max |T_true(T_est^-1(p)) -
p|`` for ``p`` in the overlap.  A run *succeeds* if this is below 1 px; a
transform returned but more than 1 px off is a *wrong answer* (the worst
outcome, counted separately); an exception or time-out is a *failure*.
For the unrelated-fields category the right answer is a refusal: any
returned transform is wrong.  A wrong answer that came with an
astroalign_nd warning (PoorFitWarning) is counted as wrong, and also
reported as "warned" (it was not silent).

Each method runs in its own worker process (started once, warmed up
outside the timing) with a time limit per call (``--timeout``); a worker
that times out is killed and restarted.  Calls run one at a time.

Usage::

    python benchmarks/bench_hard_cases.py [--seeds 3] [--cases overlap crowded]
        [--methods astroalign_nd astroalign] [--timeout 60] [-v]
"""

import argparse
import multiprocessing as mp
import queue
import sys
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

TITLE = ("Hard registration cases: astroalign_nd against astroalign, aafitrans and "
         "spalipy on the same simulated inputs")
METHODS = ("astroalign_nd", "astroalign", "aafitrans", "spalipy", "spalipy-affine")
BRIGHT = dict(flux_range=(1e3, 3e5))
#: Target pixels on this step are checked (in the overlap).
GRID_STEP = 8


# -- cases ----------------------------------------------------------------------------------

@dataclass
class Case:
    name: str
    source: np.ndarray              # image, or (N, 2) catalog
    target: np.ndarray
    truth: np.ndarray               # 3x3 source -> target, None for unrelated fields
    source_shape: tuple
    target_shape: tuple
    catalogs: bool = False
    refuse: bool = False            # the right answer is to raise
    affine: bool = False            # fit an affine model where the method can
    info: dict = field(default_factory=dict)


def _pair_case(name, seed, affine=False, **kw):
    from astroalign_nd.simulate import simulate_pair

    p = simulate_pair(seed=seed, **kw)
    return Case(name, p.source, p.target, p.truth_matrix, p.source.shape, p.target.shape,
                affine=affine)


def _shear_matrix(shear=0.03):
    c, s = np.cos(0.35), np.sin(0.35)
    lin = np.array([[c, -s], [s, c]]) @ np.array([[1.0, shear], [0.0, 1.0]])
    m = np.eye(3)
    m[:2, :2] = lin
    ctr = np.array([255.5, 255.5])
    m[:2, 2] = ctr - lin @ ctr + [5.3, -2.1]
    return m


def _catalog_case(name, seed, n_common, n_src_only, n_dst_only, noise):
    """Catalogs in a 512 x 512 frame sharing only ``n_common`` stars (shuffled)."""
    from astroalign_nd import SimilarityTransform

    truth = SimilarityTransform(scale=0.7, rotation=200.0, translation_x=310.0,
                                translation_y=45.5).matrix
    rng = np.random.default_rng(seed)
    common = rng.uniform(0, 500, (n_common, 2))
    src = np.vstack([common, rng.uniform(0, 500, (n_src_only, 2))])
    dst_common = common @ truth[:2, :2].T + truth[:2, 2]
    dst = np.vstack([dst_common, rng.uniform(0, 500, (n_dst_only, 2))])
    if noise:
        src = src + rng.normal(0, noise, src.shape)
        dst = dst + rng.normal(0, noise, dst.shape)
    src = src[rng.permutation(len(src))]
    dst = dst[rng.permutation(len(dst))]
    return Case(name, src, dst, truth, (512, 512), (512, 512), catalogs=True)


def _unrelated_case(name, seed):
    from astroalign_nd.simulate import simulate_field

    n = (10, 15, 20)[seed % 3]
    a, _ = simulate_field((256, 256), n_stars=n, seed=1000 + seed, **BRIGHT)
    b, _ = simulate_field((256, 256), n_stars=n, seed=2000 + seed, **BRIGHT)
    return Case(name, a, b, None, a.shape, b.shape, refuse=True, info={"n_stars": n})


CASES = {
    "3 common stars (catalogs 5 vs 6)": lambda s: _catalog_case(
        "3 common", s, 3, 2, 3, 0.0),
    "4 common stars (catalogs 7 vs 8, 0.01 px)": lambda s: _catalog_case(
        "4 common", s, 4, 3, 4, 0.01),
    "scale 1:3": lambda s: _pair_case(
        "scale 1:3", s, shape=(768, 768), n_stars=600, scale=1 / 3, rotation=40.0, fwhm=6.0,
        target_fwhm=2.0, **BRIGHT),
    "scale 3:1": lambda s: _pair_case(
        "scale 3:1", s, shape=(512, 512), n_stars=400, scale=3.0, rotation=-20.0, fwhm=2.0,
        target_fwhm=5.0, **BRIGHT),
    "mirrored": lambda s: _pair_case(
        "mirrored", s, n_stars=300, rotation=75.0, mirror=True, **BRIGHT),
    "meridian flip 180": lambda s: _pair_case(
        "meridian flip", s, n_stars=300, rotation=180.0, translation=(3.2, -4.7), **BRIGHT),
    "overlap 25%": lambda s: _pair_case(
        "overlap", s, n_stars=600, rotation=5.0, translation=(256.0, 256.0), **BRIGHT),
    "half missing + 150 transients": lambda s: _pair_case(
        "missing", s, n_stars=300, rotation=30.0, missing_fraction=0.5, n_transients=150,
        **BRIGHT),
    "500 hot pixels + 200 cosmics": lambda s: _pair_case(
        "hot", s, n_stars=300, rotation=30.0, n_hot_pixels=500, n_cosmic_rays=200, **BRIGHT),
    "crowded 30k stars 1024^2": lambda s: _pair_case(
        "crowded", s, shape=(1024, 1024), n_stars=30000, rotation=30.0,
        flux_range=(300, 3e5), noise="gaussian"),
    "fwhm 2 vs 9": lambda s: _pair_case(
        "fwhm", s, n_stars=300, rotation=30.0, fwhm=2.0, target_fwhm=9.0, **BRIGHT),
    "gradient x10": lambda s: _pair_case(
        "gradient", s, n_stars=300, rotation=30.0, gradient=10.0, **BRIGHT),
    "gradient x30": lambda s: _pair_case(
        "gradient30", s, n_stars=300, rotation=30.0, gradient=30.0, **BRIGHT),
    "saturated (5000 counts)": lambda s: _pair_case(
        "saturated", s, n_stars=300, rotation=30.0, saturation=5000.0, **BRIGHT),
    "low snr": lambda s: _pair_case(
        "low snr", s, n_stars=300, rotation=30.0, flux_range=(150, 5000), background=1000.0),
    "rectangular 300x900": lambda s: _pair_case(
        "rectangular", s, shape=(300, 900), n_stars=300, rotation=8.0, **BRIGHT),
    "rectangular onto portrait (90 deg)": lambda s: _pair_case(
        "rect90", s, shape=(300, 900), target_shape=(900, 300), n_stars=300, rotation=90.0,
        **BRIGHT),
    "affine shear 3% (affine fit)": lambda s: _pair_case(
        "shear", s, affine=True, n_stars=300, transform=_shear_matrix(), **BRIGHT),
    "unrelated sparse fields (must refuse)": lambda s: _unrelated_case("unrelated", s),
}


# -- accuracy -------------------------------------------------------------------------------

def overlap_grid(case):
    """Target pixels (every GRID_STEP) whose true preimage lies in the source frame."""
    ny, nx = case.target_shape
    yy, xx = np.mgrid[0:ny:GRID_STEP, 0:nx:GRID_STEP]
    p = np.column_stack([xx.ravel(), yy.ravel()]).astype(float)
    inv = np.linalg.inv(case.truth)
    q = p @ inv[:2, :2].T + inv[:2, 2]
    sy, sx = case.source_shape
    inside = (q[:, 0] >= -0.5) & (q[:, 0] <= sx - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] <= sy - 0.5)
    return p[inside] if inside.any() else p


def error_from_inverse(inverse_map, case):
    """max |T_true(T_est^-1(p)) - p| over the overlap grid (target pixels)."""
    p = overlap_grid(case)
    q = np.asarray(inverse_map(p), float)
    r = q @ case.truth[:2, :2].T + case.truth[:2, 2]
    return float(np.max(np.hypot(r[:, 0] - p[:, 0], r[:, 1] - p[:, 1])))


def matrix_inverse_map(m):
    inv = np.linalg.inv(np.asarray(m, float))
    return lambda p: p @ inv[:2, :2].T + inv[:2, 2]


# -- the four methods (run inside the worker processes) -------------------------------------

def run_astroalign_nd(case):
    import astroalign_nd

    opts = {"transform_type": "affine"} if case.affine else {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t, _ = astroalign_nd.find_transform(case.source, case.target, **opts)
    note = ""
    if any(issubclass(w.category, astroalign_nd.AstroalignWarning) for w in caught):
        note = "warned"
    q = t.meta["quality"]
    return matrix_inverse_map(t.matrix), f"n={q['n_matches']} {note}".strip()


def run_astroalign(case):
    import astroalign

    t, (s, _) = astroalign.find_transform(case.source, case.target)
    return matrix_inverse_map(t.params), f"n={len(s)}"


def _xy(image, n=100):
    import astroalign_nd

    tab = astroalign_nd.find_sources(image, n_sources=n)
    return np.column_stack([np.asarray(tab["x"], float), np.asarray(tab["y"], float)])


def run_aafitrans(case):
    import aafitrans

    if case.catalogs:
        src, dst = case.source, case.target
    else:
        src, dst = _xy(case.source), _xy(case.target)
    t, (s, _) = aafitrans.find_transform(src, dst,
                                         ttype="affine" if case.affine else "similarity")
    return matrix_inverse_map(t.params), f"n={len(s)}"


def run_spalipy(case, spline_order=3):
    import logging

    from astropy.table import Table
    import spalipy

    logging.disable(logging.CRITICAL)
    if case.catalogs:
        def det(xy):
            n = len(xy)
            return Table({"x": xy[:, 0], "y": xy[:, 1], "flux": np.arange(n, 0, -1.0),
                          "fwhm": np.full(n, 3.0), "flag": np.zeros(n, int)})
        sp = spalipy.Spalipy(np.zeros(case.source_shape), source_det=det(case.source),
                             template_det=det(case.target), min_n_match=10,
                             spline_order=spline_order)
    else:
        sp = spalipy.Spalipy(case.source, template_data=case.target, min_n_match=10,
                             spline_order=spline_order)
    sp.make_source_quadlist()
    sp.make_template_quadlist()
    sp.fit_affine_transform()
    sp.fit_spline_transform()

    def inverse_map(p):
        # spalipy's own target -> source mapping (affine + spline), as used to resample.
        out = sp.full_transform(np.asarray(p, float).T[:, None, :], 0, inverse=True)
        return np.asarray(out)[:, 0, :].T

    return inverse_map, f"n={len(sp.source_det_matched)}"


def run_spalipy_affine(case):
    return run_spalipy(case, spline_order=0)


RUNNERS = {"astroalign_nd": run_astroalign_nd, "astroalign": run_astroalign,
           "aafitrans": run_aafitrans, "spalipy": run_spalipy,
           "spalipy-affine": run_spalipy_affine}


def _worker(method, inq, outq):
    warnings.simplefilter("ignore")
    runner = RUNNERS[method]
    while True:
        case = inq.get()
        if case is None:
            return
        t0 = time.perf_counter()
        try:
            inverse_map, note = runner(case)
            dt = time.perf_counter() - t0
            err = np.nan if case.truth is None else error_from_inverse(inverse_map, case)
            outq.put(("returned", err, dt, note))
        except Exception as exc:  # noqa: BLE001 - every failure is counted, none is fatal
            dt = time.perf_counter() - t0
            outq.put(("failed", np.nan, dt, f"{type(exc).__name__}: {str(exc)[:70]}"))


class Worker:
    """One method in its own process, with a time limit per call."""

    def __init__(self, method, ctx, timeout):
        self.method, self.ctx, self.timeout = method, ctx, timeout
        self._start()

    def _start(self):
        self.inq, self.outq = self.ctx.Queue(), self.ctx.Queue()
        self.proc = self.ctx.Process(target=_worker, args=(self.method, self.inq, self.outq),
                                     daemon=True)
        self.proc.start()
        # Warm-up (imports), outside the timing.
        self.call(_pair_case("warm-up", 0, shape=(256, 256), n_stars=80, rotation=10.0,
                             **BRIGHT), timeout=max(self.timeout, 300))

    def call(self, case, timeout=None):
        self.inq.put(case)
        try:
            return self.outq.get(timeout=timeout or self.timeout)
        except queue.Empty:
            self.proc.kill()
            self.proc.join()
            self._start()
            return ("failed", np.nan, float(self.timeout), f"time-out ({self.timeout:g} s)")

    def close(self):
        try:
            self.inq.put(None)
            self.proc.join(5)
        finally:
            if self.proc.is_alive():
                self.proc.kill()


# -- main -----------------------------------------------------------------------------------

def classify(case, status, err):
    if case.refuse:
        return "ok" if status == "failed" else "wrong"
    if status != "returned":
        return "fail"
    return "ok" if err <= 1.0 else "wrong"


def main(argv=None):
    ap = argparse.ArgumentParser(description=TITLE)
    ap.add_argument("--seeds", type=int, default=3, help="seeds per category (default 3)")
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--cases", nargs="*", default=None,
                    help="only categories whose name contains one of these strings")
    ap.add_argument("--methods", nargs="*", default=list(METHODS), choices=METHODS)
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per call (default 60)")
    ap.add_argument("-v", "--verbose", action="store_true", help="one line per run")
    args = ap.parse_args(argv)

    names = [n for n in CASES
             if not args.cases or any(c.lower() in n.lower() for c in args.cases)]
    if not names:
        ap.error(f"no category matches {args.cases}; categories: {list(CASES)}")
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))

    print(TITLE)
    print(f"seeds {seeds}; time limit {args.timeout:g} s per call; success = within 1 px over "
          "the overlap; wrong = returned but > 1 px off (or any transform for unrelated fields)")
    print("aafitrans is fed astroalign_nd.find_sources detections (100 brightest; it uses 50); "
          "spalipy uses its own sep detection, min_n_match=10; astroalign its own sep detection.")
    print("median err: over the runs that returned a transform; median time: over all runs "
          "(wall clock of the call, detection included).\n", flush=True)

    ctx = mp.get_context("spawn")
    workers = {}
    t_start = time.perf_counter()
    try:
        for m in args.methods:
            workers[m] = Worker(m, ctx, args.timeout)
        summary = {}
        for name in names:
            rows = {m: [] for m in args.methods}
            for seed in seeds:
                case = CASES[name](seed)
                for m in args.methods:
                    status, err, dt, note = workers[m].call(case)
                    verdict = classify(case, status, err)
                    rows[m].append((verdict, err, dt, note))
                    if args.verbose:
                        print(f"    {name} seed {seed} {m:14s} {verdict:5s} err {err:8.3f} px "
                              f"{dt:7.3f} s  {note}", flush=True)
            summary[name] = rows
            print_category(name, rows, len(seeds))
        print_summary(summary, args.methods, len(seeds))
        print(f"\ntotal wall time {time.perf_counter() - t_start:.0f} s")
    finally:
        for w in workers.values():
            w.close()


def _stats(runs):
    ok = sum(v == "ok" for v, *_ in runs)
    wrong = sum(v == "wrong" for v, *_ in runs)
    warned = sum(v == "wrong" and "warned" in note for v, _, _, note in runs)
    fail = sum(v == "fail" for v, *_ in runs)
    errs = [e for _, e, _, _ in runs if np.isfinite(e)]
    med_err = float(np.median(errs)) if errs else np.nan
    med_t = float(np.median([t for _, _, t, _ in runs]))
    return ok, wrong, warned, fail, med_err, med_t


def print_category(name, rows, n):
    print(f"== {name} ({n} seeds) ==")
    print(f"  {'method':14s} {'success':>8s} {'wrong':>6s} {'warned':>7s} {'failed':>7s} "
          f"{'median err':>11s} {'median time':>12s}  last message")
    for m, runs in rows.items():
        ok, wrong, warned, fail, med_err, med_t = _stats(runs)
        last = next((note for v, _, _, note in reversed(runs) if v != "ok"), "")
        err_s = "-" if not np.isfinite(med_err) else f"{med_err:.3f} px"
        print(f"  {m:14s} {ok:>4d}/{n:<3d} {wrong:>6d} {warned:>7d} {fail:>7d} {err_s:>11s} "
              f"{med_t:>10.2f} s  {last[:60]}")
    print(flush=True)


def print_summary(summary, methods, n):
    print("== summary: successes/runs [wrong answers, w = of which warned], median error px ==")
    width = 19
    print(f"{'category':42s}" + "".join(f"{m:>{width}s}" for m in methods))
    tot = {m: [0, 0, 0] for m in methods}
    for name, rows in summary.items():
        cells = []
        for m in methods:
            ok, wrong, warned, fail, med_err, _ = _stats(rows[m])
            tot[m][0] += ok
            tot[m][1] += wrong
            tot[m][2] += len(rows[m])
            e = "" if not np.isfinite(med_err) else f" {med_err:.2f}"
            w = f" [{wrong}{f' {warned}w' if warned else ''}]" if wrong else ""
            cells.append(f"{ok}/{n}{w}{e}")
        print(f"{name:42s}" + "".join(f"{c:>{width}s}" for c in cells))
    print(f"{'TOTAL successes / wrong answers':42s}"
          + "".join(f"{f'{t[0]}/{t[2]} / {t[1]}':>{width}s}" for t in tot.values()))


if __name__ == "__main__":
    sys.exit(main())
