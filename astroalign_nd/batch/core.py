# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""`register_batch`: register many frames onto one reference."""

from __future__ import annotations

import errno
import os
import time
from collections.abc import Callable, Iterable
from contextlib import closing
from dataclasses import asdict, replace
from typing import Any
import numpy as np
from ..io.read import batch_frames, display_names
from ..config import RegistrationConfig
from ..options import AnyCallable, convert
from ..resample import ResampleConfig
from ..exceptions import warn
from ..io.write import make_output_dir
from ..registration import Reference, prepare_target
from .results import BatchResult, FrameResult
from .frame import (_Config, _Job, _failed, _own_output, _registered_before, _stream_jobs,
                    shifted_transform)
from .planning import _StreamNamer, _is_path, _plan_outputs
from .canvas import canvas_wcs, _kept_on_canvas, _union_grid, _valid_margin
from .runners import _execute
from ..sequence.solve import SOLVE_OPTIONS
from .joint import solve_jobs

__all__ = ['register_batch']


def _verified(results):
    """A frame reported as done has its file: the summary never counts a lost result."""
    seen = set()
    for k, f in enumerate(results):
        if f.ok and f.output is not None:
            key = os.path.realpath(f.output)
            if key in seen or not os.path.isfile(f.output):
                results[k] = replace(f, status="failed", error=f"OSError: {f.output} is "
                                     "missing or was written twice (another process writing "
                                     "to the same folder?)")
            seen.add(key)
    return results

# -- the public function ---------------------------------------------------------------------


