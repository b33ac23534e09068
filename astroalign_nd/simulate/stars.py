# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Stars on a pixel grid: `render_stars` (pixel-integrated Gaussian or Moffat
profiles), `simulate_image` (one noisy CCD-like frame from a star list),
`draw_fluxes` and `simulate_field` (a random field, rendered), and the
argument checks the other simulators share.
"""

import numbers

import numpy as np
from astropy.table import Table
from scipy.special import erf

from astroalign_nd._kernels import GAUSS_SIGMA_TO_FWHM

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

__all__ = ["render_stars", "simulate_image", "draw_fluxes", "simulate_field", "bayer_mosaic"]


# -- argument checking -----------------------------------------------------------------


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


def _finite_pair(value):
    """``value`` as floats (None if not numbers), and whether it is a finite (x, y) pair."""
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None, False
    return a, a.shape == (2,) and bool(np.all(np.isfinite(a)))


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


# -- rendering -------------------------------------------------------------------------

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


# -- single frames ---------------------------------------------------------------------

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

    if trail is not None:  # (length, angle); None (or length 0) for round stars
        try:
            length, angle = (float(v) for v in trail)
        except (TypeError, ValueError):
            raise TypeError(f"trail must be (length, angle) in pixels and degrees, or None; "
                            f"got {trail!r}.") from None
        if not (np.isfinite(length) and np.isfinite(angle)) or not 0.0 <= length <= 1000.0:
            raise ValueError(f"trail length must be finite, from 0 to 1000 pixels, and the "
                             f"angle finite; got {trail!r}.")
        if length != 0.0:
            # Each star as points 0.25 px apart along its trail, sharing its flux.
            k = int(np.ceil(length / 0.25)) + 1
            t = np.linspace(-0.5 * length, 0.5 * length, k)
            c, s = np.cos(np.deg2rad(angle)), np.sin(np.deg2rad(angle))
            fwhm = np.repeat(np.broadcast_to(np.asarray(fwhm, float), x.shape), k)
            x, y = (x[:, None] + c * t).ravel(), (y[:, None] + s * t).ravel()
            flux = np.repeat(flux / k, k)
    # The sky: background * (1 + gradient * (u + v) / 2), u, v in [0, 1].
    img = np.empty(shape, dtype=dtype)
    if gradient == 0.0:
        img.fill(background)
    else:
        u = np.arange(shape[1]) / max(shape[1] - 1, 1)
        v = np.arange(shape[0]) / max(shape[0] - 1, 1)
        bx = (background * gradient * 0.5 * u).astype(dtype)
        by = (background * (1.0 + gradient * 0.5 * v)).astype(dtype)
        np.add(by[:, None], bx[None, :], out=img)
    _render_into(img, x, y, flux, fwhm, psf, beta)
    if noise is not None:
        _add_noise(img, noise, read_noise, gain, rng_noise)
    _add_artifacts(img, n_hot_pixels, n_cosmic_rays, rng_artifacts)
    if saturation is not None:
        np.minimum(img, saturation, out=img)
    return img


# -- star fields -----------------------------------------------------------------------

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

    from astroalign_nd.io.bayer import bayer_channels

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
