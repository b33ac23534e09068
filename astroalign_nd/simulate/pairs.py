# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
`simulate_pair`: one star field seen in two frames through a known source ->
target transform (optionally with lens distortion, transients and missing
stars), returned as a `SimulatedPair`.
"""

from dataclasses import dataclass, field
import numbers

import numpy as np
from astropy.table import Table

from astroalign_nd.transforms.convert import as_matrix, from_matrix
from astroalign_nd.transforms.linear import LinearTransform2D, SimilarityTransform
from astroalign_nd.simulate.stars import (
    _MAX_STARS, _check_count, _check_dtype, _check_flux_range, _check_fwhm,
    _check_image_options, _check_noise, _check_psf, _check_real, _check_shape, _draw_fluxes,
    _finite_pair, _inside, _spawn, _stamp_half_size, _star_table, simulate_image,
)

__all__ = ["SimulatedPair", "simulate_pair"]


@dataclass(eq=False)
class SimulatedPair:
    """
    A simulated source/target image pair with its ground truth.

    Attributes
    ----------
    source, target : 2-D ndarray
        The two simulated frames.
    transform : `~astroalign_nd.transforms.LinearTransform2D`
        The true transform mapping source pixel coordinates to target pixel
        coordinates (its linear part, when the pair has distortion).
    truth_matrix : (3, 3) ndarray
        Its homogeneous matrix.
    source_stars, target_stars : `~astropy.table.Table`
        Stars whose centre lies inside each frame (and that were not removed
        by ``missing_fraction``), with columns ``x``, ``y``, ``flux`` and
        ``id``, brightest first.  Positions are in each frame's own pixel
        coordinates; the same ``id`` is the same star in both tables, and
        ``truth_map(source x, y) == target x, y`` for it (and
        ``transform(source x, y)`` when the pair has no distortion).
    transients : `~astropy.table.Table`
        Extra stars present only in the target (same columns, target
        coordinates, ids that no real star uses).
    meta : dict
        The simulation settings actually used (rotation in degrees, scale,
        centre shift, mirror, per-frame fwhm and background, number of stars,
        seed...).
    mapping : callable or None
        ``mapping(x, y) -> (x_target, y_target)``: the full non-linear truth
        when the pair was simulated with ``distortion`` (None otherwise);
        use `truth_map`, which falls back on ``transform``.

    Examples
    --------
    `simulate_pair` makes one; the truth maps every matched source star onto
    its target position:

    >>> import numpy as np
    >>> from astroalign_nd.simulate import SimulatedPair, simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> isinstance(pair, SimulatedPair), pair.source.shape, pair.source.dtype
    (True, (256, 256), dtype('float32'))
    >>> len(pair.source_stars), pair.source_stars.colnames
    (100, ['x', 'y', 'flux', 'id'])
    >>> m = pair.matched_stars()
    >>> xt, yt = pair.transform(m["x_source"], m["y_source"])
    >>> bool(np.allclose(xt, m["x_target"]) and np.allclose(yt, m["y_target"]))
    True
    >>> bool(np.allclose(pair.transform.matrix, pair.truth_matrix))
    True
    """

    source: np.ndarray
    target: np.ndarray
    transform: LinearTransform2D
    truth_matrix: np.ndarray
    source_stars: Table
    target_stars: Table
    transients: Table
    meta: dict = field(default_factory=dict)
    mapping: object = None

    def truth_map(self, x, y):
        """
        The true source -> target mapping, at any source position.

        Equals ``transform(x, y)`` for a pair without distortion; with
        ``distortion`` it includes the lens's radial distortion and the
        tilt of the focal plane (see `simulate_pair`), so a fitted model
        can be checked over the whole frame, not only at the stars.

        Parameters
        ----------
        x, y : float or array-like
            Source pixel coordinates.

        Returns
        -------
        x_target, y_target : ndarray
            Target pixel coordinates.

        Examples
        --------
        >>> import numpy as np
        >>> from astroalign_nd.simulate import simulate_pair
        >>> pair = simulate_pair((256, 256), n_stars=50, rotation=10.0, seed=1,
        ...                      distortion={"k1": -0.02})
        >>> xt, yt = pair.truth_map([0.0, 127.5], [0.0, 127.5])
        >>> lx, ly = pair.transform([0.0, 127.5], [0.0, 127.5])
        >>> np.round(np.hypot(xt - lx, yt - ly), 2)  # barrel: 2% of the half diagonal
        array([3.58, 0.  ])
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if self.mapping is None:
            xt, yt = self.transform(x, y)
            return np.asarray(xt, dtype=float), np.asarray(yt, dtype=float)
        return self.mapping(x, y)

    def matched_stars(self):
        """
        Stars present in both frames, joined on ``id``.

        Returns
        -------
        `~astropy.table.Table`
            Columns ``id``, ``x_source``, ``y_source``, ``x_target``,
            ``y_target``, ``flux``, brightest first.
        """
        s, t = self.source_stars, self.target_stars
        common, i_s, i_t = np.intersect1d(
            np.asarray(s["id"]), np.asarray(t["id"]), return_indices=True
        )
        out = Table(
            [common, np.asarray(s["x"])[i_s], np.asarray(s["y"])[i_s],
             np.asarray(t["x"])[i_t], np.asarray(t["y"])[i_t], np.asarray(s["flux"])[i_s]],
            names=("id", "x_source", "y_source", "x_target", "y_target", "flux"),
        )
        out = out[np.lexsort((out["id"], -np.asarray(out["flux"])))]
        return out

    def __repr__(self):
        return (
            f"<SimulatedPair source{self.source.shape} target{self.target.shape} "
            f"{self.source.dtype}, {len(self.source_stars)} source stars, "
            f"{len(self.target_stars)} target stars, {len(self.transients)} transients, "
            f"transform={self.transform!r}>"
        )


