"""
Colour frames from the camera: Bayer drizzle against demosaic-then-stack.

The 12 raw GRBG subs of M94 from a Seestar S50 in
``../shared/data/seestar_raw`` (1080 x 1920, 2.39"/px, undersampled;
skipped with a message when absent), stacked two ways by
``astroalign_nd.stack`` in one run, both registered on the frames' grey
2x2-superpixel versions with the same transforms:

* demosaic-then-stack: ``stack(files, bayer='auto', demosaic=...)`` (each
  frame demosaiced by colour-demosaicing, 'bilinear' and 'Menon2007' by
  default, each colour resampled and combined with sigma clipping), then
  each plane up-sampled x2 by a cubic spline onto the drizzle's output grid
  (``scipy.ndimage.map_coordinates``, order 3);
* Bayer drizzle: ``stack(files, bayer='auto', drizzle=2, pixfrac=...)``.

On the same stars (found on the drizzled green plane: isolated, unsaturated,
far from the edges), a circular 2-D Gaussian is fitted in every plane of both
stacks (photutils' ``fit_2dgaussian``, after a ``Background2D`` sky): the
median FWHM in arcsec per colour, and each star's R-G and B-G centroid
offsets, in input pixels, in both stacks and their per-star difference.
Menon2007 (like Malvar2004) builds red and blue from green's detail: their
stars take green's width and position, so the atmospheric dispersion of
the frames (about 0.15 px) disappears from its colour offsets; bilinear
keeps each colour's own.

A star's colour offset is noisy (its blue has the fewest photons), so the
per-star agreement of the two stacks is set against what their noise alone
gives (``--halves``): the even and the odd frames are stacked apart by each
path, each star's drizzle-minus-demosaic offset measured in both halves, and
half the spread of its change between the halves is the spread that noise
alone gives the full stack's per-star differences (they are independent
frames); the correlation of the two halves' differences says whether a
star's difference is its own (a systematic) or noise.

Each star's difference is also set against its own predicted noise: the
four fits' position errors (``x_err``, ``y_err``), whose scale ``--halves``
checks (the spread of a star's change between the halves over the error
predicted for it: 1 if they are right) and, per colour, corrects; printed are
the fraction within 0.1 px of the stars whose predicted noise is at most
0.033 px (noise alone puts 99.7 % of them there) and at most 0.05 px, the
chi-square per star and the weighted mean difference in its sd over all the
stars (a colour fringe of either path shows as chi2/N >> 1 or a mean of many
sd), and the difference by the star's raw pixel phase (modulo the 2 px
period of the red and blue pixels).  ``--save`` writes the fits.

``--simulate`` measures both paths instead on simulated raw GRBG frames with a
known truth, made like the real ones: the real frames' transforms (their drift
and field rotation, found on them; then the same shifts without rotation),
their sky and noise per colour, their stars' widths per colour (2.35 raw px in
green, 2.5 in blue, 3.5 in red: the drizzled widths come out as the real
ones), blue 0.6 and red 0.78 of green's flux, and a dispersion along the
frames' x (red 0.15 raw px left of green, blue 0.2 right).

Usage::

    python benchmarks/bench_bayer.py [--pixfrac 1.0] [--frames 12] [--demosaic bilinear]
                                     [--halves] [--save FITS.npz] [--simulate]

(``--simulate --halves`` also checks the halves' noise estimate against the
simulated frames' error from the truth.)
"""

import argparse
import glob
import os
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "shared", "data", "seestar_raw")
SCALE = 2


def _upsample(plane, scale):
    """A plane on the drizzle's output grid by a cubic spline (reference ``c`` at
    ``scale * (c + 0.5) - 0.5``)."""
    from scipy import ndimage

    ny, nx = plane.shape
    yy, xx = np.mgrid[0:ny * scale, 0:nx * scale].astype(float)
    filled = np.where(np.isfinite(plane), plane, np.nanmedian(plane))
    return ndimage.map_coordinates(filled, [(yy + 0.5) / scale - 0.5, (xx + 0.5) / scale - 0.5],
                                   order=3, mode="nearest")


