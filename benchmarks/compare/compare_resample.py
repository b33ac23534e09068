"""
Bit-for-bit check of a change to the resampler: the arrays it returns on fixed inputs.

Resamples fixed random images (float32 and float64, 2-D and 3-channel)
through three affine matrices (a rotation with scale, a shift, a shear), with
every order, with no variance, a variance, a standard deviation (in the data's
type and in float64), an inverse variance, with and without a mask, and with
and without ``conserve_flux``, and a 2600x2600 float32 frame (several bands
of output rows) with a mask and a variance or standard deviation; saves
every data, variance and mask array to
an ``.npz`` file.  It also resamples through a projective matrix and a
polynomial model (the coordinate-map path), through the NumPy fallback
kernels, and through `~astroalign_nd.apply_transform` (CCDData with each
uncertainty class, a mask, flags and a WCS: its data, mask, uncertainty,
flags, header and WCS cards).  Run it on the tree before a change and on the tree after;
``--compare`` reports every array that differs (exact equality, NaN equal to
NaN).

Usage::

    PYTHONPATH=/old/tree python benchmarks/compare/compare_resample.py --out before.npz
    PYTHONPATH=. python benchmarks/compare/compare_resample.py --out after.npz
    python benchmarks/compare/compare_resample.py --compare before.npz after.npz
"""

import re

import numpy as np

from _command import run_command


def _cases():
    rng = np.random.default_rng(5)
    data = rng.normal(100, 10, (300, 280))
    std = rng.uniform(1, 3, data.shape)
    bad = rng.random(data.shape) < 0.01
    th = np.deg2rad(33.0)
    mats = [
        np.array([[1.1 * np.cos(th), -1.1 * np.sin(th), 160.0],
                  [1.1 * np.sin(th), 1.1 * np.cos(th), -20.0], [0, 0, 1]]),
        np.array([[1.0, 0, 2.5], [0, 1, -3.0], [0, 0, 1]]),
        np.array([[0.97, 0.02, 3.3], [-0.01, 1.02, 1.1], [0, 0, 1]]),
    ]
    for dt in (np.float32, np.float64):
        d, s = data.astype(dt), std.astype(dt)
        rgb = np.stack([d, d * 2, d + 1], -1)
        for mi, m in enumerate(mats):
            for order in range(4):
                for kind, var in (("none", None), ("variance", s * s), ("stddev", s),
                                  ("inverse", 1 / (s * s)), ("stddev64", std)):
                    for mk in (None, bad):
                        for cf in (False, True):
                            k = {"none": "variance", "stddev64": "stddev"}.get(kind, kind)
                            key = f"{dt.__name__}_{mi}_{order}_{kind}_{mk is not None}_{cf}"
                            yield key, (d, m, order), dict(variance=var, mask=mk,
                                                           conserve_flux=cf, _variance_kind=k)
                key = f"rgb_{dt.__name__}_{mi}_{order}"
                yield key, (rgb, m, order), dict(variance=s * s, mask=bad)
    # A frame large enough for several bands of output rows (the banded
    # working planes, before the kernel read the mask and standard deviation).
    big = rng.normal(100, 10, (2600, 2600)).astype(np.float32)
    big_std = rng.uniform(1, 3, big.shape).astype(np.float32)
    big_bad = rng.random(big.shape) < 0.001
    for order in (1, 3):
        for kind, var in (("variance", big_std * big_std), ("stddev", big_std)):
            yield f"large_{order}_{kind}", (big, mats[0], order), dict(
                variance=var, mask=big_bad, _variance_kind=kind, shape_out=(2500, 2700))


def _map_cases():
    """Non-linear transforms (the coordinate-map path), and the NumPy kernels."""
    from astroalign_nd import PolynomialTransform

    rng = np.random.default_rng(6)
    data = rng.normal(100, 10, (200, 190))
    std = rng.uniform(1, 3, data.shape)
    bad = rng.random(data.shape) < 0.01
    h = np.array([[1.01, 0.03, 2.0], [-0.02, 0.99, -1.5], [2e-5, -1e-5, 1.0]])
    poly = PolynomialTransform(degree=3, crpix=(95.0, 95.0), translation_x=97.0,
                               translation_y=94.0, a11=1.01, a12=0.02, a21=-0.02,
                               a22=1.01, A_3_0=4e-7, A_1_2=4e-7, B_2_1=4e-7, B_0_3=4e-7)
    for dt in (np.float32, np.float64):
        d, s = data.astype(dt), std.astype(dt)
        for name, tf in (("proj", h), ("poly", poly), ("affine", h * [[1], [1], [0]] + [
                [0, 0, 0], [0, 0, 0], [0, 0, 1]])):
            for order in range(4):
                for kind, var in (("variance", s * s), ("stddev", s), ("inverse", 1 / (s * s)),
                                  ("stddev64", std)):
                    k = {"stddev64": "stddev"}.get(kind, kind)
                    for cf in (False, True):
                        key = f"map_{name}_{dt.__name__}_{order}_{kind}_{cf}"
                        yield key, (d, tf, order), dict(variance=var, mask=bad,
                                                        conserve_flux=cf, _variance_kind=k,
                                                        _output_kind=k, shape_out=(180, 200))