def _check_transform(transform):
    if isinstance(transform, LinearTransform2D):
        model = transform.copy()
        m = model.matrix
    else:
        try:
            m = as_matrix(transform)
        except (TypeError, ValueError) as exc:
            raise TypeError(
                "transform must be an astroalign_nd transform model, a 3x3 (or 2x3) "
                "homogeneous matrix, an astropy AffineTransformation2D or a scikit-image "
                f"geometric transform; got {type(transform).__name__} ({exc})"
            ) from None
        model = None
    if not np.all(np.isfinite(m)):
        raise ValueError("transform contains NaN or infinite values.")
    if not np.allclose(m[2], [0.0, 0.0, 1.0]):
        raise ValueError("transform must be affine (last matrix row [0, 0, 1]).")
    det = np.linalg.det(m[:2, :2])
    if not abs(det) > 1e-12:
        raise ValueError(
            f"transform is singular (determinant {det:g}); it must be invertible."
        )
    if model is None:
        model = from_matrix(m)
    return model, np.array(m, dtype=float)


def _build_transform(rng, shape, target_shape, rotation, scale, translation, mirror):
    """SimilarityTransform about the frame centres, plus its description (degrees)."""
    ny, nx = shape
    randomise = rotation is None and scale is None and translation is None
    if randomise:
        rotation = float(rng.uniform(0.0, 360.0))
        translation = rng.uniform(-0.1, 0.1, size=2) * np.array([nx, ny], dtype=float)
        scale = 1.0
    if hasattr(rotation, "unit") and hasattr(rotation, "to_value"):  # astropy Quantity
        from astropy import units as u

        rotation = rotation.to_value(u.deg)
    rotation = 0.0 if rotation is None else _check_real(
        rotation, "rotation", hint=" Pass the counter-clockwise angle in degrees.")
    scale = 1.0 if scale is None else _check_real(
        scale, "scale", minimum=0.0, strict=True,
        hint=" Pass the magnification from source to target pixels, e.g. 1.0.")
    if translation is None:
        translation = np.zeros(2)
    else:
        translation, ok = _finite_pair(translation)
        if not ok:
            raise ValueError(
                "translation must be a finite (dx, dy) pair in target pixels (x first); "
                f"got {translation!r}."
            )
    parity = -1.0 if mirror else 1.0
    theta = np.deg2rad(rotation)
    lin = scale * np.array(
        [[np.cos(theta), -np.sin(theta) * parity], [np.sin(theta), np.cos(theta) * parity]]
    )
    c_src = np.array([(nx - 1) / 2.0, (ny - 1) / 2.0])
    c_tgt = np.array([(target_shape[1] - 1) / 2.0, (target_shape[0] - 1) / 2.0])
    shift = c_tgt + translation - lin @ c_src
    model = SimilarityTransform(
        scale=scale, rotation=rotation, translation_x=shift[0], translation_y=shift[1],
        parity=parity,
    )
    info = {
        "rotation": rotation,
        "scale": scale,
        "translation": tuple(float(v) for v in translation),
        "mirror": bool(mirror),
        "random_transform": randomise,
    }
    return model, info


