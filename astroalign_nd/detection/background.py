# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The sky: noise and background estimates that the detector compares sources with."""

import functools

import numpy as np
from .._kernels import median as _median

__all__ = ['estimate_noise']


def estimate_noise(data, mask=None, *, max_samples=50_000):
    """
    Robust per-pixel noise of an image from neighbouring-pixel differences.

    Differences of adjacent pixels cancel smooth background and gradients;
    the median absolute deviation then ignores stars and hot pixels.

    Parameters
    ----------
    data : 2-D ndarray
    mask : 2-D bool ndarray, optional
        True for pixels to ignore.
    max_samples : int, optional
        Rows are subsampled so that about this many differences are used.

    Returns
    -------
    sigma : float

    Examples
    --------
    The sky of this simulated frame is 100 counts with a read noise of 5
    counts, so the noise is ``sqrt(100 + 5**2)``, about 11.2 counts:

    >>> from astroalign_nd.detection import estimate_noise
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> sigma = estimate_noise(pair.source)
    >>> bool(abs(sigma - 125**0.5) < 1.0)
    True
    """
    ny, nx = data.shape
    step = max(1, (ny * nx) // max_samples)
    rows, mrows = data[::step], None if mask is None else mask[::step]
    sigma, mad = _diff_sigma(rows, mrows, 1)
    if np.isfinite(sigma) and nx > 8:
        # Resampled, drizzled, JPEG-compressed or interpolated frames have
        # correlated noise: neighbouring pixels differ less than the pixels
        # scatter, and the lag-1 figure is too low (too many detections).
        # Differences 3 pixels apart see the full scatter.
        sigma = max(sigma, _diff_sigma(rows, mrows, 3, mad)[0])
    return float(sigma)


def _diff_sigma(rows, mrows, lag, bound=None, min_size=10):
    """
    Robust sigma of one pixel from differences ``lag`` pixels apart, and the
    median absolute deviation it comes from (None when it does not: fewer
    than ``min_size`` differences, or the standard deviation's sigma).

    With ``bound``, a positive median absolute deviation: (0.0, None) when
    this one is proven positive and at most ``bound`` (its sigma at most
    ``bound``'s: a count of the deviations instead of their median).
    """
    with np.errstate(invalid="ignore"):  # inf - inf: filtered just below
        diff = (rows[:, lag:] - rows[:, :-lag]).ravel()
    good = np.isfinite(diff)
    if mrows is not None:
        good &= ~(mrows[:, lag:] | mrows[:, :-lag]).ravel()
    if not good.all():  # (most frames: no copy)
        diff = diff[good]
    if diff.size < min_size:
        return float("nan"), None

    def sorted_median(a):  # the same middle values, and their mean as `_median` takes it
        srt, k = np.sort(a), a.size // 2
        return srt[k] if a.size % 2 else (srt[k - 1] + srt[k]) / 2

    # Many equal differences (flat or quantised skies): NumPy's partition
    # slows down on ties (several times), its sort does not.
    median = sorted_median if np.count_nonzero(diff == 0) > 0.15 * diff.size else _median
    med = median(diff)
    dev = diff - med
    dev = np.abs(dev, out=dev)
    k = dev.size // 2
    if bound is not None and np.count_nonzero(dev <= bound) > k and np.count_nonzero(dev == 0) < k:
        return 0.0, None  # (more than half the deviations at most bound, fewer than half 0)
    mad = median(dev)
    sigma = 1.4826 * mad / np.sqrt(2.0)
    if sigma <= 0:
        # Quantised or noiseless images: fall back to the standard deviation.
        return float(np.std(diff) / np.sqrt(2.0)), None
    return float(sigma), mad


@functools.lru_cache(maxsize=32)
def _interp_weights(n_out, n_blocks, block):
    """
    Bilinear weights from block centres to pixels: for each output pixel,
    the lower block ``k`` and the weights of blocks ``k`` and ``k + 1``
    (read-only: kept for the next frame of this size).
    """
    if n_blocks == 1:
        out = np.zeros(n_out, int), np.ones(n_out), np.zeros(n_out)
    else:
        centres = (np.arange(n_blocks) + 0.5) * block - 0.5
        # Beyond the outer block centres the sky is extrapolated linearly, so
        # that a steep gradient leaves no ramp along the frame's edges.
        pos = np.arange(n_out, dtype=float)
        k = np.clip(np.searchsorted(centres, pos, side="right") - 1, 0, n_blocks - 2)
        f = (pos - centres[k]) / (centres[k + 1] - centres[k])
        out = k, 1.0 - f, f
    for a in out:
        a.setflags(write=False)
    return out


def _background_map(binned, box):
    """
    Coarse block-median background, bilinearly expanded to ``binned``.

    Medians of ``box`` x ``box`` blocks follow gradients while ignoring
    stars; the expansion is separable, two blocks per pixel along each axis.
    """
    ny, nx = binned.shape
    by, bx = max(1, ny // box), max(1, nx // box)
    cy, cx = ny // by, nx // bx
    blocks = binned[: by * cy, : bx * cx].reshape(by, cy, bx, cx)
    blocks = np.moveaxis(blocks, 2, 1).reshape(by, bx, cy * cx)
    bkg = _median(blocks, axis=2)
    ky, wy0, wy1 = _interp_weights(ny, by, cy)
    kx, wx0, wx1 = _interp_weights(nx, bx, cx)
    # Two products per pixel (not matrix products: those wake OpenBLAS's
    # threads, which then spin and take the cores from the compiled kernels
    # that follow).
    b64 = bkg.astype(float)
    if by == 1:
        rows = np.broadcast_to(b64[0], (ny, bx))
    else:
        rows = wy0[:, None] * b64[ky] + wy1[:, None] * b64[ky + 1]
    if bx == 1:
        return np.broadcast_to(rows[:, :1], (ny, nx)).astype(np.float32), bkg
    # Column by column of blocks (the columns between two block centres):
    # the sum in float64 cast once to float32, without full-frame float64
    # temporaries.
    full = np.empty((ny, nx), np.float32)
    cuts = np.searchsorted(kx, np.arange(1, bx - 1)).tolist()
    for j, (c0, c1) in enumerate(zip([0] + cuts, cuts + [nx])):
        c = slice(c0, c1)
        np.add(rows[:, j, None] * wx0[c], rows[:, j + 1, None] * wx1[c], out=full[:, c])
    return full, bkg


def _local_background(cut, bad, r_in, offset=None):
    """
    Median of each cutout's good pixels at least ``r_in`` from its centre
    (0 for none; less ``offset``, one value per cutout, when given:
    ``cut - offset`` is not formed for the pixels the median does not
    read), `_median`'s (and `_median_of_good`'s), bit for bit.
    """
    n, size, _ = cut.shape
    g = np.arange(size) - size // 2
    outer = (g[:, None] ** 2 + g[None, :] ** 2) >= r_in**2
    sel = outer.ravel()
    vals = cut.reshape(n, -1)[:, sel]
    m = vals.shape[1]

    def badv(rows):  # the bad pixels among these cutouts' values
        return bad.reshape(n, -1)[rows][:, sel]

    # (the bad pixels of the few cutouts with any: at edges or masks)
    edge = np.flatnonzero(bad.reshape(n, -1).any(axis=1))
    n_good = np.full(n, m)
    n_good[edge] -= np.count_nonzero(badv(edge), axis=1)
    v32 = vals.astype(np.float32)
    if (vals.dtype == np.float64 and np.array_equal(v32, vals) and np.isfinite(v32).all()
            and (offset is None or np.isfinite(offset).all())):
        # Pixels of a float32 image (most frames): the middle values of
        # each row from one float32 sort (faster than a float64 partition
        # and its lower half's maximum), bad pixels last; less the offset,
        # the middle values of ``vals - offset`` (a shift keeps the order).
        if edge.size:
            v32[edge] = np.where(badv(edge), np.inf, v32[edge])
        v32.sort(axis=1)
        k, rows = n_good // 2, np.arange(n)
        hi = v32[rows, k.clip(max=m - 1)].astype(float)
        lo = v32[rows, (k - 1).clip(min=0)].astype(float)
        if offset is not None:
            hi, lo = hi - offset, lo - offset
        # (lo + hi) / 2 in float64, as `_median` (np.mean of the two).
        bkg = np.where(n_good % 2 == 1, hi, (lo + hi) / 2)
        bkg[n_good == 0] = 0.0
        # Which zero (+0 or -0) a partition leaves in the middle is its own.
        again = np.flatnonzero(((lo == 0) | (hi == 0)) & (n_good > 0))
    else:
        again = np.arange(n)
        bkg = np.empty(n, vals.dtype if offset is None else np.result_type(vals, offset))
    if again.size:
        whole, part = again[n_good[again] == m], again[n_good[again] < m]
        for rows, med in ((whole, lambda v, b: _median(v, axis=1)), (part, _median_of_good)):
            if rows.size:
                bkg[rows] = med(vals[rows] if offset is None else vals[rows] - offset[rows, None],
                                badv(rows))
    return bkg


def _median_of_good(vals, bad):
    """
    Each row's median of its good values (0 for none): ``_median`` of each
    row's good values, np.median's, bit for bit, from one sort of every row.
    """
    def one_by_one(rows):
        return [_median(vals[i][~bad[i]]) if n_good[i] else 0.0 for i in rows]

    n_good = vals.shape[1] - bad.sum(axis=1)
    if not np.isfinite(vals[~bad]).all():  # (NaN is the median of a row with one)
        return np.array(one_by_one(range(len(vals))), vals.dtype)
    # Bad values sort last: the good ones are each row's first.
    srt = np.sort(np.where(bad, np.inf, vals), axis=1)
    rows = np.arange(len(vals))
    k = n_good // 2
    hi = srt[rows, k.clip(max=vals.shape[1] - 1)]
    lo = srt[rows, (k - 1).clip(min=0)]
    # (lo + hi) / 2 in the array's type, as `_median` (np.mean of the two).
    out = np.where(n_good % 2 == 1, hi, (lo + hi) / 2)
    out[n_good == 0] = 0.0
    # Which zero (+0 or -0) a partition leaves in the middle is its own.
    zero = np.flatnonzero(((hi == 0) | (lo == 0)) & (n_good > 0))
    if zero.size:
        out[zero] = one_by_one(zero)
    return out


def _bin_mean(data, mask, k):
    """k x k mean-binned copy; a block with a masked or NaN pixel is masked."""
    ny, nx = (data.shape[0] // k) * k, (data.shape[1] // k) * k
    work = data[:ny, :nx]
    if mask is not None:
        work = np.where(mask[:ny, :nx], np.nan, work)
    binned = work.reshape(ny // k, k, nx // k, k).mean(axis=(1, 3), dtype=np.float64)
    bmask = ~np.isfinite(binned)
    return binned, (bmask if bmask.any() else None)


#: A matched filter's noise this many times the white-noise figure counts
#: (below it the frame is taken as white: resampling leaves more).
_MIN_CORRELATION = 1.08


def _correlated_noise_factor(data, mask, noise, k=2, max_side=256):
    """
    How much more noise a sum over ``k`` x ``k`` pixels has than white noise
    of the per-pixel ``noise`` would give (1 for white noise).

    Resampled, drizzled or interpolated frames have positively correlated
    noise: a matched filter (a weighted sum) sees more noise than the
    per-pixel figure says, and its signal-to-noise is overestimated (noise
    peaks pass the threshold in numbers).  Measured on a central crop of at
    most ``max_side`` pixels, from differences of neighbouring block sums
    (which cancel gradients); 1.0 unless above `_MIN_CORRELATION`.
    """
    ny, nx = data.shape
    y0, x0 = max(0, (ny - max_side) // 2), max(0, (nx - max_side) // 2)
    crop = np.asarray(data[y0:y0 + max_side, x0:x0 + max_side], dtype=np.float32)
    if mask is not None:  # (a NaN or infinite pixel's block differences are dropped below)
        bad = ~np.isfinite(crop) | mask[y0:y0 + max_side, x0:x0 + max_side]
        if bad.any():
            crop = np.where(bad, np.nan, crop)
    cy, cx = (crop.shape[0] // k) * k, (crop.shape[1] // k) * k
    if cy < 8 * k or cx < 8 * k or not (np.isfinite(noise) and noise > 0):
        return 1.0
    crop = crop[:cy, :cx]
    with np.errstate(invalid="ignore"):  # (inf - inf: dropped below)
        if k == 2 and crop.strides[1] == crop.itemsize and crop.strides[0] >= cx * crop.itemsize:
            # The sums NumPy's reduction over axes (1, 3) gives for rows laid out
            # so (each row's pair, then the two rows: the same values), without
            # its slow casting reduction (7x), nor a float64 copy of the crop.
            blocks = np.add(crop[0::2, 0::2], crop[0::2, 1::2], dtype=np.float64)
            blocks += np.add(crop[1::2, 0::2], crop[1::2, 1::2], dtype=np.float64)
        else:
            blocks = crop.reshape(cy // k, k, cx // k, k).sum(axis=(1, 3), dtype=np.float64)
    # The sigma of differences of neighbouring block sums (none: too few, or
    # a median absolute deviation of 0).
    sigma, mad = _diff_sigma(blocks, None, 1, min_size=50)
    if mad is None:
        return 1.0
    factor = float(sigma / (k * noise))
    return factor if factor > _MIN_CORRELATION else 1.0
