# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
What real frames do to the stars, put into simulated frames for the tests and
the benchmarks (``benchmarks/`` imports this module too): nebulosity, overscan
strips, bright edge bands, 8-bit stretches with bloated stars and JPEG
compression, undersampled colour sensors, resampled copies, and the hard cases
for the trust of a registration (`simulate_trust_case`).

Our own simulator is not the judge: these effects are what the clean frames of
`astroalign_nd.simulate` lack.
"""

import numbers

import numpy as np

from astroalign_nd.transforms.convert import from_matrix
from astroalign_nd.simulate import SimulatedPair, render_stars, simulate_field, simulate_pair
from astroalign_nd.simulate.stars import (
    _FWHM_TO_SIGMA, _check_count, _check_frame, _check_real, _finite_pair, _inside,
    _star_table,
)


def _check_range(pair, name):
    """Two positive numbers, low then high."""
    try:
        lo, hi = (float(v) for v in pair)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be two numbers (low, high); got {pair!r}.") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(f"{name} must be two finite numbers with 0 < low <= high; got {pair!r}.")
    return lo, hi


def add_nebulosity(image, *, amplitude, scale=40.0, n_knots=25, knot_fwhm=(6.0, 25.0),
                   seed=None):
    """
    Add extended emission: smooth filaments plus compact knots.

    Parameters
    ----------
    image : 2-D ndarray
        Not modified; a new float array is returned.
    amplitude : float
        Peak level of the emission, in counts (compare with the stars'
        peaks: a few times brighter makes the knots outshine most stars).
    scale : float, optional
        Correlation length of the filaments, pixels.
    n_knots : int, optional
        Number of Gaussian knots (HII regions, galaxies, reflection blobs)
        whose width is drawn from ``knot_fwhm``: wider than stars, bright
        enough to be among the brightest "sources".
    knot_fwhm : (float, float), optional
        Range of the knots' FWHM, pixels.
    seed : int or `numpy.random.Generator`, optional

    Returns
    -------
    image : 2-D ndarray

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import simulate_pair
    >>> from _frame_defects import add_nebulosity
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> nebular = add_nebulosity(pair.source, amplitude=200.0, seed=1)
    >>> nebular.shape, nebular.dtype
    ((256, 256), dtype('float32'))
    >>> extra = nebular - pair.source
    >>> bool(extra.min() >= 0.0 and extra.max() > 200.0)  # knots peak above amplitude
    True
    """
    from scipy.ndimage import gaussian_filter

    src = _check_frame(image)
    amplitude = _check_real(amplitude, "amplitude", minimum=0.0)
    scale = _check_real(scale, "scale", minimum=0.0, strict=True)
    n_knots = _check_count(n_knots, "n_knots")
    knot_fwhm = _check_range(knot_fwhm, "knot_fwhm")
    img = np.array(src, dtype=np.float64)
    rng = np.random.default_rng(seed)
    ny, nx = img.shape
    field_ = gaussian_filter(rng.standard_normal((ny, nx)), scale, mode="wrap")
    field_ -= field_.mean()
    sd = field_.std()
    # Filaments and voids; a field smoother than the frame (scale >> size) stays flat.
    field_ = np.exp(2.5 * field_ / sd) if sd > 0 else np.ones_like(field_)
    img += amplitude * field_ / field_.max()
    if n_knots:
        x = rng.uniform(0, nx, n_knots)
        y = rng.uniform(0, ny, n_knots)
        fw = rng.uniform(knot_fwhm[0], knot_fwhm[1], n_knots)
        peak = amplitude * rng.uniform(0.5, 2.0, n_knots)
        flux = peak * 2 * np.pi * (fw * _FWHM_TO_SIGMA) ** 2
        knots = np.zeros((ny, nx), np.float64)
        render_stars((ny, nx), x, y, flux, fwhm=fw, out=knots)
        img += knots
    return img.astype(src.dtype if src.dtype.kind == "f" else np.float32)


def add_overscan(image, *, width=16, level=0.0, read_noise=5.0, edges=("left", "right", "top"),
                 seed=None):
    """
    Replace strips along the edges by overscan: bias level and read noise only.

    A raw CCD frame carries such strips; their edge against the sky is a
    step that a careless detector takes for sources or for a wide star.

    Parameters
    ----------
    image : 2-D ndarray
        Not modified.
    width : int, optional
        Strip width, pixels.
    level : float, optional
        Bias level of the strips (counts), usually well below the sky.
    read_noise : float, optional
    edges : sequence of {'left', 'right', 'top', 'bottom'}, optional
    seed : int or `numpy.random.Generator`, optional

    Returns
    -------
    image : 2-D ndarray
        A copy of ``image`` with the strips replaced.

    Examples
    --------
    Overscan on three edges of a simulated frame:

    >>> import numpy as np
    >>> from astroalign_nd.simulate import simulate_pair
    >>> from _frame_defects import add_overscan
    >>> frame = simulate_pair((256, 256), n_stars=100, seed=1).source
    >>> raw = add_overscan(frame, width=16, level=10.0, seed=1)
    >>> bool(abs(raw[:, :16].mean() - 10.0) < 0.5)  # left strip: bias and read noise
    True
    >>> bool(np.array_equal(raw[:-16, 16:-16], frame[:-16, 16:-16]))  # rest kept
    True
    """
    src = _check_frame(image)
    if isinstance(width, (bool, np.bool_)) or not isinstance(width, numbers.Integral):
        raise TypeError(f"width must be a whole number of pixels; got {width!r}.")
    if not 1 <= width <= min(src.shape) // 2:
        raise ValueError(f"width must be 1 to {min(src.shape) // 2} pixels (half the short side) "
                         f"for an image of shape {src.shape}; got {width}.")
    level = _check_real(level, "level")
    read_noise = _check_real(read_noise, "read_noise", minimum=0.0)
    if isinstance(edges, str):
        edges = (edges,)
    img = np.array(src, dtype=np.float32 if src.dtype.kind != "f" else src.dtype)
    rng = np.random.default_rng(seed)
    w = int(width)
    sl = {"left": np.s_[:, :w], "right": np.s_[:, -w:], "top": np.s_[-w:, :],
          "bottom": np.s_[:w, :]}
    for e in edges:
        if e not in sl:
            raise ValueError(f"edges must name 'left', 'right', 'top' or 'bottom'; got {e!r}.")
        region = img[sl[e]]
        region[...] = level + read_noise * rng.standard_normal(region.shape)
    return img


def add_edge_band(image, *, edge="bottom", amplitude=25.0, decay=1.0, noise=None, seed=None):
    """
    A copy of ``image`` with a bright band along one edge, decaying inwards.

    Raw CCD frames often carry one: the first rows read out hold charge
    left from the previous read or a bias that has not settled, brightest at
    the edge and fading over a few rows.  Its noise peaks along the edge are
    what a detector judging candidates against the whole frame's background
    takes for a row of stars.

    Parameters
    ----------
    image : 2-D ndarray
        Not modified.
    edge : {'bottom', 'top', 'left', 'right'}, optional
        The edge: 'bottom' is row 0, 'top' the last row, 'left' column 0.
    amplitude : float, optional
        The band's level on the edge row or column, in units of ``noise``
        (default 25).
    decay : float, optional
        e-folding length of the band inwards, pixels (default 1: the band is
        at about 5 ``noise`` on the fourth row from the edge, as on the SAAO
        1 m frames it copies).
    noise : float, optional
        The frame's sky noise, counts; by default measured on the image (the
        median absolute deviation, as a standard deviation).
    seed : int or `numpy.random.Generator`, optional
        The band carries its own Poisson-like noise (the square root of its
        level, in ``noise`` units), drawn from this seed.

    Returns
    -------
    image : 2-D ndarray
        A new float array.

    Examples
    --------
    >>> import numpy as np
    >>> from _frame_defects import add_edge_band
    >>> img = add_edge_band(np.zeros((64, 64)), amplitude=25.0, noise=1.0, seed=0)
    >>> bool(20 < img[0].mean() < 30), bool(img[10].std() < 0.1)
    (True, True)
    """
    src = _check_frame(image)
    amplitude = _check_real(amplitude, "amplitude", minimum=0.0,
                            hint=" Pass the band's level in units of the sky noise, e.g. 25.")
    decay = _check_real(decay, "decay", minimum=0.0, strict=True,
                        hint=" Pass the band's e-folding length in pixels, e.g. 1.")
    if edge not in ("bottom", "top", "left", "right"):
        raise ValueError(f"edge must be 'bottom', 'top', 'left' or 'right'; got {edge!r}.")
    if noise is None:
        finite = src[np.isfinite(src)].astype(float)
        noise = 1.4826 * float(np.median(np.abs(finite - np.median(finite))))
        if noise <= 0:
            noise = float(np.std(finite)) or 1.0
    else:
        noise = _check_real(noise, "noise", minimum=0.0, strict=True,
                            hint=" Pass the sky noise in counts, or None to measure it.")
    rng = np.random.default_rng(seed)
    n = src.shape[0] if edge in ("bottom", "top") else src.shape[1]
    depth = np.arange(n, dtype=float)
    profile = amplitude * np.exp(-depth / decay)
    if edge in ("top", "right"):
        profile = profile[::-1]
    level = profile[:, None] if edge in ("bottom", "top") else profile[None, :]
    level = np.broadcast_to(level, src.shape)
    band = noise * (level + np.sqrt(level) * rng.standard_normal(src.shape))
    out = np.array(src, dtype=np.result_type(src.dtype, np.float32))
    out += band.astype(out.dtype)
    return out


def to_8bit(image, *, gamma=0.45, black=None, white=None, bloat=2.0, jpeg_quality=None):
    """
    Render a frame as an 8-bit astrophoto: stretched, saturated, compressed.

    Bright stars are bloated (a wide halo, as in a stretched image with
    scattered light), the image is gamma-stretched between ``black`` and
    ``white`` and clipped to 0..255, so that bright stars become wide flat
    plateaus, and optionally JPEG-compressed.

    Parameters
    ----------
    image : 2-D ndarray
        Not modified.
    gamma : float, optional
        Display stretch exponent (< 1 lifts the faint end).
    black, white : float, optional
        Levels mapped to 0 and 255; by default the 10th and 99.7th
        percentiles, which saturates the brightest stars.
    bloat : float, optional
        Halo added around every pixel brighter than ``white``: a Gaussian of
        this many times the core's width (0 for none).
    jpeg_quality : int, optional
        If given, JPEG-compress at this quality (1-95) with Pillow.

    Returns
    -------
    image : 2-D uint8 ndarray

    Examples
    --------
    >>> from astroalign_nd.simulate import simulate_pair
    >>> from _frame_defects import to_8bit
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> photo = to_8bit(pair.source)
    >>> photo.shape, photo.dtype, int(photo.min()), int(photo.max())
    ((256, 256), dtype('uint8'), 0, 255)
    >>> bool((photo == 255).sum() > 50)  # bright stars become flat plateaus
    True
    """
    from scipy.ndimage import gaussian_filter

    img = np.asarray(_check_frame(image), dtype=np.float64)
    gamma = _check_real(gamma, "gamma", minimum=0.0, strict=True)
    bloat = _check_real(bloat, "bloat", minimum=0.0)
    if jpeg_quality is not None and (
            isinstance(jpeg_quality, (bool, np.bool_))
            or not isinstance(jpeg_quality, numbers.Integral) or not 1 <= jpeg_quality <= 95):
        raise ValueError(f"jpeg_quality must be an integer from 1 to 95, or None; "
                         f"got {jpeg_quality!r}.")
    finite = img[np.isfinite(img)]
    lo = np.percentile(finite, 10) if black is None else _check_real(black, "black")
    hi = np.percentile(finite, 99.7) if white is None else _check_real(white, "white")
    img = np.where(np.isfinite(img), img, lo)  # blank pixels render black
    if bloat:
        excess = np.clip(img - hi, 0, None)
        img = img + gaussian_filter(excess, 2.0 * bloat) * 0.5
    v = np.clip((img - lo) / max(hi - lo, 1e-12), 0.0, 1.0) ** gamma
    out = np.round(255.0 * v).astype(np.uint8)
    if jpeg_quality is not None:
        import io

        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(out).save(buf, format="JPEG", quality=int(jpeg_quality))
        buf.seek(0)
        out = np.asarray(Image.open(buf).convert("L"))
    return out


def bayer_bin(pair, *, gains=(0.55, 1.0, 1.0, 0.75)):
    """
    A colour sensor's frames, each 2x2 Bayer cell averaged into one pixel.

    Smart telescopes and DSLRs have a colour filter mosaic; averaging each
    2x2 cell gives a grey frame of half the size whose stars are
    undersampled when the optics were matched to the full sensor.

    Parameters
    ----------
    pair : `SimulatedPair`
        Simulated at twice the wanted size and FWHM (e.g. 2.6 px for 1.3 px
        binned stars).
    gains : 4 floats, optional
        Relative response of the R, G, G, B pixels of each cell.

    Returns
    -------
    pair : `SimulatedPair`
        Binned images, star tables and truth in binned pixel coordinates.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import simulate_pair
    >>> from _frame_defects import bayer_bin
    >>> full = simulate_pair((256, 256), n_stars=100, fwhm=2.6, seed=1)
    >>> binned = bayer_bin(full)
    >>> binned.source.shape, binned.source.dtype
    ((128, 128), dtype('float32'))
    >>> m = binned.matched_stars()
    >>> xt, yt = binned.transform(m["x_source"], m["y_source"])
    >>> bool(np.allclose(xt, m["x_target"]) and np.allclose(yt, m["y_target"]))
    True
    """
    if not isinstance(pair, SimulatedPair):
        raise TypeError(f"bayer_bin takes a SimulatedPair (from simulate_pair, simulated at twice "
                        f"the wanted size); got {type(pair).__name__}.")
    try:
        g = np.asarray(gains, dtype=float).reshape(2, 2)
    except (TypeError, ValueError):
        raise ValueError(f"gains must be 4 numbers (R, G, G, B); got {gains!r}.") from None
    if not np.all(np.isfinite(g) & (g > 0)):
        raise ValueError(f"gains must be 4 positive finite numbers; got {gains!r}.")

    def binned(img):
        a = np.asarray(img, np.float64)
        ny, nx = (a.shape[0] // 2) * 2, (a.shape[1] // 2) * 2
        a = a[:ny, :nx] * np.tile(g, (ny // 2, nx // 2))
        return a.reshape(ny // 2, 2, nx // 2, 2).mean(axis=(1, 3)).astype(np.float32)

    # Full-resolution x maps to binned (x - 0.5) / 2.
    c = np.array([[0.5, 0.0, -0.25], [0.0, 0.5, -0.25], [0.0, 0.0, 1.0]])
    truth = c @ np.asarray(pair.truth_matrix) @ np.linalg.inv(c)

    def stars(tab):
        t = tab.copy()
        t["x"] = (t["x"] - 0.5) / 2.0
        t["y"] = (t["y"] - 0.5) / 2.0
        return t

    def binned_mapping(x, y):
        xt, yt = pair.mapping(2.0 * np.asarray(x, float) + 0.5, 2.0 * np.asarray(y, float) + 0.5)
        return (xt - 0.5) / 2.0, (yt - 0.5) / 2.0

    mapping = None if pair.mapping is None else binned_mapping

    meta = dict(pair.meta, bayer_binned=True)
    return SimulatedPair(source=binned(pair.source), target=binned(pair.target),
                         transform=from_matrix(truth), truth_matrix=truth,
                         source_stars=stars(pair.source_stars),
                         target_stars=stars(pair.target_stars),
                         transients=stars(pair.transients), meta=meta, mapping=mapping)


def resampled_copy(image, *, rotation=2.0, translation=(35.0, -12.0), order=3, noise=0.02,
                   seed=None):
    """
    A rotated, shifted and resampled copy of a frame, as an aligned or drizzled frame is.

    The copy is ``scipy.ndimage.affine_transform`` of ``image`` (spline of
    ``order``, pixels from outside the frame set to its median), plus
    Gaussian noise of ``noise`` times the frame's standard deviation.  The
    resampling smooths what was sharp in the frame (cosmic rays, hot
    pixels) into star-like blobs: the case of a resampled frame registered
    against a raw one.

    Parameters
    ----------
    image : 2-D ndarray
        The raw frame (not modified).
    rotation : float, optional
        Counter-clockwise rotation about the frame centre, degrees.
    translation : (float, float), optional
        Shift ``(dx, dy)`` of the frame centre, pixels.
    order : int, optional
        Spline order of the resampling (0 to 5).
    noise : float, optional
        Standard deviation of the added noise, as a fraction of the frame's.
    seed : int, `numpy.random.Generator` or None, optional
        Seed of the noise.

    Returns
    -------
    copy : 2-D float32 ndarray
        The resampled copy, of the frame's shape.
    transform : `~astroalign_nd.transforms.SimilarityTransform`
        The true transform, frame pixels -> copy pixels.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import simulate_field
    >>> from _frame_defects import resampled_copy
    >>> image, stars = simulate_field((128, 128), n_stars=20, seed=0)
    >>> copy, truth = resampled_copy(image, seed=1)
    >>> copy.shape, round(float(truth.rotation_deg), 6)
    ((128, 128), 2.0)
    >>> xt, yt = truth(63.5, 63.5)  # the centre moves by the translation
    >>> round(float(xt) - 63.5, 6), round(float(yt) - 63.5, 6)
    (35.0, -12.0)
    """
    from scipy.ndimage import affine_transform

    img = np.asarray(_check_frame(image), dtype=np.float64)
    rotation = _check_real(rotation, "rotation")
    shift, ok = _finite_pair(translation)
    if not ok:
        raise ValueError(f"translation must be two finite numbers (dx, dy); got {translation!r}.")
    dx, dy = shift
    noise = _check_real(noise, "noise", minimum=0.0)
    if isinstance(order, (bool, np.bool_)) or not isinstance(order, numbers.Integral) \
            or not 0 <= order <= 5:
        raise ValueError(f"order must be an integer from 0 to 5; got {order!r}.")
    ny, nx = img.shape
    c = np.array([(nx - 1) / 2.0, (ny - 1) / 2.0])
    th = np.deg2rad(rotation)
    a = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    m = np.eye(3)
    m[:2, :2] = a
    m[:2, 2] = c + np.array([dx, dy]) - a @ c
    inv = np.linalg.inv(m)
    # affine_transform maps output (row, col) to input (row, col): swap x and y.
    swap = np.array([[0, 1], [1, 0]])
    finite = np.isfinite(img)
    fill = float(np.median(img[finite])) if finite.any() else 0.0
    out = affine_transform(np.where(finite, img, fill), swap @ inv[:2, :2] @ swap,
                           offset=swap @ inv[:2, 2], order=int(order), mode="constant",
                           cval=fill)
    if noise:
        sigma = noise * float(np.std(img[finite]))
        out += np.random.default_rng(seed).normal(0.0, sigma, out.shape)
    return out.astype(np.float32), from_matrix(m, "similarity")


def simulate_hot_night(seed, *, trail=True):
    """
    A night of frames from a camera with hot pixels, one frame crossed by a trail.

    Ten 256x256 frames of 200 stars (FWHM 3 px, fluxes 300 to 5000 counts,
    sky noise 10 counts, integer shifts within 5 px: `simulate_sequence`),
    each with 300 single hot pixels at 50 sigma; one frame (drawn from 1 to
    9) is crossed by a 3-px wide satellite trail at 30 sigma, from the left
    edge to the right at random heights.

    Parameters
    ----------
    seed : int
        The same seed gives the same night.
    trail : bool, optional
        Draw the trail (False: the same night, hot pixels and all, without it).

    Returns
    -------
    seq : `~astroalign_nd.simulate.SimulatedSequence`
        The clean night: its ``transforms`` are the truth.
    frames : list of 2-D float32 ndarray
        The frames with their defects.
    trail_frame : int
        The index of the frame with the trail.
    ends : ((float, float), (float, float))
        The trail's start and end ``(x, y)`` (outside the frame).

    Examples
    --------
    >>> import numpy as np
    >>> from _frame_defects import simulate_hot_night
    >>> seq, frames, k, ((x0, y0), (x1, y1)) = simulate_hot_night(4)
    >>> len(frames), frames[0].shape, 1 <= k <= 9, (x0, x1)
    (10, (256, 256), True, (-10.0, 266.0))
    >>> hot = frames[0] - np.asarray(seq.frames[0].data)
    >>> int(np.sum(hot > 400))  # the hot pixels
    300
    """
    from astroalign_nd.simulate import add_satellite_trail, simulate_sequence

    seq = simulate_sequence((256, 256), n_frames=10, n_stars=200, max_shift=5,
                            noise_sigma=10.0, seed=seed)
    rng = np.random.default_rng(seed + 999)
    frames = []
    trail_frame = int(rng.integers(1, 10))
    ends = None
    for k, f in enumerate(seq.frames):
        d = np.array(f.data, float)
        d.flat[rng.integers(0, d.size, 300)] += 50 * 10.0
        if k == trail_frame:
            y0, y1 = rng.uniform(0, 255, 2)
            ends = ((-10.0, float(y0)), (266.0, float(y1)))
            if trail:
                d = add_satellite_trail(d, *ends, width=3.0, amplitude=30 * 10.0)
        frames.append(d.astype(np.float32))
    return seq, frames, trail_frame, ends


#: The cases that `simulate_trust_case` makes (see there).
TRUST_CASES = ("trailed", "sparse_8bit", "resampled_copy")


def simulate_trust_case(case, *, seed=None):
    """
    One pair of a hard case for the trust of a registration.

    Cases (each draw of ``seed`` varies the field, the transform and the
    artefacts within the ranges given):

    ``'trailed'``
        512x512 float frames of 20-40 stars; the source frame's stars
        trailed over 4-10 px at a random angle (a tracking error), the
        target's round.  Random rotation, shift up to 10% of the frame.
    ``'sparse_8bit'``
        512x512 8-bit frames (`to_8bit`) of 9-19 stars, as a finder or
        all-sky camera gives; one frame slightly trailed (1.5-3 px), the
        scale 0.998-1.002, random rotation and shift up to 30 px.
    ``'resampled_copy'``
        A 512x512 raw frame of 60-120 stars with 150 cosmic rays and 50 hot
        pixels, against its copy rotated by 2 degrees and shifted by
        (35, -12) px with `resampled_copy` (order 3, noise 2% of the frame's
        standard deviation).

    Parameters
    ----------
    case : str
        One of ``TRUST_CASES`` (``"trailed"``, ``"sparse_8bit"``, ``"resampled_copy"``).
    seed : int or None, optional
        The same seed gives the same pair.

    Returns
    -------
    `SimulatedPair`
        Its ``transform`` is the truth; ``meta['case']`` names the case.

    Examples
    --------
    >>> from _frame_defects import simulate_trust_case
    >>> pair = simulate_trust_case("sparse_8bit", seed=3)
    >>> pair.source.dtype, 9 <= len(pair.source_stars) <= 19
    (dtype('uint8'), True)
    """
    if case not in TRUST_CASES:
        raise ValueError(f"case must be one of {TRUST_CASES}; got {case!r}.")
    rng = np.random.default_rng(seed)
    shape = (512, 512)
    if case == "trailed":
        pair = simulate_pair(shape, n_stars=int(rng.integers(20, 41)),
                             flux_range=(3e3, 3e5), fwhm=float(rng.uniform(2.5, 3.5)),
                             trail=(float(rng.uniform(4.0, 10.0)),
                                    float(rng.uniform(0.0, 180.0))),
                             seed=rng)
    elif case == "sparse_8bit":
        pair = simulate_pair(
            shape, n_stars=int(rng.integers(9, 20)), rotation=float(rng.uniform(0.0, 360.0)),
            scale=float(rng.uniform(0.998, 1.002)),
            translation=tuple(float(v) for v in rng.uniform(-30.0, 30.0, 2)),
            flux_range=(5e3, 5e5), fwhm=float(rng.uniform(2.0, 3.0)),
            target_trail=(float(rng.uniform(1.5, 3.0)), float(rng.uniform(0.0, 180.0))),
            seed=rng)
        pair.source, pair.target = to_8bit(pair.source), to_8bit(pair.target)
    else:
        image, stars = simulate_field(shape, n_stars=int(rng.integers(60, 121)),
                                      flux_range=(1e3, 3e5), n_cosmic_rays=150,
                                      n_hot_pixels=50, seed=rng)
        copy, truth = resampled_copy(image, seed=rng)
        xt, yt = truth(np.asarray(stars["x"]), np.asarray(stars["y"]))
        inside = _inside(xt, yt, shape)
        pair = SimulatedPair(
            source=image, target=copy, transform=truth,
            truth_matrix=np.array(truth.matrix, dtype=float), source_stars=stars,
            target_stars=_star_table(xt[inside], yt[inside],
                                     np.asarray(stars["flux"])[inside],
                                     np.asarray(stars["id"])[inside]),
            transients=_star_table(np.empty(0), np.empty(0), np.empty(0),
                                   np.empty(0, np.int64)),
            meta={"shape": shape, "target_shape": shape})
    pair.meta["case"] = case
    return pair