_DISTORTION_KEYS = ("k1", "k2", "tilt", "center")


def _check_distortion(distortion, shape):
    """Validated distortion settings (a dict), or None for no distortion."""
    if distortion is None:
        return None
    if not isinstance(distortion, dict):
        raise TypeError(
            "distortion must be a dict with keys among "
            f"{list(_DISTORTION_KEYS)}, e.g. {{'k1': -0.003}} for a barrel distortion; "
            f"got {type(distortion).__name__}.")
    unknown = sorted(set(distortion) - set(_DISTORTION_KEYS))
    if unknown:
        raise ValueError(f"unknown distortion key(s) {unknown}; use {list(_DISTORTION_KEYS)}.")
    hint = " Pass a dimensionless coefficient (radius in units of the half diagonal)."
    k1 = _check_real(distortion.get("k1", 0.0), "distortion['k1']", hint=hint)
    k2 = _check_real(distortion.get("k2", 0.0), "distortion['k2']", hint=hint)
    ny, nx = shape
    pairs = {}
    for key, default in (("tilt", (0.0, 0.0)), ("center", ((nx - 1) / 2.0, (ny - 1) / 2.0))):
        value = distortion.get(key, default)
        a, ok = _finite_pair(value)
        if not ok:
            raise ValueError(f"distortion['{key}'] must be a finite (x, y) pair; got {value!r}.")
        pairs[key] = (float(a[0]), float(a[1]))
    if np.hypot(*pairs["tilt"]) >= 0.5:
        raise ValueError(
            f"distortion['tilt'] = {pairs['tilt']} is too strong: its length must be below 0.5 "
            "(a tilt of t changes the scale by about t across the half diagonal).")
    radius = 0.5 * float(np.hypot(nx, ny))  # half diagonal of the source frame
    return dict(k1=k1, k2=k2, tilt=pairs["tilt"], center=pairs["center"], radius=radius)


def _distort(d, x, y):
    """
    Source pixels through the optics: radial distortion about ``center``
    (``r' = r (1 + k1 rho**2 + k2 rho**4)``, ``rho = r / radius``), then
    the tilted focal plane (a homography that keeps the centre fixed).
    """
    cx, cy = d["center"]
    u = np.asarray(x, dtype=float) - cx
    v = np.asarray(y, dtype=float) - cy
    rho2 = (u * u + v * v) / d["radius"] ** 2
    f = 1.0 + rho2 * (d["k1"] + d["k2"] * rho2)
    u, v = u * f, v * f
    tx, ty = d["tilt"]
    if tx or ty:
        w = 1.0 + (tx * u + ty * v) / d["radius"]
        u, v = u / w, v / w
    return u + cx, v + cy


def _check_monotonic(d, box):
    """Refuse a distortion that folds the plane over inside the simulated region."""
    x0, x1, y0, y1 = box
    cx, cy = d["center"]
    rho2 = max((x - cx) ** 2 + (y - cy) ** 2 for x in (x0, x1) for y in (y0, y1))
    rho2 = rho2 / d["radius"] ** 2
    r = np.linspace(0.0, np.sqrt(rho2), 256) ** 2
    slope = 1.0 + 3.0 * d["k1"] * r + 5.0 * d["k2"] * r * r  # d r' / d r
    f = 1.0 + d["k1"] * r + d["k2"] * r * r
    if np.any(slope <= 0.05) or np.any(f <= 0.05):
        raise ValueError(
            f"distortion k1={d['k1']:g}, k2={d['k2']:g} folds the image over inside the "
            "simulated field; use smaller coefficients (|k1| of a few 0.001 gives a few "
            "pixels at the corners of a 4096 px frame).")
    tx, ty = d["tilt"]
    corners = np.array([(x, y) for x in (x0, x1) for y in (y0, y1)], float)
    w = 1.0 + (tx * (corners[:, 0] - cx) + ty * (corners[:, 1] - cy)) / d["radius"]
    if np.any(w <= 0.1):
        raise ValueError(
            f"distortion['tilt'] = {d['tilt']} sends part of the simulated field to infinity; "
            "use a smaller tilt.")


def _map_xy(m, x, y):
    return m[0, 0] * x + m[0, 1] * y + m[0, 2], m[1, 0] * x + m[1, 1] * y + m[1, 2]


