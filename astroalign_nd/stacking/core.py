# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""`stack`: register frames onto a reference and combine them."""

from __future__ import annotations

import dataclasses
import errno
import os
import tempfile
from collections.abc import Iterator
from typing import Any

import astropy.units as u
import numpy as np
from astropy.io import fits
from astropy.nddata import CCDData, VarianceUncertainty

from ..io.read import batch_frames, parse_input
from ..batch import BatchResult, reference_on_canvas, register_batch
from ..batch.canvas import canvas_wcs
from ..batch.core import Interrupted
from ..exceptions import TransformNotFoundError, warn
from ..io import write_ccddata, write_output
from ..io.bayer import bayer_pattern
from ..io.header import fits_text
from ..io.write import check_not_input, check_output_path, make_output_dir, remove_empty_dirs
from ..io.writers import output_suffixes
from .combine import (combine_files, frame_stats, frame_variance, frame_weights, normalise,
                      star_tolerance)
from .drizzle import (DrizzleAccumulator, blot_mask, coverage_report, output_shape, pixel_map,
                      scaled_wcs, weight_map)
from .colour import _demosaicing, colour_ccddata, drizzle_bayer, register_bayer
from .header import stack_ccddata
from .quality import as_taken, auto_weight, finish_table, measure_frames
from ..options import AnyCallable, convert
from .options import StackConfig

__all__ = ["stack"]


