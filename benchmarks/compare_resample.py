"""
Bit-for-bit check of a change to the resampler: the arrays it returns on fixed inputs.

Resamples fixed random images (float32 and float64, 2-D and 3-channel)
through three affine matrices (a rotation with scale, a shift, a shear), with
every order, with no variance, a variance, a standard deviation (in the data's
type and in float64), an inverse variance, with and without a mask, and with
and without ``conserve_flux``, and a 2600x2600 float32 frame (several bands
of output rows) with a mask and a variance or standard deviation; saves
every data, variance and mask array to
an ``.npz`` file.  Run it on the tree before a change and on the tree after;
``--compare`` reports every array that differs (exact equality, NaN equal to
NaN).

Usage::

    PYTHONPATH=/old/tree python benchmarks/compare_resample.py --out before.npz
    PYTHONPATH=. python benchmarks/compare_resample.py --out after.npz
    python benchmarks/compare_resample.py --compare before.npz after.npz
"""

import argparse

import numpy as np


def _cases():
    rng = np.random.default_rng(5)
    data = rng.normal(100, 10, (300, 280))
    std = rng.uniform(1, 3, data.shape)
    bad = rng.random(data.shape) < 0.01
    th = np.deg2rad(33.0)
    mats = [
        np.array([[1.1 * np.cos(th), -1.1 * np.sin(th), 160.0],
                  [1.1 * np.sin(th), 1.1 * np.cos(th), -20.0], [0, 0, 1]]),
        np.array([[1.0, 0, 2.5], [0, 1, -3.0], [0, 0, 1]]),
        np.array([[0.97, 0.02, 3.3], [-0.01, 1.02, 1.1], [0, 0, 1]]),
    ]
    for dt in (np.float32, np.float64):
        d, s = data.astype(dt), std.astype(dt)
        rgb = np.stack([d, d * 2, d + 1], -1)
        for mi, m in enumerate(mats):
            for order in range(4):
                for kind, var in (("none", None), ("variance", s * s), ("stddev", s),
                                  ("inverse", 1 / (s * s)), ("stddev64", std)):
                    for mk in (None, bad):
                        for cf in (False, True):
                            k = {"none": "variance", "stddev64": "stddev"}.get(kind, kind)
                            key = f"{dt.__name__}_{mi}_{order}_{kind}_{mk is not None}_{cf}"
                            yield key, (d, m, order), dict(variance=var, mask=mk,
                                                           conserve_flux=cf, _variance_kind=k)
                key = f"rgb_{dt.__name__}_{mi}_{order}"
                yield key, (rgb, m, order), dict(variance=s * s, mask=bad)
    # A frame large enough for several bands of output rows (issue 16's banded
    # working planes, before the kernel read the mask and standard deviation).
    big = rng.normal(100, 10, (2600, 2600)).astype(np.float32)
    big_std = rng.uniform(1, 3, big.shape).astype(np.float32)
    big_bad = rng.random(big.shape) < 0.001
    for order in (1, 3):
        for kind, var in (("variance", big_std * big_std), ("stddev", big_std)):
            yield f"large_{order}_{kind}", (big, mats[0], order), dict(
                variance=var, mask=big_bad, _variance_kind=kind, shape_out=(2500, 2700))


def run(out):
    from astroalign_nd.resample import resample

    res = {}
    for key, (d, m, order), kw in _cases():
        o = resample(d, m, kw.pop("shape_out", (290, 310)), order=order, **kw)
        res[key + "_d"], res[key + "_m"] = o[0], o[2]
        if o[1] is not None:
            res[key + "_v"] = o[1]
    np.savez(out, **res)
    print(f"{len(res)} arrays written to {out}")


def compare(a, b):
    ra, rb = np.load(a), np.load(b)
    keys = sorted(set(ra.files) | set(rb.files))
    ndiff = 0
    for k in keys:
        if k not in ra.files or k not in rb.files:
            ndiff += 1
            print(f"{k}: only in {'after' if k not in ra.files else 'before'}")
        elif not np.array_equal(ra[k], rb[k], equal_nan=True):
            ndiff += 1
            x, y = ra[k].astype(float), rb[k].astype(float)
            with np.errstate(invalid="ignore", divide="ignore"):
                rel = np.nanmax(np.abs(x - y) / np.maximum(np.abs(x), 1e-300))
            print(f"{k}: differs in {np.sum(~((x == y) | (np.isnan(x) & np.isnan(y))))} of "
                  f"{x.size} elements (max relative difference {rel:.3g})")
    print(f"{len(keys)} arrays compared, {ndiff} different")
    return ndiff


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out")
    ap.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    args = ap.parse_args(argv)
    if args.compare:
        return 1 if compare(*args.compare) else 0
    if not args.out:
        ap.error("give --out FILE or --compare BEFORE AFTER")
    run(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
