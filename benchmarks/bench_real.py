"""
Real frames: astroalign_nd against astroalign and aafitrans on the
same real images, in one run.

Inputs are every frame in ``../shared/data/real`` and ``../shared/data/field``
(see their README.txt for provenance):

* **warped singles**: each frame warped by known similarity transforms
  (rotations up to 180 degrees, scale 0.7 to 1.4, one mirrored), so the
  truth is exact.  Pixels that fall outside the original are filled with the
  frame's median sky plus noise of its own level; integer frames (8-bit
  JPEGs, raw uint16) are rounded back to their type.
* **real pairs** of one field: the HAT-P-32 night, the Seestar nights,
  the M44 plates 65 years apart, the two JWST epochs, the DECam stamps and
  2MASS J/H.  Where the publishers resampled both onto one grid (JWST,
  DECam, 2MASS) the truth is the identity; elsewhere no truth is known and
  an answer is judged by agreement with the other tools (see below) and by
  loop closure.
* **cross-field pairs**, which must be refused.
* **loop closure** over frame triplets i, j, k of one field:
  ``max |T_jk(T_ij(p)) - T_ik(p)|`` over frame ``i``, which needs no truth.

Methods (same float32 arrays for all):

* astroalign_nd: ``find_transform(source, target)`` with its defaults;
* astroalign: ``astroalign.find_transform(source, target)`` with its defaults;
* aafitrans: ``aafitrans.find_transform`` on astroalign's detections
  (``astroalign._find_sources``, 5 sigma, as in aafitrans' docs), defaults;
* fitsh: FITSH's ``fistar`` and ``grmatch`` (``run_fitsh``), when installed.

Error of a returned transform: the largest distance, in target pixels,
between the true and the estimated position over a grid of target pixels
(every 8th) that receive source data.  Solved: error <= 2 px (``--tol``).
Wrong: a transform returned with a larger error (for cross-field pairs:
any transform).  For real pairs with no truth, the reference for
solved/wrong is the median of the transforms returned by the tools that
agree with each other within 2 px (at least two); with no two tools
agreeing the case is not judged.  Median errors are reported only where
the truth is known (warps; JWST, DECam and 2MASS pairs): the consensus
leans towards the two peers, which share astroalign's detections.  The
precision on the other real pairs is measured by loop closure.

Usage::

    python benchmarks/bench_real.py [--data ../shared/data] [--warps 5] [--only NAME]
        [--methods astroalign_nd astroalign aafitrans fitsh] [--timeout 120] [-v]
"""

import argparse
import itertools
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

HERE = Path(__file__).resolve().parent
DEFAULT_DATA = HERE.parents[1] / "shared" / "data"
GRID_STEP = 8
#: FITSH runs where its programs are installed.
METHODS = ("astroalign_nd", "astroalign", "aafitrans") + (
    ("fitsh",) if all(map(shutil.which, ("fistar", "grmatch", "grtrans"))) else ())

# (name, rotation deg, scale, mirrored, shift x, shift y): source -> target.
WARPS = [
    ("rot2", 2.0, 1.0, False, 14.0, -9.0),
    ("rot30", 30.0, 1.0, False, 10.0, 5.0),
    ("rot120s0.7", 120.0, 0.7, False, 0.0, 0.0),
    ("rot-170s1.4", -170.0, 1.4, False, -5.0, 8.0),
    ("mirror75s1.1", 75.0, 1.1, True, 0.0, 0.0),
]


# -- frames ---------------------------------------------------------------------------------

def load(path):
    """(float32 image, original dtype) of a file, as astroalign_nd reads it."""
    from astroalign_nd.io.read import parse_input

    p = parse_input(str(path))
    img = p.detection_image
    return np.ascontiguousarray(img, dtype=np.float32), np.asarray(p.data).dtype


def singles(data):
    files = sorted((data / "real" / "singles").glob("*"))
    files += sorted((data / "real" / "pairs").glob("*/*"))
    files += sorted((data / "field").glob("*.fits*")) + sorted((data / "field").glob("*.jpg"))
    return [f for f in files if f.suffix.lower() not in (".txt",)]


def similarity(rot, scale, mirror, tx, ty, shape):
    """3x3 source -> target matrix about the frame centre."""
    ny, nx = shape
    c = np.array([(nx - 1) / 2.0, (ny - 1) / 2.0])
    a = np.deg2rad(rot)
    r = scale * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    if mirror:
        r = r @ np.diag([-1.0, 1.0])
    m = np.eye(3)
    m[:2, :2] = r
    m[:2, 2] = c - r @ c + [tx, ty]
    return m


