"""
Fuzz campaign: no hang, no raw exception, no modified input, no confident
wrong answer, bounded memory.

Parts (``--part``, several allowed):

``related``
    Catalog pairs sharing stars under a known transform of each type
    (translation, euclidean, similarity, affine; mirrored half the time),
    with random star counts, extra unrelated stars, missing stars, noise,
    shuffled or kept in order.  Each must be recovered (error within
    ``max(2, 10 * noise)`` px everywhere in the overlap of the two frames)
    or refused (`AstroalignError`); a returned transform further off is a
    *wrong answer*.
``unrelated``
    Independent random catalogs of 3 to 300 stars under every transform
    type: every one must be refused.
``adversarial``
    Hostile inputs: degenerate catalogs (duplicates, collinear, lattices,
    one pixel wide, NaN rows, huge coordinates), random option values,
    random matrices to the models, damaged headers and ASDF trees, tiny
    and non-finite images to resampling.  Any exception other than
    ``ValueError``, ``TypeError`` or the package's own is *raw*; so is one
    raised from inside a library instead of by astroalign_nd.
``memory``
    Peak memory (RSS) and time of large and adversarial catalogs, each in
    its own process.

Every call runs in a worker process with a timeout (``--timeout``); a call
that does not return in time is a *hang* and the worker is restarted.
Every input array is compared with a copy after the call (*modified*).

Usage::

    python benchmarks/fuzz.py --part related --types affine --n 1000
    python benchmarks/fuzz.py --part unrelated --n 1000
    python benchmarks/fuzz.py --part adversarial --n 2000
    python benchmarks/fuzz.py --part memory
"""

import argparse
import multiprocessing as mp
import os
import resource
import subprocess
import sys
import time
import traceback
import warnings

import numpy as np

# The transforms drawn here are the tests' (tests/_helpers.py), over wider ranges.
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "tests"))
import _helpers  # noqa: E402

TYPES = ["translation", "euclidean", "similarity", "affine"]
FRAME = 1000.0
CORNERS = np.array([[0.0, 0.0], [FRAME, 0.0], [0.0, FRAME], [FRAME, FRAME]])


# -- case generators (run in the worker: only seeds cross the process boundary) -----

def random_matrix(rng, transform_type, mirrored):
    """A source -> target matrix of the type: wider scales, shears and shifts than the tests'."""
    return _helpers.random_matrix(rng, transform_type, mirrored, frame=FRAME,
                                  scale_range=(0.5, 2.0), stretch=0.2, shear=0.15, shift=300.0)


def overlap_error(model, m, n_grid=17):
    """
    Largest error (target px) over a grid of target pixels in the overlap.

    ``max |T_est(T_true^-1(p)) - p|`` over the points ``p`` of the target
    frame whose true preimage is in the source frame (as in the other
    benchmarks); the frame corners if the overlap has no grid point.
    """
    g = np.linspace(0.0, FRAME, n_grid)
    p = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    pre = (p - m[:2, 2]) @ np.linalg.inv(m[:2, :2]).T
    inside = np.all((pre >= 0) & (pre <= FRAME), axis=1)
    if inside.any():
        p, pre = p[inside], pre[inside]
    else:
        p, pre = CORNERS @ m[:2, :2].T + m[:2, 2], CORNERS
    got = np.column_stack(model(pre[:, 0], pre[:, 1]))
    return float(np.max(np.hypot(*(got - p).T)))


def related_case(seed, transform_type):
    rng = np.random.default_rng(seed)
    mirrored = bool(rng.integers(2))
    m = random_matrix(rng, transform_type, mirrored)
    n_true = int(rng.integers(3, 150))
    noise = float(rng.choice([0.0, 0.02, 0.1, 0.3, 1.0]))
    n_extra_src = int(rng.integers(0, 2 * n_true + 1))
    n_extra_dst = int(rng.integers(0, 2 * n_true + 1))
    true = rng.uniform(0, FRAME, (n_true, 2))
    moved = true @ m[:2, :2].T + m[:2, 2] + rng.normal(0, noise, (n_true, 2))
    # Some stars missing from one image or the other.
    keep_s = rng.uniform(size=n_true) > rng.uniform(0, 0.3)
    keep_d = rng.uniform(size=n_true) > rng.uniform(0, 0.3)
    src = np.vstack([true[keep_s], rng.uniform(0, FRAME, (n_extra_src, 2))])
    dst = np.vstack([moved[keep_d], rng.uniform(0, FRAME, (n_extra_dst, 2))])
    if rng.integers(2):  # shuffled: brightness order unrelated across images
        src, dst = src[rng.permutation(len(src))], dst[rng.permutation(len(dst))]
    desc = (f"{transform_type}{' mirrored' if mirrored else ''} n_true={n_true} "
            f"extra={n_extra_src}/{n_extra_dst} noise={noise}")
    return src, dst, m, noise, desc


