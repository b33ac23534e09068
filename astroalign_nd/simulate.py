# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Simulated star fields and image pairs with a known ground-truth transform.

These functions produce realistic test data for the registration code, its
tests, documentation and benchmarks:

* `render_stars` adds pixel-integrated point-spread functions to an image,
  fast enough for tens of thousands of stars;
* `simulate_image` makes one noisy CCD-like frame (sky background, optional
  gradient, stars, Poisson and read noise, saturation, hot pixels and cosmic
  rays) from a list of star positions;
* `simulate_field` draws a random star field and renders it;
* `simulate_pair` draws a star field, maps it through a (random or given)
  source -> target transform and renders both frames, returning the images,
  the true transform and the per-frame star catalogs in a `SimulatedPair`;
* `add_nebulosity`, `add_overscan`, `to_8bit` and `bayer_bin` add what real
  frames do to the stars: extended emission and knots, overscan strips,
  8-bit stretches with bloated saturated stars and JPEG compression, and
  undersampled colour sensors.

Conventions are those of the rest of the package: positions are 0-based
``(x, y)`` with ``x`` the column index, pixel ``(i, j)`` (row ``i``, column
``j``) covers ``x`` in ``[j - 0.5, j + 0.5]`` and ``y`` in
``[i - 0.5, i + 0.5]``, image shapes are numpy's ``(ny, nx)``, and transforms
map *source* pixel coordinates to *target* pixel coordinates.