def warp(img, dtype, m, seed):
    """The image as seen through ``m`` (source -> target), same shape."""
    inv = np.linalg.inv(m)
    # ndimage works in (row, col): swap axes of the inverse map.
    mat = inv[:2, :2][::-1, ::-1]
    off = inv[:2, 2][::-1]
    bad = ~np.isfinite(img)
    good = img[~bad]
    med = float(np.median(good))
    # NaN would spread through the spline prefilter: warp the blank
    # pixels (mosaic edges) separately and blank them again afterwards.
    out = ndimage.affine_transform(np.where(bad, med, img).astype(np.float64), mat,
                                   offset=off, order=3, mode="constant", cval=np.nan,
                                   prefilter=True)
    if bad.any():
        wbad = ndimage.affine_transform(bad.astype(np.float32), mat, offset=off, order=0,
                                        mode="constant", cval=0.0) > 0.5
        out[wbad] = np.nan
    return fill_holes(out, img, med, dtype, seed)


def fill_holes(out, img, med, dtype, seed):
    """Pixels from outside the frame (NaN): the sky plus noise of ``img``'s level, as float32."""
    hole = ~np.isfinite(out)
    if hole.any():
        d = np.diff(img[::4].astype(np.float64), axis=1).ravel()
        d = d[np.isfinite(d)]
        sig = 1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2)
        rng = np.random.default_rng(seed)
        out[hole] = med + sig * rng.standard_normal(hole.sum())
    if np.dtype(dtype).kind in "iu":
        info = np.iinfo(dtype)
        out = np.clip(np.round(out), info.min, info.max)
    return out.astype(np.float32)


@dataclass
class Case:
    kind: str          # 'warp', 'pair', 'cross'
    name: str
    source: object
    target: object
    truth: object = None   # 3x3 or None
    refuse: bool = False


def build_cases(data, n_warps, only=None):
    cases = []
    frames = {}
    for f in singles(data):
        if only and not any(o in f.name for o in only):
            continue
        img, dtype = load(f)
        frames[f] = img
        for k, (wname, rot, scale, mirror, tx, ty) in enumerate(WARPS[:n_warps]):
            m = similarity(rot, scale, mirror, tx, ty, img.shape)
            cases.append(Case("warp", f"{f.name}:{wname}", img, warp(img, dtype, m, k), m))
    return cases, frames


def pair_specs(data):
    """(name, source path, target path, truth or None) of the real pairs."""
    real, field = data / "real" / "pairs", data / "field"
    hat = sorted((real / "exotic_hatp32_microobservatory").glob("*.FITS"))
    jw = sorted((real / "jwst_a2744_f200w").glob("*.fits"))
    specs = [(f"hatp32 {i}-{j}", hat[i], hat[j], None) for i, j in
             itertools.combinations(range(len(hat)), 2)]
    m94 = {k: field / f"seestar_m94_{k}.fits.gz" for k in ("n1a", "n1b", "n2a", "n3a", "n3b")}
    ngc = {k: field / f"seestar_ngc7023_{k}.fits.gz" for k in ("y24a", "y24b", "y25a")}
    for group in (m94, ngc):
        for a, b in itertools.combinations(sorted(group), 2):
            specs.append((f"seestar {a}-{b}", group[a], group[b], None))
    specs += [
        ("m44 1910-1975", real / "m44_plates" / "m44-1910-04-01.jpg",
         real / "m44_plates" / "m44-1975-01-18.jpg", None),
        ("jwst 1324-2561", jw[0], jw[1], np.eye(3)),
        ("decam 04a-18a", field / "decam_DEC-OBS04a.mini.fits",
         field / "decam_DEC-OBS18a.mini.fits", np.eye(3)),
        ("2mass j-h", field / "gc_2MASS_j.fits.gz", field / "gc_2MASS_h.fits.gz", np.eye(3)),
    ]
    return specs


