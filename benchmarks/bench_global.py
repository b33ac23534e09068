"""
A night or a mosaic as one: `solve_sequence` (the global
solution) against pairwise registration to the reference (astroalign_nd's
``find_transform`` onto a ``Reference``, and astroalign's
``find_transform``), on the same inputs in one run.

Parts (each can be run alone with ``--only``):

* ``real``: the HAT-P-32 night (``real/pairs/exotic_hatp32_microobservatory``,
  5 frames) and the Seestar sequences (``field/seestar_m94_*``, 5 frames,
  and ``field/seestar_ngc7023_*``, 3 frames).  No truth: each frame's
  global transform is compared with the pairwise ones (largest difference
  over the frame), the pairwise transforms' loop closure over triplets
  (``max |T_jk(T_ij(p)) - T_ik(p)|`` over frame i; the global solution
  closes by construction) and the global solution's link residuals.
* ``mosaic``: a simulated 3x3 mosaic (256x256 tiles, 20% overlaps,
  reference at a corner): every tile's error against the truth.
* ``sequence``: simulated 30-frame dithered sequences (256x256, 300 stars,
  shifts up to 40 px, rotations up to 2 degrees, independent noise): the
  median over frames of the largest error over the frame, global against
  pairwise (ours and astroalign), pooled over ``--sequences``.
* ``long``: long sequences of catalogs (30, 100 and 300 frames, the same
  300 stars in every frame, 0.05 px noise, similarity and affine): global
  against pairwise (ours and astroalign), the mean scale error and the
  median largest error; equal precision is expected at any length.
* ``speed``: ``register_batch(solve='global')`` against
  ``register_batch`` (pairwise onto one reference), both from FITS files
  of ``--frames`` simulated 1024x1024 frames written to a temporary folder
  and resampled there.

Usage::

    python benchmarks/bench_global.py [--data ../shared/data] [--only real mosaic ...]
        [--sequences 8] [--frames 60] [--out /tmp/global]
"""

import argparse
import itertools
import json
import os
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from astropy.io import fits

import astroalign_nd
from astroalign_nd import Reference, find_transform, register_batch, solve_sequence
from astroalign_nd.simulate import (dither_transforms, draw_fluxes, mosaic_transforms,
                                    simulate_image, simulate_views)
from astroalign_nd.transforms import as_matrix

try:
    import astroalign
except ImportError:  # the peer is optional
    astroalign = None

HERE = Path(__file__).resolve().parent


def max_diff(a, b, shape):
    """Largest distance (px) over a grid of the frame between two transforms."""
    ny, nx = shape
    gx, gy = np.meshgrid(np.linspace(-0.5, nx - 0.5, 9), np.linspace(-0.5, ny - 0.5, 9))
    p = np.column_stack([gx.ravel(), gy.ravel()])
    ma, mb = as_matrix(a), as_matrix(b)
    d = p @ ma[:2, :2].T + ma[:2, 2] - (p @ mb[:2, :2].T + mb[:2, 2])
    return float(np.max(np.hypot(d[:, 0], d[:, 1])))


