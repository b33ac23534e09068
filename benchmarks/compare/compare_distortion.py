"""
Bit-for-bit check of a refactor of the distortion stage (model selection).

Runs, on a fixed set of inputs, ``find_transform(..., transform_type=
'polynomial')`` (``degree`` 2, 3 and ``'auto'``) and ``transform_type=
'projective'``, and ``matching.fit_nonlinear`` on given pairs, and
writes per input the model's class and parameters, the covariance, the pairs'
indices, the quality dict (without timing) and the warnings' texts, or the
exception's type and message, to a JSON file (floats through their hex
representation: exact).  ``--compare`` reports every difference.

Inputs:

* simulated 1024x1024 pairs (``simulate.simulate_pair(..., distortion=...)``):
  barrel, pincushion, tilt, pure similarity, and a sparse field (few stars:
  a warning or a refusal);
* ``fit_nonlinear`` on given pairs (a barrel distortion, 30% of the pairs
  wrong; ``linear=None`` for the consensus start; projective; and a few
  pairs too few);
* if ``--data`` (default ``../shared/data``) exists: real frames through a
  known radial distortion and similarity (``bench_distortion_real``'s
  ``Truth`` and ``distort``): M6707HH.fits, the centre of
  m44-1910-04-01.jpg, and the 2MASS J-H pair as it is.

Usage (the checkout this script lives in is measured: its first line of
output names the package it imported)::

    python benchmarks/compare/compare_distortion.py --out before.json
    python benchmarks/compare/compare_distortion.py --out after.json
    python benchmarks/compare/compare_distortion.py --compare before.json after.json

It exits with status 1 if ``--compare`` finds a difference.
"""

import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

_HERE = os.path.dirname(os.path.abspath(__file__))
_BENCH = os.path.dirname(_HERE)  # benchmarks/: bench_real, bench_distortion_real
# The checkout this script lives in is the one measured (not an installed copy).
sys.path[:0] = [os.path.dirname(_BENCH), _BENCH, _HERE]
_DATA = Path(_BENCH).parent.parent / "shared" / "data"

# The same JSON comparison as the linear models' check.
from _command import run_command  # noqa: E402
from compare_transforms import compare  # noqa: E402

SIZE = 1024
#: (name, simulate_pair keywords) of the simulated pairs.
SIMULATED = [
    ("barrel", dict(n_stars=800, distortion=dict(k1=-0.02), rotation=12.0, seed=1)),
    ("pincushion", dict(n_stars=800, distortion=dict(k1=0.015), rotation=-30.0, seed=2)),
    ("tilt", dict(n_stars=800, distortion=dict(tilt=(0.03, -0.02)), rotation=5.0, seed=3)),
    ("similarity", dict(n_stars=800, rotation=40.0, scale=1.01, seed=4)),
    ("sparse", dict(n_stars=45, distortion=dict(k1=-0.02), rotation=8.0, seed=5)),
]
#: find_transform keywords run on every pair.
MODELS = [
    ("poly2", dict(transform_type="polynomial", degree=2)),
    ("poly3", dict(transform_type="polynomial", degree=3)),
    ("auto", dict(transform_type="polynomial", degree="auto")),
    ("projective", dict(transform_type="projective")),
]


def _exact(x):
    """A JSON value equal only for identical float64 values (or a plain value)."""
    if x is None or isinstance(x, (bool, str)):
        return x
    if isinstance(x, dict):
        return {str(k): _exact(v) for k, v in x.items()
                if "time" not in str(k) and "second" not in str(k)}
    if isinstance(x, (list, tuple)) and any(isinstance(v, (dict, str, type(None))) for v in x):
        return [_exact(v) for v in x]
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        return repr(x)
    return {"shape": list(a.shape), "hex": [float(v).hex() for v in a.ravel()]}


def _model(t):
    return {"class": type(t).__name__,
            "parameters": {n: _exact(getattr(t, n).value) for n in t.param_names},
            "repr": repr(t.parameters.tolist())}


def _catch(func):
    """Run ``func``: (its result, the sorted warnings) or (None, the exception)."""
    import astroalign_nd

    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            r = func()
    except Exception as exc:  # noqa: BLE001 - the exception is the recorded outcome
        return None, {"error": f"{type(exc).__name__}: {exc}"}
    return r, sorted(f"{w.category.__name__}: {w.message}" for w in caught
                     if issubclass(w.category, astroalign_nd.AstroalignWarning))


def _find(source, target, kw):
    import astroalign_nd

    r, caught = _catch(lambda: astroalign_nd.find_transform(source, target, **kw))
    if r is None:
        return caught
    t, (s, d) = r
    return {"model": _model(t), "source_points": _exact(s), "target_points": _exact(d),
            "quality": _exact(t.meta.get("quality", {})), "warnings": caught}