def cross_specs(data):
    s, f = data / "real" / "singles", data / "field"
    return [
        ("HorseHead x M67", s / "HorseHead.fits", s / "M6707HH.fits"),
        ("m94 x ngc7023", f / "seestar_m94_n1a.fits.gz", f / "seestar_ngc7023_y24a.fits.gz"),
        ("m13 x sep_eso", s / "m13_dss_skyview.fits", s / "sep_eso_image.fits"),
        ("a8280271 x decam", s / "a8280271.fits", f / "decam_DEC-OBS04a.mini.fits"),
        ("2mass_k x spitzer", s / "gc_2mass_k.fits", s / "spitzer_example_image.fits"),
        ("hatp32 x m94", sorted((data / "real" / "pairs" / "exotic_hatp32_microobservatory")
                                .glob("*.FITS"))[0], f / "seestar_m94_n2a.fits.gz"),
        ("anet_sdss x decam", f / "anet_sdss.jpg", f / "decam_DEC-OBS18a.mini.fits"),
        ("jwst x hdf", sorted((data / "real" / "pairs" / "jwst_a2744_f200w").glob("*.fits"))[0],
         s / "hubble_deep_field.jpg"),
    ]


def triplets():
    """Frame triplets (by pair-name convention) for loop closure."""
    out = [("hatp32", i, j, k) for i, j, k in itertools.combinations(range(5), 3)]
    out += [("seestar", a, b, c) for a, b, c in
            [("n1a", "n1b", "n2a"), ("n1a", "n1b", "n3a"), ("n1a", "n3a", "n3b"),
             ("n2a", "n3a", "n3b"), ("y24a", "y24b", "y25a")]]
    return out


# -- methods --------------------------------------------------------------------------------

def run_astroalign_nd(src, dst):
    import astroalign_nd

    t, _ = astroalign_nd.find_transform(src, dst)
    return np.asarray(t.matrix, float), t.meta["quality"]["n_matches"]


def run_astroalign(src, dst):
    import astroalign

    t, (s, _) = astroalign.find_transform(src, dst)
    return np.asarray(t.params, float), len(s)


def run_aafitrans(src, dst):
    import aafitrans
    import astroalign

    # As aafitrans' README does: positions from a source extractor, brightest first.
    s = astroalign._find_sources(src)
    d = astroalign._find_sources(dst)
    t, (ms, _) = aafitrans.find_transform(s, d)
    return np.asarray(t.params, float), len(ms)


def run_aafitrans_nd(src, dst):
    """aafitrans on astroalign_nd's detections (100 brightest), as ``bench_hard_cases``."""
    import aafitrans

    from astroalign_nd import find_sources

    s, d = (find_sources(img, n_sources=100) for img in (src, dst))
    xy = [np.column_stack([t["x"], t["y"]]) for t in (s, d)]
    t, (ms, _) = aafitrans.find_transform(*xy)
    return np.asarray(t.params, float), len(ms)


FISTAR = shutil.which("fistar")
GRMATCH = shutil.which("grmatch")
GRTRANS = shutil.which("grtrans")


def run_fitsh(src, dst):
    """
    FITSH: ``fistar`` on each frame (its default 'uplink' algorithm and
    elliptic model, a flux threshold of 5 sky sigmas from the median
    absolute deviation, brightest first), ``grmatch --match-points`` with an
    affine (order 1) fit of the pairs within 1 px (``--max-distance 1``: by
    default a few chance pairs skew its fit by pixels), and ``grtrans`` to
    read the fit back as a matrix.
    Runs the two programs as the command line would, files and all.
    """
    if not (FISTAR and GRMATCH and GRTRANS):
        raise RuntimeError("FITSH (fistar, grmatch, grtrans) is not installed")
    from astropy.io import fits
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cats = []
        for name, img in (("src", src), ("dst", dst)):
            data = np.asarray(img, np.float32)
            good = data[np.isfinite(data)]
            sigma = 1.4826 * np.median(np.abs(good - np.median(good)))
            fits.writeto(tmp / f"{name}.fits", data)
            cat = tmp / f"{name}.cat"
            subprocess.run([FISTAR, "-i", str(tmp / f"{name}.fits"), "-o", str(cat),
                            "-t", f"{max(5.0 * sigma, 1e-6):g}", "-s", "flux",
                            "-F", "x,y,flux"], check=True, capture_output=True, timeout=600)
            cats.append(cat)
        trans = tmp / "trans.txt"
        run = subprocess.run([GRMATCH, "--match-points", "-r", str(cats[0]), "-i", str(cats[1]),
                              "--col-ref", "1,2", "--col-inp", "1,2",
                              "--col-ref-ordering", "-3", "--col-inp-ordering", "-3",
                              "--order", "1", "--max-distance", "1",
                              "--output-transformation", str(trans),
                              "--output", str(tmp / "pairs.txt")],
                             capture_output=True, text=True, timeout=600)
        if run.returncode != 0 or not trans.exists() or trans.stat().st_size == 0:
            raise RuntimeError(f"grmatch found no match: {run.stderr.strip()[-60:]}")
        n = len(np.loadtxt(tmp / "pairs.txt", ndmin=2))
        # FITSH puts pixel centres at half-integers; these are 0-based centres.
        q = np.array([[0.0, 0.0], [1000.0, 0.0], [0.0, 1000.0]])
        np.savetxt(tmp / "q.txt", q + 0.5, fmt="%.6f")
        out = subprocess.run([GRTRANS, "--input", str(tmp / "q.txt"), "--col-xy", "1,2",
                              "--input-transformation", str(trans), "--output", "-"],
                             capture_output=True, text=True, check=True)
        p = np.array([[float(v) for v in line.split()[:2]] for line in out.stdout.splitlines()
                      if line.strip() and not line.startswith("#")]) - 0.5
    m = np.eye(3)
    m[:2, :2] = np.column_stack([(p[1] - p[0]) / 1000.0, (p[2] - p[0]) / 1000.0])
    m[:2, 2] = p[0]
    return m, n