def stack(frames: Any, reference: Any = None, *, output: str | os.PathLike | None = None,
          overwrite: bool = False, aligned_dir: str | os.PathLike | None = None,
          temp_dir: str | None = None, workers: int | None = None, progress: bool = False,
          callback: Any = None, hdu: int | str | None = None, unit: Any = None,
          order: str | int = "bilinear", dtype: Any = np.float32, **options: Any) -> CCDData:
    """
    Register frames onto a reference and combine them into one deep image.

    Each frame is registered as `~astroalign_nd.register_batch` registers
    it (onto the reference's grid, or onto the union canvas) and measured as
    it was taken (`~astroalign_nd.frame_quality`: its sky noise, stars' FWHM
    and elongation, transparency), the frames ``select`` and the limits
    leave out are set aside with the reason, each frame's sky level is
    brought to the reference's, values far from the other frames' are
    rejected pixel by pixel (cosmic rays, satellite and aircraft trails,
    hot pixels; not the cores of the sharpest frames' stars), and the rest
    are combined with their weights, a strip of rows at a time within
    ``memory_limit``.  Each frame's noise, weight and rejection limits are
    those of the frame as taken: interpolation smooths a frame's pixel
    noise (and correlates it), so a resampled frame's variance is its
    propagated variance times the ratio of its variance as taken to it,
    and the stack's uncertainty is that of sums over a few pixels and more
    (an aperture), not of one smoothed pixel.  The frames are assumed
    calibrated (bias, dark and flat already applied, e.g. with ccdproc):
    the stack does not calibrate them.

    Parameters
    ----------
    frames : iterable
        The frames: paths, arrays, NDData/CCDData, ``(frame, file name)``
        pairs, or a `~ccdproc.ImageFileCollection`, as
        `~astroalign_nd.register_batch` takes them.  Paths are best for
        many frames (the registered frames go to temporary files, never
        all in memory).
    reference : optional
        The frame whose grid the stack is on (default: the first frame).
        It is in the stack: given both here and among ``frames`` (the same
        object or the same file) it is used once, unregistered.
    output : str or path, optional
        Also write the stack to this FITS file (atomically).
    overwrite : bool, optional
        Replace ``output`` (and files in ``aligned_dir``) if they exist.
    aligned_dir : str or path, optional
        Keep the registered frames in this folder (default: a temporary
        folder, removed at the end); raw colour frames demosaiced: each
        frame's registered red, green and blue planes.  Not with ``bayer``
        and ``drizzle`` (ValueError): the Bayer drizzle makes no registered
        frame.
    temp_dir : str, optional
        Where the temporary folder goes (default: the system's).
    workers, progress, hdu, unit, order
        As in `~astroalign_nd.register_batch`.
    callback : callable, optional
        Called with each frame's `~astroalign_nd.batch.FrameResult` as soon
        as its registration ends (registered, or failed with its error), in
        completion order: what the command line prints while a stack runs.
        Raw colour frames (``bayer``) give the transform, the error and the
        time, without the match's figures.
    dtype : numpy dtype, optional
        Of the output's data and uncertainty (default float32).  An integer
        type gets the values rounded, and clipped to its range with a
        warning that counts the pixels outside it (never wrapped around).
    **options
        The stacking options, the fields of
        `~astroalign_nd.stacking.StackConfig` (how the frames are combined:
        ``method``, the rejection ``clip``, sky ``normalize``, ``weights``,
        ``gain`` and ``read_noise``, the ``canvas``, ``memory_limit``, the
        frame selection ``select``, ``max_fwhm``, ``max_elongation``,
        ``min_transparency``, ``min_stars``... each documented there), and
        `~astroalign_nd.register_batch`'s options (``transform_type``,
        detection and matching options...).

    Returns
    -------
    stacked : `~astropy.nddata.CCDData`
        The combined image; ``uncertainty`` a `~astropy.nddata.StdDevUncertainty`
        combined from the frames'; ``mask`` True only where no frame
        reaches (a pixel masked in some frames is combined from the others);
        ``flags`` the number of frames reaching each pixel; ``meta`` the
        reference's header with ``NCOMBINE``, ``IMCMBnnn`` (every frame
        combined, with its sky offset ``AASKYnnn``, scale ``AASCLnnn``,
        weight ``AAWGTnnn``, rejected pixels ``AANRJnnn`` and its measures:
        FWHM ``AAFWHnnn``, elongation ``AAELGnnn``, transparency
        ``AATRNnnn``, sky noise ``AANOInnn``), ``AAREJnnn`` (every frame
        left out, and why) and a HISTORY line of how many were used of how
        many.  With ``drizzle``:
        on the finer grid, its WCS the reference's scaled to it (SIP too);
        the uncertainty through drizzle's squared-weight path; ``mask``
        True where no input reached; ``flags`` the number of frames reaching
        each pixel; the header's ``AADRIZ``, ``AADZPFR``, ``AADZKERN`` (scale,
        pixfrac, kernel), ``AADZEMPT`` and ``AADZUNIF`` (the fraction of
        empty pixels inside the frames and the weight's relative spread,
        see `~astroalign_nd.stacking.drizzle.coverage_report`) and HISTORY
        naming every frame drizzled.  Written to ``output``, the count is
        the ``FLAGS`` extension and drizzle's weight map the ``WEIGHT``
        extension (in memory: the CCDData's ``weight`` attribute).

    Raises
    ------
    KeyboardInterrupt
        When interrupted (Ctrl-C; the command line raises it for SIGTERM
        too) while the frames are registered: the frames registered so far
        are combined (a HISTORY line says the stack is partial and how many
        frames were not registered yet), written to ``output`` if given,
        and the stack is the exception's ``partial_result``.  Nothing is
        stacked if no frame but the reference was registered yet, with
        ``canvas='union'`` (known only once every frame is registered), or
        when the combination itself is interrupted.
    ValueError, TypeError
        For bad arguments, before any work.
    FileExistsError
        If ``output`` exists and ``overwrite`` is False.
    TransformNotFoundError
        If no frame but the reference could be registered.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd import stack
    >>> from astroalign_nd.simulate import simulate_sequence
    >>> seq = simulate_sequence((128, 128), n_frames=4, n_stars=60, seed=3)
    >>> stacked = stack(seq.frames)
    >>> stacked.meta["NCOMBINE"], stacked.shape, int(stacked.mask.sum())
    (4, (128, 128), 0)
    """
    opts, options = StackConfig.from_keywords("stack", options)
    dtype = _check_dtype(dtype)
    callback = convert("callback", AnyCallable("a function of one FrameResult"), callback)
    items, hdu = batch_frames(frames, hdu)
    if isinstance(items, Iterator):
        items = list(items)
    # In-memory frames are named by their place among the frames, in the header too.
    items = [(f, f"frame{k}" if label is None else label) for k, (f, label) in enumerate(items)]
    ref_item, others, n_frames, weights = _checked_frames(items, reference, opts.weights,
                                                          output, overwrite)
    if opts.bayer is not None:
        return _stack_colour(ref_item, others, opts, weights, aligned_dir, temp_dir, hdu, unit,
                             order, dtype, options, output=output, overwrite=overwrite,
                             callback=callback)
    ref = parse_input(ref_item[0], "reference", hdu=hdu, unit=unit)
    if ref.data is None or ref.data.ndim != 2:
        raise ValueError("the reference must be a 2-D image (stack one colour channel at a "
                         "time, or raw colour frames with bayer='auto').")
    interrupt = None
    with _aligned_folder(aligned_dir, temp_dir) as folder:
        try:
            result = _register([it for it, _ in others], ref, folder, opts.canvas, overwrite,
                               workers, progress, callback, hdu, unit, order, options,
                               ref_item[0])
        except KeyboardInterrupt as exc:
            # Ctrl-C (SIGTERM on the command line): the frames registered so far are stacked.
            result, interrupt = getattr(exc, "partial_result", None), exc
            if opts.canvas == "union" or result is None or not result.succeeded:
                raise  # a union canvas is known only once every frame is registered
        frames_ = [_reference_frame(ref_item, result, folder, hdu, unit)]
        frames_ += [(f.name, f.output, k) for f, (_, k) in zip(result.frames, others) if f.ok]
        not_done = [f for f in result.failed if _not_done(f)]
        rejected = [(f.name, f.error) for f in result.failed if not _not_done(f)]
        x0, y0 = result.canvas_offset
        # What a drizzle reads again: each frame as given, and its transform onto the canvas.
        # (by registered file, which the quality selection below keeps or not)
        sources = [(ref_item[0], np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]]))]
        sources += [(it[0], f.transform) for f, (it, _) in zip(result.frames, others) if f.ok]
        sources = {frame[1]: src for frame, src in zip(frames_, sources)}
        if others and not result.succeeded:
            raise TransformNotFoundError(
                "no frame could be registered onto the reference: "
                + "; ".join(f"{n}: {e}" for n, e in rejected))
        frames_, measured = _quality(frames_, ref_item, others, result, rejected, hdu, unit,
                                     opts)
        used, stats = _measure(frames_, rejected, opts, weights, measured)
        for name, why in rejected:  # never silently: the header alone is easy to miss
            warn(f"{name} was left out of the stack: {why}")
        opts = _feasible_clip(_star_clip(opts, stats), len(used))
        paths = [frames_[i][1] for i in used]
        if opts.drizzle is not None:
            ccd, weight = _drizzled(paths, [sources[p] for p in paths], stats, result, ref, opts,
                                    folder, dtype, [frames_[i][0] for i in used], rejected,
                                    hdu=hdu, unit=unit)
        else:
            value, variance, coverage = combine_files(
                paths, stats, result.canvas_shape, opts, gain=opts.gain,
                read_noise=opts.read_noise, memory_limit=opts.memory_limit)
            wcs = canvas_wcs(ref.wcs, result.canvas_offset, result.canvas_shape)
    if opts.drizzle is None:
        ccd = _stacked(value, variance, coverage, ref, wcs, dtype,
                       [frames_[i][0] for i in used], stats, rejected, opts)
    ccd.meta.add_history(f"astroalign_nd stack: {len(used)} of {n_frames} frames used")
    if interrupt is not None:
        # One HISTORY card (72 characters): the frames left out are in NREJECT.
        ccd.meta.add_history(f"partial stack (interrupted): {len(used)} of {len(others) + 1} "
                             f"frames stacked, {len(not_done)} not registered")
    if output is not None and opts.drizzle is None:
        write_output(ccd, output, overwrite=overwrite)
    elif output is not None:
        write_ccddata(ccd, output, overwrite=overwrite, hdu_flags="FLAGS",
                      extra_hdus=[fits.ImageHDU(weight, name="WEIGHT")])
    if interrupt is not None:
        interrupt.partial_result = ccd
        raise interrupt
    return ccd


