"""
Bit-for-bit check of a change to detection's masked path: masks and NaNs.

``compare_transforms.py`` has no masked or non-finite input.  This runs
`~astroalign_nd.find_sources` on simulated frames (1024^2 to 1100x4000,
float32 and float64) with a mask, with NaN pixels, and with both, and
`~astroalign_nd.find_transform` from a masked `~astropy.nddata.CCDData`
(with a `~astropy.nddata.StdDevUncertainty`), from a frame with NaNs, and
from the 8192^2 masked CCDData of ``bench_ccddata.py memory``; it saves
every table column (bytes), table meta and matrix, and ``--compare``
reports the ones that differ.

Usage::

    PYTHONPATH=/old/tree python benchmarks/compare/compare_masked_detection.py --out before.pkl
    PYTHONPATH=. python benchmarks/compare/compare_masked_detection.py --out after.pkl
    python benchmarks/compare/compare_masked_detection.py --compare before.pkl after.pkl
"""

import pickle
import warnings

import numpy as np

from _command import run_command


def _results():
    import astroalign_nd as aa
    from astropy.nddata import CCDData, StdDevUncertainty

    from astroalign_nd.detection import find_sources
    from astroalign_nd.simulate import simulate_pair

    print(f"astroalign_nd from {aa.__file__}")
    res = {}
    rng = np.random.default_rng(2)
    for i, shape in enumerate([(1024, 1024), (1300, 1500), (2048, 2048), (1100, 4000)]):
        p = simulate_pair(shape, n_stars=400, rotation=11.0 * i, translation=(7.0, -5.0),
                          noise="gaussian", seed=10 + i)
        src = np.asarray(p.source, np.float32 if i % 2 else np.float64).copy()
        m = rng.random(shape) < 0.002 * (i + 1)
        m[100:130, 50:600] = True
        nan = src.copy()
        nan[rng.random(shape) < 0.001] = np.nan
        for name, img, mk in (("mask", src, m), ("nan", nan, None), ("nan+mask", nan, m)):
            t = find_sources(img, mask=mk, n_sources=200)
            for c in t.colnames:
                res[f"{shape} {name} find_sources {c}"] = np.asarray(t[c]).tobytes()
            res[f"{shape} {name} meta"] = repr(sorted((k, str(v)) for k, v in t.meta.items()))
        ccd = CCDData(src, unit="adu", mask=m,
                      uncertainty=StdDevUncertainty(np.sqrt(np.abs(src) + 25)))
        res[f"{shape} CCDData find_transform"] = np.asarray(
            aa.find_transform(ccd, p.target)[0].matrix).tobytes()
        res[f"{shape} nan find_transform"] = np.asarray(
            aa.find_transform(nan, p.target)[0].matrix).tobytes()
    n = 8192
    pair = simulate_pair((n, n), n_stars=3000, rotation=17.0, scale=1.01,
                         translation=(0.03 * n, -0.02 * n), noise="gaussian", seed=3)
    s8 = np.asarray(pair.source, np.float32)
    m8 = np.zeros(s8.shape, bool)
    m8[10:20, 10:400] = True
    m8.flat[np.random.default_rng(1).choice(m8.size, m8.size // 1000, replace=False)] = True
    res["8192 CCDData find_transform"] = np.asarray(aa.find_transform(
        CCDData(s8, unit="adu", mask=m8), np.asarray(pair.target, np.float32))[0].matrix
    ).tobytes()
    return res


def record(out):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = _results()
    with open(out, "wb") as f:
        pickle.dump(res, f)
    print(f"{len(res)} results written to {out}")


def compare(old, new):
    a, b = (pickle.load(open(f, "rb")) for f in (old, new))
    diff = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
    for k in diff:
        print("differs:", k)
    print(f"{len(set(a) | set(b))} results compared, {len(diff)} different")
    return len(diff)


def main(argv=None):
    return run_command(argv, __doc__, record, compare)


if __name__ == "__main__":
    raise SystemExit(main())