RUNNERS = {"astroalign_nd": run_astroalign_nd, "astroalign": run_astroalign,
           "aafitrans": run_aafitrans, "aafitrans-nd": run_aafitrans_nd, "fitsh": run_fitsh}


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout()


def call(method, src, dst, timeout):
    t0 = time.perf_counter()
    alarm = hasattr(signal, "SIGALRM")  # not on Windows: no time limit there
    if alarm:
        signal.signal(signal.SIGALRM, _alarm)
        signal.alarm(int(timeout))
    try:
        m, n = RUNNERS[method](src, dst)
        status, note = "returned", f"n={n}"
    except _Timeout:
        m, status, note = None, "failed", f"time-out ({timeout} s)"
    except Exception as exc:  # noqa: BLE001 - every failure is counted, none is fatal
        m, status, note = None, "failed", f"{type(exc).__name__}: {str(exc)[:60]}"
    finally:
        if alarm:
            signal.alarm(0)
    return status, m, time.perf_counter() - t0, note


# -- accuracy -------------------------------------------------------------------------------

def overlap_grid(truth, src_shape, dst_shape):
    ny, nx = dst_shape
    yy, xx = np.mgrid[0:ny:GRID_STEP, 0:nx:GRID_STEP]
    p = np.column_stack([xx.ravel(), yy.ravel()]).astype(float)
    inv = np.linalg.inv(truth)
    q = p @ inv[:2, :2].T + inv[:2, 2]
    sy, sx = src_shape
    inside = (q[:, 0] >= -0.5) & (q[:, 0] <= sx - 0.5) & (q[:, 1] >= -0.5) & (q[:, 1] <= sy - 0.5)
    return (p[inside] if inside.any() else p), (q[inside] if inside.any() else q)


def error(m_est, truth, src_shape, dst_shape):
    """max |T_est(q) - T_true(q)| over source points q that land in the target."""
    p, q = overlap_grid(truth, src_shape, dst_shape)
    r = q @ m_est[:2, :2].T + m_est[:2, 2]
    return float(np.max(np.hypot(r[:, 0] - p[:, 0], r[:, 1] - p[:, 1])))


def frame_distance(m1, m2, shape):
    ny, nx = shape
    yy, xx = np.mgrid[0:ny:GRID_STEP, 0:nx:GRID_STEP]
    q = np.column_stack([xx.ravel(), yy.ravel()]).astype(float)
    a = q @ m1[:2, :2].T + m1[:2, 2]
    b = q @ m2[:2, :2].T + m2[:2, 2]
    return float(np.max(np.hypot(*(a - b).T)))


def consensus(mats, shape, tol):
    """Median matrix of the largest group of transforms agreeing within tol, or None."""
    names = [k for k, m in mats.items() if m is not None]
    best = []
    for k in names:
        group = [j for j in names if frame_distance(mats[k], mats[j], shape) <= tol]
        if len(group) > len(best):
            best = group
    if len(best) < 2:
        return None
    return np.median(np.stack([mats[k] for k in best]), axis=0)


