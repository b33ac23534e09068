# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Sequences of frames: `simulate_sequence` (a dithered run to stack, with cosmic
rays; `add_satellite_trail` puts a trail into a frame), and `simulate_views`
with `mosaic_transforms` and `dither_transforms` (frames of one sky through
known transforms, for the global solution).
"""

from dataclasses import dataclass, field

import numpy as np
from astropy.table import Table

from astroalign_nd.transforms.convert import as_matrix, from_matrix
from astroalign_nd.simulate.stars import (
    _FWHM_TO_SIGMA, _add_artifacts, _check_count, _check_flux_range, _check_frame, _check_fwhm,
    _check_real, _check_shape, _draw_fluxes, _finite_pair, _inside, _spawn, _stamp_half_size,
    _star_table, simulate_image,
)
from astroalign_nd.simulate.pairs import _check_transform, _map_xy

__all__ = [
    "add_satellite_trail",
    "SimulatedSequence",
    "simulate_sequence",
    "SimulatedViews",
    "simulate_views",
    "mosaic_transforms",
    "dither_transforms",
    "simulate_night",
]


def add_satellite_trail(image, start, end, *, width=2.0, amplitude=500.0):
    """
    A copy of ``image`` with a satellite (or aircraft) trail across it.

    The trail is a straight band with a Gaussian profile across it (FWHM
    ``width`` pixels) and a constant ``amplitude`` (counts at its centre)
    along it, from ``start`` to ``end`` (``(x, y)`` pixel positions, which
    may lie outside the frame).

    Parameters
    ----------
    image : 2-D ndarray
    start, end : (float, float)
    width : float, optional
        FWHM of the trail's profile, pixels (default 2).
    amplitude : float, optional
        Counts at the trail's centre line (default 500).

    Returns
    -------
    image : 2-D ndarray
        A new array (``image`` is not modified), float.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import add_satellite_trail
    >>> img = add_satellite_trail(np.zeros((50, 60)), (0, 10), (59, 40), amplitude=100.0)
    >>> round(float(img.max()))
    100
    """
    image = _check_frame(image)
    points = []
    for name, value in (("start", start), ("end", end)):
        xy, ok = _finite_pair(value)
        if not ok:
            raise ValueError(f"{name} must be a finite (x, y) pixel position; got {value!r}.")
        points.append(xy)
    (x0, y0), (x1, y1) = points
    width = _check_real(width, "width", minimum=0.0, strict=True,
                        hint=" Pass the trail's FWHM in pixels, e.g. 2.")
    amplitude = _check_real(amplitude, "amplitude", hint=" Pass counts, e.g. 500.")
    length = np.hypot(x1 - x0, y1 - y0)
    if length == 0:
        raise ValueError("the trail's start and end are the same point; give two points.")
    yy, xx = np.mgrid[0:image.shape[0], 0:image.shape[1]]
    ux, uy = (x1 - x0) / length, (y1 - y0) / length
    along = (xx - x0) * ux + (yy - y0) * uy
    across = (xx - x0) * uy - (yy - y0) * ux
    sig = width * _FWHM_TO_SIGMA
    band = amplitude * np.exp(-0.5 * (across / sig) ** 2)
    band[(along < 0) | (along > length)] = 0.0
    out = np.array(image, dtype=np.result_type(image.dtype, np.float32))
    out += band.astype(out.dtype)
    return out


@dataclass(eq=False)
class SimulatedSequence:
    """
    A simulated sequence of frames of one field, with its truth.

    Attributes
    ----------
    frames : list of `~astropy.nddata.CCDData`
        The frames (the first is the reference), each with a
        `~astropy.nddata.StdDevUncertainty` holding its true noise (unless
        the sequence was made with ``uncertainty=False``).
    truth : 2-D ndarray
        The noiseless reference frame: its sky and stars, without
        artefacts (on the reference's grid).
    transforms : list of `~astroalign_nd.transforms.LinearTransform2D`
        Each frame's true frame-to-reference transform (identity first).
    sky : list of float
        Each frame's sky level.
    shifts : (n_frames, 2) ndarray
        Each frame's ``(dx, dy)`` offset onto the reference.
    meta : dict
        The settings used.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import simulate_sequence
    >>> seq = simulate_sequence((128, 128), n_frames=3, n_stars=50, seed=2)
    >>> dx, dy = seq.shifts[1]
    >>> bool(np.allclose(seq.transforms[1].matrix[:2, 2], [dx, dy]))
    True
    """

    frames: list
    truth: np.ndarray
    transforms: list
    sky: list
    shifts: np.ndarray
    meta: dict = field(default_factory=dict)


def _sequence_frame(shape, x, y, flux, fwhm, sky, noise_sigma, read_noise, gain, rng, n_cr):
    """One frame of a sequence: the noiseless model, and the noisy frame with its sigma."""
    model = simulate_image(shape, x, y, flux, fwhm=fwhm, background=sky, noise=False,
                           dtype=np.float64)
    if noise_sigma is None:
        sigma = np.sqrt(np.maximum(model, 0.0) / gain + read_noise ** 2)
    else:
        sigma = np.full(shape, float(noise_sigma))
    frame = model + sigma * rng.standard_normal(shape)
    _add_artifacts(frame, 0, n_cr, rng)
    return model, frame.astype(np.float32), sigma.astype(np.float32)


def simulate_sequence(shape=(256, 256), *, n_frames=10, n_stars=150, max_shift=12,
                      integer_shifts=True, fwhm=3.0, flux_range=(300.0, 5e3),
                      background=100.0, sky_drift=0.0, noise_sigma=None, read_noise=5.0,
                      gain=1.0, n_cosmic_rays=0, uncertainty=True, seed=None):
    """
    Simulate a dithered sequence of frames of one star field (for stacking).

    Frame ``k`` is the reference field seen shifted by ``shifts[k]``
    (frame ``k``'s pixel ``(x, y)`` is the reference's ``(x + dx, y + dy)``),
    with its own sky level and noise; the first frame is the reference
    (shift 0).

    Parameters
    ----------
    shape : tuple of int, optional
        Every frame's ``(ny, nx)``.
    n_frames : int, optional
        Number of frames (default 10).
    n_stars : int, optional
        Stars in the reference frame (about as many in the others).
    max_shift : float, optional
        Shifts are drawn uniformly within ``+-max_shift`` pixels per axis.
    integer_shifts : bool, optional
        Whole-pixel shifts (default True): the registered frames are then
        the truth plus noise, without interpolation error.
    fwhm : float, optional
        PSF FWHM, pixels.
    flux_range : (float, float), optional
        Star fluxes, see `draw_fluxes`.
    background : float, optional
        The reference's sky level, counts.
    sky_drift : float, optional
        Each other frame's sky is ``background * (1 + u)``, ``u`` uniform in
        ``+-sky_drift`` (a night's changing sky).
    noise_sigma : float, optional
        Gaussian noise of this sigma everywhere (counts); default: the
        Poisson noise of ``value / gain`` plus ``read_noise``, as a Gaussian.
    read_noise, gain : float, optional
        Counts, and electrons per count (default 5 and 1).
    n_cosmic_rays : int, optional
        Cosmic-ray hits per frame (see `simulate_image`).
    uncertainty : bool, optional
        Give each frame its true noise sigma as a `~astropy.nddata.StdDevUncertainty`.
    seed : int, `numpy.random.Generator` or None, optional

    Returns
    -------
    sequence : `SimulatedSequence`

    Examples
    --------
    >>> from astroalign_nd.simulate import simulate_sequence
    >>> seq = simulate_sequence((128, 128), n_frames=3, n_stars=50, noise_sigma=5.0, seed=1)
    >>> len(seq.frames), float(seq.frames[1].uncertainty.array[0, 0]), seq.shifts[0].tolist()
    (3, 5.0, [0.0, 0.0])
    """
    from astropy.nddata import CCDData, StdDevUncertainty

    shape = _check_shape(shape)
    n_frames = _check_count(n_frames, "n_frames")
    if n_frames < 1:
        raise ValueError("n_frames must be at least 1.")
    max_shift = _check_real(max_shift, "max_shift", minimum=0.0)
    sky_drift = _check_real(sky_drift, "sky_drift", minimum=0.0, maximum=1.0, strict_max=True)
    if noise_sigma is not None:
        noise_sigma = _check_real(noise_sigma, "noise_sigma", minimum=0.0, strict=True)
    rng_stars, rng_frames = _spawn(seed, 2)
    ny, nx = shape
    shifts = rng_stars.uniform(-max_shift, max_shift, (n_frames, 2))
    if integer_shifts:
        shifts = np.round(shifts)
    shifts[0] = 0.0
    # Stars over the reference grid widened by the largest shift (every frame is filled).
    pad = max_shift + 3.0 * fwhm
    area = (nx + 2 * pad) * (ny + 2 * pad)
    n_all = int(round(n_stars * area / (nx * ny)))
    xs = rng_stars.uniform(-pad, nx - 1 + pad, n_all)
    ys = rng_stars.uniform(-pad, ny - 1 + pad, n_all)
    (lo, hi), alpha = _check_flux_range(flux_range, 1.5)
    flux = _draw_fluxes(rng_stars, n_all, lo, hi, alpha)
    skies = [float(background)] + [
        float(background * (1.0 + rng_stars.uniform(-sky_drift, sky_drift)))
        for _ in range(n_frames - 1)]
    frames, transforms, truth = [], [], None
    for k in range(n_frames):
        dx, dy = shifts[k]
        model, img, sig = _sequence_frame(shape, xs - dx, ys - dy, flux, fwhm, skies[k],
                                          noise_sigma, read_noise, gain, rng_frames,
                                          n_cosmic_rays)
        truth = model if k == 0 else truth
        unc = StdDevUncertainty(sig) if uncertainty else None
        frames.append(CCDData(img, unit="adu", uncertainty=unc, meta={"SKYTRUE": skies[k]}))
        transforms.append(from_matrix(np.array([[1.0, 0, dx], [0, 1.0, dy], [0, 0, 1.0]])))
    meta = dict(shape=shape, n_frames=n_frames, n_stars=n_stars, max_shift=max_shift,
                fwhm=fwhm, background=background, sky_drift=sky_drift,
                noise_sigma=noise_sigma, read_noise=read_noise, gain=gain, seed=seed)
    return SimulatedSequence(frames=frames, truth=truth, transforms=transforms, sky=skies,
                             shifts=shifts, meta=meta)


# -- sequences and mosaics -------------------------------------------------------------

@dataclass(eq=False)
class SimulatedViews:
    """
    Frames cut from one star field, each with its known transform.

    Attributes
    ----------
    frames : list of 2-D ndarray
        The simulated frames (independent noise).
    transforms : list of `~astroalign_nd.transforms.LinearTransform2D`
        The true frame-to-sky transforms (sky: the field's own pixel
        coordinates).
    stars : `~astropy.table.Table`
        The field: ``x``, ``y`` (sky pixels), ``flux`` and ``id``.
    meta : dict
        The settings used.

    Examples
    --------
    >>> from astroalign_nd.simulate import mosaic_transforms, simulate_views
    >>> seq = simulate_views(mosaic_transforms((1, 2), (128, 128)), (128, 128),
    ...                         n_stars=60, seed=1)
    >>> len(seq.frames), seq.frames[0].shape
    (2, (128, 128))
    >>> seq.truth(1, 0).translation.tolist()  # frame 1 in frame 0's pixels
    [102.0, 0.0]
    """

    frames: list
    transforms: list
    stars: Table
    meta: dict = field(default_factory=dict)

    def truth(self, i, reference=0):
        """The true transform from frame ``i`` to frame ``reference``'s pixels."""
        m = np.linalg.inv(as_matrix(self.transforms[reference])) @ as_matrix(self.transforms[i])
        return from_matrix(m)


def mosaic_transforms(grid=(3, 3), shape=(256, 256), *, overlap=0.2):
    """
    Frame-to-sky transforms of a ``grid = (rows, columns)`` mosaic of tiles
    of ``shape`` that overlap their neighbours by ``overlap`` of a side.

    Tiles are listed row by row (tile 0 at the sky origin).

    Examples
    --------
    >>> from astroalign_nd.simulate import mosaic_transforms
    >>> [t.translation.tolist() for t in mosaic_transforms((1, 2), (100, 100))]
    [[0.0, 0.0], [80.0, 0.0]]
    """
    rows, cols = (_check_count(g, "grid") for g in grid)
    overlap = _check_real(overlap, "overlap", minimum=0.0, maximum=1.0, strict_max=True)
    ny, nx = _check_shape(shape)
    step_x, step_y = round(nx * (1 - overlap)), round(ny * (1 - overlap))
    return [from_matrix(np.array([[1.0, 0, c * step_x], [0, 1.0, r * step_y], [0, 0, 1]]),
                        "translation") for r in range(rows) for c in range(cols)]


def dither_transforms(n_frames=30, *, max_shift=40.0, max_rotation=2.0, shape=(256, 256),
                      seed=None):
    """
    Frame-to-sky transforms of a dithered sequence: random shifts up to
    ``max_shift`` px and rotations up to ``max_rotation`` degrees about the
    frame centre (frame 0 unmoved).

    Examples
    --------
    >>> from astroalign_nd.simulate import dither_transforms
    >>> ts = dither_transforms(5, seed=1)
    >>> len(ts), ts[0].translation.tolist()
    (5, [0.0, 0.0])
    """
    n = _check_count(n_frames, "n_frames")
    rng = np.random.default_rng(seed)
    ny, nx = _check_shape(shape)
    centre = np.array([(nx - 1) / 2.0, (ny - 1) / 2.0])
    out = []
    for i in range(n):
        shift = rng.uniform(-max_shift, max_shift, 2) if i else np.zeros(2)
        angle = np.radians(rng.uniform(-max_rotation, max_rotation)) if i else 0.0
        c, s = np.cos(angle), np.sin(angle)
        rot = np.array([[c, -s], [s, c]])
        m = np.eye(3)
        m[:2, :2] = rot
        m[:2, 2] = centre - rot @ centre + shift
        out.append(from_matrix(m, "euclidean"))
    return out


def simulate_views(transforms, shape=(256, 256), *, n_stars=300, fwhm=3.0,
                   flux_range=(300.0, 3e5), flux_index=1.5, background=100.0,
                   read_noise=5.0, gain=1.0, noise="gaussian", seed=None,
                   dtype=np.float32):
    """
    Frames of one star field seen through ``transforms`` (frame to sky).

    The field is drawn uniformly over the union of the footprints (with a
    PSF-size margin) at ``n_stars`` per frame area; each frame renders the
    stars that fall on it with its own noise (`simulate_image`).

    Parameters
    ----------
    transforms : list of models or (3, 3) arrays
        Frame-to-sky transforms (`mosaic_transforms`, `dither_transforms`).
    shape : (ny, nx), optional
        Every frame's shape.
    n_stars : int, optional
        Stars per frame area.
    fwhm, flux_range, flux_index, background, read_noise, gain, noise, dtype
        As in `simulate_field` (``noise`` 'gaussian' by default: faster).
    seed : int or None, optional
        The same seed gives the same frames.

    Returns
    -------
    `SimulatedViews`

    Examples
    --------
    Three dithered frames of one field:

    >>> from astroalign_nd.simulate import dither_transforms, simulate_views
    >>> seq = simulate_views(dither_transforms(3, seed=1), (128, 128), n_stars=50, seed=2)
    >>> len(seq.frames), seq.frames[2].shape, seq.frames[2].dtype
    (3, (128, 128), dtype('float32'))
    """
    mats = [_check_transform(t)[1] for t in transforms]
    if not mats:
        raise ValueError("transforms is empty: pass one frame-to-sky transform per frame.")
    ny, nx = shape = _check_shape(shape)
    n_stars = _check_count(n_stars, "n_stars")
    (lo, hi), alpha = _check_flux_range(flux_range, flux_index)
    rng_stars, rng_frames = _spawn(seed, 2)
    pad = _stamp_half_size(np.max(_check_fwhm(fwhm, "fwhm"))) + 1.0
    box = np.array([[-0.5 - pad, -0.5 - pad], [nx - 0.5 + pad, -0.5 - pad],
                    [-0.5 - pad, ny - 0.5 + pad], [nx - 0.5 + pad, ny - 0.5 + pad]])
    corners = np.vstack([np.array(_map_xy(m, box[:, 0], box[:, 1])).T for m in mats])
    (x0, y0), (x1, y1) = corners.min(axis=0), corners.max(axis=0)
    area = abs(np.linalg.det(mats[0][:2, :2])) * nx * ny
    count = int(rng_stars.poisson(n_stars * (x1 - x0) * (y1 - y0) / area))
    sx, sy = rng_stars.uniform(x0, x1, count), rng_stars.uniform(y0, y1, count)
    flux = _draw_fluxes(rng_stars, count, lo, hi, alpha)
    frames = []
    for m, rng in zip(mats, _spawn(rng_frames, len(mats))):
        fx, fy = _map_xy(np.linalg.inv(m), sx, sy)
        keep = _inside(fx, fy, shape, pad)
        frames.append(simulate_image(shape, fx[keep], fy[keep], flux[keep], fwhm=fwhm,
                                     background=background, read_noise=read_noise, gain=gain,
                                     noise=noise, seed=rng, dtype=dtype))
    stars = _star_table(sx, sy, flux, np.arange(count))
    meta = dict(shape=shape, n_stars=n_stars, fwhm=fwhm, seed=seed)
    return SimulatedViews(frames, [from_matrix(m) for m in mats], stars, meta)


def simulate_night(shape=(256, 256), *, n_frames=24, fwhm_range=(2.0, 8.0), reference_fwhm=2.5,
                   n_cloudy=3, cloud_transparency=0.4, n_trailed=2, trail_elongation=3.0,
                   n_satellite=1, n_stars=120, flux_range=(2e3, 1e5), n_faint=40,
                   faint_flux=300.0, background=200.0, read_noise=5.0, gain=1.0, max_shift=6.0,
                   seed=None):
    """
    Simulate a night of frames of one field whose quality varies: seeing,
    thin cloud, trailed frames and a satellite.

    Frame ``k`` is the field shifted by ``shifts[k]`` (sub-pixel: every frame
    but the reference is resampled by a stack), seen with its own seeing
    (FWHM log-uniform in ``fwhm_range``; the reference ``reference_fwhm``)
    and transparency (1, or ``cloud_transparency`` for ``n_cloudy``
    frames); ``n_trailed`` frames have their stars trailed to
    ``trail_elongation`` (major over minor axis of the trailed PSF) and
    ``n_satellite`` frames a satellite trail.  Besides the bright stars
    (``flux_range``: the registration's), ``n_faint`` faint stars of flux
    ``faint_flux`` lie on a grid away from them, for the stack's faint-star
    signal-to-noise.  Noise: Poisson on ``(sky + stars) * gain`` plus
    ``read_noise``; the frames carry no uncertainty, as a camera's do not.

    Parameters
    ----------
    shape : tuple of int, optional
    n_frames : int, optional
        The first is the reference (round stars, clear sky).
    fwhm_range : (float, float), optional
        Pixels.
    reference_fwhm : float, optional
    n_cloudy, n_trailed, n_satellite : int, optional
        Frames (other than the reference) with thin cloud, trailed stars, a
        satellite trail (disjoint sets).
    cloud_transparency : float, optional
    trail_elongation : float, optional
    n_stars : int, optional
        Bright stars in the field.
    flux_range : (float, float), optional
        Their fluxes (counts).
    n_faint : int, optional
    faint_flux : float, optional
        Counts at transparency 1.
    background, read_noise, gain : float, optional
        The sky (counts, scaled by each frame's transparency), counts, e-/count.
    max_shift : float, optional
        Pixels.
    seed : int, `numpy.random.Generator` or None, optional

    Returns
    -------
    night : `SimulatedSequence`
        ``meta`` holds the truth per frame: ``fwhm``, ``transparency``,
        ``elongation``, ``trailed``, ``satellite`` (bool arrays),
        ``sky_noise`` (the sky's noise per pixel, counts), and the faint
        stars ``faint_x``, ``faint_y`` (on the reference) and ``faint_flux``.

    Examples
    --------
    >>> from astroalign_nd.simulate import simulate_night
    >>> night = simulate_night((128, 128), n_frames=6, n_faint=4, n_cloudy=1, n_trailed=1,
    ...                        n_satellite=1, seed=1)
    >>> len(night.frames), int(night.meta["trailed"].sum()), float(night.meta["transparency"][0])
    (6, 1, 1.0)
    """
    from astropy.nddata import CCDData

    shape = _check_shape(shape)
    n_frames = _check_count(n_frames, "n_frames")
    if n_cloudy + n_trailed + n_satellite > n_frames - 1:
        n_bad = n_cloudy + n_trailed + n_satellite
        raise ValueError(f"n_cloudy + n_trailed + n_satellite ({n_bad}) must leave the "
                         f"reference: at most n_frames - 1 "
                         f"({n_frames - 1}).")
    lo, hi = (float(v) for v in fwhm_range)
    if not 0 < lo <= hi:
        raise ValueError(f"fwhm_range must be (low, high) with 0 < low <= high; got "
                         f"{fwhm_range!r}.")
    rng_stars, rng_frames = _spawn(seed, 2)
    ny, nx = shape
    fwhm = np.exp(rng_stars.uniform(np.log(lo), np.log(hi), n_frames))
    fwhm[0] = reference_fwhm
    kinds = rng_stars.permutation(np.arange(1, n_frames))
    cloudy = np.zeros(n_frames, bool)
    cloudy[kinds[:n_cloudy]] = True
    trailed = np.zeros(n_frames, bool)
    trailed[kinds[n_cloudy:n_cloudy + n_trailed]] = True
    satellite = np.zeros(n_frames, bool)
    satellite[kinds[n_cloudy + n_trailed:n_cloudy + n_trailed + n_satellite]] = True
    transp = np.where(cloudy, float(cloud_transparency), 1.0)
    shifts = rng_stars.uniform(-max_shift, max_shift, (n_frames, 2))
    shifts[0] = 0.0
    pad = max_shift + 3.0 * hi
    xs = rng_stars.uniform(-pad, nx - 1 + pad, n_stars)
    ys = rng_stars.uniform(-pad, ny - 1 + pad, n_stars)
    (flo, fhi), alpha = _check_flux_range(flux_range, 1.5)
    flux = _draw_fluxes(rng_stars, n_stars, flo, fhi, alpha)
    # The faint stars: a jittered grid, away from the edges and from the bright stars.
    side = int(np.ceil(np.sqrt(max(n_faint, 1)) * 1.6))
    gx, gy = np.meshgrid(np.linspace(30, nx - 31, side), np.linspace(30, ny - 31, side))
    gx, gy = gx.ravel(), gy.ravel()
    dist = np.hypot(gx[:, None] - xs[None], gy[:, None] - ys[None]).min(axis=1)
    order = np.argsort(-dist, kind="stable")[:n_faint]
    fx, fy = gx[order] + 0.3, gy[order] + 0.6
    elong = np.where(trailed, float(trail_elongation), 1.0)
    frames, transforms = [], []
    for k in range(n_frames):
        dx, dy = shifts[k]
        trail = None
        if trailed[k]:
            sig = fwhm[k] * _FWHM_TO_SIGMA
            trail = (float(np.sqrt(12.0 * (trail_elongation ** 2 - 1.0)) * sig),
                     float(rng_stars.uniform(0, 180)))
        img = simulate_image(shape, np.concatenate([xs, fx]) - dx, np.concatenate([ys, fy]) - dy,
                             np.concatenate([flux, np.full(len(fx), float(faint_flux))])
                             * transp[k], fwhm=fwhm[k], background=background * transp[k],
                             read_noise=read_noise, gain=gain, seed=rng_frames, trail=trail,
                             noise="gaussian")
        if satellite[k]:
            y0, y1 = rng_stars.uniform(0, ny, 2)
            img = add_satellite_trail(img, (-5.0, y0), (nx + 5.0, y1), width=2.5,
                                      amplitude=6.0 * np.sqrt(background)).astype(np.float32)
        frames.append(CCDData(img, unit="adu", meta={"MJD-OBS": 60000.5 + k * 0.01}))
        transforms.append(from_matrix(np.array([[1.0, 0, dx], [0, 1.0, dy], [0, 0, 1.0]])))
    sky_noise = np.sqrt(background * transp / gain + read_noise ** 2)
    meta = dict(fwhm=fwhm, transparency=transp, elongation=elong, trailed=trailed,
                satellite=satellite, cloudy=cloudy, sky_noise=sky_noise, star_x=xs, star_y=ys,
                star_flux=flux, faint_x=fx,
                faint_y=fy, faint_flux=float(faint_flux), background=background, gain=gain,
                read_noise=read_noise, seed=seed)
    truth = simulate_image(shape, np.concatenate([xs, fx]), np.concatenate([ys, fy]),
                           np.concatenate([flux, np.full(len(fx), float(faint_flux))]),
                           fwhm=fwhm[0], background=background, noise=False)
    return SimulatedSequence(frames=frames, truth=truth, transforms=transforms,
                             sky=list(background * transp), shifts=shifts, meta=meta)
