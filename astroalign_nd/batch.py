# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Register many frames onto one reference: in this process, in a local pool
of worker processes, or on dask.distributed.

The reference's stars and triangles are computed once.  A bad frame does
not stop the batch: it is reported in the result, with the reason.  Output
names are fixed, and made unique, before any work; every file is written
atomically (`~astroalign_nd.io.atomic_write`), so an interrupted
night can be resumed with ``skip_existing=True``.
"""

from __future__ import annotations

import itertools
import os
import time
import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from astropy.table import Table

from ._input import batch_frames, parse_input
from .exceptions import warn
from .io.write import FITS_EXTENSIONS, _check_writable_dir, write_ccddata
from .registration import Reference, _find_for_apply, _prepared_target

__all__ = ["FrameResult", "BatchResult", "register_batch", "plan_outputs", "union_canvas"]

#: Status of a frame in a `BatchResult`.
_STATUSES = ("registered", "skipped", "failed")

#: Header keywords recording where a "union" canvas lies in reference pixels.
_CANVAS_KEYS = ("AACNVX0", "AACNVY0")
#: Header keywords recording the source frame's shape (a resumed union needs it).
_SOURCE_SHAPE_KEYS = ("AASRCNX", "AASRCNY")

#: Refuse canvases larger than this many pixels (about 1 GB per float32 frame).
_MAX_CANVAS_PIXELS = 2**28

_INPUT_EXTENSIONS = (*FITS_EXTENSIONS, ".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp",
                     ".gif")


@dataclass
class FrameResult:
    """
    The outcome for one frame of a batch.

    Attributes
    ----------
    name : str
        File name (the path as given when two inputs of a list share a file
        name; ``<name>#2``, ``#3``... for a generator's repeated names), the
        file name of a ``(frame, file name)`` pair, or ``frame<i>`` for
        in-memory inputs.
    status : {'registered', 'skipped', 'failed'}
        'skipped': a complete output was already there (``skip_existing``);
        its transform and quality are read back from that file's header.
    transform : model or None
        The transform applied: source to reference pixels, or source to
        canvas pixels with ``canvas='union'``.
    quality : dict or None
        As in ``transform.meta['quality']``.
    output : str or None
        The FITS file written (or kept), if ``output_dir`` was given.
    error : str or None
        ``'<ExceptionType>: message'`` for a failed frame.
    seconds : float
        Time spent on this frame (both passes with ``canvas='union'``).
    ccd : `~astropy.nddata.CCDData` or None
        The registered frame, when no ``output_dir`` was given.
    source : str or None
        The input path as given, None for in-memory inputs.
    shape : tuple or None
        The source frame's ``(ny, nx)``, where it was needed (``canvas='union'``).

    Examples
    --------
    >>> from astroalign_nd.batch import register_batch
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> frame = register_batch([pair.source], pair.target).frames[0]
    >>> frame.name, frame.status, frame.ok
    ('frame0', 'registered', True)
    >>> bool(frame.quality["rms"] < 1.0), frame.ccd.shape
    (True, (256, 256))
    """

    name: str
    status: str
    transform: object = None
    quality: dict = None
    output: str = None
    error: str = None
    seconds: float = 0.0
    ccd: object = field(default=None, repr=False)
    source: str = None
    shape: tuple = field(default=None, repr=False)  # the source frame's (ny, nx)
    _grid: tuple = field(default=None, repr=False)  # (shape, offset) of a kept output

    @property
    def ok(self):
        """True when the frame's registered image exists (registered or skipped)."""
        return self.status != "failed"


@dataclass
class BatchResult:
    """
    All frames of a batch, in input order.

    Attributes
    ----------
    frames : list of `FrameResult`
    canvas_shape : tuple or None
        ``(ny, nx)`` of the output grid.
    canvas_offset : tuple or None
        ``(x0, y0)``: reference pixel coordinates of the output grid's pixel
        ``(0, 0)``; ``(0, 0)`` for ``canvas='reference'``.

    Examples
    --------
    A batch of one good frame and one without stars:

    >>> import numpy as np
    >>> from astroalign_nd.batch import register_batch
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> result = register_batch([pair.source, np.zeros((64, 64))], pair.target)
    >>> print(result.summary())
    1 of 2 frames registered, 1 failed
      FAILED frame1: TooFewSourcesError: ...
    >>> [f.name for f in result.succeeded], [f.name for f in result.failed]
    (['frame0'], ['frame1'])
    >>> result.to_table()["status"].tolist(), result.canvas_shape
    (['registered', 'failed'], (256, 256))
    """

    frames: list
    canvas_shape: tuple = None
    canvas_offset: tuple = (0, 0)

    @property
    def succeeded(self):
        """The frames registered in this run."""
        return [f for f in self.frames if f.status == "registered"]

    @property
    def skipped(self):
        """The frames whose complete output was already there (``skip_existing``)."""
        return [f for f in self.frames if f.status == "skipped"]

    @property
    def failed(self):
        """The frames that could not be registered (see their ``error``)."""
        return [f for f in self.frames if f.status == "failed"]

    def to_table(self):
        """
        One row per frame, in input order.

        Columns: ``name``, ``status``, ``ok`` (registered or skipped:
        the output is there), ``n_matches``, ``rms`` (px),
        ``log10_false_alarm``, ``seconds``, ``error``, ``output`` and
        ``source``.  Write it with ``result.to_table().write('night.ecsv')``.
        """
        rows = []
        for f in self.frames:
            q = f.quality or {}
            rows.append((f.name, f.status, f.ok, int(q.get("n_matches", 0)),
                         float(q.get("rms", np.nan)),
                         float(q.get("log10_false_alarm", np.nan)), float(f.seconds),
                         f.error or "", f.output or "", f.source or ""))
        t = Table(rows=rows or None,
                  names=("name", "status", "ok", "n_matches", "rms", "log10_false_alarm",
                         "seconds", "error", "output", "source"),
                  dtype=(str, str, bool, int, float, float, float, str, str, str))
        t["rms"].unit = "pix"
        t["seconds"].unit = "s"
        if self.canvas_shape is not None:
            t.meta["canvas_shape"] = list(self.canvas_shape)
            t.meta["canvas_offset"] = list(self.canvas_offset)
        return t

    def summary(self):
        """A short human-readable report."""
        n = len(self.frames)
        line = f"{len(self.succeeded)} of {n} frames registered"
        if self.skipped:
            line += f", {len(self.skipped)} skipped (complete output already there)"
        if self.failed:
            line += f", {len(self.failed)} failed"
        lines = [line]
        for f in self.failed:
            lines.append(f"  FAILED {f.name}: {f.error}")
        return "\n".join(lines)


# -- output names ----------------------------------------------------------------------------


def _is_path(src):
    return isinstance(src, (str, os.PathLike))


def _stem(name):
    low = name.lower()
    for ext in sorted(_INPUT_EXTENSIONS, key=len, reverse=True):
        if low.endswith(ext):
            return name[: -len(ext)]
    return name


def _base(label, i):
    """A frame's short name: its file name, or ``frame<i>`` in memory."""
    return os.path.basename(label) if label is not None else f"frame{i}"


def _in_folder(path, folder_real):
    """True when ``path`` (as given) names a file directly inside ``folder_real``."""
    return os.path.realpath(os.path.dirname(os.path.abspath(path))) == folder_real


def _located(frame, label):
    """The input file a frame was read from, when known (it must never be written to)."""
    if _is_path(frame):
        return os.fspath(frame)
    if label is not None and os.path.dirname(label):  # a pair's file name with its folder
        return label
    return None


def _display_names(items):
    """Basenames, or the label as given where two inputs share a basename."""
    base = [_base(label, i) for i, (_, label) in enumerate(items)]
    counts = {}
    for b in base:
        counts[b] = counts.get(b, 0) + 1
    names = [label if label is not None and counts[b] > 1 else b
             for (_, label), b in zip(items, base)]
    seen, out = {}, []
    for n in names:  # the same path given twice
        k = seen.get(n, 0)
        seen[n] = k + 1
        out.append(n if k == 0 else f"{n}#{k + 1}")
    return out


def plan_outputs(sources, output_dir, suffix="_aligned", protected=()):
    """
    Output file of each frame, unique by construction.

    A frame's natural output is ``<stem><suffix>.fits``, where ``stem`` is
    its file name without the extension (``frame<i>`` in memory; the file
    name of a ``(frame, file name)`` pair).  When two frames would share it
    (``in/a.fits`` and ``in2/a.fits``, ``a.fits`` and ``a.fit``, or names
    differing only in case, which collide on macOS and Windows), or when it
    would replace an input file, the later frame in input order gets
    ``<stem>_2<suffix>.fits`` (``_3``...), skipping every name that another
    frame uses naturally.  The same input list always gives the same names,
    so a resumed run finds its outputs again.

    Parameters
    ----------
    sources : list or `~ccdproc.ImageFileCollection`
        The frames, as given to `register_batch`.
    output_dir : str
    suffix : str, optional
    protected : iterable of str, optional
        Further input paths that must never be written to (the target).

    Returns
    -------
    paths : list of str
        One output path per frame.
    renamed : list of (int, str, str)
        ``(index, natural name, name used)`` for each frame renamed.

    Examples
    --------
    Two inputs named ``m31.fits`` in different folders:

    >>> import os
    >>> from astroalign_nd.batch import plan_outputs
    >>> paths, renamed = plan_outputs(
    ...     ["night1/m31.fits", "night2/m31.fits", "m33.fit"], "out")
    >>> [os.path.basename(p) for p in paths]
    ['m31_aligned.fits', 'm31_2_aligned.fits', 'm33_aligned.fits']
    >>> renamed
    [(1, 'm31_aligned.fits', 'm31_2_aligned.fits')]
    """
    items, _ = batch_frames(sources)
    return _plan_outputs(list(items), output_dir, suffix, protected)


def _plan_outputs(items, output_dir, suffix, protected):
    stems = [_stem(_base(label, i)) for i, (_, label) in enumerate(items)]
    natural = [f"{s}{suffix}.fits" for s in stems]
    out_real = os.path.realpath(output_dir)
    located = [_located(frame, label) for frame, label in items]
    inputs = {os.path.basename(os.fspath(p)).casefold()
              for p in [*located, *protected] if p is not None and _in_folder(p, out_real)}
    reserved = {n.casefold() for n in natural}
    used, paths, renamed = set(), [], []
    for i, (stem, nat) in enumerate(zip(stems, natural)):
        chosen = nat
        if nat.casefold() in used or nat.casefold() in inputs:
            k = 2
            while True:
                chosen = f"{stem}_{k}{suffix}.fits"
                key = chosen.casefold()
                if key not in used and key not in reserved and key not in inputs:
                    break
                k += 1
            renamed.append((i, nat, chosen))
        used.add(chosen.casefold())
        paths.append(os.path.join(output_dir, chosen))
    return paths, renamed


class _StreamNamer:
    """
    Names and outputs of a generator's frames, decided as each frame arrives.

    A generator cannot be looked ahead, so the rule is `plan_outputs`'s
    without the reservation of later frames' natural names: a frame whose
    natural output is already used in this run, or is an input file seen
    so far (or the target), gets the next free ``_2``, ``_3``... name, and
    a display name already shown gets ``#2``, ``#3``...  Deterministic: the
    same sequence of frames always gives the same names.
    """

    def __init__(self, output_dir, suffix, protected):
        self.output_dir, self.suffix = output_dir, suffix
        self.out_real = os.path.realpath(output_dir) if output_dir is not None else None
        self.inputs = {os.path.basename(os.fspath(p)).casefold() for p in protected
                       if self.out_real is not None and _in_folder(p, self.out_real)}
        self.used, self.shown = set(), set()

    def __call__(self, i, frame, label):
        """``(display name, output path or None, renamed (natural, used) or None)``."""
        base = name = _base(label, i)
        k = 2
        while name in self.shown:
            name, k = f"{base}#{k}", k + 1
        self.shown.add(name)
        if self.output_dir is None:
            return name, None, None
        here = _located(frame, label)
        if here is not None and _in_folder(here, self.out_real):
            self.inputs.add(os.path.basename(here).casefold())
        stem = _stem(base)
        natural = chosen = f"{stem}{self.suffix}.fits"
        k = 2
        while chosen.casefold() in self.used or chosen.casefold() in self.inputs:
            chosen, k = f"{stem}_{k}{self.suffix}.fits", k + 1
        self.used.add(chosen.casefold())
        return name, os.path.join(self.output_dir, chosen), (
            None if chosen == natural else (natural, chosen))


# -- resuming --------------------------------------------------------------------------------


def _read_done(path):
    """
    The transform, quality, shape and canvas origin recorded in a complete
    registered frame, or a reason why ``path`` is not one.
    """
    from astropy.io import fits

    from .io.header import transform_from_header

    try:
        # A warning ("file may have been truncated") counts as incomplete.  It
        # is recorded, not raised: raised inside fits.open it would leave the
        # file open; here the file is ours to close, whatever happens.
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with open(path, "rb") as fh, fits.open(
                    fh, memmap=not path.lower().endswith(".gz")) as hdul:
                hdul.readall()
                for hdu in hdul:  # every data block is there, in full
                    if hdu.data is not None:
                        np.asarray(hdu.data).ravel()[-1:].copy()
                header = hdul[0].header
                shape = hdul[0].data.shape[:2] if hdul[0].data is not None else None
    except Exception as exc:  # noqa: BLE001 - any unreadable file is not complete
        return None, f"it is incomplete or unreadable ({type(exc).__name__}: {exc})"
    if caught:
        w = caught[0]
        return None, (f"it is incomplete or unreadable ({w.category.__name__}: "
                      f"{w.message})")
    if shape is None or "AATTYPE" not in header:
        return None, "it is not a frame registered by astroalign_nd"
    try:
        transform = transform_from_header(header)
    except Exception as exc:  # noqa: BLE001
        return None, f"its transform keywords cannot be read ({exc})"
    quality = {}
    for key, name in (("AATNMAT", "n_matches"), ("AATRMS", "rms"),
                      ("AATLFA", "log10_false_alarm")):
        if key in header:
            quality[name] = header[key]
    offset = tuple(int(header[k]) for k in _CANVAS_KEYS) if all(
        k in header for k in _CANVAS_KEYS) else (0, 0)
    source_shape = (int(header[_SOURCE_SHAPE_KEYS[1]]), int(header[_SOURCE_SHAPE_KEYS[0]])) \
        if all(k in header for k in _SOURCE_SHAPE_KEYS) else None
    return dict(transform=transform, quality=quality, shape=tuple(shape), offset=offset,
                source_shape=source_shape), None


# -- the work on one frame (runs on workers) -------------------------------------------------


@dataclass
class _Config:
    """What every frame needs: shipped to each worker once, with the reference."""

    reference: object
    options: dict
    apply_options: dict
    overwrite: bool
    skip_existing: bool
    union: bool
    hdu: object = None  # the HDU to read from the frames' files
    unit: object = None  # the unit of frames without one
    add_keyword: bool = True  # record the registration (and canvas) in each header


@dataclass
class _Job:
    index: int
    source: object
    name: str
    output: str = None
    stage: str = "full"  # 'full': find and apply; 'find' / 'apply': the two union passes
    transform: object = None
    quality: dict = None
    canvas: tuple = None  # (shape, (x0, y0), wcs) for the 'apply' stage
    source_shape: tuple = None


def _failed(job, exc, t0, src_path=None):
    if src_path is None and _is_path(job.source):
        src_path = os.fspath(job.source)
    return FrameResult(name=job.name, status="failed", error=f"{type(exc).__name__}: {exc}",
                       seconds=time.perf_counter() - t0, output=None, source=src_path)


def _skip_or_refuse(job, cfg):
    """A complete output to keep (dict), or None to (re)do the frame; raises if refused."""
    if job.output is None or not os.path.lexists(job.output):
        return None
    if cfg.skip_existing:
        done, why = _read_done(job.output)
        if done is not None:
            return _same_grid(done, job, cfg)
        if not cfg.overwrite:
            raise FileExistsError(f"{job.output} exists but {why}; pass overwrite=True (or "
                                  "--overwrite) to redo this frame.")
        return None
    if not cfg.overwrite:
        raise FileExistsError(f"{job.output} exists; pass overwrite=True (or --overwrite) to "
                              "replace it, or skip_existing=True (--skip-existing) to keep "
                              "complete outputs.")
    return None


def _same_grid(done, job, cfg):
    """A kept output ``done`` if this run can keep it, None to redo it; raises if refused."""
    if not cfg.union and (tuple(done["offset"]) != (0, 0)
                          or tuple(done["shape"]) != cfg.reference.shape):
        if not cfg.overwrite:
            raise FileExistsError(f"{job.output} was registered onto another grid (a "
                                  "'union' canvas); pass overwrite=True (or --overwrite) "
                                  "to redo it.")
        done = None
    if done is not None and cfg.union and done["source_shape"] is None:
        if not cfg.overwrite:
            raise FileExistsError(f"{job.output} does not record its source's shape, "
                                  "needed for a 'union' canvas; pass overwrite=True (or "
                                  "--overwrite) to redo it.")
        done = None
    return done


def _run(job, cfg):
    """Process one frame; never raises (a batch must go on)."""
    t0 = time.perf_counter()
    src_path = os.fspath(job.source) if _is_path(job.source) else None
    try:
        if job.stage == "apply":
            return _apply_stage(job, cfg, t0, src_path)
        done = _skip_or_refuse(job, cfg)
        if done is not None:
            transform = done["transform"]
            if cfg.union:  # back to reference pixels, for the canvas computation
                transform = _shifted(transform, done["offset"], sign=+1)
            return FrameResult(name=job.name, status="skipped", transform=transform,
                               quality=done["quality"], output=job.output, source=src_path,
                               seconds=time.perf_counter() - t0, shape=done["source_shape"],
                               _grid=(done["shape"], done["offset"]))
        # Read (parsed) once, here on the worker, for both stages.
        src, _, transform, quality = _find_for_apply(job.source, cfg.reference, cfg.options,
                                                     hdu=cfg.hdu, unit=cfg.unit)
        if job.stage == "find":
            return FrameResult(name=job.name, status="registered", transform=transform,
                               quality=quality, source=src_path, output=job.output,
                               shape=src.shape, seconds=time.perf_counter() - t0)
        # A copy: the caller's job list must not keep the frame's pixels alive.
        job = replace(job, source=src, transform=transform, quality=quality,
                      canvas=None, source_shape=src.shape)
        return _apply_stage(job, cfg, t0, src_path)
    except Exception as exc:  # noqa: BLE001 - report every failure, keep going
        return _failed(job, exc, t0, src_path)


def _apply_stage(job, cfg, t0, src_path=None):
    from .ccddata import apply_transform

    # Already parsed in the 'full' stage (a Reference); read here in 'apply'.
    src = parse_input(job.source, "source", hdu=cfg.hdu, unit=cfg.unit)
    if job.canvas is None:
        ccd = apply_transform(job.transform, src, cfg.reference,
                              quality=job.quality, **cfg.apply_options)
    else:
        shape, offset, wcs = job.canvas
        ccd = apply_transform(job.transform, src, tuple(shape), quality=job.quality,
                              **cfg.apply_options)
        if wcs is not None:
            ccd.wcs = wcs
        if cfg.add_keyword:
            ccd.meta[_CANVAS_KEYS[0]] = (int(offset[0]), "canvas x0 [reference px]")
            ccd.meta[_CANVAS_KEYS[1]] = (int(offset[1]), "canvas y0 [reference px]")
    src_shape = job.source_shape or src.shape
    if cfg.add_keyword:  # what a resumed run needs to find this frame's grid again
        ccd.meta[_SOURCE_SHAPE_KEYS[0]] = (int(src_shape[1]), "source frame width [px]")
        ccd.meta[_SOURCE_SHAPE_KEYS[1]] = (int(src_shape[0]), "source frame height [px]")
    if job.output is not None:
        # FLAGS as an extension, so that CCDData.read(..., hdu_flags='FLAGS') reads it back.
        write_ccddata(ccd, job.output, overwrite=cfg.overwrite, hdu_flags="FLAGS")
        ccd = None  # memory stays flat: nothing of the frame is kept
    return FrameResult(name=job.name, status="registered", transform=job.transform,
                       quality=job.quality, output=job.output, ccd=ccd, source=src_path,
                       seconds=time.perf_counter() - t0)


# -- the union canvas ------------------------------------------------------------------------


def _shifted(transform, offset, sign):
    """``transform`` followed by a shift of ``sign * offset`` pixels."""
    from .transforms import as_matrix, from_matrix

    m = as_matrix(transform).copy()
    m[0, 2] += sign * offset[0]
    m[1, 2] += sign * offset[1]
    out = from_matrix(m, transform_type=_type_of(transform))
    out.meta.update(getattr(transform, "meta", {}) or {})
    return out


def _type_of(transform):
    from .transforms import TRANSFORM_TYPES

    for name, cls in TRANSFORM_TYPES.items():
        if type(transform) is cls:
            return name
    return None


def _valid_margin(order):
    """
    How far inside the frame's edge pixel centres the resampling is valid
    (see `~astroalign_nd.resample.resample`): a frame's pixels count from
    ``margin`` to ``n - 1 - margin``; -0.5 for nearest-neighbour, 0 for
    bilinear, 0.5 for biquadratic and 1 for bicubic interpolation.
    """
    from .resample import _parse_order

    return (_parse_order(order) - 1) / 2.0


def union_canvas(transforms, shapes, reference_shape, margin=0.0):
    """
    The smallest grid, aligned with the reference's pixels, that holds the
    reference and every frame mapped into it.

    Like reproject's ``find_optimal_celestial_wcs``, but from the fitted
    transforms and without resampling the reference: the canvas is the
    reference's grid shifted by whole pixels and enlarged.

    Parameters
    ----------
    transforms : list of models
        Source-to-reference transforms.
    shapes : list of (ny, nx)
        The source frames' shapes.
    reference_shape : (ny, nx)
    margin : float, optional
        Source positions ``margin <= x <= nx - 1 - margin`` can be
        resampled (0 for bilinear interpolation, which needs the pixels on
        both sides); canvas pixels beyond would be masked in every frame.

    Returns
    -------
    shape : (ny, nx)
        Canvas shape.
    offset : (x0, y0)
        Reference pixel coordinates of canvas pixel ``(0, 0)`` (integers,
        so that the reference's pixels fall exactly on canvas pixels).

    Examples
    --------
    A 100 x 100 frame shifted by 50.5 pixels in x and -20 in y from a
    100 x 100 reference:

    >>> import numpy as np
    >>> from astroalign_nd.batch import union_canvas
    >>> shift = np.array([[1.0, 0.0, 50.5], [0.0, 1.0, -20.0], [0.0, 0.0, 1.0]])
    >>> union_canvas([shift], [(100, 100)], (100, 100))
    ((120, 150), (0, -20))
    """
    from .transforms import as_matrix

    ny, nx = reference_shape
    xs, ys = [0.0, nx - 1.0], [0.0, ny - 1.0]
    for t, (h, w) in zip(transforms, shapes):
        m = as_matrix(t)
        lo_x, hi_x, lo_y, hi_y = margin, w - 1.0 - margin, margin, h - 1.0 - margin
        cx = np.array([lo_x, hi_x, lo_x, hi_x])
        cy = np.array([lo_y, lo_y, hi_y, hi_y])
        xs.extend(m[0, 0] * cx + m[0, 1] * cy + m[0, 2])
        ys.extend(m[1, 0] * cx + m[1, 1] * cy + m[1, 2])
    # Canvas pixel centres inside the mapped frames: a pixel whose centre is
    # outside all of them would be masked in every frame.
    eps = 1e-6
    x0, x1 = int(np.ceil(min(xs) - eps)), int(np.floor(max(xs) + eps))
    y0, y1 = int(np.ceil(min(ys) - eps)), int(np.floor(max(ys) + eps))
    return (y1 - y0 + 1, x1 - x0 + 1), (x0, y0)


def _canvas_wcs(wcs, offset, shape):
    if wcs is None:
        return None
    w = wcs.deepcopy()
    w.wcs.crpix = [w.wcs.crpix[0] - offset[0], w.wcs.crpix[1] - offset[1]]
    w.pixel_shape = (shape[1], shape[0])
    return w


# -- running jobs ----------------------------------------------------------------------------

_WORKER_CONFIG = None


def _init_worker(cfg, threads):
    global _WORKER_CONFIG
    _WORKER_CONFIG = cfg
    # Several processes share the cores: do not let each run every core's
    # threads, unless the user chose how many.
    from . import _kernels
    from ._config import conf

    if not _kernels._threads_chosen():
        conf.num_threads = threads


def _run_in_worker(job):
    return _run(job, _WORKER_CONFIG)


def _execute(jobs, cfg, client, workers, stream=False):
    """
    Run the jobs; yield ``(job, FrameResult)`` in completion order.

    ``jobs`` may be a generator (a batch's generator of frames): jobs are
    taken from it only as workers free up, a few in flight per worker, so
    that the frames of a generator are never all in memory at once.
    """
    jobs = iter(jobs)
    first = next(jobs, None)
    if first is None:
        return
    jobs = _prepend(first, jobs)
    del first
    if client is not None:
        yield from _execute_dask(jobs, cfg, client, stream)
        return
    if workers is None or workers <= 1:
        for job in jobs:
            yield job, _run(job, cfg)
        return
    yield from _execute_pool(jobs, cfg, workers)


def _prepend(first, rest):
    """``first``, then ``rest``; unlike itertools.chain([first], rest), ``first`` is let go."""
    box = [first]
    del first  # a generator's first frame must not stay alive for the whole batch
    yield box.pop()
    yield from rest


def _execute_dask(jobs, cfg, client, stream):
    from dask.distributed import as_completed

    cfg_future = client.scatter(cfg, broadcast=True)
    by_key, running = {}, as_completed()

    def submit(job):
        fut = client.submit(_run, job, cfg_future, pure=False)
        by_key[fut.key] = job
        running.add(fut)

    # A list of frames is submitted at once (the scheduler plans it all); a
    # generator's frames a few per worker thread at a time.
    window = max(2, 2 * sum(client.nthreads().values())) if stream else None
    for job in itertools.islice(jobs, window):
        submit(job)
    for fut in running:
        job = by_key.pop(fut.key)
        try:
            res = fut.result()
        except Exception as exc:  # a worker died: report, go on
            res = _failed(job, exc, time.perf_counter())
        fut.release()
        yield job, res
        if stream:
            nxt = next(jobs, None)
            if nxt is not None:
                submit(nxt)


def _execute_pool(jobs, cfg, workers):
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    # fork starts fast and needs no importable __main__; the compiled loops'
    # thread pool is re-created in the child (see _kernels).
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods and os.name == "posix"
                                      and not _is_macos() else None)
    threads = max(1, (os.cpu_count() or 1) // workers)
    pending, back = {}, []  # ``back``: a job whose submission failed

    def next_job():
        return back.pop() if back else next(jobs, None)

    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker,
                             initargs=(cfg, threads)) as pool:
        broken = None
        while True:
            # A few frames in flight per worker: memory does not grow with the batch.
            while len(pending) < 2 * workers and broken is None:
                job = next_job()
                if job is None:
                    break
                try:
                    pending[pool.submit(_run_in_worker, job)] = job
                except Exception as exc:  # the pool broke
                    broken = exc
                    back.append(job)
            if broken is not None and not pending:
                for job in itertools.chain(back, jobs):
                    yield job, _failed(job, RuntimeError(
                        f"not run: a worker process died ({broken})"), time.perf_counter())
                return
            if not pending:
                return
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                job = pending.pop(fut)
                try:
                    res = fut.result()
                except Exception as exc:  # the worker died (out of memory?)
                    broken = broken or exc
                    res = _failed(job, RuntimeError(f"a worker process died while "
                                                    f"registering this frame ({exc!r})"),
                                  time.perf_counter())
                yield job, res