def read(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.asarray(fits.getdata(path), dtype=np.float32)


def aa_matrix(src, dst):
    """astroalign's source->target matrix, or None."""
    if astroalign is None:
        return None
    try:
        t, _ = astroalign.find_transform(src, dst)
    except Exception:  # noqa: BLE001 - astroalign's failure is a result
        return None
    return np.asarray(t.params, float)


def closure(mats, shapes):
    """Loop closure of pairwise matrices ``mats[(i, j)]`` over every triplet (px)."""
    out = []
    for i, j, k in itertools.permutations(range(len(shapes)), 3):
        if i < j < k and all(mats.get(p) is not None for p in ((i, j), (j, k), (i, k))):
            out.append(max_diff(mats[(j, k)] @ mats[(i, j)], mats[(i, k)], shapes[i]))
    return out


def real_sequence(name, paths):
    """The global solution against pairwise, on one real sequence."""
    t0 = time.perf_counter()
    sol = solve_sequence([str(p) for p in paths], reference=0)
    t_global = time.perf_counter() - t0
    data = [read(p) for p in paths]
    t0 = time.perf_counter()
    ref = Reference(str(paths[0]))
    ours = [np.eye(3)] + [as_matrix(find_transform(str(p), ref)[0]) for p in paths[1:]]
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    peer = [np.eye(3)] + [aa_matrix(d, data[0]) for d in data[1:]]
    t_aa = time.perf_counter() - t0
    shapes = [d.shape for d in data]
    n = len(paths)
    rows = []
    for i in range(n):
        g = sol.transforms[i]
        rows.append(dict(
            frame=Path(paths[i]).name, solved=g is not None,
            n_links=int(g.meta["quality"]["n_links"]) if g is not None else 0,
            predicted_error=float(sol.predicted_errors[i]),
            global_vs_ours=max_diff(g, ours[i], shapes[i]) if g is not None else None,
            global_vs_astroalign=(max_diff(g, peer[i], shapes[i])
                                  if g is not None and peer[i] is not None else None)))
    pair_ours = {(i, j): as_matrix(find_transform(str(paths[i]), str(paths[j]))[0])
                 for i, j in itertools.permutations(range(n), 2) if i < j}
    pair_aa = {(i, j): aa_matrix(data[i], data[j])
               for i, j in itertools.permutations(range(n), 2) if i < j}
    links = [dict(source=k.source, target=k.target, status=k.status, n_matches=k.n_matches,
                  own_rms=k.rms, residual_rms=k.residual_rms, misfit=k.misfit)
             for k in sol.links]
    return dict(name=name, n_frames=n, all_solved=all(r["solved"] for r in rows),
                frames=rows, links=links, n_stars=sol.n_stars,
                closure_ours=closure(pair_ours, shapes), closure_astroalign=closure(pair_aa,
                                                                                    shapes),
                seconds=dict(global_=t_global, pairwise_ours=t_ours, pairwise_astroalign=t_aa))


def run_real(data_dir):
    real = Path(data_dir) / "real" / "pairs" / "exotic_hatp32_microobservatory"
    field = Path(data_dir) / "field"
    seqs = [("HAT-P-32", sorted(real.glob("*.FITS"))),
            ("Seestar M94", sorted(field.glob("seestar_m94_*.fits.gz"))),
            ("Seestar NGC 7023", sorted(field.glob("seestar_ngc7023_*.fits.gz")))]
    return [real_sequence(name, paths) for name, paths in seqs if len(paths) >= 2]


def run_mosaic(seed=3):
    shape = (256, 256)
    truth = mosaic_transforms((3, 3), shape, overlap=0.2)
    seq = simulate_views(truth, shape, n_stars=500, flux_range=(5e3, 3e5), seed=seed)
    t0 = time.perf_counter()
    sol = solve_sequence(seq.frames, reference=0, n_stars=400)
    seconds = time.perf_counter() - t0
    errors = [max_diff(sol.transforms[i], seq.truth(i, 0), shape) if sol.transforms[i]
              is not None else None for i in range(9)]
    ref = Reference(seq.frames[0])
    pairwise = []
    for f in seq.frames[1:]:  # tiles that do not overlap the reference cannot be registered
        try:
            find_transform(f, ref)
            pairwise.append(True)
        except astroalign_nd.AstroalignError:
            pairwise.append(False)
    return dict(errors=errors, max_error=max(e for e in errors if e is not None),
                predicted=[float(v) for v in sol.predicted_errors], seconds=seconds,
                solved=sum(e is not None for e in errors),
                pairwise_solved=1 + sum(pairwise), n_links=len(sol.accepted))


def run_sequences(n_seq, n_stars=None):
    shape = (256, 256)
    glob, ours, peer, used = [], [], [], []
    t_g = t_o = 0.0
    for s in range(n_seq):
        truth = dither_transforms(30, max_shift=40, max_rotation=2, shape=shape, seed=100 + s)
        seq = simulate_views(truth, shape, n_stars=300, seed=200 + s)
        t0 = time.perf_counter()
        sol = solve_sequence(seq.frames, reference=0, n_stars=n_stars)
        t_g += time.perf_counter() - t0
        t0 = time.perf_counter()
        ref = Reference(seq.frames[0])
        pw = [find_transform(f, ref)[0] for f in seq.frames[1:]]
        t_o += time.perf_counter() - t0
        g = [max_diff(sol.transforms[i], seq.truth(i, 0), shape) for i in range(1, 30)]
        o = [max_diff(pw[i - 1], seq.truth(i, 0), shape) for i in range(1, 30)]
        a = [max_diff(m, seq.truth(i, 0), shape) if m is not None else np.inf
             for i, m in ((i, aa_matrix(seq.frames[i], seq.frames[0])) for i in range(1, 30))]
        used.append(np.median([t.meta["quality"]["n_matches"] for t in sol.transforms[1:]]))
        glob.append(np.median(g))
        ours.append(np.median(o))
        peer.append(np.median(a))
    return dict(per_sequence=dict(global_=glob, pairwise_ours=ours, pairwise_astroalign=peer),
                pooled_median_global=float(np.median(glob)),
                pooled_median_pairwise_ours=float(np.median(ours)),
                pooled_median_pairwise_astroalign=float(np.median(peer)),
                ratio_global_to_ours=float(np.median(glob) / np.median(ours)),
                seconds=dict(global_=t_g, pairwise_ours=t_o), n_stars=n_stars,
                detections_per_frame=float(np.median(used)))


def run_catalogs(n_seq, n_stars=300, sigma=0.05):
    """
    The control experiment: 30-frame dithered sequences of catalogs in
    which every frame holds the same ``n_stars`` stars, each with its own
    Gaussian centroid noise (``sigma`` px per axis).  Pairwise and global
    then fit the same stars (a catalog's every point refines the pairwise
    fit), so any difference comes from the solve, not from the star lists.
    """
    shape = (256, 256)
    glob, ours = [], []
    for s in range(n_seq):
        truth = dither_transforms(30, max_shift=40, max_rotation=2, shape=shape, seed=100 + s)
        rng = np.random.default_rng(300 + s)
        sky = rng.uniform(0, 256, (n_stars, 2))
        cats = []
        for t in truth:
            inv = np.linalg.inv(as_matrix(t))
            cats.append(sky @ inv[:2, :2].T + inv[:2, 2] + rng.normal(0, sigma, sky.shape))
        sol = solve_sequence(cats, reference=0)
        ref = Reference(cats[0])
        pw = [find_transform(c, ref)[0] for c in cats[1:]]
        true = [np.linalg.inv(as_matrix(truth[0])) @ as_matrix(t) for t in truth]
        glob.append(np.median([max_diff(sol.transforms[i], true[i], shape) for i in range(1, 30)]))
        ours.append(np.median([max_diff(pw[i - 1], true[i], shape) for i in range(1, 30)]))
    return dict(per_sequence=dict(global_=glob, pairwise_ours=ours), n_stars=n_stars,
                sigma=sigma, pooled_median_global=float(np.median(glob)),
                pooled_median_pairwise_ours=float(np.median(ours)),
                ratio_global_to_ours=float(np.median(glob) / np.median(ours)))


def run_long(lengths=(30, 100, 300), kinds=("similarity", "affine"), n_stars=300, sigma=0.05,
             n_seq=2):
    """
    Long sequences of catalogs (every frame the same ``n_stars`` stars,
    Gaussian centroid noise ``sigma`` px): the joint solution against
    pairwise (ours and astroalign, similarity only), for growing numbers of
    frames.  Both should be equally precise at any length; a fit whose
    residuals are not weighed in each frame's own pixels shrinks the frames
    more the more frames there are.  Reports the mean (scale - 1) against
    the truth and the median of the largest error over the frame.
    """
    shape = (256, 256)
    out = []
    for kind in kinds:
        for n in lengths:
            scale = dict(global_=[], pairwise_ours=[], pairwise_astroalign=[])
            err = {k: [] for k in scale}
            for s in range(n_seq):
                truth = dither_transforms(n, max_shift=40, max_rotation=2, shape=shape,
                                          seed=100 + s)
                rng = np.random.default_rng(300 + s)
                sky = rng.uniform(0, 256, (n_stars, 2))
                cats = []
                for t in truth:
                    inv = np.linalg.inv(as_matrix(t))
                    cats.append(sky @ inv[:2, :2].T + inv[:2, 2]
                                + rng.normal(0, sigma, sky.shape))
                sol = solve_sequence(cats, reference=0, transform_type=kind)
                ref = Reference(cats[0])
                true = [np.linalg.inv(as_matrix(truth[0])) @ as_matrix(t) for t in truth]
                for i in range(1, n):
                    mats = dict(global_=as_matrix(sol.transforms[i]),
                                pairwise_ours=as_matrix(find_transform(
                                    cats[i], ref, transform_type=kind)[0]))
                    if kind == "similarity":
                        mats["pairwise_astroalign"] = aa_matrix(cats[i], cats[0])
                    for k, m in mats.items():
                        if m is None:
                            err[k].append(np.inf)
                            continue
                        det = np.linalg.det(m[:2, :2]) / np.linalg.det(true[i][:2, :2])
                        scale[k].append(np.sqrt(abs(det)) - 1.0)
                        err[k].append(max_diff(m, true[i], shape))
            row = dict(kind=kind, n_frames=n, n_sequences=n_seq)
            for k in scale:
                if err[k]:
                    row[k] = dict(scale_ppm=1e6 * float(np.mean(scale[k])),
                                  median_error=float(np.median(err[k])))
            row["ratio_global_to_ours"] = (row["global_"]["median_error"]
                                           / row["pairwise_ours"]["median_error"])
            out.append(row)
            print(f"long {kind} {n}: ratio {row['ratio_global_to_ours']:.3f}", flush=True)
    return out


def write_frames(folder, n_frames, shape=(1024, 1024), n_stars=800, seed=10):
    """
    ``n_frames`` dithered FITS frames of one star field, written one at a
    time (500 frames of 1024x1024 are never in memory together): the star
    field as `simulate_views` draws it, each frame rendered by
    `simulate_image` with its own noise.  Returns the paths and the truth.
    """
    ny, nx = shape
    truth = dither_transforms(n_frames, max_shift=60, max_rotation=1, shape=shape, seed=9)
    rng = np.random.default_rng(seed)
    pad = 70.0  # the largest shift and rotation, and a PSF's margin
    box = (-0.5 - pad, nx - 0.5 + pad, -0.5 - pad, ny - 0.5 + pad)
    count = int(rng.poisson(n_stars * (box[1] - box[0]) * (box[3] - box[2]) / (nx * ny)))
    sx, sy = rng.uniform(box[0], box[1], count), rng.uniform(box[2], box[3], count)
    flux = draw_fluxes(count, seed=rng)
    paths = []
    for i, t in enumerate(truth):
        inv = np.linalg.inv(as_matrix(t))
        fx = inv[0, 0] * sx + inv[0, 1] * sy + inv[0, 2]
        fy = inv[1, 0] * sx + inv[1, 1] * sy + inv[1, 2]
        keep = (fx > -10) & (fx < nx + 9) & (fy > -10) & (fy < ny + 9)
        img = simulate_image(shape, fx[keep], fy[keep], flux[keep], noise="gaussian",
                             seed=rng)
        paths.append(str(Path(folder) / f"f{i:03d}.fits"))
        fits.writeto(paths[-1], img)
    return paths, truth


def speed_child(folder, solve, workers, out):
    """One timed ``register_batch`` in this (fresh) process; its figures to ``out``."""
    import resource

    paths = sorted(str(p) for p in Path(folder).glob("f*.fits"))
    dest = Path(folder) / f"out_{solve}"
    t0 = time.perf_counter()
    res = register_batch(paths[1:], paths[0], output_dir=dest, solve=solve, workers=workers)
    seconds = time.perf_counter() - t0
    assert not res.failed, res.summary()
    sol = getattr(res, "solution", None)
    fig = dict(seconds=seconds, parts=dict(sol.seconds) if sol is not None else {},
               n_links=len(sol.links) if sol is not None else len(paths) - 1,
               n_tried=len(sol.links) + len(sol.attempts) if sol is not None else None,
               transforms=[as_matrix(f.transform).tolist() for f in res.frames],
               maxrss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
               maxrss_children_mb=resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024)
    Path(out).write_text(json.dumps(fig))
    for p in dest.glob("*"):
        p.unlink()


def run_speed(n_frames, workers=None, repeats=1):
    """
    ``register_batch(solve='global')`` against pairwise, interleaved, each
    in a fresh process (for its peak memory), from the same FITS files.
    """
    import subprocess
    import sys

    out = dict(n_frames=n_frames, shape=(1024, 1024), workers=workers, runs=[])
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        paths, truth = write_frames(tmp, n_frames)
        out["seconds_writing"] = time.perf_counter() - t0
        for rep in range(repeats):
            run = {}
            # Alternate which goes first, and flush the previous run's
            # written frames to disk before each: otherwise the second run
            # pays the first one's write-back (2.5 GB at 500 frames).
            order = ("pairwise", "global")[::1 if rep % 2 == 0 else -1]
            run["first"] = order[0]
            for solve in order:
                if hasattr(os, "sync"):
                    os.sync()
                fig = Path(tmp) / f"{solve}.json"
                subprocess.run([sys.executable, __file__, "--speed-child", tmp, solve,
                                str(workers or 0), str(fig)], check=True)
                run[solve] = json.loads(fig.read_text())
            # Accuracy against the truth: each frame's largest error over the frame.
            for solve in ("pairwise", "global"):
                r = run[solve]
                err = [max_diff(np.asarray(m), np.linalg.inv(as_matrix(truth[0]))
                                @ as_matrix(t), (1024, 1024))
                       for m, t in zip(r.pop("transforms"), truth[1:])]
                r["median_error"], r["max_error"] = float(np.median(err)), float(np.max(err))
            run["ratio"] = run["global"]["seconds"] / run["pairwise"]["seconds"]
            out["runs"].append(run)
            print(f"speed run {rep}: pairwise {run['pairwise']['seconds']:.1f} s, global "
                  f"{run['global']['seconds']:.1f} s, ratio {run['ratio']:.2f}", flush=True)
    out["ratios"] = [r["ratio"] for r in out["runs"]]
    return out


def markdown(results):
    lines = ["# The global solution (`solve_sequence`) against pairwise", ""]
    for r in results.get("real", []):
        diffs = [f["global_vs_ours"] for f in r["frames"] if f["global_vs_ours"] is not None]
        lines += [f"## {r['name']} ({r['n_frames']} frames)", "",
                  f"every frame solved: {r['all_solved']}; stars in the joint solve: "
                  f"{r['n_stars']}; largest global-vs-pairwise (ours) difference over a frame: "
                  f"{max(diffs):.3f} px",
                  f"pairwise loop closure, median / max (px): ours "
                  f"{_mm(r['closure_ours'])}, astroalign {_mm(r['closure_astroalign'])}", "",
                  "| frame | links | predicted error (px) | global - ours (px) | "
                  "global - astroalign (px) |", "|---|---|---|---|---|"]
        for f in r["frames"]:
            lines.append(f"| {f['frame']} | {f['n_links']} | {f['predicted_error']:.3f} | "
                         f"{_f(f['global_vs_ours'])} | {_f(f['global_vs_astroalign'])} |")
        lines += ["", "| link | status | matches | own RMS | residual RMS | misfit |",
                  "|---|---|---|---|---|---|"]
        for k in r["links"]:
            lines.append(f"| {k['source']}->{k['target']} | {k['status']} | {k['n_matches']} | "
                         f"{k['own_rms']:.3f} | {k['residual_rms']:.3f} | {k['misfit']:.3f} |")
        s = r["seconds"]
        lines += ["", f"seconds: global {s['global_']:.1f}, pairwise ours "
                  f"{s['pairwise_ours']:.1f}, astroalign {s['pairwise_astroalign']:.1f}", ""]
    if "mosaic" in results:
        m = results["mosaic"]
        lines += ["## Simulated 3x3 mosaic, 20% overlaps, reference at a corner", "",
                  f"tiles solved: global {m['solved']}/9, pairwise to the reference "
                  f"{m['pairwise_solved']}/9; largest error {m['max_error']:.4f} px; per tile: "
                  + ", ".join(_f(e) for e in m["errors"]), ""]
    if "catalogs" in results:
        q = results["catalogs"]
        lines += [f"## Control: catalogs with the same {q['n_stars']} stars in every frame "
                  f"(sigma {q['sigma']} px)", "",
                  f"median over frames of the largest error, pooled: global "
                  f"{q['pooled_median_global']:.4f} px, pairwise ours "
                  f"{q['pooled_median_pairwise_ours']:.4f} px; ratio global/ours "
                  f"{q['ratio_global_to_ours']:.3f}", ""]
    for key in ("sequence", "sequence_deep", "sequence_all"):
        if key in results:
            q = results[key]
            lines += [f"## Simulated 30-frame dithered sequences ({key}, n_stars="
                      f"{q['n_stars']})", "",
                      f"median over frames of the largest error, pooled: global "
                      f"{q['pooled_median_global']:.4f} px, pairwise ours "
                      f"{q['pooled_median_pairwise_ours']:.4f} px, astroalign "
                      f"{q['pooled_median_pairwise_astroalign']:.4f} px; ratio global/ours "
                      f"{q['ratio_global_to_ours']:.3f}; detections per frame in the joint "
                      f"solve (median) {q['detections_per_frame']:.0f}; seconds: global "
                      f"{q['seconds']['global_']:.1f}, pairwise ours "
                      f"{q['seconds']['pairwise_ours']:.1f}", ""]
    if "long" in results:
        lines += ["## Long sequences of catalogs: the same 300 stars in every frame, 0.05 px",
                  "", "| type | frames | scale - 1 (ppm): global / ours / astroalign | median "
                  "largest error (px): global / ours / astroalign | global / ours |",
                  "|---|---|---|---|---|"]
        for r in results["long"]:
            keys = ("global_", "pairwise_ours", "pairwise_astroalign")
            sc = " / ".join(f"{r[k]['scale_ppm']:+.1f}" if k in r else "-" for k in keys)
            er = " / ".join(f"{r[k]['median_error']:.4f}" if k in r else "-" for k in keys)
            lines.append(f"| {r['kind']} | {r['n_frames']} | {sc} | {er} | "
                         f"{r['ratio_global_to_ours']:.3f} |")
        lines.append("")
    if "speed" in results:
        s = results["speed"]
        lines += [f"## Speed: {s['n_frames']} frames of 1024x1024, detected, solved and "
                  f"resampled to files (workers={s['workers']})", "",
                  "| run (first) | pairwise (s) | global (s) | ratio | global: detect / match / "
                  "solve (s) | links (tried) | peak RSS pairwise / global (MB) | median error "
                  "pairwise / global (px) |", "|---|---|---|---|---|---|---|---|"]
        for i, r in enumerate(s["runs"]):
            p, g = r["pairwise"], r["global"]
            parts = " / ".join(f"{g['parts'].get(k, 0):.1f}"
                               for k in ("detect", "match", "solve"))
            rss = [max(x["maxrss_mb"], x["maxrss_children_mb"]) for x in (p, g)]
            first = r.get("first", "pairwise")
            lines.append(f"| {i} ({first}) | {p['seconds']:.1f} | {g['seconds']:.1f} | "
                         f"{r['ratio']:.2f} | {parts} | {g['n_links']} ({g['n_tried']}) | "
                         f"{rss[0]:.0f} / {rss[1]:.0f} | {p['median_error']:.4f} / "
                         f"{g['median_error']:.4f} |")
        lines += ["", f"median ratio {np.median(s['ratios']):.2f}; each run in a fresh process "
                  "after the previous run's output was flushed to disk, the order alternating", ""]
    return "\n".join(lines)


def _f(v):
    return "-" if v is None else f"{v:.3f}"


def _mm(v):
    return f"{np.median(v):.3f} / {np.max(v):.3f}" if len(v) else "-"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(HERE.parent.parent / "shared" / "data"))
    ap.add_argument("--only", nargs="+",
                    default=["real", "mosaic", "sequence", "long", "speed"])
    ap.add_argument("--sequences", type=int, default=8)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--speed-child", nargs=4, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help="also write OUT.json and OUT.md")
    args = ap.parse_args()
    if args.speed_child:
        folder, solve, workers, out = args.speed_child
        return speed_child(folder, solve, int(workers) or None, out)
    print(f"astroalign_nd {astroalign_nd.__version__} from {astroalign_nd.__file__}")
    results = {}
    if "real" in args.only:
        results["real"] = run_real(args.data)
    if "mosaic" in args.only:
        results["mosaic"] = run_mosaic()
    if "sequence" in args.only:
        results["sequence"] = run_sequences(args.sequences)
        results["sequence_deep"] = run_sequences(args.sequences, n_stars=300)
        results["sequence_all"] = run_sequences(args.sequences, n_stars=1000)
        results["catalogs"] = run_catalogs(args.sequences)
    if "long" in args.only:
        results["long"] = run_long()
    if "speed" in args.only:
        results["speed"] = run_speed(args.frames, args.workers, args.repeats)
    text = markdown(results)
    print(text)
    if args.out:
        Path(args.out + ".json").write_text(json.dumps(results, indent=1, default=float))
        Path(args.out + ".md").write_text(text + "\n")


if __name__ == "__main__":
    main()
