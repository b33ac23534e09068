# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""One frame of a batch: register it, write it, report it."""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field, replace
from ..io.read import parse_input
from ..exceptions import warn
from ..io import WRITERS, writer_for
from ..registration import find_for_apply, quality_dict
from ..resample import apply_transform
from ..transforms import as_matrix, from_matrix
from ..transforms.registry import transform_type_of
from .results import FrameResult
from .planning import _CANVAS_KEYS, _SOURCE_SHAPE_KEYS, _is_path, _read_done, _skip_or_refuse

__all__ = []

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
    batch_id: str = None  # digest of the reference and options (see _job_id)
    # The output formats, as registered when the batch starts: workers (other
    # processes) write and resume with the same ones.
    writers: dict = field(default_factory=lambda: dict(WRITERS))


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
    before: object = None  # the output's _stat_key when the batch first sent the frame out
    points: tuple = None  # the matched positions, carried to the result


def _failed(job, exc, t0, src_path=None):
    if src_path is None and _is_path(job.source):
        src_path = os.fspath(job.source)
    return FrameResult(name=job.name, status="failed", error=f"{type(exc).__name__}: {exc}",
                       seconds=time.perf_counter() - t0, output=None, source=src_path)


#: Header keyword of a written frame: which batch and frame wrote it (a retry knows its own).
_JOB_KEY = "AABATCH"