def _drizzled(paths, sources, stats, result, ref, opts, folder, dtype, names, rejected, *, hdu,
              unit):
    """
    The frames drizzled one at a time, after the stack's rejection on the canvas
    (each frame's rejected pixels carried back onto it, and weighing nothing there).
    Returns the stack's CCDData and drizzle's weight map.
    """
    scale, pixfrac, kernel = opts.drizzle, opts.pixfrac, opts.kernel
    gain, read_noise = opts.gain, opts.read_noise
    n, shape = len(paths), tuple(result.canvas_shape)
    # The rejection maps on disk: one frame's at a time in memory, whatever the number of frames.
    flags = np.lib.format.open_memmap(os.path.join(folder, ".rejected.npy"), mode="w+",
                                      dtype=np.bool_, shape=(n,) + shape)
    _, _, coverage = combine_files(paths, stats, shape, opts, gain=gain, read_noise=read_noise,
                                   memory_limit=opts.memory_limit, rejected=flags)
    acc = DrizzleAccumulator(output_shape(shape, scale), scale, pixfrac, kernel)
    for k, ((item, transform), st) in enumerate(zip(sources, stats)):
        frame = parse_input(item, "frame", hdu=hdu, unit=unit)
        data = np.asarray(frame.data, dtype=np.float64)
        var = None if frame.uncertainty is None else np.asarray(
            frame.uncertainty.represent_as(VarianceUncertainty).array, dtype=np.float64)
        var = frame_variance(data, var, st, gain, read_noise)
        pm = pixel_map(transform, data.shape)
        bad = blot_mask(flags[k], pm)
        w = weight_map(data, frame.mask, var, weight=st.weight,
                       saturation=opts.saturation)
        st.n_rejected = int((bad & (w > 0)).sum())  # the frame's own pixels
        w[bad] = 0.0
        pm = scale * (pm + 0.5) - 0.5  # onto the finer grid (drizzle.pixel_map's Grids)
        acc.add(data * st.scale - st.offset, pm, w, var * st.scale ** 2)
        del frame, data, var, pm, w, bad
    del flags
    ccd = drizzle_ccddata(acc.planes(), coverage, opts, _settings(opts, n), meta=ref.meta,
                          wcs=ref.wcs, offset=result.canvas_offset, names=names, stats=stats,
                          rejected=rejected, unit=ref.unit or "adu", dtype=dtype,
                          how="outliers rejected on the reference grid and blotted back")
    return ccd, ccd.weight


