# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Combining registered frames, strip by strip: sky normalisation, rejection
(sigma or min/max clipping), weights and the combined uncertainty.

The frames are registered FITS files on one grid (``MASK`` and ``UNCERT``
extensions as `~astropy.nddata.CCDData.write` writes them); they are read
through memory maps, a strip of rows of every frame at a time, so that the
memory a stack needs is bounded by ``memory_limit`` whatever the number of
frames (as ccdproc's ``combine`` does).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from astropy.stats import sigma_clipped_stats

from ..io.read import image_shape_unit, read_rows

__all__ = ["FrameStats", "frame_stats", "array_stats",
           "combine_files", "normalise", "frame_weights", "reject", "combine", "frame_variance",
           "rows_per_strip", "robust_sigma", "MIN_MAD_VALUES"]

#: Bytes of working memory per frame and per pixel of a strip (the values, their
#: variance and validity, and the temporaries of the median and the clipping).
_BYTES_PER_VALUE = 64
#: Pixels sampled for a frame's sky statistics (a regular subsample: deterministic).
_SKY_SAMPLES = 100_000
_MAD_TO_SIGMA = 1.482602218505602
#: Values at a pixel from which sigma clipping also trusts their MAD for the spread.
MIN_MAD_VALUES = 6
#: Variance of the median of n Gaussian values, relative to that of their mean (large n).
_MEDIAN_EFFICIENCY = math.pi / 2.0


@dataclass
class FrameStats:
    """
    One registered frame's sky, noise and weight.

    Attributes
    ----------
    sky : float
        Sigma-clipped median of its valid pixels.
    noise : float
        Sigma-clipped standard deviation of its valid pixels (the sky noise).
    median_variance : float or None
        Median of its propagated variance (None without an uncertainty).
    n_valid : int
        Number of valid (unmasked, finite) pixels.
    offset, scale : float
        Its normalisation: ``value * scale - offset`` is on the reference's sky.
    weight : float
        Its weight in the average.
    n_rejected : int
        Pixels of it that the clipping rejected.
    unit : str or None
        Its unit (``BUNIT``), if its file says.
    converted : str or None
        How it was brought into the reference's unit, if it was.
    var_factor : float
        Its variance on the stack's grid is its propagated (or sky) variance
        times this: the variance of the frame as taken over that of the
        resampled frame, whose interpolation smoothed (and correlated) its
        noise (see `frame_variance`).
    transparency : float or None
        The stars' flux relative to the reference's (``normalize='stars'``).
    quality : dict or None
        Its measures (FWHM, elongation, transparency, sky noise) for the header.
    """

    sky: float
    noise: float
    median_variance: float | None
    n_valid: int
    offset: float = 0.0
    scale: float = 1.0
    weight: float = 1.0
    n_rejected: int = field(default=0)
    unit: str | None = None
    converted: str | None = None
    var_factor: float = 1.0
    transparency: float | None = None
    quality: dict | None = None


def robust_sigma(values):
    """
    The standard deviation of ``values`` from their median absolute deviation.

    Parameters
    ----------
    values : array-like
        Finite values.

    Returns
    -------
    sigma : float

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.stacking.combine import robust_sigma
    >>> rng = np.random.default_rng(0)
    >>> bool(abs(robust_sigma(rng.normal(0.0, 2.0, 100_000)) - 2.0) < 0.05)
    True
    """
    v = np.asarray(values, dtype=float)
    return float(_MAD_TO_SIGMA * np.median(np.abs(v - np.median(v))))


def frame_stats(path, memory_limit=512e6):
    """
    The sky, noise and median variance of a registered frame (see `FrameStats`).

    The frame is read a strip of rows at a time (within ``memory_limit``
    bytes), and a regular subsample of its valid pixels is kept.

    Parameters
    ----------
    path : str
        A registered FITS file.
    memory_limit : float, optional
        Bytes.

    Returns
    -------
    stats : `FrameStats`

    Raises
    ------
    ValueError
        If the frame is not a 2-D image, or has no valid pixel.
    """
    shape, unit = image_shape_unit(path)
    if len(shape) != 2:
        raise ValueError(f"its data has shape {shape}, not a 2-D image like the other "
                         "frames; stack one plane (colour channel) at a time.")
    ny, nx = shape
    step = max(1, (ny * nx) // _SKY_SAMPLES)
    rows = rows_per_strip(1, nx, memory_limit)
    values, variances, n_valid, has_var = [], [], 0, True
    for r0 in range(0, ny, rows):
        data, var, valid = read_rows(path, r0, min(ny, r0 + rows))
        n_valid += int(valid.sum())
        values.append(data[valid][::step])
        has_var = has_var and var is not None
        if has_var:
            variances.append(var[valid][::step])
    data = np.concatenate(values)
    var = np.concatenate(variances) if has_var else None
    stats = array_stats(data, var, np.ones(data.shape, dtype=bool))
    stats.n_valid, stats.unit = n_valid, unit
    return stats


def array_stats(data, var, valid):
    """
    The sky, noise and median variance of a registered frame's arrays.

    Parameters
    ----------
    data : 2-D ndarray
    var : 2-D ndarray or None
    valid : 2-D bool ndarray

    Returns
    -------
    stats : `FrameStats`
        Its ``unit`` unset (the arrays do not say it), ``n_valid`` counted
        in ``valid``.

    Raises
    ------
    ValueError
        If the frame has no valid pixel, or its sky cannot be measured.
    """
    n_valid = int(valid.sum())
    if n_valid == 0:
        raise ValueError("no valid pixel on the stack's grid (every pixel masked or NaN)")
    values = data[valid]
    step = max(1, values.size // _SKY_SAMPLES)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # astropy's all-masked warnings: checked below
        _, sky, noise = sigma_clipped_stats(values[::step], sigma=3.0, maxiters=10)
    med_var = None if var is None else float(np.median(var[valid][::step]))
    if not (np.isfinite(sky) and np.isfinite(noise)):
        raise ValueError("its sky level could not be measured")
    return FrameStats(sky=float(sky), noise=float(noise), median_variance=med_var,
                      n_valid=n_valid)


def rows_per_strip(n_frames, nx, memory_limit):
    """
    How many rows of every frame fit in ``memory_limit`` bytes at once (at least 1).

    Parameters
    ----------
    n_frames, nx : int
    memory_limit : float
        Bytes.

    Returns
    -------
    rows : int

    Examples
    --------
    >>> from astroalign_nd.stacking.combine import rows_per_strip
    >>> rows_per_strip(10, 1000, 64e6)
    100
    """
    return max(1, int(memory_limit // (_BYTES_PER_VALUE * max(n_frames, 1) * max(nx, 1))))


def _nanmedian(a):
    """
    The median along axis 0, ignoring NaN (NaN where all are): a sort of the
    few values of each pixel, several times faster than `numpy.nanmedian`
    along a short axis.
    """
    s = np.sort(a, axis=0)  # NaN sort last
    k = np.count_nonzero(~np.isnan(a), axis=0)
    lo = np.maximum(k - 1, 0) // 2
    hi = k // 2
    med = 0.5 * (np.take_along_axis(s, lo[None], axis=0)[0]
                 + np.take_along_axis(s, np.minimum(hi, a.shape[0] - 1)[None], axis=0)[0])
    return np.where(k > 0, med, np.nan)


#: The star allowance's part for registration and normalisation errors: all of it for a
#: night of equal seeing.
STAR_TOLERANCE_FLOOR = 0.3


def star_tolerance(fwhm):
    """
    The clipping's allowance for the stars' own signal (``star_tolerance``) from the
    frames' star FWHMs: the largest ratio of a frame's star peak to the median frame's
    (peaks scale as the inverse FWHM squared), minus 1, plus ``STAR_TOLERANCE_FLOOR`` for
    registration and normalisation errors; None with fewer than two FWHMs (the
    non-finite and non-positive ones left out).
    """
    fwhm = np.array([f for f in fwhm if f is not None], float)
    fwhm = fwhm[np.isfinite(fwhm) & (fwhm > 0)]
    if fwhm.size < 2:
        return None
    ratio = (np.median(fwhm) / fwhm) ** 2
    return float(np.max(np.abs(ratio - 1.0))) + STAR_TOLERANCE_FLOOR


def _sigma_clip(x, var, valid, opts):
    """
    Reject values beyond ``sigma_low``/``sigma_high`` times the spread about the
    median, iteratively.  The spread is the MAD's sigma, but never less than
    each value's own uncertainty; with fewer than `MIN_MAD_VALUES` values
    it is that uncertainty alone (the MAD of a few values, one of them an
    outlier, is as large as the outlier's distance).
    """
    keep = valid.copy()
    # Each value's own uncertainty (its frame as taken: see `frame_variance`), so that an
    # unresampled frame is not held to the smoothed frames' tighter scatter.
    floor = np.sqrt(var)
    tolerance = opts.star_tolerance or 0.0
    for _ in range(opts.maxiters):
        vals = np.where(keep, x, np.nan)
        med = _nanmedian(vals)
        mad = _MAD_TO_SIGMA * _nanmedian(np.abs(vals - med))
        spread = np.where(keep.sum(axis=0) >= MIN_MAD_VALUES, np.fmax(mad, floor), floor)
        allow = 0.0
        if tolerance > 0 and np.isfinite(med).any():
            # The stars' own signal above the sky (each row's: the median of its medians).
            with np.errstate(invalid="ignore"):
                sky = np.nanmedian(med, axis=-1, keepdims=True)
                allow = tolerance * np.abs(np.nan_to_num(med - sky))
        with np.errstate(invalid="ignore"):
            bad = keep & ((x - med > opts.sigma_high * spread + allow)
                          | (med - x > opts.sigma_low * spread + allow))
        if not bad.any():
            break
        keep &= ~bad
    return keep


def reject(x, var, valid, opts):
    """
    The values kept at each pixel by ``opts.clip``.

    A pixel whose values would all be rejected keeps them all.

    Parameters
    ----------
    x, var : (n, ny, nx) ndarray
        The frames' normalised values and their variance.
    valid : (n, ny, nx) bool ndarray
    opts : `~astroalign_nd.stacking.StackConfig`

    Returns
    -------
    keep : (n, ny, nx) bool ndarray
    """
    if opts.clip == "sigma":
        keep = _sigma_clip(x, var, valid, opts)
    elif opts.clip == "minmax":  # the nlow lowest and nhigh highest valid values dropped
        order = np.argsort(np.where(valid, x, np.inf), axis=0, kind="stable")
        rank = np.empty_like(order)
        np.put_along_axis(rank, order, np.arange(x.shape[0])[:, None, None], axis=0)
        keep = valid & (rank >= opts.nlow) & (rank < valid.sum(axis=0) - opts.nhigh)
    else:
        return valid
    lost = ~keep.any(axis=0) & valid.any(axis=0)
    keep[:, lost] = valid[:, lost]
    return keep


def combine(x, var, keep, weights, opts, n_total):
    """
    The combined values and variance of the values kept (NaN where none is).

    Parameters
    ----------
    x, var : (n, ny, nx) ndarray
    keep : (n, ny, nx) bool ndarray
    weights : (n,) ndarray
        Per frame.
    opts : `~astroalign_nd.stacking.StackConfig`
        Its ``method``.
    n_total : int
        The number of frames of the stack (the factor of ``'sum'``).

    Returns
    -------
    value, variance : (ny, nx) ndarray
    """
    n_kept = keep.sum(axis=0)
    if opts.method == "median":
        value = _nanmedian(np.where(keep, x, np.nan))
        with np.errstate(invalid="ignore", divide="ignore"):
            variance = (_MEDIAN_EFFICIENCY * np.where(keep, var, 0.0).sum(axis=0)
                        / n_kept.astype(float) ** 2)
        return value, variance
    w = np.where(keep, weights[:, None, None], 0.0)
    wsum = w.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        value = (w * np.where(keep, x, 0.0)).sum(axis=0) / wsum
        variance = (w * w * np.where(keep, var, 0.0)).sum(axis=0) / (wsum * wsum)
    if opts.method == "sum":  # a frame's worth for every frame: no steps where some miss
        value, variance = value * n_total, variance * float(n_total) ** 2
    return value, variance


def frame_variance(data, var, stats, gain, read_noise):
    """
    A frame's variance: its own, else from gain and read noise, else its sky noise.

    Parameters
    ----------
    data : ndarray
    var : ndarray or None
        Its own (propagated) variance.
    stats : `FrameStats`
    gain, read_noise : float or None
        Electrons per count, and electrons.

    Returns
    -------
    variance : ndarray
    """
    if var is not None:
        return var * stats.var_factor if stats.var_factor != 1.0 else var
    if gain is not None:
        rn = 0.0 if read_noise is None else read_noise
        return np.maximum(data, 0.0) / gain + (rn / gain) ** 2
    return np.full_like(data, stats.noise ** 2)


def combine_files(paths, stats, shape, opts, *, gain=None, read_noise=None,
                  memory_limit=512e6, rejected=None):
    """
    Combine registered frames on one grid, a strip of rows at a time.

    Parameters
    ----------
    paths : list of str
        Registered FITS files, all of ``shape``.
    stats : list of `FrameStats`
        Their normalisation (``offset``, ``scale``) and ``weight``; their
        ``n_rejected`` is filled in.
    shape : (ny, nx)
    opts : `~astroalign_nd.stacking.StackConfig`
    gain, read_noise : float, optional
        For frames without an uncertainty (see `~astroalign_nd.stack`).
    memory_limit : float, optional
        Bytes of working memory (default 512 MB).
    rejected : (n, ny, nx) writable array, optional
        Receives each frame's rejected pixels (True or 1), e.g. a memory
        map on disk: what a drizzle blots back onto the frames.

    Returns
    -------
    value, variance : (ny, nx) float64 ndarray
        NaN where no frame reaches.
    coverage : (ny, nx) int16 ndarray
        Number of frames that reach each pixel (before rejection).
    """
    ny, nx = shape
    value = np.full(shape, np.nan)
    variance = np.full(shape, np.nan)
    coverage = np.zeros(shape, dtype=np.int16)
    weights = np.array([s.weight for s in stats], dtype=float)
    rows = rows_per_strip(len(paths), nx, memory_limit)
    for r0 in range(0, ny, rows):
        r1 = min(ny, r0 + rows)
        # Every frame's normalised values, variance and validity for these rows.
        xs, vs, oks = [], [], []
        for path, st in zip(paths, stats):
            data, var, ok = read_rows(path, r0, r1)
            var = frame_variance(data, var, st, gain, read_noise)
            xs.append(data * st.scale - st.offset)
            vs.append(var * st.scale ** 2)
            oks.append(ok)
        x, var, valid = np.stack(xs), np.stack(vs), np.stack(oks)
        keep = reject(x, var, valid, opts)
        out = valid & ~keep
        for st, n in zip(stats, out.sum(axis=(1, 2))):
            st.n_rejected += int(n)
        if rejected is not None:
            rejected[:, r0:r1] = out
        v, e = combine(x, var, keep, weights, opts, len(paths))
        reach = valid.any(axis=0)
        value[r0:r1] = np.where(reach, v, np.nan)
        variance[r0:r1] = np.where(reach, e, np.nan)
        coverage[r0:r1] = valid.sum(axis=0)
    return value, variance, coverage


def normalise(st, reference_sky, normalize):
    """
    Set a frame's ``offset``/``scale`` so that its sky matches the reference's.

    Parameters
    ----------
    st : `FrameStats`
    reference_sky : float
    normalize : {None, 'offset', 'scale', 'stars'}
        'stars': scaled by the inverse of its ``transparency`` (its stars'
        flux relative to the reference's), then its sky brought to the
        reference's.

    Raises
    ------
    ValueError
        For ``'scale'`` when a sky level is not positive (sky-subtracted
        frames: use ``'offset'``).
    """
    if normalize == "offset":
        st.offset, st.scale = st.sky - reference_sky, 1.0
    elif normalize == "scale":
        if not (st.sky > 0 and reference_sky > 0):
            raise ValueError(f"normalize='scale' needs positive sky levels; this frame's is "
                             f"{st.sky:.4g} and the reference's {reference_sky:.4g} "
                             "(sky-subtracted frames?). Use normalize='offset'.")
        st.offset, st.scale = 0.0, reference_sky / st.sky
    elif normalize == "stars":
        t = st.transparency
        if t is None or not (np.isfinite(t) and t > 0):
            raise ValueError("normalize='stars' needs the frame's transparency from its "
                             "matched stars, which could not be measured; use "
                             "normalize='offset' or 'scale'.")
        st.scale = 1.0 / t
        st.offset = st.sky * st.scale - reference_sky
    else:
        st.offset, st.scale = 0.0, 1.0


def frame_weights(stats, weights, gain, read_noise):
    """
    Each frame's weight: given, or the inverse of its median variance.

    Parameters
    ----------
    stats : list of `FrameStats`
    weights : 'variance', None or sequence of float
    gain, read_noise : float or None

    Raises
    ------
    ValueError
        If given weights are not one finite non-negative value per frame.
    """
    if weights is None:
        w = np.ones(len(stats))
    elif isinstance(weights, str):
        w = []
        # Each frame's typical pixel variance (its median), as frame_variance gives it.
        for st in stats:
            if st.median_variance is not None and st.median_variance > 0:
                typical = st.median_variance
            elif gain is not None:
                rn = 0.0 if read_noise is None else read_noise
                typical = max(st.sky, 0.0) / gain + (rn / gain) ** 2 or 1.0
            else:
                typical = st.noise ** 2 if st.noise > 0 else 1.0
            w.append(1.0 / (typical * st.scale ** 2))
        w = np.array(w)
    else:
        w = np.asarray(weights, dtype=float).ravel()
        if w.size != len(stats) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError(f"weights must be one finite value >= 0 per frame ({len(stats)} "
                             f"frames, the reference included), not all 0; got {weights!r}.")
    for st, wi in zip(stats, w):
        st.weight = float(wi)