def _sky_subtracted(plane):
    from astropy.stats import SigmaClip
    from photutils.background import Background2D, MedianBackground

    bkg = Background2D(np.where(np.isfinite(plane), plane, np.nanmedian(plane)), 128,
                       filter_size=3, sigma_clip=SigmaClip(3.0),
                       bkg_estimator=MedianBackground())
    return plane - bkg.background, bkg.background_rms_median


def _stars(green, saturated, n_max=400):
    """Isolated, unsaturated stars of a plane, far from its edges."""
    from photutils.detection import DAOStarFinder

    data, rms = _sky_subtracted(green)
    found = DAOStarFinder(threshold=15 * rms, fwhm=4.0, exclude_border=True)(
        np.nan_to_num(data))
    x, y, peak = (np.asarray(found[c], float) for c in ("x_centroid", "y_centroid", "peak"))
    ny, nx = green.shape
    d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    np.fill_diagonal(d, np.inf)
    ok = (d.min(axis=1) > 16) & (x > 40) & (x < nx - 40) & (y > 40) & (y < ny - 40)
    ok &= ~saturated[np.round(y).astype(int), np.round(x).astype(int)]
    order = np.argsort(-peak[ok])[:n_max]
    return np.column_stack([x[ok][order], y[ok][order]])


def _fit(plane, xy):
    """(x, y, fwhm, x_err, y_err) of a circular Gaussian fitted at each position (NaN where
    it failed); the errors are the fit's, from its covariance scaled by its residuals."""
    from photutils.psf import fit_2dgaussian

    data, _ = _sky_subtracted(plane)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fit_2dgaussian(np.nan_to_num(data), xypos=xy, fwhm=4.0, fix_fwhm=False,
                             fit_shape=(11, 11), mask=~np.isfinite(data)).results
    out = np.column_stack([res[c] for c in ("x_fit", "y_fit", "fwhm_fit", "x_err", "y_err")]
                          ).astype(float)
    bad = (res["flags"] != 0) | ~np.isfinite(out).all(axis=1)
    out[np.asarray(bad)] = np.nan
    return out


def _saturated(files):
    """The output pixels near a star that reaches the raw saturation in the reference."""
    from astropy.io import fits
    from scipy import ndimage

    raw = fits.getdata(files[0]).astype(float)
    sat = ndimage.binary_dilation(raw >= 0.95 * raw.max(), np.ones((7, 7), bool))
    return np.kron(sat, np.ones((SCALE, SCALE), bool))


def _offset(fits_, c, axis, good):
    """Each good star's offset of colour ``c`` from green along ``axis``, in input pixels."""
    return (fits_[c][good, axis] - fits_[1][good, axis]) / SCALE


def _on_half(xy, files, k):
    """Output positions ``xy`` of a stack on ``files[0]`` seen on a stack on ``files[k]``."""
    if k == 0:
        return xy
    from astroalign_nd.stacking.colour import find_bayer_transform
    from astroalign_nd.transforms import as_matrix

    m = np.asarray(as_matrix(find_bayer_transform(files[0], files[k])), float)  # raw -> raw
    raw = (xy + 0.5) / SCALE - 0.5
    x = m[0, 0] * raw[:, 0] + m[0, 1] * raw[:, 1] + m[0, 2]
    y = m[1, 0] * raw[:, 0] + m[1, 1] * raw[:, 1] + m[1, 2]
    return np.column_stack([SCALE * (x + 0.5) - 0.5, SCALE * (y + 0.5) - 0.5])