def register_batch(sources: Iterable[Any] | Any, target: Any, *,
                   output_dir: str | os.PathLike | None = None, overwrite: bool = False,
                   skip_existing: bool = False, suffix: str = "_aligned",
                   canvas: str = "reference", client: Any = None, workers: int | None = None,
                   progress: bool = False, callback: Callable[[FrameResult], Any] | None = None,
                   order: str | int = "bilinear", conserve_flux: bool = False,
                   fill_value: float = np.nan, method: str = "interpolate", unit: Any = None,
                   hdu: int | str | None = None, add_keyword: bool = True,
                   solve: str = "pairwise", **options: Any) -> BatchResult:
    """
    Register every frame of ``sources`` onto ``target``.

    The argument order is that of the rest of the API
    (``register(source, target)``, ``find_transform(source, target)``):
    what moves first, the reference last.

    Parameters
    ----------
    sources : iterable or `~ccdproc.ImageFileCollection`
        Frames: paths (best for large batches: each worker reads its own
        files), arrays, NDData/CCDData, ``(frame, file name)`` pairs such as
        ``ImageFileCollection.ccds(return_fname=True)`` yields, a generator
        of any of these, or an ``ImageFileCollection`` (its files, read
        with its ``ext``).  File names name the outputs.  A generator is
        taken one frame at a time and never held in memory all at once
        (except with ``canvas='union'``, see there); its output names are
        planned as its frames arrive (see `plan_outputs`).
    target : anything `~astroalign_nd.find_transform` accepts, or `~astroalign_nd.Reference`
        The reference frame; prepared once.  The detection options of a
        `~astroalign_nd.Reference` (``Reference(img, fwhm=4)``) apply to
        every frame too, unless given again here.
    output_dir : str or path, optional
        Write each registered frame to ``<output_dir>/<name><suffix>.fits``
        (with ``MASK``, ``UNCERT`` and ``FLAGS`` extensions, as
        `~astropy.nddata.CCDData.write` writes them) instead of returning
        it.  For a list or a collection, names are made unique before any
        work (see `plan_outputs`); files are written atomically: a killed
        run leaves no partial file under a final name.
    overwrite : bool, optional
        Replace existing output files (default False: such a frame fails,
        and the others go on).  An old output is replaced only once the new
        one is complete.
    skip_existing : bool, optional
        Resume an interrupted run: a frame whose output is already there
        and complete is not redone, and is reported with status 'skipped'
        (its transform and quality read back from the file's header).  An
        incomplete or foreign file under that name fails the frame, unless
        ``overwrite`` is also given, which redoes it.
    suffix : str, optional
        Added to output file names (default ``'_aligned'``).
    canvas : {'reference', 'union'}, optional
        The output grid.  'reference' (default): the reference's pixel
        grid; frame pixels outside it are lost.  'union': the smallest grid,
        aligned with the reference's pixels, that holds the reference and
        every frame, so that a dithered or mosaic set is stacked with
        nothing cut off.  Each frame's mask is True outside its footprint;
        the reference's WCS goes along (CRPIX shifted).  This takes two
        passes: all transforms first, then the resampling (frames are read
        twice; only the transforms are kept in between).  The second pass
        needs every frame again, so a generator's items are collected into
        a list first: give paths (or a collection), not in-memory frames,
        to keep memory flat.
    client : ``dask.distributed.Client``, optional
        Run the frames as dask.distributed tasks (the reference is
        broadcast to the workers once): the way to use several machines.
    workers : int, optional
        Without a client: the number of local worker processes (default:
        none, the frames run one after the other in this process).
    progress : bool, optional
        Show a tqdm progress bar.
    callback : callable, optional
        Called with each frame's `FrameResult` as soon as that frame is
        done, in completion order (the returned result is in input order).
    order, conserve_flux, fill_value, method, unit, add_keyword
        As in `~astroalign_nd.apply_transform`.  ``add_keyword=False``
        leaves the frames' headers as they were, so it cannot be combined
        with ``skip_existing`` (resuming reads the transform back from the
        outputs' headers).
    solve : {'pairwise', 'global'}, optional
        'pairwise' (default): each frame is registered onto the target on
        its own.  'global': every frame's transform is solved together
        (`~astroalign_nd.solve_sequence`: the frames linked to each other
        and to the target, one least-squares solution over all their
        stars), so that a frame that does not overlap the target is
        registered through its neighbours, and a link that disagrees with
        the rest is rejected; then every frame is resampled with its
        transform.  Each frame's ``quality`` then also holds ``n_links``
        and ``predicted_error`` (px).  The frames are held in memory
        during the solve, and a generator's are collected into a list.
        ``solve_sequence``'s own options (``n_stars``, ``all_pairs``,
        ``n_hubs``, ``min_overlap``, ``link_tolerance``) go in ``**options``.
    hdu : int or str, optional
        The HDU to read from FITS files (frames and target), as in
        `~astroalign_nd.find_transform`; by default the first one with
        image data.  The files of an ``ImageFileCollection`` are read with
        its ``ext`` unless ``hdu`` is given.
    **options
        As in `~astroalign_nd.find_transform` (``transform_type``,
        ``n_sources``, ``max_sources``, detection and matching options).

    Returns
    -------
    result : `~astroalign_nd.batch.BatchResult`
        Per-frame results in input order; ``result.failed`` lists the
        frames that could not be registered and why, ``result.to_table()``
        tabulates them all.

    Raises
    ------
    KeyboardInterrupt
        When interrupted (Ctrl-C; the command line raises it for SIGTERM
        too), after the worker processes are stopped; its
        ``partial_result`` attribute is the `~astroalign_nd.batch.BatchResult`
        so far, the frames not done reported as failed.

    Notes
    -----
    A worker process that dies (the out-of-memory killer, say) does not end
    the batch: the frames its pool held are retried, one at a time, and
    only a frame that kills its worker even alone fails.  A retried frame
    recognises the output its first attempt wrote (its header's
    ``AABATCH`` names the batch and the frame), also on dask.distributed.

    Examples
    --------
    Register two frames onto a reference and write them to a folder (a
    temporary one here); the frame without stars fails and the batch goes
    on:

    >>> import os
    >>> import tempfile
    >>> import numpy as np
    >>> from astroalign_nd.batch import register_batch
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     result = register_batch([pair.source, np.zeros((64, 64))], pair.target,
    ...                             output_dir=tmp)
    ...     written = sorted(os.listdir(tmp))
    >>> written
    ['frame0_aligned.fits']
    >>> [f.status for f in result.frames]
    ['registered', 'failed']
    >>> bool(abs(result.frames[0].transform.rotation_deg - 30.0) < 0.1)
    True
    """
    _check_arguments(sources, canvas, skip_existing, output_dir, add_keyword, suffix, client,
                     workers, solve)
    callback = convert("callback", AnyCallable("a function of one FrameResult"), callback)
    resample = ResampleConfig(order=order, conserve_flux=conserve_flux, fill_value=fill_value,
                              method=method, add_keyword=add_keyword)
    if isinstance(target, Reference):
        # The reference's detection options are the batch's, unless overridden here.
        options = {**target.detect_options, **options}
    # The search's options, and those of the joint solution (solve_sequence's own).
    global_options = {k: options.pop(k) for k in SOLVE_OPTIONS if k in options}
    if global_options and solve != "global":
        raise TypeError(f"{sorted(global_options)} are options of solve='global'; pass "
                        "solve='global' too, or leave them out.")
    # Every option checked once, and the reference's stars and triangles
    # computed once, before it is shipped to the workers.
    config = RegistrationConfig.from_keywords(**options)
    ref = prepare_target(target, config, hdu)
    union = canvas == "union"
    # A list of (frame, label); or, for a generator, an iterator of them.
    items, frames_hdu = batch_frames(sources, hdu)
    stream = not isinstance(items, list)
    if stream and (union or solve == "global"):
        items, stream = list(items), False  # pass 2 needs every frame again
    protected = [os.fspath(target)] if _is_path(target) else []
    if output_dir is not None:
        output_dir = os.fspath(output_dir)
        make_output_dir(output_dir, "output_dir")
    jobs, outputs = _first_jobs(items, stream, union or solve == "global", output_dir, suffix,
                                protected)
    apply_options = dict(asdict(resample), unit=unit)
    cfg = _Config(reference=ref, options=config, apply_options=apply_options,
                  overwrite=overwrite, skip_existing=skip_existing, union=union,
                  hdu=frames_hdu, unit=unit, add_keyword=add_keyword,
                  batch_id=_batch_id(ref, options, apply_options, union, frames_hdu))
    total = None if stream else len(items) * (2 if union else 1)
    inflight = {}  # the jobs out on workers, by index (what an interrupt catches running)
    with _Report(callback, progress, total) as report:
        try:
            if solve == "global":
                found, solution = solve_jobs(jobs, items, target, ref,
                                             {**options, **global_options},
                                             (client, workers), report, cfg)
                result = _apply_found(found, items, outputs, cfg, client, workers, report,
                                      _valid_margin(resample), inflight)
                result.solution = solution
                return result
            if union:
                margin = _valid_margin(resample)
                return _run_union(jobs, items, outputs, cfg, client, workers, report, margin,
                                  inflight)
            with closing(_execute(jobs, cfg, client, workers, stream=stream,
                                  inflight=inflight)) as run:
                for job, res in run:
                    report.done(job.index, res)
        except KeyboardInterrupt as exc:  # (SIGTERM too, on the command line)
            # The workers are stopped (closing the runner stops them): what is done is final.
            exc.partial_result = _interrupted(report, jobs if not stream else (), inflight,
                                              cfg, ref.shape, exc)
            raise
        return BatchResult(_verified(report.in_order()), canvas_shape=ref.shape,
                           canvas_offset=(0, 0))


