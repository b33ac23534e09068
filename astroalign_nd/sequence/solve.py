# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
`solve_sequence`: register a night or a mosaic as one, with every frame's
transform to the reference solved together (a bundle adjustment).

1. Each frame is detected once (a `~astroalign_nd.Reference` per frame).
2. Links: pairs of frames matched by the trusted search
   (`~astroalign_nd.find_match`, each with its false-alarm figure): every
   overlapping pair of a small set; for a large one, each frame with the
   next in time and with a few well-connected frames; then pairs across
   the groups until the frames are connected.
3. The link adjustment (`~astroalign_nd.sequence.adjust`): the frames'
   transforms from every link's matched stars at once; a link that
   disagrees with the rest is rejected, the worst first.
4. The bundle adjustment: the transforms and every star's position in the
   reference frame, from all detections of all stars (robust: outlying
   detections are clipped), with each frame's covariance.
"""

from __future__ import annotations

import dataclasses
import os
import time
from typing import Any

import numpy as np
from astropy.table import Table
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .._pools import task_pool
from .._results import status_list
from ..io.read import batch_frames, display_names
from ..config import RegistrationConfig
from ..exceptions import AstroalignError, warn
from ..matching.pairing import mutual_matches
from ..options import Int, Real, convert
from ..registration import Reference
from ..transforms.convert import as_matrix, from_matrix
from ..transforms.layers import layer_of
from ..transforms.registry import (LINEAR_TYPES, TRANSFORM_REGISTRY, transform_class,
                                   transform_type_of)
from . import adjust
from .links import (Graph, Link, bridge_pairs, chain_pairs, choose_hubs, guided_link,
                    match_link, wanted)

__all__ = ["solve_sequence", "SequenceSolution", "Link"]

#: Gauss-Newton steps at most; and the parameter change (px at the frame's edge) that ends them.
_MAX_STEPS, _CONVERGED = 30, 1e-7
#: `solve_sequence`'s options that `~astroalign_nd.register_batch` passes on with solve='global'.
SOLVE_OPTIONS = ("n_stars", "all_pairs", "n_hubs", "min_overlap", "link_tolerance")
#: Detections further than this many robust sigmas from their star's mean are clipped.
_CLIP_SIGMA = 5.0


@dataclasses.dataclass
class SequenceSolution:
    """
    The joint solution of `solve_sequence`.

    Attributes
    ----------
    transforms : list
        Per frame, its transform to the reference frame's pixels (a
        `~astroalign_nd.transforms.LinearTransform2D` of the requested
        type), or None for a frame that could not be solved.  Its
        ``meta['quality']`` holds ``n_matches`` (detections used),
        ``rms`` (px), ``n_links``, ``log10_false_alarm`` (its most
        significant link), ``predicted_error`` and ``covariance``.
    covariances : list
        Per frame, the (6, 6) covariance of its matrix elements
        ``(m00, m01, m02, m10, m11, m12)`` (reference-frame px), None if
        not solved (zeros for the reference).
    predicted_errors : ndarray
        Per frame, the largest 1-sigma position error (px) over the
        frame's corners, propagated from the covariance (NaN if not solved).
    reference : int
        The reference frame's index.
    links : list of `~astroalign_nd.sequence.Link`
        Every trusted link, accepted or rejected, with its residuals under
        the solution.
    unsolved : dict
        Frame index -> why it could not be solved.
    names, shapes : list
        The frames' names and ``(ny, nx)``.
    n_stars : int
        Stars (tracks seen in at least two frames) in the bundle adjustment.
    attempts : list of (int, int, str)
        The pairs tried that gave no trusted match, with the reason.
    seconds : dict
        Time spent on ``detect``, ``match`` and ``solve``.

    Examples
    --------
    Three catalogs of one field, shifted; frame 0 is the reference:

    >>> import numpy as np
    >>> from astroalign_nd import solve_sequence
    >>> rng = np.random.default_rng(0)
    >>> field = rng.uniform(0, 300, (80, 2))
    >>> sol = solve_sequence([field, field + [10.0, 0.0], field + [0.0, -7.0]], reference=0)
    >>> [round(float(v), 6) + 0.0 for v in sol.transforms[2].translation]
    [0.0, 7.0]
    >>> sol.to_table()["status"].tolist(), len(sol.accepted), sol.unsolved
    (['reference', 'solved', 'solved'], 3, {})
    """

    transforms: list
    covariances: list
    predicted_errors: np.ndarray
    reference: int
    links: list
    unsolved: dict
    names: list
    shapes: list
    n_stars: int = 0
    attempts: list = dataclasses.field(default_factory=list)
    seconds: dict = dataclasses.field(default_factory=dict)

    accepted = status_list("links", "accepted", "The links used by the solution.")
    rejected = status_list("links", "rejected", "The links rejected for disagreeing with the "
                           "rest.")

    def to_table(self):
        """
        One row per frame: ``index``, ``name``, ``status`` ('reference',
        'solved' or 'unsolved'), ``n_links``, ``n_matches`` (detections
        used), ``rms`` (px), ``predicted_error`` (px) and ``reason``.
        """
        rows = []
        for i, t in enumerate(self.transforms):
            q = (t.meta.get("quality", {}) if t is not None else {})
            status = "reference" if i == self.reference else (
                "solved" if t is not None else "unsolved")
            rows.append((i, self.names[i], status, int(q.get("n_links", 0)),
                         int(q.get("n_matches", 0)), float(q.get("rms", np.nan)),
                         float(self.predicted_errors[i]), self.unsolved.get(i, "")))
        t = Table(rows=rows or None, names=("index", "name", "status", "n_links", "n_matches",
                                            "rms", "predicted_error", "reason"),
                  dtype=(int, str, str, int, int, float, float, str))
        t["rms"].unit = t["predicted_error"].unit = "pix"
        return t

    def links_table(self):
        """
        One row per link: ``source``, ``target``, ``status``, ``n_matches``,
        ``rms`` (its own fit), ``log10_false_alarm``, ``misfit`` and
        ``residual_rms`` (under the solution; px) and ``reason``.
        """
        rows = [(k.source, k.target, k.status, k.n_matches, k.rms, k.log10_false_alarm,
                 k.misfit, k.residual_rms, k.reason) for k in self.links]
        t = Table(rows=rows or None, names=("source", "target", "status", "n_matches", "rms",
                                            "log10_false_alarm", "misfit", "residual_rms",
                                            "reason"),
                  dtype=(int, int, str, int, float, float, float, float, str))
        for c in ("rms", "misfit", "residual_rms"):
            t[c].unit = "pix"
        return t

    def __repr__(self):
        # One line: the dataclass's own repr printed every covariance (about 60 lines).
        n = len(self.transforms)
        solved = sum(t is not None for t in self.transforms)
        return (f"<SequenceSolution: {solved} of {n} frames solved onto frame "
                f"{self.reference}, {len(self.accepted)} links, {self.n_stars} stars; "
                "see .summary() and .to_table()>")

    def summary(self):
        """A short human-readable report."""
        n = len(self.transforms)
        solved = sum(t is not None for t in self.transforms)
        lines = [f"{solved} of {n} frames solved onto frame {self.reference} "
                 f"({self.names[self.reference]}) from {len(self.accepted)} links and "
                 f"{self.n_stars} stars; {len(self.rejected)} link(s) rejected"]
        for k in self.rejected:
            lines.append(f"  REJECTED link {k.source}->{k.target}: {k.reason}")
        for i, why in sorted(self.unsolved.items()):
            lines.append(f"  UNSOLVED {self.names[i]}: {why}")
        return "\n".join(lines)


def solve_sequence(frames: Any, reference: Any = None, *, transform_type: str = "similarity",
                   all_pairs: int = 10, n_hubs: int = 1, min_overlap: float = 0.1,
                   link_tolerance: float = 1.0, n_stars: int | None = None,
                   client: Any = None, workers: int | None = None,
                   hdu: int | str | None = None, unit: Any = None,
                   **options: Any) -> SequenceSolution:
    """
    Register a night or a mosaic as one: every frame's transform to the
    reference frame, solved together over all the stars of all links.

    Each frame is detected once.  Pairs of frames are matched by the
    trusted search of `~astroalign_nd.find_match` (each link with its
    false-alarm figure): every overlapping pair of a set of up to
    ``all_pairs`` frames; for more, each frame with the next one in time and
    with ``n_hubs`` well-connected frames; then pairs across the groups
    still apart, until the frames are connected.  The transforms are then
    fitted to all links at once (a link that disagrees with the rest by
    more than ``link_tolerance`` is rejected, and reported), and finally
    with every star's position in the reference frame (a bundle
    adjustment: each star's position is the weighted mean of all its
    detections, each residual weighed in its own frame's pixels).  The
    transforms still carry the reference's own centroid errors (they fix
    where its pixels lie among the stars), so a frame that shares all its
    stars with the reference is about as precise as registered pairwise;
    the joint solution gains from the stars the reference does not share,
    from frames that overlap it little or not at all, and in trust: the
    loops of links close, and a link that disagrees is caught.

    Parameters
    ----------
    frames : iterable or `~ccdproc.ImageFileCollection`
        What `~astroalign_nd.register_batch` takes (paths, arrays,
        NDData/CCDData, ``(frame, file name)`` pairs, a collection), or
        catalogs (tables with ``x``/``y``, (N, 2) arrays) as
        `~astroalign_nd.find_transform` takes them.  Their order is taken
        as the order in time.
    reference : int, frame or None, optional
        The reference frame: its index, the frame itself (the same object,
        or the same path), or None (default) for the best-connected frame
        (the one with the most links).
    transform_type : str, optional
        The model of every frame (default 'similarity'): a linear type of
        the registry ('similarity', 'euclidean', 'translation', 'affine', or
        one registered with its parameter layer, which the joint solution
        adjusts).
    all_pairs : int, optional
        Up to this many frames, every pair predicted to overlap is matched
        (default 10); more frames get the sparse graph.
    n_hubs : int, optional
        Well-connected frames every frame of a large set is matched with
        (default 1: the reference when given; each further hub costs a
        match per frame).
    min_overlap : float, optional
        Pairs predicted (from the links found so far) to share less than
        this fraction of a frame are not matched (default 0.1).
    link_tolerance : float, optional
        A link whose own transform differs from the joint solution by more
        than this (pixels, largest over its stars) is rejected (default 1).
    n_stars : int, optional
        Stars per frame in the joint solve.  By default the stars detected
        for the matching (up to ``2 * n_sources``); more (a second, deeper
        detection of each frame) make every transform more precise, most
        for small overlaps.
    client : ``dask.distributed.Client``, optional
        Match the links of each round as dask tasks; the solve runs here.
    workers : int, optional
        Detect the frames read from files, and match the links, in this
        many local processes (as `~astroalign_nd.register_batch`'s
        ``workers``); the solve runs here.  Frames read from files keep
        only their stars once detected (their pixels are let go).
    hdu, unit : optional
        As in `~astroalign_nd.register_batch`.
    **options
        Detection and matching options, ``n_sources`` and ``max_sources``,
        as in `~astroalign_nd.find_transform`.

    Returns
    -------
    `SequenceSolution`

    Raises
    ------
    ValueError, TypeError
        For an empty set of frames, an unknown reference, a non-linear
        ``transform_type`` or an option out of range.

    Examples
    --------
    A 2 x 2 mosaic with 30% overlaps, solved onto tile 0:

    >>> import numpy as np
    >>> from astroalign_nd import solve_sequence
    >>> from astroalign_nd.simulate import mosaic_transforms, simulate_views
    >>> seq = simulate_views(mosaic_transforms((2, 2), (200, 200), overlap=0.3),
    ...                         (200, 200), n_stars=150, seed=3)
    >>> sol = solve_sequence(seq.frames, reference=0)
    >>> len(sol.accepted), sol.unsolved
    (4, {})
    >>> err = abs(sol.transforms[3].translation - seq.truth(3, 0).translation)
    >>> bool(np.all(err < 0.1))
    True
    """
    kind, numbers = _check_arguments(transform_type, all_pairs, n_hubs, min_overlap,
                                     link_tolerance)
    if n_stars is not None and (isinstance(n_stars, bool) or not isinstance(
            n_stars, (int, np.integer)) or n_stars < 3):
        raise ValueError(f"n_stars must be an integer >= 3 or None; got {n_stars!r}.")
    # The links are matched as similarities for the conformal types (a
    # similarity's links are no worse for them), else as the type itself.
    config = RegistrationConfig.from_keywords(
        transform_type="similarity" if TRANSFORM_REGISTRY[kind].conformal else kind, **options)
    items, frames_hdu = batch_frames(frames, hdu)
    items = list(items)
    if not items:
        raise ValueError("frames is empty: pass the frames to solve (file paths, CCDData, arrays "
                         "or an ImageFileCollection); one frame alone is its own reference.")
    names = display_names(items)
    ref = reference_index(reference, items)
    seconds, t0 = {}, time.perf_counter()
    if workers is not None:
        workers = convert("workers", Int(0, None), workers)
        if client is not None and workers > 1:
            raise ValueError("give either client (dask.distributed) or workers (local "
                             "processes), not both.")
    with task_pool(workers) as pool:
        refs, unsolved = _detect(items, names, config, (frames_hdu, unit), n_stars, pool)
        shapes = [_shape(r) for r in refs]
        repeats = _repeats(refs, config.n_sources, ref)
        for j, i in repeats.items():  # solved once, as the frame it repeats
            refs[j], unsolved[j] = None, f"the same frame as {names[i]}"
        seconds["detect"], t0 = time.perf_counter() - t0, time.perf_counter()
        graph = _link(refs, shapes, config, ref, numbers, (client, pool, workers))
    seconds["match"], t0 = time.perf_counter() - t0, time.perf_counter()
    if ref is None:
        ref = _best_connected(graph, refs)
    elif refs[ref] is None:
        raise AstroalignError(f"the reference frame {names[ref]} could not be used: "
                              f"{unsolved[ref]}")
    solution = _solve(graph, refs, shapes, names, ref, kind, link_tolerance, unsolved,
                      (config.n_sources, n_stars))
    # Each repeated frame gets the solution of the frame it repeats, with a warning.
    for j, i in repeats.items():
        del solution.unsolved[j]
        if solution.transforms[i] is None:
            solution.unsolved[j] = f"the same frame as {solution.names[i]}, which is unsolved"
        else:
            solution.transforms[j] = solution.transforms[i].copy()
            solution.covariances[j] = solution.covariances[i]
            solution.predicted_errors[j] = solution.predicted_errors[i]
        warn(f"{solution.names[j]} is the same frame as {solution.names[i]} (identical "
             "detections); it is solved once, so that its stars do not count twice.")
    seconds["solve"] = time.perf_counter() - t0
    solution.seconds = seconds
    solution.attempts = [(a, b, why) for (a, b), why in sorted(graph.failures.items())]
    return solution


def _check_arguments(transform_type, all_pairs, n_hubs, min_overlap, link_tolerance):
    solvable = sorted(t for t in LINEAR_TYPES if layer_of(transform_class(t)) is not None)
    if not isinstance(transform_type, str) or transform_type not in solvable:
        raise ValueError(f"transform_type must be one of {solvable} for a "
                         f"joint solution; got {transform_type!r} (a distortion model is "
                         "fitted pair by pair: use register_batch without solve='global').")
    convert("link_tolerance", Real(0, infinite=True), link_tolerance)
    return transform_type, (convert("all_pairs", Int(2, None), all_pairs),
                            convert("n_hubs", Int(1, None), n_hubs),
                            convert("min_overlap", Real(0, 1), min_overlap))


def reference_index(reference, items):
    """
    The index of ``reference`` among `batch_frames`' ``items``: an index, the
    frame itself (the same object) or its path; None stays None (to be chosen).
    """
    if reference is None:
        return None
    if isinstance(reference, (int, np.integer)) and not isinstance(reference, bool):
        if not -len(items) <= reference < len(items):
            raise ValueError(f"reference index {reference} is out of range for "
                             f"{len(items)} frames.")
        return int(reference) % len(items)
    for i, (frame, _) in enumerate(items):
        if frame is reference:
            return i
    if isinstance(reference, (str, os.PathLike)):
        want = os.path.abspath(os.fspath(reference))
        for i, (frame, _) in enumerate(items):
            if isinstance(frame, (str, os.PathLike)) and os.path.abspath(os.fspath(frame)) == want:
                return i
    raise ValueError("reference must be a frame's index, one of the frames itself (the same "
                     "object or path), or None to choose the best-connected frame.")


def detect_frame(frame, name, config, read, n_stars):
    """
    One frame's detected `Reference` (its pixels let go when it can read
    them again), or the reason it failed (str).  Runs in a worker as well
    as here.
    """
    hdu, unit = read
    try:
        ref = frame if isinstance(frame, Reference) else Reference(
            frame, hdu=hdu, unit=unit, _role=f"frame {name}", _config=config.detection)
        found = len(ref.stars(config.n_sources)[0])
        if n_stars is not None and n_stars > found:
            ref.stars(-(-n_stars // 2))  # the deeper list of the joint solve, while read
    except (AstroalignError, OSError, ValueError, TypeError) as exc:
        return f"{type(exc).__name__}: {exc}"
    if ref is not frame:  # (a Reference passed in is the caller's: left as it is)
        ref.release_pixels()
    return ref


def _detect(items, names, config, read, n_stars, pool):
    """A detected `Reference` per frame (None, with the reason, for a frame that failed)."""
    # Files are read and detected in the workers; arrays here (shipping
    # their pixels to a worker and back costs more than it saves).
    remote = {i: pool.submit(detect_frame, frame, names[i], config, read, n_stars)
              for i, (frame, _) in enumerate(items)
              if pool is not None and isinstance(frame, (str, os.PathLike))}
    refs, unsolved = [], {}
    for i, (frame, _) in enumerate(items):
        res = remote[i].result() if i in remote else detect_frame(frame, names[i], config,
                                                                  read, n_stars)
        if isinstance(res, str):
            res, unsolved[i] = None, res
        refs.append(res)
    return refs, unsolved


def _repeats(refs, n_sources, ref):
    """
    ``{j: i}`` for each frame ``j`` whose detections are exactly frame ``i``'s (``i`` the
    reference, or the first of them): the same file or array given twice.  Solved twice, it would
    count its stars twice in the joint solution and shrink the others' predicted errors.
    """
    keys = {}
    for j, r in enumerate(refs):
        if r is not None:
            pts = np.ascontiguousarray(r.stars(n_sources)[0], dtype=float)
            keys[j] = (pts.shape, pts.tobytes())
    seen, repeats = {}, {}
    for j in sorted(keys, key=lambda f: (f != ref, f)):  # the reference first
        if keys[j] in seen:
            repeats[j] = seen[keys[j]]
        else:
            seen[keys[j]] = j
    return repeats


def _shape(ref):
    """A frame's (ny, nx); a catalog's: the extent of its points."""
    if ref is None:
        return None
    if ref.shape is not None:
        return tuple(ref.shape)
    pts = ref.stars(1)[0]
    return (int(np.ceil(pts[:, 1].max())) + 1, int(np.ceil(pts[:, 0].max())) + 1)


def _match_all(pairs, refs, config, runners, shipped):
    """
    The `Link` (or the reason there is none) of each pair, here, in the
    local workers or as dask tasks; ``shipped`` (frame -> future) holds the
    frames already sent to the cluster, each sent once for the whole solve.
    """
    client, pool, workers = runners
    if len(pairs) >= 2 and pool is not None:
        return list(pool.map(match_link, [refs[a] for a, _ in pairs],
                             [refs[b] for _, b in pairs], [config] * len(pairs),
                             [a for a, _ in pairs], [b for _, b in pairs],
                             chunksize=max(1, len(pairs) // (4 * workers))))
    if client is None or len(pairs) < 2:
        return [match_link(refs[a], refs[b], config, a, b) for a, b in pairs]
    new = sorted({f for p in pairs for f in p} - set(shipped))
    if new:
        shipped.update(zip(new, client.scatter([refs[f] for f in new], hash=False)))
    tasks = [client.submit(match_link, shipped[a], shipped[b], config, a, b, pure=False)
             for a, b in pairs]
    out = []
    for task in tasks:
        try:
            out.append(task.result())
        except Exception as exc:  # noqa: BLE001 - a worker lost: the pair is not linked
            out.append(f"{type(exc).__name__}: {exc}")
    return out


def _link(refs, shapes, config, ref, numbers, runners):
    """The rounds of linking: the chain, then every pair or the hubs, then bridges."""
    all_pairs, n_hubs, min_overlap = numbers
    valid = [i for i, r in enumerate(refs) if r is not None]
    graph = Graph(len(refs), shapes)
    client, pool, workers = runners
    # Without a client the pairs go one by one (a link found may show that
    # the next pair does not overlap); with one, a batch per worker thread.
    size = (max(2, 2 * sum(client.nthreads().values())) if client is not None
            else 8 * workers if pool is not None else 1)
    shipped = {}

    def run(pairs):
        """Match ``pairs``; True when a link joined two groups (the placement changes)."""
        joined = False
        if guide:  # each pair's guided link (`guided_link`), predicted through a frame
            rest = []  # linked to both; the pairs without one are searched
            for a, b in pairs:
                start = graph.predict(a, b)
                res = None if start is None else guided_link(refs[a], refs[b], config, a, b,
                                                             start)
                if not isinstance(res, Link):
                    rest.append((a, b))
                    continue
                graph.tried.add((min(a, b), max(a, b)))
                joined |= graph.add(res)
            pairs = rest
        for (a, b), res in zip(pairs, _match_all(pairs, refs, config, runners, shipped)):
            graph.tried.add((min(a, b), max(a, b)))
            if isinstance(res, Link):
                joined |= graph.add(res)
            else:
                graph.failures[(a, b)] = res
        return joined

    def run_pruned(cands):
        place, pending = graph.placement(), list(cands)
        while pending:
            batch = []
            while pending and len(batch) < size:
                pair = pending.pop(0)
                batch += wanted(graph, [pair], place, min_overlap)
            if batch and run(batch):
                place = graph.placement()

    guide = False
    run(chain_pairs(valid))
    if len(valid) <= all_pairs:
        cands = sorted(((a, b) for a in valid for b in valid if a < b),
                       key=lambda p: (p[1] - p[0], p))
    else:
        hubs = choose_hubs(graph, valid, n_hubs, graph.placement(), fixed=ref)
        cands = [(f, h) for h in hubs for f in valid if f != h]
        # A hub link predicted by the frame's neighbour's is verified, not searched.
        guide = transform_type_of(config.model.transform_type).linear
    run_pruned(cands)
    guide = False
    for _ in range(3):  # bridges across the groups still apart
        groups = graph.components(valid)
        pairs = bridge_pairs(graph, groups, all_pairs) if len(groups) > 1 else []
        if not pairs:
            break
        run_pruned(pairs)
    return graph


def _best_connected(graph, refs):
    """The frame with the most links (then the most matched stars, then the middle one)."""
    valid = [i for i, r in enumerate(refs) if r is not None]
    if not valid:
        raise AstroalignError("no frame could be used: every frame failed detection.")
    main = graph.components(valid)[0]
    count, stars = dict.fromkeys(main, 0), dict.fromkeys(main, 0)
    for k in graph.links:
        for f in (k.source, k.target):
            if f in count:
                count[f] += 1
                stars[f] += k.n_matches
    mid = np.median(main)
    return max(main, key=lambda f: (count[f], stars[f], -abs(f - mid), -f))


class _StarList:
    """A frame's detected stars, with the matched positions of its links as indices."""

    def __init__(self, ref, n_sources, n_stars=None):
        pts, err, _ = ref.stars(n_sources)
        self.points = [np.asarray(pts, float)]
        self.errors = [np.ones(len(pts)) if err is None else np.asarray(err, float)]
        self.tree, self.n = cKDTree(self.points[0]), len(pts)
        self.typical = float(np.median(self.errors[0]))
        if n_stars is not None and n_stars > len(pts):
            # The deeper list: its stars not already in the control list.
            deep, deep_err, _ = ref.stars(-(-n_stars // 2))
            far = self.tree.query(deep)[0] > 1.0
            self.points.append(np.asarray(deep, float)[far])
            self.errors.append(np.ones(int(far.sum())) if deep_err is None
                               else np.asarray(deep_err, float)[far])
            self.n += int(far.sum())
            self.tree = cKDTree(np.vstack(self.points))

    def index(self, pts):
        """Indices of ``pts`` (new positions, from another attempt's list, are appended)."""
        dist, idx = self.tree.query(pts)
        new = dist > 1e-6
        if np.any(new):
            idx = idx.copy()
            idx[new] = self.n + np.arange(int(new.sum()))
            self.points.append(np.asarray(pts[new], float))
            self.errors.append(np.full(int(new.sum()), self.typical))
            self.n += int(new.sum())
            self.tree = cKDTree(np.vstack(self.points))
        return idx

    def error(self, idx):
        return np.concatenate(self.errors)[idx]


def _solve(graph, refs, shapes, names, ref, kind, tolerance, unsolved, counts):
    """Both adjustments, then the `SequenceSolution`."""
    stars = {i: _StarList(r, *counts) for i, r in enumerate(refs) if r is not None}
    # The matched stars of each link as indices into each frame's list.
    idx = {id(k): (stars[k.source].index(k.source_points), stars[k.target].index(k.target_points))
           for k in graph.links}
    while True:
        # The frames joined to the reference by accepted links.
        place = graph.placement(root=ref)
        solved = {f for f, (root, _) in place.items() if root == ref and refs[f] is not None}
        frames = _initial(graph, shapes, ref, kind, solved)
        links = [k for k in graph.links if k.status == "accepted" and k.source in solved]
        _adjust_links(frames, links, stars, idx)
        misfit = [_misfit(frames, k) for k in links]
        for k, m in zip(links, misfit):
            k.misfit = m
        worst = int(np.argmax(misfit)) if misfit else None
        if worst is None or misfit[worst] <= tolerance:
            break
        links[worst].status = "rejected"
        links[worst].reason = (f"disagrees with the other links by {misfit[worst]:.2f} px "
                               f"(largest over its stars; link_tolerance is {tolerance:g} px)")
    _unsolved_reasons(graph, refs, solved, ref, unsolved)
    # Each link's pairs, grown to every star its two frames share under the link
    # adjustment's solution (mutual nearest neighbours within 3 times the link's
    # RMS, at least 1 px): not just the stars the search matched.
    for k in links:
        pa, pb = np.vstack(stars[k.source].points), np.vstack(stars[k.target].points)
        ca = _apply(_matrix(frames, k.source), pa)
        cb = _apply(_matrix(frames, k.target), pb)
        ia, ib = mutual_matches(ca, cKDTree(cb), max(1.0, 3.0 * k.rms))
        if len(ia) >= len(idx[id(k)][0]):
            idx[id(k)] = (ia, ib)
    obs = _observations(frames, links, stars, idx)
    fit = _adjust_bundle(frames, obs)
    return _assemble(frames, graph, obs, fit, shapes, names, solved, unsolved)


def _initial(graph, shapes, ref, kind, solved):
    """The frames' parameters from the links' transforms along a spanning tree."""
    place = graph.placement(root=ref)
    n = len(shapes)
    centres = np.zeros((n, 2))
    layer = adjust.layer_of(kind)
    parity, theta = np.ones(n), np.zeros((n, layer.k))
    for f in solved:
        ny, nx = shapes[f]
        centres[f] = ((nx - 1) / 2.0, (ny - 1) / 2.0)
        m = place[f][1]
        parity[f] = 1.0 if np.linalg.det(m[:2, :2]) > 0 else -1.0
        theta[f] = adjust.theta_from_matrix(layer, m, centres[f], parity[f])
    return adjust.Frames(kind, centres, parity, theta, ref, frozenset(range(n)) - set(solved))


def _radius(frames):
    """About the largest distance of a frame's pixel from its centre."""
    return float(np.max(np.hypot(frames.centres[:, 0], frames.centres[:, 1]))) + 1.0


def _small(delta, radius):
    """True when a step moves no frame's pixels by more than `_CONVERGED` px."""
    return float(np.max(np.abs(delta), initial=0.0)) * radius < _CONVERGED


def _adjust_links(frames, links, stars, idx):
    """The link adjustment: the transforms from the links' matched pairs (Gauss-Newton)."""
    pairs = []
    for k in links:
        ia, ib = idx[id(k)]
        w = 1.0 / (stars[k.source].error(ia) ** 2 + stars[k.target].error(ib) ** 2)
        pairs.append((k.source, k.target, frames.local(k.source, k.source_points),
                      frames.local(k.target, k.target_points), w))
    radius = _radius(frames)
    for _ in range(_MAX_STEPS):
        delta, _ = adjust.link_step(frames, pairs)
        if delta is None:
            break
        frames.theta += delta
        # As in the bundle: a model linear in its parameters needs one step.
        if _small(delta, radius) or frames.layer.linear:
            break


def _matrix(frames, f):
    return adjust.matrix_from_theta(frames.layer, frames.theta[f], frames.centres[f],
                                    frames.parity[f])


def _apply(m, pts):
    return pts @ m[:2, :2].T + m[:2, 2]


def _misfit(frames, link):
    """Largest distance over the link's stars between its transform and the solution's."""
    both = np.linalg.inv(_matrix(frames, link.target)) @ _matrix(frames, link.source)
    pts = link.source_points
    d = _apply(both, pts) - _apply(as_matrix(link.transform), pts)
    return float(np.max(np.hypot(d[:, 0], d[:, 1])))


def _unsolved_reasons(graph, refs, solved, ref, unsolved):
    """Why each usable frame outside the reference's group could not be solved."""
    for f, r in enumerate(refs):
        if r is None or f in solved:
            continue
        own = [k for k in graph.links if f in (k.source, k.target)]
        tried = [(p, why) for p, why in graph.failures.items() if f in p]
        if not own:
            why = f"no trusted link to any other frame ({len(tried)} pair(s) tried"
            if tried:
                (a, b), msg = tried[0]
                why += f"; with frame {b if a == f else a}: {msg}"
            unsolved[f] = why + ")"
        elif all(k.status == "rejected" for k in own):
            unsolved[f] = "its links were rejected: they disagree with the other links"
        else:
            group = sorted(g for g, (root, _) in graph.placement().items()
                           if root == graph.placement()[f][0])
            unsolved[f] = (f"not connected to the reference frame {ref}: its group of "
                           f"frames {group} has no trusted link to the reference's group")


def _observations(frames, links, stars, idx):
    """
    Every detection of every star seen in two frames or more: the stars
    are the connected groups of the links' matched pairs.  A group holding
    two detections of one frame (contradicting matches) is left out.
    """
    order = sorted(stars)
    offset = dict(zip(order, np.cumsum([0] + [stars[f].n for f in order[:-1]])))
    total = sum(stars[f].n for f in order)
    ends = [(offset[k.source] + idx[id(k)][0], offset[k.target] + idx[id(k)][1])
            for k in links]
    u = np.concatenate([e[0] for e in ends]) if ends else np.zeros(0, int)
    v = np.concatenate([e[1] for e in ends]) if ends else np.zeros(0, int)
    _, label = connected_components(coo_matrix((np.ones(len(u)), (u, v)), shape=(total, total)),
                                    directed=False)
    nodes = np.unique(np.concatenate([u, v]))
    starts = np.array([offset[f] for f in order])
    frame = np.array(order)[np.searchsorted(starts, nodes, side="right") - 1]
    star = nodes - starts[np.searchsorted(starts, nodes, side="right") - 1]
    lab = label[nodes]
    pairs = np.unique(np.column_stack([lab, frame]), axis=0)
    size = np.bincount(lab)
    distinct = np.bincount(pairs[:, 0], minlength=len(size))
    good = (size[lab] == distinct[lab]) & (size[lab] >= 2)
    frame, star, lab = frame[good], star[good], lab[good]
    _, track = np.unique(lab, return_inverse=True)
    q = np.zeros((len(frame), 2))
    err = np.zeros(len(frame))
    for f in np.unique(frame):
        sel = frame == f
        pts = np.vstack(stars[f].points)[star[sel]]
        q[sel] = frames.local(f, pts)
        err[sel] = stars[f].error(star[sel])
    return adjust.Observations(frame, track.ravel(), q, 1.0 / err ** 2,
                               int(track.max()) + 1 if len(track) else 0, var=err ** 2)


@dataclasses.dataclass
class _BundleFit:
    active: np.ndarray  # detections kept (not clipped)
    residuals: np.ndarray  # (n, 2) of every detection, at the solution
    lu: object  # SuperLU factor of the reduced normal matrix
    scale: float  # the reduced chi-square: the covariance's scale


def _subset(obs, keep):
    return adjust.Observations(obs.frame[keep], obs.track[keep], obs.q[keep], obs.w[keep],
                               obs.n_tracks, obs.var[keep])


def _adjust_bundle(frames, obs):
    """
    The bundle adjustment, robust: Gauss-Newton to convergence, then the
    detections beyond `_CLIP_SIGMA` robust sigmas are clipped, until none
    changes.
    """
    active = np.ones(len(obs.frame), bool)
    radius = _radius(frames)
    precond = None  # the first step's factor: a later round's steps need no factor of their own
    for _ in range(5):
        sub = _subset(obs, active)
        for _ in range(_MAX_STEPS):
            delta, _, lu = adjust.bundle_step(frames, sub, precond)
            precond = lu if precond is None else precond
            if delta is None:
                break
            frames.theta += delta
            # A model linear in its parameters is solved by one step (a second
            # would only confirm it, at the cost of a solve of every frame):
            # the area-scale weights (`adjust.weights`) vary by parts in 1e4,
            # and 300 frames solved to convergence differ by 1e-8 px.
            if _small(delta, radius) or frames.layer.linear:
                break
        xs, _ = adjust.star_positions(frames, sub)
        pred = adjust.star_positions(frames, obs)[1]
        resid = pred - xs[obs.track]
        z = np.hypot(resid[:, 0], resid[:, 1]) * np.sqrt(adjust.weights(frames, obs))
        # The median of a 2-D normal's length is 1.177 sigma.
        sigma = np.median(z[active]) / 1.1774 if active.any() else 0.0
        keep = np.isfinite(z) & (z <= _CLIP_SIGMA * max(sigma, 1e-12))
        # The weights with the jitter the residuals show (`adjust.jitter`): the
        # detections' own errors leave out part of the scatter, most for the
        # bright stars, which would otherwise weigh too much.
        old = obs.w
        _, p = frames.index()
        r2 = np.sum(resid[keep] ** 2, axis=1)
        dof = 2 * int(keep.sum()) - p - 2 * len(np.unique(obs.track[keep]))
        j2 = adjust.jitter(r2, 2.0 * obs.var[keep], dof) / 2.0 if dof > 0 else 0.0
        obs.w = 1.0 / (obs.var + j2)
        if np.array_equal(keep, active) and np.allclose(old, obs.w, rtol=1e-3):
            break
        active = keep
    sub = _subset(obs, active)
    _, r, lu = adjust.bundle_step(frames, sub)
    _, p = frames.index()
    dof = 2 * len(sub.frame) - p - 2 * len(np.unique(sub.track))
    chi2 = float(np.sum(adjust.weights(frames, sub) * np.sum(r ** 2, axis=1)))
    return _BundleFit(active, resid, lu, chi2 / dof if dof > 0 else 1.0)


def _assemble(frames, graph, obs, fit, shapes, names, solved, unsolved):
    """The `SequenceSolution` of the solved frames."""
    n, kind = len(shapes), frames.kind
    covs = adjust.frame_covariances(frames, fit.lu, fit.scale)
    transforms, covariances, errors = [None] * n, [None] * n, np.full(n, np.nan)
    accepted = [k for k in graph.links if k.status == "accepted" and k.source in solved]
    for f in sorted(solved):
        mine = [k for k in accepted if f in (k.source, k.target)]
        sel = fit.active & (obs.frame == f)
        r = fit.residuals[sel]
        errors[f] = adjust.predicted_error(frames, f, covs[f], shapes[f])
        # The (6, 6) covariance of the matrix elements, from the parameters'.
        base, theta = _matrix(frames, f)[:2].ravel(), frames.theta[f]
        jac = np.zeros((6, len(theta)))
        for j in range(len(theta)):
            step = 1e-7 * max(1.0, abs(theta[j]))
            t = theta.copy()
            t[j] += step
            m = adjust.matrix_from_theta(frames.layer, t, frames.centres[f], frames.parity[f])
            jac[:, j] = (m[:2].ravel() - base) / step
        covariances[f] = jac @ covs[f] @ jac.T
        try:  # the package model of ``kind`` (a mirrored matrix may need another)
            t = from_matrix(_matrix(frames, f), kind)
        except ValueError:
            t = from_matrix(_matrix(frames, f))
        t.meta["quality"] = dict(
            n_matches=int(sel.sum()), n_links=len(mine),
            rms=float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))) if len(r) else 0.0,
            log10_false_alarm=min((k.log10_false_alarm for k in mine), default=0.0),
            predicted_error=float(errors[f]), covariance=covariances[f])
        transforms[f] = t
    for k in graph.links:
        if k.source in solved and k.target in solved:
            k.misfit = _misfit(frames, k)
            k.residuals = (_apply(_matrix(frames, k.source), k.source_points)
                           - _apply(_matrix(frames, k.target), k.target_points))
    n_stars = len(np.unique(obs.track[fit.active]))
    return SequenceSolution(transforms, covariances, errors, frames.reference, graph.links,
                            dict(sorted(unsolved.items())), list(names), list(shapes),
                            n_stars=n_stars)
