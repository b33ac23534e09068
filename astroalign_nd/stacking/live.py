# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Live stacking: frames added one at a time to a running stack, with
clipping against it; and a folder watched for new frames (polling: no
file-system notification library, the same on every platform).
"""

from __future__ import annotations

import dataclasses
import os
import time
from typing import Any, Callable

import numpy as np
from astropy.io import fits
from astropy.nddata import CCDData

from ..io.read import parse_input
from ..config import RegistrationConfig
from ..resample import ResampleConfig
from ..exceptions import warn
from ..io import FITSWriter, write_output
from ..io.write import FITS_EXTENSIONS, check_not_input, check_output_path, interrupts_held
from ..options import AnyCallable, Int, Real, convert
from ..registration import prepare_target, register_and_match
from .combine import array_stats, frame_variance, normalise, reject
from .core import drizzle_ccddata
from .drizzle import DrizzleAccumulator, blot_mask, output_shape, pixel_map, weight_map
from .header import stack_ccddata
from .quality import (as_taken, auto_weight, frame_time, measure_parsed, quality_row, quality_table,
                      quality_weights, select_frames, transparency)
from .options import StackConfig

__all__ = ["LiveStack", "watch_folder", "write_with_retry"]

#: Seconds and tries of `write_with_retry` (a viewer holding the file open, on Windows).
_RETRY_SECONDS, _RETRY_TRIES = 0.2, 25
#: Polls a complete-looking file that does not parse is waited for before it counts as bad.
_UNREADABLE_POLLS = 3


class LiveStack:
    """
    A running stack on the reference's grid, one frame at a time.

    Each frame added is registered onto the reference (prepared once), its
    sky brought to the reference's (``normalize``), and combined into a
    running weighted mean.  Clipping against the running stack: each pixel's
    first ``n_start`` values are held and clipped together about their
    median (as `~astroalign_nd.stack` clips); after them, a pixel of a new frame
    more than ``sigma_low``/``sigma_high`` times the spread from the
    running mean is rejected (the spread is the running standard deviation of the values kept at
    that pixel, but never less than the frame's own uncertainty), so that
    a satellite trail or cosmic ray in one frame does not stay, wherever
    it falls.  Memory: about ``60 + 12 * n_start`` bytes per pixel of the
    reference.  The frames are assumed calibrated.

    Parameters
    ----------
    reference
        The reference frame (anything `~astroalign_nd.register` takes):
        the stack's grid and its first frame.
    hdu, unit, order
        As in `~astroalign_nd.register`.
    name : str, optional
        The reference's name in the header.
    **options
        The stacking options of a live stack, the fields of
        `~astroalign_nd.stacking.StackConfig` it takes: ``clip`` ('sigma',
        the default, or None), ``sigma`` (3; ``sigma_low``, ``sigma_high``),
        ``maxiters``, ``n_start`` (each pixel's values held and clipped
        together, about their median, before the running clipping starts
        there: default 5, at least 3; the stack clips the values held as
        soon as there are three, but five tell a trail and a cosmic ray in
        two of the first frames from the sky), ``normalize``, ``weights``
        ('variance', 'auto' or None: 'auto' from each frame's transparency,
        sky noise and star size, relative to the reference's), ``select``
        (None or 'auto': a frame trailed or an outlier among the frames so
        far is left out with the reason, and a warning), ``max_fwhm``,
        ``max_elongation``, ``min_transparency``, ``min_stars``, ``gain``
        and ``read_noise``; and `~astroalign_nd.register`'s options.

    Attributes
    ----------
    used : list of str
        The frames in the stack (the reference first).
    rejected : list of (str, str)
        The frames that failed or were left out, and why.
    quality : `~astropy.table.Table`
        Every frame measured so far, as `~astroalign_nd.frame_quality`
        gives it (those left out too, with the reason).

    Examples
    --------
    >>> from astroalign_nd.stacking import LiveStack
    >>> from astroalign_nd.simulate import simulate_sequence
    >>> seq = simulate_sequence((128, 128), n_frames=4, n_stars=60, seed=3)
    >>> live = LiveStack(seq.frames[0])
    >>> for k, frame in enumerate(seq.frames[1:], start=1):
    ...     live.add(frame, name=f"frame{k}")
    >>> ccd = live.result()
    >>> ccd.meta["NCOMBINE"], live.used[-1]
    (4, 'frame3')
    """

    def __init__(self, reference: Any, *, hdu: int | str | None = None, unit: Any = None,
                 order: str | int = "bilinear", name: str = "reference", **options: Any):
        self.opts, options = StackConfig.from_keywords("live", options)
        self.hdu, self.unit = hdu, unit
        self.options = dict(options, order=order)
        resample = {f.name for f in dataclasses.fields(ResampleConfig)}
        config = RegistrationConfig.from_keywords(
            **{k: v for k, v in options.items() if k not in resample})
        self._ref = prepare_target(reference, config, hdu)
        parsed = parse_input(reference, "reference", hdu=hdu, unit=unit)
        if parsed.data is None or parsed.data.ndim != 2:
            raise ValueError("the reference must be a 2-D image.")
        self.shape, self.wcs, self.meta = parsed.data.shape, parsed.wcs, parsed.meta
        self.unit_out = parsed.unit or "adu"
        self.used, self.rejected, self._stats = [], [], []
        self._acc, self._ref_sky = _Running(self.shape, self.opts.n_start), None
        self._driz = None if self.opts.drizzle is None else DrizzleAccumulator(
            output_shape(self.shape, self.opts.drizzle), self.opts.drizzle, self.opts.pixfrac,
            self.opts.kernel)
        self._ref_data = np.asarray(parsed.data, dtype=np.float64)
        self._ref_m = measure_parsed(parsed)
        row = quality_row(name, self._ref_m, self._ref_m, 1.0, self._ref_m.n_stars,
                          time=frame_time(parsed.meta))
        row["weight"] = 1.0
        self._rows = [row]
        valid = np.isfinite(parsed.data) & (True if parsed.mask is None else ~parsed.mask)
        var = _variance(parsed.uncertainty)
        self._add_arrays(self._ref_data, var, valid, (parsed, None), name, (row, self._ref_m))

    @property
    def quality(self):
        """Every frame measured so far (`~astroalign_nd.frame_quality`'s table)."""
        return quality_table(self._rows)

    def add(self, frame: Any, name: str | None = None) -> str | None:
        """
        Register ``frame`` onto the reference and add it to the stack.

        Parameters
        ----------
        frame
            A path, array, NDData/CCDData...
        name : str, optional
            Its name in the header (default: the file name, or ``frame<n>``).

        Returns
        -------
        left_out : str or None
            Why the frame was left out (``select``, the limits: it is then
            in ``rejected``, and a warning says so), or None once added.

        Raises
        ------
        Exception
            Whatever registering it raised (`~astroalign_nd.AstroalignError`,
            `ValueError`...): the stack is then unchanged.
        """
        if name is None:
            name = os.path.basename(os.fspath(frame)) if isinstance(
                frame, (str, os.PathLike)) else f"frame{len(self.used) + len(self.rejected)}"
        prepared = self._registered(frame, name)
        with interrupts_held():  # a Ctrl-C leaves the frame out or in, never half added
            return self._commit(prepared, name)

    def _registered(self, frame, name):
        """
        ``frame`` on the reference's grid and measured as taken, nothing added yet:
        ``(data, variance, valid, raw, (row, measures))``; ``raw`` is the frame as
        given and its transform when drizzling, else None.
        """
        ccd, result = register_and_match(frame, self._ref, hdu=self.hdu, unit=self.unit,
                                         **self.options)
        parsed = parse_input(frame, "source", hdu=self.hdu, unit=self.unit)
        row, m = self._measure(parsed, name, result)
        data = np.asarray(ccd.data, dtype=np.float64)
        valid = np.isfinite(data) & (True if ccd.mask is None else ~np.asarray(ccd.mask))
        raw = None if self._driz is None else (parsed, result.transform)
        return data, _variance(ccd.uncertainty), valid, raw, (row, m)

    def _commit(self, prepared, name):
        """
        A registered frame added to the stack, or left out by the selection
        (returns the reason then, else None).
        """
        data, var, valid, raw, (row, m) = prepared
        why = self._left_out(row)
        if why is not None:
            row.update(used=False, reason=why)
            self._rows.append(row)
            warn(f"{name} was left out of the live stack: {why}")
            self.fail(name, why)
            return why
        self._rows.append(row)
        self._add_arrays(data, var, valid, raw, name, (row, m))
        return None

    def _measure(self, p, name, result):
        """The frame's quality row and measures as taken (before resampling)."""
        data = np.asarray(p.data, dtype=np.float64)
        m = measure_parsed(p)
        t, n = transparency(data, self._ref_data, result.source_points, result.target_points,
                            m, self._ref_m)
        row = quality_row(name, m, self._ref_m, t, n, dict(
            rms=result.rms, log10_false_alarm=result.log10_false_alarm),
            time=frame_time(p.meta))
        row["weight"] = float(quality_weights(quality_table([self._rows[0], row]))[1])
        return row, m

    def _left_out(self, row):
        """Why the new frame is left out (the limits, and 'auto' among the frames so far)."""
        o = self.opts
        rows = [r for r in self._rows if r.get("used", True)] + [row]
        reasons = select_frames(quality_table(rows), o.select, max_fwhm=o.max_fwhm,
                                max_elongation=o.max_elongation,
                                min_transparency=o.min_transparency, min_stars=o.min_stars,
                                min_frames=0)
        return reasons[-1]

    def _add_arrays(self, data, var, valid, raw, name, measured):
        st = array_stats(data, var, valid)
        as_taken(st, *measured)
        self._ref_sky = st.sky if self._ref_sky is None else self._ref_sky
        normalise(st, self._ref_sky, self.opts.normalize)
        var = frame_variance(data, var, st, self.opts.gain, self.opts.read_noise)
        x = data * st.scale - st.offset
        var = var * st.scale ** 2
        valid = valid & np.isfinite(var)
        if self.opts.weights == "auto":
            st.weight = auto_weight(st)
        else:
            st.weight = 1.0 if self.opts.weights is None else \
                1.0 / max(float(np.median(var[valid])), 1e-300)
        self._stats.append(st)
        self.used.append(name)
        rejected = self._acc.add(x, var, valid, len(self._stats) - 1, self._stats, self.opts)
        if self._driz is not None:
            self._drizzle(raw, st, rejected)

    def _drizzle(self, raw, st, rejected):
        """
        Drizzle a frame as it arrives, its pixels rejected against the running stack
        (blotted back onto it) weighing nothing.  The values held at a pixel until
        ``n_start`` frames reach it are clipped later, after those frames were
        drizzled: there, the first frames' outliers stay.
        """
        parsed, transform = raw
        data = np.asarray(parsed.data, dtype=np.float64)
        var = frame_variance(data, _variance(parsed.uncertainty), st, self.opts.gain,
                             self.opts.read_noise)
        pm = pixel_map(transform, data.shape)
        w = weight_map(data, parsed.mask, var, weight=st.weight, saturation=self.opts.saturation)
        w[blot_mask(rejected, pm)] = 0.0
        s = self.opts.drizzle
        self._driz.add(data * st.scale - st.offset, s * (pm + 0.5) - 0.5, w, var * st.scale ** 2)

    def fail(self, name: str, reason: str) -> None:
        """Record a frame that could not be added (listed in the header)."""
        self.rejected.append((name, reason))

    def result(self) -> CCDData:
        """
        The stack so far.

        Returns
        -------
        stacked : `~astropy.nddata.CCDData`
            As `~astroalign_nd.stack` returns it (``flags``: the frames
            reaching each pixel).
        """
        value, variance, coverage = self._acc.value(self._stats, self.opts)
        if self._driz is not None:
            settings = {"AASTKMTH": ("live average", "astroalign_nd live stack"),
                        "AASTKCLP": (self.opts.clip or "none", "rejection vs the running stack"),
                        "AASTKNRM": (self.opts.normalize or "none", "sky normalisation")}
            return drizzle_ccddata(self._driz.planes(), coverage, self.opts, settings,
                                   meta=self.meta, wcs=self.wcs, offset=(0, 0), names=self.used,
                                   stats=self._stats, rejected=self.rejected,
                                   unit=self.unit_out, dtype=np.float32,
                                   how="each frame as it arrived, its outliers against the "
                                   "running stack blotted back")
        reach = coverage > 0
        value, variance = np.where(reach, value, np.nan), np.where(reach, variance, np.nan)
        settings = {"AASTKMTH": ("live average", "astroalign_nd live stack"),
                    "AASTKCLP": (self.opts.clip or "none", "rejection vs the running stack"),
                    "AASTKNRM": (self.opts.normalize or "none", "sky normalisation")}
        return stack_ccddata(value, variance, coverage, meta=self.meta, names=self.used,
                             stats=self._stats, rejected=self.rejected, settings=settings,
                             wcs=self.wcs, unit=self.unit_out)


class _Running:
    """
    Per-pixel running sums (the weighted mean and its variance, the values'
    mean and spread), and each pixel's first ``n_start`` values held until
    they can be clipped together: a pixel is clipped against the running
    stack only once it has a stack to be clipped against.
    """

    def __init__(self, shape, n_start):
        self.n_start = n_start
        self.wsum, self.wx, self.w2v = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        self.n = np.zeros(shape, dtype=np.int32)
        self.mean, self.m2 = np.zeros(shape), np.zeros(shape)  # Welford, for the spread
        self.coverage = np.zeros(shape, dtype=np.int16)
        self.started = np.zeros(shape, dtype=bool)
        # The held values: float32 keeps the memory at about 10 bytes per pixel per frame.
        self.held_x = np.zeros((n_start,) + tuple(shape), dtype=np.float32)
        self.held_v = np.zeros((n_start,) + tuple(shape), dtype=np.float32)
        self.held_k = np.full((n_start,) + tuple(shape), -1, dtype=np.int32)
        self.n_held = np.zeros(shape, dtype=np.int8)

    def take(self, where, x, var, w):
        """Add the values ``x`` (with variance ``var``, weight ``w``) at pixels ``where``."""
        self.wsum[where] += w
        self.wx[where] += w * x
        self.w2v[where] += w * w * var
        n_new = self.n[where] + 1
        delta = x - self.mean[where]
        self.mean[where] += delta / n_new
        self.m2[where] += delta * (x - self.mean[where])
        self.n[where] = n_new

    def add(self, x, var, valid, k, stats, opts):
        """
        Frame ``k``'s values: clipped against the stack where it has started, else held.
        Returns its values rejected now (True), on the reference's grid.
        """
        st = stats[k]
        self.coverage += valid.astype(np.int16)
        run = valid & self.started
        xs, vs = x[run], var[run]
        rejected = np.zeros(valid.shape, dtype=bool)
        if opts.clip == "sigma":
            with np.errstate(invalid="ignore", divide="ignore"):
                spread = np.fmax(np.sqrt(self.m2[run] / np.maximum(self.n[run] - 1, 1)),
                                 np.sqrt(vs))
                mean = self.mean[run]
                far = (xs - mean > opts.sigma_high * spread) | (mean - xs > opts.sigma_low
                                                                * spread)
            st.n_rejected += int(far.sum())
            rejected[run] = far
            run[run] = ~far
            xs, vs = x[run], var[run]
        self.take(run, xs, vs, st.weight)
        self._hold(x, var, valid & ~self.started, k, stats, opts)
        return rejected

    def _hold(self, x, var, hold, k, stats, opts):
        """Hold frame ``k``'s values at ``hold``; clip and add the pixels that have enough."""
        slot = self.n_held[hold].astype(np.intp)
        rows, cols = np.nonzero(hold)
        self.held_x[slot, rows, cols] = x[hold]
        self.held_v[slot, rows, cols] = var[hold]
        self.held_k[slot, rows, cols] = k
        self.n_held[hold] += 1
        full = hold & (self.n_held == self.n_start)
        if not full.any():
            return
        hx = self.held_x[:, full].astype(np.float64)
        hv = self.held_v[:, full].astype(np.float64)
        hk = self.held_k[:, full]
        keep = reject(hx, hv, np.ones(hx.shape, dtype=bool), opts) if opts.clip else \
            np.ones(hx.shape, dtype=bool)
        weights = np.array([s.weight for s in stats])
        where = np.nonzero(full)
        for j in range(self.n_start):  # in order: the values' running mean as if one by one
            kj = keep[j]
            sub = tuple(w[kj] for w in where)
            mask = np.zeros(full.shape, dtype=bool)
            mask[sub] = True
            self.take(mask, hx[j][kj], hv[j][kj], weights[hk[j][kj]])
        for kk in np.unique(hk[~keep]):
            stats[kk].n_rejected += int(((hk == kk) & ~keep).sum())
        self.started |= full
        self.n_held[full] = 0

    def value(self, stats, opts):
        """
        The stack: the running sums, plus the values held where it has not
        started (clipped together once there are three).
        """
        weights = np.array([s.weight for s in stats])
        wsum, wx, w2v = self.wsum.copy(), self.wx.copy(), self.w2v.copy()
        at = (~self.started) & (self.n_held > 0)
        n_held = self.n_held[at]
        valid = np.arange(self.n_start)[:, None] < n_held
        hx = self.held_x[:, at].astype(np.float64)
        hv = self.held_v[:, at].astype(np.float64)
        keep = valid
        if opts.clip:
            keep = np.where(n_held >= 3, reject(hx, hv, valid, opts), valid)
        w = np.where(keep, weights[np.maximum(self.held_k[:, at], 0)], 0.0)
        wsum[at] += w.sum(axis=0)
        wx[at] += (w * np.where(keep, hx, 0.0)).sum(axis=0)
        w2v[at] += (w * w * np.where(keep, hv, 0.0)).sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            return wx / wsum, w2v / (wsum * wsum), self.coverage


def _variance(uncertainty):
    """An NDUncertainty as a float64 variance array (None without one)."""
    if uncertainty is None:
        return None
    name = type(uncertainty).__name__
    u = np.asarray(uncertainty.array, dtype=np.float64)
    if name == "StdDevUncertainty":
        return u * u
    if name == "InverseVariance":
        with np.errstate(divide="ignore"):
            return np.where(u > 0, 1.0 / np.where(u > 0, u, 1.0), np.inf)
    if name == "VarianceUncertainty":
        return u.copy()
    raise ValueError(f"a stack needs StdDevUncertainty, VarianceUncertainty or "
                     f"InverseVariance; got {name}.")


def write_with_retry(ccd, path, *, overwrite=True, tries=_RETRY_TRIES):
    """
    Write ``ccd`` atomically, retrying while the old file cannot be replaced.

    On Windows a viewer that holds the file open makes the final rename fail
    with `PermissionError`; the write is retried every 0.2 s, ``tries``
    times, and a reader always sees the old or the new file, never a part.

    Parameters
    ----------
    ccd : `~astropy.nddata.CCDData`
    path : str
    overwrite : bool, optional
    tries : int, optional

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.nddata import CCDData
    >>> from astroalign_nd.stacking.live import write_with_retry
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "stack.fits")
    ...     write_with_retry(CCDData(np.ones((3, 3)), unit="adu"), path)
    ...     write_with_retry(CCDData(np.zeros((3, 3)), unit="adu"), path)
    ...     print(os.listdir(folder))
    ['stack.fits']
    """
    for attempt in range(tries):
        try:
            write_output(ccd, path, overwrite=overwrite)
            return
        except PermissionError:
            if attempt == tries - 1:
                raise
            time.sleep(_RETRY_SECONDS)


class _Poller:
    """
    The new files of a folder: stable across two polls, then parsed, each once.

    A file that stays unreadable for `_UNREADABLE_POLLS` polls is given up, until it
    changes again (a slow writer: a network share, a camera over USB); the files the
    package writes itself (registered frames, stacks: their ``AAT*`` keywords) are set
    aside, never stacked on top of the raw frames.
    """

    def __init__(self, folder, ignore):
        self.folder = folder
        self.ignore = {os.path.realpath(p) for p in ignore}
        self.seen, self.last, self.bad_polls, self.gave_up = set(), {}, {}, {}
        self.paths = {}  # real path -> the path in the folder
        self.listing_errors = 0

    def _names(self):
        """The folder's file names; an error once it cannot be listed for a few polls."""
        try:
            names = sorted(os.listdir(self.folder))
        except OSError as exc:
            self.listing_errors += 1
            if self.listing_errors >= _UNREADABLE_POLLS:
                raise OSError(f"the watched folder {self.folder} cannot be read any more "
                              f"({exc.strerror or exc}): it was removed, renamed or made "
                              "unreadable; give the folder again, or another one.") from None
            return []
        self.listing_errors = 0
        return names

    def scan(self):
        """
        ``(ready, unreadable, own)``: paths complete now, paths given up as unreadable,
        and the package's own outputs (set aside).
        """
        ready, unreadable, own, now = [], [], [], {}
        for name in self._names():
            path = os.path.join(self.folder, name)
            real = os.path.realpath(path)
            if real in self.seen or real in self.ignore or not (
                    name.lower().endswith(FITS_EXTENSIONS) and not name.startswith(".")):
                continue
            try:
                st = os.stat(path)
            except OSError:
                continue
            key = (st.st_size, st.st_mtime_ns)
            now[real] = key
            self.paths[real] = path
            if self.gave_up.get(real, key) != key:
                del self.gave_up[real]  # it changed: look at it again
            if real in self.gave_up:
                continue
            if self.last.get(real) != key or st.st_size == 0:
                self.bad_polls.pop(real, None)  # still being written: count afresh
                continue
            try:  # all its data blocks there (the check a resumed batch makes)?
                _, shape = FITSWriter().read_done(path)
            except Exception:  # noqa: BLE001 - any failure to parse: not (yet) a complete file
                shape = None
            if shape is not None:
                self.seen.add(real)
                try:  # a file this package wrote: a registered frame or a stack
                    header = fits.getheader(path)
                    package = "AATTYPE" in header or "AASTKMTH" in header
                except (OSError, ValueError):
                    package = False
                (own if package else ready).append(path)
            else:
                self.bad_polls[real] = self.bad_polls.get(real, 0) + 1
                if self.bad_polls[real] >= _UNREADABLE_POLLS:
                    unreadable.append(path)
                    self.gave_up[real] = key
        self.last = now
        return ready, unreadable, own

    def waiting(self):
        """The files seen but not taken yet: still being written (or not yet stable)."""
        return [self.paths[real] for real in sorted(self.last)
                if real not in self.seen and real not in self.gave_up]


def watch_folder(folder: str | os.PathLike, reference: Any, output: str | os.PathLike, *,
                 interval: float = 2.0, max_frames: int | None = None,
                 timeout: float | None = None, overwrite: bool = False,
                 callback: Callable[[str, str | None], Any] | None = None,
                 **options: Any) -> LiveStack:
    """
    Stack the FITS frames that appear in ``folder``, as they appear.

    The folder is polled every ``interval`` seconds (no file-system
    notification: the same on every platform).  A new file is taken once
    it is complete: the same size and time across two polls, and a FITS
    file that parses in full.  Each is registered and added to a
    `LiveStack`, and the stack is rewritten to ``output`` atomically after
    each frame (a reader sees the old stack or the new one, never part of
    a file; on Windows the write is retried while a viewer holds the file).
    Hidden files (the package's temporary files among them), ``output``
    and the reference are ignored; a frame that fails is listed in the
    header and the watch goes on.  Interrupted (`KeyboardInterrupt`), it
    writes the stack and re-raises.

    Parameters
    ----------
    folder : str or path
    reference
        The reference frame (its grid; the stack's first frame).
    output : str or path
        The stack's FITS file (written at once, with the reference alone).
    interval : float, optional
        Seconds between polls (default 2).
    max_frames : int, optional
        Stop after this many new frames (added or failed).
    timeout : float, optional
        Stop when no new frame has come for this many seconds.
    overwrite : bool, optional
        Replace ``output`` if it exists at the start (default False:
        `FileExistsError`).
    callback : callable, optional
        ``callback(path, error)`` after each frame (``error`` None if added).
    **options
        As in `LiveStack`.

    Returns
    -------
    live : `LiveStack`
        Its ``used`` and ``rejected`` list the frames.

    Examples
    --------
    Three frames already in the folder (a script would copy them in as
    they come); the watch stops after 0.2 s without a new one:

    >>> import os, tempfile
    >>> from astroalign_nd.io import write_ccddata
    >>> from astroalign_nd.simulate import simulate_sequence
    >>> from astroalign_nd.stacking import watch_folder
    >>> seq = simulate_sequence((128, 128), n_frames=3, n_stars=60, seed=3)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     for k, frame in enumerate(seq.frames):
    ...         write_ccddata(frame, os.path.join(folder, f"f{k}.fits"))
    ...     live = watch_folder(folder, os.path.join(folder, "f0.fits"),
    ...                         os.path.join(folder, "stack.fits"), interval=0.05, timeout=0.2)
    >>> live.used, live.rejected
    (['f0.fits (reference)', 'f1.fits', 'f2.fits'], [])
    """
    folder, output = os.fspath(folder), os.fspath(output)
    interval = convert("interval", Real(0, lo_open=True, unit="seconds"), interval)
    timeout = convert("timeout", Real(0, none=True, unit="seconds"), timeout)
    max_frames = convert("max_frames", Int(1, None, none=True), max_frames)
    callback = convert("callback", AnyCallable("a function of (path, error)"), callback)
    if not os.path.isdir(folder):
        raise NotADirectoryError(f"folder {folder!r} does not exist or is not a folder.")
    inputs = [reference] if isinstance(reference, (str, os.PathLike)) else []
    check_not_input(output, inputs)
    check_output_path(output, overwrite)
    name = (os.path.basename(os.fspath(reference)) if inputs else "reference") + " (reference)"
    live = LiveStack(reference, name=name, **options)
    write_with_retry(live.result(), output, overwrite=overwrite)
    poller = _Poller(folder, [output] + [os.fspath(p) for p in inputs])
    callback = callback or (lambda path, error: None)
    todo = []  # the frames taken and not yet added (or failed) and reported
    try:
        _watch_loop(live, poller, output, interval, max_frames, timeout, callback, todo)
    except KeyboardInterrupt as exc:
        # Every frame seen is accounted for, in the header and to the callback alike.
        why = f"not stacked: the watch was stopped ({str(exc) or 'SIGINT'}) before it was"
        for path, state in [(p, "registered") for p in todo] + [
                (p, "completely written") for p in poller.waiting()]:
            live.fail(os.path.basename(path), f"{why} {state}")
            callback(path, f"{why} {state}")
        write_with_retry(live.result(), output)  # the last frame added is in the file
        exc.partial_result = live
        raise
    return live


def _watch_loop(live, poller, output, interval, max_frames, timeout, callback, todo):
    """
    Poll, add and write until ``max_frames`` or ``timeout`` (or an interrupt); ``todo``
    holds the frames taken and not yet in the stack (or failed) and reported.
    """
    n_done, last_new, failed = 0, time.monotonic(), {}
    while max_frames is None or n_done < max_frames:
        ready, unreadable, own = poller.scan()
        todo.extend(ready)
        left_out = [(p, "not a complete FITS file") for p in unreadable]
        left_out += [(p, "an astroalign_nd output (AAT* keywords: a registered frame or a "
                      "stack), not a raw frame; not stacked again") for p in own]
        for path, why in left_out:
            if path in failed:  # given up again after a change: one entry per file
                live.rejected.remove(failed[path])
            failed[path] = (os.path.basename(path), why)
            live.fail(*failed[path])
            callback(path, why)
        while todo:
            path, error = todo[0], None
            try:
                # (interrupted here: not in the stack)
                prepared = live._registered(path, os.path.basename(path))
            except Exception as exc:  # noqa: BLE001 - a bad frame is listed, not fatal
                error = f"{type(exc).__name__}: {exc}"
            with interrupts_held():  # the stack and the console change together
                if path in failed:  # given up before, complete now: no longer a failure
                    live.rejected.remove(failed.pop(path))
                if error is None:  # (the reason when the selection leaves it out)
                    error = live._commit(prepared, os.path.basename(path))
                else:
                    live.fail(os.path.basename(path), error)
                todo.pop(0)
                callback(path, error)
            write_with_retry(live.result(), output)
            n_done += 1
            if max_frames is not None and n_done >= max_frames:
                todo.clear()  # the rest are taken again by the next watch (not marked seen)
                return
        if left_out:
            write_with_retry(live.result(), output)
            n_done += len(left_out)
        if ready or left_out:
            last_new = time.monotonic()
        elif timeout is not None and time.monotonic() - last_new >= timeout:
            return
        time.sleep(interval)