def _fit(src, dst, linear, kw):
    try:  # (its home since the transforms stopped importing the matching)
        from astroalign_nd.matching import fit_nonlinear
    except ImportError:
        from astroalign_nd.model_selection import fit_nonlinear

    r, caught = _catch(lambda: fit_nonlinear(src, dst, linear, **kw))
    if r is None:
        return caught
    return {"model": _model(r.transform), "covariance": _exact(r.covariance),
            "source_index": np.asarray(r.source_index).tolist(),
            "target_index": np.asarray(r.target_index).tolist(),
            "residuals": _exact(r.residuals), "info": _exact(r.info), "warnings": caught}


def _given_pairs():
    rng = np.random.default_rng(17)
    src = rng.uniform(0, 4095, (600, 2))
    u = (src - 2047.5) / 2896.0
    dst = src + (u * -0.0035 * (u ** 2).sum(1)[:, None]) * 2896.0
    dst = dst @ np.array([[0.99, -0.05], [0.05, 0.99]]).T + [30.0, -12.0]
    dst[:180] = rng.uniform(0, 4095, (180, 2))  # 30% wrong
    lin = np.array([[0.99, -0.05, 30.0], [0.05, 0.99, -12.0], [0, 0, 1]])
    frame = (-0.5, 4095.5, -0.5, 4095.5)
    err = rng.uniform(0.05, 0.2, len(src))
    base = dict(pairs_given=True, tolerance=15.0, source_frame=frame)
    yield "given auto", src, dst, lin, dict(base, degree="auto")
    yield "given auto similarity", src, dst, lin, dict(base, degree="auto",
                                                       linear_type="similarity")
    yield "given 2 errors", src, dst, lin, dict(base, degree=2, source_errors=err,
                                                target_errors=err)
    yield "given 5", src, dst, lin, dict(base, degree=5)
    yield "given consensus", src, dst, None, dict(base, degree=3)
    yield "given projective", src, dst, lin, dict(base, transform_type="projective")
    yield "given no frame", src, dst, lin, dict(pairs_given=True, tolerance=15.0, degree=3)
    yield "given few", src[200:230], dst[200:230], lin, dict(base, degree=5)
    yield "given too few", src[200:202], dst[200:202], lin, dict(base, degree=3)
    yield "given bad degree", src, dst, lin, dict(base, degree=7)
    # Positional pairing (not given): the same stars, shuffled target list.
    order = rng.permutation(len(src) - 180) + 180
    yield "positional auto", src[180:], dst[order], lin, dict(
        degree="auto", tolerance=15.0, source_frame=frame, seed_points=src[300:340])


def _real_frames(data):
    from bench_distortion_real import RadialTruth, distort
    from bench_real import load

    frames = [("M6707HH", data / "real" / "singles" / "M6707HH.fits", None),
              ("m44 1910 centre", data / "real" / "pairs" / "m44_plates" / "m44-1910-04-01.jpg",
               (slice(900, 2100), slice(900, 2100)))]
    for i, (name, path, crop) in enumerate(frames):
        if not path.exists():
            continue
        img, dtype = load(path)
        if crop is not None:
            img = np.ascontiguousarray(img[crop])
        truth = RadialTruth(img.shape, -4.0 if i == 0 else 6.0, rotation=15.0, shift=(7.0, -5.0))
        yield name, distort(img, dtype, truth, seed=i), img
    j, h = data / "field" / "gc_2MASS_j.fits.gz", data / "field" / "gc_2MASS_h.fits.gz"
    if j.exists() and h.exists():
        yield "2mass j-h", load(j)[0], load(h)[0]


def inputs(data):
    """Yield (name, function returning the record)."""
    from astroalign_nd.simulate import simulate_pair

    for name, kw in SIMULATED:
        pair = simulate_pair((SIZE, SIZE), **kw)
        for label, mkw in MODELS:
            yield f"sim {name} {label}", (lambda p=pair, k=mkw: _find(p.source, p.target, k))
    for name, src, dst, lin, kw in _given_pairs():
        yield f"fit {name}", (lambda a=(src, dst, lin, kw): _fit(*a))
    if data.is_dir():
        for name, src, dst in _real_frames(data):
            for label, mkw in MODELS:
                if name == "2mass j-h" and label != "auto":
                    continue
                yield f"real {name} {label}", (lambda s=src, d=dst, k=mkw: _find(s, d, k))


def record(out, data):
    import astroalign_nd

    print(f"astroalign_nd from {os.path.dirname(astroalign_nd.__file__)}")
    results = {}
    t0 = time.perf_counter()
    for name, run in inputs(data):
        results[name] = run()
    with open(out, "w") as f:
        json.dump(results, f, indent=0, sort_keys=True)
    n_err = sum("error" in v for v in results.values())
    n_warn = sum(bool(v.get("warnings")) for v in results.values())
    print(f"{len(results)} inputs ({n_err} raised, {n_warn} warned) in "
          f"{time.perf_counter() - t0:.0f} s -> {out}")


def main(argv=None):
    return run_command(argv, __doc__, record, compare, [
        (("--data",), dict(type=Path, default=_DATA,
                           help="the real data folder (skipped when absent)"))])


if __name__ == "__main__":
    sys.exit(main())
