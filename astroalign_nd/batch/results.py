# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The results of a batch: one FrameResult per frame and their BatchResult."""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np
from astropy.table import Table
from .._results import status_list
from ..transforms.convert import as_matrix

__all__ = ['FrameResult', 'BatchResult']

#: Status of a frame in a `BatchResult`.
_STATUSES = ("registered", "skipped", "failed")


def transform_figures(transform, offset=(0, 0)):
    """
    ``(shift_x, shift_y, rotation_deg, scale)`` of a frame's transform, onto
    reference pixels (``offset``: the canvas's, added back), from its
    linear part; NaNs when there is none.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.batch.results import transform_figures
    >>> m = np.array([[0.0, -2.0, 5.0], [2.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    >>> [round(v, 6) for v in transform_figures(m, offset=(10, 20))]
    [15.0, 19.0, 90.0, 2.0]
    """
    if transform is None:
        return (np.nan,) * 4
    linear = getattr(transform, "linear_part", None)  # a distortion model: without it
    try:
        m = np.asarray(as_matrix(transform if linear is None else linear), dtype=float)
    except (TypeError, ValueError):
        return (np.nan,) * 4
    return (float(m[0, 2] + offset[0]), float(m[1, 2] + offset[1]),
            float(np.degrees(np.arctan2(m[1, 0], m[0, 0]))),
            float(np.sqrt(abs(np.linalg.det(m[:2, :2])))))


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
    points : tuple of two (K, 2) ndarray or None
        The matched star positions, ``(source_points, reference_points)``
        in source and reference pixels, as `~astroalign_nd.find_transform`
        returns them (None for a skipped or failed frame): what the
        diagnostic figures draw without searching again.

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
    points: tuple = field(default=None, repr=False)  # matched (source, reference) positions
    _grid: tuple = field(default=None, repr=False)  # (shape, offset) of a kept output
    _write_errno: int = field(default=None, repr=False)  # the output could not be written

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
    solution : `~astroalign_nd.sequence.SequenceSolution` or None
        The joint solution of ``solve='global'`` (its links, their
        residuals, the rejected ones); None otherwise.

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
    solution: object = field(default=None, repr=False)

    succeeded = status_list("frames", "registered", "The frames registered in this run.")
    skipped = status_list("frames", "skipped", "The frames whose complete output was already "
                          "there (``skip_existing``).")
    failed = status_list("frames", "failed", "The frames that could not be registered (see "
                         "their ``error``).")

    def to_table(self):
        """
        One row per frame, in input order.

        Columns: ``name``, ``status``, ``ok`` (registered or skipped:
        the output is there), ``n_matches``, ``rms`` (px),
        ``log10_false_alarm``, ``shift_x`` and ``shift_y`` (px),
        ``rotation`` (deg) and ``scale`` of the source-to-reference
        transform (its linear part, whatever the canvas; NaN for a failed
        frame), ``seconds``, ``error``, ``output`` and ``source``; with
        ``solve='global'`` also ``n_links`` and ``predicted_error`` (px).
        Write it with ``result.to_table().write('night.ecsv')``.
        """
        rows = []
        for f in self.frames:
            q = f.quality or {}
            rows.append((f.name, f.status, f.ok, int(q.get("n_matches", 0)),
                         float(q.get("rms", np.nan)),
                         float(q.get("log10_false_alarm", np.nan)),
                         *transform_figures(f.transform, self.canvas_offset), float(f.seconds),
                         f.error or "", f.output or "", f.source or ""))
        t = Table(rows=rows or None,
                  names=("name", "status", "ok", "n_matches", "rms", "log10_false_alarm",
                         "shift_x", "shift_y", "rotation", "scale",
                         "seconds", "error", "output", "source"),
                  dtype=(str, str, bool, int, float, float, float, float, float, float,
                         float, str, str, str))
        t["rms"].unit = t["shift_x"].unit = t["shift_y"].unit = "pix"
        t["rotation"].unit = "deg"
        t["seconds"].unit = "s"
        if self.solution is not None:
            qs = [f.quality or {} for f in self.frames]
            t["n_links"] = [int(q.get("n_links", 0)) for q in qs]
            t["predicted_error"] = [float(q.get("predicted_error", np.nan)) for q in qs]
            t["predicted_error"].unit = "pix"
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
        if self.solution is not None:
            sol = self.solution
            lines.append(f"  global solution: {len(sol.accepted)} links, {sol.n_stars} stars, "
                         f"{len(sol.rejected)} link(s) rejected")
            lines += [f"  REJECTED link {k.source}->{k.target}: {k.reason}"
                      for k in sol.rejected]
            for f in self.frames:
                q = f.quality or {}
                if "n_links" in q:
                    lines.append(f"  {f.name}: {q['n_links']} links, predicted error "
                                 f"{q['predicted_error']:.3f} px")
        for f in self.failed:
            lines.append(f"  FAILED {f.name}: {f.error}")
        return "\n".join(lines)