def _frame_stars(x, y, flux, ids, present, shape):
    """The catalog of the stars rendered in a frame and inside it."""
    keep = present & _inside(x, y, shape)
    return _star_table(x[keep], y[keep], flux[keep], ids[keep])


def _pair_transform(rng, transform, rotation, scale, translation, mirror, shape,
                    target_shape):
    """The true linear transform of `simulate_pair`: ``(model, matrix, meta entries)``."""
    if transform is None:
        model, info = _build_transform(rng, shape, target_shape, rotation, scale,
                                       translation, mirror)
        return model, model.matrix, info
    given = [n for n, v in (("rotation", rotation), ("scale", scale),
                            ("translation", translation)) if v is not None]
    if mirror:
        given.append("mirror")
    if given:
        raise ValueError(
            f"pass either transform or rotation/scale/translation/mirror, not both "
            f"(got transform and {', '.join(given)})."
        )
    model, m = _check_transform(transform)
    return model, m, {"random_transform": False}


def _star_region(shape, target_shape, m_inv, pads, dist):
    """
    The box ``(x0, x1, y0, y1)``, in source pixels, over which stars are drawn:
    the source frame and the target frame's footprint, each padded by ``pads``
    (source, target), widened for the distortion if any.
    """
    ny, nx = shape
    nty, ntx = target_shape
    pad_s, pad_t = pads
    cx = np.array([-0.5 - pad_t, ntx - 0.5 + pad_t, ntx - 0.5 + pad_t, -0.5 - pad_t])
    cy = np.array([-0.5 - pad_t, -0.5 - pad_t, nty - 0.5 + pad_t, nty - 0.5 + pad_t])
    fx, fy = _map_xy(m_inv, cx, cy)  # padded target footprint in source coordinates
    x0 = min(fx.min(), -0.5 - pad_s)
    x1 = max(fx.max(), nx - 0.5 + pad_s)
    y0 = min(fy.min(), -0.5 - pad_s)
    y1 = max(fy.max(), ny - 0.5 + pad_s)
    if dist is not None:
        # The distorted footprint: widen the region by the largest
        # displacement at its corners (the farthest points from the centre).
        _check_monotonic(dist, (x0, x1, y0, y1))
        bx = np.array([x0, x1, x1, x0])
        by = np.array([y0, y0, y1, y1])
        dx, dy = _distort(dist, bx, by)
        grow = float(np.max(np.hypot(dx - bx, dy - by))) * 1.25 + 1.0
        x0, x1, y0, y1 = x0 - grow, x1 + grow, y0 - grow, y1 + grow
        _check_monotonic(dist, (x0, x1, y0, y1))
    return x0, x1, y0, y1


def _draw_pair_stars(rng, n_stars, shape, target_shape, region, pads, mapping, lumin,
                     missing_fraction):
    """
    The star field of `simulate_pair`, in source pixels: ``n_stars`` in the
    source frame and as dense over ``region`` wherever a star can touch either
    frame.  Returns ``(x, y, flux, ids, present_in_source, present_in_target)``
    (id 0 is the brightest star).
    """
    ny, nx = shape
    x0, x1, y0, y1 = region
    pad_s, pad_t = pads
    density = n_stars / float(nx * ny)
    expected = density * (x1 - x0) * (y1 - y0)
    if expected > _MAX_STARS:
        raise ValueError(
            f"this configuration needs about {expected:.3g} stars to fill both frames "
            f"(more than {_MAX_STARS:.0e}); reduce n_stars, the target size or the scale "
            "difference between the frames."
        )
    x_in = rng.uniform(-0.5, nx - 0.5, n_stars)
    y_in = rng.uniform(-0.5, ny - 0.5, n_stars)
    n_out = int(rng.poisson(expected)) if n_stars else 0
    x_out = rng.uniform(x0, x1, n_out)
    y_out = rng.uniform(y0, y1, n_out)
    xt_out, yt_out = mapping(x_out, y_out)
    keep = ~_inside(x_out, y_out, shape) & (
        _inside(x_out, y_out, shape, pad_s) | _inside(xt_out, yt_out, target_shape, pad_t)
    )
    xs = np.concatenate([x_in, x_out[keep]])
    ys = np.concatenate([y_in, y_out[keep]])
    flux = _draw_fluxes(rng, xs.size, *lumin)
    ids = np.empty(xs.size, dtype=np.int64)
    ids[np.lexsort((np.arange(xs.size), -flux))] = np.arange(xs.size)  # 0 = brightest
    present_src = rng.random(xs.size) >= missing_fraction
    present_tgt = rng.random(xs.size) >= missing_fraction
    return xs, ys, flux, ids, present_src, present_tgt


