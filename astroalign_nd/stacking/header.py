# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The header of a stack (every frame used and every frame rejected, and why), and the
stack as a CCDData: one builder for `~astroalign_nd.stack` and the live stack alike.
"""

from __future__ import annotations

import numpy as np
from astropy.io import fits
from astropy.nddata import CCDData, StdDevUncertainty

from ..exceptions import warn
from ..io.header import fits_text, header_from_meta, header_without_wcs

__all__ = ["stack_header", "stack_ccddata", "MAX_LISTED"]

#: Structural cards of the reference's file: the stack's own are written with its data.
_STRUCTURAL = ("SIMPLE", "BITPIX", "NAXIS", "NAXIS1", "NAXIS2", "NAXIS3", "EXTEND", "BZERO",
               "BSCALE", "BLANK", "DATAMIN", "DATAMAX", "NCOMBINE", "NREJECT")
_LISTS = ("IMCMB", "AASKY", "AASCL", "AAWGT", "AANRJ", "AAREJ", "AAFWH", "AAELG", "AATRN",
          "AANOI")
#: A frame's measures as taken (`~astroalign_nd.frame_quality`): keyword prefix, comment.
_MEASURES = (("fwhm", "AAFWH", "median star FWHM, pixels"),
             ("elongation", "AAELG", "median star elongation"),
             ("transparency", "AATRN", "transparency, stars vs reference"),
             ("sky_noise", "AANOI", "sky noise per pixel as taken"))

#: Frames listed with numbered keywords (``IMCMB001``...); beyond, in HISTORY only.
MAX_LISTED = 999


def stack_header(meta, used, rejected, settings):
    """
    The header of a stack.

    Parameters
    ----------
    meta : dict-like
        The reference's header (its WCS cards are dropped: the stack's WCS
        is written from its ``wcs``).
    used : list of dict
        One per frame combined: ``name``, and optionally ``offset``,
        ``scale``, ``weight``, ``n_rejected`` and ``quality`` (a dict of
        its ``fwhm``, ``elongation``, ``transparency`` and ``sky_noise``).
    rejected : list of (str, str)
        ``(name, reason)`` of each frame left out.
    settings : dict
        ``{keyword: (value, comment)}`` of the combination's settings.

    Returns
    -------
    header : `~astropy.io.fits.Header`
        ``NCOMBINE``, ``NREJECT``, ``IMCMBnnn`` (each frame used),
        ``AAREJnnn`` (``'name: reason'`` of each frame left out) and the
        settings, with HISTORY lines saying the same.

    Examples
    --------
    >>> from astroalign_nd.stacking.header import stack_header
    >>> h = stack_header({}, [{"name": "a.fits"}, {"name": "b.fits"}],
    ...                  [("c.fits", "TooFewSourcesError: 2 stars")], {})
    >>> h["NCOMBINE"], h["IMCMB002"], h["AAREJ001"]
    (2, 'b.fits', 'c.fits: TooFewSourcesError: 2 stars')
    """
    header = header_without_wcs(header_from_meta(meta))
    # A stack of stacks: the old lists are not this one's; nor the file's structure.
    for key in [k for k in header.keys() if k.startswith(_LISTS) or k in _STRUCTURAL]:
        del header[key]
    header["NCOMBINE"] = (len(used), "number of frames combined")
    header["NREJECT"] = (len(rejected), "number of frames left out")
    for key, (value, comment) in settings.items():
        header[key] = (value, comment)
    # IMCMBnnn (IRAF's name of a combined frame), its normalisation and weight.
    for k, frame in enumerate(used, start=1):
        # A file name may hold what a card cannot (non-ASCII characters).
        name = fits_text(frame["name"])
        if len(used) > MAX_LISTED:
            header.add_history(f"stacked: {name}")
            continue
        header[f"IMCMB{k:03d}"] = (name, "frame combined")
        if "offset" in frame:
            header[f"AASKY{k:03d}"] = (round(float(frame["offset"]), 6),
                                       "sky offset subtracted")
            header[f"AASCL{k:03d}"] = (round(float(frame["scale"]), 8), "scale applied")
        if "weight" in frame:
            header[f"AAWGT{k:03d}"] = (float(f"{frame['weight']:.6g}"), "relative weight")
        if "n_rejected" in frame:
            header[f"AANRJ{k:03d}"] = (int(frame["n_rejected"]), "pixels rejected")
        for key, prefix, comment in _MEASURES:
            value = (frame.get("quality") or {}).get(key)
            if value is not None and np.isfinite(value):
                header[f"{prefix}{k:03d}"] = (float(f"{value:.5g}"), comment)
    for k, (name, reason) in enumerate(rejected, start=1):
        name, reason = fits_text(name), fits_text(reason)
        if len(rejected) <= MAX_LISTED:
            header[f"AAREJ{k:03d}"] = (f"{name}: {reason}", "frame left out: why")
        header.add_history(f"left out {name}: {reason}")
    return fits.Header(header)


def stack_ccddata(value, variance, coverage, *, meta, names, stats, rejected, settings, wcs,
                  unit, dtype=np.float32):
    """
    A stack as a CCDData: data, uncertainty, mask, coverage and header.

    Parameters
    ----------
    value, variance : `~numpy.ndarray`
        The combined value of each pixel and its variance.
    coverage : `~numpy.ndarray` of int
        The frames reaching each pixel (``flags``); the mask is where none does.
    meta : dict-like
        The reference's header (see `stack_header`).
    names : list of str
        The name of each frame combined.
    stats : list of `~astroalign_nd.stacking.combine.FrameStats`
        Their sky offset, scale, weight, pixels rejected and unit conversion.
    rejected : list of (str, str)
        ``(name, reason)`` of each frame left out.
    settings : dict
        ``{keyword: (value, comment)}`` of the combination's settings.
    wcs : `~astropy.wcs.WCS` or None
        The stack's WCS.
    unit : `~astropy.units.Unit` or str
        The stack's unit.
    dtype : numpy dtype, optional
        Of the data and the uncertainty (an integer type gets them rounded
        and clipped to its range, with a warning).

    Returns
    -------
    stacked : `~astropy.nddata.CCDData`
    """
    used = [dict(name=n, offset=st.offset, scale=st.scale, weight=st.weight,
                 n_rejected=st.n_rejected, quality=st.quality) for n, st in zip(names, stats)]
    header = stack_header(meta, used, rejected, settings)
    for n, st in zip(names, stats):
        if st.converted:
            header.add_history(f"astroalign_nd stack: {fits_text(n)} {st.converted}")
    with np.errstate(invalid="ignore"):
        std = np.sqrt(variance)
    return CCDData(_as_dtype(value, dtype, "value"), unit=unit, mask=coverage == 0,
                   uncertainty=StdDevUncertainty(_as_dtype(std, dtype, "uncertainty")),
                   flags=coverage, wcs=wcs, meta=header)


def _as_dtype(values, dtype, what):
    """
    ``values`` as ``dtype``; an integer type gets them rounded, and clipped to its range
    with a warning that counts the pixels (a cast alone would wrap them around).  Pixels
    without a value (no frame reaches them; the mask marks them) are 0.
    """
    dt = np.dtype(dtype)
    if dt.kind == "f":
        return values.astype(dt)
    info = np.iinfo(dt)
    rounded = np.rint(values)
    finite = np.isfinite(rounded)
    outside = finite & ((rounded < info.min) | (rounded > info.max))
    n_outside = int(outside.sum())
    if n_outside:
        warn(f"{n_outside} pixels of the stack's {what} lie outside the range of {dt} "
             f"({info.min} to {info.max}) and were clipped to it; pass dtype=np.float32 "
             "(the default) to keep them.")
    return np.clip(np.where(finite, rounded, 0), info.min, info.max).astype(dt)