def _ccd_cases():
    """`apply_transform` on CCDData with each uncertainty class, flags and a WCS."""
    from astropy.nddata import (CCDData, InverseVariance, StdDevUncertainty,
                                VarianceUncertainty)
    from astropy.wcs import WCS

    rng = np.random.default_rng(7)
    data = rng.normal(100, 10, (150, 160)).astype(np.float32)
    std = rng.uniform(1, 3, data.shape).astype(np.float32)
    bad = rng.random(data.shape) < 0.01
    flags = rng.integers(0, 4, data.shape).astype(np.int16)
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval, w.wcs.crpix, w.wcs.cdelt = [10.0, 20.0], [80.0, 75.0], [-1e-4, 1e-4]
    th = np.deg2rad(12.0)
    mat = np.array([[np.cos(th), -np.sin(th), 15.0], [np.sin(th), np.cos(th), -8.0], [0, 0, 1]])
    proj = mat + [[0, 0, 0], [0, 0, 0], [1e-5, -2e-5, 0]]
    for ui, unc in enumerate((None, StdDevUncertainty(std), VarianceUncertainty(std * std),
                              InverseVariance(1 / (std * std)))):
        ccd = CCDData(data, unit="electron", uncertainty=unc, mask=bad, flags=flags, wcs=w,
                      meta={"OBJECT": "field", "EXPTIME": 30.0})
        for ti, tf in enumerate((mat, proj)):
            for method in ("interpolate", "exact"):
                if method == "exact" and (ti or ui > 1):
                    continue  # (reproject is slow)
                for order in ("bilinear", 3):
                    yield f"ccd_{ui}_{ti}_{method}_{order}", (tf, ccd, (140, 170)), dict(
                        method=method, order=order, conserve_flux=bool(ui % 2))
    rgb = np.stack([data, data * 2, data + 1], -1)
    yield "ccd_rgb", (mat, CCDData(rgb, unit="adu", uncertainty=StdDevUncertainty(std)),
                      (140, 170)), dict(order="biquadratic")


def _use_compiled(rs, compiled):
    """Turn the compiled kernels on or off: ``conf.use_compiled``, and on older trees the
    resampler's own switch (``_USE_COMPILED``, in ``resample`` or ``resample.core``)."""
    from astroalign_nd import conf

    conf.use_compiled = compiled
    module = getattr(rs, "core", rs)
    if hasattr(module, "_USE_COMPILED"):
        module._USE_COMPILED = compiled


def run(out):
    import astroalign_nd.resample as rs
    from astroalign_nd.resample import apply_transform
    from astroalign_nd.resample import resample

    res = {}
    cases = list(_cases()) + list(_map_cases())
    numpy_cases = [(k, a, kw) for k, a, kw in cases
                   if k.startswith("map_") or k.startswith("float64_2_")]
    for compiled, group in ((True, cases), (False, numpy_cases)):
        _use_compiled(rs, compiled)
        for key, (d, m, order), kw in group:
            kw = dict(kw)
            o = resample(d, m, kw.pop("shape_out", (290, 310)), order=order, **kw)
            key = key if compiled else "numpy_" + key
            res[key + "_d"], res[key + "_m"] = o[0], o[2]
            if o[1] is not None:
                res[key + "_v"] = o[1]
    _use_compiled(rs, True)
    for key, (tf, ccd, target), kw in _ccd_cases():
        o = apply_transform(tf, ccd, target, **kw)
        res[key + "_d"], res[key + "_m"] = o.data, o.mask
        if o.uncertainty is not None:
            res[key + "_u"] = o.uncertainty.array
            res[key + "_ut"] = np.array(type(o.uncertainty).__name__ + str(o.uncertainty.unit))
        if o.flags is not None:
            res[key + "_f"] = o.flags
        # (Without the HISTORY line's version and time stamp.)
        res[key + "_h"] = np.array(re.sub(r"astroalign_nd \S+ \S+ UTC", "astroalign_nd",
                                          repr(o.header)))
        res[key + "_w"] = np.array("" if o.wcs is None else o.wcs.to_header_string())
        res[key + "_unit"] = np.array(str(o.unit))
    np.savez(out, **res)
    print(f"{len(res)} arrays written to {out}")


def compare(a, b):
    ra, rb = np.load(a), np.load(b)
    keys = sorted(set(ra.files) | set(rb.files))
    ndiff = 0
    for k in keys:
        if k not in ra.files or k not in rb.files:
            ndiff += 1
            print(f"{k}: only in {'after' if k not in ra.files else 'before'}")
        elif not np.array_equal(ra[k], rb[k], equal_nan=ra[k].dtype.kind in "fc"):
            ndiff += 1
            if ra[k].dtype.kind == "U":
                print(f"{k}: differs")
                continue
            x, y = ra[k].astype(float), rb[k].astype(float)
            with np.errstate(invalid="ignore", divide="ignore"):
                rel = np.nanmax(np.abs(x - y) / np.maximum(np.abs(x), 1e-300))
            print(f"{k}: differs in {np.sum(~((x == y) | (np.isnan(x) & np.isnan(y))))} of "
                  f"{x.size} elements (max relative difference {rel:.3g})")
    print(f"{len(keys)} arrays compared, {ndiff} different")
    return ndiff


def main(argv=None):
    return run_command(argv, __doc__, run, compare)


if __name__ == "__main__":
    raise SystemExit(main())
