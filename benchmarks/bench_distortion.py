"""
Wide-field distortion: astroalign_nd's projective and polynomial
models against aafitrans and scikit-image, accuracy over the whole frame,
robustness to wrong matches, and time, on the same inputs in one run.

Inputs: 4096x4096 pairs simulated with ``simulate_pair(distortion=...)``
(barrel or pincushion distortion moving the corners by 2 to 10 px, one with
a tilted focal plane too, and one with a tilted focal plane only: the
projective model's case), a small rotation and shift, 6000 stars.

Accuracy of a mapping: its distance to the true mapping
(``SimulatedPair.truth_map``) on a 65x65 grid over the whole source frame,
corners included: max and RMS, pixels.

Part A, end to end (images in):

* ours-polynomial / ours-auto / ours-projective / ours-affine:
  ``find_transform(source, target, transform_type=..., degree=...)`` (the
  affine one is the best linear model we give);
* astroalign+skimage: ``astroalign.find_transform(source, target,
  max_control_points=K)`` (K = 50, its default, and 200), then
  ``skimage.transform.PolynomialTransform`` (order 3, least squares) fitted
  to the matched point lists astroalign returns;
* aafitrans-projective / aafitrans-polynomial:
  ``aafitrans.find_transform(src_xy, dst_xy, ttype=..., seed=0)`` (its
  default 50 control points: 100 made its projective search 15 times
  slower, 91 s on a 2048 px pair) on the 500 brightest detections of
  ``astroalign_nd.find_sources`` in each image (their detection time is
  included).  Its 'polynomial' is skimage's ``estimate_transform(
  'polynomial')``, order 2, which its RANSAC fits to one triangle (3 pairs,
  fewer than the 6 coefficients per axis) by default; with ``n_samples=3``
  (9 pairs) it can work but took 303 s on a 2048 px pair (trial run), so
  the default is run.

Part B, fitting only, on given pairs: the 600 brightest source detections
paired with the target detection nearest their true position (within
1 px): correct pairs with real centroid errors over the whole frame.  Each
fitter gets the same pairs, clean, then with 30% of them wrong:

* "random": the target position of 30% of the pairs replaced by a uniform
  random position in the frame (a wrong match to a star that is not
  there);
* "swapped": the target positions of 30% of the pairs permuted among
  themselves (each wrong pair points at another real star: the
  mismatch a matcher makes).

Fitters: ours (``matching.fit_nonlinear(src, dst, None,
pairs_given=True, tolerance=8)``, polynomial degree 3, auto, projective:
it finds its own affine start by consensus), skimage PolynomialTransform
order 3 by least squares, skimage ``measure.ransac`` with
PolynomialTransform order 3 (min_samples 10, residual_threshold 2 px, 2000
trials, seed 0), and aafitrans projective/polynomial on the two lists in
the same order (its 50 first pairs: it re-matches them itself, so "swapped" changes nothing for
it: not run; "random" is 30% of target stars moved at random).

Times: wall clock of each call on one core pair shared with other work;
ratios between methods in the same run are what count.

Usage::

    python benchmarks/bench_distortion.py [--pairs 4] [--size 4096] [--out FILE]
"""

import argparse
import os
import sys
import time
import warnings

import numpy as np

_HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(_HERE))  # this checkout's astroalign_nd

#: (corner shift px, barrel?, tilt, rotation deg, seed)
CASES = [
    (2.0, True, None, 3.0, 1),
    (5.0, False, None, -8.0, 2),
    (10.0, True, None, 12.0, 3),
    (4.0, True, (0.0015, -0.001), 5.0, 4),
    (0.0, True, (0.0015, -0.001), -4.0, 5),
]
GRID = 65


def _pair(size, corner, barrel, tilt, rotation, seed, n_stars):
    from astroalign_nd.simulate import simulate_pair

    half = 0.5 * np.hypot(size, size)
    dist = {"k1": (-1 if barrel else 1) * corner / half}
    if tilt is not None:
        dist["tilt"] = tilt
    return simulate_pair((size, size), n_stars=n_stars, rotation=rotation,
                         translation=(31.0, -17.0), seed=seed, distortion=dist,
                         noise="gaussian", flux_range=(500.0, 3e5))


def _grid(size):
    g = np.linspace(-0.5, size - 0.5, GRID)
    gx, gy = np.meshgrid(g, g)
    return gx.ravel(), gy.ravel()


def _error(fn, pair, size):
    """(max, rms) distance to the truth over the frame, or None."""
    if fn is None:
        return None
    gx, gy = _grid(size)
    tx, ty = pair.truth_map(gx, gy)
    try:
        mx, my = fn(gx, gy)
    except Exception:  # a degenerate fit that cannot even be evaluated
        return None
    e = np.hypot(np.asarray(mx) - tx, np.asarray(my) - ty)
    if not np.all(np.isfinite(e)):
        return (float("inf"), float("inf"))
    return float(e.max()), float(np.sqrt(np.mean(e ** 2)))