Every random draw comes from ``numpy.random.default_rng(seed)``: the same
``seed`` gives bit-identical arrays and tables.
"""

from dataclasses import dataclass, field
import numbers

import numpy as np
from astropy.table import Table
from scipy.special import erf

from astroalign_nd._kernels import GAUSS_SIGMA_TO_FWHM
from astroalign_nd.transforms.linear import LinearTransform2D, SimilarityTransform
from astroalign_nd.transforms.convert import as_matrix, from_matrix

__all__ = [
    "SimulatedPair",
    "simulate_night",
    "render_stars",
    "simulate_image",
    "simulate_field",
    "simulate_pair",
    "draw_fluxes",
    "add_nebulosity",
    "add_overscan",
    "add_edge_band",
    "simulate_sparse_pair",
    "to_8bit",
    "bayer_bin",
    "bayer_mosaic",
    "resampled_copy",
    "simulate_trust_case",
    "TRUST_CASES",
    "simulate_sequence",
    "SimulatedSequence",
    "add_satellite_trail",
    "SimulatedCatalogs",
    "simulate_catalogs",
    "SimulatedViews",
    "simulate_views",
    "mosaic_transforms",
    "dither_transforms",
]

# Number of stamp elements processed at once by `render_stars` (bounds memory:
# about 5 arrays of this many 8-byte values).
_CHUNK_ELEMENTS = 1 << 19
# Number of pixels per block when adding noise (bounds float64 temporaries).
_NOISE_BLOCK_PIXELS = 1 << 20
# Sub-pixel sampling of the Moffat profile (per axis).
_MOFFAT_OVERSAMPLE = 5
# Refuse to simulate absurdly many stars (memory and time guard).
_MAX_STARS = 10_000_000
_PSF_NAMES = ("gaussian", "moffat")
_SQRT2 = np.sqrt(2.0)
_FWHM_TO_SIGMA = 1.0 / GAUSS_SIGMA_TO_FWHM


# -- argument checking ----------------------------------------------------------

def _check_shape(shape, name="shape"):
    msg = (
        f"{name} must be a (ny, nx) pair of positive integers, numpy order, "
        f"e.g. (512, 512); got {shape!r}."
    )
    if isinstance(shape, (str, bytes)) or not hasattr(shape, "__len__") or len(shape) != 2:
        raise ValueError(msg)
    out = []
    for n in shape:
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, numbers.Integral):
            if isinstance(n, numbers.Real) and float(n).is_integer() and not isinstance(
                n, (bool, np.bool_)
            ):
                n = int(n)
            else:
                raise ValueError(msg)
        if n < 1:
            raise ValueError(msg)
        out.append(int(n))
    return tuple(out)


def _check_real(value, name, *, minimum=None, strict=False, maximum=None, strict_max=False,
                hint=""):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        arr = np.asarray(value) if not isinstance(value, (str, bytes)) else None
        if arr is None or arr.ndim != 0 or not np.issubdtype(arr.dtype, np.number):
            raise TypeError(f"{name} must be a real number; got {value!r}.{hint}")
        value = arr.item()
    value = float(value)
    if not np.isfinite(value):
        raise ValueError(f"{name} must be finite; got {value!r}.{hint}")
    if minimum is not None and (value < minimum or (strict and value == minimum)):
        rel = ">" if strict else ">="
        raise ValueError(f"{name} must be {rel} {minimum:g}; got {value!r}.{hint}")
    if maximum is not None and (value > maximum or (strict_max and value == maximum)):
        rel = "<" if strict_max else "<="
        raise ValueError(f"{name} must be {rel} {maximum:g}; got {value!r}.{hint}")
    return value


def _check_count(value, name):
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be a non-negative integer; got {value!r}.")
    if value < 0:
        raise ValueError(f"{name} must be a non-negative integer; got {value!r}.")
    return int(value)


def _check_dtype(dtype):
    try:
        dt = np.dtype(dtype)
    except TypeError as exc:
        raise TypeError(
            f"dtype must be a floating-point numpy dtype such as np.float32 or np.float64; "
            f"got {dtype!r}."
        ) from exc
    if not np.issubdtype(dt, np.floating):
        raise TypeError(
            f"dtype must be a floating-point numpy dtype such as np.float32 or np.float64; "
            f"got {dt}."
        )
    return dt


def _check_psf(psf, beta):
    if not isinstance(psf, str) or psf.lower() not in _PSF_NAMES:
        raise ValueError(f"psf must be one of {list(_PSF_NAMES)}; got {psf!r}.")
    psf = psf.lower()
    beta = _check_real(beta, "beta", minimum=1.0, strict=True,
                       hint=" The Moffat beta must exceed 1 (typical values 2.5-4.765).")
    return psf, beta


def _check_fwhm(fwhm, name, n=None):
    """Scalar fwhm, or (with ``n``) a scalar or an (n,) array of them."""
    hint = " Pass the PSF full width at half maximum in pixels, e.g. 3.0."
    if n is None or np.ndim(fwhm) == 0:
        return _check_real(fwhm, name, minimum=0.0, strict=True, hint=hint)
    arr = np.asarray(fwhm, dtype=float)
    if arr.ndim != 1 or arr.size != n:
        raise ValueError(
            f"{name} must be a scalar or one value per star ({n}); got shape {arr.shape}."
        )
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ValueError(f"every {name} value must be finite and > 0.{hint}")
    return arr


def _check_flux_range(flux_range, flux_index):
    msg = (
        "flux_range must be a (min_flux, max_flux) pair with 0 < min_flux <= max_flux, "
        f"e.g. (300, 3e5); got {flux_range!r}."
    )
    try:
        lo, hi = (float(v) for v in flux_range)
    except (TypeError, ValueError):
        raise ValueError(msg) from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(msg)
    flux_index = _check_real(flux_index, "flux_index", minimum=0.0, strict=True,
                             hint=" It is the slope alpha of N(>F) ~ F**-alpha, e.g. 1.5.")
    return (lo, hi), flux_index


def _star_arrays(x, y, flux):
    arrays = []
    for name, v in (("x", x), ("y", y), ("flux", flux)):
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            raise TypeError(f"{name} must be a number or a 1-D array of numbers.") from None
        if a.ndim > 1:
            raise ValueError(f"{name} must be a scalar or a 1-D array; got shape {a.shape}.")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} contains NaN or infinite values; remove those stars.")
        arrays.append(a)
    try:
        x, y, flux = np.broadcast_arrays(*arrays)
    except ValueError:
        raise ValueError(
            "x, y and flux must have the same length (or be scalars); got lengths "
            f"{[a.size if a.ndim else 'scalar' for a in arrays]}."
        ) from None
    return np.atleast_1d(x).ravel(), np.atleast_1d(y).ravel(), np.atleast_1d(flux).ravel()


def _spawn(seed, n):
    """``n`` independent child generators derived deterministically from ``seed``."""
    rng = np.random.default_rng(seed)
    entropy = rng.integers(0, 2**63, size=4, dtype=np.uint64)
    return [np.random.default_rng(s) for s in np.random.SeedSequence(entropy).spawn(n)]


# -- rendering ------------------------------------------------------------------

def _stamp_half_size(fwhm_max):
    return max(2, int(np.ceil(4.0 * fwhm_max)))


def _gaussian_profiles(first, pos, sigma, k):
    """(m, k) pixel-integrated 1-D Gaussian profiles; pixel ``first + j`` for column j."""
    edges = np.arange(k + 1, dtype=float) - 0.5  # relative to the first pixel centre
    z = (first[:, None] - pos[:, None] + edges) / (_SQRT2 * sigma[:, None])
    return 0.5 * np.diff(erf(z), axis=1)


def _moffat_stamps(x0, y0, x, y, fwhm, beta, k):
    """(m, k, k) Moffat stamps sampled on a sub-pixel grid and normalised to unit sum."""
    s = _MOFFAT_OVERSAMPLE
    alpha = fwhm / (2.0 * np.sqrt(2.0 ** (1.0 / beta) - 1.0))
    sub = (np.arange(s) + 0.5) / s - 0.5
    grid = (np.arange(k)[:, None] + sub).ravel()  # k*s sub-pixel centres
    dx = (x0[:, None] - x[:, None] + grid) / alpha[:, None]
    dy = (y0[:, None] - y[:, None] + grid) / alpha[:, None]
    r2 = dy[:, :, None] ** 2 + dx[:, None, :] ** 2
    r2 += 1.0
    prof = r2 ** (-beta)
    m = len(x)
    stamps = prof.reshape(m, k, s, k, s).sum(axis=(2, 4))
    stamps /= stamps.sum(axis=(1, 2), keepdims=True)
    return stamps


def _render_into(out, x, y, flux, fwhm, psf, beta):
    ny, nx = out.shape
    if x.size == 0:
        return out
    fwhm = np.broadcast_to(np.asarray(fwhm, dtype=float), x.shape)
    h = _stamp_half_size(float(np.max(fwhm)))
    k = 2 * h + 1
    # Drop stars whose stamp cannot touch the image (also avoids int overflow).
    keep = (x > -h - 1.0) & (x < nx + h) & (y > -h - 1.0) & (y < ny + h) & (flux != 0)
    if not np.all(keep):
        x, y, flux, fwhm = x[keep], y[keep], flux[keep], fwhm[keep]
    if x.size == 0:
        return out
    ix = np.floor(x + 0.5).astype(np.int64)
    iy = np.floor(y + 0.5).astype(np.int64)
    order = np.argsort(iy * (nx + 2 * k) + ix, kind="stable")  # memory locality
    x, y, flux, fwhm, ix, iy = (a[order] for a in (x, y, flux, fwhm, ix, iy))
    sigma = fwhm * _FWHM_TO_SIGMA

    contiguous = out.flags.c_contiguous
    flat = out.reshape(-1) if contiguous else None
    per_star = k * k * (_MOFFAT_OVERSAMPLE**2 if psf == "moffat" else 1)
    step = max(1, _CHUNK_ELEMENTS // per_star)
    offsets = np.arange(-h, h + 1)
    for start in range(0, x.size, step):
        sl = slice(start, start + step)
        cols = ix[sl, None] + offsets  # (m, k)
        rows = iy[sl, None] + offsets
        col_ok = (cols >= 0) & (cols < nx)
        row_ok = (rows >= 0) & (rows < ny)
        if psf == "gaussian":
            px = _gaussian_profiles(cols[:, 0], x[sl], sigma[sl], k)
            py = _gaussian_profiles(rows[:, 0], y[sl], sigma[sl], k)
            py *= flux[sl, None]
            px[~col_ok] = 0.0  # clip the stamps at the image borders
            py[~row_ok] = 0.0
            # Outer product directly in the output dtype: np.add.at is ~20x
            # slower when it has to cast, and float32 halves memory traffic.
            px = px.astype(out.dtype, copy=False)
            py = py.astype(out.dtype, copy=False)
            stamps = py[:, :, None] * px[:, None, :]
        else:
            stamps = _moffat_stamps(cols[:, 0], rows[:, 0], x[sl], y[sl], fwhm[sl], beta, k)
            stamps *= (flux[sl, None] * row_ok)[:, :, None]
            stamps *= col_ok[:, None, :]
        np.clip(cols, 0, nx - 1, out=cols)
        np.clip(rows, 0, ny - 1, out=rows)
        stamps = stamps.astype(out.dtype, copy=False)
        if contiguous:
            rows *= nx
            idx = rows[:, :, None] + cols[:, None, :]
            np.add.at(flat, idx.ravel(), stamps.ravel())
        else:
            rr = np.broadcast_to(rows[:, :, None], stamps.shape)
            cc = np.broadcast_to(cols[:, None, :], stamps.shape)
            np.add.at(out, (rr.ravel(), cc.ravel()), stamps.ravel())
    return out


def render_stars(shape, x, y, flux, *, fwhm=3.0, psf="gaussian", beta=3.0, out=None,
                 dtype=np.float32):
    """
    Add pixel-integrated stars to an image.

    The Gaussian PSF is integrated exactly over each pixel (difference of
    error functions at the pixel edges, separable in x and y), so the
    flux-weighted centroid of an isolated star equals its true position to
    better than 0.001 pixel for ``fwhm >= 1.5`` and the pixel values sum to
    its ``flux``.  Each star is drawn on a square stamp of half-size
    ``ceil(4 * fwhm)`` pixels (at least 2), clipped at the image borders: a
    star near an edge loses the part of its light that falls outside.

    Parameters
    ----------
    shape : tuple of int
        Image shape ``(ny, nx)``.  Must equal ``out.shape`` if ``out`` is given.
    x, y : float or (N,) array-like
        Star positions, 0-based pixel coordinates (``x`` is the column).
        Stars outside the image are allowed; only the part of their stamp
        that overlaps the image is drawn.
    flux : float or (N,) array-like
        Total flux of each star (image units, e.g. counts).
    fwhm : float or (N,) array-like, optional
        Full width at half maximum of the PSF in pixels, one value for all
        stars or one per star.
    psf : {'gaussian', 'moffat'}, optional
        PSF model.  The Moffat profile
        ``(1 + r**2 / alpha**2) ** -beta`` is sampled on a 5x5 sub-pixel
        grid and each stamp is normalised to ``flux`` (its wings beyond the
        stamp are dropped); it is about 30 times slower than the Gaussian.
    beta : float, optional
        Moffat power index (> 1).  Ignored for the Gaussian.
    out : 2-D float ndarray, optional
        Image to add the stars to, in place.  If not given, a new image of
        zeros with ``shape`` and ``dtype`` is created.
    dtype : numpy dtype, optional
        Floating-point type of the new image (ignored when ``out`` is given).

    Returns
    -------
    image : 2-D ndarray
        ``out`` (modified in place) or the new image.

    Raises
    ------
    ValueError
        For a malformed shape, mismatched array lengths, non-finite values,
        a non-positive fwhm or an unknown psf.
    TypeError
        For a non-float ``dtype`` or an ``out`` that is not a writeable float
        array.

    Notes
    -----
    Stamps are computed as ``(N, k)`` x- and y-profiles in vectorised numpy
    and accumulated with `numpy.add.at` in chunks, so memory stays bounded:
    30,000 stars with ``fwhm=3`` on a 1024x1024 image take a fraction of a
    second.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import render_stars
    >>> img = render_stars((64, 64), [20.3, 40.7], [30.1, 10.6], [1000.0, 500.0])
    >>> bool(np.isclose(img.sum(), 1500.0, rtol=1e-5))
    True
    """
    shape = _check_shape(shape)
    x, y, flux = _star_arrays(x, y, flux)
    fwhm = _check_fwhm(fwhm, "fwhm", n=x.size)
    psf, beta = _check_psf(psf, beta)
    if out is None:
        out = np.zeros(shape, dtype=_check_dtype(dtype))
    else:
        if not isinstance(out, np.ndarray):
            raise TypeError(f"out must be a 2-D numpy array; got {type(out).__name__}.")
        if out.shape != shape:
            raise ValueError(f"out has shape {out.shape} but shape is {shape}; they must match.")
        if not np.issubdtype(out.dtype, np.floating):
            raise TypeError(f"out must have a floating-point dtype; got {out.dtype}.")
        if not out.flags.writeable:
            raise TypeError("out is read-only; pass a writeable array.")
    return _render_into(out, x, y, flux, fwhm, psf, beta)


# -- single frames --------------------------------------------------------------

def _background_image(shape, background, gradient, dtype):
    """Sky level ``background * (1 + gradient * (u + v) / 2)``, u, v in [0, 1]."""
    ny, nx = shape
    img = np.empty(shape, dtype=dtype)
    if gradient == 0.0:
        img.fill(background)
        return img
    u = np.arange(nx) / max(nx - 1, 1)
    v = np.arange(ny) / max(ny - 1, 1)
    bx = (background * gradient * 0.5 * u).astype(dtype)
    by = (background * (1.0 + gradient * 0.5 * v)).astype(dtype)
    np.add(by[:, None], bx[None, :], out=img)
    return img


def _add_noise(img, model, read_noise, gain, rng):
    """Photon noise (in electrons) plus Gaussian read noise, in row blocks, in place."""
    ny, nx = img.shape
    rows = max(1, _NOISE_BLOCK_PIXELS // nx)
    normal_dtype = np.float32 if img.dtype == np.float32 else np.float64
    for r0 in range(0, ny, rows):
        block = img[r0:r0 + rows]
        if model == "poisson":
            electrons = block.astype(np.float64)
            electrons *= gain
            np.maximum(electrons, 0.0, out=electrons)
            noisy = rng.poisson(electrons).astype(np.float64)
            noisy /= gain
            if read_noise > 0:
                noisy += rng.standard_normal(size=noisy.shape, dtype=normal_dtype) * read_noise
            block[...] = noisy
        else:  # Gaussian approximation with the Poisson variance
            var = np.maximum(block, 0.0).astype(np.float64)
            var /= gain
            var += read_noise**2
            np.sqrt(var, out=var)
            var *= rng.standard_normal(size=var.shape, dtype=normal_dtype)
            block += var


def _check_noise(noise):
    if noise is True or (isinstance(noise, str) and noise.lower() == "poisson"):
        return "poisson"
    if isinstance(noise, str) and noise.lower() == "gaussian":
        return "gaussian"
    if noise is False or noise is None:
        return None
    raise ValueError(
        f"noise must be True/'poisson' (exact Poisson photon noise), 'gaussian' (its "
        f"normal approximation, about 4x faster) or False (no noise); got {noise!r}."
    )


def _add_artifacts(img, n_hot_pixels, n_cosmic_rays, rng):
    ny, nx = img.shape
    flat = img.reshape(-1)
    if n_hot_pixels:
        idx = rng.integers(0, ny * nx, size=n_hot_pixels)
        amp = 10.0 ** rng.uniform(3.0, 4.0, size=n_hot_pixels)
        np.add.at(flat, idx, amp)
    if n_cosmic_rays:
        n = n_cosmic_rays
        length = rng.integers(1, 5, size=n)  # 1-4 pixels
        angle = rng.uniform(0.0, np.pi, size=n)
        r0 = rng.uniform(-0.5, ny - 0.5, size=n)
        c0 = rng.uniform(-0.5, nx - 0.5, size=n)
        amp = 10.0 ** rng.uniform(3.3, 4.5, size=n)
        t = np.arange(4)
        rr = np.floor(r0[:, None] + t * np.sin(angle)[:, None] + 0.5).astype(np.int64)
        cc = np.floor(c0[:, None] + t * np.cos(angle)[:, None] + 0.5).astype(np.int64)
        vals = amp[:, None] * rng.uniform(0.4, 1.0, size=(n, 4))
        ok = (t < length[:, None]) & (rr >= 0) & (rr < ny) & (cc >= 0) & (cc < nx)
        np.add.at(flat, rr[ok] * nx + cc[ok], vals[ok])


def _check_trail(trail):
    """``(length, angle)`` of a star trail, or None for round stars."""
    if trail is None:
        return None
    try:
        length, angle = (float(v) for v in trail)
    except (TypeError, ValueError):
        raise TypeError(f"trail must be (length, angle) in pixels and degrees, or None; "
                        f"got {trail!r}.") from None
    if not (np.isfinite(length) and np.isfinite(angle)) or not 0.0 <= length <= 1000.0:
        raise ValueError(f"trail length must be finite, from 0 to 1000 pixels, and the angle "
                         f"finite; got {trail!r}.")
    return None if length == 0.0 else (length, angle)


def _trail_points(x, y, flux, fwhm, trail):
    """Each star as points 0.25 px apart along its trail, sharing its flux."""
    length, angle = trail
    k = int(np.ceil(length / 0.25)) + 1
    t = np.linspace(-0.5 * length, 0.5 * length, k)
    c, s = np.cos(np.deg2rad(angle)), np.sin(np.deg2rad(angle))
    xs = (x[:, None] + c * t).ravel()
    ys = (y[:, None] + s * t).ravel()
    fwhm = np.broadcast_to(np.asarray(fwhm, float), x.shape)
    return xs, ys, np.repeat(flux / k, k), np.repeat(fwhm, k)


def _check_image_options(background, gradient, read_noise, gain, saturation, n_hot_pixels,
                         n_cosmic_rays, name_prefix=""):
    background = _check_real(background, name_prefix + "background", minimum=0.0,
                             hint=" Pass the sky level in counts per pixel, e.g. 100.")
    gradient = _check_real(gradient, "gradient", minimum=-1.0,
                           hint=" It is the fractional change of the sky across the "
                                "frame diagonal (1.0 doubles it; must be >= -1).")
    read_noise = _check_real(read_noise, "read_noise", minimum=0.0,
                             hint=" Pass the read-noise sigma in counts, e.g. 5.")
    gain = _check_real(gain, "gain", minimum=0.0, strict=True,
                       hint=" Pass the detector gain in electrons per count, e.g. 1.")
    if saturation is not None:
        saturation = _check_real(saturation, "saturation", minimum=0.0, strict=True,
                                 hint=" Pass a positive level in counts, or None.")
    n_hot_pixels = _check_count(n_hot_pixels, "n_hot_pixels")
    n_cosmic_rays = _check_count(n_cosmic_rays, "n_cosmic_rays")
    return background, gradient, read_noise, gain, saturation, n_hot_pixels, n_cosmic_rays


def simulate_image(shape, x, y, flux, *, fwhm=3.0, psf="gaussian", beta=3.0, background=100.0,
                   gradient=0.0, read_noise=5.0, gain=1.0, saturation=None, n_hot_pixels=0,
                   n_cosmic_rays=0, noise=True, seed=None, dtype=np.float32, trail=None):
    """
    Simulate one CCD-like frame of the given stars.

    The frame is built in this order: sky background (with an optional
    linear gradient), stars (`render_stars`), Poisson noise on
    ``(sky + stars) * gain`` electrons converted back to counts plus
    Gaussian read noise, hot pixels and cosmic rays, and finally clipping
    at the ``saturation`` level.

    Parameters
    ----------
    shape : tuple of int
        Image shape ``(ny, nx)``.
    x, y : float or (N,) array-like
        Star positions (0-based pixels, ``x`` is the column).
    flux : float or (N,) array-like
        Total star fluxes in counts.
    fwhm : float or (N,) array-like, optional
        PSF full width at half maximum, pixels.
    psf : {'gaussian', 'moffat'}, optional
        PSF model, see `render_stars`.
    beta : float, optional
        Moffat power index.
    background : float, optional
        Sky level in counts per pixel (>= 0).
    gradient : float, optional
        Linear sky gradient along the image diagonal, as a fractional change:
        the sky goes from ``background`` at pixel ``(0, 0)`` to
        ``background * (1 + gradient)`` at the opposite corner
        (``gradient=1`` doubles it).  Must be >= -1.
    read_noise : float, optional
        Standard deviation of the Gaussian read noise, in counts.
    gain : float, optional
        Electrons per count; sets the Poisson noise level.
    saturation : float, optional
        If given, pixel values are clipped at this level (flat-topped bright
        stars, as in a saturated CCD).
    n_hot_pixels : int, optional
        Number of hot pixels: single pixels at random positions, 1e3 to 1e4
        counts (log-uniform) above their surroundings.
    n_cosmic_rays : int, optional
        Number of cosmic-ray hits: sharp tracks of 1 to 4 pixels with about
        1e3 to 3e4 counts per pixel.
    noise : bool or {'poisson', 'gaussian'}, optional
        ``True`` or ``'poisson'`` (default): exact Poisson photon noise on
        ``(sky + stars) * gain`` electrons, converted back to counts, plus
        Gaussian read noise.  ``'gaussian'``: its normal approximation
        (variance ``value / gain + read_noise**2``), about four times faster
        on large frames (numpy's Poisson sampler costs ~0.15 s per million
        pixels).  ``False``: no noise at all, the noiseless model (still with
        hot pixels, cosmic rays and saturation if requested).
    seed : int, `numpy.random.Generator` or None, optional
        Seed of ``numpy.random.default_rng``; the same seed gives a
        bit-identical image.
    dtype : numpy dtype, optional
        Floating-point type of the image (default float32).
    trail : (float, float), optional
        ``(length, angle)``: trail every star over ``length`` pixels at
        ``angle`` degrees (counter-clockwise from +x), as a tracking error,
        wind or field rotation does.  Each star's light is spread uniformly
        along a segment centred on its position, so that its centroid stays
        at ``(x, y)``.  ``None`` (default) or length 0: round stars.

    Returns
    -------
    image : 2-D ndarray
        The simulated frame, in counts.

    Raises
    ------
    ValueError, TypeError
        For invalid arguments; the message says which one and what to pass.

    Examples
    --------
    >>> from astroalign_nd.simulate import simulate_image
    >>> img = simulate_image((100, 120), [30.2, 70.5], [40.1, 60.9], [2e4, 5e3], seed=1)
    >>> img.shape, img.dtype
    ((100, 120), dtype('float32'))
    """
    shape = _check_shape(shape)
    x, y, flux = _star_arrays(x, y, flux)
    fwhm = _check_fwhm(fwhm, "fwhm", n=x.size)
    psf, beta = _check_psf(psf, beta)
    dtype = _check_dtype(dtype)
    (background, gradient, read_noise, gain, saturation, n_hot_pixels,
     n_cosmic_rays) = _check_image_options(background, gradient, read_noise, gain, saturation,
                                           n_hot_pixels, n_cosmic_rays)
    noise = _check_noise(noise)
    rng_noise, rng_artifacts = _spawn(seed, 2)

    trail = _check_trail(trail)
    if trail is not None:
        x, y, flux, fwhm = _trail_points(x, y, flux, fwhm, trail)
    img = _background_image(shape, background, gradient, dtype)
    _render_into(img, x, y, flux, fwhm, psf, beta)
    if noise is not None:
        _add_noise(img, noise, read_noise, gain, rng_noise)
    _add_artifacts(img, n_hot_pixels, n_cosmic_rays, rng_artifacts)
    if saturation is not None:
        np.minimum(img, saturation, out=img)
    return img


# -- star fields ----------------------------------------------------------------

def draw_fluxes(n, *, flux_range=(300.0, 3e5), flux_index=1.5, seed=None):
    """
    Draw star fluxes from a truncated power-law luminosity function.

    The cumulative number of stars brighter than ``F`` is
    ``N(>F) ~ F ** -flux_index`` between ``flux_range[0]`` and
    ``flux_range[1]`` (a truncated Pareto distribution, drawn by inverting its
    CDF): many faint stars and few bright ones, with no pile-up at the
    maximum.

    Parameters
    ----------
    n : int
        Number of fluxes.
    flux_range : (float, float), optional
        Minimum and maximum total flux (counts).
    flux_index : float, optional
        Power-law slope ``alpha`` (> 0); 1.5 is the Euclidean value for a
        uniform population.
    seed : int, `numpy.random.Generator` or None, optional
        Random seed.

    Returns
    -------
    flux : (n,) ndarray of float64

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import draw_fluxes
    >>> flux = draw_fluxes(1000, flux_range=(300.0, 3e5), seed=1)
    >>> flux.shape, flux.dtype
    ((1000,), dtype('float64'))
    >>> bool(flux.min() >= 300.0 and flux.max() <= 3e5)
    True
    >>> bool(np.median(flux) < 600.0)  # many faint stars, few bright ones
    True
    >>> bool(np.array_equal(flux, draw_fluxes(1000, seed=1)))  # same seed, same fluxes
    True
    """
    n = _check_count(n, "n")
    (lo, hi), alpha = _check_flux_range(flux_range, flux_index)
    rng = np.random.default_rng(seed)
    return _draw_fluxes(rng, n, lo, hi, alpha)


def _draw_fluxes(rng, n, lo, hi, alpha):
    u = rng.random(n)
    tail = (lo / hi) ** alpha  # fraction of the untruncated law above hi
    return lo * (1.0 - u * (1.0 - tail)) ** (-1.0 / alpha)


def _star_table(x, y, flux, ids):
    order = np.lexsort((ids, -flux))  # brightest first, ties by id
    t = Table(
        [x[order], y[order], flux[order], ids[order].astype(np.int64)],
        names=("x", "y", "flux", "id"),
    )
    t["x"].description = "x position, 0-based pixels (column)"
    t["y"].description = "y position, 0-based pixels (row)"
    t["flux"].description = "total flux (counts)"
    t["id"].description = "star identifier, the same in every frame"
    return t


def _inside(x, y, shape, pad=0.0):
    ny, nx = shape
    return (x >= -0.5 - pad) & (x < nx - 0.5 + pad) & (y >= -0.5 - pad) & (y < ny - 0.5 + pad)


def simulate_field(shape=(512, 512), *, n_stars=300, fwhm=3.0, psf="gaussian", beta=3.0,
                   flux_range=(300.0, 3e5), flux_index=1.5, background=100.0, gradient=0.0,
                   read_noise=5.0, gain=1.0, saturation=None, n_hot_pixels=0, n_cosmic_rays=0,
                   noise=True, seed=None, dtype=np.float32):
    """
    Simulate a single frame of a random star field.

    Stars are uniformly distributed; exactly ``n_stars`` have their centre
    inside the frame and, at the same density, stars just outside the edges
    (within the PSF stamp size) spill their light into it, as in a real
    field.  Fluxes follow `draw_fluxes`.

    Parameters
    ----------
    shape : tuple of int, optional
        Image shape ``(ny, nx)``.
    n_stars : int, optional
        Number of stars whose centre lies inside the frame.
    fwhm, psf, beta, background, gradient, read_noise, gain, saturation, \
