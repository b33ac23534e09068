# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Colour (Bayer) frames, stacked straight from the camera.

Each raw frame is registered on its grey version (each colour scaled to
green's response to starlight, `~astroalign_nd.io.bayer.balanced_grey`),
so a colour frame registers like a grey one, in raw pixels, and all its
colours share one transform.  Then each frame is demosaiced (``colour-demosaicing``, the
``[colour]`` extra) and each colour is registered and combined as
`~astroalign_nd.stack` combines grey frames (sky normalisation, rejection,
weights, the combined uncertainty, within ``memory_limit``), or each
colour's raw pixels are drizzled (`drizzle_bayer`) after the stack's
rejection on the frames' grey versions.

The stack is an RGB `~astropy.nddata.CCDData` cube ``(3, ny, nx)``
(red, green, blue planes) with an uncertainty, mask and coverage per
plane, which `~astropy.nddata.CCDData.read`, ccdproc and FITS viewers read
as a three-plane colour image.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import time
import warnings

import numpy as np
from astropy.nddata import CCDData, StdDevUncertainty
from scipy import ndimage

from ..batch.results import FrameResult
from ..detection.options import DetectionConfig
from ..io.read import parse_input
from ..exceptions import AstroalignError
from ..io import write_ccddata
from ..io.header import fits_text, header_from_meta
from ..io.write import interrupts_held
from ..io.bayer import (balanced_grey, bayer_channels, bayer_pattern, superpixel,
                        superpixel_to_raw)
from ..registration import Reference, find_transform
from ..resample import apply_transform
from .combine import (STAR_TOLERANCE_FLOOR, array_stats, combine_files, frame_stats,
                      frame_variance, frame_weights, normalise, star_tolerance)
from .drizzle import DrizzleAccumulator, blot_mask, output_shape, pixel_map, weight_map
from .header import stack_ccddata, stack_header
from .options import DEMOSAIC_METHODS

__all__ = ["find_bayer_transform", "GREY_VERSIONS", "demosaic",
           "register_bayer",
           "drizzle_bayer",
           "colour_ccddata"]

#: The options of a frame's detection (the others are the matching's).
_DETECTION_KEYS = tuple(f.name for f in dataclasses.fields(DetectionConfig))

#: A raw colour frame's keywords that no longer describe the stack (it is not a mosaic).
_BAYER_KEYS = ("BAYERPAT", "XBAYROFF", "YBAYROFF", "ROWORDER")


def _demosaicing():
    printing = np.get_printoptions()
    try:
        with warnings.catch_warnings():  # its own imports of deprecated scipy namespaces
            warnings.simplefilter("ignore", DeprecationWarning)
            import colour_demosaicing
    except ImportError:
        raise ImportError("demosaicing colour (Bayer) frames needs colour-demosaicing: pip "
                          "install \"astroalign_nd[colour]\" (or pip install "
                          "colour-demosaicing).") from None
    finally:
        # Importing it (colour-science) sets numpy's printing to its 1.13 style for everyone.
        np.set_printoptions(**printing)
    return colour_demosaicing


def demosaic(data, pattern, method="Menon2007", mask=None):
    """
    Demosaic a raw colour frame with ``colour-demosaicing``.

    Parameters
    ----------
    data : 2-D array
        The raw frame.
    pattern : str
        The pattern of its first 2x2 cell
        (`~astroalign_nd.io.bayer.bayer_pattern`).
    method : {'Menon2007', 'Malvar2004', 'bilinear'}, optional
        ``colour-demosaicing``'s algorithm (default 'Menon2007', DDFAPD).
    mask : 2-D bool array, optional
        Bad raw pixels (NaN ones are added).  They are filled from their
        colour's neighbours before demosaicing, and every output pixel
        within one pixel of one is masked (each is interpolated from its
        neighbours).

    Returns
    -------
    rgb : (ny, nx, 3) float32 ndarray
        Red, green and blue.
    mask : (ny, nx) bool ndarray

    Raises
    ------
    ImportError
        Without ``colour-demosaicing`` (the ``[colour]`` extra).

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.stacking.colour import demosaic
    >>> raw = np.tile([[2.0, 4.0], [1.0, 2.0]], (4, 4))  # GRBG: R 4, G 2, B 1
    >>> rgb, _ = demosaic(raw, "GRBG", method="bilinear")
    >>> rgb[3, 3].tolist()
    [4.0, 2.0, 1.0]
    """
    if method not in DEMOSAIC_METHODS:
        raise ValueError(f"demosaic must be one of {', '.join(map(repr, DEMOSAIC_METHODS))}; "
                         f"got {method!r}.")
    cd = _demosaicing()
    raw = np.array(data, dtype=np.float64)
    bad = ~np.isfinite(raw) if mask is None else (np.asarray(mask, bool) | ~np.isfinite(raw))
    if bad.any():
        raw = _fill_bad(raw, bad)
    fn = {"Menon2007": cd.demosaicing_CFA_Bayer_Menon2007,
          "Malvar2004": cd.demosaicing_CFA_Bayer_Malvar2004,
          "bilinear": cd.demosaicing_CFA_Bayer_bilinear}[method]
    rgb = np.asarray(fn(raw, pattern), dtype=np.float32)
    return rgb, ndimage.binary_dilation(bad, np.ones((3, 3), bool)) if bad.any() else bad


def _fill_bad(raw, bad):
    """Bad pixels set to the median of the good ones of their colour (two pixels away)."""
    out = raw.copy()
    for dy in (0, 1):
        for dx in (0, 1):
            plane, b = out[dy::2, dx::2], bad[dy::2, dx::2]
            if b.all():
                plane[...] = 0.0
                continue
            good = np.where(b, np.nan, plane)
            filled = ndimage.generic_filter(good, np.nanmedian, size=3, mode="nearest") \
                if b.sum() < 1e4 else np.full_like(plane, np.nanmedian(good))
            plane[b] = np.where(np.isfinite(filled[b]), filled[b], np.nanmedian(good))
    return out


def _raw_frame(item, bayer, hdu, unit, name):
    """A frame read as a raw colour frame: its ParsedInput and the pattern of its first cell."""
    p = parse_input(item, name, hdu=hdu, unit=unit)
    if p.data is None or p.data.ndim != 2:
        shape = None if p.data is None else p.data.shape
        raise ValueError(f"{name} is not a raw colour frame: a Bayer frame is a 2-D image "
                         f"(got {'a catalog' if shape is None else f'shape {shape}'}); "
                         "leave bayer=None for frames that are already in colour or grey.")
    given = None if bayer == "auto" else bayer
    return p, bayer_pattern(p.meta, given, shape=p.data.shape)


#: The grey versions of a raw frame that it can be registered on.
GREY_VERSIONS = ("balanced", "superpixel")


def _grey(p, pattern, grey="balanced"):
    """A raw frame's grey version, as a CCDData (and the transform's conversion to raw)."""
    if grey == "superpixel":
        data, mask = superpixel(p.data, p.mask)
        return CCDData(data, unit=p.unit or "adu", mask=mask), superpixel_to_raw
    return (CCDData(balanced_grey(p.data, pattern, p.mask), unit=p.unit or "adu",
                    mask=p.mask), lambda t: t)


def _registered_planes(p, pattern, transform, shape, method, order, folder, stem, resampling):
    """
    A frame demosaiced, its planes resampled onto the reference grid with its one
    transform and written to ``folder``: the three paths.
    """
    rgb, bad = demosaic(p.data, pattern, method, p.mask)
    frame = CCDData(rgb, unit=p.unit or "adu",
                    mask=np.repeat(bad[..., None], 3, axis=2) if bad.any() else None)
    if transform is not None:
        frame = apply_transform(transform, frame, shape, order=order, add_keyword=False,
                                **resampling)
    paths = []
    for c in range(3):
        path = os.path.join(folder, f"{stem}_{'RGB'[c]}.fits")
        mask = None if frame.mask is None else frame.mask[..., c]
        write_ccddata(CCDData(frame.data[..., c], unit=frame.unit, mask=mask), path,
                      overwrite=True)
        paths.append(path)
    return paths


def find_bayer_transform(source, target, *, bayer="auto", grey="balanced", hdu=None, unit=None,
                         **options):
    """
    The transform of a raw colour frame onto another, in raw pixels.

    Both frames are registered on their grey versions, as grey frames are:
    one transform for all the colours of the frame.

    Parameters
    ----------
    source, target : path, array-like or `~astropy.nddata.NDData`
        Raw colour frames (2-D).
    bayer : str, optional
        'auto' (each frame's ``BAYERPAT``; default) or the pattern of the
        frames' first 2x2 cell.
    grey : {'balanced', 'superpixel'}, optional
        The grey version: 'balanced' (default) each colour scaled to green's
        response at full resolution (`~astroalign_nd.io.bayer.balanced_grey`);
        'superpixel' each 2x2 cell summed (`~astroalign_nd.io.bayer.superpixel`,
        a quarter of the pixels), the transform then converted to raw pixels
        (`~astroalign_nd.io.bayer.superpixel_to_raw`).  On undersampled
        stars (2.2 raw px) the balanced version is about ten times as
        precise (0.01 against 0.1 to 0.6 px on simulated frames): the
        superpixels halve a sampling that is already too coarse.
    hdu, unit
        As in `~astroalign_nd.find_transform`.
    **options
        `~astroalign_nd.find_transform`'s options (``transform_type``...).

    Returns
    -------
    transform : `~astroalign_nd.transforms.LinearTransform2D` or model
        Source raw pixels -> target raw pixels.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import bayer_mosaic, dither_transforms, simulate_views
    >>> from astroalign_nd.stacking.colour import find_bayer_transform
    >>> views = simulate_views(dither_transforms(2, max_shift=5, shape=(160, 160), seed=1),
    ...                        (160, 160), n_stars=80, fwhm=2.5, seed=2)
    >>> raw = [bayer_mosaic(f, "GRBG") for f in views.frames]
    >>> t = find_bayer_transform(raw[1], raw[0])
    >>> bool(np.abs(t.matrix - views.truth(1, 0).matrix).max() < 0.3)
    True
    """
    if grey not in GREY_VERSIONS:
        raise ValueError(f"grey must be one of {', '.join(map(repr, GREY_VERSIONS))}; got "
                         f"{grey!r}.")
    src, src_pattern = _raw_frame(source, bayer, hdu, unit, "source")
    dst, dst_pattern = _raw_frame(target, bayer, hdu, unit, "target")
    (src_grey, to_raw), (dst_grey, _) = _grey(src, src_pattern, grey), _grey(dst, dst_pattern,
                                                                             grey)
    t, _ = find_transform(src_grey, dst_grey, **options)
    return to_raw(t)


def _find_raw_transforms(others, ref, ref_pattern, bayer, hdu, unit, options, callback=None,
                         fwhms=None):
    """
    Each frame's transform onto the reference, found on grey versions, in raw pixels.

    Yields ``(index, label, ParsedInput, pattern, transform, error)`` one frame at a
    time (its ParsedInput, pattern and transform None when it failed, and the error
    then says why), after giving ``callback`` its `~astroalign_nd.batch.FrameResult`.
    ``fwhms``, a dict, gets the stars' FWHM (grey pixels) that each frame's detection
    used, by index (the reference's by None), as it is found.
    """
    # Each frame's detection, as `find_transform` would make it (the user's
    # detection options on both sides), kept for its FWHM.
    detect = {k: v for k, v in options.items() if k in _DETECTION_KEYS}
    target = Reference(_grey(ref, ref_pattern)[0], _role="target", **detect)
    for (item, label), k in others:
        start = time.perf_counter()
        try:
            p, pattern = _raw_frame(item, bayer, hdu, unit, label or f"frame{k}")
            source = Reference(_grey(p, pattern)[0], _role="source", **detect)
            t, _ = find_transform(source, target, **options)
            if fwhms is not None:
                fwhms[k], fwhms[None] = source.fwhm, target.fwhm
        except (AstroalignError, ValueError, OSError) as exc:
            p = pattern = t = None
            error = f"{type(exc).__name__}: {exc}"
        else:
            error = None
        if callback is not None:
            callback(FrameResult(name=os.path.basename(label) if label else f"frame{k}",
                                 status="failed" if error else "registered", transform=t,
                                 error=error, seconds=time.perf_counter() - start))
        yield k, label, p, pattern, t, error


def register_bayer(ref_item, others, folder, *, bayer, method, hdu, unit, order, options,
                   resampling=None, callback=None):
    """
    Raw colour frames registered on their grey versions, demosaiced, and their
    colours resampled onto the reference's grid with each frame's one transform.

    One frame at a time: each is read, registered, demosaiced and written as three
    files (red, green, blue) in ``folder``.

    Parameters
    ----------
    ref_item : (frame, index, label)
        The reference, as `~astroalign_nd.stack` splits it from the frames.
    others : list of ((frame, label), index)
        The other frames.
    folder : str
    bayer : str
        'auto' (each frame's ``BAYERPAT``...) or the pattern of every frame's
        first 2x2 cell.
    method : str
        The demosaicing method (``astroalign_nd.stacking.options.DEMOSAIC_METHODS``).
    hdu, unit, order
        As in `~astroalign_nd.stack`.
    options : dict
        Registration options (``transform_type``, detection and matching).
    resampling : dict, optional
        `~astroalign_nd.apply_transform`'s ``conserve_flux`` and ``fill_value``.
    callback : callable, optional
        As in `~astroalign_nd.stack`.

    Returns
    -------
    channels : list of 3 lists of (name, path, index)
        For each colour, the reference's plane first, then every frame
        registered.
    rejected : list of (name, reason)
        The frames left out, and why.
    reference : ``ParsedInput``
        The reference as read.
    pattern : str
        The reference's pattern.
    """
    ref_name = ref_item[2] or "reference"
    ref, pattern = _raw_frame(ref_item[0], bayer, hdu, unit, ref_name)
    shape = ref.data.shape
    resampling = resampling or {}
    planes = _registered_planes(ref, pattern, None, shape, method, order, folder, "reference",
                                resampling)
    channels = [[(f"{os.path.basename(ref_name)} (reference)", path, ref_item[1])]
                for path in planes]
    rejected, done = [], 0
    found = _find_raw_transforms(others, ref, pattern, bayer, hdu, unit, options, callback)
    try:
        for k, label, p, pat, transform, error in found:
            name = os.path.basename(label) if label else f"frame{k}"
            if error is not None:
                rejected.append((name, error))
            else:
                planes = _registered_planes(p, pat, transform, shape, method, order, folder,
                                            f"frame{k:05d}", resampling)
                for c, path in enumerate(planes):
                    channels[c].append((name, path, k))
            done += 1
    except KeyboardInterrupt as exc:
        # Ctrl-C (SIGTERM on the command line): the frames registered so far can be stacked
        # (a frame stopped between its colours is left out of all three).
        for ch in channels:
            del ch[min(len(c) for c in channels):]
        exc.not_registered = len(others) - done
        exc.partial_result = channels, rejected, ref, pattern
        raise
    return channels, rejected, ref, pattern


def drizzle_bayer(ref_item, others, *, bayer, scale, pixfrac, kernel, normalize, weights,
                  gain, read_noise, hdu, unit, options, saturation=None, callback=None,
                  reject=None, folder=None, order="bilinear"):
    """
    Bayer drizzle: each colour's raw pixels dropped at their true positions.

    Each frame is registered on its grey version (as `register_bayer` does),
    its colours' skies brought to the reference's (``normalize``), and each
    colour drizzled (``astroalign_nd.stacking.drizzle``)
    with the frame's one pixel map and a weight map that is zero on the
    other colours' pixels: no demosaicing, no interpolation.  With
    ``reject``, the outliers (cosmic rays, trails, hot pixels) are found
    first as `~astroalign_nd.stack` finds them: the frames' grey versions
    are resampled onto the reference's grid (files in ``folder``) and
    combined with the stack's clipping; each frame's rejected pixels are
    carried back onto its raw pixels (`~astroalign_nd.stacking.drizzle.blot_mask`)
    and weigh nothing in any colour.  One frame in memory at a time.

    Parameters
    ----------
    ref_item, others, bayer, hdu, unit, options
        As in `register_bayer`.
    scale, pixfrac, kernel
        Drizzle's output scale, drop size and kernel.
    normalize : {'offset', 'scale', None}
        As in `~astroalign_nd.stack`, per colour.
    weights : 'variance', None or (n_frames,) ndarray
        As in `~astroalign_nd.stack` (per frame; 'variance' per colour).
    gain, read_noise : float or None
        The frames' variance model (else each colour's measured sky noise).
    saturation : float, optional
        Raw values at or above weigh nothing.
    reject : `~astroalign_nd.stacking.StackConfig`, optional
        The stack's options whose clipping (``clip``...) finds the outliers
        (default None: no rejection); a ``star_tolerance`` of None is derived, as
        `~astroalign_nd.stack` derives it, from the stars' FWHMs that the
        grey versions' detection found.
    folder : str, optional
        With ``reject``: where the grey versions on the reference's grid go.
    order : str or int, optional
        With ``reject``: their resampling's interpolation.

    Returns
    -------
    channels : list of 3 tuples
        ``(value, variance, coverage, names, stats)`` for red, green, blue,
        as `colour_ccddata` takes them (counts per output pixel; each
        colour's stats count its raw pixels rejected).
    rejected : list of (name, reason)
    reference : ``ParsedInput``
    pattern : str
    """
    def planes():  # (value, variance, coverage, names, stats) of each colour
        return [(pl.value, pl.variance, pl.count, names, st)
                for pl, st in zip((acc.planes() for acc in accs), stats)]

    ref_name = ref_item[2] or "reference"
    ref, pattern = _raw_frame(ref_item[0], bayer, hdu, unit, ref_name)
    shape = ref.data.shape
    out_shape = output_shape(shape, scale)
    accs = [DrizzleAccumulator(out_shape, scale, pixfrac, kernel) for _ in range(3)]
    names, stats, rejected, fwhms = [], [[], [], []], [], {}
    frames = itertools.chain([(0, ref_item[2], ref, pattern, None, None)],
                             _find_raw_transforms(others, ref, pattern, bayer, hdu, unit,
                                                  options, callback, fwhms))
    interrupt = None
    if reject is not None:
        try:  # the outliers first: each frame's rejection map on the reference's grid
            frames, interrupt = _outliers(frames, shape, reject, folder, order, fwhms), None
        except KeyboardInterrupt as exc:  # the frames registered so far are drizzled
            frames, interrupt = exc.partial_result, exc
        items = {k: item for (item, _), k in others}
        # Each frame read again, its rejected pixels blotted back onto it.
        frames = ((k, label, ref if transform is None else _raw_frame(
            items[k], bayer, hdu, unit, label or f"frame{k}")[0], pat, transform, error,
            None if flags is None else blot_mask(flags, pixel_map(transform, shape)))
            for k, label, pat, transform, error, flags in frames)
    try:
        _drizzle_frames(frames, ref_item, accs, names, stats, rejected, weights, gain,
                        read_noise, normalize, scale, saturation)
    except KeyboardInterrupt as exc:
        # Ctrl-C (SIGTERM on the command line): the frames drizzled so far can be stacked
        # (a frame stopped half-way is left out of the stack and of its accounts).
        interrupt = exc
    if interrupt is not None:
        interrupt.not_registered = len(others) + 1 - len(names) - len(rejected)
        interrupt.partial_result = planes(), rejected, ref, pattern
        raise interrupt
    return planes(), rejected, ref, pattern


def _outliers(frames, shape, opts, folder, order, fwhms):
    """
    `drizzle_bayer`'s rejection: each frame's grey version resampled onto the reference's
    grid and written to ``folder`` (one frame at a time), then the stack's clipped
    combination of them, its star allowance (``star_tolerance``), unless given, from
    ``fwhms`` (`_find_raw_transforms`', filled as the frames are registered) as
    `~astroalign_nd.stack` derives it, else ``STAR_TOLERANCE_FLOOR``.  Returns the frames
    as ``(index, label, pattern, transform, error, rejection map)`` (a failed one's map
    None), the maps a memory map in ``folder``.
    On Ctrl-C, the exception carries the frames registered so far, with their maps.
    """
    done, paths, stats, keys, interrupt = [], [], [], [], None
    try:
        for k, label, p, pat, transform, error in frames:
            done.append([k, label, pat, transform, error, None])
            if error is not None:
                continue
            grey = _grey(p, pat)[0]
            if transform is not None:
                grey = apply_transform(transform, grey, shape, order=order, add_keyword=False)
            paths.append(os.path.join(folder, f"grey{len(paths):05d}.fits"))
            write_ccddata(grey, paths[-1], overwrite=True)
            del p, grey
            try:
                st = frame_stats(paths[-1], opts.memory_limit)
            except ValueError:  # nothing on the reference's grid: the drizzle says why
                paths.pop()
                continue
            normalise(st, st.sky if not stats else stats[0].sky, opts.normalize)
            stats.append(st)
            keys.append(None if transform is None else k)  # (the reference's: None)
            done[-1][5] = len(paths) - 1
    except KeyboardInterrupt as exc:
        interrupt = exc
        while done and done[-1][4] is None and done[-1][5] is None:
            del done[-1]  # stopped between its registration and its grey version
    flags = np.lib.format.open_memmap(os.path.join(folder, ".rejected.npy"), mode="w+",
                                      dtype=np.bool_, shape=(max(len(paths), 1),) + shape)
    if opts.clip == "sigma" and opts.star_tolerance is None:
        # Undersampled stars' cores are clipped without an allowance; with fewer than two
        # FWHMs, the allowance for a night of equal seeing.
        # (The reference's FWHM is known once a frame has been registered onto it.)
        tolerance = star_tolerance([fwhms.get(key) for key in keys])
        opts = dataclasses.replace(opts, star_tolerance=STAR_TOLERANCE_FLOOR
                                   if tolerance is None else tolerance)
    if paths:
        frame_weights(stats, None, opts.gain, opts.read_noise)
        combine_files(paths, stats, shape, opts, gain=opts.gain, read_noise=opts.read_noise,
                      memory_limit=opts.memory_limit, rejected=flags)
    done = [tuple(f[:5]) + (None if f[5] is None else flags[f[5]],) for f in done]
    if interrupt is not None:
        interrupt.partial_result = done
        raise interrupt
    return done


def _drizzle_frames(frames, ref_item, accs, names, stats, rejected, weights, gain, read_noise,
                    normalize, scale, saturation):
    """
    `drizzle_bayer`'s frames drizzled one at a time into ``accs`` (and the accounts);
    a frame's optional seventh item marks its rejected raw pixels.
    """
    ref_stats = None
    for k, label, p, pat, transform, error, *bad in frames:
        k = ref_item[1] if transform is None and error is None else k
        name = os.path.basename(label) if label else f"frame{k}"
        if error is not None:
            rejected.append((name, error))
            continue
        data = np.asarray(p.data, dtype=np.float64)
        channels = bayer_channels(data.shape, pat)
        valid = weight_map(data, p.mask, saturation=saturation) > 0
        bad = bad[0] if bad and bad[0] is not None else np.zeros(data.shape, bool)
        # The frame's weight: given, 1 without weights, None ('variance') from its noise.
        w = 1.0 if weights is None else None if isinstance(weights, str) else weights[k]
        try:  # each colour's sky, noise, normalisation (to the reference's skies) and weight
            st = []
            for c in range(3):
                st.append(array_stats(data, None, valid & (channels == c)))
                normalise(st[c], st[c].sky if ref_stats is None else ref_stats[c].sky,
                          normalize)
                if w is None:
                    frame_weights([st[c]], "variance", gain, read_noise)
                else:
                    st[c].weight = float(w)
        except ValueError as exc:
            if ref_stats is None:
                raise ValueError(f"the reference cannot be stacked: {exc}") from None
            rejected.append((name, f"ValueError: {exc}"))
            continue
        ref_stats = st if ref_stats is None else ref_stats
        pm = pixel_map(transform, data.shape, scale)
        with interrupts_held():  # a frame is in every colour and the accounts, or in none
            for c in range(3):
                sel = valid & (channels == c)
                st[c].n_rejected = int((sel & bad).sum())
                var = frame_variance(data, None, st[c], gain, read_noise) * st[c].scale ** 2
                accs[c].add(data * st[c].scale - st[c].offset, pm,
                            np.where(sel & ~bad, np.float32(st[c].weight), np.float32(0.0)),
                            var)
                stats[c].append(st[c])
            names.append(name if transform is not None else f"{name} (reference)")


def colour_ccddata(channels, *, meta, wcs, unit, dtype, rejected, settings):
    """
    The RGB stack as a CCDData cube ``(3, ny, nx)``.

    Parameters
    ----------
    channels : list of 3 tuples
        For red, green and blue: ``(value, variance, coverage, names, stats)``
        as `~astroalign_nd.stack` combines one colour.
    meta : dict-like
        The reference's header (its Bayer keywords are dropped: the stack is
        not a mosaic).
    wcs : `~astropy.wcs.WCS` or None
    unit, dtype
        The stack's unit and data type.
    rejected : list of (name, reason)
    settings : dict
        ``{keyword: (value, comment)}`` of the stack's settings.

    Returns
    -------
    cube : `~astropy.nddata.CCDData`
        ``data``, ``uncertainty`` (`~astropy.nddata.StdDevUncertainty`),
        ``mask`` and ``flags`` (the frames reaching each pixel) of shape
        ``(3, ny, nx)``; ``meta`` lists the frames of the green plane, and
        HISTORY each plane's.
    """
    meta = header_from_meta(meta)  # a copy, its COMMENT and blank cards kept as cards
    for key in _BAYER_KEYS:
        meta.remove(key, ignore_missing=True, remove_all=True)
    planes = [stack_ccddata(value, variance, coverage, meta={}, names=names, stats=stats,
                            rejected=[], settings={}, wcs=None, unit=unit, dtype=dtype)
              for value, variance, coverage, names, stats in channels]
    # Each frame's pixels rejected: its three colours'.
    header = stack_header(meta, [{"name": n, "n_rejected": sum(ch[4][k].n_rejected
                                                               for ch in channels)}
                                 for k, n in enumerate(channels[1][3])], rejected, settings)
    header["AACHANS"] = ("R,G,B", "colour of each plane of the cube")
    for colour, (_, _, _, names, stats) in zip("RGB", channels):
        for name, st in zip(names, stats):
            header.add_history(f"{colour}: {fits_text(name)} sky offset {st.offset:.6g} scale "
                               f"{st.scale:.6g} weight {st.weight:.6g} rejected "
                               f"{st.n_rejected} px")
    return CCDData(np.stack([pl.data for pl in planes]), unit=unit,
                   mask=np.stack([pl.mask for pl in planes]),
                   uncertainty=StdDevUncertainty(np.stack([pl.uncertainty.array
                                                           for pl in planes])),
                   flags=np.stack([pl.flags for pl in planes]), wcs=wcs, meta=header)