def _batch_id(ref, options, apply_options, union, hdu):
    """
    A digest of what every frame's output depends on besides the frame itself.

    Written (with the frame's name) into each output: a retried frame
    recognises the output of its earlier attempt.  A digest, not a random
    run id: the same inputs give the same headers from run to run.
    """
    import hashlib

    h = hashlib.sha256()
    data = np.ascontiguousarray(ref._parsed.data)
    h.update(repr((data.shape, data.dtype.str)).encode())
    h.update(data.tobytes())
    h.update(repr((sorted(options.items(), key=repr), sorted(apply_options.items(), key=repr),
                   union, hdu)).encode())
    return h.hexdigest()[:32]


def _interrupted(report, jobs, inflight, cfg, shape, exc):
    """
    The `BatchResult` of an interrupted batch: the frames done, and the
    others as failed (not done), except a frame whose worker finished its
    output just before the stop (the summary matches the files).
    """
    why = str(exc) or type(exc).__name__
    results = dict(report.results)
    t0 = time.perf_counter()
    pending = {job.index: job for job in jobs}
    pending.update(inflight)
    for i in sorted(pending):
        if i in results:
            continue
        job = pending[i]
        src = os.fspath(job.source) if _is_path(job.source) else None
        own = _own_output(job, cfg) if job.stage != "find" else None
        if own is not None:
            results[i] = _registered_before(job, own, src, t0)
        else:
            results[i] = _failed(job, Interrupted(
                f"not done: the batch was stopped ({why}) before this frame was finished; "
                "its output was not written. Run the batch again with skip_existing=True "
                "(--skip-existing) to finish it."), t0, src)
    return BatchResult(_verified([results[i] for i in sorted(results)]), canvas_shape=shape,
                       canvas_offset=(0, 0))


class Interrupted(Exception):
    """A frame that an interrupted batch did not finish (the error of its result)."""


def _check_arguments(sources, canvas, skip_existing, output_dir, add_keyword, suffix, client,
                     workers, solve="pairwise"):
    """Refuse `register_batch`'s bad arguments before any work."""
    if solve not in ("pairwise", "global"):
        raise ValueError(f"solve must be 'pairwise' or 'global'; got {solve!r}.")
    if _is_path(sources):
        raise TypeError("sources must be a list of frames or paths, not a single path; "
                        f"pass [{os.fspath(sources)!r}], or an ImageFileCollection for a "
                        "folder.")
    if canvas not in ("reference", "union"):
        raise ValueError(f"canvas must be 'reference' or 'union'; got {canvas!r}.")
    if skip_existing and output_dir is None:
        raise ValueError("skip_existing=True needs an output_dir (the outputs to look for).")
    if skip_existing and not add_keyword:
        raise ValueError("skip_existing=True reads each output's transform back from its "
                         "header, which add_keyword=False leaves out; pass add_keyword=True.")
    if not isinstance(suffix, str) or os.sep in suffix or (os.altsep and os.altsep in suffix):
        raise ValueError(f"suffix must be a string without path separators; got {suffix!r}.")
    if client is not None and workers not in (None, 0, 1):
        raise ValueError("give either client (dask.distributed) or workers (local processes), "
                         "not both.")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 0):
        raise ValueError(f"workers must be a non-negative integer; got {workers!r}.")


