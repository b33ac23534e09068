# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The stars' FWHM, measured from the frame itself."""

import numpy as np
from .._kernels import adaptive_fwhm as _adaptive_fwhm
from .._kernels import median as _median
from .candidates import _as_image, _auto_bin, _binned_candidates, _extract_cutouts, _recenter
from .background import _bin_mean, _local_background, estimate_noise

__all__ = ['estimate_fwhm']


def estimate_fwhm(data, *, mask=None, n_stars=30):
    """
    Estimate the stellar FWHM (pixels) of an image.

    The mode of the second-moment FWHMs of the brightest compact
    candidates found by `find_sources`'s first (binned) detection stage,
    so that nebulosity, galaxies, blends and saturated stars do not move it.

    Parameters
    ----------
    data : 2-D array-like
    mask : 2-D bool array, optional
    n_stars : int, optional
        About a third of the number of bright candidates measured.

    Returns
    -------
    fwhm : float

    Examples
    --------
    >>> from astroalign_nd.detection import estimate_fwhm
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, fwhm=3.0, seed=1)
    >>> fwhm = estimate_fwhm(pair.source)
    >>> bool(abs(fwhm - 3.0) < 0.3)
    True
    """
    data, mask = _as_image(data, mask)
    noise = estimate_noise(data, mask)
    b = _auto_bin(data.shape)
    cand = _binned_candidates(data, mask, b, noise, 5.0, 4 * n_stars)
    if len(cand["x"]) == 0:
        return float("nan")
    cand = _recenter(data, mask, cand, b, None)
    return _estimate_fwhm(data, mask, cand, noise, n_max=max(5 * n_stars, 30)).fwhm


class _FwhmEstimate:
    """An FWHM estimate, whether it deserves a second opinion, and others to try."""

    def __init__(self, fwhm, doubtful, alternatives=(), from_gap=False):
        self.fwhm, self.doubtful = float(fwhm), bool(doubtful)
        self.alternatives = tuple(float(a) for a in alternatives)
        # (`_gap_fwhm`'s: detection checks that the sources measure it too.)
        self.from_gap = bool(from_gap)


def _log_mode(values, width=0.1):
    """
    The densest value of a positive sample, in log space.

    Each value counts its neighbours within ``width`` dex; the value with
    the most (the smaller on ties: stars are more compact than knots of
    nebulosity) is refined to the median of the values within 1.5 widths.
    Returns (mode, fraction of the sample near it).
    """
    lv = np.log10(values)
    near = np.abs(lv[:, None] - lv[None, :]) <= width
    count = near.sum(axis=1)
    best = np.flatnonzero(count == count.max())
    centre = lv[best[np.argmin(lv[best])]]
    close = np.abs(lv - centre) <= 1.5 * width
    return float(10 ** _median(lv[close])), float(close.mean())


def _estimate_fwhm(data, mask, cand, noise=None, n_max=80, half=14, gap=True):
    """
    Stage 2: FWHM from the population of compact candidates.

    The second moments of up to ``n_max`` of the brightest candidates are
    measured; candidates whose cutout leaves the frame or touches masked
    pixels (edges, overscan strips, chip gaps) and saturation plateaus are
    left out, and the *mode* of the rest is taken, so that knots of
    nebulosity, galaxies, blends and bloated bright stars (all wider) and
    hot pixels (narrower) do not move it.  Stars wider than the cutouts
    can measure are measured on a binned copy.  When both a compact and a
    wide population are large (digitised plates: faint stars of a few
    pixels, bright ones of tens), both widths are returned and the scale
    search of `_best_scale` chooses.  With ``gap``, stars a little too
    wide for the cutouts are measured in larger ones first (`_gap_fwhm`).
    """
    fw, ok = _candidate_fwhms(data, mask, cand, n_max, half, noise)
    vals = fw[ok]
    wide = np.isfinite(fw) & (fw >= half / 1.5 - 0.5)
    compact = None
    if vals.size >= 10:
        mode, frac = _log_mode(vals)
        # Cosmic rays and their smeared copies in a resampled frame spread
        # over a range of compact widths that can outnumber the stars; the
        # stars share one width closely.  A much wider cluster that is the
        # denser one at a narrow window (8 candidates at least) is theirs.
        tight, tfrac = _log_mode(vals, 0.03)  # (tfrac: within 0.045 dex of it)
        if (tight > 1.8 * mode and tfrac * vals.size >= 8
                and tfrac > np.mean(np.abs(np.log10(vals / mode)) <= 0.045)):
            mode, frac = tight, float(np.mean(np.abs(np.log10(vals / tight)) <= 0.15))
        if frac >= 0.3 and mode < half / 2.0:
            # Enough compact sources share one width: those are the stars,
            # unless the wide ones are stars too (checked below).
            compact = float(np.clip(mode, 1.0, half / 1.5))
    if wide.sum() >= max(3, 0.5 * max(1, ok.sum() + wide.sum())):
        if compact is None and gap:
            # Stars of 7 to 10 px are too wide for these cutouts, yet
            # compact in cutouts twice as large (their own mode there).
            width = _gap_fwhm(data, mask, cand, noise, n_max, half)
            if width is not None:
                return _FwhmEstimate(width, False, from_gap=True)
        # Digitised plates and defocused frames: measure on a binned copy.
        broad = _wide_fwhm(data, mask, n_max, half)
        if compact is not None:
            # Two populations: only the two widths compete (a ladder would
            # let a width between them win on nebulosity).
            return _FwhmEstimate(compact, False, () if broad is None else (broad,))
        # A few compact candidates beside the wide ones: the wide ones may be
        # galaxies or knots, so let the scale search have a say.
        return _FwhmEstimate(half / 1.5 if broad is None else broad,
                             broad is None or vals.size >= 3)
    if compact is not None:
        return _FwhmEstimate(compact, False)
    if vals.size < 3:
        return _FwhmEstimate(3.0 if vals.size == 0 else np.median(vals), True)
    mode, frac = _log_mode(vals)
    # Too few candidates share one width (or too few to tell): the list is
    # dominated by something other than stars; let the scale search decide.
    doubtful = frac < 0.3 or vals.size < 5 or (vals.size < 8 and frac < 0.6)
    return _FwhmEstimate(np.clip(mode, 1.0, half / 1.5), doubtful)