def _is_macos():
    import sys

    return sys.platform == "darwin"


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


def _stream_jobs(items, namer):
    """Jobs of a generator's frames, named as they arrive; nothing of earlier frames kept."""
    for i, (frame, label) in enumerate(items):
        name, output, renamed = namer(i, frame, label)
        if renamed is not None:
            warn(f"output names collide; renamed: {name} -> {renamed[1]} ({renamed[0]} "
                 "is taken)")
        yield _Job(i, frame, name, output, stage="full")


# -- the public function ---------------------------------------------------------------------


def register_batch(sources: Iterable[Any] | Any, target: Any, *,
                   output_dir: str | os.PathLike | None = None, overwrite: bool = False,
                   skip_existing: bool = False, suffix: str = "_aligned",
                   canvas: str = "reference", client: Any = None, workers: int | None = None,
                   progress: bool = False, callback: Callable[[FrameResult], Any] | None = None,
                   order: str | int = "bilinear", conserve_flux: bool = False,
                   fill_value: float = np.nan, method: str = "interpolate", unit: Any = None,
                   hdu: int | str | None = None, add_keyword: bool = True,
                   **options: Any) -> BatchResult:
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
    from .transforms import transform_class

    _check_arguments(sources, canvas, skip_existing, output_dir, add_keyword, suffix, client,
                     workers)
    transform_class(options.get("transform_type", "similarity"))
    # Every option checked, and the reference's stars and triangles computed
    # once, before it is shipped to the workers.
    ref = _prepared_target(target, options, hdu)
    union = canvas == "union"
    # A list of (frame, label); or, for a generator, an iterator of them.
    items, frames_hdu = batch_frames(sources, hdu)
    stream = not isinstance(items, list)
    if stream and union:
        items, stream = list(items), False  # pass 2 needs every frame again
    if isinstance(target, Reference):
        # The reference's detection options are the batch's, unless overridden here.
        options = {**target.detect_options, **options}
    protected = [os.fspath(target)] if _is_path(target) else []
    if output_dir is not None:
        output_dir = os.fspath(output_dir)
        os.makedirs(output_dir, exist_ok=True)
        _check_writable_dir(output_dir)
    jobs, outputs = _first_jobs(items, stream, union, output_dir, suffix, protected)
    apply_options = dict(order=order, conserve_flux=conserve_flux, fill_value=fill_value,
                         method=method, unit=unit, add_keyword=add_keyword)
    cfg = _Config(reference=ref, options=options, apply_options=apply_options,
                  overwrite=overwrite, skip_existing=skip_existing, union=union,
                  hdu=frames_hdu, unit=unit, add_keyword=add_keyword)
    total = None if stream else len(items) * (2 if union else 1)
    with _Report(callback, progress, total) as report:
        if union:
            margin = -0.5 if method == "exact" else _valid_margin(order)
            return _run_union(jobs, items, outputs, cfg, client, workers, report, margin)
        for job, res in _execute(jobs, cfg, client, workers, stream=stream):
            report.done(job.index, res)
        return BatchResult(_verified(report.in_order()), canvas_shape=ref.shape,
                           canvas_offset=(0, 0))


