"""
Checked per-star weights: is the final fit ever worse than an unweighted fit
of the same matched pairs?

On each simulated pair, the error of a transform is the largest distance,
over the four corners of the source frame, between where it and the truth
put them (target pixels).  Columns, all on the same pairs in one run:

* ours: ``find_match`` (similarity), whose final fit weighs the pairs by
  their detection errors once `~astroalign_nd.transforms.checked_weights`
  has checked them against the residuals;
* claimed: ``find_match`` with the check switched off (the weights are
  the detections' errors as they are, ``1 / (s^2 e_src^2 + e_dst^2)``: the
  code before the check);
* unweighted: a least-squares similarity on the same matched pairs;
* astroalign: ``astroalign.find_transform(source, target)``, defaults;
* aafitrans: ``aafitrans.find_transform`` on astroalign's detections
  (``astroalign._find_sources``), defaults.

Cases:

* sparse, wrong errors: `simulate_sparse_pair` below
  (about 25 faint stars, 0.12 px per-axis centroid offsets between the
  frames, 3 faint stars hit by a cosmic ray), random rotation and shift;
* sparse, honest errors: the same without the offsets and the hits;
* well sampled: ``simulate_pair`` with 150 stars of the default (high
  S/N) flux range.

Medians and 90th percentiles are over the pairs each method solved (the
``solved`` column); ours and unweighted share their pairs.

Usage::

    python benchmarks/bench_fit_weights.py [--seeds 100] [--other-seeds 30]
        [--no-peers]
"""

import argparse
import contextlib
import time
import warnings

import numpy as np

from astroalign_nd import find_match
from astroalign_nd.matching import verify
from astroalign_nd._kernels import GAUSS_SIGMA_TO_FWHM
from astroalign_nd.simulate import SimulatedPair, simulate_image, simulate_pair
from astroalign_nd.simulate.stars import _check_count, _check_real, _spawn
from astroalign_nd.transforms import apply_matrix, fit_transform