n_hot_pixels, n_cosmic_rays, noise, dtype
        See `simulate_image`.
    flux_range, flux_index
        Luminosity function, see `draw_fluxes`.
    seed : int, `numpy.random.Generator` or None, optional
        Random seed; the same seed gives bit-identical output.

    Returns
    -------
    image : 2-D ndarray
        The simulated frame.
    stars : `~astropy.table.Table`
        Columns ``x``, ``y``, ``flux``, ``id`` of the stars whose centre is
        inside the frame, brightest first.

    Examples
    --------
    >>> from astroalign_nd.simulate import simulate_field
    >>> image, stars = simulate_field((256, 256), n_stars=50, seed=0)
    >>> len(stars)
    50
    """
    shape = _check_shape(shape)
    n_stars = _check_count(n_stars, "n_stars")
    fwhm = _check_fwhm(fwhm, "fwhm")
    (lo, hi), alpha = _check_flux_range(flux_range, flux_index)
    rng_stars, rng_image = _spawn(seed, 2)
    ny, nx = shape
    pad = _stamp_half_size(fwhm) + 1.0
    x_in = rng_stars.uniform(-0.5, nx - 0.5, n_stars)
    y_in = rng_stars.uniform(-0.5, ny - 0.5, n_stars)
    density = n_stars / float(nx * ny)
    big_area = (nx + 2 * pad) * (ny + 2 * pad)
    m = int(rng_stars.poisson(density * big_area)) if n_stars else 0
    x_out = rng_stars.uniform(-0.5 - pad, nx - 0.5 + pad, m)
    y_out = rng_stars.uniform(-0.5 - pad, ny - 0.5 + pad, m)
    edge = ~_inside(x_out, y_out, shape)
    x = np.concatenate([x_in, x_out[edge]])
    y = np.concatenate([y_in, y_out[edge]])
    flux = _draw_fluxes(rng_stars, x.size, lo, hi, alpha)
    ids = np.empty(x.size, dtype=np.int64)
    ids[np.lexsort((np.arange(x.size), -flux))] = np.arange(x.size)
    image = simulate_image(
        shape, x, y, flux, fwhm=fwhm, psf=psf, beta=beta, background=background,
        gradient=gradient, read_noise=read_noise, gain=gain, saturation=saturation,
        n_hot_pixels=n_hot_pixels, n_cosmic_rays=n_cosmic_rays, noise=noise, seed=rng_image,
        dtype=dtype,
    )
    inside = _inside(x, y, shape)
    return image, _star_table(x[inside], y[inside], flux[inside], ids[inside])


# -- image pairs ----------------------------------------------------------------

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


def _finite_pair(value):
    """``value`` as floats (None if not numbers), and whether it is a finite (x, y) pair."""
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None, False
    return a, a.shape == (2,) and bool(np.all(np.isfinite(a)))


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


def _check_pair_counts(n_stars, n_transients, mirror):
    """Check `simulate_pair`'s counts of stars and its ``mirror``; return the counts."""
    n_stars = _check_count(n_stars, "n_stars")
    n_transients = _check_count(n_transients, "n_transients")
    if not isinstance(mirror, (bool, np.bool_)):
        raise TypeError(f"mirror must be True or False; got {mirror!r}.")
    return n_stars, n_transients