# -- main -----------------------------------------------------------------------------------

def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--warps", type=int, default=len(WARPS))
    ap.add_argument("--only", nargs="*", default=None,
                    help="only frames / pairs whose name contains one of these")
    ap.add_argument("--methods", nargs="*", default=list(METHODS))
    ap.add_argument("--timeout", type=int, default=120)
    ap.add_argument("--tol", type=float, default=2.0)
    ap.add_argument("--skip", nargs="*", default=[], choices=["warp", "pair", "cross"])
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    if not args.data.is_dir():
        sys.exit(f"no data folder at {args.data}")
    methods = args.methods
    for m in methods:  # warm-up: imports outside the timing
        from astroalign_nd.simulate import simulate_pair
        pr = simulate_pair((256, 256), n_stars=80, rotation=10.0, seed=0)
        call(m, np.asarray(pr.source.data, np.float32), np.asarray(pr.target.data, np.float32),
             300)

    rows = []   # (kind, name, method, status, err, seconds, note, verdict)
    mats = {}   # (pair name, method) -> matrix

    def record(kind, name, results, truth, src_shape, dst_shape, refuse=False):
        judged = truth
        if truth is None and not refuse:
            judged = consensus({m: r[1] for m, r in results.items()}, src_shape, args.tol)
        for m, (status, mat, dt, note) in results.items():
            err = np.nan
            if refuse:
                verdict = "ok" if status == "failed" else "WRONG"
            elif status != "returned":
                verdict = "fail"
            elif judged is None:
                verdict = "unjudged"
            else:
                err = error(mat, judged, src_shape, dst_shape)
                verdict = "ok" if err <= args.tol else "WRONG"
            rows.append((kind, name, m, status, err, dt, note, verdict, truth is not None))
            if args.verbose:
                print(f"  {kind:5s} {name:42s} {m:14s} {verdict:8s} err={err:8.3f} "
                      f"t={dt:7.3f}s {note}", flush=True)

    if "warp" not in args.skip:
        cases, _ = build_cases(args.data, args.warps, args.only)
        for c in cases:
            res = {m: call(m, c.source, c.target, args.timeout) for m in methods}
            record("warp", c.name, res, c.truth, c.source.shape, c.target.shape)

    cache = {}

    def get(path):
        if path not in cache:
            cache[path] = load(path)[0]
        return cache[path]

    if "pair" not in args.skip:
        for name, a, b, truth in pair_specs(args.data):
            if args.only and not any(o in name for o in args.only):
                continue
            src, dst = get(a), get(b)
            res = {m: call(m, src, dst, args.timeout) for m in methods}
            for m, r in res.items():
                mats[(name, m)] = r[1]
            record("pair", name, res, truth, src.shape, dst.shape)

    if "cross" not in args.skip:
        for name, a, b in cross_specs(args.data):
            if args.only and not any(o in name for o in args.only):
                continue
            src, dst = get(a), get(b)
            res = {m: call(m, src, dst, args.timeout) for m in methods}
            record("cross", name, res, None, src.shape, dst.shape, refuse=True)

    report(rows, mats, methods, args)


def loop_closures(mats, methods):
    """{method: [closure error]} over the frame triplets."""
    out = {m: [] for m in methods}
    shapes = {"hatp32": (500, 650), "seestar": (540, 960)}
    for group, i, j, k in triplets():
        for m in methods:
            tij = mats.get((f"{group} {i}-{j}", m))
            tjk = mats.get((f"{group} {j}-{k}", m))
            tik = mats.get((f"{group} {i}-{k}", m))
            if tij is None or tjk is None or tik is None:
                out[m].append(np.nan)
                continue
            out[m].append(frame_distance(tjk @ tij, tik, shapes[group]))
    return out


def time_ratio(times, method, only=None, peer="astroalign"):
    """
    'median (90th percentile)' over cases of ``method``'s time over
    ``peer``'s on the same case; ``times`` maps (case, method) to seconds,
    ``only`` (a set of (case, method)) keeps the cases ``method`` refused.
    """
    r = [t / times[(case, peer)] for (case, m), t in times.items()
         if m == method and (case, peer) in times and times[(case, peer)] > 0
         and (only is None or (case, m) in only)]
    if not r:
        return "-"
    return f"{np.median(r):.2f} ({np.percentile(r, 90):.2f})"


