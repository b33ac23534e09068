# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Register many frames onto one reference, locally or on dask.distributed.

The reference's stars and triangles are computed once.  A bad frame does
not stop the batch: it is reported in the result, with the reason.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from astropy.table import Table

from ._input import iter_frames, parse_input
from .registration import _as_reference, _split_options, find_match, quality_dict

__all__ = ["FrameResult", "BatchResult", "register_batch"]


@dataclass
class FrameResult:
    """
    The outcome for one frame of a batch.

    Attributes
    ----------
    name : str
        File name, or ``frame<i>`` for in-memory inputs.
    ok : bool
    transform : model or None
    quality : dict or None
        As in ``transform.meta['quality']``.
    output : str or None
        The FITS file written, if ``output_dir`` was given.
    error : str or None
        ``'<ExceptionType>: message'`` for a failed frame.
    seconds : float
    ccd : `~astropy.nddata.CCDData` or None
        The registered frame, when no ``output_dir`` was given.
    """

    name: str
    ok: bool
    transform: object = None
    quality: dict = None
    output: str = None
    error: str = None
    seconds: float = 0.0
    ccd: object = field(default=None, repr=False)


@dataclass
class BatchResult:
    """All frames of a batch, in input order."""

    frames: list

    @property
    def succeeded(self):
        """The frames that were registered."""
        return [f for f in self.frames if f.ok]

    @property
    def failed(self):
        """The frames that could not be registered (see their ``error``)."""
        return [f for f in self.frames if not f.ok]

    def to_table(self):
        """One row per frame: name, ok, matches, RMS, output, error."""
        rows = []
        for f in self.frames:
            q = f.quality or {}
            rows.append((f.name, f.ok, q.get("n_matches", 0), q.get("rms", np.nan),
                         f.output or "", f.error or "", f.seconds))
        return Table(rows=rows, names=("name", "ok", "n_matches", "rms", "output", "error",
                                       "seconds"),
                     dtype=(str, bool, int, float, str, str, float))

    def summary(self):
        """A short human-readable report."""
        lines = [f"{len(self.succeeded)} of {len(self.frames)} frames registered"]
        for f in self.failed:
            lines.append(f"  FAILED {f.name}: {f.error}")
        return "\n".join(lines)


def _output_path(output_dir, name, suffix):
    stem, _, dup = name.partition("#")
    dup = f"_{dup}" if dup else ""
    for ext in (".fits.gz", ".fits", ".fit", ".fts", ".FITS", ".FIT", ".jpg", ".jpeg", ".png",
                ".tif", ".tiff"):
        if stem.endswith(ext):
            stem = stem[: -len(ext)]
            break
    return os.path.join(output_dir, f"{stem}{dup}{suffix}.fits")