def _frame_options(psf, beta, dtype, noise, **detector):
    """
    The `simulate_image` options common to both frames of `simulate_pair`
    (PSF, dtype and noise checked), and the noise model's name.
    """
    psf, beta = _check_psf(psf, beta)
    dtype = _check_dtype(dtype)
    noise_model = _check_noise(noise)
    return dict(psf=psf, beta=beta, **detector, noise=noise, dtype=dtype), noise_model


def _frame_stars(x, y, flux, ids, present, shape):
    """The catalog of the stars rendered in a frame and inside it."""
    keep = present & _inside(x, y, shape)
    return _star_table(x[keep], y[keep], flux[keep], ids[keep])


def _check_pair_image_options(background, target_background, gradient, read_noise, gain,
                              saturation, n_hot_pixels, n_cosmic_rays):
    """Check the detector options of both frames; return the target's background."""
    _check_image_options(background, gradient, read_noise, gain, saturation, n_hot_pixels,
                         n_cosmic_rays)
    if target_background is None:
        target_background = background
    _check_image_options(target_background, gradient, read_noise, gain, saturation,
                         n_hot_pixels, n_cosmic_rays, name_prefix="target_")
    return target_background


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


def _pair_mapping(m, dist):
    """Source -> target pixels: the matrix ``m``, after the optics' distortion if any."""
    if dist is None:
        def mapping(x, y):
            return _map_xy(m, x, y)
    else:
        def mapping(x, y):
            return _map_xy(m, *_distort(dist, x, y))
    return mapping


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