def drizzle_ccddata(planes, coverage, opts, settings, *, meta, wcs, offset, names, stats,
                    rejected, unit, dtype, how):
    """
    A drizzle's planes as the stack's CCDData (`stack_ccddata`): the coverage
    report (warned, and in the header), the drizzle's settings, the WCS scaled
    to the output grid, HISTORY naming every frame; drizzle's weight map as
    its ``weight`` attribute (written as the ``WEIGHT`` extension).
    """
    scale, pixfrac, kernel = opts.drizzle, opts.pixfrac, opts.kernel
    empty, spread = coverage_report(planes, coverage, len(names), scale, pixfrac=pixfrac)
    settings = dict(settings)
    settings.update({"AADRIZ": (scale, "drizzle: output pixels per reference pixel"),
                     "AADZPFR": (pixfrac, "drizzle: pixfrac"),
                     "AADZKERN": (kernel, "drizzle: kernel"),
                     "AADZEMPT": (round(empty, 6), "drizzle: empty fraction inside frames"),
                     "AADZUNIF": (round(spread, 4) if np.isfinite(spread) else -1.0,
                                  "drizzle: weight std/mean, all frames")})
    ccd = stack_ccddata(planes.value, planes.variance, planes.count, meta=meta, names=names,
                        stats=stats, rejected=rejected, settings=settings,
                        wcs=scaled_wcs(wcs, scale, planes.value.shape, offset), unit=unit,
                        dtype=dtype)
    ccd.meta.add_history(f"astroalign_nd stack: drizzled at scale {scale:g}, pixfrac "
                         f"{pixfrac:g}, kernel {kernel}, {how}")
    for name in names:
        ccd.meta.add_history(f"drizzled {fits_text(name)}")
    if ccd.mask.all():
        warn("no frame reaches any pixel of the stack.")
    ccd.weight = planes.weight
    return ccd


def _not_done(frame):
    """A frame an interrupted `register_batch` did not reach (not a failure of its own)."""
    return (frame.error or "").startswith(f"{Interrupted.__name__}: ")


def _stack_colour(ref_item, others, opts, weights, aligned_dir, temp_dir, hdu, unit, order,
                  dtype, options, *, output, overwrite, callback):
    """Raw colour frames: demosaiced and combined per colour, or Bayer-drizzled (and written)."""
    if opts.drizzle is not None and aligned_dir is not None:
        # Not silently ignored: the user expects the registered frames there.
        raise ValueError("aligned_dir cannot be kept with bayer and drizzle: the Bayer "
                         "drizzle drops each frame's raw pixels onto the output directly "
                         "and makes no registered frame; leave aligned_dir out, or "
                         "demosaic (drizzle=None) to keep each frame's registered colour "
                         "planes there.")
    bayer = opts.bayer if opts.bayer == "auto" else bayer_pattern(pattern=opts.bayer)
    # Resampling's options (the command line passes them): the demosaiced planes' only.
    resampling = {k: options.pop(k) for k in ("conserve_flux", "fill_value") if k in options}
    interrupt = None
    try:
        if opts.drizzle is not None:
            ccd = _drizzle_bayer(ref_item, others, opts, weights, hdu, unit, dtype, options,
                                 bayer=bayer, callback=callback, temp_dir=temp_dir,
                                 order=order)
        else:
            _demosaicing()  # the [colour] extra's ImportError before any work
            ccd = _stack_bayer(ref_item, others, opts, weights, aligned_dir, temp_dir, hdu,
                               unit, order, dtype, options, resampling, bayer=bayer,
                               callback=callback)
    except KeyboardInterrupt as exc:
        # Ctrl-C (SIGTERM on the command line): the partial stack of the frames registered.
        ccd, interrupt = getattr(exc, "partial_result", None), exc
        if not isinstance(ccd, CCDData):
            raise
    if output is not None:
        write_output(ccd, output, overwrite=overwrite)
    if interrupt is not None:
        raise interrupt
    return ccd


