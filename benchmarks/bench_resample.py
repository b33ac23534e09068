# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Benchmark of astroalign_nd.resample against scipy.ndimage and scikit-image.

Run from the repository root::

    python benchmarks/bench_resample.py [--sizes 1024 4096] [--repeat 5]

For each image size (float32) and a rotation + shift + 1.01 scale transform
it reports

* the median wall time of ``--repeat`` calls after one warm-up call, for
  our kernel (data only, and data + variance + mask) at bilinear and bicubic
  order, ``scipy.ndimage.affine_transform`` (order 1 and 3; order 3 includes
  its B-spline prefilter) and ``skimage.transform.warp`` order 3 (what
  astroalign's ``apply_transform`` uses);
* the first-call latency in a fresh Python process: the import of the
  library and the first call, separately (our kernel is compiled when the
  package is built, so there is nothing to compile or load at run time).
  The first-call subprocesses use a 1024x1024 image.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

ANGLE = np.deg2rad(7.0)
SCALE = 1.01
SHIFT = (12.3, -7.8)


def transform_matrix():
    """Source -> target matrix: rotation, 1.01 scale, shift."""
    c, s = SCALE * np.cos(ANGLE), SCALE * np.sin(ANGLE)
    return np.array([[c, -s, SHIFT[0]], [s, c, SHIFT[1]], [0.0, 0.0, 1.0]])


def make_image(n, seed=0):
    rng = np.random.default_rng(seed)
    return (100.0 + 10.0 * rng.standard_normal((n, n))).astype(np.float32)


# -- the contenders: each takes (image, variance, mask, matrix) -------------------

def ours(order, with_variance):
    from astroalign_nd.resample import resample

    def run(img, var, mask, m):
        if with_variance:
            return resample(img, m, img.shape, order=order, variance=var, mask=mask)
        return resample(img, m, img.shape, order=order)
    return run


def scipy_affine(order):
    from scipy import ndimage

    def run(img, var, mask, m):
        # ndimage works in (row, col) and wants the output -> input mapping.
        inv = np.linalg.inv(m)
        swap = np.array([[0, 1, 0], [1, 0, 0], [0, 0, 1]])
        rc = swap @ inv @ swap
        return ndimage.affine_transform(img, rc, order=order, mode="constant",
                                        cval=np.nan, output=np.float32)
    return run


def skimage_warp(order):
    from skimage.transform import AffineTransform, warp

    def run(img, var, mask, m):
        # As astroalign.apply_transform does it.
        return warp(img, inverse_map=AffineTransform(matrix=np.linalg.inv(m)),
                    output_shape=img.shape, order=order, mode="constant", cval=np.nan,
                    clip=False, preserve_range=True)
    return run


CONTENDERS = {
    "ours bilinear, data only": ("ours", 1, False),
    "ours bilinear, data+var+mask": ("ours", 1, True),
    "ours bicubic, data only": ("ours", 3, False),
    "ours bicubic, data+var+mask": ("ours", 3, True),
    "scipy affine_transform order=1": ("scipy", 1, None),
    "scipy affine_transform order=3": ("scipy", 3, None),
    "skimage warp order=3": ("skimage", 3, None),
}


def build(kind, order, with_variance):
    if kind == "ours":
        return ours(order, with_variance)
    if kind == "scipy":
        return scipy_affine(order)
    return skimage_warp(order)


def time_steady(n, repeat):
    img = make_image(n)
    var = np.abs(img)
    mask = np.zeros(img.shape, bool)
    mask[n // 3, n // 2] = True
    m = transform_matrix()
    results = {}
    for name, spec in CONTENDERS.items():
        fn = build(*spec)
        fn(img, var, mask, m)  # warm-up (JIT, caches, page faults)
        times = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            fn(img, var, mask, m)
            times.append(time.perf_counter() - t0)
        results[name] = statistics.median(times)
    return results


# -- first-call latency in a fresh interpreter ------------------------------------

_CHILD = """
import json, sys, time
t0 = time.perf_counter()
sys.path.insert(0, {root!r}); sys.path.insert(0, {bench!r})
import bench_resample as b
fn = b.build({kind!r}, {order}, {with_var})   # imports the library
t1 = time.perf_counter()
import numpy as np
img = b.make_image({n}); var = np.abs(img); mask = np.zeros(img.shape, bool)
t2 = time.perf_counter()
fn(img, var, mask, b.transform_matrix())
t3 = time.perf_counter()
print(json.dumps({{"import": t1 - t0, "first": t3 - t2}}))
"""


def first_call(kind, order, with_var, n, env=None):
    code = _CHILD.format(root=ROOT, bench=os.path.dirname(os.path.abspath(__file__)),
                         kind=kind, order=order, with_var=with_var, n=n)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def time_first_calls(n):
    return {name: first_call(*spec, n) for name, spec in CONTENDERS.items()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--no-first-call", action="store_true",
                        help="skip the fresh-process first-call measurements")
    args = parser.parse_args(argv)

    from astroalign_nd._kernels import num_threads

    print(f"python {sys.version.split()[0]}, numpy {np.__version__}, "
          f"{os.cpu_count()} CPUs, astroalign_nd threads {num_threads()}, "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"transform: rotation {np.rad2deg(ANGLE):.0f} deg, scale {SCALE}, shift {SHIFT}; "
          "float32 images\n")

    steady = {n: time_steady(n, args.repeat) for n in args.sizes}
    width = max(len(k) for k in CONTENDERS)
    header = f"{'median of %d (s)' % args.repeat:<{width}}" + "".join(
        f"{f'{n}x{n}':>12}" for n in args.sizes)
    print(header)
    print("-" * len(header))
    for name in CONTENDERS:
        print(f"{name:<{width}}" + "".join(f"{steady[n][name]:>12.3f}" for n in args.sizes))

    if not args.no_first_call:
        n = min(args.sizes)
        rows = time_first_calls(n)
        width = max(len(k) for k in rows)
        print(f"\n{'first call, fresh process, %dx%d' % (n, n):<{width}}"
              f"{'import (s)':>12}{'1st call (s)':>14}")
        print("-" * (width + 26))
        for name, r in rows.items():
            print(f"{name:<{width}}{r['import']:>12.2f}{r['first']:>14.2f}")


if __name__ == "__main__":
    main()
