# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Frame quality: each frame measured as it was taken (before resampling), the
weights that maximise the faint stars' signal-to-noise in a stack, and the
selection of the frames to leave out, with the reason.

The measures (`measure_frame`, `transparency`) come from the stars that
detection finds and that matching pairs with the reference's; `frame_quality`
puts them in a table, one row per frame; `quality_weights` and
`select_frames` turn the table into weights and a selection, as
`~astroalign_nd.stack` (``weights='auto'``, ``select=...``) and
`~astroalign_nd.stacking.LiveStack` use them.

The weight of a frame for faint point sources (see the stacking docs for the
derivation) is ``T**2 / (sigma**2 * A)``: its transparency ``T`` (the
stars' flux relative to the reference's), its sky noise per pixel
``sigma`` (of the frame as taken) and the PSF's noise-equivalent area
``A = 4 pi sigma_a sigma_b`` (``1 / sum(P**2)`` of a Gaussian PSF).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from astropy.table import Table

__all__ = ["FrameMeasures", "measure_frame", "measure_frames", "star_shapes", "transparency",
           "frame_quality", "quality_weights", "select_frames", "as_taken", "auto_weight",
           "SelectionError",
           "QUALITY_COLUMNS"]

_GAUSS_FWHM = 2.0 * math.sqrt(2.0 * math.log(2.0))
#: Stars (brightest, unsaturated) whose shapes are measured.
_N_SHAPES = 60
#: Elongation (major / minor axis) above which a frame is trailed, whatever the night.
TRAILED_ELONGATION = 1.5
#: Robust z-score beyond which a frame is an outlier of the night (``select='auto'``).
OUTLIER_Z = 4.0
#: Floors of the night's spreads in the robust z-scores (natural log units), so that a
#: night of near-identical frames does not make a small difference an outlier.
_LOG_SPREAD_FLOOR = {"fwhm": 0.15, "transparency": 0.1, "sky_noise": 0.1, "star_ratio": 0.15}

#: The table's columns, in order.
QUALITY_COLUMNS = ("name", "time", "fwhm", "fwhm_spread", "elongation", "n_stars",
                   "star_ratio", "sky", "sky_noise", "transparency", "n_photometry",
                   "rms", "log10_false_alarm", "weight", "used", "reason")


class SelectionError(ValueError):
    """A selection that would leave fewer than three frames (the message names the limit)."""


@dataclass
class FrameMeasures:
    """
    One frame measured as it was taken.

    Attributes
    ----------
    sky, sky_noise : float
        Sigma-clipped median of the pixels, and the per-pixel noise from
        neighbouring-pixel differences (not smoothed: the frame as taken).
    fwhm, fwhm_spread : float
        Median FWHM (pixels, geometric mean of the axes) of the bright
        unsaturated stars, and the robust spread of their FWHMs.
    elongation : float
        Median ratio of the stars' major to minor axis (1: round; trailed
        frames 1.5 and more).
    area : float
        The PSF's noise-equivalent area ``4 pi sigma_a sigma_b`` (pixels).
    n_stars : int
        Sources detected.
    x, y, peak : ndarray
        The detected sources (pixels, brightest first) and their peak values.
    saturation : float
        The frame's largest value (stars reaching it are not photometered).
    median_variance : float or None
        The median of its own variance (None without an uncertainty).
    sky_subtracted : ndarray or None
        The frame minus its smooth sky, once `transparency` has made it (kept
        for the reference, which every frame's photometry meets).
    """

    sky: float
    sky_noise: float
    fwhm: float
    fwhm_spread: float
    elongation: float
    area: float
    n_stars: int
    x: np.ndarray
    y: np.ndarray
    peak: np.ndarray
    saturation: float
    median_variance: float | None = None
    sky_subtracted: np.ndarray | None = field(default=None, repr=False)


def _cutouts(data, x, y, half):
    """Square cutouts (NaN outside the frame) around the rounded positions."""
    ny, nx = data.shape
    xc, yc = np.round(x).astype(int), np.round(y).astype(int)
    off = np.arange(-half, half + 1)
    rows = yc[:, None, None] + off[None, :, None]
    cols = xc[:, None, None] + off[None, None, :]
    inside = (rows >= 0) & (rows < ny) & (cols >= 0) & (cols < nx)
    cut = data[np.clip(rows, 0, ny - 1), np.clip(cols, 0, nx - 1)].astype(np.float64)
    cut[~inside] = np.nan
    return cut, xc, yc


