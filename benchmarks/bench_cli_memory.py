"""
Peak memory of a FITS-to-FITS ``astroalign-nd register`` run on large frames
(the aim: at most 3 times the bytes of the input plus output frames).

Two float32 star fields of ``--size`` pixels on a side (default 16000, 1 GB
each) are written to ``--workdir`` with a known similarity transform between
them (a few thousand Gaussian stars, sky 200 counts, Gaussian noise), then
the command line registers one onto the other in a fresh process:

    python -m astroalign_nd.cli register SOURCE TARGET -o OUTPUT

and the process's peak resident memory (``ru_maxrss``, kernel-measured,
everything included: Python, imports, arrays) is reported, with the bytes
of the frames, the ratio, the time and the transform error against the
truth.  The files are deleted afterwards (``--keep`` keeps them).

Usage::

    PYTHONPATH=. python benchmarks/bench_cli_memory.py --workdir /tmp/big [--size 16000]
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import time

import numpy as np

from bench_speed import frame_error  # noqa: E402  (the same error as bench_speed's)

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _frame(size, x, y, flux, sigma, seed, path):
    """Write a float32 star field to ``path`` (built row band by row band)."""
    from astropy.io import fits

    rng = np.random.default_rng(seed)
    img = np.empty((size, size), np.float32)
    for r0 in range(0, size, 1000):
        r1 = min(size, r0 + 1000)
        img[r0:r1] = rng.standard_normal((r1 - r0, size), dtype=np.float32) * 15.0 + 200.0
    half = int(np.ceil(4 * sigma))
    g = np.arange(-half, half + 1)
    for xi, yi, fi in zip(x, y, flux):
        ix, iy = int(round(xi)), int(round(yi))
        if not (half <= ix < size - half and half <= iy < size - half):
            continue
        gx = np.exp(-0.5 * ((g + ix - xi) / sigma) ** 2)
        gy = np.exp(-0.5 * ((g + iy - yi) / sigma) ** 2)
        stamp = fi / (2 * np.pi * sigma**2) * np.outer(gy, gx)
        img[iy - half:iy + half + 1, ix - half:ix + half + 1] += stamp.astype(np.float32)
    fits.PrimaryHDU(img).writeto(path, overwrite=True)


def make_frames(size, n_stars, folder, seed=0):
    rng = np.random.default_rng(seed)
    theta, s = np.deg2rad(17.0), 1.01
    c = (size - 1) / 2.0
    a = s * np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    truth = np.eye(3)
    truth[:2, :2] = a
    truth[:2, 2] = np.array([c + 0.013 * size, c - 0.021 * size]) - a @ np.array([c, c])
    lo, hi = -0.25 * size, 1.25 * size
    n = int(n_stars * 2.25)
    x, y = rng.uniform(lo, hi, n), rng.uniform(lo, hi, n)
    flux = 2000.0 * (1.0 + rng.pareto(1.5, n))
    xt, yt = (truth @ np.vstack([x, y, np.ones(n)]))[:2]
    src, dst = os.path.join(folder, "big_source.fits"), os.path.join(folder, "big_target.fits")
    _frame(size, x, y, flux, 1.3, seed + 1, src)
    _frame(size, xt, yt, flux, 1.4, seed + 2, dst)
    return src, dst, truth


_CHILD = r"""
import json, resource, subprocess, sys, time
t0 = time.perf_counter()
res = subprocess.run(sys.argv[1:], capture_output=True, text=True)
t = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
print(json.dumps(dict(rc=res.returncode, time=t, peak=peak, out=res.stdout[-800:],
                      err=res.stderr[-2000:])))
"""


def run_cli(src, dst, out, pythonpath):
    env = dict(os.environ, PYTHONPATH=pythonpath)
    cmd = [sys.executable, "-m", "astroalign_nd.cli", "register", src, dst, "-o", out,
           "--overwrite"]
    res = subprocess.run([sys.executable, "-c", _CHILD, *cmd], capture_output=True, text=True,
                         env=env, cwd=pythonpath, timeout=900)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workdir", required=True, help="folder for the frames (deleted after)")
    ap.add_argument("--size", type=int, default=16000)
    ap.add_argument("--stars", type=int, default=4000)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--before", default=None, help="a source tree of an older astroalign_nd")
    ap.add_argument("--keep", action="store_true", help="keep the frames")
    args = ap.parse_args(argv)
    os.makedirs(args.workdir, exist_ok=True)
    t0 = time.perf_counter()
    src, dst, truth = make_frames(args.size, args.stars, args.workdir)
    print(f"{args.size}x{args.size} float32 frames written in {time.perf_counter() - t0:.0f} s; "
          f"load average {os.getloadavg()[0]:.1f}", flush=True)
    out = os.path.join(args.workdir, "big_aligned.fits")
    trees = [("astroalign_nd", HERE)]
    if args.before:
        trees.append(("before", os.path.abspath(args.before)))
    try:
        for rep in range(args.repeats):
            for name, tree in trees:
                r = run_cli(src, dst, out, tree)
                if r["rc"] != 0:
                    print(f"{name}: failed\n{r['err']}")
                    continue
                from astropy.io import fits

                from astroalign_nd.io.header import transform_from_header

                with fits.open(out, memmap=True) as hdul:
                    header = hdul[0].header
                    nbytes_out = sum(h.size
                                     for h in hdul if h.data is not None)
                    names = [f"{h.name}:{h.header.get('BITPIX')}" for h in hdul]
                    err = frame_error(transform_from_header(header).matrix, truth,
                                      (args.size, args.size))
                in_bytes = os.path.getsize(src) + os.path.getsize(dst)
                frame = args.size * args.size * 4
                print(f"{name}: peak RSS {r['peak'] / 1e9:.2f} GB, {r['time']:.1f} s; "
                      f"inputs {in_bytes / 1e9:.2f} GB, output {nbytes_out / 1e9:.2f} GB "
                      f"({' '.join(names)}); peak / (inputs + output) "
                      f"{r['peak'] / (in_bytes + nbytes_out):.2f}, peak / one float32 frame "
                      f"{r['peak'] / frame:.2f}; transform error {err:.4f} px", flush=True)
    finally:
        if not args.keep:
            for p in (src, dst, out):
                if os.path.exists(p):
                    os.unlink(p)
    print(f"own process peak {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB")


if __name__ == "__main__":
    main()
