"""
Loop closure of distortion models on a real night sequence (issue 18).

The five HAT-P-32 frames of ``../shared/data/real/pairs`` drift by up to
275 px over the detector during the night.  No truth is known, but the
transforms of a consistent method close loops: over each triplet i, j, k,
``T_jk(T_ij(p))`` must land where ``T_ik(p)`` does.  This prints, for the
affine model and ``transform_type='polynomial'`` with ``degree='auto'`` and
``degree=2``, the largest loop non-closure over the part of frame i that
all three frames see (median over the 10 triplets, and the worst), and the
median over the frame.

Usage::

    python benchmarks/bench_distortion_loops.py [--data ../shared/data]
"""

import argparse
import itertools
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_real import DEFAULT_DATA, load  # noqa: E402

SETTINGS = (dict(transform_type="affine"),
            dict(transform_type="polynomial", degree="auto"),
            dict(transform_type="polynomial", degree=2))


def main(argv=None):
    import astroalign_nd

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    hat = sorted((args.data / "real" / "pairs" / "exotic_hatp32_microobservatory").glob("*.FITS"))
    imgs = [load(p)[0] for p in hat]
    ny, nx = imgs[0].shape
    gx, gy = np.meshgrid(np.linspace(0, nx - 1, 40), np.linspace(0, ny - 1, 40))
    for kw in SETTINGS:
        t = {(i, j): astroalign_nd.find_transform(imgs[i], imgs[j], **kw)[0]
             for i, j in itertools.combinations(range(len(imgs)), 2)}
        chosen = [str(m.meta["quality"].get("degree", 1)) for m in t.values()]
        res = []
        for i, j, k in itertools.combinations(range(len(imgs)), 3):
            mx, my = t[i, j](gx, gy)
            ax, ay = t[j, k](mx, my)
            bx, by = t[i, k](gx, gy)
            inside = np.ones(gx.shape, bool)
            for x, y in ((mx, my), (ax, ay), (bx, by)):
                inside &= (x >= 0) & (x < nx) & (y >= 0) & (y < ny)
            d = np.hypot(ax - bx, ay - by)[inside]
            res.append((d.max(), np.median(d)))
        r = np.array(res)
        print(f"{str(kw):55s} degrees {','.join(chosen)}: loop closure over {len(r)} triplets: "
              f"median of max {np.median(r[:, 0]):.3f} px, worst {r[:, 0].max():.3f} px, "
              f"median {np.median(r[:, 1]):.3f} px", flush=True)


if __name__ == "__main__":
    main()
