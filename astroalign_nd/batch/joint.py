# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
`~astroalign_nd.register_batch`'s ``solve='global'``: the frames'
transforms solved together by `~astroalign_nd.solve_sequence`, then each
frame resampled as in a pairwise batch.
"""

from __future__ import annotations

import os
import time

import numpy as np

from ..sequence.solve import reference_index, solve_sequence
from .frame import _failed, _skipped
from .planning import _is_path, _skip_or_refuse
from .results import FrameResult

__all__ = []


def solve_jobs(jobs, items, target, ref, options, runners, report, cfg):
    """
    The transforms of `~astroalign_nd.register_batch`'s ``solve='global'``:
    index -> `FrameResult` of each frame to resample (or keep); frames that
    cannot be solved, or whose output may not be written, are reported as
    failed at once.  Returns the found results and the
    `~astroalign_nd.sequence.SequenceSolution`.
    """
    t0 = time.perf_counter()
    frames = [frame for frame, _ in items]
    try:  # the target's index among the frames (the same object or path)
        index = reference_index(target, items)
    except ValueError:
        index = None
    if index is None:  # the target is not one of the frames: it joins them, unwritten
        frames.append(ref)
        index = len(items)
    else:
        frames[index] = ref  # its stars are already detected
    client, workers = runners
    sol = solve_sequence(frames, reference=index, client=client, workers=workers, hdu=cfg.hdu,
                         unit=cfg.unit, **options)
    each = (time.perf_counter() - t0) / max(1, len(items))
    found = {}
    for job in jobs:
        i, src = job.index, (os.fspath(job.source) if _is_path(job.source) else None)
        if sol.transforms[i] is None:
            why = sol.unsolved[i]
            error = why if why.split(":")[0].isidentifier() else (
                f"TransformNotFoundError: {why}")
            report.done(i, FrameResult(name=job.name, status="failed", error=error,
                                       seconds=each, source=src))
            continue
        try:
            done = _skip_or_refuse(job, cfg)
        except Exception as exc:  # noqa: BLE001 - the frame fails, the batch goes on
            report.done(i, _failed(job, exc, t0, src))
            continue
        if done is None:
            t = sol.transforms[i]
            found[i] = FrameResult(name=job.name, status="registered", transform=t,
                                   quality=dict(t.meta["quality"]), source=src,
                                   output=job.output, shape=sol.shapes[i], seconds=each,
                                   points=_frame_points(sol, i))
        else:
            found[i] = _skipped(job, done, cfg, src, each)
        report.tick()
    return found, sol


def _frame_points(sol, i):
    """
    Frame ``i``'s matched stars (its pixels) and their partners (reference pixels), as
    `~astroalign_nd.batch.FrameResult.points` holds them for the figures: from its link
    with the reference, else from its link of most stars, the partners placed by their
    frame's solved transform (the residuals drawn are then the joint solution's).
    """
    links = [k for k in sol.accepted if i in (k.source, k.target)
             and sol.transforms[k.target if k.source == i else k.source] is not None]
    if not links:
        return None
    link = max(links, key=lambda k: (sol.reference in (k.source, k.target), k.n_matches))
    mine, other, j = ((link.source_points, link.target_points, link.target)
                      if link.source == i else
                      (link.target_points, link.source_points, link.source))
    placed = sol.transforms[j](other[:, 0], other[:, 1])
    return np.asarray(mine, dtype=float), np.column_stack(placed).astype(float)
