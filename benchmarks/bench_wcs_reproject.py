"""
astroalign_nd against what a ccdproc user with WCS frames would call:
`reproject.reproject_interp` and `ccdproc.wcs_project`.

A 4096x4096 float32 pair of the second simulator of ``bench_speed_workloads.py``
(photutils Moffat stars) with a known similarity transform; both frames get
TAN WCSs consistent with it (the target's: 0.5 arcsec per pixel about
RA 150, Dec 30; the source's: the target's composed with the transform), so
that reprojecting by WCS and registering by stars solve the same problem.
Timed in one run, interleaved, median of ``--repeats``:

- ``register``: astroalign_nd from the pixels alone (detection, matching,
  bilinear resampling, CCDData output with mask);
- ``apply_transform`` of the true transform (resampling and output only);
- ``reproject_interp(..., order='bilinear')`` from the WCSs;
- ``ccdproc.wcs_project(..., order='bilinear')`` from the WCSs (CCDData out,
  with its mask);
- ``astroalign.register``, for the usual ratio.

The outputs are compared where all are defined (median and 99th percentile
of the absolute difference, relative to the sky noise), which checks that
the WCSs agree with the transform (``wcs_project``'s output is divided by
the ratio of the pixel areas, which it multiplies by to conserve flux).

Usage::

    PYTHONPATH=. python benchmarks/bench_wcs_reproject.py --size 4096 --repeats 3
"""

import argparse
import os
import sys
import time
import warnings

import numpy as np

warnings.simplefilter("ignore")
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_speed_workloads import frame_error, photutils_pair  # noqa: E402


def wcs_pair(truth, size):
    """TAN WCSs (source, target) such that source pixel p and target pixel T(p) see one sky."""
    from astropy.wcs import WCS

    wt = WCS(naxis=2)
    wt.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    wt.wcs.crval = [150.0, 30.0]
    c = (size - 1) / 2.0
    wt.wcs.crpix = [c + 1.0, c + 1.0]  # FITS pixels are 1-based
    cd_t = np.array([[-0.5, 0.0], [0.0, 0.5]]) / 3600.0
    wt.wcs.cd = cd_t
    a, t = truth[:2, :2], truth[:2, 2]
    ws = WCS(naxis=2)
    ws.wcs.ctype = wt.wcs.ctype
    ws.wcs.crval = wt.wcs.crval
    # world(p) = TAN(CD_t (A p + t - r_t)) = TAN(CD_t A (p - A^-1 (r_t - t)))
    ws.wcs.cd = cd_t @ a
    ws.wcs.crpix = np.linalg.solve(a, np.array([c, c]) - t) + 1.0
    return ws, wt


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=4096)
    ap.add_argument("--stars", type=int, default=3000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    import astroalign
    import ccdproc
    import reproject
    from astropy.nddata import CCDData
    from reproject import reproject_interp

    import astroalign_nd

    src, dst, truth = photutils_pair(args.size, args.stars, 7)
    ws, wt = wcs_pair(truth, args.size)
    csrc = CCDData(src, unit="adu", wcs=ws)
    cdst = CCDData(dst, unit="adu", wcs=wt)
    shape = dst.shape
    tr, _ = astroalign_nd.find_transform(csrc, cdst)
    print(f"{args.size}x{args.size} float32, {args.stars} stars; astroalign_nd from "
          f"{os.path.dirname(astroalign_nd.__file__)}; reproject {reproject.__version__}, "
          f"ccdproc {ccdproc.__version__}, astroalign {astroalign.__version__}; "
          f"load average {os.getloadavg()[0]:.1f}")
    err = frame_error(tr.matrix, truth, shape)
    print(f"transform error of astroalign_nd's match: {err:.4f} px")
    # The true transform as a model, for apply_transform.
    from astroalign_nd.transforms import from_matrix

    true_model = from_matrix(truth)

    tools = {
        "astroalign_nd register": lambda: astroalign_nd.register(csrc, cdst).data,
        "astroalign_nd apply_transform (known)":
            lambda: astroalign_nd.apply_transform(true_model, csrc, cdst).data,
        "reproject_interp bilinear":
            lambda: reproject_interp((src, ws), wt, shape_out=shape, order="bilinear")[0],
        "ccdproc.wcs_project bilinear":
            lambda: ccdproc.wcs_project(csrc, wt, target_shape=shape, order="bilinear").data,
        "astroalign.register": lambda: astroalign.register(src, dst)[0],
    }
    astroalign_nd.register(src[:1024, :1024], src[:1024, :1024])  # warm-up (imports)
    times = {k: [] for k in tools}
    outs = {}
    for _ in range(args.repeats):
        for name, fn in tools.items():
            t0 = time.perf_counter()
            outs[name] = fn()
            times[name].append(time.perf_counter() - t0)
    med = {k: float(np.median(v)) for k, v in times.items()}
    ours = med["astroalign_nd register"]
    print(f"\nmedian of {args.repeats} (s), and astroalign_nd register's time as a fraction:")
    for name, t in med.items():
        print(f"  {name:>40}: {t:8.3f} s   ours / this {ours / t:6.3f}")
    ref = np.asarray(outs["reproject_interp bilinear"], float)
    noise = float(np.std(dst[:200, :200]))
    print(f"\nagreement with reproject_interp where both are defined (sky noise {noise:.1f}):")
    # wcs_project conserves flux: it multiplies by the ratio of the pixel areas.
    area_ratio = 1.0 / abs(np.linalg.det(truth[:2, :2]))
    for name in ("astroalign_nd register", "astroalign_nd apply_transform (known)",
                 "ccdproc.wcs_project bilinear"):
        o = np.asarray(outs[name], float)
        if name.startswith("ccdproc"):
            o = o / area_ratio
        ok = np.isfinite(o) & np.isfinite(ref)
        # Pixels next to the edge of the source differ by the edge convention.
        d = np.abs(o - ref)[ok]
        print(f"  {name:>40}: median |diff| {np.median(d) / noise:.2e} noise, 99th percentile "
              f"{np.percentile(d, 99) / noise:.2e} noise, over {ok.mean():.1%} of the pixels")


if __name__ == "__main__":
    main()