def simulate_sparse_pair(shape=(512, 512), *, n_stars=25, rotation=None, translation=None,
                         scale=None, flux_range=(600.0, 6e4), background=300.0,
                         centroid_jitter=0.12, n_hits=3, seed=None, **pair_options):
    """
    A sparse, faint pair whose detections' position errors are wrong.

    Like a blue frame of a high-latitude field against a red one: about
    ``n_stars`` stars, most near the detection limit, and centroids that
    differ between the two frames by more than their noise says.  Two
    things the detector cannot know are added to the target frame:

    * ``centroid_jitter``: every star is drawn at its true position plus a
      Gaussian offset of this many pixels per axis (a star's colour moves
      its centroid between bands; the PSFs differ).  The bright stars'
      position errors, estimated from their S/N, are then far too small;
    * ``n_hits``: as many of the fainter stars get a cosmic-ray-like hit of
      one or two pixels, 1 to 2 pixels from their centre, that pulls their
      centroid without making them look different.

    The truth (``transform``, ``truth_matrix``, ``target_stars``) is that of
    the stars' true positions: the offsets are errors of the frame, not
    part of the transform.

    Parameters
    ----------
    shape : tuple of int, optional
        Both frames' shape ``(ny, nx)``.
    n_stars, rotation, translation, scale, flux_range, background
        As for `simulate_pair` (here: few, faint stars on a bright sky).
    centroid_jitter : float, optional
        Per-axis standard deviation of the target stars' offsets, pixels.
    n_hits : int, optional
        Number of fainter target stars hit by a cosmic ray.
    seed : int or `numpy.random.Generator`, optional
        Makes the pair reproducible.
    **pair_options
        Other options of `simulate_pair` (``fwhm``, ``read_noise``...).

    Returns
    -------
    pair : `SimulatedPair`
        With ``meta["centroid_jitter"]``, ``meta["hit_ids"]`` (the ids of
        the hit stars) and ``meta["target_offsets"]`` (per target star, in
        the order of ``target_stars``).

    Examples
    --------
    >>> import numpy as np
    >>> from bench_fit_weights import simulate_sparse_pair
    >>> pair = simulate_sparse_pair(seed=3, rotation=30.0)
    >>> len(pair.source_stars) < 40, len(pair.meta["hit_ids"])
    (True, 3)
    >>> off = pair.meta["target_offsets"]
    >>> bool(0.05 < np.std(off) < 0.2)
    True
    """
    centroid_jitter = _check_real(centroid_jitter, "centroid_jitter", minimum=0.0,
                                  hint=" Pass the offsets' standard deviation in pixels.")
    n_hits = _check_count(n_hits, "n_hits")
    rng_pair, rng_off, rng_img = _spawn(seed, 3)
    pair = simulate_pair(shape, n_stars=n_stars, rotation=rotation, translation=translation,
                         scale=scale, flux_range=flux_range, background=background,
                         seed=rng_pair, **pair_options)
    meta = pair.meta
    tgt = pair.target_stars
    off = rng_off.normal(0.0, centroid_jitter, (len(tgt), 2))
    xt, yt = np.asarray(tgt["x"]) + off[:, 0], np.asarray(tgt["y"]) + off[:, 1]
    image = simulate_image(
        meta["target_shape"], xt, yt, np.asarray(tgt["flux"]), fwhm=meta["target_fwhm"],
        psf=meta["psf"], background=meta["target_background"], gradient=meta["gradient"],
        read_noise=meta["read_noise"], gain=meta["gain"], saturation=meta["saturation"],
        noise=meta["noise"], seed=rng_img, dtype=pair.target.dtype)
    # Hits on the fainter half (the catalog is brightest first), at a peak
    # of 1 to 3 times the star's own.
    faint = np.arange(len(tgt) // 2, len(tgt))
    hit = rng_off.choice(faint, size=min(n_hits, len(faint)), replace=False)
    sig = meta["target_fwhm"] / GAUSS_SIGMA_TO_FWHM
    for i in hit:
        ang = rng_off.uniform(0.0, 2.0 * np.pi)
        dist = rng_off.uniform(1.0, 2.0)
        peak = tgt["flux"][i] / (2.0 * np.pi * sig**2) * rng_off.uniform(1.0, 3.0)
        for k in range(int(rng_off.integers(1, 3))):
            c = int(np.floor(xt[i] + (dist + k) * np.cos(ang) + 0.5))
            r = int(np.floor(yt[i] + (dist + k) * np.sin(ang) + 0.5))
            if 0 <= r < image.shape[0] and 0 <= c < image.shape[1]:
                image[r, c] += peak
    meta = {**meta, "centroid_jitter": centroid_jitter,
            "hit_ids": [int(v) for v in tgt["id"][hit]], "target_offsets": off}
    return SimulatedPair(source=pair.source, target=image, transform=pair.transform,
                         truth_matrix=pair.truth_matrix, source_stars=pair.source_stars,
                         target_stars=tgt, transients=pair.transients, meta=meta,
                         mapping=pair.mapping)


def corner_error(matrix, truth, shape):
    ny, nx = shape
    c = np.array([[-0.5, -0.5], [nx - 0.5, -0.5], [-0.5, ny - 0.5], [nx - 0.5, ny - 0.5]])
    return float(np.max(np.hypot(*(apply_matrix(matrix, c) - apply_matrix(truth, c)).T)))


@contextlib.contextmanager
def unchecked_weights():
    """The search with the detections' weights taken as claimed (the code before the check)."""
    saved = verify.checked_weights
    verify.checked_weights = lambda src, dst, weights, *a, **k: weights
    try:
        yield
    finally:
        verify.checked_weights = saved


def run_ours(pair, unchecked=False):
    with warnings.catch_warnings(), (unchecked_weights() if unchecked
                                     else contextlib.nullcontext()):
        warnings.simplefilter("ignore")
        res = find_match(pair.source, pair.target)
    parity = 1 if np.linalg.det(res.transform.matrix[:2, :2]) > 0 else -1
    unw = fit_transform(res.source_points, res.target_points, "similarity",
                        parity=parity)[0].matrix
    return res.transform.matrix, unw


def run_astroalign(pair):
    import astroalign
    t, _ = astroalign.find_transform(pair.source, pair.target)
    return np.asarray(t.params, float)


def run_aafitrans(pair):
    import aafitrans
    import astroalign
    s = astroalign._find_sources(pair.source)
    d = astroalign._find_sources(pair.target)
    t, _ = aafitrans.find_transform(s, d)
    return np.asarray(t.params, float)


def cases(n_sparse, n_other):
    rng = np.random.default_rng(2026)
    for seed in range(n_sparse):
        rot, tx, ty = rng.uniform(-180, 180), *rng.uniform(-40, 40, 2)
        yield "sparse, wrong errors", simulate_sparse_pair(
            seed=seed, rotation=rot, translation=(tx, ty))
    for seed in range(n_other):
        rot, tx, ty = rng.uniform(-180, 180), *rng.uniform(-40, 40, 2)
        yield "sparse, honest errors", simulate_sparse_pair(
            seed=1000 + seed, rotation=rot, translation=(tx, ty), centroid_jitter=0.0, n_hits=0)
    for seed in range(n_other):
        rot, tx, ty = rng.uniform(-180, 180), *rng.uniform(-40, 40, 2)
        yield "well sampled", simulate_pair((512, 512), n_stars=150, seed=2000 + seed,
                                            rotation=rot, translation=(tx, ty))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=100, help="sparse pairs with wrong errors")
    ap.add_argument("--other-seeds", type=int, default=30,
                    help="pairs of each of the two other cases")
    ap.add_argument("--no-peers", action="store_true", help="skip astroalign and aafitrans")
    args = ap.parse_args(argv)
    methods = ["ours", "claimed", "unweighted"] + ([] if args.no_peers else
                                                   ["astroalign", "aafitrans"])
    errs = {}
    wins = {}
    t0 = time.perf_counter()
    for case, pair in cases(args.seeds, args.other_seeds):
        shape = pair.source.shape
        e = errs.setdefault(case, {m: [] for m in methods})
        try:
            m, unw = run_ours(pair)
            e["ours"].append(corner_error(m, pair.truth_matrix, shape))
            e["unweighted"].append(corner_error(unw, pair.truth_matrix, shape))
            wins.setdefault(case, []).append(e["ours"][-1] - e["unweighted"][-1])
        except Exception:  # refused: counted as not solved
            e["ours"].append(np.nan)
            e["unweighted"].append(np.nan)
        try:
            e["claimed"].append(corner_error(run_ours(pair, True)[0], pair.truth_matrix, shape))
        except Exception:
            e["claimed"].append(np.nan)
        for name, fn in (("astroalign", run_astroalign), ("aafitrans", run_aafitrans)):
            if name not in methods:
                continue
            try:
                e[name].append(corner_error(fn(pair), pair.truth_matrix, shape))
            except Exception:
                e[name].append(np.nan)
    print(f"corner error (max over the source frame's corners, target px); "
          f"{time.perf_counter() - t0:.0f} s")
    print(f"{'case':<22} {'method':<11} {'solved':>8} {'median':>8} {'p90':>8} "
          f"{'median/unw':>10} {'p90/unw':>8}")
    for case, e in errs.items():
        ref = np.asarray(e["unweighted"], float)
        ref = ref[np.isfinite(ref)]
        r_med, r_p90 = (np.median(ref), np.percentile(ref, 90)) if len(ref) else (np.nan,) * 2
        for m in methods:
            v = np.asarray(e[m], float)
            ok = v[np.isfinite(v)]
            med = np.median(ok) if len(ok) else np.nan
            p90 = np.percentile(ok, 90) if len(ok) else np.nan
            print(f"{case:<22} {m:<11} {len(ok):>4}/{len(v):<3} {med:8.3f} {p90:8.3f} "
                  f"{med / r_med:10.2f} {p90 / r_p90:8.2f}")
        d = np.asarray(wins.get(case, []))
        if len(d):
            print(f"{case:<22} ours - unweighted per pair: median {np.median(d):+.3f}, "
                  f"worst {np.max(d):+.3f}, ours better on {np.mean(d < 0):.0%}")


if __name__ == "__main__":
    main()
