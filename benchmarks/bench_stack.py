"""
Stacking: ``astroalign_nd.stack`` against astroalign + numpy / ccdproc.

Two inputs, each run by every tool in the same process, one after the other:

* the five HAT-P-32 frames of ``../shared/data/real`` (650x500, one night,
  drifting by up to 275 px; skipped when the data are absent): the time of
  ``astroalign_nd.stack`` (reference grid, and the union canvas) and of
  the peer: ``astroalign.register`` of each frame onto the reference, then
  a numpy average (``np.nanmean`` over the footprints) and ccdproc's
  ``Combiner`` (sigma clipping, average).  Reported: seconds (best of
  ``--repeats``), the ratio, the masked pixel count of each stack, and for
  the union canvas the pixels no frame reaches computed independently (each
  canvas pixel mapped back into each frame through astroalign's
  transforms), the uncertainty plane, the frames the header lists, and the
  sky noise of the reference alone and of each stack (robust sigma of the
  sky, the same pixels).
* ten simulated 256x256 frames with a known noise sigma, cosmic rays (60
  per frame; and a second set without) and a satellite trail
  (``simulate_sequence``): the largest deviation from the
  noiseless truth in units of each stack's uncertainty where >= 5 frames
  overlap (astroalign + ccdproc has no uncertainty: its deviation is in
  units of sigma / sqrt(n)), and the stack's sky uncertainty against
  sigma / sqrt(10).  The peer's frames that astroalign cannot register
  (its detection takes cosmic rays for stars) are counted and left out.

Usage::

    python benchmarks/bench_stack.py --out /tmp/stack
"""

import argparse
import glob
import json
import os
import sys
import time
import warnings

import numpy as np

warnings.filterwarnings("ignore")

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "shared", "data", "real", "pairs",
                    "exotic_hatp32_microobservatory")


def _best(f, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t0)
    return min(times), out


def _peer(frames, ref):
    """astroalign.register of each frame onto the reference, then numpy and ccdproc averages."""
    import astroalign
    from astropy.nddata import CCDData
    from ccdproc import Combiner

    aligned, transforms, failed = [ref.astype(np.float64)], [np.eye(3)], 0
    for f in frames:
        try:
            t, _ = astroalign.find_transform(f, ref)
        except Exception:  # noqa: BLE001 - the peer's failures are counted, not fatal
            failed += 1
            continue
        img, footprint = astroalign.apply_transform(t, f, ref)
        img = img.astype(np.float64)
        img[footprint] = np.nan
        aligned.append(img)
        transforms.append(t.params)
    cube = np.array(aligned)
    t0 = time.perf_counter()
    mean = np.nanmean(cube, axis=0)
    t_numpy = time.perf_counter() - t0
    t0 = time.perf_counter()
    ccds = [CCDData(a, mask=~np.isfinite(a), unit="adu") for a in aligned]
    comb = Combiner(ccds)
    comb.sigma_clipping(low_thresh=3, high_thresh=3)
    clipped = comb.average_combine()
    t_ccdproc = time.perf_counter() - t0
    return dict(mean=mean, ccdproc=clipped, transforms=transforms, t_numpy=t_numpy,
                t_ccdproc=t_ccdproc, failed=failed)


def _unreached(transforms, shapes, ref_shape):
    """Canvas pixels that no frame reaches, from the peer's transforms (bilinear margin 0)."""
    from astroalign_nd.batch import union_canvas

    shape, (x0, y0) = union_canvas(transforms[1:], shapes[1:], ref_shape)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    pts = np.stack([xx.ravel() + x0, yy.ravel() + y0, np.ones(xx.size)])
    reach = np.zeros(xx.size, bool)
    for m, (h, w) in zip(transforms, shapes):
        src = np.linalg.inv(m) @ pts
        eps = 1e-6
        reach |= ((src[0] >= -eps) & (src[0] <= w - 1 + eps) & (src[1] >= -eps)
                  & (src[1] <= h - 1 + eps))
    return shape, int((~reach).sum())


def _sky_sigma(img, sky):
    from astroalign_nd.stacking.combine import robust_sigma

    v = np.asarray(img, float)[sky]
    return robust_sigma(v[np.isfinite(v)])