def _pair_meta(info, seed, dist, m, mapping, **entries):
    """
    A pair's ``meta``: the transform's ``info``, the options ``entries``, the
    seed and, for a distorted pair, the distortion and its largest corner shift.
    """
    meta = dict(info)
    meta.update(entries,
                seed=seed if isinstance(seed, (numbers.Integral, type(None))) else repr(seed))
    if dist is not None:
        ny, nx = entries["shape"]
        ccx = np.array([-0.5, nx - 0.5, nx - 0.5, -0.5])
        ccy = np.array([-0.5, -0.5, ny - 0.5, ny - 0.5])
        lx, ly = _map_xy(m, ccx, ccy)
        tx_, ty_ = mapping(ccx, ccy)
        meta.update(distortion={k: dist[k] for k in _DISTORTION_KEYS},
                    corner_shift=float(np.max(np.hypot(tx_ - lx, ty_ - ly))))
    return meta


def simulate_pair(shape=(512, 512), *, n_stars=300, transform=None, rotation=None, scale=None,
                  translation=None, mirror=False, target_shape=None, fwhm=3.0, target_fwhm=None,
                  psf="gaussian", beta=3.0, background=100.0, target_background=None,
                  gradient=0.0, flux_range=(300.0, 3e5), flux_index=1.5, read_noise=5.0,
                  gain=1.0, saturation=None, n_hot_pixels=0, n_cosmic_rays=0,
                  missing_fraction=0.0, n_transients=0, noise=True, seed=None,
                  dtype=np.float32, distortion=None, trail=None, target_trail=None):
    """
    Simulate a source/target image pair of one star field with a known transform.

    A uniform random star field is drawn in source pixel coordinates, over a
    region that covers both the source frame and the footprint of the
    target frame mapped back through the inverse transform (plus a PSF-size
    margin), so that both frames are fully and uniformly populated whatever
    the shift, rotation, scale or overlap.  Target positions are
    ``transform(source positions)``.  A star keeps the same total flux in
    both frames (same star, same exposure); only its PSF width and the sky
    level may differ between frames.

    Parameters
    ----------
    shape : tuple of int, optional
        Source image shape ``(ny, nx)``.
    n_stars : int, optional
        Star density, expressed as the number of stars whose centre lies in
        the source frame (exactly ``n_stars`` before ``missing_fraction``).
        The target frame holds about ``n_stars * target_area / (source_area
        * |det A|)`` stars (its footprint in the source frame).
    transform : model or array-like, optional
        The true source -> target transform: an astroalign_nd transform
        model (used as given) or anything `~astroalign_nd.transforms.as_matrix`
        accepts, e.g. a 3x3 matrix (converted with
        `~astroalign_nd.transforms.from_matrix`, i.e. to the simplest class
        that represents it).  Cannot be combined with ``rotation``,
        ``scale``, ``translation`` or ``mirror``.
    rotation : float, optional
        Counter-clockwise rotation in degrees (as the model stores it),
        about the frame centres.  An angular
        `~astropy.units.Quantity` is converted.
    scale : float, optional
        Magnification from source to target pixels (> 1: stars farther
        apart in the target).
    translation : (float, float), optional
        Shift ``(dx, dy)`` in target pixels (x first) of the frame centres:
        the centre of the source frame lands at the centre of the target
        frame plus ``translation``.  (The model's own ``translation_x/y``
        are those of the full matrix and include the rotation and scaling
        about the centre.)
    mirror : bool, optional
        Flip the source y axis before rotating (parity -1).
    target_shape : tuple of int, optional
        Target image shape; defaults to ``shape``.
    fwhm : float, optional
        PSF FWHM of the source frame, pixels.
    target_fwhm : float, optional
        PSF FWHM of the target frame, target pixels.  Defaults to the same
        seeing on the sky: ``fwhm * sqrt(|det A|)`` (``fwhm * scale`` for a
        similarity transform), with ``A`` the linear part of the transform.
    psf, beta
        PSF model of both frames, see `render_stars`.
    background : float, optional
        Source sky level, counts per pixel.
    target_background : float, optional
        Target sky level; defaults to ``background``.
    gradient : float, optional
        Sky gradient of both frames, see `simulate_image`.
    flux_range, flux_index
        Luminosity function, see `draw_fluxes`.
    read_noise, gain, saturation, n_hot_pixels, n_cosmic_rays, noise, dtype
        Detector options of both frames, see `simulate_image` (hot pixels
        and cosmic rays are drawn independently in each frame).
    missing_fraction : float, optional
        Fraction in [0, 1) of stars removed, independently in each frame
        (variable stars, defects...): a removed star is neither rendered
        nor listed in that frame's table.
    n_transients : int, optional
        Number of extra stars (fluxes log-uniform over ``flux_range``, so
        many are bright) added to the target only, uniformly over its
        frame, and listed in ``transients`` rather than ``target_stars``.
    seed : int, `numpy.random.Generator` or None, optional
        Random seed; the same seed gives bit-identical images and tables.
        The geometry, the star field, each frame's noise and the transients
        use independent streams, so that e.g. adding transients does not
        change the star field.
    distortion : dict, optional
        Make the mapping non-linear, as wide-field optics do: source
        positions go through the lens's radial distortion, then a tilted
        focal plane, then ``transform``.  Keys (all optional):

        * ``k1``, ``k2``: radial coefficients about ``center``,
          ``r' = r (1 + k1 rho**2 + k2 rho**4)`` with ``rho`` the radius in
          units of the source frame's half diagonal ``R``; negative is
          barrel, positive pincushion.  The corners move by
          ``R (k1 + k2)`` pixels (``k1=-0.0035``: 10 px on a 4096x4096
          frame).
        * ``tilt``: ``(tx, ty)``, the focal plane's tilt, a homography
          ``(u, v) -> (u, v) / (1 + (tx u + ty v) / R)`` about ``center``
          (dimensionless, ``|tilt| < 0.5``).
        * ``center``: the optical centre ``(x, y)`` in source pixels
          (default the frame centre).

        The pair's `SimulatedPair.truth_map` is then the true mapping
        (``transform`` stays its linear part) and ``meta['corner_shift']``
        the largest distance, over the source frame's corners, between the
        true mapping and ``transform``.  ``None`` (default): no distortion,
        bit-identical to a pair simulated without this option.
    trail, target_trail : (float, float), optional
        ``(length, angle)`` of the star trails in the source and the target
        frame (pixels, degrees counter-clockwise from +x; see
        `simulate_image`).  The catalogs keep the trails' centres.  ``None``
        (default): round stars in that frame.

    Returns
    -------
    `SimulatedPair`
        Fields ``source``, ``target``, ``transform``, ``truth_matrix``,
        ``source_stars``, ``target_stars``, ``transients`` and ``meta``.

    Notes
    -----
    When none of ``transform``, ``rotation``, ``scale`` or ``translation``
    is given, the transform is a random rotation uniform in [0, 360) degrees
    about the frame centres, scale 1, and a random centre shift uniform in
    +-10% of the source frame size along each axis (``mirror`` still
    applies).  When some of them are given, the others default to no
    rotation, unit scale and no shift.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, scale=1.1,
    ...                      translation=(5.0, -3.0), seed=42)
    >>> pair.source.shape, type(pair.transform).__name__
    ((256, 256), 'SimilarityTransform')
    >>> bool(np.isclose(pair.transform.rotation.value, 30.0))
    True
    >>> m = pair.matched_stars()
    >>> xt, yt = pair.transform(m["x_source"], m["y_source"])
    >>> bool(np.allclose(xt, m["x_target"]) and np.allclose(yt, m["y_target"]))
    True

    A wide-field pair, barrel distortion moving the corners by 5 px:

    >>> wide = simulate_pair((512, 512), n_stars=200, rotation=5.0, seed=1,
    ...                      distortion={"k1": -5.0 / np.hypot(256, 256)})
    >>> round(wide.meta["corner_shift"], 1)
    5.0
    >>> m = wide.matched_stars()
    >>> xt, yt = wide.truth_map(m["x_source"], m["y_source"])
    >>> bool(np.allclose(xt, m["x_target"]) and np.allclose(yt, m["y_target"]))
    True
    """
    shape = _check_shape(shape)
    target_shape = shape if target_shape is None else _check_shape(target_shape, "target_shape")
    dist = _check_distortion(distortion, shape)
    n_stars = _check_count(n_stars, "n_stars")
    n_transients = _check_count(n_transients, "n_transients")
    if not isinstance(mirror, (bool, np.bool_)):
        raise TypeError(f"mirror must be True or False; got {mirror!r}.")
    fwhm = _check_fwhm(fwhm, "fwhm")
    (lo, hi), alpha = _check_flux_range(flux_range, flux_index)
    psf, beta = _check_psf(psf, beta)
    dtype = _check_dtype(dtype)
    noise_model = _check_noise(noise)
    # The simulate_image options both frames share.
    common = dict(psf=psf, beta=beta, gradient=gradient, read_noise=read_noise, gain=gain,
                  saturation=saturation, n_hot_pixels=n_hot_pixels,
                  n_cosmic_rays=n_cosmic_rays, noise=noise, dtype=dtype)
    missing_fraction = _check_real(
        missing_fraction, "missing_fraction", minimum=0.0, maximum=1.0, strict_max=True,
        hint=" Pass the fraction of stars to drop from each frame, in [0, 1).")
    detector = (gradient, read_noise, gain, saturation, n_hot_pixels, n_cosmic_rays)
    _check_image_options(background, *detector)
    target_background = background if target_background is None else target_background
    _check_image_options(target_background, *detector, name_prefix="target_")

    rng_geom, rng_stars, rng_src, rng_tgt, rng_trans = _spawn(seed, 5)
    model, m, info = _pair_transform(rng_geom, transform, rotation, scale, translation, mirror,
                                     shape, target_shape)
    m_inv = np.linalg.inv(m)
    # The target's FWHM: by default the same seeing on the sky (the source's, scaled).
    target_fwhm = _check_fwhm(
        fwhm * float(np.sqrt(abs(np.linalg.det(m[:2, :2])))) if target_fwhm is None
        else target_fwhm, "target_fwhm")

    def mapping(x, y):
        """Source -> target pixels: the matrix ``m``, after the optics' distortion if any."""
        return _map_xy(m, x, y) if dist is None else _map_xy(m, *_distort(dist, x, y))

    pads = (_stamp_half_size(fwhm) + 1.0, _stamp_half_size(target_fwhm) + 1.0)
    region = _star_region(shape, target_shape, m_inv, pads, dist)
    xs, ys, flux, ids, present_src, present_tgt = _draw_pair_stars(
        rng_stars, n_stars, shape, target_shape, region, pads, mapping, (lo, hi, alpha),
        missing_fraction)
    xt, yt = mapping(xs, ys)
    # The transients: in the target only, uniform over it, log-uniform fluxes.
    tr_x = rng_trans.uniform(-0.5, target_shape[1] - 0.5, n_transients)
    tr_y = rng_trans.uniform(-0.5, target_shape[0] - 0.5, n_transients)
    tr_flux = np.exp(rng_trans.uniform(np.log(lo), np.log(hi), n_transients))
    tr_ids = xs.size + np.arange(n_transients, dtype=np.int64)

    source = simulate_image(shape, xs[present_src], ys[present_src], flux[present_src],
                            fwhm=fwhm, background=background, seed=rng_src, trail=trail,
                            **common)
    # The target: the field's stars through the mapping, and the transients.
    target = simulate_image(
        target_shape, *(np.concatenate([a[present_tgt], b])
                        for a, b in ((xt, tr_x), (yt, tr_y), (flux, tr_flux))),
        fwhm=target_fwhm, background=target_background, seed=rng_tgt, trail=target_trail,
        **common,
    )

    meta = _pair_meta(
        info, seed, dist, m, mapping,
        shape=shape, target_shape=target_shape, n_stars=n_stars, n_stars_simulated=xs.size,
        fwhm=fwhm, target_fwhm=target_fwhm, psf=common["psf"], background=float(background),
        target_background=float(target_background), gradient=float(gradient),
        flux_range=(lo, hi), flux_index=alpha, read_noise=float(read_noise), gain=float(gain),
        saturation=saturation, noise=noise_model, missing_fraction=missing_fraction,
        n_transients=n_transients)
    return SimulatedPair(
        source=source, target=target, transform=model, truth_matrix=np.array(m, dtype=float),
        source_stars=_frame_stars(xs, ys, flux, ids, present_src, shape),
        target_stars=_frame_stars(xt, yt, flux, ids, present_tgt, target_shape),
        transients=_star_table(tr_x, tr_y, tr_flux, tr_ids),
        meta=meta, mapping=None if dist is None else mapping,
    )
