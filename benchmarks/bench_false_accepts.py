"""
Unrelated pairs must raise, never return a transform.

Runs astroalign_nd and astroalign on the same pairs of *unrelated*
simulated fields (independent star positions) of varied density, from
sparse 10-star fields to 1000 stars, and counts false accepts: a returned
transform is always wrong here.

Usage::

    python benchmarks/bench_false_accepts.py [--pairs 200] [--seed 0]
"""

import argparse
import time
import warnings

import numpy as np

import astroalign_nd as aand
from astroalign_nd.simulate import simulate_field


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--pairs", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-astroalign", action="store_true")
    args = ap.parse_args(argv)
    try:
        import astroalign as aa
    except ImportError:
        aa = None
    if args.no_astroalign:
        aa = None

    rng = np.random.default_rng(args.seed)
    densities = [10, 12, 15, 20, 30, 50, 100, 300, 1000]
    ours = {"accept": 0, "reject": 0, "error": 0, "time": []}
    theirs = {"accept": 0, "reject": 0, "error": 0, "time": []}
    per_density = {d: [0, 0, 0] for d in densities}  # pairs, our FA, their FA
    for i in range(args.pairs):
        n = densities[i % len(densities)]
        shape = (256, 256) if n <= 50 else (512, 512)
        s1, s2 = rng.integers(0, 2**31, 2)
        a, _ = simulate_field(shape, n_stars=n, flux_range=(2e3, 3e5), seed=int(s1))
        b, _ = simulate_field(shape, n_stars=n, flux_range=(2e3, 3e5), seed=int(s2))
        per_density[n][0] += 1
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                aand.find_transform(a, b)
            ours["accept"] += 1
            per_density[n][1] += 1
        except aand.AstroalignError:
            ours["reject"] += 1
        except Exception as exc:  # noqa: BLE001 - counted and shown
            ours["error"] += 1
            print(f"  astroalign_nd raised {type(exc).__name__}: {exc}")
        ours["time"].append(time.perf_counter() - t0)
        if aa is not None:
            t0 = time.perf_counter()
            try:
                aa.find_transform(a, b)
                theirs["accept"] += 1
                per_density[n][2] += 1
            except Exception:  # noqa: BLE001 - astroalign raises various types
                theirs["reject"] += 1
            theirs["time"].append(time.perf_counter() - t0)

    print(f"\n{args.pairs} unrelated pairs (seed {args.seed})")
    print(f"{'stars':>6} {'pairs':>6} {'aa_nd false accepts':>20} {'astroalign false accepts':>25}")
    for d in densities:
        p, fa, fb = per_density[d]
        print(f"{d:>6} {p:>6} {fa:>20} {fb if aa is not None else '-':>25}")
    print(f"astroalign_nd: {ours['accept']} false accepts, {ours['reject']} correct refusals, "
          f"{ours['error']} other errors; median time {np.median(ours['time']):.3f} s, "
          f"max {np.max(ours['time']):.2f} s")
    if aa is not None:
        print(f"astroalign:    {theirs['accept']} false accepts, {theirs['reject']} refusals; "
              f"median time {np.median(theirs['time']):.3f} s, max {np.max(theirs['time']):.2f} s")
    return 1 if ours["accept"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
