# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Output planning and resume: the output name of each frame, and which outputs are already done."""

from __future__ import annotations

import os
from ..io.read import batch_frames, frame_name
from ..io import WRITERS, output_suffixes, transform_from_header, writer_for
from ..io.write import FITS_EXTENSIONS

__all__ = ['plan_outputs']

#: Header keywords recording where a "union" canvas lies in reference pixels.
_CANVAS_KEYS = ("AACNVX0", "AACNVY0")

#: Header keywords recording the source frame's shape (a resumed union needs it).
_SOURCE_SHAPE_KEYS = ("AASRCNX", "AASRCNY")

_INPUT_EXTENSIONS = (*FITS_EXTENSIONS, ".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp",
                     ".gif")

# -- output names ----------------------------------------------------------------------------


def _is_path(src):
    return isinstance(src, (str, os.PathLike))


def _stem(name):
    low = name.lower()
    for ext in sorted(_INPUT_EXTENSIONS, key=len, reverse=True):
        if low.endswith(ext):
            return name[: -len(ext)]
    return name


def _output_name(stem, suffix):
    """
    ``<stem><suffix>``, followed by the default format's ending (``.fits``)
    unless ``suffix`` ends in an output format's own (``'_aligned.fits.gz'``).
    """
    try:
        writer_for(suffix)
    except ValueError:
        return f"{stem}{suffix}{output_suffixes()[0]}"
    return f"{stem}{suffix}"


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


def plan_outputs(sources, output_dir, suffix="_aligned", protected=()):
    """
    Output file of each frame, unique by construction.

    A frame's natural output is ``<stem><suffix>.fits``, where ``stem`` is
    its file name without the extension (``frame<i>`` in memory; the file
    name of a ``(frame, file name)`` pair).  A ``suffix`` that ends in the
    ending of an output format (`~astroalign_nd.io.writer_for`:
    ``'_aligned.fits.gz'``, or that of a format added with
    `~astroalign_nd.io.register_writer`) is used as it is, and selects that
    format.  When two frames would share it
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
    stems = [_stem(frame_name(label, i)) for i, (_, label) in enumerate(items)]
    natural = [_output_name(s, suffix) for s in stems]
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
                chosen = _output_name(f"{stem}_{k}", suffix)
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
        base = name = frame_name(label, i)
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
        natural = chosen = _output_name(stem, self.suffix)
        k = 2
        while chosen.casefold() in self.used or chosen.casefold() in self.inputs:
            chosen, k = _output_name(f"{stem}_{k}", self.suffix), k + 1
        self.used.add(chosen.casefold())
        return name, os.path.join(self.output_dir, chosen), (
            None if chosen == natural else (natural, chosen))

# -- resuming --------------------------------------------------------------------------------


def _read_done(path, writers=None):
    """
    The transform, quality, shape and canvas origin recorded in a complete
    registered frame, or a reason why ``path`` is not one.

    The file is read by the writer of its format (`~astroalign_nd.io.writer_for`
    among ``writers``, by default every registered one).
    """
    try:
        header, shape = writer_for(path, WRITERS if writers is None else writers).read_done(path)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is not complete
        return None, f"it is incomplete or unreadable ({type(exc).__name__}: {exc})"
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


def _skip_or_refuse(job, cfg):
    """A complete output to keep (dict), or None to (re)do the frame; raises if refused."""
    if job.output is None or not os.path.lexists(job.output):
        return None
    if cfg.skip_existing:
        done, why = _read_done(job.output, cfg.writers)
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