def _noise_lines(fits_, halves, good):
    """Per-star drizzle - demosaic offsets against the spread noise alone gives them."""
    from scipy.special import erf

    print(f"{'drizzle - demosaic, per star':30s}{'median':>9s}{'sd':>7s}{'<=0.1':>7s}"
          f"{'| noise sd':>11s}{'<=0.1':>7s}{'corr(halves)':>14s}{'noise drz, dem':>16s}")
    for c, colour in ((0, "R"), (2, "B")):
        for axis, name in ((0, "x"), (1, "y")):
            d = (_offset(fits_["drizzle"], c, axis, good)
                 - _offset(fits_["demosaic"], c, axis, good))
            line = (f"{colour + '-G ' + name:30s}{np.median(d):+9.3f}{np.std(d):7.3f}"
                    f"{np.mean(np.abs(d) <= 0.1):7.0%}")
            if halves is not None:
                dh = [_offset(h["drizzle"], c, axis, good) - _offset(h["demosaic"], c, axis, good)
                      for h in halves]
                # Independent halves: the full stack's per-star noise is half their change.
                sd = np.std(dh[0] - dh[1]) / 2
                line += (f"{sd:11.3f}{erf(0.1 / (sd * np.sqrt(2))):7.0%}"
                         f"{np.corrcoef(dh[0], dh[1])[0, 1]:+14.2f}")
                # Each path's own per-star noise of the offset (full stack), alike.
                own = [np.std(_offset(halves[0][n], c, axis, good)
                              - _offset(halves[1][n], c, axis, good)) / 2
                       for n in ("drizzle", "demosaic")]
                line += f"{own[0]:10.3f},{own[1]:6.3f}"
            print(line)


def _offset_err(fits_, c, axis, good):
    """Each good star's fit error of its colour offset (colour and green independent)."""
    return np.hypot(fits_[c][good, 3 + axis], fits_[1][good, 3 + axis]) / SCALE


def _diff_err(fits_, c, axis, good):
    """A star's drizzle - demosaic offset and its predicted noise from the four fits'
    errors (taken as independent: the two stacks share their photons, which the halves'
    check of the scale below measures)."""
    d = (_offset(fits_["drizzle"], c, axis, good)
         - _offset(fits_["demosaic"], c, axis, good))
    return d, np.hypot(_offset_err(fits_["drizzle"], c, axis, good),
                       _offset_err(fits_["demosaic"], c, axis, good))


#: Predicted noise at which noise alone puts 99.7 % of the stars within 0.1 px (3 sigma).
BRIGHT_ERR = 0.1 / 3


def _agreement(d, e, label):
    """One line: the stars of predicted noise ``e`` at most `BRIGHT_ERR` (and 0.05 px)
    within 0.1 px, against what noise alone gives them; chi2/N and the weighted mean of
    all the stars' differences ``d``."""
    from scipy.special import erf

    line = f"  {label}:"
    for cut in (BRIGHT_ERR, 0.05):
        sel = e <= cut
        line += (f" err<={cut:.3f}: {int(sel.sum()):2d} stars, "
                 + (f"{np.mean(np.abs(d[sel]) <= 0.1):4.0%} within 0.1 (noise "
                    f"{np.mean(erf(0.1 / (e[sel] * np.sqrt(2)))):4.0%});" if sel.any()
                    else "     -                   ;"))
    w = 1 / e ** 2
    mean = np.sum(w * d) / np.sum(w)
    print(line + f" all {d.size}: chi2/N {np.mean((d / e) ** 2):.2f}, weighted mean "
          f"{mean:+.3f} px = {mean * np.sqrt(np.sum(w)):+.1f} sd")