def run_real(repeats):
    from astropy.io import fits

    import astroalign_nd

    paths = sorted(glob.glob(os.path.join(DATA, "*.FITS")))
    if len(paths) != 5:
        return None
    data = [fits.getdata(p).astype(np.float32) for p in paths]
    t_nd, ccd = _best(lambda: astroalign_nd.stack(paths), repeats)
    t_union, union = _best(lambda: astroalign_nd.stack(paths, canvas="union"), repeats)
    t_peer, peer = _best(lambda: _peer(data[1:], data[0]), repeats)
    shape, unreached = _unreached(peer["transforms"], [d.shape for d in data],
                                  data[0].shape)
    # Sky: pixels every frame reaches, away from the stars (below the reference's median + 1 sigma).
    ref = data[0]
    med, sig = np.median(ref), _sky_sigma(ref, np.ones(ref.shape, bool))
    sky = (ccd.flags == 5) & (ref < med + sig) & np.isfinite(peer["mean"])
    h = ccd.meta
    return dict(
        frames=[os.path.basename(p) for p in paths],
        header_frames=[h[f"IMCMB{k:03d}"] for k in range(1, h["NCOMBINE"] + 1)],
        seconds_nd_stack=t_nd, seconds_nd_stack_union=t_union,
        seconds_astroalign_register_plus_numpy=t_peer - peer["t_ccdproc"],
        seconds_astroalign_register_plus_ccdproc=t_peer - peer["t_numpy"],
        ratio_nd_vs_astroalign_numpy=t_nd / (t_peer - peer["t_ccdproc"]),
        ratio_nd_vs_astroalign_ccdproc=t_nd / (t_peer - peer["t_numpy"]),
        frames_failed_astroalign=peer["failed"],
        masked_px_reference_canvas=int(ccd.mask.sum()),
        masked_px_union_canvas=int(union.mask.sum()), union_shape=list(union.shape),
        unreached_px_union_from_astroalign_transforms=unreached,
        union_shape_from_astroalign_transforms=list(shape),
        uncertainty_plane=type(ccd.uncertainty).__name__,
        uncertainty_finite_fraction=float(np.isfinite(ccd.uncertainty.array).mean()),
        sky_sigma_reference_alone=_sky_sigma(ref, sky),
        sky_sigma_nd_stack=_sky_sigma(ccd.data, sky),
        sky_sigma_nd_stack_predicted=float(np.median(ccd.uncertainty.array[sky])),
        sky_sigma_astroalign_numpy=_sky_sigma(peer["mean"], sky),
        sky_sigma_astroalign_ccdproc=_sky_sigma(peer["ccdproc"].data, sky),
    )


def run_simulated(repeats, n_cosmic_rays=60):
    from astropy.nddata import CCDData

    import astroalign_nd
    from astroalign_nd.simulate import add_satellite_trail, simulate_sequence

    sigma = 10.0
    seq = simulate_sequence((256, 256), n_frames=10, n_stars=200, noise_sigma=sigma,
                            sky_drift=0.3, n_cosmic_rays=n_cosmic_rays, seed=29)
    f = seq.frames[3]
    seq.frames[3] = CCDData(add_satellite_trail(f.data, (-10, 30), (270, 220)),
                            uncertainty=f.uncertainty, unit="adu")
    t_nd, ccd = _best(lambda: astroalign_nd.stack(seq.frames), repeats)
    plain = astroalign_nd.stack(seq.frames, clip=None, normalize=None)
    arrays = [np.asarray(fr.data) for fr in seq.frames]
    t_peer, peer = _best(lambda: _peer(arrays[1:], arrays[0]), repeats)
    deep = ccd.flags >= 5
    dev = np.abs(ccd.data - seq.truth) / ccd.uncertainty.array
    dev_plain = np.abs(plain.data - seq.truth) / plain.uncertainty.array
    # The peer's combination keeps each frame's sky: compare after removing the median offset.
    pc = np.asarray(peer["ccdproc"].data, float)
    pc = pc - np.nanmedian(pc - seq.truth)
    dev_peer = np.abs(pc - seq.truth)[deep] / (sigma / np.sqrt(ccd.flags[deep]))
    sky = deep & (seq.truth < seq.sky[0] + 1.0) & (ccd.flags == 10)
    return dict(
        seconds_nd_stack=t_nd, seconds_astroalign_register_plus_ccdproc=t_peer - peer["t_numpy"],
        ratio_nd_vs_astroalign_ccdproc=t_nd / (t_peer - peer["t_numpy"]),
        frames_failed_nd=int(ccd.meta["NREJECT"]), frames_failed_astroalign=peer["failed"],
        max_dev_sigma_nd_clipped=float(np.nanmax(dev[deep])),
        max_dev_sigma_nd_unclipped=float(np.nanmax(dev_plain[deep])),
        max_dev_sigma_astroalign_ccdproc=float(np.nanmax(dev_peer)),
        sky_uncertainty_over_sigma_sqrt10=float(np.median(ccd.uncertainty.array[sky])
                                                / (sigma / np.sqrt(10))),
        sky_scatter_over_sigma_sqrt10=float(np.std((ccd.data - seq.truth)[sky])
                                            / (sigma / np.sqrt(10))),
    )


def _markdown(res):
    lines = ["# Stacking: astroalign_nd.stack vs astroalign + numpy/ccdproc", ""]
    for name, block in res.items():
        if block is None:
            lines += [f"## {name}: skipped (data absent)", ""]
            continue
        lines += [f"## {name}", "", "| figure | value |", "|---|---|"]
        for k, v in block.items():
            if isinstance(v, float):
                v = f"{v:.4g}"
            lines.append(f"| {k} | {v} |")
        lines.append("")
    return "\n".join(lines)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--out", default=None, help="write OUT.json and OUT.md")
    args = p.parse_args()
    import astroalign_nd

    print(f"astroalign_nd from {os.path.dirname(astroalign_nd.__file__)}", file=sys.stderr)
    res = dict(hatp32_real=run_real(args.repeats), simulated_10=run_simulated(args.repeats),
               simulated_10_trail_only=run_simulated(args.repeats, n_cosmic_rays=0))
    text = _markdown(res)
    print(text)
    if args.out:
        with open(args.out + ".json", "w") as f:
            json.dump(res, f, indent=1)
        with open(args.out + ".md", "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