def _sk(tf):
    def fn(x, y):
        out = tf(np.column_stack([x, y]))
        return out[:, 0], out[:, 1]
    return fn


def _timed(fn):
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = fn()
        err = None
    except Exception as exc:  # every method's failure is a result here
        out, err = None, f"{type(exc).__name__}: {str(exc)[:60]}"
    return out, time.perf_counter() - t0, err


def part_a(pair, size, rows, label):
    import astroalign
    from skimage.transform import PolynomialTransform

    import astroalign_nd
    from astroalign_nd import find_sources

    for name, kw in [("ours-polynomial3", dict(transform_type="polynomial", degree=3)),
                     ("ours-auto", dict(transform_type="polynomial", degree="auto")),
                     ("ours-projective", dict(transform_type="projective")),
                     ("ours-affine", dict(transform_type="affine"))]:
        out, dt, err = _timed(lambda: astroalign_nd.find_transform(pair.source, pair.target,
                                                                   **kw))
        model = out[0] if out else None
        extra = ""
        if model is not None:
            q = model.meta["quality"]
            extra = (f"{q['n_matches']} stars" + (f", {q['model']} deg {q['degree']}, "
                                                  f"pred.err {q['predicted_error_max']:.3f}"
                                                  if "model" in q else ""))
        rows.append((label, "A", name, _error(model, pair, size), dt, err or extra))

    for k in (50, 200):
        def aa_sk():
            _, (s, d) = astroalign.find_transform(pair.source, pair.target,
                                                  max_control_points=k)
            tf = PolynomialTransform()
            if not tf.estimate(s, d, order=3):
                raise RuntimeError("PolynomialTransform.estimate failed")
            return tf, len(s)
        out, dt, err = _timed(aa_sk)
        rows.append((label, "A", f"astroalign{k}+skimage-poly3",
                     _error(_sk(out[0]) if out else None, pair, size), dt,
                     err or f"{out[1]} matches"))

    def detected():
        s = find_sources(pair.source, n_sources=500)
        d = find_sources(pair.target, n_sources=500)
        return np.column_stack([s["x"], s["y"]]), np.column_stack([d["x"], d["y"]])

    _aafitrans_rows(rows, label, "A", pair, size, detected)


def _aafitrans_rows(rows, tag, part, pair, size, points):
    """Rows of aafitrans (projective, polynomial) on ``points()``: (source, target), timed too."""
    import aafitrans

    for ttype in ("projective", "polynomial"):
        def aaf():
            tf, (ms, _) = aafitrans.find_transform(*points(), ttype=ttype, seed=0)
            return tf, len(ms)
        out, dt, err = _timed(aaf)
        rows.append((tag, part, f"aafitrans-{ttype}",
                     _error(_sk(out[0]) if out else None, pair, size), dt,
                     err or f"{out[1]} matches"))


def _given_pairs(pair, n=600):
    from scipy.spatial import cKDTree

    from astroalign_nd import find_sources

    s = find_sources(pair.source, n_sources=2 * n)
    d = find_sources(pair.target, n_sources=4 * n)
    sxy = np.column_stack([s["x"], s["y"]])[:n]
    dxy = np.column_stack([d["x"], d["y"]])
    tx, ty = pair.truth_map(sxy[:, 0], sxy[:, 1])
    dist, j = cKDTree(dxy).query(np.column_stack([tx, ty]))
    ok = dist < 1.0
    return sxy[ok], dxy[j[ok]]


