# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The stacking options: `StackConfig`, each option's default, accepted values,
message and command-line flag once (the package's one checking system,
``astroalign_nd.options``).

`~astroalign_nd.stack` and the live stack (`~astroalign_nd.stacking.LiveStack`,
`~astroalign_nd.stacking.watch_folder`) take these options as keywords and
check them by building a `StackConfig` (`StackConfig.from_keywords`); the
``stack`` and ``watch`` commands' combination flags are generated from its
fields.

To add a stacking option, add one field to `StackConfig`:

- ``option(default, check, help, used_by=..., flag=...)``: the default; the
  accepted values (``astroalign_nd.options.Real``, ``Int``, ``Choice``...,
  or a class with ``describe`` and ``convert`` such as ``FrameWeights``); the
  help text of its flag; which users take it, ``("stack",)``,
  ``("live",)`` or both (None; ``"live"`` is ``LiveStack``, ``watch_folder``
  and the ``watch`` command); and with ``flag="--name"`` (and ``type``,
  ``metavar``...; a ``Choice`` gives the flag its choices, None spelled
  ``none``) its command-line flag, on the commands of its users;
- a line in the class's docstring;
- its use where the stack reads it: ``opts.<name>``, the `StackConfig` that
  ``stack`` (``stacking/core.py``, passing it on to ``combine.py``) and
  ``LiveStack`` (``live.py``) hold.