def _interrupted(ccd, exc, n_used, others):
    """``exc`` with the partial stack ``ccd`` (its HISTORY says so), to raise."""
    ccd.meta.add_history(f"partial stack (interrupted): {n_used} of {len(others) + 1} "
                         f"frames stacked, {exc.not_registered} not registered")
    exc.partial_result = ccd
    return exc


def _stack_bayer(ref_item, others, opts, weights, aligned_dir, temp_dir, hdu, unit, order,
                 dtype, options, resampling, *, bayer, callback):
    """Raw colour frames registered on their grey versions, demosaiced, combined per colour."""
    interrupt = None
    with _aligned_folder(aligned_dir, temp_dir) as folder:
        try:
            channels, rejected, ref, pattern = register_bayer(
                ref_item, others, folder, bayer=bayer, method=opts.demosaic, hdu=hdu,
                unit=unit, order=order, options=options, resampling=resampling,
                callback=callback)
        except KeyboardInterrupt as exc:
            partial = getattr(exc, "partial_result", None)
            if partial is None or len(partial[0][0]) < 2:
                raise  # no frame but the reference registered: nothing to stack
            (channels, rejected, ref, pattern), interrupt = partial, exc
        _check_registered(others, len(channels[0]) - 1, rejected)
        combined, all_rejected = [], list(rejected)
        for frames_ in channels:
            lost = list(rejected)
            used, stats = _measure(frames_, lost, opts, weights)
            if not combined:
                for name, why in lost:  # never silently: the header alone is easy to miss
                    warn(f"{name} was left out of the stack: {why}")
            copts = _feasible_clip(opts, len(used))
            value, variance, coverage = combine_files(
                [frames_[i][1] for i in used], stats, ref.data.shape, copts, gain=opts.gain,
                read_noise=opts.read_noise, memory_limit=opts.memory_limit)
            all_rejected += [r for r in lost if r not in all_rejected]
            combined.append((value, variance, coverage, [frames_[i][0] for i in used], stats))
    settings = _settings(copts, len(used))
    settings["AABAYER"] = (pattern, "Bayer pattern of the reference's first cell")
    settings["AADEMOS"] = (opts.demosaic, "demosaicing (colour-demosaicing)")
    ccd = colour_ccddata(combined, meta=ref.meta, wcs=ref.wcs, unit=ref.unit or "adu",
                         dtype=dtype, rejected=all_rejected, settings=settings)
    if interrupt is not None:
        raise _interrupted(ccd, interrupt, len(combined[0][3]), others)
    return ccd


def _drizzle_bayer(ref_item, others, opts, weights, hdu, unit, dtype, options, *, bayer,
                   callback, temp_dir, order):
    """
    Raw colour frames registered on their grey versions and Bayer-drizzled, after the
    stack's rejection on the grey versions (unless ``clip`` is None).
    """
    interrupt = None
    # (The star allowance, unless given, from the FWHMs that the grey versions' detection
    # found: `drizzle_bayer`'s rejection.)
    opts = _feasible_clip(opts, len(others) + 1)
    with _aligned_folder(None, temp_dir) as folder:
        try:
            channels, rejected, ref, pattern = drizzle_bayer(
                ref_item, others, bayer=bayer, scale=opts.drizzle, pixfrac=opts.pixfrac,
                kernel=opts.kernel, normalize=opts.normalize, weights=weights, gain=opts.gain,
                read_noise=opts.read_noise, hdu=hdu, unit=unit, options=options,
                saturation=opts.saturation, callback=callback,
                reject=opts if opts.clip else None, folder=folder, order=order)
        except KeyboardInterrupt as exc:
            partial = getattr(exc, "partial_result", None)
            if partial is None or len(partial[0][0][3]) < 2:
                raise  # no frame but the reference drizzled: nothing to stack
            (channels, rejected, ref, pattern), interrupt = partial, exc
    _check_registered(others, len(channels[0][3]) - 1, rejected)
    for name, why in rejected:
        warn(f"{name} was left out of the stack: {why}")
    settings = _settings(opts, len(channels[0][3]))
    settings.update({"AASTKMTH": ("drizzle", "astroalign_nd stack: combination"),
                     "AADRIZ": (opts.drizzle, "drizzle: output pixels per reference pixel"),
                     "AADZPFR": (opts.pixfrac, "drizzle: pixfrac"),
                     "AADZKERN": (opts.kernel, "drizzle: kernel"),
                     "AABAYER": (pattern, "Bayer pattern of the reference's first cell")})
    wcs = scaled_wcs(ref.wcs, opts.drizzle, channels[0][0].shape)
    ccd = colour_ccddata(channels, meta=ref.meta, wcs=wcs, unit=ref.unit or "adu",
                         dtype=dtype, rejected=rejected, settings=settings)
    ccd.meta.add_history("astroalign_nd stack: Bayer drizzle, " + (
        "outliers rejected on the grey versions and blotted back" if opts.clip
        else "no rejection"))
    if interrupt is not None:
        raise _interrupted(ccd, interrupt, len(channels[0][3]), others)
    return ccd


