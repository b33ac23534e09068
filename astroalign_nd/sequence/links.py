# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The links of `~astroalign_nd.solve_sequence`: which pairs of frames are
matched, matched by the trusted search (`~astroalign_nd.find_match`'s),
round by round until the frames are connected.
"""

from __future__ import annotations

import warnings
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..exceptions import AstroalignError
from ..matching import bounding_frame, chance_pairs_log10
from ..matching.allpairs import pair_all
from ..registration import find_match_from_config
from ..transforms.convert import as_matrix
from ..transforms.registry import transform_type_of

__all__ = ["Link"]

#: Grid points per side used to predict the overlap of two frames.
_OVERLAP_GRID = 9
#: A guided link (`guided_link`): the first pairing radius (px; the prediction
#: composes two trusted links, good to a few hundredths of a pixel), and the
#: fraction of the source stars predicted on the target frame that must pair.
_GUIDED_RADIUS, _GUIDED_FRACTION = 2.0, 0.5


@dataclass
class Link:
    """
    One matched pair of frames of a `~astroalign_nd.solve_sequence`.

    Attributes
    ----------
    source, target : int
        The frames' indices; ``transform`` maps ``source`` pixels onto
        ``target`` pixels.
    transform : model
        The pair's own transform (`~astroalign_nd.find_match`).
    n_matches : int
        Matched stars.
    rms : float
        The pair's own fit RMS (target px).
    log10_false_alarm : float
        log10 of the probability that this many stars match by chance.
    source_points, target_points : (K, 2) ndarray
        The matched positions, each in its frame's pixels.
    status : {'accepted', 'rejected'}
        'rejected': the link disagreed with the rest (see ``reason``).
    misfit : float
        Largest distance (target px) over the matched stars between the
        link's own transform and the global solution's (NaN when the link
        is not part of the solution).
    residuals : (K, 2) ndarray or None
        ``T_source(source_points) - T_target(target_points)`` under the
        global solution (reference-frame px), None when not solved.
    reason : str
        Why the link was rejected ('' when accepted).
    warnings : list of str
        Warnings the pair's search gave (a poor fit, ...).

    Examples
    --------
    The links of a `~astroalign_nd.sequence.SequenceSolution`:

    >>> import numpy as np
    >>> from astroalign_nd import solve_sequence
    >>> field = np.random.default_rng(0).uniform(0, 300, (80, 2))
    >>> link = solve_sequence([field, field + [10.0, 0.0]]).links[0]
    >>> (link.source, link.target), link.status, link.n_matches
    ((0, 1), 'accepted', 80)
    >>> bool(link.residual_rms < 1e-6)
    True
    """

    source: int
    target: int
    transform: object
    n_matches: int
    rms: float
    log10_false_alarm: float
    source_points: np.ndarray = field(repr=False)
    target_points: np.ndarray = field(repr=False)
    status: str = "accepted"
    misfit: float = np.nan
    residuals: np.ndarray = field(default=None, repr=False)
    reason: str = ""
    warnings: list = field(default_factory=list, repr=False)

    @property
    def residual_rms(self):
        """RMS length of ``residuals`` (px), NaN when not solved."""
        if self.residuals is None or not len(self.residuals):
            return float("nan")
        return float(np.sqrt(np.mean(np.sum(self.residuals ** 2, axis=1))))


def match_link(src, dst, config, a, b):
    """
    The trusted match of frames ``a`` -> ``b`` as a `Link`, or the reason
    there is none (str).  Runs on a dask worker as well as here.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = find_match_from_config(src, dst, config)
        except AstroalignError as exc:
            return f"{type(exc).__name__}: {exc}"
    return Link(a, b, result.transform, int(result.n_matches), float(result.rms),
                float(result.log10_false_alarm), np.array(result.source_points, float),
                np.array(result.target_points, float),
                warnings=[str(w.message) for w in caught])


def guided_link(src, dst, config, a, b, start):
    """
    The link ``a`` -> ``b`` from a predicted transform ``start`` (3x3: the
    composition of two trusted links through a third frame), without a
    search: the stars paired under it and the model refitted on all pairs
    (`~astroalign_nd.matching.allpairs.pair_all`), verified by the share
    of the stars predicted on the target that pair and by the pairs'
    false-alarm figure.  A `Link`, or the reason there is none (str): the
    caller then runs the full search.
    """
    n = config.n_sources
    (s_pts, _, s_frame), (d_pts, _, d_frame) = src.stars(n), dst.stars(n)
    if len(s_pts) < 3 or len(d_pts) < 3:
        return "too few stars for a guided link"
    s_pts, d_pts = np.asarray(s_pts, float), np.asarray(d_pts, float)
    # A catalog has no frame: its stars' bounding box stands for it.
    s_frame, d_frame = (f if f is not None else bounding_frame(p)
                        for f, p in ((s_frame, s_pts), (d_frame, d_pts)))
    try:
        kind = transform_type_of(config.model.transform_type).name
        fit = pair_all(s_pts, d_pts, start, transform_type=kind,
                       tolerance=_GUIDED_RADIUS, max_iterations=5)
    except (AstroalignError, ValueError, np.linalg.LinAlgError) as exc:
        return f"{type(exc).__name__}: {exc}"
    m = as_matrix(fit.transform)
    n_pairs = len(fit.source_index)
    lfa, n_on = chance_pairs_log10(m, s_pts, d_pts, n_pairs, fit.radius, s_frame, d_frame)
    if n_pairs < max(6, _GUIDED_FRACTION * n_on) or lfa > np.log10(
            config.matching.max_false_alarm) or 4.0 * fit.sigma > fit.radius:
        return (f"guided link: {n_pairs} pairs of {n_on} stars, log10 false alarm "
                f"{lfa:.1f}, sigma {fit.sigma:.3f} px in a {fit.radius:.3f} px radius")
    rms = float(np.sqrt(np.mean(np.sum(fit.residuals ** 2, axis=1))))
    return Link(a, b, fit.transform, n_pairs, rms, lfa, s_pts[fit.source_index],
                d_pts[fit.target_index])


class Graph:
    """The links found so far, the frames' components and their placement."""

    def __init__(self, n, shapes):
        self.n, self.shapes = n, shapes
        self.links, self.tried, self.failures = [], set(), {}
        self._parent = list(range(n))  # union-find of the frames joined by links
        self._grids = {}
        self._mats = {}  # (a, b) -> matrix a -> b of each link found, both ways
        self._nbrs = {}  # frame -> the frames linked to it

    def predict(self, a, b):
        """Matrix ``a`` -> ``b`` through a frame linked to both, or None."""
        for g in self._nbrs.get(a, ()):
            if (g, b) in self._mats:
                return self._mats[g, b] @ self._mats[a, g]
        return None

    def group(self, f):
        """The representative of frame ``f``'s group (links found, rejection aside)."""
        while self._parent[f] != f:
            self._parent[f] = f = self._parent[self._parent[f]]
        return f

    def add(self, link):
        """Record a link; True when it joined two groups."""
        self.links.append(link)
        m = as_matrix(link.transform)
        self._mats[link.source, link.target] = m
        self._mats[link.target, link.source] = np.linalg.inv(m)
        self._nbrs.setdefault(link.source, []).append(link.target)
        self._nbrs.setdefault(link.target, []).append(link.source)
        a, b = self.group(link.source), self.group(link.target)
        self._parent[max(a, b)] = min(a, b)
        return a != b

    def neighbours(self, accepted_only=True):
        """Adjacency: frame -> list of (other frame, matrix other<-frame)."""
        adj = {i: [] for i in range(self.n)}
        for link in self.links:
            if accepted_only and link.status != "accepted":
                continue
            m = as_matrix(link.transform)
            adj[link.source].append((link.target, m))
            adj[link.target].append((link.source, np.linalg.inv(m)))
        return adj

    def placement(self, root=None):
        """
        Frame -> (component root, matrix frame pixels -> root pixels), by a
        breadth-first walk of the accepted links (each component from its
        lowest frame, or from ``root``).
        """
        adj = self.neighbours()
        place = {}
        order = ([root] if root is not None else []) + list(range(self.n))
        for start in order:
            if start in place or not adj[start] and start != root:
                continue
            place[start] = (start, np.eye(3))
            todo = deque([start])
            while todo:
                f = todo.popleft()
                for g, m in adj[f]:  # m maps f -> g; g -> root = (f -> root) @ inv(m)
                    if g not in place:
                        place[g] = (start, place[f][1] @ np.linalg.inv(m))
                        todo.append(g)
        return place

    def overlap(self, place, a, b):
        """Predicted fraction of frame ``a`` on frame ``b`` (None: not placed together)."""
        if a not in place or b not in place or place[a][0] != place[b][0]:
            return None
        m = np.linalg.inv(place[b][1]) @ place[a][1]
        ny, nx = self.shapes[a]
        if (ny, nx) not in self._grids:
            self._grids[ny, nx] = np.meshgrid(np.linspace(0, nx - 1, _OVERLAP_GRID),
                                              np.linspace(0, ny - 1, _OVERLAP_GRID))
        gx, gy = self._grids[ny, nx]
        x = m[0, 0] * gx + m[0, 1] * gy + m[0, 2]
        y = m[1, 0] * gx + m[1, 1] * gy + m[1, 2]
        hb, wb = self.shapes[b]
        return float(np.mean((x >= -0.5) & (x <= wb - 0.5) & (y >= -0.5) & (y <= hb - 0.5)))

    def components(self, frames):
        """The connected groups of ``frames`` (largest first, then by lowest frame)."""
        groups = {}
        for f in frames:
            groups.setdefault(self.group(f), []).append(f)
        return sorted(groups.values(), key=lambda g: (-len(g), g[0]))


def chain_pairs(frames):
    """Each frame with the next one in time."""
    return list(zip(frames[:-1], frames[1:]))


def wanted(graph, pairs, place, min_overlap):
    """The pairs of ``pairs`` worth matching: untried, and overlapping unless not placed."""
    out = []
    for a, b in pairs:
        key = (min(a, b), max(a, b))
        if key in graph.tried or a == b:
            continue
        ov = graph.overlap(place, a, b)
        if ov is not None and ov < min_overlap:
            continue
        out.append((a, b))
    return out


def choose_hubs(graph, frames, n_hubs, place, fixed=None):
    """
    The best-connected frames: the ones predicted to overlap the most other
    frames (at least half of a frame each), spread over the sequence.
    """
    hubs = [] if fixed is None else [fixed]
    if len(hubs) >= n_hubs:  # the reference is the only hub: no scores needed (n^2 overlaps)
        return hubs
    score = {}
    for f in frames:
        score[f] = sum((graph.overlap(place, g, f) or 0.0) >= 0.5 for g in frames)
    # Spread: the best of each of n_hubs equal parts of the sequence.
    for part in np.array_split(np.asarray(frames), max(1, n_hubs)):
        if len(hubs) >= n_hubs or not len(part):
            break
        cands = [f for f in part.tolist() if f not in hubs]
        if cands:
            hubs.append(max(cands, key=lambda f: (score[f], -abs(f - np.median(part)))))
    return hubs[:max(1, n_hubs)]


def bridge_pairs(graph, groups, max_tries):
    """Pairs across the groups (each smaller group to the largest), nearest in time first."""
    main = groups[0]
    out = []
    for g in groups[1:]:
        cands = sorted(((a, b) for a in g for b in main), key=lambda p: (abs(p[0] - p[1]), p))
        cands = [p for p in cands if (min(p), max(p)) not in graph.tried]
        out.extend(cands[:max_tries])
    return out