def star_shapes(data, x, y, *, fwhm_guess=3.0, half=None, n_iter=8):
    """
    Each star's Gaussian-equivalent covariance from adaptive second moments.

    The moments are weighted by a Gaussian of the star's own shape (the
    weight is updated until it matches the deconvolved moments), so that
    neighbours, sky noise and the cutout's edge move them little; for a
    Gaussian star the result is its covariance exactly, for a trailed star
    the covariance of the Gaussian of the same second moments.

    Parameters
    ----------
    data : 2-D ndarray
        The frame (sky not subtracted: each cutout's border median is).
    x, y : (N,) array-like
        Star positions (pixels).
    fwhm_guess : float, optional
        The first weight's FWHM (pixels).
    half : int, optional
        Cutouts are ``2 * half + 1`` pixels wide (default from ``fwhm_guess``).
    n_iter : int, optional

    Returns
    -------
    fwhm : (N,) ndarray
        Geometric-mean FWHM of the axes (NaN where the moments failed).
    elongation : (N,) ndarray
        Major over minor axis.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import simulate_image
    >>> from astroalign_nd.stacking.quality import star_shapes
    >>> img = simulate_image((64, 64), [31.3], [30.6], [1e5], fwhm=4.0, noise=False)
    >>> fwhm, elong = star_shapes(img, [31.3], [30.6], fwhm_guess=3.0)

    The FWHM is the sampled image's: a 4 px Gaussian integrated over unit
    pixels is ``sqrt(4**2 + 2.3548**2 / 12)`` = 4.057 px wide.

    >>> bool(abs(fwhm[0] - 4.057) < 0.01), bool(abs(elong[0] - 1.0) < 0.01)
    (True, True)
    """
    data = np.asarray(data, dtype=np.float64)
    x, y = np.atleast_1d(np.asarray(x, float)), np.atleast_1d(np.asarray(y, float))
    if half is None:
        half = int(np.clip(math.ceil(3.5 * fwhm_guess), 8, 32))
    cut, xc, yc = _cutouts(data, x, y, half)
    n = len(x)
    border = np.concatenate([cut[:, 0, :], cut[:, -1, :], cut[:, 1:-1, 0], cut[:, 1:-1, -1]],
                            axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        cut = cut - np.nanmedian(border, axis=1)[:, None, None]
    good = np.isfinite(cut)
    cut = np.where(good, cut, 0.0)
    off = np.arange(-half, half + 1, dtype=float)
    dy0, dx0 = np.meshgrid(off, off, indexing="ij")
    s2 = (fwhm_guess / _GAUSS_FWHM) ** 2
    cxx, cyy, cxy = np.full(n, s2), np.full(n, s2), np.zeros(n)
    mx, my = x - xc, y - yc
    ok = np.ones(n, dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for _ in range(n_iter):
            det = cxx * cyy - cxy ** 2
            ixx, iyy, ixy = cyy / det, cxx / det, -cxy / det
            dx, dy = dx0[None] - mx[:, None, None], dy0[None] - my[:, None, None]
            w = np.exp(-0.5 * (ixx[:, None, None] * dx ** 2 + iyy[:, None, None] * dy ** 2
                               + 2 * ixy[:, None, None] * dx * dy))
            iw = cut * w
            s = iw.sum(axis=(1, 2))
            ex = (iw * dx).sum(axis=(1, 2)) / s
            ey = (iw * dy).sum(axis=(1, 2)) / s
            mxx = (iw * dx * dx).sum(axis=(1, 2)) / s - ex ** 2
            myy = (iw * dy * dy).sum(axis=(1, 2)) / s - ey ** 2
            mxy = (iw * dx * dy).sum(axis=(1, 2)) / s - ex * ey
            # Deconvolve the weight: C = (M^-1 - W^-1)^-1.
            mdet = mxx * myy - mxy ** 2
            axx, ayy, axy = myy / mdet - ixx, mxx / mdet - iyy, -mxy / mdet - ixy
            adet = axx * ayy - axy ** 2
            step = (s > 0) & (mdet > 0) & (adet > 0) & (axx > 0)
            ok &= step
            nxx, nyy, nxy = ayy / adet, axx / adet, -axy / adet
            # The weighted centroid moves half way for a matched weight: C M^-1 corrects it.
            sx = (nxx * (myy * ex - mxy * ey) + nxy * (-mxy * ex + mxx * ey)) / mdet
            sy = (nxy * (myy * ex - mxy * ey) + nyy * (-mxy * ex + mxx * ey)) / mdet
            cxx, cyy, cxy = (np.where(ok, nxx, cxx), np.where(ok, nyy, cyy),
                             np.where(ok, nxy, cxy))
            mx = np.where(ok, np.clip(mx + sx, -half / 2, half / 2), mx)
            my = np.where(ok, np.clip(my + sy, -half / 2, half / 2), my)
        tr, det = cxx + cyy, cxx * cyy - cxy ** 2
        disc = np.sqrt(np.maximum(tr * tr / 4 - det, 0.0))
        lmax, lmin = tr / 2 + disc, tr / 2 - disc
        fwhm = _GAUSS_FWHM * det ** 0.25
        elong = np.sqrt(lmax / lmin)
    # Too wide for the cutout, or the moments of noise: not a measurement.
    ok &= np.isfinite(fwhm) & (fwhm > 0.5) & (np.sqrt(lmax) < half / 2.0) & (lmin > 0)
    return np.where(ok, fwhm, np.nan), np.where(ok, elong, np.nan)


def measure_frame(data, mask=None, *, variance=None, n_sources=300, **detect_options):
    """
    A frame's sky, noise, star count and star shapes, as it was taken.

    Parameters
    ----------
    data : 2-D array-like
        The frame before any resampling.
    mask : 2-D bool array-like, optional
    variance : 2-D ndarray, optional
        Its own variance (its ``median_variance`` is the median).
    n_sources : int, optional
        Most sources detected (the star count saturates there).
    **detect_options
        Options of `~astroalign_nd.find_sources`.

    Returns
    -------
    measures : `FrameMeasures`
    """
    from astropy.stats import sigma_clipped_stats

    from ..detection import find_sources

    data = np.asarray(data, dtype=np.float64)
    mask = None if mask is None else np.asarray(mask, dtype=bool)
    valid = np.isfinite(data) if mask is None else np.isfinite(data) & ~mask
    if not valid.any():
        raise ValueError("the frame has no valid pixel (every pixel masked or NaN)")
    values = data[valid]
    step = max(1, values.size // 200_000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, sky, _ = sigma_clipped_stats(values[::step], sigma=3.0, maxiters=10)
        table = find_sources(data, mask=~valid, n_sources=n_sources, **detect_options)
    # The per-pixel noise from differences of pixels two columns apart (which cancel
    # the sky and its gradients, and compare pixels of one colour in a raw Bayer
    # mosaic): their sigma-clipped standard deviation over sqrt(2).  A standard
    # deviation, not a MAD: the MAD of integer counts with a noise of one or two
    # counts is quantised.
    d = (data[:, 2:] - data[:, :-2])[valid[:, 2:] & valid[:, :-2]]
    noise = float("nan")
    if d.size:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _, _, std = sigma_clipped_stats(d[::max(1, d.size // 200_000)], sigma=3.0,
                                            maxiters=10)
        noise = float(std / math.sqrt(2.0))
    x, y = np.asarray(table["x"], float), np.asarray(table["y"], float)
    peak = np.asarray(table["peak"], float)
    saturation = float(np.max(values))
    fwhm_det = float(table.meta.get("fwhm") or 3.0)
    # Bright, unsaturated stars: their moments are not noise's nor a plateau's.
    bright = np.flatnonzero((peak < 0.8 * (saturation - sky)) & (peak > 10.0 * noise))
    bright = bright[:_N_SHAPES] if bright.size >= 5 else np.arange(min(len(x), _N_SHAPES))
    fw, el = star_shapes(data, x[bright], y[bright], fwhm_guess=fwhm_det)
    okf = np.isfinite(fw)
    if okf.sum() >= 1:
        fwhm = float(np.median(fw[okf]))
        spread = float(1.4826 * np.median(np.abs(fw[okf] - fwhm))) if okf.sum() > 2 else 0.0
        elong = float(np.median(el[okf]))
    else:
        fwhm, spread, elong = fwhm_det, float("nan"), float("nan")
    area = 4.0 * math.pi * (fwhm / _GAUSS_FWHM) ** 2
    med_var = None
    if variance is not None:
        v = np.asarray(variance, dtype=np.float64)[valid]
        v = v[np.isfinite(v)]
        med_var = float(np.median(v)) if v.size else None
    return FrameMeasures(sky=float(sky), sky_noise=noise, fwhm=fwhm, fwhm_spread=spread,
                         elongation=elong, area=area, n_stars=len(x), x=x, y=y, peak=peak,
                         saturation=saturation, median_variance=med_var)


def _variance_of(parsed):
    """A parsed frame's variance (None without an uncertainty)."""
    unc = parsed.uncertainty
    if unc is None:
        return None
    a = np.asarray(unc.array, dtype=np.float64)
    name = type(unc).__name__
    if name == "StdDevUncertainty":
        return a * a
    if name == "InverseVariance":
        with np.errstate(divide="ignore"):
            return np.where(a > 0, 1.0 / np.where(a > 0, a, 1.0), np.inf)
    return a


def measure_parsed(parsed):
    """`measure_frame` of a parsed input (its data, mask and uncertainty)."""
    return measure_frame(np.asarray(parsed.data, dtype=np.float64), parsed.mask,
                         variance=_variance_of(parsed))


def measure_frames(reference, others, *, hdu=None, unit=None):
    """
    The quality rows of a stack's frames, from what its registration found.

    Parameters
    ----------
    reference : (name, frame)
        The reference as given (before any resampling).
    others : list of (name, frame, points, quality)
        Each registered frame as given, its matched ``(frame, reference)``
        positions and its registration's quality dict (``rms``,
        ``log10_false_alarm``).
    hdu, unit : optional
        As in `~astroalign_nd.register`.

    Returns
    -------
    rows : list of dict
        One per frame, the reference first (see ``quality_row``); a frame
        that cannot be measured has its error as ``reason``.
    measures : list of `FrameMeasures` or None
    """
    from ..io.read import parse_input

    ref = parse_input(reference[1], "reference", hdu=hdu, unit=unit)
    ref_data = np.asarray(ref.data, dtype=np.float64)
    ref_m = measure_parsed(ref)
    rows = [quality_row(reference[0], ref_m, ref_m, 1.0, ref_m.n_stars,
                        time=frame_time(ref.meta))]
    measures = [ref_m]
    for name, frame, points, quality in others:
        try:
            p = parse_input(frame, "source", hdu=hdu, unit=unit)
            m = measure_parsed(p)
            t, n = transparency(np.asarray(p.data, dtype=np.float64), ref_data, points[0],
                                points[1], m, ref_m)
        except (ValueError, TypeError) as exc:
            rows.append(dict(name=name, used=False, reason=f"{type(exc).__name__}: {exc}"))
            measures.append(None)
            continue
        rows.append(quality_row(name, m, ref_m, t, n, quality, time=frame_time(p.meta)))
        measures.append(m)
    return rows, measures


def _sky_map(data, box, mask=None):
    """A smooth sky (photutils' `~photutils.background.Background2D`, sigma-clipped
    medians of ``box``-pixel boxes, ``mask`` left out), or the sigma-clipped median
    where it cannot run."""
    from astropy.stats import SigmaClip, sigma_clipped_stats
    from photutils.background import Background2D, MedianBackground

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return Background2D(data, box, filter_size=3, sigma_clip=SigmaClip(sigma=2.5),
                                bkg_estimator=MedianBackground(), mask=mask,
                                exclude_percentile=80.0).background
        except (ValueError, TypeError):
            return np.full(data.shape, sigma_clipped_stats(data[np.isfinite(data)])[1])


def _sky_subtracted(data, measures):
    """
    The frame minus a smooth sky measured with the detected stars masked (to twice
    their FWHM): the wings of broad stars in a crowded field would raise it, and
    lower the fluxes.
    """
    box = int(np.clip(min(data.shape) // 4, 32, 128))
    stars = np.zeros(data.shape, dtype=bool)
    r = max(2.0 * measures.fwhm, 3.0)
    half = int(math.ceil(r))
    off = np.arange(-half, half + 1)
    disk = np.hypot(off[:, None], off[None, :]) <= r
    dy, dx = np.nonzero(disk)
    for xs, ys in zip(np.round(measures.x).astype(int), np.round(measures.y).astype(int)):
        rr, cc = ys + dy - half, xs + dx - half
        ok = (rr >= 0) & (rr < data.shape[0]) & (cc >= 0) & (cc < data.shape[1])
        stars[rr[ok], cc[ok]] = True
    return data - _sky_map(data, box, stars | ~np.isfinite(data))


def _aperture_fluxes(sub, x, y, radius, sky_noise):
    """Circular-aperture fluxes of a sky-subtracted frame, and their noise."""
    from photutils.aperture import CircularAperture, aperture_photometry

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        phot = aperture_photometry(np.where(np.isfinite(sub), sub, 0.0),
                                   CircularAperture(np.column_stack([x, y]), r=radius))
    err = sky_noise * math.sqrt(math.pi) * radius
    return np.asarray(phot["aperture_sum"], float), err


def transparency(data, ref_data, points, ref_points, measures, ref_measures):
    """
    The robust ratio of the matched stars' fluxes to the reference's.

    Each matched pair is photometered in both frames, in an aperture of
    twice the larger of the two FWHMs (whatever the seeing, the same
    fraction of the flux: more than 99.99% of a Gaussian) with the sky of
    an annulus around it; pairs too close to an edge, saturated or faint
    are left out, and the median of the ratios is taken.

    Parameters
    ----------
    data, ref_data : 2-D ndarray
        The frame and the reference, as taken.
    points, ref_points : (N, 2) ndarray
        Matched star positions (x, y) in each.
    measures, ref_measures : `FrameMeasures`

    Returns
    -------
    transparency : float
        NaN when no pair could be photometered.
    n : int
        The pairs used.
    """
    points, ref_points = np.asarray(points, float), np.asarray(ref_points, float)
    if len(points) == 0:
        return float("nan"), 0
    radius = float(np.clip(2.0 * max(measures.fwhm, ref_measures.fwhm), 3.0, 40.0))
    keep = np.ones(len(points), dtype=bool)
    for img, pts in ((data, points), (ref_data, ref_points)):
        ny, nx = img.shape
        edge = radius + 1.0
        keep &= ((pts[:, 0] > edge) & (pts[:, 0] < nx - 1 - edge)
                 & (pts[:, 1] > edge) & (pts[:, 1] < ny - 1 - edge))
    if not keep.any():
        return float("nan"), 0
    points, ref_points = points[keep], ref_points[keep]
    sub = _sky_subtracted(np.asarray(data, float), measures)
    if ref_measures.sky_subtracted is None:
        ref_measures.sky_subtracted = _sky_subtracted(np.asarray(ref_data, float), ref_measures)
    f, ef = _aperture_fluxes(sub, points[:, 0], points[:, 1], radius, measures.sky_noise)
    r, er = _aperture_fluxes(ref_measures.sky_subtracted, ref_points[:, 0], ref_points[:, 1],
                             radius, ref_measures.sky_noise)
    peak_f = _local_max(data, points)
    peak_r = _local_max(ref_data, ref_points)
    ok = (np.isfinite(f) & np.isfinite(r) & (r > 20.0 * er) & (f > 5.0 * ef)
          & (peak_f < 0.9 * measures.saturation) & (peak_r < 0.9 * ref_measures.saturation))
    if ok.sum() < 3:  # few stars: take the faint and the saturated rather than nothing
        ok = np.isfinite(f) & np.isfinite(r) & (r > 0) & (f > 0)
    if not ok.any():
        return float("nan"), 0
    return float(np.median(f[ok] / r[ok])), int(ok.sum())


def _local_max(data, pts):
    cut, _, _ = _cutouts(np.asarray(data, float), pts[:, 0], pts[:, 1], 2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmax(cut.reshape(len(pts), -1), axis=1)


def quality_weights(table):
    """
    Faint-point-source weights: ``transparency**2 / (sky_noise**2 * area)``.

    ``area`` is the PSF's noise-equivalent area ``4 pi (fwhm / 2.3548)**2``.
    The weights are relative to the reference's (the first row): 1 for it.
    A frame whose transparency could not be measured counts as 1.

    Parameters
    ----------
    table : `~astropy.table.Table`
        As `frame_quality` returns it (``fwhm``, ``sky_noise``,
        ``transparency``).

    Returns
    -------
    weights : ndarray

    Examples
    --------
    >>> from astropy.table import Table
    >>> from astroalign_nd.stacking.quality import quality_weights
    >>> t = Table({"fwhm": [3.0, 6.0, 3.0], "sky_noise": [10.0, 10.0, 10.0],
    ...            "transparency": [1.0, 1.0, 0.5]})
    >>> quality_weights(t).round(3).tolist()
    [1.0, 0.25, 0.25]
    """
    fwhm = np.asarray(table["fwhm"], float)
    noise = np.asarray(table["sky_noise"], float)
    t = np.asarray(table["transparency"], float)
    t = np.where(np.isfinite(t) & (t > 0), t, 1.0)
    area = 4.0 * math.pi * (fwhm / _GAUSS_FWHM) ** 2
    w = t ** 2 / (noise ** 2 * area)
    w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
    return w / w[0] if w[0] > 0 else w / max(w.max(), 1e-300)


def _robust_z(values, floor):
    """Robust z-scores of log values (median, MAD sigma with a floor)."""
    lv = np.log(np.where(np.asarray(values, float) > 0, values, np.nan))
    ok = np.isfinite(lv)
    if ok.sum() < 3:
        return np.zeros(len(lv))
    med = np.median(lv[ok])
    spread = max(1.4826 * np.median(np.abs(lv[ok] - med)), floor)
    return np.where(ok, (lv - med) / spread, 0.0)


def select_frames(table, select=None, *, max_fwhm=None, max_elongation=None,
                  min_transparency=None, min_stars=None, min_frames=3):
    """
    Which frames to leave out of a stack, and why.

    Parameters
    ----------
    table : `~astropy.table.Table`
        As `frame_quality` returns it; the first row is the reference
        (never left out).
    select : None, 'auto' or float, optional
        None: only the explicit limits.  'auto': also the trailed frames
        (elongation above 1.5 and 25% above the night's median) and the
        outliers of the night: robust z-scores of the log of FWHM (high),
        transparency, star count (low) and sky noise (high) beyond 4.  A
        fraction in (0, 1]: keep that fraction of the frames, the highest
        weights (the ``weight`` column) first.
    max_fwhm, max_elongation, min_transparency : float, optional
        Explicit limits (pixels, ratio, relative to the reference).
    min_stars : int, optional
        The fewest sources detected.
    min_frames : int, optional
        Fewer frames left is a `SelectionError` (default 3).

    Returns
    -------
    reasons : list of str or None
        Per row: None when used, else why it is left out.

    Raises
    ------
    SelectionError
        If fewer than ``min_frames`` would be left: the message names the
        limit that left out the most frames, to relax.
    """
    n = len(table)
    col = {k: np.asarray(table[k], float) for k in
           ("fwhm", "elongation", "transparency", "n_stars", "sky_noise", "star_ratio")}
    reasons = [[] for _ in range(n)]
    culprits = {}

    def leave(idx, why, limit):
        for i in np.flatnonzero(idx):
            if i == 0:
                continue
            reasons[i].append(why(i))
            culprits[limit] = culprits.get(limit, 0) + 1

    with np.errstate(invalid="ignore"):
        if max_fwhm is not None:
            leave(col["fwhm"] > max_fwhm, lambda i: f"fwhm {col['fwhm'][i]:.2f} px > max_fwhm "
                  f"{max_fwhm:g}", "max_fwhm")
        if max_elongation is not None:
            leave(col["elongation"] > max_elongation,
                  lambda i: f"trailed: elongation {col['elongation'][i]:.2f} > max_elongation "
                  f"{max_elongation:g}", "max_elongation")
        if min_transparency is not None:
            leave(col["transparency"] < min_transparency,
                  lambda i: f"transparency {col['transparency'][i]:.3f} < min_transparency "
                  f"{min_transparency:g}", "min_transparency")
        if min_stars is not None:
            leave(col["n_stars"] < min_stars, lambda i: f"{int(col['n_stars'][i])} stars < "
                  f"min_stars {min_stars}", "min_stars")
        if isinstance(select, str) and select == "auto":
            elong = col["elongation"]
            med_e = np.nanmedian(elong)
            leave((elong > TRAILED_ELONGATION) & (elong > 1.25 * med_e),
                  lambda i: f"trailed: elongation {elong[i]:.2f} (night's median "
                  f"{med_e:.2f})", "select='auto' (trailed)")
            # (Not the star count: it falls with the seeing, which the FWHM judges.)
            for key, sign, what in (("fwhm", 1, "FWHM"), ("transparency", -1, "transparency"),
                                    ("sky_noise", 1, "sky noise")):
                z = sign * _robust_z(col[key], _LOG_SPREAD_FLOOR[key])
                med = np.nanmedian(col[key])
                leave(z > OUTLIER_Z, lambda i, key=key, what=what, med=med, z=z:
                      f"outlier of the night: {what} {col[key][i]:.3g} (median {med:.3g}, "
                      f"robust z {z[i] * sign:+.1f})", f"select='auto' ({what})")
        elif select is not None and not isinstance(select, str):
            frac = float(select)
            n_keep = max(min_frames, int(math.ceil(frac * n)))
            w = np.asarray(table["weight"], float).copy()
            w[0] = np.inf  # the reference stays
            order = np.argsort(-w, kind="stable")
            low = np.zeros(n, dtype=bool)
            low[order[n_keep:]] = True
            leave(low, lambda i: f"not in the best {frac:.0%} by weight "
                  f"({table['weight'][i]:.3g})", f"select={frac:g}")
    out = ["; ".join(r) if r else None for r in reasons]
    n_left = sum(r is None for r in out)
    if n_left < min_frames and culprits:  # (too few frames to start with is not the selection's)
        worst = max(culprits, key=culprits.get)
        raise SelectionError(
            f"the selection leaves {n_left} of {n} frames, fewer than {min_frames}: relax "
            f"{worst} (it left out {culprits[worst]}), or pass select=None. Left out: "
            + "; ".join(f"{table['name'][i]}: {r}" for i, r in enumerate(out) if r))
    return out


def quality_table(rows):
    """The quality rows (dicts) as a `~astropy.table.Table` of ``QUALITY_COLUMNS``."""
    cols = {}
    for key in QUALITY_COLUMNS:
        vals = [r.get(key) for r in rows]
        if key in ("name", "reason"):
            cols[key] = [("" if v is None else str(v)) for v in vals]
        elif key == "used":
            cols[key] = [bool(v) for v in vals]
        elif key in ("n_stars", "n_photometry"):
            cols[key] = [int(v or 0) for v in vals]
        else:
            cols[key] = [float("nan") if v is None else float(v) for v in vals]
    t = Table(cols)
    for key, fmt in (("fwhm", ".2f"), ("fwhm_spread", ".2f"), ("elongation", ".2f"),
                     ("star_ratio", ".2f"), ("sky", ".5g"), ("sky_noise", ".4g"),
                     ("transparency", ".3f"), ("rms", ".3f"), ("log10_false_alarm", ".1f"),
                     ("weight", ".3f"), ("time", ".5f")):
        t[key].format = fmt
    return t


def quality_row(name, measures, ref_measures, transp, n_phot, match_quality=None, time=None):
    """One frame's row of the quality table (a dict of ``QUALITY_COLUMNS``)."""
    q = match_quality or {}
    return dict(name=name, time=time, fwhm=measures.fwhm, fwhm_spread=measures.fwhm_spread,
                elongation=measures.elongation, n_stars=measures.n_stars,
                star_ratio=measures.n_stars / max(ref_measures.n_stars, 1), sky=measures.sky,
                sky_noise=measures.sky_noise, transparency=transp, n_photometry=n_phot,
                rms=q.get("rms", 0.0 if measures is ref_measures else None),
                log10_false_alarm=q.get("log10_false_alarm"), weight=None, used=True,
                reason=None)


def frame_time(meta):
    """A frame's time (MJD) from its header (``MJD-OBS``, ``DATE-OBS``), or None."""
    from astropy.time import Time

    if meta is None:
        return None
    for key in ("MJD-OBS", "MJD_OBS"):
        if key in meta:
            try:
                return float(meta[key])
            except (TypeError, ValueError):
                pass
    for key in ("DATE-OBS", "DATE_OBS", "UT-OBS"):
        if key in meta:
            try:
                return float(Time(str(meta[key])[:23], scale="utc").mjd)
            except (TypeError, ValueError):
                pass
    return None


def frame_quality(frames: Any, reference: Any = None, *, select: Any = None,
                  max_fwhm: float | None = None, max_elongation: float | None = None,
                  min_transparency: float | None = None, min_stars: int | None = None,
                  hdu: int | str | None = None, unit: Any = None, **options: Any) -> Table:
    """
    Measure every frame of a night: one row per frame.

    Each frame is measured as it was taken (before any resampling): its
    sky level and per-pixel noise, the median FWHM of its bright stars and
    their spread, their elongation (trailing), its source count relative to
    the reference's, and its transparency (the median ratio of the matched
    stars' fluxes to the reference's, in apertures of twice the larger
    FWHM).  It is matched to the reference as `~astroalign_nd.register`
    matches it (the registration's RMS and false-alarm figure are in the
    row), and given the weight that ``stack(weights='auto')`` gives it, and
    the selection's verdict.

    Parameters
    ----------
    frames : iterable
        As `~astroalign_nd.stack` takes them.
    reference : optional
        The reference (default: the first frame): the first row.
    select, max_fwhm, max_elongation, min_transparency, min_stars : optional
        The selection, as in `~astroalign_nd.stacking.quality.select_frames`
        (default: none; every frame that could be measured is used).
    hdu, unit, **options
        As in `~astroalign_nd.register` (matching and detection options).

    Returns
    -------
    table : `~astropy.table.Table`
        Columns `~astroalign_nd.stacking.quality.QUALITY_COLUMNS`: ``name``, ``time`` (MJD, from the
        header; NaN without), ``fwhm`` and ``fwhm_spread`` (pixels),
        ``elongation``, ``n_stars``, ``star_ratio`` (to the reference's),
        ``sky``, ``sky_noise``, ``transparency``, ``n_photometry`` (pairs
        in the transparency), ``rms`` (pixels) and ``log10_false_alarm``
        of the registration, ``weight`` (relative to the reference's),
        ``used`` and ``reason`` (why a frame is not used; a frame that
        could not be matched has its error there).

    Raises
    ------
    SelectionError
        If the selection leaves fewer than three frames.

    Examples
    --------
    >>> from astroalign_nd import frame_quality
    >>> from astroalign_nd.simulate import simulate_sequence
    >>> seq = simulate_sequence((192, 192), n_frames=3, n_stars=80, fwhm=3.0,
    ...                         flux_range=(2e3, 5e4), seed=2)
    >>> t = frame_quality(seq.frames)
    >>> len(t), bool(abs(t["fwhm"][1] - 3.0) < 0.3), bool(abs(t["transparency"][2] - 1) < 0.05)
    (3, True, True)
    """
    from ..io.read import batch_frames, parse_input
    from ..registration import Reference, find_match

    items, hdu = batch_frames(frames, hdu)
    items = [(f, f"frame{k}" if label is None else str(label))
             for k, (f, label) in enumerate(list(items))]
    if not items:
        raise ValueError("frames is empty: give at least one frame.")
    if reference is None:
        ref_item, others = items[0], items[1:]
    else:
        ref_item = (reference, "reference")
        others = [it for it in items if it[0] is not reference]
    match_opts = {k: v for k, v in options.items()}
    ref = parse_input(ref_item[0], "reference", hdu=hdu, unit=unit)
    ref_data = np.asarray(ref.data, dtype=np.float64)
    ref_m = measure_parsed(ref)
    target = Reference(ref_item[0], hdu=hdu, unit=unit)
    rows = [quality_row(ref_item[1], ref_m, ref_m, 1.0, ref_m.n_stars,
                        time=frame_time(ref.meta))]
    for frame, name in others:
        try:
            p = parse_input(frame, "source", hdu=hdu, unit=unit)
            data = np.asarray(p.data, dtype=np.float64)
            m = measure_parsed(p)
            result = find_match(frame, target, hdu=hdu, **match_opts)
            t, n = transparency(data, ref_data, result.source_points, result.target_points,
                                m, ref_m)
            rows.append(quality_row(name, m, ref_m, t, n, dict(
                rms=result.rms, log10_false_alarm=result.log10_false_alarm),
                time=frame_time(p.meta)))
        except Exception as exc:  # noqa: BLE001 - a bad frame is listed with its error
            rows.append(dict(name=name, used=False, reason=f"{type(exc).__name__}: {exc}"))
    return finish_table(rows, select, dict(max_fwhm=max_fwhm, max_elongation=max_elongation,
                                           min_transparency=min_transparency,
                                           min_stars=min_stars))


def as_taken(st, row, m):
    """
    A registered frame's stats with its noise as taken (before resampling smoothed it):
    its sky noise, or the factor of its propagated variance; its transparency and
    measures for ``normalize='stars'`` and the header.

    Parameters
    ----------
    st : ``astroalign_nd.stacking.combine.FrameStats``
        Of the registered frame; changed in place.
    row : dict or None
        Its quality row (``quality_row``).
    m : `FrameMeasures` or None
        Its measures as taken (None: ``st`` is left as it is).
    """
    if m is None:
        return
    if st.median_variance is not None and m.median_variance and st.median_variance > 0:
        st.var_factor = max(m.median_variance / st.median_variance, 1.0)
        st.median_variance = m.median_variance
    elif m.sky_noise > 0:
        st.noise = m.sky_noise
    st.transparency = row["transparency"]
    st.quality = {k: row[k] for k in ("fwhm", "elongation", "transparency", "sky_noise",
                                      "weight")}


def auto_weight(st):
    """
    A frame's ``weights='auto'`` weight for its values as normalised: its quality
    weight ``T**2 / (sigma**2 * A)`` (for frames scaled by ``1 / T``) divided by the
    star signal ``T * scale`` its normalisation leaves (1 for ``normalize='stars'``):
    with signal ``g = T s`` and noise ``sigma s`` per pixel, the best weight is
    ``g / (sigma**2 s**2 A)``.  NaN without a measure.
    """
    if not st.quality:
        return float("nan")
    t = st.transparency if st.transparency and np.isfinite(st.transparency) else 1.0
    return st.quality["weight"] / (t * st.scale)


def finish_table(rows, select, limits):
    """The table of ``rows`` with its weights, selection and reasons filled in."""
    measured = [r for r in rows if r.get("reason") is None]
    sub = quality_table(measured)
    weights = quality_weights(sub) if len(sub) else np.zeros(0)
    sub["weight"] = weights
    reasons = select_frames(sub, select, **limits) if len(sub) else []
    for r, w, why in zip(measured, weights, reasons):
        r.update(weight=float(w), used=why is None, reason=why)
    for r in rows:
        if r.get("weight") is None:
            r.update(weight=0.0, used=False)
    return quality_table(rows)