def _draw_transients(rng, n, target_shape, lo, hi, first_id):
    """Extra stars of the target only, uniform over it, log-uniform fluxes, and their ids."""
    nty, ntx = target_shape
    x = rng.uniform(-0.5, ntx - 0.5, n)
    y = rng.uniform(-0.5, nty - 0.5, n)
    flux = np.exp(rng.uniform(np.log(lo), np.log(hi), n))
    return x, y, flux, first_id + np.arange(n, dtype=np.int64)


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


def _check_missing(missing_fraction):
    return _check_real(
        missing_fraction, "missing_fraction", minimum=0.0, maximum=1.0, strict_max=True,
        hint=" Pass the fraction of stars to drop from each frame, in [0, 1).")


def _target_fwhm(fwhm, target_fwhm, m):
    """The target's FWHM: by default the same seeing on the sky (the source's, scaled)."""
    return _check_fwhm(
        fwhm * float(np.sqrt(abs(np.linalg.det(m[:2, :2])))) if target_fwhm is None
        else target_fwhm, "target_fwhm")


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
    n_stars, n_transients = _check_pair_counts(n_stars, n_transients, mirror)
    fwhm = _check_fwhm(fwhm, "fwhm")
    (lo, hi), alpha = _check_flux_range(flux_range, flux_index)
    common, noise_model = _frame_options(
        psf, beta, dtype, noise, gradient=gradient, read_noise=read_noise, gain=gain,
        saturation=saturation, n_hot_pixels=n_hot_pixels, n_cosmic_rays=n_cosmic_rays)
    missing_fraction = _check_missing(missing_fraction)
    target_background = _check_pair_image_options(
        background, target_background, gradient, read_noise, gain, saturation, n_hot_pixels,
        n_cosmic_rays)

    rng_geom, rng_stars, rng_src, rng_tgt, rng_trans = _spawn(seed, 5)
    model, m, info = _pair_transform(rng_geom, transform, rotation, scale, translation, mirror,
                                     shape, target_shape)
    m_inv = np.linalg.inv(m)
    target_fwhm = _target_fwhm(fwhm, target_fwhm, m)

    mapping = _pair_mapping(m, dist)
    pads = (_stamp_half_size(fwhm) + 1.0, _stamp_half_size(target_fwhm) + 1.0)
    region = _star_region(shape, target_shape, m_inv, pads, dist)
    xs, ys, flux, ids, present_src, present_tgt = _draw_pair_stars(
        rng_stars, n_stars, shape, target_shape, region, pads, mapping, (lo, hi, alpha),
        missing_fraction)
    xt, yt = mapping(xs, ys)
    tr_x, tr_y, tr_flux, tr_ids = _draw_transients(rng_trans, n_transients, target_shape,
                                                   lo, hi, xs.size)

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