def _check_registered(others, n_registered, rejected):
    """Refuse a stack of the reference alone when there were other frames."""
    if others and not n_registered:
        raise TransformNotFoundError(
            "no frame could be registered onto the reference: "
            + "; ".join(f"{n}: {e}" for n, e in rejected))


def _is_path(obj):
    return isinstance(obj, (str, os.PathLike))


def _checked_frames(items, reference, weights, output, overwrite):
    """
    The frames, checked before any work: ``(reference, its index, its label)``, the
    others as ``[((item, label), index)...]``, the number of frames and the weights.

    The reference is taken out of the frames; its index is 0 when it is not one of
    them (the others' indices then start at 1), as ``weights`` counts them.  Each file
    (or object) is stacked once: one given twice would count twice in the stack, as if
    it were two exposures; each repeat is left out with a warning.  A sequence of
    ``weights`` becomes an array of one per frame.  ``output`` can be written and is not
    an input.
    """
    if reference is None:
        if not items:
            raise ValueError("frames is empty: give at least one frame (the first is the "
                             "reference unless reference= is given).")
        ref_item, n_frames = (items[0][0], 0, items[0][1]), len(items)
        others = [(it, k) for k, it in enumerate(items)][1:]
    else:
        if isinstance(reference, list):
            raise TypeError("reference must be one frame, not a list of frames.")
        at = next((k for k, it in enumerate(items) if _same(it[0], reference)), None)
        shift = 1 if at is None else 0
        others = [(it, k + shift) for k, it in enumerate(items) if k != at]
        label = os.fspath(reference) if _is_path(reference) else None
        ref_item, n_frames = (reference, 0 if at is None else at, label), len(items) + shift
    kept, repeats = [], {}
    for (item, label), k in others:
        first = next((lab for (it, lab), _ in kept if _same(it, item)), None)
        if first is None and _same(ref_item[0], item):
            first = ref_item[2] or "the reference"
        if first is None:
            kept.append(((item, label), k))
        else:
            repeats[first] = repeats.get(first, 1) + 1
    for label, n in repeats.items():
        warn(f"{label} is given {n} times among the frames; it is stacked once (each frame "
             "counts as one exposure).")
    if weights is not None and not isinstance(weights, str):
        if len(weights) != n_frames:
            raise ValueError(f"weights must be one finite number >= 0 per frame ({n_frames}, "
                             f"the reference's first when it is not one of the frames), not "
                             f"all 0; got {list(weights)!r}.")
        weights = np.asarray(weights)
    if output is not None:
        check_not_input(output, [it[0] for it in items] + [ref_item[0]])
        check_output_path(output, overwrite, extensions=output_suffixes())
    return ref_item, kept, n_frames, weights


def _reference_frame(ref_item, result, folder, hdu, unit):
    """
    The reference as a frame of the stack, ``(name, path, index)``: on the canvas
    (`~astroalign_nd.batch.reference_on_canvas`), written as a file in ``folder``.
    """
    ccd = reference_on_canvas(ref_item[0], result, hdu=hdu, unit=unit, add_keyword=False)
    path = os.path.join(folder, ".reference_on_canvas.fits")
    write_ccddata(ccd, path, overwrite=True)
    name = os.path.basename(ref_item[2]) if ref_item[2] else "reference"
    return f"{name} (reference)", path, ref_item[1]