def _register_one(src, name, reference, output_dir, overwrite, suffix, options,
                  apply_options):
    """Register one frame; never raises (a batch must go on)."""
    from .ccddata import apply_transform

    t0 = time.perf_counter()
    out_path = None
    try:
        if output_dir is not None:
            out_path = _output_path(output_dir, name, suffix)
            if os.path.exists(out_path) and not overwrite:
                raise FileExistsError(
                    f"{out_path} exists; pass overwrite=True (or --overwrite) to replace it")
        src = parse_input(src, "source")  # a FrameLoader: read the frame here, once
        result = find_match(src, reference, **options)
        ccd = apply_transform(result.transform, src, reference, quality=quality_dict(result),
                              **apply_options)
        if out_path is not None:
            ccd.write(out_path, overwrite=overwrite, hdu_flags="FLAGS")
            ccd = None
        return FrameResult(name=name, ok=True, transform=result.transform,
                           quality=quality_dict(result), output=out_path, ccd=ccd,
                           seconds=time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - report every failure, keep going
        return FrameResult(name=name, ok=False, error=f"{type(exc).__name__}: {exc}",
                           seconds=time.perf_counter() - t0)


def register_batch(sources: Iterable[Any] | Any, target: Any, *,
                   output_dir: str | os.PathLike | None = None, overwrite: bool = False,
                   suffix: str = "_aligned", client: Any = None, progress: bool = False,
                   order: str | int = "bilinear", conserve_flux: bool = False,
                   fill_value: float = np.nan, method: str = "interpolate", unit: Any = None,
                   hdu: int | str | None = None, add_keyword: bool = True,
                   **options: Any) -> BatchResult:
    """
    Register every frame of ``sources`` onto ``target``.

    Parameters
    ----------
    sources : iterable or `~ccdproc.ImageFileCollection`
        Frames: paths (best for large batches: each worker reads its own
        files), arrays, NDData/CCDData, ``(frame, file name)`` pairs such as
        ``ImageFileCollection.ccds(return_fname=True)`` yields, a generator
        of any of these, or an ``ImageFileCollection`` (its files, read
        with its ``ext``).  Frames are taken one at a time, so a generator
        is never held in memory all at once; file names name the outputs.
    target : anything `~astroalign_nd.find_transform` accepts, or `~astroalign_nd.Reference`
        The reference frame; prepared once.
    output_dir : str or path, optional
        Write each registered frame to ``<output_dir>/<name><suffix>.fits``
        instead of returning it.
    overwrite : bool, optional
        Replace existing output files (default False: such a frame fails,
        and the others go on).
    suffix : str, optional
        Added to output file names (default ``'_aligned'``).
    client : ``dask.distributed.Client``, optional
        Run the frames as dask.distributed tasks (the reference is
        broadcast to the workers once).  Without it, frames run one after
        the other in this process.
    progress : bool, optional
        Show a tqdm progress bar.
    order, conserve_flux, fill_value, method, unit, add_keyword
        As in `~astroalign_nd.apply_transform`.
    hdu : int or str, optional
        The HDU to read from FITS files (and the target), as in
        `~astroalign_nd.find_transform`.
    **options
        As in `~astroalign_nd.find_transform` (``transform_type``,
        ``n_sources``, detection and matching options).

    Returns
    -------
    result : `~astroalign_nd.batch.BatchResult`
        Per-frame results in input order; ``result.failed`` lists the
        frames that could not be registered and why.
    """
    det, _ = _split_options({k: v for k, v in options.items()
                             if k not in ("transform_type", "n_sources", "max_sources")})
    if output_dir is not None:
        output_dir = os.fspath(output_dir)
        os.makedirs(output_dir, exist_ok=True)
    ref = _as_reference(target, "target", det, hdu)
    # Compute the reference's stars and triangles once, before shipping it.
    n = options.get("n_sources", 50)
    ref.stars(n)
    ref.asterisms(n, options.get("n_neighbors", 4))
    apply_options = dict(order=order, conserve_flux=conserve_flux, fill_value=fill_value,
                         method=method, unit=unit, add_keyword=add_keyword)
    frames = iter_frames(sources, hdu=hdu, unit=unit)
    args = (output_dir, overwrite, suffix, options, apply_options)

    bar = None
    if progress:
        from tqdm.auto import tqdm

        total = len(sources.files) if hasattr(sources, "files_filtered") else (
            len(sources) if hasattr(sources, "__len__") else None)
        bar = tqdm(total=total, unit="frame")
    results, names = [], []
    if client is None:
        for name, src in frames:
            results.append(_register_one(src, name, ref, *args))
            if bar is not None:
                bar.update(1)
    else:
        from dask.distributed import as_completed

        ref_future = client.scatter(ref, broadcast=True)
        futures = []
        for name, src in frames:
            names.append(name)
            futures.append(client.submit(_register_one, src, name, ref_future, *args,
                                         pure=False))
        results = [None] * len(futures)
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):
            i = index[fut.key]
            try:
                results[i] = fut.result()
            except Exception as exc:  # a worker died: report, go on
                results[i] = FrameResult(name=names[i], ok=False,
                                         error=f"{type(exc).__name__}: {exc}")
            if bar is not None:
                bar.update(1)
    if bar is not None:
        bar.close()
    return BatchResult(results)