# -- what real frames do to the stars -------------------------------------------
#
# Our own simulator is not the judge: real frames carry nebulosity, overscan
# strips, 8-bit stretches with bloated stars, and undersampled colour sensors.
# These functions put that into simulated frames, so that the tests catch it.

def _check_frame(image, name="image"):
    """A frame given to the effects below: 2-D, numeric, some finite pixels."""
    arr = np.asarray(image)
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"{name} must be a numeric 2-D image; got dtype {arr.dtype}.")
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D image; got shape {arr.shape}.")
    if min(arr.shape) < 4:
        raise ValueError(f"{name} is too small (shape {arr.shape}); pass at least 4x4 pixels.")
    if not np.isfinite(arr).any():
        raise ValueError(f"{name} has no finite pixel.")
    return arr


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
    >>> from astroalign_nd.simulate import add_nebulosity, simulate_pair
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
    >>> from astroalign_nd.simulate import add_overscan, simulate_pair
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
    >>> from astroalign_nd.simulate import add_edge_band
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
    >>> from astroalign_nd.simulate import simulate_pair, to_8bit
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
    >>> from astroalign_nd.simulate import bayer_bin, simulate_pair
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


def bayer_mosaic(image, pattern="GRBG", *, gains=(0.55, 1.0, 0.75)):
    """
    A raw colour frame, as a one-shot-colour camera writes it.

    Each pixel keeps the colour its filter passes: a grey ``image`` is
    multiplied by that colour's gain, or a colour ``image`` ``(3, ny, nx)``
    (red, green, blue planes, e.g. with the stars shifted per colour as
    atmospheric dispersion shifts them) gives each pixel its colour's plane.

    Parameters
    ----------
    image : 2-D array or (3, ny, nx) array
        A grey frame (e.g. from `simulate_image` or `simulate_views`), or
        red, green and blue planes.
    pattern : {'RGGB', 'BGGR', 'GRBG', 'GBRG'}, optional
        The colours of the first 2x2 cell, row by row (default 'GRBG', the
        Seestar's).
    gains : 3 floats, optional
        The red, green and blue response (applied to a grey ``image`` only).

    Returns
    -------
    raw : `~astropy.nddata.CCDData`
        The mosaic (float32, ``adu``), with ``BAYERPAT`` in its header.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import bayer_mosaic
    >>> raw = bayer_mosaic(np.full((4, 4), 100.0), "GRBG")
    >>> raw.data[:2, :2].tolist(), raw.meta["BAYERPAT"]
    ([[100.0, 55.0], [75.0, 100.0]], 'GRBG')
    """
    from astropy.nddata import CCDData

    from .io.bayer import bayer_channels

    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 3 and img.shape[0] == 3:
        planes = img
    elif img.ndim == 2:
        g = np.asarray(gains, dtype=float).ravel()
        if g.size != 3 or not np.all(np.isfinite(g) & (g > 0)):
            raise ValueError(f"gains must be 3 positive numbers (R, G, B); got {gains!r}.")
        planes = g[:, None, None] * img
    else:
        raise ValueError(f"image must be a 2-D frame or (3, ny, nx) colour planes; got shape "
                         f"{img.shape}.")
    channel = bayer_channels(planes.shape[1:], pattern)
    raw = np.take_along_axis(planes, channel[None].astype(np.intp), axis=0)[0]
    return CCDData(raw.astype(np.float32), unit="adu", meta={"BAYERPAT": pattern.upper()})


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
    >>> from astroalign_nd.simulate import resampled_copy, simulate_field
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