``stack(name=...)``, ``LiveStack(name=...)`` and the flag then exist and
are checked, with no list to edit; ``tests/stacking/test_stack_options.py``
checks that every field reaches its users.
"""

import dataclasses

import numpy as np

from ..options import Choice, Int, Real, check_fields, convert, fields_of, option

__all__ = ["StackConfig", "FrameWeights", "FrameSelection", "STACK_METHODS", "CLIP_METHODS",
           "NORMALIZE_METHODS", "WEIGHT_METHODS", "DEMOSAIC_METHODS", "DEFAULT_MEMORY_LIMIT"]

# The two lists below are declared here, not imported from ``drizzle.py`` and
# ``io/bayer.py`` (which use them), so that the command line's flags are built
# without importing astropy.modeling or the drizzle package.

#: The drizzle kernels, as the `drizzle` package names them.
DRIZZLE_KERNELS = ("square", "gaussian", "point", "turbo", "lanczos2", "lanczos3")
#: The Bayer patterns understood, by the colours of the first 2x2 cell row by row.
BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")

#: The combinations: weighted mean, median, and the sum (the mean times the number of frames).
STACK_METHODS = ("average", "median", "sum")
#: The rejections: sigma clipping about the median, min/max (extrema) clipping, none.
CLIP_METHODS = ("sigma", "minmax", None)
#: The sky normalisations: an offset (sky added), a scale (the sky ratio), the stars'
#: flux ratio (transparency from matched stars) with the sky offset, none.
NORMALIZE_METHODS = ("offset", "scale", "stars", None)
#: The frame weights by name: the inverse median variance, the faint-source weights from
#: each frame's transparency, sky noise and star size, equal weights.
WEIGHT_METHODS = ("variance", "auto", None)
#: The demosaicing methods of ``colour-demosaicing`` offered for raw colour frames.
DEMOSAIC_METHODS = ("Menon2007", "Malvar2004", "bilinear")
#: Default working memory of the combination, bytes.
DEFAULT_MEMORY_LIMIT = 512e6

#: Who takes the options (`option`'s ``used_by``), as a message names them.
_USERS = {"stack": "stack", "live": "a live stack (LiveStack, watch_folder, watch)"}


class FrameWeights:
    """The frame weights: one of `WEIGHT_METHODS`, or one number >= 0 per frame, not all 0."""

    choices = WEIGHT_METHODS

    def describe(self):
        return (f"{' or '.join(map(repr, self.choices))} or a sequence of finite numbers "
                ">= 0 (one per frame, not all 0)")

    def convert(self, value):
        if value is None or isinstance(value, str):
            if value in self.choices:
                return value
            raise ValueError
        try:
            w = np.asarray(value, dtype=float).ravel()
        except (TypeError, ValueError):
            raise TypeError from None
        if not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError
        return tuple(float(v) for v in w)


class FrameSelection:
    """The frame selection: None, 'auto', or a fraction of the frames to keep in (0, 1]."""

    # (Not ``choices``: the command line's flag takes a fraction too.)
    names = (None, "auto")

    def describe(self):
        return "None, 'auto' or a fraction of the frames to keep in (0, 1]"

    def convert(self, value):
        if value is None or isinstance(value, str):
            if value in self.names:
                return value
            try:  # the command line's fraction
                value = float(value)
            except ValueError:
                raise ValueError from None
        if isinstance(value, bool):
            raise TypeError
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise TypeError from None
        if not 0 < f <= 1:
            raise ValueError
        return f


@dataclasses.dataclass(frozen=True)
class StackConfig:
    """
    How frames are stacked (the options of `~astroalign_nd.stack`, and of
    the live stack: `~astroalign_nd.stacking.LiveStack`).

    Parameters
    ----------
    method : {'average', 'median', 'sum'}, optional
        'average' (default): the weighted mean.  'median': the median (its
        uncertainty is ``sqrt(pi / 2)`` times the mean's).  'sum': the mean
        times the number of frames, so that a pixel some frames miss is
        not darker.  (`~astroalign_nd.stack` only: a live stack averages.)
    clip : {'sigma', 'minmax', None}, optional
        Rejection before combining.  'sigma' (default): values more than
        ``sigma_low``/``sigma_high`` spreads below/above the pixel's median
        are dropped, for up to ``maxiters`` rounds; the spread is the
        values' MAD standard deviation, but never less than the frames'
        median uncertainty at that pixel.  'minmax' (not for a live
        stack): the ``nlow`` lowest and ``nhigh`` highest values of each
        pixel are dropped (ccdproc's ``clip_extrema``).  A pixel whose
        values would all go keeps them.  None: no rejection.
    sigma, sigma_low, sigma_high : float, optional
        Sigma clipping's limits (``sigma``, 3 by default, for both sides;
        after construction ``sigma_low`` and ``sigma_high`` hold the
        limits used).
    maxiters : int, optional
        Sigma clipping's rounds at most (default 3).
    nlow, nhigh : int, optional
        Min/max clipping's counts (default 1 and 1).
    normalize : {'offset', 'scale', 'stars', None}, optional
        Bring each frame's sky (its sigma-clipped median) to the
        reference's before the rejection, so that a night's changing sky
        does not decide which frames are clipped: 'offset' (default)
        subtracts the difference (moonlight, twilight: sky added), 'scale'
        multiplies by the ratio (needs positive sky levels), 'stars'
        divides by the transparency measured on the matched stars (thin
        cloud; not the sky ratio, which clouds and moonlight break) and
        subtracts the sky offset, None leaves the frames as they are.
    gain, read_noise : float, optional
        For frames without an uncertainty: their variance is
        ``max(value, 0) / gain + (read_noise / gain) ** 2`` (``gain`` in
        electrons per count, ``read_noise`` in electrons, as ccdproc's
        ``create_deviation``).  Without ``gain``, such a frame's variance
        is its measured sky noise squared.  Frames with an uncertainty
        use their own, propagated through the registration.
    weights : 'variance', 'auto', None or sequence of float, optional
        'variance' (default): each frame weighs the inverse of its median
        pixel variance as taken, before resampling (per frame, not per
        pixel: per-pixel weights from a Poisson variance would favour the
        pixels that came out low).  'auto': the weights that maximise faint
        point sources' signal-to-noise, ``T**2 / (sigma**2 * A)`` from each
        frame's transparency ``T``, sky noise ``sigma`` and PSF
        noise-equivalent area ``A`` (`~astroalign_nd.frame_quality`; the
        derivation is in the frame quality docs).  None: equal weights.
        A sequence (not for a live stack): one weight per frame, the
        reference's first when it is not one of the frames.
    memory_limit : float, optional
        Bytes of working memory for the combination (default 512 MB).
    canvas : {'reference', 'union'}, optional
        The stack's grid, as in `~astroalign_nd.register_batch`.
    n_start : int, optional
        A live stack's values held at each pixel and clipped together
        (about their median) before the running clipping starts there
        (default 5, at least 3).
    drizzle : float, optional
        Drizzle the frames onto a grid ``drizzle`` times finer than the
        reference's (or the canvas's), e.g. 2, instead of interpolating
        them: each frame's own pixels, shrunk by ``pixfrac``, are dropped
        at their true positions through the frame's transform (any type,
        polynomial distortion included) by the `drizzle` package, one frame
        at a time, which recovers resolution from the dithers between
        undersampled frames.  The rejection is the stack's (the clipped
        combination on the reference's grid finds the outliers; they are
        carried back onto each frame and weigh nothing there); the weights
        and sky normalisation are the stack's (per frame from the sky
        noise, per pixel from masks, NaN and ``saturation``).  The output
        holds counts per output pixel (flux conserved: a flat sky of ``b``
        becomes ``b / drizzle**2``), with the planes `~astroalign_nd.stack`
        describes.  Only with ``method='average'``.  A live stack drizzles
        each frame as it arrives, its outliers against the running stack
        weighing nothing (a pixel's first ``n_start`` values are clipped
        only after they were drizzled: outliers among them stay).
    pixfrac : float, optional
        With ``drizzle``: the linear fraction of an input pixel its value is
        dropped onto, in (0, 1] (default 0.7; toward 1 with few frames or
        little dither, or the output gets holes).  For the sharpest stack
        of well-dithered frames use ``pixfrac = sqrt(3 / n_frames)`` (at
        most 1): each output pixel then gets about three drops on average
        (``n_frames * pixfrac**2``), enough for no holes and an honest
        uncertainty, while the drop, whose width adds to the stars', is as
        small as that allows (0.43 for 16 frames, 0.31 for 32; see the
        drizzle section of the benchmarks page).
    kernel : str, optional
        With ``drizzle``: the drizzle kernel, one of
        `~astroalign_nd.stacking.drizzle.DRIZZLE_KERNELS` (default 'square').
    saturation : float, optional
        With ``drizzle``: input values at or above this weigh nothing.
    bayer : {'auto', 'RGGB', 'BGGR', 'GRBG', 'GBRG'} or None, optional
        Raw colour frames of a one-shot-colour camera (default None: grey
        or already colour).  'auto' reads each frame's pattern from its
        header (``BAYERPAT``, ``XBAYROFF``, ``YBAYROFF``, ``ROWORDER``: see
        `astroalign_nd.io.bayer`); a pattern names the colours of every
        frame's first 2x2 cell (``data[0:2, 0:2]``, row by row) and
        overrides the headers.  Each frame is registered on its grey
        version (each colour scaled to green's response), then demosaiced
        and each colour stacked with the frame's one transform, or with
        ``drizzle`` Bayer-drizzled (each colour's raw pixels dropped at
        their true positions, after the stack's rejection found on the
        frames' grey versions on the reference's grid and carried back
        onto each raw frame;
        `astroalign_nd.stacking.colour.drizzle_bayer`; ``pixfrac`` toward 1,
        each colour having a quarter or half of the pixels).  The stack is
        an RGB cube ``(3, ny, nx)``, each plane with its uncertainty, mask
        and coverage (`astroalign_nd.stacking.colour`).  Demosaicing needs
        ``colour-demosaicing`` (the ``[colour]`` extra); ``canvas`` must be
        'reference'.
    demosaic : {'Menon2007', 'Malvar2004', 'bilinear'}, optional
        With ``bayer``: ``colour-demosaicing``'s method (default
        'Menon2007').  Menon2007 and Malvar2004 build red and blue from
        green's detail (their stars take green's width and position: a
        real colour offset such as atmospheric dispersion disappears);
        'bilinear' keeps each colour's own.
    select : None, 'auto' or float, optional
        Frames left out before combining
        (`~astroalign_nd.stacking.quality.select_frames`): None (default)
        only by the limits below; 'auto' also the trailed frames and the
        outliers of the night (robust z-scores of FWHM, transparency and
        sky noise; a live stack: of the frames so far); a fraction in
        (0, 1] (not for a live stack) keeps that fraction, the highest
        ``'auto'`` weights first.  Every frame left out is in the header
        (``AAREJnnn``), the log and a warning, with the reason; leaving
        fewer than 3 frames is a
        `~astroalign_nd.stacking.quality.SelectionError` (a ValueError)
        naming the limit to relax.  The reference is never left out.
    max_fwhm, max_elongation, min_transparency : float, optional
        Leave out the frames whose stars are wider (pixels), more elongated
        (major over minor axis), or dimmer (relative to the reference's).
    min_stars : int, optional
        Leave out the frames with fewer sources detected.
    star_tolerance : float, optional
        Sigma clipping's allowance for the stars' own signal: a value goes
        only beyond ``sigma`` spreads plus this times the pixel's median
        above the sky, so that the cores of the sharpest frames' stars
        (far above the others' at the same pixel) stay and only outliers
        (cosmic rays, trails, hot pixels) go.  Default (None): from the
        night's PSF differences, the largest ratio of a frame's star peak
        to the median frame's (the inverse FWHM squared) minus 1, plus
        0.3; 0: plain sigma clipping.

    Raises
    ------
    TypeError, ValueError
        For a value out of its range (``maxiters=0`` below), with a message
        that names the option and its accepted values.

    Examples
    --------
    >>> from astroalign_nd.stacking import StackConfig
    >>> cfg = StackConfig(sigma=2.5, sigma_high=4)
    >>> cfg.sigma_low, cfg.sigma_high
    (2.5, 4.0)
    >>> StackConfig(maxiters=0)
    Traceback (most recent call last):
    ...
    ValueError: maxiters must be an integer >= 1; got 0.
    """

    method: str = option(
        "average", Choice(STACK_METHODS), "how the frames are combined (default: %(default)s)",
        used_by=("stack",), flag="--combine")
    clip: str | None = option(
        "sigma", Choice(CLIP_METHODS), "rejection before combining (default: %(default)s)",
        flag="--clip")
    sigma: float = option(
        3.0, Real(0, lo_open=True), "sigma clipping's limit, both sides (default: %(default)s)",
        flag="--sigma", type=float)
    sigma_low: float | None = option(
        None, Real(0, lo_open=True, none=True), "its low limit", flag="--sigma-low", type=float)
    sigma_high: float | None = option(
        None, Real(0, lo_open=True, none=True), "its high limit", flag="--sigma-high",
        type=float)
    maxiters: int = option(
        3, Int(1, None), "sigma clipping rounds at most", flag="--maxiters", type=int)
    nlow: int = option(
        1, Int(0, None), "minmax: lowest values dropped", used_by=("stack",), flag="--nlow",
        type=int)
    nhigh: int = option(
        1, Int(0, None), "minmax: highest values dropped", used_by=("stack",), flag="--nhigh",
        type=int)
    normalize: str | None = option(
        "offset", Choice(NORMALIZE_METHODS),
        "bring each frame's sky to the reference's (default: %(default)s)", flag="--normalize")
    gain: float | None = option(
        None, Real(0, lo_open=True, none=True, unit="electrons per count"),
        "electrons per count, for frames without an uncertainty", flag="--gain", type=float)
    read_noise: float | None = option(
        None, Real(0, none=True, unit="electrons"), "read noise in electrons, with --gain",
        flag="--read-noise", type=float)
    weights: object = option(
        "variance", FrameWeights(),
        "frame weights: inverse median variance (default), auto (faint stars: "
        "transparency, sky noise and seeing), or equal", flag="--weights")
    memory_limit: float = option(
        DEFAULT_MEMORY_LIMIT, Real(0, lo_open=True, unit="bytes"),
        "working memory of the combination, MB (default: %(default)s)", used_by=("stack",),
        flag="--memory-limit", type=float, metavar="MB", scale=1e6)
    canvas: str = option(
        "reference", Choice(("reference", "union")),
        "the stack's grid: the reference's (default) or the union of frames",
        used_by=("stack",), flag="--canvas")
    n_start: int = option(5, Int(3, None), used_by=("live",))
    drizzle: float | None = option(
        None, Real(0, lo_open=True, none=True),
        "drizzle onto a grid SCALE times finer (e.g. 2) instead of interpolating",
        flag="--drizzle", type=float, metavar="SCALE")
    pixfrac: float = option(
        0.7, Real(0, 1, lo_open=True),
        "with --drizzle: the linear fraction of a pixel dropped (default: %(default)s)",
        flag="--pixfrac", type=float)
    kernel: str = option(
        "square", Choice(DRIZZLE_KERNELS),
        "with --drizzle: the drizzle kernel (default: %(default)s)", flag="--kernel")
    saturation: float | None = option(
        None, Real(none=True), "with --drizzle: input values at or above weigh nothing",
        flag="--saturation", type=float)
    bayer: str | None = option(
        None, Choice(("auto",) + BAYER_PATTERNS + tuple(p.lower() for p in BAYER_PATTERNS)
                     + (None,)),
        "raw colour frames: their Bayer pattern (the colours of the first 2x2 cell), or auto "
        "(each frame's BAYERPAT); OUT is an RGB cube", used_by=("stack",), flag="--bayer",
        metavar="PATTERN")
    demosaic: str = option(
        "Menon2007", Choice(DEMOSAIC_METHODS),
        "with --bayer: colour-demosaicing's method (default: %(default)s)", used_by=("stack",),
        flag="--demosaic")
    select: object = option(
        None, FrameSelection(),
        "leave frames out: 'auto' (trailed frames and the night's outliers) or a fraction "
        "to keep", flag="--select")
    max_fwhm: float | None = option(
        None, Real(0, lo_open=True, none=True, unit="pixels"),
        "leave out frames whose stars' FWHM is larger (pixels)", flag="--max-fwhm",
        type=float)
    max_elongation: float | None = option(
        None, Real(1, none=True), "leave out frames whose stars are more elongated (trailed)",
        flag="--max-elongation", type=float)
    min_transparency: float | None = option(
        None, Real(0, lo_open=True, none=True),
        "leave out frames whose stars are dimmer, relative to the reference's",
        flag="--min-transparency", type=float)
    min_stars: int | None = option(
        None, Int(0, None, none=True), "leave out frames with fewer stars detected",
        flag="--min-stars", type=int)
    star_tolerance: float | None = option(
        None, Real(0, none=True), "sigma clipping's allowance for the stars' own signal "
        "(default: from the night's PSF differences; 0: plain clipping)",
        flag="--star-tolerance", type=float)

    def __post_init__(self):
        check_fields(self)
        if self.drizzle is not None and self.method != "average":
            raise ValueError(f"drizzle gives a weighted average; method={self.method!r} cannot "
                             "be drizzled: use method='average' (the default), or no drizzle.")
        if self.bayer is not None and self.canvas != "reference":
            raise ValueError("bayer frames are stacked on the reference's grid: pass "
                             "canvas='reference' (the default).")
        for side in ("sigma_low", "sigma_high"):
            if getattr(self, side) is None:
                object.__setattr__(self, side, self.sigma)

    @classmethod
    def from_keywords(cls, user, options):
        """
        The config of ``user``'s keywords, and the keywords that are not its own.

        Parameters
        ----------
        user : {'stack', 'live'}
            `~astroalign_nd.stack`, or the live stack.
        options : dict
            Keyword arguments: the stacking options among them are checked,
            the others returned (the registration's, checked by it).

        Raises
        ------
        TypeError, ValueError
            For a stacking option that ``user`` does not take, or a value
            out of its range.

        Examples
        --------
        >>> from astroalign_nd.stacking import StackConfig
        >>> cfg, rest = StackConfig.from_keywords("stack", {"clip": None, "fwhm": 3})
        >>> cfg.clip, rest
        (None, {'fwhm': 3})
        """
        mine = {f.name for f in fields_of(cls, user)}
        foreign = sorted(set(options) & ({f.name for f in dataclasses.fields(cls)} - mine))
        if foreign:
            raise TypeError(f"{', '.join(foreign)}: not an option of {_USERS[user]}, which "
                            f"takes the stacking options {sorted(mine)}.")
        config = cls(**{k: v for k, v in options.items() if k in mine})
        if user == "live":  # it clips and weighs against a running stack
            convert("a live stack's clip", Choice(("sigma", None)), config.clip)
            convert("a live stack's weights", Choice(WEIGHT_METHODS), config.weights)
            convert("a live stack's select", Choice((None, "auto")), config.select)
        return config, {k: v for k, v in options.items() if k not in mine}