def _stat_key(path):
    """What identifies the file at ``path`` now: False if there is none, None if unknown."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def _job_id(job, cfg):
    """The frame's identity in this batch, as its output's header records it."""
    import hashlib

    key = "\0".join((cfg.batch_id, job.name, os.path.basename(job.output)))
    return hashlib.sha256(key.encode("utf-8", "surrogatepass")).hexdigest()[:32]


def _own_output(job, cfg):
    """
    The frame's complete output written by an earlier attempt of this batch
    (a retry after a worker died), as `_read_done` reads it; else None.

    Its own: the file appeared (or was replaced) after the batch first sent
    the frame out, and its header names this batch and frame.
    """
    if job.output is None or job.before is None or cfg.batch_id is None or not cfg.add_keyword:
        return None
    now = _stat_key(job.output)
    if not now or now == job.before:  # none, or the file that was there before
        return None
    done, _ = _read_done(job.output)
    if done is None:
        return None
    from astropy.io import fits

    try:
        if fits.getval(job.output, _JOB_KEY, ext=0) != _job_id(job, cfg):
            return None
    except (OSError, KeyError):
        return None
    return done


def _run(job, cfg):
    """Process one frame; never raises (a batch must go on)."""
    t0 = time.perf_counter()
    src_path = os.fspath(job.source) if _is_path(job.source) else None
    try:
        own = _own_output(job, cfg) if job.stage != "find" else None
        if own is not None:  # a retry: the first attempt wrote it, then its worker died
            return _registered_before(job, own, src_path, t0)
        if job.stage == "apply":
            return _apply_stage(job, cfg, t0, src_path)
        done = _skip_or_refuse(job, cfg)
        if done is not None:
            return _skipped(job, done, cfg, src_path, time.perf_counter() - t0)
        # Read (parsed) once, here on the worker, for both stages.
        src, _, result = find_for_apply(job.source, cfg.reference, cfg.options, hdu=cfg.hdu,
                                        unit=cfg.unit)
        transform, quality = result.transform, quality_dict(result)
        points = (result.source_points, result.target_points)
        if job.stage == "find":
            return FrameResult(name=job.name, status="registered", transform=transform,
                               quality=quality, source=src_path, output=job.output,
                               shape=src.shape, seconds=time.perf_counter() - t0,
                               points=points)
        # A copy: the caller's job list must not keep the frame's pixels alive.
        job = replace(job, source=src, transform=transform, quality=quality,
                      canvas=None, source_shape=src.shape, points=points)
        return _apply_stage(job, cfg, t0, src_path)
    except Exception as exc:  # noqa: BLE001 - report every failure, keep going
        return _failed(job, exc, t0, src_path)


def _skipped(job, done, cfg, src_path, seconds):
    """A frame whose complete output is kept (``skip_existing``), as `_skip_or_refuse` read it."""
    transform = done["transform"]
    if cfg.union:  # back to reference pixels, for the canvas computation
        transform = shifted_transform(transform, done["offset"], sign=+1)
    return FrameResult(name=job.name, status="skipped", transform=transform,
                       quality=done["quality"], output=job.output, source=src_path,
                       seconds=seconds, shape=done["source_shape"],
                       _grid=(done["shape"], done["offset"]))


def _registered_before(job, done, src_path, t0):
    """The result of a frame whose earlier attempt in this batch wrote its output."""
    if job.stage == "apply":  # the transform onto the canvas, as the first pass found it
        transform, quality = job.transform, job.quality
    else:
        transform, quality = done["transform"], done["quality"]
    return FrameResult(name=job.name, status="registered", transform=transform,
                       quality=quality, output=job.output, source=src_path,
                       seconds=time.perf_counter() - t0)


def _apply_stage(job, cfg, t0, src_path=None):
    # Already parsed in the 'full' stage (a Reference); read here in 'apply'.
    src = parse_input(job.source, "source", hdu=cfg.hdu, unit=cfg.unit)
    if job.canvas is None:
        ccd = apply_transform(job.transform, src, cfg.reference,
                              quality=job.quality, **cfg.apply_options)
    else:
        shape, offset, wcs = job.canvas
        ccd = apply_transform(job.transform, src, tuple(shape), quality=job.quality,
                              target_name=canvas_name(cfg.reference, shape, offset),
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
        if cfg.batch_id is not None and job.output is not None:
            ccd.meta[_JOB_KEY] = (_job_id(job, cfg), "batch+frame id (for retries)")
    if job.output is not None:
        try:
            writer_for(job.output, cfg.writers).write(ccd, job.output, overwrite=cfg.overwrite)
        except OSError as exc:  # the batch decides: a full disk stops it (see _Report)
            return replace(_failed(job, exc, t0, src_path), _write_errno=exc.errno)
        ccd = None  # memory stays flat: nothing of the frame is kept
    return FrameResult(name=job.name, status="registered", transform=job.transform,
                       quality=job.quality, output=job.output, ccd=ccd, source=src_path,
                       seconds=time.perf_counter() - t0, points=job.points)

# -- the union canvas ------------------------------------------------------------------------


def canvas_name(reference, shape, offset):
    """
    How a frame's HISTORY names the union canvas: the reference's name, the
    canvas size and where the reference's pixel (0, 0) falls on it.
    """
    name = getattr(getattr(reference, "_parsed", reference), "name", "the reference")
    return (f"the {shape[1]}x{shape[0]} union canvas of {name} (its pixel (0, 0) at "
            f"canvas pixel ({-int(offset[0])}, {-int(offset[1])}))")


def shifted_transform(transform, offset, sign):
    """``transform`` followed by a shift of ``sign * offset`` pixels."""
    m = as_matrix(transform).copy()
    m[0, 2] += sign * offset[0]
    m[1, 2] += sign * offset[1]
    # The registry name of the transform's own class (None for any other class).
    entry = transform_type_of(transform, exact=True)
    out = from_matrix(m, transform_type=None if entry is None else entry.name)
    out.meta.update(getattr(transform, "meta", {}) or {})
    return out


def _stream_jobs(items, namer):
    """Jobs of a generator's frames, named as they arrive; nothing of earlier frames kept."""
    for i, (frame, label) in enumerate(items):
        name, output, renamed = namer(i, frame, label)
        if renamed is not None:
            warn(f"output names collide; renamed: {name} -> {renamed[1]} ({renamed[0]} "
                 "is taken)")
        yield _Job(i, frame, name, output, stage="full")