def _same(a, b):
    """The same frame: the same object, or the same file."""
    if a is b:
        return True
    if _is_path(a) and _is_path(b):
        return os.path.realpath(os.fspath(a)) == os.path.realpath(os.fspath(b))
    return False


class _aligned_folder:
    """The folder of the registered frames: the user's (kept) or a temporary one."""

    def __init__(self, aligned_dir, temp_dir):
        self.keep = aligned_dir is not None
        self.path, self.tmp = (os.fspath(aligned_dir) if self.keep else None), None
        if temp_dir is not None and not os.path.isdir(temp_dir):
            raise NotADirectoryError(f"temp_dir {temp_dir!r} is not a folder.")
        self.temp_dir = temp_dir

    def __enter__(self):
        if self.keep:
            self.created = make_output_dir(self.path, "aligned_dir")
            return self.path
        self.tmp = tempfile.TemporaryDirectory(prefix="aastack-", dir=self.temp_dir)
        return self.tmp.name

    def __exit__(self, *exc):
        if self.tmp is not None:
            self.tmp.cleanup()
        else:
            remove_empty_dirs(self.created)  # nothing registered: no empty folder left


def _register(others, ref, folder, canvas, overwrite, workers, progress, callback, hdu, unit,
              order, options, reference):
    """`register_batch` of the frames other than the reference, into ``folder``."""
    frames = [frame if (_is_path(frame) or label is None) else (frame, label)
              for frame, label in others]
    if not frames:
        return BatchResult([], canvas_shape=tuple(ref.data.shape), canvas_offset=(0, 0))
    try:
        return register_batch(frames, reference, output_dir=folder, overwrite=overwrite,
                              canvas=canvas, workers=workers, progress=progress,
                              callback=callback, hdu=hdu,
                              unit=unit, order=order, **options)
    except OSError as exc:
        if getattr(exc, "frame", None) is None:
            raise
        # The batch's own advice (run it again with skip_existing) is no stack's: the
        # registered frames are the stack's working files, removed when it stops.
        full = exc.errno in (errno.ENOSPC, errno.EDQUOT)
        stop = OSError(f"the stack stopped at {exc.frame}: {exc.reason.partition(': ')[2]} "
                       f"The registered frames go to {folder} before they are combined: "
                       + ("free some space there, or give aligned_dir a folder on another "
                          "disk." if full else "give aligned_dir a folder you can write to."))
        stop.errno = exc.errno
        raise stop from None


def _measure(frames, rejected, opts, weights, measured=None):
    """
    Each frame's statistics, normalisation and weight; a frame that cannot
    be measured joins ``rejected``.  Returns the indices used and their stats.
    ``measured``: each frame's quality row and measures as taken (default: none).
    """
    used, stats = [], []
    ref_sky = ref_unit = None
    for i, (name, path, _) in enumerate(frames):
        try:
            st = frame_stats(path, opts.memory_limit)
            as_taken(st, *(measured[i] if measured else (None, None)))
            ref_unit = st.unit if i == 0 else ref_unit
            factor = _unit_factor(st, ref_unit)
            ref_sky = st.sky if ref_sky is None else ref_sky
            # Normalised in its own unit, then brought into the reference's.
            normalise(st, ref_sky / factor, opts.normalize)
            st.scale, st.offset = st.scale * factor, st.offset * factor
        except ValueError as exc:
            if i == 0:
                raise ValueError(f"the reference cannot be stacked: {exc}") from None
            rejected.append((name, f"ValueError: {exc}"))
            continue
        used.append(i)
        stats.append(st)
    if isinstance(weights, str) and weights == "auto":
        w = np.array([auto_weight(st) for st in stats])
        weights = np.where(np.isfinite(w), w, np.nanmedian(w) if np.isfinite(w).any() else 1)
    elif weights is not None and not isinstance(weights, str):
        weights = weights[[frames[i][2] for i in used]]
    frame_weights(stats, weights, opts.gain, opts.read_noise)
    return used, stats