def report(rows, mats, methods, args):
    print(f"\nReal frames: {', '.join(methods)} on the same inputs (tol {args.tol:g} px)\n")
    kinds = ("warp", "pair", "cross")
    hdr = f"{'':22s}" + "".join(f"{m:>16s}" for m in methods)
    print(hdr)
    for kind in kinds:
        sub = [r for r in rows if r[0] == kind]
        if not sub:
            continue
        n = len({r[1] for r in sub})
        for label, pick in (("solved", "ok"), ("wrong", "WRONG"), ("failed", "fail"),
                            ("unjudged", "unjudged")):
            vals = [sum(1 for r in sub if r[2] == m and r[7] == pick) for m in methods]
            if pick == "unjudged" and not any(vals):
                continue
            print(f"{kind + ' ' + label + f' (of {n})':22s}" + "".join(f"{v:16d}" for v in vals))
        if kind != "cross":
            # Errors only where the truth is known: against the consensus of
            # tools, two of which share astroalign's detections, they say
            # who agrees with whom, not who is right.
            # (A name of its own: the times below are over every case.)
            known = [r for r in sub if r[8]]
            med = []
            for m in methods:
                e = [r[4] for r in known if r[2] == m and r[7] == "ok"]
                med.append(np.median(e) if e else np.nan)
            print(f"{kind + f' truth({len(known) // len(methods)}) err px':22s}"
                  + "".join(f"{v:16.3f}" for v in med))
            # Errors on the cases every method solved: the fair comparison.
            common = [nm for nm in {r[1] for r in known}
                      if all(any(r[1] == nm and r[2] == m and r[7] == "ok" for r in known)
                             for m in methods)]
            med = []
            for m in methods:
                e = [r[4] for r in known if r[2] == m and r[1] in common]
                med.append(np.median(e) if e else np.nan)
            print(f"{kind + f' common({len(common)}) px':22s}" + "".join(f"{v:16.3f}" for v in med))
        tmed = [np.median([r[5] for r in sub if r[2] == m]) for m in methods]
        print(f"{kind + ' median time s':22s}" + "".join(f"{v:16.3f}" for v in tmed))
        if "astroalign" in methods:
            t = {(r[1], r[2]): r[5] for r in sub}
            refused = {(r[1], r[2]) for r in sub if r[3] != "returned"}
            for label, only in (("t / astroalign", False), ("refused t / aa", True)):
                print(f"{kind + ' ' + label:22s}" + "".join(
                    f"{time_ratio(t, m, refused if only else None):>16s}" for m in methods))
    loops = loop_closures(mats, methods)
    if any(np.isfinite(v).any() for v in loops.values()):
        print(f"{'loop closure med px':22s}" + "".join(
            f"{np.nanmedian(loops[m]) if np.isfinite(loops[m]).any() else np.nan:16.3f}"
            for m in methods))
        print(f"{'loop closure max px':22s}" + "".join(
            f"{np.nanmax(loops[m]) if np.isfinite(loops[m]).any() else np.nan:16.3f}"
            for m in methods))
        print(f"{'loops closed (of ' + str(len(triplets())) + ')':22s}" + "".join(
            f"{int(np.isfinite(loops[m]).sum()):16d}" for m in methods))
    # Cases some peer solved and astroalign_nd did not.
    if "astroalign_nd" in methods:
        names = sorted({(r[0], r[1]) for r in rows})
        lost = []
        for kind, nm in names:
            v = {r[2]: r for r in rows if r[0] == kind and r[1] == nm}
            if v["astroalign_nd"][7] != "ok" and any(
                    v[m][7] == "ok" for m in methods if m != "astroalign_nd"):
                lost.append((kind, nm, v["astroalign_nd"][7], v["astroalign_nd"][6]))
        print(f"\nCases a peer solves and astroalign_nd does not: {len(lost)}")
        for kind, nm, verdict, note in lost:
            print(f"  {kind:5s} {nm:42s} {verdict:8s} {note}")
        bad = [r for r in rows if r[7] == "WRONG"]
        print(f"\nWrong answers: {len(bad)}")
        for r in bad:
            print(f"  {r[0]:5s} {r[1]:42s} {r[2]:14s} err={r[4]:.2f} {r[6]}")


if __name__ == "__main__":
    main()