def part_b(pair, size, rows, label):
    from skimage.measure import ransac
    from skimage.transform import PolynomialTransform

    from astroalign_nd.matching import fit_nonlinear

    src, dst = _given_pairs(pair)
    n = len(src)
    rng = np.random.default_rng(0)
    bad = rng.choice(n, int(round(0.3 * n)), replace=False)
    variants = {"clean": dst}
    rand = dst.copy()
    rand[bad] = rng.uniform(-0.5, size - 0.5, (len(bad), 2))
    variants["30% random"] = rand
    swap = dst.copy()
    swap[bad] = dst[np.roll(bad, 1)]
    variants["30% swapped"] = swap
    frame = (-0.5, size - 0.5, -0.5, size - 0.5)
    for vname, d in variants.items():
        tag = f"{label} B {vname} ({n} pairs)"
        for name, kw in [("ours-polynomial3", dict(degree=3)),
                         ("ours-auto", dict(degree="auto")),
                         ("ours-projective", dict(transform_type="projective"))]:
            out, dt, err = _timed(lambda: fit_nonlinear(src, d, None, pairs_given=True,
                                                        tolerance=8.0, source_frame=frame,
                                                        **kw))
            extra = ""
            if out is not None:
                kept = set(out.source_index.tolist())
                wrong_kept = len(kept & set(bad.tolist())) if vname != "clean" else 0
                extra = (f"kept {len(kept)}, wrong kept {wrong_kept}, {out.info['model']} "
                         f"deg {out.info['degree']}")
            rows.append((tag, "B", name, _error(out.transform if out else None, pair, size),
                         dt, err or extra))

        def sk_lsq():
            tf = PolynomialTransform()
            if not tf.estimate(src, d, order=3):
                raise RuntimeError("estimate failed")
            return tf
        out, dt, err = _timed(sk_lsq)
        rows.append((tag, "B", "skimage-poly3-lstsq",
                     _error(_sk(out) if out else None, pair, size), dt, err or ""))

        def sk_ransac():
            tf, inl = ransac((src, d), PolynomialTransform, min_samples=10,
                             residual_threshold=2.0, max_trials=2000, rng=0)
            if tf is None:
                raise RuntimeError("ransac found no model")
            # skimage's ransac estimates with the class's default order (2):
            # refit order 3 on its inliers.
            tf3 = PolynomialTransform()
            tf3.estimate(src[inl], d[inl], order=3)
            return tf3, int(inl.sum())
        out, dt, err = _timed(sk_ransac)
        rows.append((tag, "B", "skimage-ransac-poly3",
                     _error(_sk(out[0]) if out else None, pair, size), dt,
                     err or f"kept {out[1]}"))

        if vname != "30% swapped":
            _aafitrans_rows(rows, tag, "B", pair, size, lambda d=d: (src, d))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=len(CASES))
    ap.add_argument("--size", type=int, default=4096)
    ap.add_argument("--n-stars", type=int, default=6000)
    ap.add_argument("--out", default=None, help="also write the report to this file")
    args = ap.parse_args(argv)

    import astroalign
    import aafitrans  # noqa: F401
    import skimage

    import astroalign_nd

    lines = []

    def say(s=""):
        print(s, flush=True)
        lines.append(s)

    say("Wide-field distortion: astroalign_nd vs aafitrans and skimage")
    say(f"astroalign_nd from {os.path.dirname(astroalign_nd.__file__)}; astroalign "
        f"{astroalign.__version__}; scikit-image {skimage.__version__}")
    say(f"frames {args.size}x{args.size}, {args.n_stars} stars; error = distance to the true "
        f"mapping on a {GRID}x{GRID} grid over the whole source frame (px)")
    # Warm-up outside the timing (imports, first-call costs).
    from astroalign_nd.simulate import simulate_pair
    warm = simulate_pair((512, 512), n_stars=300, rotation=10.0, seed=0)
    astroalign_nd.find_transform(warm.source, warm.target)
    astroalign.find_transform(warm.source, warm.target)

    rows = []
    for corner, barrel, tilt, rotation, seed in CASES[:args.pairs]:
        t0 = time.perf_counter()
        pair = _pair(args.size, corner, barrel, tilt, rotation, seed, args.n_stars)
        label = ((f"{'barrel' if barrel else 'pincushion'} {corner:g}px" if corner else "")
                 + (f" + tilt {tilt}" if tilt else "") + f" (corner shift "
                 f"{pair.meta['corner_shift']:.1f} px)")
        say()
        say(f"== {label}, simulated in {time.perf_counter() - t0:.1f} s")
        start = len(rows)
        part_a(pair, args.size, rows, label)
        part_b(pair, args.size, rows, label)
        last = None
        for tag, part, name, err, dt, note in rows[start:]:
            if tag != last:
                say(f"  -- {'end to end (images)' if part == 'A' else tag.split(' B ')[1]}")
                last = tag
            e = "   failed         " if err is None else f"{err[0]:8.3f} {err[1]:8.3f} "
            say(f"  {name:28s} {e} {dt:7.2f} s  {note}")

    # Summary: median over pairs of the max error, and median time, per method and part.
    say()
    say("== summary: median over the pairs of max error (px) [worst pair], median time (s), "
        "failures")
    keys = []
    for tag, part, name, *_ in rows:
        variant = "end to end" if part == "A" else tag.split(" B ")[1].split(" (")[0]
        if (variant, name) not in keys:
            keys.append((variant, name))
    for variant, name in keys:
        sel = [r for r in rows if r[2] == name and (
            (r[1] == "A" and variant == "end to end")
            or (r[1] == "B" and r[0].split(" B ")[1].startswith(variant)))]
        errs = [r[3][0] for r in sel if r[3] is not None]
        fails = sum(r[3] is None for r in sel)
        times = [r[4] for r in sel]
        e = (f"{np.median(errs):9.3f} [{max(errs):8.3f}]" if errs else "     failed         ")
        say(f"  {variant:12s} {name:28s} {e}  {np.median(times):7.2f} s  {fails} failed "
            f"of {len(sel)}")
    if args.out:
        with open(args.out, "w") as fh:
            fh.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