def _gap_fwhm(data, mask, cand, noise, n_max, half):
    """
    The stars' FWHM when it lies between the compact widths of
    `_estimate_fwhm`'s cutouts (below ``half / 2``) and those measured on
    binned copies (`_wide_fwhm`, from ``_MAX_FULL_RES_FWHM``): the mode of
    the candidates measured in cutouts of ``2 * half``, when most of them
    (at least 5) share it; None otherwise.  Without it such stars (a wide seeing, a target resampled
    to a larger scale) send detection to the scale ladder, whose widest
    trial fits them worse and measures most slowly.
    """
    fw, ok = _candidate_fwhms(data, mask, cand, n_max, 2 * half, noise)
    vals = fw[ok]
    if vals.size < 5:
        return None
    mode, frac = _log_mode(vals)
    if frac >= 0.5 and frac * vals.size >= 5 and half / 2.0 <= mode < _MAX_FULL_RES_FWHM:
        return mode
    return None


def _wide_fwhm(data, mask, n_max, half):
    """FWHM of stars too wide for the cutouts, measured on 4x or 16x binned copies."""
    for k in (4, 16):
        if min(data.shape) // k < 16:
            break
        binned, bmask = _bin_mean(data, mask, k)
        bnoise = estimate_noise(binned, bmask)
        if not (np.isfinite(bnoise) and bnoise > 0):
            break
        bc = _binned_candidates(binned, bmask, 1, bnoise, 5.0, 150)
        if len(bc["x"]) < 3:
            break
        bc = _recenter(binned, bmask, bc, 1, None)
        bfw, bok = _candidate_fwhms(binned, bmask, bc, n_max, half, bnoise)
        bwide = np.isfinite(bfw) & (bfw >= half / 1.5 - 0.5)
        if bok.sum() >= 3 and bwide.sum() < 0.5 * (bok.sum() + bwide.sum()):
            mode, _ = _log_mode(bfw[bok])
            return float(max(mode * k, _MAX_FULL_RES_FWHM))
    return None


def _candidate_fwhms(data, mask, cand, n_max, half, noise=None):
    """FWHM of each of the first ``n_max`` candidates, and which are usable."""
    top = np.arange(min(n_max, len(cand["x"])))
    x, y, bkg = cand["x"][top], cand["y"][top], cand["bkg"][top]
    xc = np.round(x).astype(int)
    yc = np.round(y).astype(int)
    cut, bad = _extract_cutouts(data, mask, xc, yc, half, 0.0)
    # A local sky: any pedestal left would inflate the moments.
    sky = _local_background(cut, bad, 0.75 * half, offset=bkg)
    cut -= sky[:, None, None]  # (in place: the cutouts are this call's own)
    cut -= bkg[:, None, None]
    cut[bad] = 0.0
    fwhm = _adaptive_fwhm(cut, bad, x - xc, y - yc, sigma0=max(1.5, half / 10.0), n_iter=6)
    peak = cut.reshape(len(x), -1).max(axis=1)
    # Hot pixels and cosmic rays give a tiny FWHM; saturated (flat-topped)
    # stars a biased one; cutouts that leave the frame or touch a mask a
    # wrong one (overscan strips, frame edges).
    inner = ~bad[:, half - 3:half + 4, half - 3:half + 4].any(axis=(1, 2))
    ok = np.isfinite(fwhm) & (fwhm > 0.7) & (fwhm < half / 1.5) & inner
    ok &= bad.sum(axis=(1, 2)) / bad[0].size < 0.25  # (np.mean's values, without its casts)
    if ok.sum() >= 3:
        sat = peak >= 0.98 * np.max(peak[ok])
        if (sat & ok).sum() >= 2:  # several equal peaks: a saturation plateau
            ok &= ~sat
    # Bright peaks only, when there are enough: faint candidates are mostly
    # noise peaks, whose width is the noise's correlation length, not the
    # stars'.  The full-resolution peak counts (binning that drops each
    # block's brightest pixel hides undersampled stars).
    if noise is not None and np.isfinite(noise) and noise > 0:
        bright = ok & (peak >= 10.0 * noise)
        if bright.sum() < 10:
            # Sparse or faint: the ten highest peaks above 5 sigma instead.
            top = np.flatnonzero(ok & (peak >= 5.0 * noise))
            top = top[np.argsort(-peak[top], kind="stable")[:10]]
            if top.size > bright.sum():
                bright = np.zeros_like(ok)
                bright[top] = True
        if bright.sum() >= 5:
            ok = bright
    return fwhm, ok


_MAX_FULL_RES_FWHM = 10.0