def unrelated_case(seed):
    rng = np.random.default_rng(seed)
    transform_type = TYPES[int(rng.integers(4))]
    n_s, n_d = int(rng.integers(3, 300)), int(rng.integers(3, 300))
    src, dst = rng.uniform(0, FRAME, (n_s, 2)), rng.uniform(0, FRAME, (n_d, 2))
    if rng.integers(2):  # clustered fields
        src = rng.normal(FRAME / 2, 100, (n_s, 2))
    return src, dst, transform_type, f"{transform_type} {n_s} vs {n_d}"


def _bad_value(rng):
    pool = [0, -1, 1, 2, 0.0, -0.5, 1e-300, 1e300, np.nan, np.inf, -np.inf, "a", "3", None,
            True, (1,), (2, 1), (0, 1), (1, 2, 3), [], {}, 10**9, 2.5, np.float32(1.5),
            np.int64(4), (np.nan, 1), ("a", "b"), 1j]
    return pool[int(rng.integers(len(pool)))]


def _degenerate_catalog(rng):
    kind = int(rng.integers(9))
    n = int(rng.integers(0, 200))
    if kind == 0:  # duplicates
        pts = np.repeat(rng.uniform(0, 500, (max(1, n // 5), 2)), 5, axis=0)
    elif kind == 1:  # collinear
        t = rng.uniform(0, 500, n)
        pts = np.column_stack([t, 2 * t + 1])
    elif kind == 2:  # lattice
        k = int(rng.integers(2, 40))
        pts = np.stack(np.meshgrid(np.arange(k), np.arange(k)), -1).reshape(-1, 2) * 10.0
    elif kind == 3:  # all within one pixel
        pts = rng.uniform(0, 1, (n, 2))
    elif kind == 4:  # NaN / inf rows
        pts = rng.uniform(0, 500, (n, 2))
        if n:
            pts[rng.integers(0, n, max(1, n // 3))] = rng.choice([np.nan, np.inf, -np.inf])
    elif kind == 5:  # huge coordinates
        pts = rng.uniform(0, 1, (n, 2)) * 10.0 ** rng.uniform(0, 300)
    elif kind == 6:  # wrong shape
        pts = rng.uniform(0, 500, (n, int(rng.integers(1, 4))))
    elif kind == 7:  # integers, negatives
        pts = rng.integers(-1000, 1000, (n, 2))
    else:  # a few points
        pts = rng.uniform(0, 500, (int(rng.integers(0, 6)), 2))
    return pts


def adversarial_case(seed):
    """Return (callable, inputs to check for modification, description)."""
    import asdf
    from asdf.testing.helpers import yaml_to_asdf
    from astropy.io import fits

    import astroalign_nd as aand
    from astroalign_nd import transforms as tr
    from astroalign_nd.io import transform_from_header, transform_to_header
    from astroalign_nd.io.header import header_from_meta
    from astroalign_nd.resample import resample

    rng = np.random.default_rng(seed)
    kind = int(rng.integers(7))
    if kind == 0:  # degenerate catalogs
        a = _degenerate_catalog(rng)
        b = a + rng.uniform(-5, 5) if rng.integers(2) and a.size else _degenerate_catalog(rng)
        tt = TYPES[int(rng.integers(4))]
        return (lambda: aand.find_transform(a, b, transform_type=tt)), [a, b], \
            f"degenerate catalogs {a.shape} {b.shape} {tt}"
    if kind == 1:  # random option values
        from astroalign_nd.config import OPTIONS

        names = sorted(OPTIONS)
        opts = {names[int(rng.integers(len(names)))]: _bad_value(rng)
                for _ in range(int(rng.integers(1, 3)))}
        a = rng.uniform(0, 500, (40, 2))
        b = a + 3.0
        return (lambda: aand.find_transform(a, b, **opts)), [a, b], f"options {opts!r}"
    if kind == 2:  # models from random matrices and points
        m = rng.normal(0, 1, (3, 3)) * rng.choice([0.0, 1.0, 1e-12, 1e12])
        m[2] = [0, 0, 1] if rng.integers(4) else m[2]
        cls = [tr.TranslationTransform, tr.EuclideanTransform, tr.SimilarityTransform,
               tr.AffineTransform][int(rng.integers(4))]
        pts = _degenerate_catalog(rng)

        def call():
            model = cls.from_matrix(m) if rng.integers(2) else cls.from_points(pts, pts * 2)
            model.inverse
            return model
        return call, [m, pts], f"{cls.__name__} from matrix/points"
    if kind == 3:  # headers with hostile values
        meta = {}
        for _ in range(int(rng.integers(1, 6))):
            key = "".join(chr(int(c)) for c in rng.integers(32, 300, int(rng.integers(1, 10))))
            meta[key] = _bad_value(rng) if rng.integers(2) else "\u00e9\n" * 3
        model = tr.SimilarityTransform(scale=1.1)

        def call():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                hdr = transform_to_header(model, header_from_meta(meta))
            back = fits.Header.fromstring(hdr.tostring())
            d = dict(meta)
            d.update(dict(hdr))
            transform_from_header(d)
            return transform_from_header(back)
        return call, [], f"meta {meta!r}"[:120]
    if kind == 4:  # ASDF trees with hostile values
        name, cls = [("translation", tr.TranslationTransform), ("euclidean", tr.EuclideanTransform),
                     ("similarity", tr.SimilarityTransform),
                     ("affine", tr.AffineTransform)][int(rng.integers(4))]
        vals = {p: rng.choice(["0", "1", "-1", "5", ".nan", ".inf", "'x'", "[1, 2]", "1e308",
                               "0.5", "{a: 1}", "null"]) for p in cls.param_names}
        if rng.integers(2):
            vals.pop(cls.param_names[int(rng.integers(len(cls.param_names)))])
        body = "\n".join(f"  {k}: {v}" for k, v in vals.items())
        text = f"model: !<asdf://astroalign-nd.org/astroalign_nd/tags/{name}_transform-1.0.0>\n"

        def call():
            with asdf.config_context() as cfg:
                cfg.warn_on_failed_conversion = False
                with asdf.open(yaml_to_asdf(text + body + "\n")) as af:
                    model = af["model"]
            assert np.all(np.isfinite(model.matrix)), "non-finite model read"
            model.inverse
            return model
        return call, [], f"asdf {name} {vals}"
    if kind == 5:  # resampling with hostile images and matrices
        shape = tuple(int(v) for v in rng.integers(0, 6, 2)) if rng.integers(2) else (20, 30)
        data = rng.normal(size=shape)
        if data.size and rng.integers(2):
            data[rng.integers(0, shape[0]), :] = rng.choice([np.nan, np.inf])
        m = np.eye(3)
        m[:2] = rng.normal(0, 1, (2, 3)) * rng.choice([1.0, 1e-15, 1e15])
        out_shape = tuple(int(v) for v in rng.integers(0, 40, 2))
        order = ["nearest-neighbor", "bilinear", "bicubic", 5, "x"][int(rng.integers(5))]
        return (lambda: resample(data, m, out_shape, order=order)), [data, m], \
            f"resample {shape}->{out_shape} order={order}"
    # kind 6: apply_transform with hostile quality / uncertainty / transform
    from astropy.nddata import NDData, StdDevUncertainty

    img = rng.normal(size=(24, 24))
    unc = StdDevUncertainty(np.ones((24, 24) if rng.integers(2) else (24,)))
    quality = [None, {}, {"rms": 1}, {"n_matches": "a", "rms": 1, "log10_false_alarm": 0},
               {"n_matches": 3, "rms": np.nan, "log10_false_alarm": -9}, "bad"][
                   int(rng.integers(6))]
    t = tr.SimilarityTransform(scale=float(rng.choice([1.0, 0.0, 1e-20])))
    return (lambda: aand.apply_transform(t, NDData(img, uncertainty=unc), img,
                                         quality=quality)), [img], \
        f"apply_transform quality={quality!r}"


# -- the worker --------------------------------------------------------------------

def _raised_by_us(exc):
    """True if the exception was raised by astroalign_nd's own code."""
    tb = exc.__traceback__
    last = None
    while tb is not None:
        last = tb.tb_frame.f_code.co_filename
        tb = tb.tb_next
    return last is not None and f"astroalign_nd{os.sep}" in last and "site-packages" not in last


def run_case(part, seed, arg):
    """Run one case; return (outcome, detail)."""
    import astroalign_nd as aand

    warnings.simplefilter("ignore")
    if part in ("related", "unrelated"):
        if part == "related":
            src, dst, m, noise, desc = related_case(seed, arg)
            tt = arg
        else:
            src, dst, tt, desc = unrelated_case(seed)
        copies = (src.copy(), dst.copy())
        try:
            model, _ = aand.find_transform(src, dst, transform_type=tt)
        except aand.AstroalignError:
            outcome, detail = "refused", desc
        except Exception as exc:  # noqa: BLE001 - the point of fuzzing
            outcome, detail = "raw", f"{desc}: {type(exc).__name__}: {exc}"
        else:
            if part == "unrelated":
                outcome, detail = "wrong", f"{desc}: accepted log10 FA " \
                    f"{model.meta['quality']['log10_false_alarm']:.1f}"
            else:
                err = overlap_error(model, m)
                ok = err <= max(2.0, 10 * noise)
                outcome = "recovered" if ok else "wrong"
                detail = (f"{desc}: error {err:.2f} px, "
                          f"{model.meta['quality']['n_matches']} matches, log10 FA "
                          f"{model.meta['quality']['log10_false_alarm']:.1f}")
        if not (np.array_equal(src, copies[0]) and np.array_equal(dst, copies[1])):
            outcome, detail = "modified", desc
        return outcome, detail
    call, inputs, desc = adversarial_case(seed)
    copies = [np.array(a, copy=True) for a in inputs]
    try:
        call()
        outcome, detail = "ok", desc
    except (ValueError, TypeError, aand.AstroalignError) as exc:
        if _raised_by_us(exc):
            outcome, detail = "clear error", desc
        else:
            outcome = "raw"
            detail = f"{desc}: {type(exc).__name__} from a library: {exc}\n" + "".join(
                traceback.format_tb(exc.__traceback__)[-2:])
    except Exception as exc:  # noqa: BLE001 - the point of fuzzing
        outcome = "raw"
        detail = f"{desc}: {type(exc).__name__}: {exc}\n" + "".join(
            traceback.format_tb(exc.__traceback__)[-2:])
    for a, b in zip(inputs, copies):
        if not np.array_equal(np.asarray(a), b, equal_nan=True):
            outcome, detail = "modified", desc
    return outcome, detail


def _worker(tasks, results):
    os.environ.setdefault("ASTROALIGN_ND_NUM_THREADS", "1")
    while True:
        task = tasks.get()
        if task is None:
            return
        try:
            results.put((task, *run_case(*task)))
        except BaseException as exc:  # noqa: BLE001 - reported, the worker goes on
            results.put((task, "raw", f"harness: {type(exc).__name__}: {exc}"))


class Runner:
    """One worker process, restarted after a hang."""

    def __init__(self, timeout):
        self.timeout = timeout
        self.ctx = mp.get_context("fork")
        self._start()

    def _start(self):
        self.tasks, self.results = self.ctx.Queue(), self.ctx.Queue()
        self.proc = self.ctx.Process(target=_worker, args=(self.tasks, self.results),
                                     daemon=True)
        self.proc.start()

    def run(self, task):
        self.tasks.put(task)
        try:
            _, outcome, detail = self.results.get(timeout=self.timeout)
        except Exception:  # queue.Empty: a hang (or a crashed worker)
            crashed = not self.proc.is_alive()
            self.proc.kill()
            self.proc.join()
            self._start()
            return ("crash" if crashed else "hang"), f"{task}"
        return outcome, detail

    def close(self):
        self.tasks.put(None)
        self.proc.join(5)
        if self.proc.is_alive():
            self.proc.kill()


def campaign(part, n, seed0, timeout, types, verbose):
    runner = Runner(timeout)
    counts, notes = {}, {}
    t0 = time.perf_counter()
    groups = types if part == "related" else [None]
    for group in groups:
        for i in range(n):
            task = (part, seed0 + i, group)
            outcome, detail = runner.run(task)
            key = (group or part, outcome)
            counts[key] = counts.get(key, 0) + 1
            if outcome in ("wrong", "raw", "hang", "crash", "modified"):
                notes.setdefault(key, []).append(f"seed {seed0 + i}: {detail}")
            if verbose:
                print(f"{group or part} seed {seed0 + i}: {outcome} {detail}", flush=True)
    runner.close()
    elapsed = time.perf_counter() - t0
    return counts, notes, elapsed


def report(part, counts, notes, elapsed, n_groups):
    total = sum(counts.values())
    print(f"\n== part {part}: {total} inputs tried in {elapsed:.0f} s ==")
    groups = sorted({g for g, _ in counts})
    outcomes = sorted({o for _, o in counts})
    print(f"{'group':<14}" + "".join(f"{o:>13}" for o in outcomes))
    for g in groups:
        print(f"{g:<14}" + "".join(f"{counts.get((g, o), 0):>13}" for o in outcomes))
    bad = {k: v for k, v in notes.items()}
    for (g, o), lines in sorted(bad.items()):
        print(f"-- {g} {o}: {len(lines)}")
        for line in lines[:10]:
            print("   " + line.replace("\n", "\n   "))
    for o in ("wrong", "raw", "hang", "crash", "modified"):
        print(f"{o}: {sum(v for (g, oo), v in counts.items() if oo == o)}", end="; ")
    print()


# -- memory ------------------------------------------------------------------------

MEMORY_CASES = {
    "100k unrelated, defaults": "find_transform(u(100_000), u(100_000))",
    "1M unrelated, defaults": "find_transform(u(1_000_000, 40000), u(1_000_000, 40000))",
    "100k unrelated, max_sources=20000":
        "find_transform(u(100_000), u(100_000), max_sources=20000)",
    "100k unrelated, n_neighbors=8, max_sources=5000":
        "find_transform(u(100_000), u(100_000), n_neighbors=8, max_sources=5000)",
    "100k related (rotated), defaults": "find_transform(a, a @ R.T + 5)",
    "lattice 100x100, max_sources=5000": "find_transform(g, g + 0.3, max_sources=5000)",
    "10k identical points": "find_transform(np.ones((10_000, 2)), np.ones((10_000, 2)))",
    "n_neighbors=16, max_sources=5000 (refused before allocating)":
        "find_transform(u(10_000), u(10_000), n_neighbors=16, max_sources=5000)",
}

_MEMORY_CHILD = """
import resource, sys, time, warnings
import numpy as np
warnings.simplefilter("ignore")
from astroalign_nd import find_transform
rng = np.random.default_rng(0)
def u(n, size=4000.0):
    return rng.uniform(0, size, (n, 2))
a = u(100_000)
R = np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
g = np.stack(np.meshgrid(np.arange(100.0), np.arange(100.0)), -1).reshape(-1, 2) * 10
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t = time.perf_counter()
try:
    {call}
    out = "accepted"
except Exception as exc:
    out = type(exc).__name__ + ": " + str(exc)[:90]
print(f"{{time.perf_counter() - t:.1f}}|{{base / 1024:.0f}}|"
      f"{{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f}}|{{out}}")
"""


def memory(timeout):
    print("\n== part memory: peak RSS of adversarial catalogs (one process each) ==")
    print(f"{'case':<62}{'time':>8}{'RSS MB':>9}  outcome")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for name, call in MEMORY_CASES.items():
        code = _MEMORY_CHILD.format(call=call)
        try:
            res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                 timeout=timeout, env=env)
            line = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else (
                "-|-|-|crash: " + res.stderr.strip().splitlines()[-1])
        except subprocess.TimeoutExpired:
            line = f"{timeout}|-|-|HANG (timeout)"
        t, _, peak, out = line.split("|", 3)
        print(f"{name:<62}{t:>7}s{peak:>9}  {out}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parts = ["related", "unrelated", "adversarial", "memory"]
    ap.add_argument("--part", nargs="+", default=parts, choices=parts)
    ap.add_argument("--n", type=int, default=1000, help="inputs per group (default 1000)")
    ap.add_argument("--seed", type=int, default=0, help="first seed")
    ap.add_argument("--types", nargs="+", default=TYPES, choices=TYPES,
                    help="transform types of the related part")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per call")
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    import astroalign_nd

    print(f"astroalign_nd {astroalign_nd.__version__} from {astroalign_nd.__file__}")
    print(f"fuzz.py {' '.join(argv or sys.argv[1:])}; timeout {args.timeout:g} s per call")
    for part in args.part:
        if part == "memory":
            memory(max(args.timeout, 120.0))
            continue
        counts, notes, elapsed = campaign(part, args.n, args.seed, args.timeout, args.types,
                                          args.verbose)
        report(part, counts, notes, elapsed, len(args.types))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS of this process {peak:.0f} MB")


if __name__ == "__main__":
    main()
