"""
astroalign_nd vs astroalign on the seed paper's grid of simulated pairs.

Both tools' ``find_transform`` run on the *same* simulated source/target
pairs over the grid of the astroalign paper: square sizes 256, 512, 768,
1024; 300, 500, 1000, 10000 stars in the source frame; sky background
(Poisson lambda, counts per pixel) 100, 500, 1000, 5000 -- 64 cells.

Each pair has a random similarity transform: rotation uniform in [0, 360)
degrees, scale log-uniform in [0.8, 1.25], a continuous (sub-pixel) random
shift of the frame centres uniform in +-5% of the size along each axis; the
source FWHM is uniform in [2.5, 4] pixels (the target has the same seeing on
the sky, i.e. FWHM * scale).  Fluxes follow the simulator's default
luminosity function.  Noise is ``noise='gaussian'`` (the normal
approximation of Poisson photon noise plus read noise, accurate at these
backgrounds and much faster to simulate).

Per pair, the transform error is the largest displacement, over a grid of
target pixels p, of ``T_est(T_true^-1(p)) - p`` (pixels).  A *success* is a
returned transform with error <= 1 px; a *wrong answer* is a returned
transform with error > 1 px; otherwise the tool gave up (raised).

Usage::

    python benchmarks/bench_grid.py [--pairs 3] [--sizes 256 512] [--stars 300]
        [--backgrounds 100 5000] [--seed 0] [--out results.csv]
"""

import argparse
import csv
import os
import sys
import time
import warnings

import numpy as np

import astroalign_nd as aand
from astroalign_nd.simulate import simulate_pair
from astroalign_nd.transforms import as_matrix

SIZES = (256, 512, 768, 1024)
STARS = (300, 500, 1000, 10000)
BACKGROUNDS = (100, 500, 1000, 5000)
SCALE_RANGE = (0.8, 1.25)
SHIFT_FRACTION = 0.05
NOISE = "gaussian"
TOL = 1.0  # pixels: success threshold
GRID = 17  # error grid: GRID x GRID target points, corners included

# The simulator's default luminosity function (read from its signature so
# that the printed value is the one actually used).
import inspect as _inspect  # noqa: E402

_SIG = _inspect.signature(simulate_pair).parameters
FLUX_RANGE = tuple(_SIG["flux_range"].default)
FLUX_INDEX = _SIG["flux_index"].default
READ_NOISE = _SIG["read_noise"].default