def _quality(frames, ref_item, others, result, rejected, hdu, unit, opts):
    """
    Every registered frame measured as taken (`~astroalign_nd.frame_quality`'s rows), the
    selection applied: the frames left out join ``rejected`` with the reason.  Returns
    the frames kept and their ``(row, measures)``.
    """
    ok = [(f, it) for f, (it, _) in zip(result.frames, others) if f.ok]
    limits = dict(max_fwhm=opts.max_fwhm, max_elongation=opts.max_elongation,
                  min_transparency=opts.min_transparency, min_stars=opts.min_stars)
    try:
        rows, measures = measure_frames(
            (frames[0][0], ref_item[0]),
            [(f.name, it[0], f.points, f.quality) for f, it in ok], hdu=hdu, unit=unit)
    except (ValueError, TypeError) as exc:
        if opts.weights == "auto" or opts.normalize == "stars" or opts.select is not None \
                or any(v is not None for v in limits.values()):
            raise ValueError(f"the reference cannot be measured ({exc}): weights='auto', "
                             "normalize='stars', select and the limits need its stars; use "
                             "weights='variance' and no selection.") from None
        return frames, [(None, None)] * len(frames)
    rows = list(finish_table(rows, opts.select, limits))
    kept, measured = [], []
    for frame, row, m in zip(frames, rows, measures):
        if row["used"] or m is None:  # (one not measured is combined as before)
            kept.append(frame)
            measured.append((row, m))
        else:
            rejected.append((frame[0], row["reason"]))
    return kept, measured


def _star_clip(opts, stats):
    """
    The clipping's allowance for the stars' own signal (``star_tolerance``), unless
    given: `~astroalign_nd.stacking.combine.star_tolerance` of the frames' measured FWHMs
    (none with fewer than two).
    """
    if opts.clip != "sigma" or opts.star_tolerance is not None:
        return opts
    tolerance = star_tolerance([st.quality["fwhm"] for st in stats if st.quality])
    return opts if tolerance is None else dataclasses.replace(opts, star_tolerance=tolerance)


def _feasible_clip(opts, n_used):
    """
    The options, without min/max clipping when it would leave no value (it then rejects
    nothing, and the header must not say it clipped).
    """
    if opts.clip != "minmax" or n_used > opts.nlow + opts.nhigh:
        return opts
    warn(f"clip='minmax' drops the {opts.nlow} lowest and {opts.nhigh} highest values of "
         f"each pixel: with {n_used} frames none would be left, so nothing is rejected; "
         "stack more frames, lower nlow/nhigh, or use clip='sigma'.")
    return dataclasses.replace(opts, clip=None)


def _unit_factor(st, ref_unit):
    """
    The factor that brings a frame's values into the reference's unit (recorded in
    ``st.converted``); a unit astropy cannot convert is refused with what to pass.
    """
    if st.unit is None or ref_unit is None or st.unit == ref_unit:
        return 1.0
    try:
        factor = u.Unit(st.unit).to(u.Unit(ref_unit))
    except (ValueError, u.UnitsError):
        raise ValueError(f"its unit {st.unit!r} cannot be converted to the reference's "
                         f"{ref_unit!r}; give every frame in one unit (electrons to adu: "
                         "divide by the gain, e.g. with ccdproc.gain_correct).") from None
    st.converted = f"converted from {st.unit} to {ref_unit} (x {factor:.6g})"
    return factor


def _settings(opts, n_used):
    s = {"AASTKMTH": (opts.method, "astroalign_nd stack: combination"),
         "AASTKCLP": (opts.clip or "none", "rejection"),
         "AASTKNRM": (opts.normalize or "none", "sky normalisation")}
    if opts.clip == "sigma":
        s["AASTKSLO"] = (opts.sigma_low, "sigma clipping: low limit")
        s["AASTKSHI"] = (opts.sigma_high, "sigma clipping: high limit")
    elif opts.clip == "minmax":
        s["AASTKNLO"] = (opts.nlow, "min/max clipping: lowest dropped")
        s["AASTKNHI"] = (opts.nhigh, "min/max clipping: highest dropped")
    return s


def _stacked(value, variance, coverage, ref, wcs, dtype, names, stats, rejected, opts):
    """The stack as a CCDData, after warning when no frame reaches any of its pixels."""
    mask = coverage == 0
    if mask.any() and mask.all():
        warn("no frame reaches any pixel of the stack.")
    return stack_ccddata(value, variance, coverage, meta=ref.meta, names=names, stats=stats,
                         rejected=rejected, settings=_settings(opts, len(names)), wcs=wcs,
                         unit=ref.unit or "adu", dtype=dtype)


def _check_dtype(dtype):
    """The output's dtype: a real number type (integers are rounded and clipped)."""
    try:
        dt = np.dtype(dtype)
    except TypeError:
        raise TypeError(f"dtype must be a numpy number type such as np.float32; got "
                        f"{dtype!r}.") from None
    if dt.kind not in "iuf":
        raise TypeError(f"dtype must be a real number type (float or integer), such as "
                        f"np.float32; got {dt}.")
    return dt
