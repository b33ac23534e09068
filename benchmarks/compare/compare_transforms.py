"""
Bit-for-bit check of a refactor: the transforms found on a fixed set of inputs.

Runs ``find_match`` (also ``match_points`` and ``compat.find_transform``)
on a fixed set of inputs and writes, per input, the returned matrix and
quality figures (float64, exact) or the exception's type and message to a
JSON file.  Run it on the commit before a change and
on the commit after; ``--compare`` reports every difference (exact
equality, floats compared through their hex representation).

Inputs:

* 40 pairs of ``bench_grid.draw_pair`` (5 pairs in each of 8 cells:
  256/512 px, 300/1000 stars, background 100/5000), similarity model;
  every 4th pair also fitted with the affine, euclidean and translation
  models;
* the hard cases of ``bench_hard_cases`` (seeds 1 and 2), except the
  30000-star crowded field (``--crowded`` adds it: slow);
* a few catalogs (noisy, partial overlap, unrelated, too few points) with
  non-default matching options;
* ``matching.match_points`` on catalogs, and ``compat.find_transform`` on
  catalogs and on every 8th grid pair.

Usage::

    python benchmarks/compare/compare_transforms.py --out before.json
    python benchmarks/compare/compare_transforms.py --out after.json
    python benchmarks/compare/compare_transforms.py --compare before.json after.json
"""

import json
import os
import sys
import time
import warnings

import numpy as np

_HERE = os.path.dirname(os.path.abspath(__file__))
_BENCH = os.path.dirname(_HERE)  # benchmarks/: bench_grid, bench_hard_cases
# The checkout this script lives in is the one measured (not an installed copy).
sys.path[:0] = [os.path.dirname(_BENCH), _BENCH, _HERE]

from _command import run_command  # noqa: E402

GRID_CELLS = [(size, stars, bg) for size in (256, 512) for stars in (300, 1000)
              for bg in (100, 5000)]
PAIRS_PER_CELL = 5
FWHM_RANGE = (2.5, 4.0)


def _exact(x):
    """A JSON value that compares equal only if the float64 values are identical."""
    a = np.asarray(x, dtype=float)
    return {"shape": list(a.shape), "hex": [float(v).hex() for v in a.ravel()]}


def _call(source, target, kw):
    """Call the function named by ``kw['_call']``; (result, warnings) or the exception."""
    import astroalign_nd
    from astroalign_nd import compat
    from astroalign_nd.matching import match_points
    from astroalign_nd.registration import find_match

    kw = dict(kw)
    func = {"find_match": find_match, "match_points": match_points,
            "compat": compat.find_transform}[kw.pop("_call", "find_match")]
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            r = func(source, target, **kw)
    except Exception as exc:  # noqa: BLE001 - the exception is the recorded outcome
        return None, {"error": f"{type(exc).__name__}: {exc}"}
    return r, sorted(f"{w.category.__name__}: {w.message}" for w in caught
                     if issubclass(w.category, astroalign_nd.AstroalignWarning))


def _run(source, target, **kw):
    r, caught = _call(source, target, kw)
    if r is None:
        return caught
    if isinstance(r, tuple):  # compat.find_transform: (skimage transform, (src, dst))
        return {"matrix": _exact(r[0].params), "source_points": _exact(r[1][0]),
                "target_points": _exact(r[1][1]), "warnings": caught}
    extra = r.extra
    return {
        "matrix": _exact(r.transform.matrix),
        "model": type(r.transform).__name__,
        "rms": _exact(r.rms),
        "covariance": _exact(r.covariance),
        "log10_false_alarm": _exact(r.log10_false_alarm),
        "source_index": np.asarray(r.source_index).tolist(),
        "target_index": np.asarray(r.target_index).tolist(),
        "counts": [int(r.n_source), int(r.n_target), int(r.n_triangle_matches),
                   int(r.n_hypotheses), int(extra.get("n_sources_used", -1))],
        # match_points' results may hold the points only: indices suffice.
        "source_points": _exact(extra["source_points"]) if "n_sources_used" in extra else 0,
        "target_points": _exact(extra["target_points"]) if "n_sources_used" in extra else 0,
        "extra": {k: _exact(extra[k]) for k in ("model_misfit", "predicted_error")},
        "warnings": caught,
    }


def _catalog_inputs():
    rng = np.random.default_rng(17)
    m = np.array([[0.9, -0.3, 40.0], [0.3, 0.9, -12.0], [0, 0, 1]])
    src = rng.uniform(0, 500, (120, 2))
    dst = src @ m[:2, :2].T + m[:2, 2] + rng.normal(0, 0.05, src.shape)
    part = np.vstack([dst[:50], rng.uniform(0, 500, (70, 2))])
    yield "catalog noisy", src, dst, {}
    yield "catalog noisy affine tol", src, dst, dict(transform_type="affine", tolerance=2.0)
    yield "catalog partial nn6", src, part, dict(n_neighbors=6, n_sources=30)
    yield "catalog unrelated", src[:20], rng.uniform(0, 500, (20, 2)), {}
    yield "catalog too few", src[:2], dst[:2], {}
    yield "catalog no mirror", src[:40], dst[:40] * [-1, 1], dict(allow_mirror=False)
    err = rng.uniform(0.02, 0.1, len(src))
    yield "match_points errors", src, dst, dict(_call="match_points", source_errors=err,
                                                target_errors=err, source_frame=(0, 500, 0, 500))
    yield "match_points affine", src, part, dict(_call="match_points", transform_type="affine")
    yield "match_points unrelated", src[:20], part[60:80], dict(_call="match_points")
    yield "compat catalogs", src, dst, dict(_call="compat")
    yield "compat few stars", src[:5], dst[:5], dict(_call="compat")
    yield "compat unrelated", src[:20], part[60:80], dict(_call="compat")


