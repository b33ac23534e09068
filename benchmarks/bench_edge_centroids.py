"""
Centroids of stars cut by the frame's edge: astroalign_nd's detection
(``Reference(frame).stars``) against astroalign's (``astroalign._find_sources``,
sep), on the same simulated frames, in one run.

The frames are those of ``bench_global.run_sequences`` (256x256, 300 stars,
``--sequences`` sequences of ``--frames`` dithered frames), so the true
position of every star in every frame is known.  Each detection is paired
with the nearest true star (within 1 px); its error is split into the
component towards the frame's centre (positive: pulled inwards, away from
the nearest edge) and reported by the true star's distance to the nearest
edge: a centroid that counts the missing pixels as zero is pulled inwards
within about a FWHM of the edge.

Usage::

    python benchmarks/bench_edge_centroids.py [--sequences 4] [--frames 10]
        [--out /tmp/edge_centroids.txt]
"""

import argparse
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import astroalign_nd
from astroalign_nd import Reference
from astroalign_nd.simulate import dither_transforms, simulate_views
from astroalign_nd.transforms import as_matrix

try:
    import astroalign
except ImportError:  # the peer is optional
    astroalign = None

HERE = Path(__file__).resolve().parent
BANDS = [(0, 3), (3, 6), (6, 10), (10, 20), (20, 1000)]


def detections(frame, method):
    if method == "astroalign_nd":
        return np.asarray(Reference(frame).stars(500)[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pts = astroalign._find_sources(np.ascontiguousarray(frame, dtype=float))
    return np.asarray(pts, float)


def run(n_seq, n_frames, methods):
    shape = (256, 256)
    rows = {m: [] for m in methods}
    for s in range(n_seq):
        truth = dither_transforms(n_frames, max_shift=40, max_rotation=2, shape=shape,
                                  seed=100 + s)
        seq = simulate_views(truth, shape, n_stars=300, seed=200 + s)
        sky = np.column_stack([seq.stars["x"], seq.stars["y"]])
        flux = np.asarray(seq.stars["flux"], float)
        for i, frame in enumerate(seq.frames):
            inv = np.linalg.inv(as_matrix(seq.transforms[i]))
            true = sky @ inv[:2, :2].T + inv[:2, 2]
            tree = cKDTree(true)
            for m in methods:
                pts = detections(frame, m)
                if not len(pts):
                    continue
                d, j = tree.query(pts)
                ok = d < 1.0
                q, err = true[j[ok]], pts[ok] - true[j[ok]]
                edge = np.minimum.reduce([q[:, 0] + 0.5, shape[1] - 0.5 - q[:, 0],
                                          q[:, 1] + 0.5, shape[0] - 0.5 - q[:, 1]])
                c = q - [(shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0]
                inward = -np.sum(err * c, axis=1) / np.hypot(c[:, 0], c[:, 1])
                rows[m].append(np.column_stack([edge, inward, flux[j[ok]]]))
    return {m: np.vstack(r) for m, r in rows.items() if r}


def report(res):
    lines = ["Centroid error towards the frame's centre (px; positive: pulled inwards), "
             "by the true star's distance to the nearest edge", "",
             f"{'method':14s} {'edge (px)':10s} {'n':>6s} {'mean':>8s} {'+-':>7s} "
             f"{'rms':>7s} {'bright mean':>12s} {'n bright':>8s}"]
    for m, r in res.items():
        for lo, hi in BANDS:
            sel = (r[:, 0] >= lo) & (r[:, 0] < hi)
            if not sel.any():
                continue
            v = r[sel, 1]
            bright = sel & (r[:, 2] > 2000)
            bm = f"{np.mean(r[bright, 1]):+.4f}" if bright.any() else "-"
            lines.append(f"{m:14s} {f'{lo}-{hi}':10s} {sel.sum():6d} {np.mean(v):+8.4f} "
                         f"{np.std(v) / np.sqrt(sel.sum()):7.4f} "
                         f"{np.sqrt(np.mean(v ** 2)):7.4f} {bm:>12s} {bright.sum():8d}")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequences", type=int, default=4)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--out", default=None, help="also write the table to this file")
    args = ap.parse_args()
    methods = ["astroalign_nd"] + (["astroalign"] if astroalign is not None else [])
    text = (f"astroalign_nd {astroalign_nd.__version__}\n"
            + report(run(args.sequences, args.frames, methods)))
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