def _check_arguments(sources, canvas, skip_existing, output_dir, add_keyword, suffix, client,
                     workers):
    """Refuse `register_batch`'s bad arguments before any work."""
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
    names = _display_names(items)
    outputs = [None] * len(items)
    if output_dir is not None:
        outputs, renamed = _plan_outputs(items, output_dir, suffix, protected)
        if renamed:
            warn("output names collide; renamed: " + "; ".join(
                f"{names[i]} -> {new} ({old} is taken)" for i, old, new in renamed))
    jobs = [_Job(i, frame, names[i], outputs[i], stage="find" if union else "full")
            for i, (frame, _) in enumerate(items)]
    return jobs, outputs


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
        """Frame ``i`` is finished with ``res``."""
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


def _run_union(jobs, items, outputs, cfg, client, workers, report, margin):
    """The two passes of ``canvas='union'``: every transform, then the resampling."""
    # Pass 1: every transform (nothing of the frames is kept).
    found = {}
    for job, res in _execute(jobs, cfg, client, workers):
        if res.status == "failed":
            report.done(job.index, res)
        else:
            found[job.index] = res
            report.tick()
    shape, offset = _union_grid(found, cfg.reference.shape, margin)
    wcs = _canvas_wcs(cfg.reference._parsed.wcs, offset, shape)
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
                          transform=_shifted(res.transform, offset, sign=-1),
                          quality=res.quality, canvas=(shape, offset, wcs),
                          source_shape=res.shape))
    seconds = {i: found[i].seconds for i in found}
    for job, res in _execute(jobs2, cfg, client, workers):
        res.seconds += seconds[job.index]
        report.done(job.index, res)
    return BatchResult(_verified(report.in_order()), canvas_shape=shape, canvas_offset=offset)