def _first_jobs(items, stream, union, output_dir, suffix, protected):
    """
    The jobs of the first pass and the output paths (None for a generator,
    whose frames are named as they arrive).
    """
    if stream:
        return _stream_jobs(items, _StreamNamer(output_dir, suffix, protected)), None
    names = display_names(items)
    outputs = [None] * len(items)
    if output_dir is not None:
        outputs, renamed = _plan_outputs(items, output_dir, suffix, protected)
        if renamed:
            warn("output names collide; renamed: " + "; ".join(
                f"{names[i]} -> {new} ({old} is taken)" for i, old, new in renamed))
    jobs = [_Job(i, frame, names[i], outputs[i], stage="find" if union else "full")
            for i, (frame, _) in enumerate(items)]
    return jobs, outputs


#: Why an output could not be written that every later frame would meet too (a full disk,
#: a read-only or removed folder): the batch stops at the first, with one error.
_STOPPING_ERRNOS = frozenset((errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES,
                              errno.EPERM, errno.ENOENT))


class _Report:
    """The results by input index; each one to the callback and the progress bar."""

    def __init__(self, callback, progress, total):
        self.results, self.callback, self.bar = {}, callback, None
        if progress:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, unit="frame")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.close()

    def done(self, i, res):
        """Frame ``i`` is finished with ``res``; a full disk stops the batch (`OSError`)."""
        if res._write_errno in _STOPPING_ERRNOS:
            n = sum(r.status == "registered" for r in self.results.values())
            stop = OSError(f"the batch stopped at {res.name}: {res.error.partition(': ')[2]} "
                           f"The {n} frame{'' if n == 1 else 's'} written before it "
                           "are complete: run the batch again with skip_existing=True "
                           "(--skip-existing) to finish.")
            stop.errno, stop.frame, stop.reason = res._write_errno, res.name, res.error
            raise stop
        self.results[i] = res
        if self.callback is not None:
            self.callback(res)
        self.tick()

    def tick(self):
        """One step of work done (a frame's first pass)."""
        if self.bar is not None:
            self.bar.update(1)

    def in_order(self):
        """The results as a list in input order."""
        return [self.results[i] for i in range(len(self.results))]


def _run_union(jobs, items, outputs, cfg, client, workers, report, margin, inflight=None):
    """The two passes of ``canvas='union'``: every transform, then the resampling."""
    # Pass 1: every transform (nothing of the frames is kept).
    found = {}
    with closing(_execute(jobs, cfg, client, workers, inflight=inflight)) as run:
        for job, res in run:
            if res.status == "failed":
                report.done(job.index, res)
            else:
                found[job.index] = res
                report.tick()
    return _apply_found(found, items, outputs, cfg, client, workers, report, margin, inflight)


def _apply_found(found, items, outputs, cfg, client, workers, report, margin, inflight):
    """The resampling pass: each frame of ``found`` (index -> FrameResult) with its transform."""
    if cfg.union:
        shape, offset = _union_grid(found, cfg.reference.shape, margin)
    else:
        shape, offset = tuple(cfg.reference.shape), (0, 0)
    wcs = canvas_wcs(cfg.reference._parsed.wcs, offset, shape)
    # Pass 2: resample onto the canvas.
    jobs2 = []
    for i in sorted(found):
        res = found[i]
        if res.status == "skipped":
            kept = _kept_on_canvas(res, shape, offset, cfg.overwrite)
            if kept is not None:
                report.done(i, kept)
                continue
        jobs2.append(_Job(i, items[i][0], res.name, outputs[i], stage="apply",
                          transform=shifted_transform(res.transform, offset, sign=-1),
                          quality=res.quality,
                          canvas=(shape, offset, wcs) if cfg.union else None,
                          source_shape=res.shape, points=res.points))
    seconds = {i: found[i].seconds for i in found}
    with closing(_execute(jobs2, cfg, client, workers, inflight=inflight)) as run:
        for job, res in run:
            res.seconds += seconds[job.index]
            report.done(job.index, res)
    return BatchResult(_verified(report.in_order()), canvas_shape=shape, canvas_offset=offset)
