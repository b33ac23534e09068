# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
What does full CCDData output (mask and uncertainty) cost over data alone?

For square float32 images (default 1024 and 4096 pixels on a side) this
times, on the same simulated source and the true transform:

(a) ``astroalign_nd.apply_transform`` on an ndarray          -> data + mask
(b) ``astroalign_nd.apply_transform`` on a CCDData with a
    StdDevUncertainty                                        -> data + mask + uncertainty
(b+m) as (b) with an input mask (0.1 % bad pixels)           -> same, mask-checking path
(c) bare ``astroalign_nd.resample.resample(data, matrix, shape)``, no
    variance, no input mask (the compiled kernel alone)
(c+v) ``resample`` with the variance array (kernel cost of the variance)
(d) ``astroalign.apply_transform`` (scikit-image ``warp``, cubic spline)
    for reference

All astroalign_nd calls use bilinear interpolation (the default) and the
parallel kernel.  Each case gets one warm-up call, reported separately as
"first call" (the very first call of the process also pays for lazy
imports), then the median of ``--repeat`` timed calls.

Run::

    PYTHONPATH=. python benchmarks/bench_ccddata.py [--sizes 1024 4096] [--repeat 5]
"""

import argparse
import gc
import time

import numpy as np


def _time_once(fn):
    gc.collect()
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _time_cases(cases, repeat):
    """First-call time, then ``repeat`` rounds over all cases (round-robin, so that
    a change of machine load hits every case alike); median and min per case."""
    first = [_time_once(fn) for _, fn in cases]
    times = [[] for _ in cases]
    for _ in range(repeat):
        for i, (_, fn) in enumerate(cases):
            times[i].append(_time_once(fn))
    return [(label, f, float(np.median(t)), float(np.min(t)))
            for (label, _), f, t in zip(cases, first, times)]


def bench_size(n, repeat):
    import astroalign
    from astropy.nddata import CCDData, StdDevUncertainty

    import astroalign_nd as aa
    from astroalign_nd.resample import resample
    from astroalign_nd.simulate import simulate_pair
    from astroalign_nd.transforms import to_skimage

    t0 = time.perf_counter()
    pair = simulate_pair((n, n), n_stars=int(1000 * (n / 1024) ** 2), rotation=17.0,
                         scale=1.02, translation=(12.3, -7.7), noise="gaussian", seed=1,
                         dtype=np.float32)
    t_sim = time.perf_counter() - t0
    src, tgt, t = pair.source, pair.target, pair.transform
    assert src.dtype == np.float32
    sigma = np.sqrt(np.maximum(src, 0.0) + 25.0).astype(np.float32)
    ccd = CCDData(src, unit="adu", uncertainty=StdDevUncertainty(sigma))
    rng = np.random.default_rng(0)
    bad = rng.random(src.shape) < 1e-3
    ccd_m = CCDData(src, unit="adu", uncertainty=StdDevUncertainty(sigma), mask=bad)
    var = sigma.astype(np.float32) ** 2
    sk = to_skimage(t)

    cases = [
        ("(a) apply_transform ndarray: data+mask", lambda: aa.apply_transform(t, src, tgt)),
        ("(b) apply_transform CCDData+StdDev: full",
         lambda: aa.apply_transform(t, ccd, tgt)),
        ("(b+m) as (b) + input mask (0.1% bad)", lambda: aa.apply_transform(t, ccd_m, tgt)),
        ("(c) resample(data) kernel only", lambda: resample(src, t.matrix, tgt.shape,
                                                            order="bilinear")),
        ("(c+v) resample(data, variance)", lambda: resample(src, t.matrix, tgt.shape,
                                                            order="bilinear", variance=var)),
        ("(d) astroalign.apply_transform", lambda: astroalign.apply_transform(sk, src, tgt)),
    ]
    return t_sim, _time_cases(cases, repeat)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)

    import os

    from astroalign_nd._kernels import num_threads

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"astroalign_nd threads {num_threads()}, "
          f"cpus {os.cpu_count()}, load average {load:.2f}; median (and min) of "
          f"{args.repeat} round-robin calls after one warm-up call\n")
    for n in args.sizes:
        t_sim, rows = bench_size(n, args.repeat)
        ref = {label[:4]: med for label, _, med, _ in rows}
        data_only = ref["(a) "]
        full = ref["(b) "]
        print(f"{n}x{n} float32 (simulate_pair, noise='gaussian': {t_sim:.2f} s)")
        print(f"  {'case':42s} {'first call':>11s} {'median':>9s} {'min':>9s} "
              f"{'Mpix/s':>7s} {'/ (a)':>6s}")
        for label, first, med, best in rows:
            print(f"  {label:42s} {first:10.3f}s {med:8.3f}s {best:8.3f}s "
                  f"{n * n / med / 1e6:7.1f} {med / data_only:6.2f}")
        print(f"  full CCDData / data-only = (b)/(a) = {full / data_only:.2f}; "
              f"(a)/(c) wrapper overhead = {data_only / ref['(c) ']:.2f}; "
              f"(b)/(d) vs astroalign = {full / ref['(d) ']:.2f}")
        best = {label[:4]: b for label, _, _, b in rows}
        print(f"  by min: (b)/(a) = {best['(b) '] / best['(a) ']:.2f}; "
              f"(a)/(c) = {best['(a) '] / best['(c) ']:.2f}; "
              f"(b)/(d) = {best['(b) '] / best['(d) ']:.2f}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