def inputs(crowded=False):
    """Yield (name, source, target, find_match keywords)."""
    from bench_grid import draw_pair
    from bench_hard_cases import CASES

    k = 0
    for size, stars, bg in GRID_CELLS:
        for i in range(PAIRS_PER_CELL):
            pair, _ = draw_pair(size, stars, bg, i, 0, FWHM_RANGE)
            name = f"grid {size} {stars} {bg} #{i}"
            yield name, pair.source, pair.target, {}
            if k % 8 == 0:
                yield f"{name} compat", pair.source, pair.target, dict(_call="compat")
            if k % 4 == 0:
                for tt in ("affine", "euclidean", "translation"):
                    yield f"{name} {tt}", pair.source, pair.target, dict(transform_type=tt)
            k += 1
    for label, make in CASES.items():
        if label.startswith("crowded") and not crowded:
            continue
        for seed in (1, 2):
            case = make(seed)
            kw = dict(transform_type="affine") if case.affine else {}
            yield f"hard {label} seed {seed}", case.source, case.target, kw
    yield from _catalog_inputs()


def record(out, crowded=False):
    import astroalign_nd

    print(f"astroalign_nd from {os.path.dirname(astroalign_nd.__file__)}")
    results = {}
    t0 = time.perf_counter()
    for name, src, dst, kw in inputs(crowded):
        results[name] = _run(src, dst, **kw)
    with open(out, "w") as f:
        json.dump(results, f, indent=0, sort_keys=True)
    n_err = sum("error" in v for v in results.values())
    print(f"{len(results)} inputs ({n_err} raised) in {time.perf_counter() - t0:.0f} s "
          f"-> {out}")


def compare(old, new):
    with open(old) as f:
        a = json.load(f)
    with open(new) as f:
        b = json.load(f)
    diffs = 0
    for name in sorted(set(a) | set(b)):
        if name not in a or name not in b:
            print(f"only in {'new' if name not in a else 'old'}: {name}")
            diffs += 1
            continue
        keys = sorted(set(a[name]) | set(b[name]))
        bad = [k for k in keys if a[name].get(k) != b[name].get(k)]
        if bad:
            diffs += 1
            print(f"DIFFERENT {name}: {', '.join(bad)}")
            for k in bad[:3]:
                print(f"    old {k}: {str(a[name].get(k))[:300]}")
                print(f"    new {k}: {str(b[name].get(k))[:300]}")
    print(f"{len(set(a) | set(b))} inputs compared, {diffs} different")
    _summarize(a, b)
    return diffs


def _hex_values(entry):
    return np.array([float.fromhex(h) for h in entry["hex"]])


def _summarize(a, b):
    """
    How large the differences are: the inputs whose outcome differs (the
    fields other than floating-point arrays: errors, warnings, counts, array
    shapes), and per numeric field the largest difference (absolute for
    matrices and points, which are pixels; otherwise relative to the
    array's largest value).
    """
    outcome, worst = [], {}
    for name in sorted(set(a) & set(b)):
        for key in sorted(set(a[name]) | set(b[name])):
            x, y = a[name].get(key), b[name].get(key)
            pairs = [(key, x, y)]
            if isinstance(x, dict) and isinstance(y, dict) and "hex" not in x:
                pairs = [(f"{key}.{k}", x.get(k), y.get(k)) for k in sorted(set(x) | set(y))]
            for field, u, v in pairs:
                if u == v:
                    continue
                numeric = all(isinstance(w, dict) and "hex" in w for w in (u, v))
                if not numeric or u.get("shape") != v.get("shape"):
                    outcome.append(f"{name}: {field}")
                    continue
                du, dv = _hex_values(u), _hex_values(v)
                d = np.abs(du - dv)
                if field not in ("matrix", "source_points", "target_points"):
                    d = d / max(float(np.max(np.abs(du), initial=0.0)), 1e-300)
                worst[field] = max(worst.get(field, 0.0), float(np.max(d, initial=0.0)))
    print(f"inputs whose outcome differs (errors, warnings, counts, shapes): {len(outcome)}")
    for line in outcome[:20]:
        print(f"    {line}")
    for field, d in sorted(worst.items()):
        kind = "px" if field in ("matrix", "source_points", "target_points") else "relative"
        print(f"    largest difference in {field}: {d:.2e} {kind}")


def main(argv=None):
    return run_command(argv, __doc__, record, compare, [
        (("--crowded",), dict(action="store_true",
                              help="include the 30000-star crowded hard case (slow)"))])


if __name__ == "__main__":
    sys.exit(main())