def code_version():
    """git HEAD of the package's checkout (read-only queries), '+dirty' if modified."""
    import subprocess

    root = os.path.dirname(os.path.dirname(os.path.abspath(aand.__file__)))
    try:
        head = subprocess.run(["git", "-C", root, "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", root, "status", "--porcelain", "--",
                                "astroalign_nd"], capture_output=True, text=True,
                               timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return aand.__version__
    return (head + ("+dirty" if dirty else "")) if head else aand.__version__


def transform_error(m_est, m_true, shape):
    """max over a grid of target pixels p of |T_est(T_true^-1(p)) - p| (pixels)."""
    ny, nx = shape
    gx, gy = np.meshgrid(np.linspace(-0.5, nx - 0.5, GRID), np.linspace(-0.5, ny - 0.5, GRID))
    p = np.vstack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
    q = np.linalg.solve(m_true, p)
    r = m_est @ q
    return float(np.max(np.hypot(r[0] - p[0], r[1] - p[1])))


def draw_pair(size, n_stars, background, k, seed, fwhm_range):
    """The k-th pair of a cell: its own seed, so subsets reproduce the same pairs."""
    ss = np.random.SeedSequence([seed, size, n_stars, int(background), k])
    rng = np.random.default_rng(ss)
    rotation = float(rng.uniform(0.0, 360.0))
    scale = float(np.exp(rng.uniform(np.log(SCALE_RANGE[0]), np.log(SCALE_RANGE[1]))))
    translation = rng.uniform(-SHIFT_FRACTION, SHIFT_FRACTION, 2) * size
    fwhm = float(rng.uniform(*fwhm_range))
    sim_seed = int(rng.integers(0, 2**31))
    t0 = time.perf_counter()
    pair = simulate_pair((size, size), n_stars=n_stars, rotation=rotation, scale=scale,
                         translation=translation, fwhm=fwhm, background=background,
                         noise=NOISE, seed=sim_seed)
    t_sim = time.perf_counter() - t0
    params = dict(rotation=rotation, scale=scale, dx=float(translation[0]),
                  dy=float(translation[1]), fwhm=fwhm, sim_seed=sim_seed, t_sim=t_sim)
    return pair, params


def run_ours(pair):
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model, _ = aand.find_transform(pair.source, pair.target)
        dt = time.perf_counter() - t0
        q = model.meta.get("quality", {})
        return as_matrix(model), dt, "", dict(n_matches=q.get("n_matches"),
                                              rms=q.get("rms"))
    except aand.AstroalignError as exc:
        return None, time.perf_counter() - t0, f"{type(exc).__name__}: {exc}"[:200], {}
    except Exception as exc:  # noqa: BLE001 - a crash, reported as such
        return None, time.perf_counter() - t0, f"CRASH {type(exc).__name__}: {exc}"[:200], {}


def run_astroalign(aa, pair):
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            tform, (s, _) = aa.find_transform(pair.source, pair.target)
        dt = time.perf_counter() - t0
        return np.asarray(tform.params, float), dt, "", dict(n_matches=len(s), rms=None)
    except Exception as exc:  # noqa: BLE001 - MaxIterError, ValueError (too few stars)...
        return None, time.perf_counter() - t0, f"{type(exc).__name__}: {exc}"[:200], {}


def _fmt(v, spec):
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def _median(vals):
    vals = [v for v in vals if v is not None and np.isfinite(v)]
    return float(np.median(vals)) if vals else None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--pairs", type=int, default=3, help="pairs per cell (default 3)")
    ap.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    ap.add_argument("--stars", type=int, nargs="+", default=list(STARS))
    ap.add_argument("--backgrounds", type=float, nargs="+", default=list(BACKGROUNDS))
    ap.add_argument("--fwhm-range", type=float, nargs=2, default=(2.5, 4.0),
                    metavar=("MIN", "MAX"), help="source FWHM range (equal values: fixed)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="CSV file of every pair")
    args = ap.parse_args(argv)

    import astroalign as aa

    version = code_version()
    print(f"astroalign_nd {aand.__version__} (checkout {version}) vs astroalign "
          f"{aa.__version__}")
    from astroalign_nd._kernels import num_threads

    print(f"CPUs: {os.cpu_count()}, astroalign_nd threads: {num_threads()}")
    print(f"pairs per cell: {args.pairs}; sizes {args.sizes}; stars {args.stars}; "
          f"backgrounds {[int(b) if b == int(b) else b for b in args.backgrounds]}; "
          f"seed {args.seed}")
    print(f"transform: rotation U[0, 360) deg, scale log-uniform in {list(SCALE_RANGE)}, "
          f"shift U(+-{SHIFT_FRACTION:.0%} of size) per axis (sub-pixel), "
          f"source FWHM U{list(args.fwhm_range)} px (target FWHM = FWHM * scale)")
    print(f"fluxes: simulator default flux_range={FLUX_RANGE}, flux_index={FLUX_INDEX} "
          f"(N(>F) ~ F^-{FLUX_INDEX}); read noise {READ_NOISE}; noise='{NOISE}' "
          f"(normal approximation of Poisson; exact enough at backgrounds >= 100)")
    print(f"success: returned and max error <= {TOL} px over a {GRID}x{GRID} grid of "
          f"target pixels; 'wrong' = returned but > {TOL} px off")

    # Warm-up (lazy imports) outside the timings.
    warm, _ = draw_pair(256, 300, 100.0, 0, args.seed + 12345, args.fwhm_range)
    run_ours(warm)
    run_astroalign(aa, warm)

    fields = ["size", "n_stars", "background", "pair", "rotation", "scale", "dx", "dy",
              "fwhm", "sim_seed", "t_sim", "n_src_true", "n_tgt_true",
              "ours_status", "ours_error", "ours_time", "ours_n_matches", "ours_rms",
              "ours_message",
              "aa_status", "aa_error", "aa_time", "aa_n_matches", "aa_message",
              "code_version"]
    rows = []
    cells = [(s, n, b) for s in args.sizes for n in args.stars for b in args.backgrounds]
    t_start = time.perf_counter()
    for ic, (size, n_stars, bg) in enumerate(cells):
        for k in range(args.pairs):
            pair, prm = draw_pair(size, n_stars, bg, k, args.seed, args.fwhm_range)
            row = dict(size=size, n_stars=n_stars, background=bg, pair=k, **prm,
                       code_version=version,
                       n_src_true=len(pair.source_stars), n_tgt_true=len(pair.target_stars))
            shape = pair.target.shape
            for name, runner in (("ours", run_ours), ("aa", lambda p: run_astroalign(aa, p))):
                m, dt, msg, extra = runner(pair)
                if m is None:
                    status, err = ("crash" if msg.startswith("CRASH") else "fail"), None
                else:
                    err = transform_error(m, pair.truth_matrix, shape)
                    status = "ok" if err <= TOL else "wrong"
                row.update({f"{name}_status": status, f"{name}_error": err,
                            f"{name}_time": dt, f"{name}_message": msg,
                            f"{name}_n_matches": extra.get("n_matches")})
                if name == "ours":
                    row["ours_rms"] = extra.get("rms")
            rows.append(row)
            print(f"[{ic + 1}/{len(cells)}] {size:5d} {n_stars:6d} {bg:6g} #{k}: "
                  f"ours {row['ours_status']:5s} {_fmt(row['ours_error'], '.3f'):>7s} "
                  f"{row['ours_time']:6.2f}s | aa {row['aa_status']:5s} "
                  f"{_fmt(row['aa_error'], '.3f'):>7s} {row['aa_time']:6.2f}s "
                  f"(sim {prm['t_sim']:.1f}s, {time.perf_counter() - t_start:.0f}s total)"
                  f"{'  ours: ' + row['ours_message'] if row['ours_status'] != 'ok' else ''}"
                  f"{'  aa: ' + row['aa_message'][:60] if row['aa_status'] == 'fail' else ''}",
                  flush=True)

    if args.out:
        d = os.path.dirname(args.out)
        if d:
            os.makedirs(d, exist_ok=True)
        with open(args.out, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=fields)
            w.writeheader()
            for r in rows:
                w.writerow({k: r.get(k) for k in fields})
        print(f"\nwrote {len(rows)} pairs to {args.out}")

    report(rows, cells, args.pairs)
    return 0


def report(rows, cells, npairs):
    print("\nPer cell (n = pairs; succ = success rate; wrong = returned but > 1 px off; "
          "err = median error of successes [px]; t = median find_transform time [s]; "
          "t-ratio = t_ours / t_aa; paired = median of err_ours / err_aa over the pairs "
          "both solved, with their count)")
    hdr = (f"{'size':>5} {'stars':>6} {'bkg':>5} {'n':>2} | {'succ':>5} {'wrong':>5} "
           f"{'err':>6} {'t':>6} | {'aa succ':>7} {'wrong':>5} {'err':>6} {'t':>6} | "
           f"{'t-ratio':>7} {'paired':>9}  flags")
    print(hdr)
    print("-" * len(hdr))
    worse_success, worse_error, crash_cells, worse_paired = [], [], [], []
    ratios = []
    for (size, n_stars, bg) in cells:
        rr = [r for r in rows if (r["size"], r["n_stars"], r["background"]) == (size, n_stars, bg)]
        n = len(rr)
        so = sum(r["ours_status"] == "ok" for r in rr)
        sa = sum(r["aa_status"] == "ok" for r in rr)
        wo = sum(r["ours_status"] == "wrong" for r in rr)
        wa = sum(r["aa_status"] == "wrong" for r in rr)
        co = sum(r["ours_status"] == "crash" for r in rr)
        eo = _median([r["ours_error"] for r in rr if r["ours_status"] == "ok"])
        ea = _median([r["aa_error"] for r in rr if r["aa_status"] == "ok"])
        to = _median([r["ours_time"] for r in rr])
        ta = _median([r["aa_time"] for r in rr])
        ratio = to / ta if to and ta else None
        if ratio:
            ratios.append(ratio)
        both = [r for r in rr if r["ours_status"] == "ok" and r["aa_status"] == "ok"]
        paired = _median([r["ours_error"] / r["aa_error"] for r in both if r["aa_error"] > 0])
        if paired is not None and paired > 0.5:
            worse_paired.append((size, n_stars, bg, paired, len(both)))
        flags = []
        if so < sa:
            flags.append("SUCC<AA")
            worse_success.append((size, n_stars, bg, so, sa, n))
        if eo is not None and ea is not None and eo > 0.5 * ea:
            flags.append("ERR>AA/2")
            worse_error.append((size, n_stars, bg, eo, ea))
        if wo:
            flags.append(f"OURS WRONG x{wo}")
        if co:
            flags.append(f"CRASH x{co}")
            crash_cells.append((size, n_stars, bg))
        print(f"{size:5d} {n_stars:6d} {bg:5g} {n:2d} | {so / n:5.0%} {wo:5d} "
              f"{_fmt(eo, '.3f'):>6} {_fmt(to, '.2f'):>6} | {sa / n:7.0%} {wa:5d} "
              f"{_fmt(ea, '.3f'):>6} {_fmt(ta, '.2f'):>6} | {_fmt(ratio, '.2f'):>7} "
              f"{_fmt(paired, '.2f'):>5} ({len(both)})  {' '.join(flags)}")

    n = len(rows)
    print("\nSummary")
    for name, label in (("ours", "astroalign_nd"), ("aa", "astroalign")):
        ok = [r for r in rows if r[f"{name}_status"] == "ok"]
        wrong = sum(r[f"{name}_status"] == "wrong" for r in rows)
        fail = sum(r[f"{name}_status"] == "fail" for r in rows)
        crash = sum(r[f"{name}_status"] == "crash" for r in rows)
        med_err = _median([r[f"{name}_error"] for r in ok])
        med_t = _median([r[f"{name}_time"] for r in rows])
        print(f"  {label:14s} success {len(ok)}/{n} ({len(ok) / n:.1%}), wrong answers {wrong}, "
              f"gave up {fail}, crashes {crash}; median error of successes "
              f"{_fmt(med_err, '.4f')} px; median time {_fmt(med_t, '.3f')} s")
    both = [r for r in rows if r["ours_status"] == "ok" and r["aa_status"] == "ok"]
    if both:
        print(f"  on the {len(both)} pairs both solved: median error ours "
              f"{_median([r['ours_error'] for r in both]):.4f} px vs astroalign "
              f"{_median([r['aa_error'] for r in both]):.4f} px; ours more accurate on "
              f"{sum(r['ours_error'] < r['aa_error'] for r in both)}/{len(both)}")
    only_o = sum(r["ours_status"] == "ok" and r["aa_status"] != "ok" for r in rows)
    only_a = sum(r["aa_status"] == "ok" and r["ours_status"] != "ok" for r in rows)
    print(f"  pairs solved only by ours: {only_o}; only by astroalign: {only_a}")
    pr = [r["ours_time"] / r["aa_time"] for r in rows if r["aa_time"] > 0]
    print(f"  time ratio ours/astroalign: median over cells {_fmt(_median(ratios), '.2f')}, "
          f"median over pairs {_fmt(_median(pr), '.2f')}")
    print(f"  cells where our success rate < astroalign's (target: none): "
          f"{len(worse_success)}")
    for s, k, b, so, sa, nn in worse_success:
        print(f"    size {s} stars {k} bkg {b:g}: ours {so}/{nn} vs astroalign {sa}/{nn}")
    print(f"  cells where our median error > half of astroalign's (target: none): "
          f"{len(worse_error)}")
    for s, k, b, eo, ea in worse_error:
        print(f"    size {s} stars {k} bkg {b:g}: ours {eo:.3f} px vs astroalign {ea:.3f} px")
    print("  (the unpaired medians above compare different pairs where astroalign solves "
          "only the easier ones;\n   paired view) cells where the median of err_ours/err_aa "
          f"over pairs both solved > 0.5: {len(worse_paired)}")
    for s, k, b, pr, nb in worse_paired:
        print(f"    size {s} stars {k} bkg {b:g}: median ratio {pr:.2f} over {nb} pair(s)")
    if crash_cells:
        print(f"  cells where astroalign_nd crashed (non-AstroalignError): {crash_cells}")


if __name__ == "__main__":
    sys.exit(main())