#: The cases of issue 26 that `simulate_trust_case` makes (see there).
TRUST_CASES = ("trailed", "sparse_8bit", "resampled_copy")


def simulate_trust_case(case, *, seed=None):
    """
    One pair of a hard case for the trust of a registration (issue 26).

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
    >>> from astroalign_nd.simulate import simulate_trust_case
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


# -- sequences of frames (stacking) ---------------------------------------------

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


# -- catalog pairs --------------------------------------------------------------

@dataclass(eq=False)
class SimulatedCatalogs:
    """
    Two star catalogs of one field with a known source-to-target transform.

    Attributes
    ----------
    source, target : `~astropy.table.Table`
        Columns ``x``, ``y`` (pixels), ``flux`` and ``id`` (the star's
        identifier, -1 for a spurious entry), brightest first.
    transform : `~astroalign_nd.transforms.SimilarityTransform`
        The true source-to-target transform.
    n_true_pairs : int
        Stars present in both catalogs (entries with the same ``id``).

    Examples
    --------
    `simulate_catalogs` makes one; the truth maps a star's source position
    onto its target position, to the noise:

    >>> import numpy as np
    >>> from astroalign_nd.simulate import simulate_catalogs
    >>> cats = simulate_catalogs(500, noise=0.0, seed=3)
    >>> src = cats.source[cats.source["id"] == 7]
    >>> dst = cats.target[cats.target["id"] == 7]
    >>> bool(np.allclose(cats.transform(src["x"], src["y"]), (dst["x"], dst["y"])))
    True
    """

    source: Table
    target: Table
    transform: LinearTransform2D
    n_true_pairs: int


def _catalog_rows(rng, xy, flux, ids, noise, n_spurious, box, lo, hi, alpha):
    """A catalog: the given stars with position noise, plus spurious entries in ``box``."""
    x0, x1, y0, y1 = box
    sx = rng.uniform(x0, x1, n_spurious)
    sy = rng.uniform(y0, y1, n_spurious)
    x = np.concatenate([xy[:, 0], sx]) + rng.normal(0.0, noise, len(ids) + n_spurious)
    y = np.concatenate([xy[:, 1], sy]) + rng.normal(0.0, noise, len(ids) + n_spurious)
    f = np.concatenate([flux, _draw_fluxes(rng, n_spurious, lo, hi, alpha)])
    # Photometric noise: the two epochs do not rank the stars quite alike.
    f = f * np.exp(rng.normal(0.0, 0.05, f.size))
    return _star_table(x, y, f, np.concatenate([ids, np.full(n_spurious, -1)]))


def simulate_catalogs(n_stars=10_000, *, shape=(4096, 4096), rotation=None, scale=None,
                      noise=0.1, missing_fraction=0.2, spurious_fraction=0.1,
                      flux_range=(300.0, 3e5), flux_index=1.5, seed=None):
    """
    Simulate two catalogs of one star field related by a similarity transform.

    ``n_stars`` stars are drawn uniformly over a ``shape`` frame; each
    catalog loses a random ``missing_fraction`` of them (independently),
    gains ``spurious_fraction * n_stars`` entries at random positions, and
    measures every position with Gaussian noise of ``noise`` pixels per
    axis.  The target catalog holds the stars' positions mapped through the
    transform (the whole mapped frame: nothing is cropped), so about
    ``(1 - missing_fraction)**2 * n_stars`` true pairs exist.

    Parameters
    ----------
    n_stars : int, optional
        Stars of the field.
    shape : (int, int), optional
        The source frame ``(ny, nx)``.
    rotation : float, optional
        Degrees; uniform in [-180, 180) by default.
    scale : float, optional
        Log-uniform in [0.8, 1.25] by default.
    noise : float, optional
        Position noise per axis (pixels, each catalog in its own frame).
    missing_fraction, spurious_fraction : float, optional
        As above.
    flux_range, flux_index
        The luminosity function (`draw_fluxes`).
    seed : int, `numpy.random.Generator` or None, optional
        Random seed; the same seed gives identical catalogs.

    Returns
    -------
    `SimulatedCatalogs`

    Examples
    --------
    >>> from astroalign_nd.simulate import simulate_catalogs
    >>> cats = simulate_catalogs(2000, seed=1)
    >>> cats.source.colnames
    ['x', 'y', 'flux', 'id']
    >>> bool(abs(cats.n_true_pairs - 0.64 * 2000) < 100)
    True
    """
    n_stars = _check_count(n_stars, "n_stars")
    shape = _check_shape(shape)
    noise = _check_real(noise, "noise", minimum=0.0)
    missing = _check_real(missing_fraction, "missing_fraction", minimum=0.0, maximum=1.0,
                          strict_max=True)
    spurious = _check_real(spurious_fraction, "spurious_fraction", minimum=0.0)
    (lo, hi), alpha = _check_flux_range(flux_range, flux_index)
    rng_field, rng_src, rng_dst = _spawn(seed, 3)
    ny, nx = shape
    rot = rng_field.uniform(-180.0, 180.0) if rotation is None else float(rotation)
    sc = (float(np.exp(rng_field.uniform(np.log(0.8), np.log(1.25)))) if scale is None
          else float(scale))
    shift = rng_field.uniform(-0.1, 0.1, 2) * (nx, ny)
    truth = SimilarityTransform(scale=sc, rotation=rot, translation_x=shift[0],
                                translation_y=shift[1])
    xy = np.column_stack([rng_field.uniform(-0.5, nx - 0.5, n_stars),
                          rng_field.uniform(-0.5, ny - 0.5, n_stars)])
    flux = _draw_fluxes(rng_field, n_stars, lo, hi, alpha)
    ids = np.arange(n_stars)
    keep_src = rng_src.random(n_stars) >= missing
    keep_dst = rng_dst.random(n_stars) >= missing
    n_spur = int(round(spurious * n_stars))
    src = _catalog_rows(rng_src, xy[keep_src], flux[keep_src], ids[keep_src], noise, n_spur,
                        (-0.5, nx - 0.5, -0.5, ny - 0.5), lo, hi, alpha)
    mapped = np.column_stack(truth(xy[:, 0], xy[:, 1]))
    # Spurious target entries over the mapped frame: uniform source-frame points, mapped.
    box = np.column_stack([rng_dst.uniform(-0.5, nx - 0.5, n_spur),
                           rng_dst.uniform(-0.5, ny - 0.5, n_spur)])
    spur = np.column_stack(truth(box[:, 0], box[:, 1]))
    dst = _catalog_rows(rng_dst, np.concatenate([mapped[keep_dst], spur]),
                        np.concatenate([flux[keep_dst], _draw_fluxes(rng_dst, n_spur, lo, hi,
                                                                     alpha)]),
                        np.concatenate([ids[keep_dst], np.full(n_spur, -1)]), noise, 0,
                        (0.0, 1.0, 0.0, 1.0), lo, hi, alpha)
    return SimulatedCatalogs(src, dst, truth, int(np.sum(keep_src & keep_dst)))


# -- sequences and mosaics (issue 28) ---------------------------------------------


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


def simulate_sparse_pair(shape=(512, 512), *, n_stars=25, rotation=None, translation=None,
                         scale=None, flux_range=(600.0, 6e4), background=300.0,
                         centroid_jitter=0.12, n_hits=3, seed=None, **pair_options):
    """
    A sparse, faint pair whose detections' position errors are wrong.

    Like a blue frame of a high-latitude field against a red one: about
    ``n_stars`` stars, most near the detection limit, and centroids that
    differ between the two frames by more than their noise says.  Two
    things the detector cannot know are added to the target frame:

    * ``centroid_jitter``: every star is drawn at its true position plus a
      Gaussian offset of this many pixels per axis (a star's colour moves
      its centroid between bands; the PSFs differ).  The bright stars'
      position errors, estimated from their S/N, are then far too small;
    * ``n_hits``: as many of the fainter stars get a cosmic-ray-like hit of
      one or two pixels, 1 to 2 pixels from their centre, that pulls their
      centroid without making them look different.

    The truth (``transform``, ``truth_matrix``, ``target_stars``) is that of
    the stars' true positions: the offsets are errors of the frame, not
    part of the transform.

    Parameters
    ----------
    shape : tuple of int, optional
        Both frames' shape ``(ny, nx)``.
    n_stars, rotation, translation, scale, flux_range, background
        As for `simulate_pair` (here: few, faint stars on a bright sky).
    centroid_jitter : float, optional
        Per-axis standard deviation of the target stars' offsets, pixels.
    n_hits : int, optional
        Number of fainter target stars hit by a cosmic ray.
    seed : int or `numpy.random.Generator`, optional
        Makes the pair reproducible.
    **pair_options
        Other options of `simulate_pair` (``fwhm``, ``read_noise``...).

    Returns
    -------
    pair : `SimulatedPair`
        With ``meta["centroid_jitter"]``, ``meta["hit_ids"]`` (the ids of
        the hit stars) and ``meta["target_offsets"]`` (per target star, in
        the order of ``target_stars``).

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.simulate import simulate_sparse_pair
    >>> pair = simulate_sparse_pair(seed=3, rotation=30.0)
    >>> len(pair.source_stars) < 40, len(pair.meta["hit_ids"])
    (True, 3)
    >>> off = pair.meta["target_offsets"]
    >>> bool(0.05 < np.std(off) < 0.2)
    True
    """
    centroid_jitter = _check_real(centroid_jitter, "centroid_jitter", minimum=0.0,
                                  hint=" Pass the offsets' standard deviation in pixels.")
    n_hits = _check_count(n_hits, "n_hits")
    rng_pair, rng_off, rng_img = _spawn(seed, 3)
    pair = simulate_pair(shape, n_stars=n_stars, rotation=rotation, translation=translation,
                         scale=scale, flux_range=flux_range, background=background,
                         seed=rng_pair, **pair_options)
    meta = pair.meta
    tgt = pair.target_stars
    off = rng_off.normal(0.0, centroid_jitter, (len(tgt), 2))
    xt, yt = np.asarray(tgt["x"]) + off[:, 0], np.asarray(tgt["y"]) + off[:, 1]
    image = simulate_image(
        meta["target_shape"], xt, yt, np.asarray(tgt["flux"]), fwhm=meta["target_fwhm"],
        psf=meta["psf"], background=meta["target_background"], gradient=meta["gradient"],
        read_noise=meta["read_noise"], gain=meta["gain"], saturation=meta["saturation"],
        noise=meta["noise"], seed=rng_img, dtype=pair.target.dtype)
    # Hits on the fainter half (the catalog is brightest first), at a peak
    # of 1 to 3 times the star's own.
    faint = np.arange(len(tgt) // 2, len(tgt))
    hit = rng_off.choice(faint, size=min(n_hits, len(faint)), replace=False)
    sig = meta["target_fwhm"] / GAUSS_SIGMA_TO_FWHM
    for i in hit:
        ang = rng_off.uniform(0.0, 2.0 * np.pi)
        dist = rng_off.uniform(1.0, 2.0)
        peak = tgt["flux"][i] / (2.0 * np.pi * sig**2) * rng_off.uniform(1.0, 3.0)
        for k in range(int(rng_off.integers(1, 3))):
            c = int(np.floor(xt[i] + (dist + k) * np.cos(ang) + 0.5))
            r = int(np.floor(yt[i] + (dist + k) * np.sin(ang) + 0.5))
            if 0 <= r < image.shape[0] and 0 <= c < image.shape[1]:
                image[r, c] += peak
    meta = {**meta, "centroid_jitter": centroid_jitter,
            "hit_ids": [int(v) for v in tgt["id"][hit]], "target_offsets": off}
    return SimulatedPair(source=pair.source, target=image, transform=pair.transform,
                         truth_matrix=pair.truth_matrix, source_stars=pair.source_stars,
                         target_stars=tgt, transients=pair.transients, meta=meta,
                         mapping=pair.mapping)


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
    >>> len(night.frames), int(night.meta["trailed"].sum()), night.meta["transparency"][0]
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
