"""
The trust cases: astroalign_nd, astroalign and aafitrans on the same pairs.

Each case is drawn by `simulate_trust_case` (tests/_frame_defects.py) (seeds
``--first-seed`` to ``--first-seed + n - 1``):

* ``trailed``: 512x512 frames of 20-40 stars, the source's trailed over
  4-10 px;
* ``sparse_8bit``: 512x512 8-bit frames of 9-19 stars, one slightly trailed;
* ``resampled_copy``: a raw frame with cosmic rays and hot pixels against its
  copy rotated by 2 degrees, shifted by (35, -12) px and resampled (order 3),
  plus 2% noise.

Every tool runs with its defaults on the same images (aafitrans on
astroalign's detections, as its README does, and as ``aafitrans-nd`` on
astroalign_nd's; see ``bench_real.py``).  An
outcome is

* **solved**: a transform whose largest error over the overlap of the frames
  (a grid of target points, ``bench_real.error``) is at most ``--wrong`` px
  (default 1 px);
* **wrong**: a transform with a larger error.  A warning does not excuse it:
  a wrong answer with a `~astroalign_nd.PoorFitWarning` counts as wrong;
* **refused**: an exception (or a time-out of ``--timeout`` seconds).

The report gives, per case and per tool, solved / wrong / refused out of N,
the median and largest error of the returned transforms, the median time,
and the tool's time over astroalign's on the same pair (median and 90th
percentile; over all pairs, and over the pairs the tool refused).  FITSH
(``fitsh``: fistar + grmatch, `bench_real.run_fitsh`) runs when installed.
Use ``-v`` for one line per run (with the refusal's message).

Usage::

    python benchmarks/bench_trust_cases.py [--n 200] [--cases ...] [--methods ...]
        [--wrong 1.0] [--timeout 60] [-v]
"""

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # _frame_defects
from bench_real import METHODS, RUNNERS, call, error, time_ratio  # noqa: E402

from _frame_defects import TRUST_CASES, simulate_trust_case  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--n", type=int, default=200, help="pairs per case (default 200)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--cases", nargs="*", default=list(TRUST_CASES), choices=TRUST_CASES)
    ap.add_argument("--methods", nargs="*", default=list(METHODS) + ["aafitrans-nd"],
                    choices=list(RUNNERS))
    ap.add_argument("--wrong", type=float, default=1.0,
                    help="largest error (px) of a solved pair (default 1)")
    ap.add_argument("--timeout", type=int, default=60, help="seconds per call (default 60)")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")  # counted by outcome, not by warning
    t_start = time.perf_counter()
    table, times, refused = {}, {}, set()
    warm = simulate_trust_case(args.cases[0], seed=args.first_seed)
    for method in args.methods:  # imports and first-call costs outside the timing
        call(method, np.asarray(warm.source, float), np.asarray(warm.target, float),
             args.timeout)
    for case in args.cases:
        for k in range(args.n):
            seed = args.first_seed + k
            pair = simulate_trust_case(case, seed=seed)
            src = np.asarray(pair.source, float)
            dst = np.asarray(pair.target, float)
            for method in args.methods:
                status, m, dt, note = call(method, src, dst, args.timeout)
                row = table.setdefault((case, method), dict(solved=0, wrong=0, refused=0,
                                                            err=[], t=[]))
                row["t"].append(dt)
                times[(case, seed), method] = dt
                if status != "returned":
                    outcome = "refused"
                    refused.add(((case, seed), method))
                else:
                    err = error(m, pair.truth_matrix, src.shape, dst.shape)
                    row["err"].append(err)
                    outcome = "solved" if err <= args.wrong else "wrong"
                    note = f"error {err:.3f} px, {note}"
                row[outcome] += 1
                if args.verbose:
                    print(f"{case:15s} seed {seed:4d} {method:14s} {outcome:8s} {dt:7.3f} s "
                          f"{note}", flush=True)
    print(f"\n{args.n} pairs per case (seeds {args.first_seed}-{args.first_seed + args.n - 1}); "
          f"solved: error <= {args.wrong:g} px over the overlap, wrong: larger, "
          "refused: an exception or a time-out\n")
    print(f"{'case':15s} {'method':14s} {'solved':>7s} {'wrong':>6s} {'refused':>8s} "
          f"{'median err':>11s} {'max err':>8s} {'median t':>9s} {'t / aa (p90)':>13s} "
          f"{'refused t / aa':>15s}")
    for (case, method), row in table.items():
        err = np.array(row["err"])
        med = f"{np.median(err):.3f}" if len(err) else "-"
        mx = f"{err.max():.2f}" if len(err) else "-"
        t = {k: v for k, v in times.items() if k[0][0] == case}
        print(f"{case:15s} {method:14s} {row['solved']:7d} {row['wrong']:6d} "
              f"{row['refused']:8d} {med:>11s} {mx:>8s} {np.median(row['t']):8.2f}s "
              f"{time_ratio(t, method):>13s} {time_ratio(t, method, refused):>15s}")
    if "astroalign" in args.methods:
        print("\nall cases, time / astroalign's on the same pair, median (90th percentile): "
              + ", ".join(f"{m} {time_ratio(times, m)}, refused {time_ratio(times, m, refused)}"
                          for m in args.methods if m != "astroalign"))
    print(f"\ntotal wall time {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