def _phase_lines(fits_, good, scales):
    """
    The difference's weighted mean, and each path's median offset, by the star's pixel
    phase along the axis in the raw frame (its green x or y in raw pixels, modulo the 2 px
    period of the red and blue pixels): an undersampled colour interpolated or dropped
    with a bias that depends on where the star falls between that colour's pixels
    averages out over the field, not per star.
    """
    print("  by the star's raw pixel phase (modulo 2 px): drizzle - demosaic (weighted mean "
          "+- its error, errors times the scale above) [drizzle, demosaic medians]")
    for c, colour in ((0, "R"), (2, "B")):
        for axis, name in ((0, "x"), (1, "y")):
            d, e = _diff_err(fits_, c, axis, good)
            e = scales.get(c, 1.0) * e
            phase = ((fits_["drizzle"][1][good, axis] + 0.5) / SCALE - 0.5) % 2
            line = f"    {colour}-G {name}:"
            for lo in (0.0, 0.5, 1.0, 1.5):
                sel = (phase >= lo) & (phase < lo + 0.5)
                if not sel.any():
                    continue
                w = 1 / e[sel] ** 2
                meds = [np.median(_offset(fits_[n], c, axis, good)[sel])
                        for n in ("drizzle", "demosaic")]
                line += (f" {lo:.1f}-{lo + 0.5:.1f} ({int(sel.sum())}): "
                         f"{np.sum(w * d[sel]) / np.sum(w):+.3f}+-{1 / np.sqrt(np.sum(w)):.3f}"
                         f" [{meds[0]:+.2f},{meds[1]:+.2f}];")
            print(line)


def _err_lines(fits_, halves, good, in_halves):
    """
    Per-star drizzle - demosaic offsets against each star's own predicted noise: the
    four fits' errors, in scale as they come, then (with ``halves``) times the scale that
    the halves measure per colour.

    The fits' errors (covariance scaled by the residuals) take the pixels' noise as
    independent; in both stacks it is not (drizzle drops and the up-sampling spread
    each input pixel over several output pixels), which makes them too small, and the
    two stacks share their photons, which makes the sum of their errors too large.
    Between two independent halves of the frames a star's difference changes by noise
    alone (a systematic cancels): its spread over the error predicted for it is that
    scale.
    """
    print(f"per star against its predicted noise (fit errors; {int(good.sum())} stars, "
          f"{int(in_halves.sum())} in the halves)"
          + (": sd of the halves' change / its predicted error, for the difference and "
             "for each path's offset (drizzle, demosaic)" if halves is not None else ""))
    scales = {}
    for c, colour in ((0, "R"), (2, "B")):
        for axis, name in ((0, "x"), (1, "y")):
            _agreement(*_diff_err(fits_, c, axis, good), f"{colour}-G {name}")
            if halves is None:
                continue
            dh, eh = zip(*(_diff_err(h, c, axis, in_halves) for h in halves))
            k = np.std((dh[0] - dh[1]) / np.hypot(*eh))
            own = [np.std((_offset(halves[0][n], c, axis, in_halves)
                           - _offset(halves[1][n], c, axis, in_halves))
                          / np.hypot(_offset_err(halves[0][n], c, axis, in_halves),
                                     _offset_err(halves[1][n], c, axis, in_halves)))
                   for n in ("drizzle", "demosaic")]
            scales.setdefault(c, []).append(k)
            print(f"    halves: {k:.2f}; {own[0]:.2f}, {own[1]:.2f}")
    scales = {c: float(np.sqrt(np.mean(np.square(k)))) for c, k in scales.items()}
    if scales:
        print("  the errors times the halves' scale for the difference (per colour, x and y "
              "pooled):")
        for c, colour in ((0, "R"), (2, "B")):
            for axis, name in ((0, "x"), (1, "y")):
                d, e = _diff_err(fits_, c, axis, good)
                _agreement(d, scales[c] * e, f"{colour}-G {name} (x{scales[c]:.2f})")
    _phase_lines(fits_, good, scales)


