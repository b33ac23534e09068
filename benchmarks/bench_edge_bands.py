"""
Frames with a bright band along one edge: no false accepts, same answers.

Raw CCD frames often carry a band along their first rows (row 0 at 25
sigma above the sky, fading over a few rows); a detector that judges
candidates against the whole frame reports the band's noise peaks as a
row of "stars", and a matcher can pair two such rows by chance: a
transform fixed along one line only, confidently wrong elsewhere.
astroalign_nd, astroalign and aafitrans run on the same inputs, with their
defaults (aafitrans on astroalign_nd's detections, as bench_hard_cases
does):

* unrelated images: two independent `simulate_field` frames, each with
  `add_edge_band` along its bottom edge.  Any transform returned is a false
  accept;
* unrelated catalogs: the same geometry as star lists (as a detector that
  reports a band gives them: a row of detections on y = 0 in the source,
  y = 0.65 in the target, among unrelated stars);
* related images: a `simulate_pair` with and without the band on both
  frames.  Solved within 1 px of the truth over the frame, and the change
  of the answer (largest over the frame) that the band causes.

Usage::

    python benchmarks/bench_edge_bands.py [--seeds 50] [--related 20] [--first-seed 0]
        [--amplitude 25] [--decay 1] [--tools astroalign_nd astroalign aafitrans]
"""

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import astroalign_nd as aand
from astroalign_nd.simulate import simulate_field, simulate_pair

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # _frame_defects
from _frame_defects import add_edge_band  # noqa: E402

TOOLS = ("astroalign_nd", "astroalign", "aafitrans")
SHAPE = (512, 512)
FRAME = (-0.5, SHAPE[1] - 0.5, -0.5, SHAPE[0] - 0.5)


def _xy(data):
    if data.ndim == 2 and data.shape[1] == 2:
        return data
    tab = aand.find_sources(data, n_sources=100)
    return np.column_stack([np.asarray(tab["x"], float), np.asarray(tab["y"], float)])


def solve(tool, source, target):
    """The tool's source -> target matrix, or None when it refuses."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if tool == "astroalign_nd":
                return aand.find_transform(source, target)[0].matrix
            if tool == "astroalign":
                import astroalign
                return astroalign.find_transform(source, target)[0].params
            import aafitrans
            return aafitrans.find_transform(_xy(source), _xy(target))[0].params
    except Exception:  # noqa: BLE001 - every refusal counts, whatever its type
        return None


def timed(tool, source, target):
    t0 = time.perf_counter()
    m = solve(tool, source, target)
    return m, time.perf_counter() - t0


def band_catalog(rng, n_band, n_stars, row):
    """Unrelated stars and a row of detections on ``y = row`` (brightest first: mixed)."""
    stars = rng.uniform(0.0, SHAPE[1] - 1.0, (n_stars, 2))
    band = np.column_stack([rng.uniform(0.0, SHAPE[1] - 1.0, n_band),
                            row + rng.normal(0.0, 0.05, n_band)])
    pts = np.vstack([band, stars])
    return pts[rng.permutation(len(pts))]


def max_offset(m1, m2):
    """Largest distance between two matrices' images of a grid over the frame."""
    g = np.linspace(0.0, SHAPE[0] - 1.0, 9)
    xx, yy = np.meshgrid(g, g)
    pts = np.vstack([xx.ravel(), yy.ravel(), np.ones(xx.size)])
    d = (np.asarray(m1) @ pts - np.asarray(m2) @ pts)[:2]
    return float(np.hypot(*d).max())


def run_unrelated(tools, seeds, first, amplitude, decay):
    rows = {t: [0, []] for t in tools}
    cat_rows = {t: [0, []] for t in tools}
    for i in range(first, first + seeds):
        a, _ = simulate_field(SHAPE, seed=10_000 + 2 * i)
        b, _ = simulate_field(SHAPE, seed=10_001 + 2 * i)
        a = add_edge_band(a, edge="bottom", amplitude=amplitude, decay=decay, seed=3 * i)
        b = add_edge_band(b, edge="bottom", amplitude=amplitude, decay=decay, seed=3 * i + 1)
        rng = np.random.default_rng(i)
        n_band = (40, 60)[i % 2]
        cs, cd = (band_catalog(rng, n_band, 100 - n_band, 0.0),
                  band_catalog(rng, n_band, 100 - n_band, 0.65))
        for t in tools:
            m, dt = timed(t, a, b)
            rows[t][0] += m is not None
            rows[t][1].append(dt)
            m, dt = timed(t, cs, cd)
            cat_rows[t][0] += m is not None
            cat_rows[t][1].append(dt)
    return rows, cat_rows


def run_related(tools, seeds, first, amplitude, decay):
    out = {t: {"plain": 0, "band": 0, "change": [], "time": []} for t in tools}
    for i in range(first, first + seeds):
        pair = simulate_pair(SHAPE, seed=20_000 + i)
        sb = add_edge_band(pair.source, edge="bottom", amplitude=amplitude, decay=decay,
                           seed=3 * i)
        tb = add_edge_band(pair.target, edge="bottom", amplitude=amplitude, decay=decay,
                           seed=3 * i + 1)
        for t in tools:
            m0 = solve(t, pair.source, pair.target)
            m1, dt = timed(t, sb, tb)
            ok0 = m0 is not None and max_offset(m0, pair.truth_matrix) < 1.0
            ok1 = m1 is not None and max_offset(m1, pair.truth_matrix) < 1.0
            out[t]["plain"] += ok0
            out[t]["band"] += ok1
            out[t]["time"].append(dt)
            if ok0 and ok1:
                out[t]["change"].append(max_offset(m0, m1))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--seeds", type=int, default=50, help="unrelated pairs (default 50)")
    ap.add_argument("--related", type=int, default=20, help="related pairs (default 20)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--amplitude", type=float, default=25.0)
    ap.add_argument("--decay", type=float, default=1.0)
    ap.add_argument("--tools", nargs="*", default=list(TOOLS), choices=TOOLS)
    args = ap.parse_args(argv)

    rows, cat_rows = run_unrelated(args.tools, args.seeds, args.first_seed, args.amplitude,
                                   args.decay)
    rel = run_related(args.tools, args.related, args.first_seed, args.amplitude, args.decay)
    print(f"\nEdge band (amplitude {args.amplitude:g} sigma, decay {args.decay:g} px), "
          f"{SHAPE[1]}x{SHAPE[0]}, seeds from {args.first_seed}")
    print(f"{'tool':<14} {'FA images':>10} {'FA catalogs':>12} {'t unrel':>8} "
          f"{'solved plain':>13} {'solved band':>12} {'change med':>11} {'change max':>11} "
          f"{'>0.05px':>8} {'t rel':>7}")
    for t in args.tools:
        r = rel[t]
        ch = np.array(r["change"]) if r["change"] else np.array([np.nan])
        print(f"{t:<14} {rows[t][0]:>5}/{args.seeds:<4} {cat_rows[t][0]:>6}/{args.seeds:<5} "
              f"{np.median(rows[t][1]):>7.2f}s {r['plain']:>8}/{args.related:<4} "
              f"{r['band']:>7}/{args.related:<4} {np.nanmedian(ch):>10.3f}  "
              f"{np.nanmax(ch):>10.3f} {int(np.sum(ch > 0.05)):>8} "
              f"{np.median(r['time']):>6.2f}s")
    print("FA: false accepts (any transform returned for unrelated frames); t: median time "
          "per call; change: largest shift over the frame between the answers with and "
          "without the band (pairs solved both ways, within 1 px of the truth).")


if __name__ == "__main__":
    main()
