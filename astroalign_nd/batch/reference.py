# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The reference frame of a batch on the batch's output grid (for stacking it with the rest)."""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np
from astropy.nddata import CCDData

from ..io.read import parse_input
from ..io import writer_for
from ..resample import apply_transform
from ..transforms.convert import from_matrix
from .canvas import canvas_wcs
from .frame import canvas_name
from .planning import _CANVAS_KEYS, _SOURCE_SHAPE_KEYS, _output_name, _read_done, _stem
from .results import BatchResult, FrameResult

__all__ = ["reference_on_canvas", "write_reference", "REFERENCE_KEY"]

#: Header keyword of the reference frame written by a batch (True).
REFERENCE_KEY = "AAREFFRM"


def reference_on_canvas(target: Any, result: BatchResult | None = None, *,
                        hdu: int | str | None = None, unit: Any = None,
                        fill_value: float = np.nan, add_keyword: bool = True) -> CCDData:
    """
    The reference frame of a batch on the batch's output grid.

    On the reference's own grid (``canvas='reference'``) it is the
    reference as it is, as a `~astropy.nddata.CCDData` with its own mask
    and uncertainty; on a union canvas, the reference shifted onto the
    canvas by whole pixels (nearest neighbour on an integer shift: every
    value kept exactly), masked where it has no data.  Either way, its data
    type is that of the registered frames (see
    `~astroalign_nd.resample.working_dtype`), and its header says that it
    is the reference (``AAREFFRM = T``).

    Parameters
    ----------
    target : path, array-like, `~astropy.nddata.NDData`
        The batch's reference frame, as given to
        `~astroalign_nd.register_batch`.
    result : `~astroalign_nd.batch.BatchResult`, optional
        The batch's result, whose ``canvas_shape`` and ``canvas_offset``
        give the grid; the reference's own grid when None.
    hdu, unit, fill_value, add_keyword
        As in `~astroalign_nd.register_batch`.

    Returns
    -------
    reference : `~astropy.nddata.CCDData`

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.batch import BatchResult, reference_on_canvas
    >>> ref = np.arange(100.0).reshape(10, 10)
    >>> grid = BatchResult([], canvas_shape=(12, 13), canvas_offset=(-3, 0))
    >>> out = reference_on_canvas(ref, grid)
    >>> out.shape, float(out.data[5, 3 + 4]), bool(out.mask[0, 0])
    ((12, 13), 54.0, True)
    """
    ref = parse_input(target, "target", hdu=hdu, unit=unit)
    if ref.is_catalog:
        raise TypeError("the reference is a catalog: there is no image to put on the canvas.")
    shape = tuple(ref.shape) if result is None or result.canvas_shape is None \
        else tuple(result.canvas_shape)
    offset = (0, 0) if result is None else tuple(int(v) for v in result.canvas_offset)
    union = shape != tuple(ref.shape) or offset != (0, 0)
    shift = from_matrix([[1.0, 0.0, -offset[0]], [0.0, 1.0, -offset[1]], [0.0, 0.0, 1.0]],
                        "translation")
    ccd = apply_transform(shift, ref, shape if union else ref, order="nearest-neighbor",
                          fill_value=fill_value, unit=unit, add_keyword=add_keyword,
                          target_name=canvas_name(ref, shape, offset) if union else None)
    if union and ref.wcs is not None:
        ccd.wcs = canvas_wcs(ref.wcs, offset, shape)
    if add_keyword:
        ccd.meta[REFERENCE_KEY] = (True, "the batch's reference frame")
        ccd.meta["HISTORY"] = "astroalign_nd: this is the batch's reference frame"
        if union:
            ccd.meta[_CANVAS_KEYS[0]] = (offset[0], "canvas x0 [reference px]")
            ccd.meta[_CANVAS_KEYS[1]] = (offset[1], "canvas y0 [reference px]")
        ccd.meta[_SOURCE_SHAPE_KEYS[0]] = (int(ref.shape[1]), "source frame width [px]")
        ccd.meta[_SOURCE_SHAPE_KEYS[1]] = (int(ref.shape[0]), "source frame height [px]")
    return ccd


def reference_output(target, output_dir, suffix="_reference"):
    """The path of the reference's output: ``<output_dir>/<reference name><suffix>.fits``."""
    if not isinstance(target, (str, os.PathLike)):  # in memory: no name to add to
        return os.path.join(os.fspath(output_dir), _output_name("reference", ""))
    name = os.path.basename(os.fspath(target))
    return os.path.join(os.fspath(output_dir), _output_name(_stem(name), suffix))


def write_reference(target: Any, result: BatchResult, output_dir: str | os.PathLike, *,
                    overwrite: bool = False, skip_existing: bool = False,
                    suffix: str = "_reference", **options: Any) -> FrameResult:
    """
    Write `reference_on_canvas` to ``<output_dir>/<name><suffix>.fits``
    (``<output_dir>/reference.fits`` for a reference given in memory).

    Never raises for the file: like a frame of the batch, a reference that
    cannot be written is reported as failed.

    Parameters
    ----------
    target, result
        As in `reference_on_canvas`.
    output_dir : str or path
        The batch's output folder.
    overwrite : bool, optional
        Replace an existing file.
    skip_existing : bool, optional
        Keep an existing file written for the same grid (status 'skipped').
    suffix : str, optional
        Added to the reference's file name (default ``'_reference'``).
    **options
        ``hdu``, ``unit``, ``fill_value``, ``add_keyword`` of `reference_on_canvas`.

    Returns
    -------
    frame : `~astroalign_nd.batch.FrameResult`
        Status 'reference' (written), 'skipped' or 'failed'; its transform
        is the shift from the reference onto the grid.

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.batch import register_batch, write_reference
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=3.0, seed=1)
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     result = register_batch([pair.source], pair.target, output_dir=tmp)
    ...     ref = write_reference(pair.target, result, tmp)
    ...     written = sorted(os.listdir(tmp))
    >>> ref.status, written
    ('reference', ['frame0_aligned.fits', 'reference.fits'])
    """
    t0 = time.perf_counter()
    path = reference_output(target, output_dir, suffix)
    offset = tuple(int(v) for v in result.canvas_offset)
    shift = from_matrix([[1.0, 0.0, -offset[0]], [0.0, 1.0, -offset[1]], [0.0, 0.0, 1.0]],
                        "translation")
    src = os.fspath(target) if isinstance(target, (str, os.PathLike)) else None
    frame = dict(name=os.path.basename(src) if src else "reference", transform=shift,
                 output=path, source=src)
    try:
        # A complete reference output on this grid is kept.
        done = (_read_done(path)[0] if os.path.exists(path) and not overwrite and skip_existing
                else None)
        if done is not None and tuple(done["shape"]) == tuple(result.canvas_shape) \
                and tuple(done["offset"]) == tuple(offset):
            return FrameResult(status="skipped", seconds=time.perf_counter() - t0, **frame)
        ccd = reference_on_canvas(target, result, **options)
        writer_for(path).write(ccd, path, overwrite=overwrite)
    except Exception as exc:  # noqa: BLE001 - reported like a frame of the batch
        return FrameResult(status="failed", error=f"{type(exc).__name__}: {exc}",
                           seconds=time.perf_counter() - t0, **frame)
    return FrameResult(status="reference", seconds=time.perf_counter() - t0, **frame)