def _table(fits_, method, t_dem, arcsec, halves=None):
    """The FWHM and colour-offset table of one demosaicing method against the drizzle."""
    good = np.all([np.isfinite(f[:, 2]) for fs in fits_.values() for f in fs], axis=0)
    in_halves = good.copy()  # the stars also fitted in both halves: the noise lines'
    for h in halves or ():
        in_halves &= np.all([np.isfinite(f[:, 2]) for fs in h.values() for f in fs], axis=0)
    print()
    print(f"demosaic ({method}) then stack, up-sampled x{SCALE}: {t_dem:.0f} s; "
          f"{int(good.sum())} stars fitted in every plane of both")
    print(f"{'':30s}{'demosaic+stack':>16s}{'Bayer drizzle':>16s}{'ratio':>8s}")
    for c, colour in enumerate("RGB"):
        a, b = (np.median(fits_[n][c][good, 2]) * arcsec / SCALE
                for n in ("demosaic", "drizzle"))
        print(f"{'median FWHM ' + colour + ' (arcsec)':30s}{a:16.2f}{b:16.2f}{b / a:8.3f}")
    print(f"{'colour offset (input px)':30s}{'demosaic+stack':>16s}{'Bayer drizzle':>16s}"
          f"{'|diff| med':>12s}{'p90':>8s}{'<=0.1':>8s}")
    for c, colour in ((0, "R"), (2, "B")):
        for axis, name in ((0, "x"), (1, "y")):
            off = {n: (fits_[n][c][good, axis] - fits_[n][1][good, axis]) / SCALE
                   for n in fits_}
            diff = np.abs(off["drizzle"] - off["demosaic"])
            print(f"{colour + '-G ' + name + ' (median over stars)':30s}"
                  f"{np.median(off['demosaic']):16.3f}{np.median(off['drizzle']):16.3f}"
                  f"{np.median(diff):12.3f}{np.percentile(diff, 90):8.3f}"
                  f"{np.mean(diff <= 0.1):8.0%}")
    if halves is not None:
        print(f"per star, on the {int(in_halves.sum())} stars also fitted in both halves "
              "(even, odd frames); noise: the spread noise alone gives")
    _noise_lines(fits_, halves, in_halves)
    _err_lines(fits_, halves, good, in_halves)


#: Simulated frames: sky and its noise (R, G, B; ADU, as the real frames'), e-/ADU of the
#: stars' photon noise, stars' FWHM (raw px), flux and x offset relative to green's.
SIM_SKY, SIM_NOISE, SIM_GAIN = (842.0, 995.0, 794.0), (77.0, 90.0, 71.0), 0.1
SIM_FWHM, SIM_FLUX, SIM_DX = (3.5, 2.35, 2.5), (0.78, 1.0, 0.6), (-0.15, 0.0, 0.2)


def _render(shape, x, y, flux, fwhm):
    """Pixel-integrated circular Gaussians."""
    from scipy.special import erf

    img = np.zeros(shape)
    s = fwhm / 2.3548
    h = int(np.ceil(4 * s)) + 2
    for xi, yi, fi in zip(x, y, flux):
        ix, iy = int(round(xi)), int(round(yi))
        x0, x1 = max(ix - h, 0), min(ix + h + 1, shape[1])
        y0, y1 = max(iy - h, 0), min(iy + h + 1, shape[0])
        if x0 < x1 and y0 < y1:
            px = np.diff(0.5 * erf((np.arange(x0, x1 + 1) - 0.5 - xi) / (np.sqrt(2) * s)))
            py = np.diff(0.5 * erf((np.arange(y0, y1 + 1) - 0.5 - yi) / (np.sqrt(2) * s)))
            img[y0:y1, x0:x1] += fi * py[:, None] * px[None, :]
    return img