def _union_grid(found, reference_shape, margin):
    """The union canvas of the frames found (`union_canvas`), refused if too large."""
    if not found:
        return tuple(reference_shape), (0, 0)
    order_ = sorted(found)
    shape, offset = union_canvas([found[i].transform for i in order_],
                                 [found[i].shape for i in order_], reference_shape,
                                 margin=margin)
    if shape[0] * shape[1] > _MAX_CANVAS_PIXELS:
        area = {i: np.prod(union_canvas([found[i].transform], [found[i].shape],
                                        reference_shape, margin=margin)[0]) for i in found}
        worst = max(area, key=area.get)
        raise ValueError(
            f"the union canvas would be {shape[1]}x{shape[0]} pixels, more than "
            f"{_MAX_CANVAS_PIXELS}: some frames land very far from the reference (the "
            f"farthest is {found[worst].name}, transform {found[worst].transform!r}). "
            "Leave such frames out, or use canvas='reference'.")
    return shape, offset


def _kept_on_canvas(res, shape, offset, overwrite):
    """
    A skipped frame's result if its output lies on this canvas, a failure
    if it lies on another and may not be replaced, or None to redo it.
    """
    if tuple(res._grid[0]) == tuple(shape) and tuple(res._grid[1]) == tuple(offset):
        res.transform = _shifted(res.transform, offset, sign=-1)
        return res
    if not overwrite:
        return FrameResult(
            name=res.name, status="failed", source=res.source,
            error=f"FileExistsError: {res.output} was registered onto another "
            "canvas (the set of frames changed); pass overwrite=True (or "
            "--overwrite) to redo it.")
    return None