def _simulated(matrices, shape, seed=37):
    """Raw GRBG frames of one field seen through ``matrices`` (frame -> reference) and
    its stars' true reference positions."""
    from astroalign_nd.simulate import bayer_mosaic

    rng = np.random.default_rng(seed)
    pts = []
    while len(pts) < 600:  # isolated stars, 25 px apart at least
        p = rng.uniform([60, 60], [shape[1] - 60, shape[0] - 60])
        if not pts or np.min(np.hypot(*(np.array(pts) - p).T)) > 25:
            pts.append(p)
    x, y = np.array(pts).T
    flux = np.exp(rng.uniform(np.log(3e3), np.log(8e4), x.size))
    frames = []
    for m in matrices:
        inv = np.linalg.inv(m)
        fx = inv[0, 0] * x + inv[0, 1] * y + inv[0, 2]
        fy = inv[1, 0] * x + inv[1, 1] * y + inv[1, 2]
        planes = []
        for c in range(3):
            star = _render(shape, fx + SIM_DX[c], fy, flux * SIM_FLUX[c], SIM_FWHM[c])
            sd = np.sqrt(SIM_NOISE[c] ** 2 + star / SIM_GAIN)
            planes.append(SIM_SKY[c] + star + sd * rng.normal(size=shape))
        frames.append(bayer_mosaic(np.stack(planes), "GRBG"))
    return frames, np.column_stack([x, y])


def _both_paths(frames, pixfrac):
    """The Bayer drizzle and the bilinear demosaic-then-stack (up-sampled) of ``frames``."""
    from astroalign_nd import stack

    drz = stack(frames, bayer="auto", drizzle=SCALE, pixfrac=pixfrac)
    dem = stack(frames, bayer="auto", demosaic="bilinear")
    dem = np.stack([_upsample(np.where(dem.mask[c], np.nan, dem.data[c]), SCALE)
                    for c in range(3)])
    return np.where(drz.mask, np.nan, drz.data), dem


def _check_halves(raws, matrices, xy, fits_, good, pixfrac):
    """On simulated frames: the halves' noise estimate against the error from the truth."""
    inv = np.linalg.inv(matrices[1])  # reference raw -> the odd half's reference raw
    raw = (xy + 0.5) / SCALE - 0.5
    odd = np.column_stack([inv[0, 0] * raw[:, 0] + inv[0, 1] * raw[:, 1] + inv[0, 2],
                           inv[1, 0] * raw[:, 0] + inv[1, 1] * raw[:, 1] + inv[1, 2]])
    halves = []
    for part, pos in ((raws[0::2], xy), (raws[1::2], SCALE * (odd + 0.5) - 0.5)):
        cubes = _both_paths(part, pixfrac)
        halves.append({n: [_fit(cube[c], pos) for c in range(3)]
                       for n, cube in zip(("drizzle", "demosaic"), cubes)})
    for h in halves:
        good = good & np.all([np.isfinite(f[:, 2]) for fs in h.values() for f in fs], axis=0)
    print(f"  the halves' noise (--halves) against the error from the truth, {int(good.sum())} "
          "stars, per-star sd in input px:")
    for c in (0, 2):
        truth = SIM_DX[c] - SIM_DX[1]
        line = f"    {'RGB'[c]}-G x"
        for n in ("drizzle", "demosaic"):
            err = np.std(_offset(fits_[n], c, 0, good) - truth)
            est = np.std(_offset(halves[0][n], c, 0, good) - _offset(halves[1][n], c, 0, good))
            line += f"; {n} error {err:.3f}, halves {est / 2:.3f}"
        d = [_offset(f["drizzle"], c, 0, good) - _offset(f["demosaic"], c, 0, good)
             for f in (fits_, *halves)]
        print(line + f"; drizzle - demosaic {np.std(d[0]):.3f}, halves "
              f"{np.std(d[1] - d[2]) / 2:.3f}")


def _simulate(files, pixfrac, halves=False):
    """Both paths on simulated frames with the real frames' transforms: against the truth
    (and the halves' noise estimate against the error from the truth)."""
    from astropy.io import fits

    from astroalign_nd.stacking.colour import find_bayer_transform
    from astroalign_nd.transforms import as_matrix

    shape = fits.getdata(files[0]).shape
    real = [np.eye(3)] + [np.asarray(as_matrix(find_bayer_transform(f, files[0])), float)
                          for f in files[1:]]
    rot = max(abs(np.degrees(np.arctan2(m[1, 0], m[0, 0]))) for m in real)
    shifted = [np.array([[1, 0, m[0, 2]], [0, 1, m[1, 2]], [0, 0, 1.0]]) for m in real]
    print(f"simulated raw GRBG frames {shape[1]} x {shape[0]}, 600 stars, the real frames' "
          f"{len(files)} transforms (field rotation up to {rot:.3f} deg); truth R-G x "
          f"{SIM_DX[0] - SIM_DX[1]:+.3f}, B-G x {SIM_DX[2] - SIM_DX[1]:+.3f} (frame x)")
    for label, matrices in (("real transforms", real), ("shifts only", shifted)):
        raws, truth = _simulated(matrices, shape)
        drz, dem = _both_paths(raws, pixfrac)
        xy = _stars(drz[1], np.zeros(drz[1].shape, bool), n_max=1000)
        out = SCALE * (truth + 0.5) - 0.5
        d = np.hypot(xy[:, :1] - out[None, :, 0], xy[:, 1:] - out[None, :, 1])
        near = d.argmin(axis=1)
        keep = d[np.arange(len(xy)), near] < 1.5
        xy, out = xy[keep], out[near[keep]]
        fits_ = {n: [_fit(cube[c], xy) for c in range(3)] for n, cube in
                 (("drizzle", drz), ("demosaic", dem))}
        good = np.all([np.isfinite(f[:, 2]) for fs in fits_.values() for f in fs], axis=0)
        print(f"{label}: {int(good.sum())} stars; median (mean +- its error) in input px")
        for n in ("drizzle", "demosaic"):
            g = (fits_[n][1][good, 0] - out[good, 0]) / SCALE
            line = f"  {n:9s} G x - truth {np.median(g):+.3f}"
            for c in (0, 2):
                o = _offset(fits_[n], c, 0, good)
                line += (f"; {'RGB'[c]}-G x {np.median(o):+.3f} ({o.mean():+.3f} +- "
                         f"{o.std() / np.sqrt(o.size):.3f})")
            fw = ", ".join(f"{np.median(fits_[n][c][good, 2]):.2f}" for c in range(3))
            print(line + f"; FWHM R, G, B {fw} output px")
        phase = ((out[good, 0] + 0.5) / SCALE - 0.5) % 2  # the true raw x, modulo 2 px
        for c in (0, 2):
            line = f"  {'RGB'[c]}-G x - truth by the raw pixel phase (modulo 2 px; drizzle, " \
                   "demosaic medians):"
            for lo in (0.0, 0.5, 1.0, 1.5):
                sel = (phase >= lo) & (phase < lo + 0.5)
                err = [np.median(_offset(fits_[n], c, 0, good)[sel]) - (SIM_DX[c] - SIM_DX[1])
                       for n in ("drizzle", "demosaic")]
                line += (f" {lo:.1f}-{lo + 0.5:.1f} ({int(sel.sum())}): "
                         f"{err[0]:+.3f}, {err[1]:+.3f};")
            print(line)
        for c in (0, 2):
            dd = _offset(fits_["drizzle"], c, 0, good) - _offset(fits_["demosaic"], c, 0, good)
            print(f"  drizzle - demosaic {'RGB'[c]}-G x per star: median {np.median(dd):+.3f}, "
                  f"sd {dd.std():.3f}, {np.mean(np.abs(dd) <= 0.1):.0%} <= 0.1")
        if halves and matrices is real:
            _check_halves(raws, matrices, xy, fits_, good, pixfrac)
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pixfrac", type=float, default=1.0)
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--demosaic", nargs="+", default=["bilinear", "Menon2007"],
                    help="demosaicing methods compared (default: bilinear Menon2007)")
    ap.add_argument("--halves", action="store_true",
                    help="also stack the even and the odd frames apart: the per-star "
                         "agreement that noise alone gives")
    ap.add_argument("--save", metavar="NPZ", default=None,
                    help="also write each star's fits (x, y, fwhm, x_err, y_err per plane, "
                         "stack and half) to this .npz, for a closer look")
    ap.add_argument("--simulate", action="store_true",
                    help="measure both paths on simulated frames made like the real ones "
                         "(their transforms, sky, noise, star widths) with a known truth")
    args = ap.parse_args(argv)
    files = sorted(glob.glob(os.path.join(DATA, "*.fit*")))[:args.frames]
    if not files:
        print(f"bench_bayer: the raw Seestar frames are absent ({os.path.normpath(DATA)}); "
              "nothing measured.")
        return 0
    warnings.filterwarnings("ignore")
    if args.simulate:
        return _simulate(files, args.pixfrac, args.halves)
    from astropy.io import fits

    from astroalign_nd import stack

    h = fits.getheader(files[0])
    arcsec = 206264.806 * h["XPIXSZ"] * 1e-3 / h["FOCALLEN"]  # per input pixel
    t0 = time.perf_counter()
    drz = stack(files, bayer="auto", drizzle=SCALE, pixfrac=args.pixfrac)
    t_drz = time.perf_counter() - t0
    drz_data = np.where(drz.mask, np.nan, drz.data)
    xy = _stars(drz_data[1], _saturated(files))
    fit_drz = [_fit(drz_data[c], xy) for c in range(3)]
    halves, parts, xy_half = None, [], []
    if args.halves:  # each half on its first frame's grid, the stars moved there
        parts = [files[k::2] for k in (0, 1)]
        xy_half = [_on_half(xy, files, k) for k in (0, 1)]
        halves = []
        for part, pos in zip(parts, xy_half):
            d = stack(part, bayer="auto", drizzle=SCALE, pixfrac=args.pixfrac)
            d = np.where(d.mask, np.nan, d.data)
            halves.append({"drizzle": [_fit(d[c], pos) for c in range(3)]})
    print(f"{len(files)} raw Seestar subs (GRBG), {arcsec:.3f}\"/input px; output scale "
          f"{SCALE} ({arcsec / SCALE:.3f}\"/px); Bayer drizzle pixfrac {args.pixfrac}: "
          f"{t_drz:.0f} s, empty output pixels (R, G, B): "
          + ", ".join(f"{m:.2%}" for m in drz.mask.mean(axis=(1, 2))))
    rej = [drz.meta.get(f"AANRJ{k:03d}") for k in range(1, len(files) + 1)]
    rej = np.array([r for r in rej if r is not None], float) / np.prod(drz.shape[1:])
    if rej.size:  # (raw pixels: the output's per input pixel, SCALE**2)
        print(f"raw pixels rejected per frame: {np.min(rej) * SCALE ** 2:.2%} to "
              f"{np.max(rej) * SCALE ** 2:.2%} (median {np.median(rej) * SCALE ** 2:.2%})")
    for method in args.demosaic:
        t0 = time.perf_counter()
        dem = stack(files, bayer="auto", demosaic=method)
        t_dem = time.perf_counter() - t0
        dem_up = np.stack([_upsample(np.where(dem.mask[c], np.nan, dem.data[c]), SCALE)
                           for c in range(3)])
        for h, part, pos in zip(halves or (), parts, xy_half):
            d = stack(part, bayer="auto", demosaic=method)
            h["demosaic"] = [_fit(_upsample(np.where(d.mask[c], np.nan, d.data[c]), SCALE), pos)
                             for c in range(3)]
        fits_ = {"demosaic": [_fit(dem_up[c], xy) for c in range(3)], "drizzle": fit_drz}
        _table(fits_, method, t_dem, arcsec, halves)
        if args.save:
            arrays = {f"{n}": np.stack(f) for n, f in fits_.items()}
            for i, h in enumerate(halves or ()):
                arrays.update({f"{n}_half{i}": np.stack(f) for n, f in h.items()})
            root, ext = os.path.splitext(args.save)
            np.savez(f"{root}_{method}{ext or '.npz'}", xy=xy, **arrays)
    return 0


if __name__ == "__main__":
    sys.exit(main())
