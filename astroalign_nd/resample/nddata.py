# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The last stage of the method: put the source onto the target's pixel grid
and return a `~astropy.nddata.CCDData` ready for ccdproc.

The output carries:

* ``data`` resampled with the chosen interpolation (or flux-exactly
  through reproject);
* ``mask``: True outside the source footprint, and wherever a masked or
  non-finite source pixel had a non-zero interpolation weight;
* ``uncertainty`` propagated through the interpolation weights (variance
  resampled with the squared weights) and returned in the class that came
  in.  Resampling correlates neighbouring output pixels; the per-pixel
  variance is right, but the pixels are no longer independent;
* ``flags`` of the source, resampled by nearest neighbour (0 outside the
  footprint); written to a ``FLAGS`` extension by
  ``ccd.write(path, hdu_flags="FLAGS")``;
* ``unit`` of the source (``adu`` when nothing says otherwise);
* ``meta``: the source header with HISTORY lines and machine-readable
  ``AAT*`` keywords from which the transform can be rebuilt
  (`~astroalign_nd.transform_from_header`), unless ``add_keyword=False``;
* ``wcs``: the target's WCS, or the source's carried through the
  transform when only the source has one.
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any
import numpy as np
from astropy import units as u
from astropy.nddata import (CCDData, FlagCollection, InverseVariance, StdDevUncertainty,
                            VarianceUncertainty)
from ..io.read import parse_input
from ..io.sip import sip_through_linear
from ..exceptions import AstroalignWarning, warn
from ..options import astroalign_advice
from ..io.header import (add_history, add_provenance, check_quality, fits_text, header_from_meta,
                         header_without_wcs)
from .coordinate_map import _MAP_BAND_PIXELS, _CoordinateMap, _parse_matrix
from .options import ORDERS, ResampleConfig, order_index
from .core import resample, working_dtype
from .exact import resample_exact
from ..transforms.linear import LinearTransform2D
from ..transforms import ProjectiveTransform
from ..transforms.convert import as_matrix, from_matrix

__all__ = ['apply_transform']

_UNCERTAINTY_CLASSES = (StdDevUncertainty, VarianceUncertainty, InverseVariance)


def _variance_of(uncertainty, dtype, check_only=False):
    """
    Variance array of an uncertainty, in ``dtype`` (the data's working type).

    Computed here rather than with ``represent_as``, which makes two copies
    of the plane (the conversion, then a deep copy of it): a
    VarianceUncertainty's array is used as it is (only read), a StdDev's is
    squared and an InverseVariance's inverted into one new array.
    """
    if not isinstance(uncertainty, _UNCERTAINTY_CLASSES):
        raise TypeError(
            f"uncertainty of type {type(uncertainty).__name__} cannot be propagated; use "
            "StdDevUncertainty, VarianceUncertainty or InverseVariance."
        )
    if check_only:
        return None
    arr = np.asarray(uncertainty.array)
    if isinstance(uncertainty, VarianceUncertainty):
        return arr
    var = np.empty(arr.shape, dtype)
    # In the array's own type, then stored as ``dtype`` (as represent_as and a cast would).
    if isinstance(uncertainty, StdDevUncertainty):
        return np.square(arr, out=var, casting="unsafe")
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.divide(1.0, arr, out=var, casting="unsafe")


def _uncertainty_like(template, variance, unit, converted=False):
    """
    Variance back into the uncertainty class that came in.

    ``variance`` is the resampler's own output: it is converted in place
    (unless ``converted``: the kernel already stored it in the template's
    kind) and wrapped without a copy (astropy's ``represent_as`` would make
    two).
    """
    var_unit = unit**2 if unit is not None else None
    cls = type(template)
    if issubclass(cls, VarianceUncertainty):
        return cls(variance, unit=var_unit, copy=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        if issubclass(cls, StdDevUncertainty):
            if not converted:
                np.sqrt(variance, out=variance)
            return cls(variance, unit=None if var_unit is None else var_unit ** (1 / 2),
                       copy=False)
        if not converted:
            np.divide(1.0, variance, out=variance)
        return cls(variance, unit=None if var_unit is None else 1 / var_unit, copy=False)


def _carry_wcs(wcs, matrix, shape_out):
    """
    The source's WCS expressed on the target's pixel grid.

    Output pixel ``q = A p + t`` for source pixel ``p``: the new ``CRPIX`` is
    the old one mapped, ``CD`` becomes ``CD A^-1``, and SIP distortion ``f``
    (forward and inverse) becomes ``A f(A^-1 v)``, re-expanded exactly (a
    polynomial of a linear map is a polynomial of the same degree).  Lookup-table
    distortions cannot be re-expressed: they are dropped with a warning that
    says how far, in pixels, sky positions then move.
    """
    w = wcs.deepcopy()
    lin = matrix[:2, :2]
    inv = np.linalg.inv(lin)
    crpix0 = np.asarray(w.wcs.crpix[:2], float) - 1.0  # FITS is 1-based
    w.wcs.crpix = lin @ crpix0 + matrix[:2, 2] + 1.0
    if w.wcs.has_cd():
        w.wcs.cd = np.asarray(w.wcs.cd) @ inv
    else:
        w.wcs.pc = np.asarray(w.wcs.get_pc()) @ inv
    if w.sip is not None:
        w.sip = sip_through_linear(w.sip, lin, w.wcs.crpix)
    _drop_lookup_tables(wcs, w, lin, matrix[:2, 2])
    w.pixel_shape = (shape_out[1], shape_out[0])
    return w


def _drop_lookup_tables(old, new, lin, shift):
    """Remove lookup-table distortions from ``new``, warning how far sky positions move."""
    tables = ("cpdis1", "cpdis2", "det2im1", "det2im2")
    if all(getattr(old, t, None) is None for t in tables):
        return
    for t in tables:
        setattr(new, t, None)
    ny, nx = old.pixel_shape[::-1] if old.pixel_shape else (1024, 1024)
    yy, xx = np.mgrid[0:ny:17j, 0:nx:17j]
    sky_old = old.all_pix2world(np.column_stack([xx.ravel(), yy.ravel()]), 0)
    q = np.column_stack([xx.ravel(), yy.ravel()]) @ lin.T + shift
    back = new.all_world2pix(sky_old, 0)
    off = float(np.max(np.hypot(*(back - q).T)))
    warn(f"the source's WCS has lookup-table distortion, which cannot follow the transform: "
         f"the output's WCS is without it, so its sky positions are off by up to {off:.2f} px.",
         AstroalignWarning)


def _resample_flags(flags, matrix, shape_out):
    """
    Flags on the output grid by nearest neighbour (0 outside the footprint).

    Flags are bit sets or labels: interpolating them has no meaning, so
    each output pixel takes the flags of the source pixel it falls on.
    """
    if isinstance(flags, FlagCollection):
        out = FlagCollection(shape=tuple(shape_out))
        for key, value in flags.items():
            out[key] = _resample_flags(np.asarray(value), matrix, shape_out)
        return out
    flags = np.asarray(flags)
    ny, nx = shape_out
    out = np.zeros((ny, nx) + flags.shape[2:], dtype=flags.dtype)
    step = max(1, _MAP_BAND_PIXELS // nx)
    if isinstance(matrix, _CoordinateMap):
        inv = None
    else:
        inv = np.linalg.inv(matrix)
    for r0 in range(0, ny, step):  # bands of rows: bounded temporaries
        r1 = min(r0 + step, ny)
        if inv is None:
            xs, ys, _ = matrix.band(r0, r1, nx)
        else:
            yo, xo = np.mgrid[r0:r1, :nx]
            xs = inv[0, 0] * xo + inv[0, 1] * yo + inv[0, 2]
            ys = inv[1, 0] * xo + inv[1, 1] * yo + inv[1, 2]
        xs, ys = np.rint(xs), np.rint(ys)
        with np.errstate(invalid="ignore"):  # NaN (no source position) is outside
            inside = (xs >= 0) & (xs < flags.shape[1]) & (ys >= 0) & (ys < flags.shape[0])
        xs = np.where(inside, xs, 0).astype(np.intp)
        ys = np.where(inside, ys, 0).astype(np.intp)
        out[r0:r1][inside] = flags[ys[inside], xs[inside]]
    return out


def _source_to_target(transform, shape_in):
    """The 3x3 matrix of an affine transform, or the `_CoordinateMap` of another."""
    from astropy.modeling import Model

    try:
        m = as_matrix(transform)
    except ValueError:
        if not isinstance(transform, Model):
            raise
        # Non-linear: its coordinate map (or a clear error).
        return _parse_matrix(transform, shape_in=shape_in)
    if np.all(np.isfinite(m)) and not np.allclose(m[2], [0.0, 0.0, 1.0]):
        return _parse_matrix(m)  # a homography (e.g. scikit-image's ProjectiveTransform)
    if not np.all(np.isfinite(m)) or abs(np.linalg.det(m[:2, :2])) < 1e-12:
        raise ValueError("transform is singular or not finite; it cannot be applied.")
    return m


def _nonlinear_provenance(header, transform, cmap, quality, names):
    """
    `add_provenance` for a non-linear transform: its header keywords when the
    model can write them, otherwise HISTORY cards only (save the model itself
    with ASDF).
    """
    from astropy.modeling import Model

    model = transform
    if not isinstance(model, Model):  # a projective matrix or scikit-image transform
        model = ProjectiveTransform.from_matrix(as_matrix(transform))
    try:
        return add_provenance(header, model, quality=quality, copy=False, **names)
    except (ValueError, TypeError):
        pass  # not storable in a header
    out = header.copy()
    add_history(out, f"astroalign_nd: registered {fits_text(names['source_name'])} onto the "
                     f"pixel grid of {fits_text(names['target_name'])} through a non-linear "
                     f"{cmap.name} (not stored in this header)")
    add_history(out, f"astroalign_nd resampling: {names['order']}, "
                     f"conserve_flux={names['conserve_flux']}")
    return out


#: `apply_transform`'s keywords as its error message lists them: the resampling
#: config's fields, and the inputs' own.
_ACCEPTED = (", ".join(f.name for f in fields(ResampleConfig))
             + ", unit, quality, hdu and target_name")


def _target_grid(target, hdu):
    """``(shape_out, parsed target)``; the target is None when given as an ``(ny, nx)`` shape."""
    if isinstance(target, tuple) and len(target) == 2 and all(
            isinstance(v, (int, np.integer)) for v in target):
        return tuple(int(v) for v in target), None
    dst = parse_input(target, "target", hdu=hdu)
    if dst.is_catalog:
        raise TypeError(
            "target is a catalog, which has no pixel grid; pass the target image or its "
            "shape as an (ny, nx) tuple."
        )
    return dst.shape, dst


def _source_variance(src, method):
    """
    ``(plane, kind)``: the source's uncertainty plane in the data's shape and
    how `resample` reads it ('variance', 'stddev' or 'inverse'); None if none.
    """
    data = src.data
    if src.uncertainty is None:
        return None, "variance"
    unc = src.uncertainty
    kind = "variance"
    if method == "exact":
        # The variance is resampled in the data's working type (see `resample`).
        dtype = working_dtype(data.dtype)
        variance = _variance_of(unc, dtype)
    else:
        _variance_of(unc, None, check_only=True)
        # resample squares (or inverts) the plane band by band: no
        # whole-frame variance is made.
        variance = np.asarray(unc.array)
        kind = ("stddev" if isinstance(unc, StdDevUncertainty) else
                "inverse" if isinstance(unc, InverseVariance) else "variance")
    if variance.shape not in (data.shape, data.shape[:2]):
        raise ValueError(
            f"the source's uncertainty has shape {variance.shape}, but its data "
            f"{data.shape}; give one uncertainty per pixel (shape {data.shape[:2]}"
            f"{' or ' + str(data.shape) if data.ndim == 3 else ''}).")
    if data.ndim == 3 and variance.ndim == 2:  # one plane for every channel
        variance = variance[..., None]
    if variance.shape != data.shape:
        variance = np.broadcast_to(variance, data.shape)
    return variance, kind


def _usable_variance(variance, kind):
    """
    ``(plane, kind, bad)``: the uncertainty plane with its unusable pixels (NaN, infinite,
    negative; an inverse variance of 0 or less) set to a variance of 0, so that they touch
    neither the data nor the mask; ``bad`` marks them (None if there are none).

    The resampler treats a non-finite variance as a bad pixel, which would spread one bad
    uncertainty value over the data and the mask of its neighbours, or blank a whole frame
    whose uncertainty is all NaN.  A bad uncertainty must never destroy good data: only the
    output uncertainty it reaches is unknown (NaN, see `_blank_uncertainty`).
    """
    if variance is None:
        return None, kind, None
    low, high = np.min(variance), np.max(variance)  # NaN propagates: two fast reductions
    floor_ok = low > 0 if kind == "inverse" else low >= 0
    if np.isfinite(low) and np.isfinite(high) and floor_ok:
        return variance, kind, None
    plane = np.asarray(variance, dtype=np.float64 if variance.dtype.itemsize > 4 else None)
    with np.errstate(invalid="ignore", divide="ignore"):
        var = (np.square(plane) if kind == "stddev" else
               1.0 / plane if kind == "inverse" else np.array(plane, copy=True))
        bad = ~np.isfinite(var) | (var < 0) | ~np.isfinite(plane) | (plane < 0)
    var[bad] = 0.0
    warn(f"{int(bad.sum())} pixels of the source's uncertainty are NaN, infinite or "
         "negative: they are left out of the output's data and mask, and its uncertainty is "
         "NaN where they contribute.", AstroalignWarning)
    return var, "variance", bad


def _blank_uncertainty(var_out, mask_out, bad, m, shape_out, method, order, parallel):
    """In place: NaN output uncertainty wherever an unusable input uncertainty contributes."""
    indicator = bad.astype(np.float32)
    if method == "exact":
        reached, _, _ = resample_exact(indicator, m, shape_out, fill_value=0.0)
    else:
        reached, _, _ = resample(indicator, m, shape_out, order=order, fill_value=0.0,
                                 parallel=parallel)
    reached = reached != 0
    valid = ~mask_out if reached.ndim == 2 else ~mask_out[..., None]
    var_out[reached & valid] = np.nan


def _output_header(src, dst, transform, m, quality, add_keyword, target_name=None, **names):
    """The source's header as FITS cards, without its WCS, and the registration's keywords."""
    # Non-FITS keys become HIERARCH cards; the WCS cards describe the old grid.
    # (The header is this function's own: stripped and completed without copies, which cost
    # a second for 20,000 cards.)
    header = header_without_wcs(header_from_meta(src.meta), copy=False)
    if not add_keyword:
        return header
    names = dict(source_name=src.name, target_name=str(target_name), **names)
    if not isinstance(m, _CoordinateMap):
        model = transform if isinstance(transform, LinearTransform2D) else from_matrix(m)
        return add_provenance(header, model, quality=quality, copy=False, **names)
    return _nonlinear_provenance(header, transform, m, quality, names)


def apply_transform(transform: Any, source: Any, target: Any, *,
                    order: str | int = "bilinear", conserve_flux: bool = False,
                    fill_value: float = np.nan, method: str = "interpolate", unit: Any = None,
                    parallel: bool = True, quality: dict | None = None,
                    hdu: int | str | None = None, add_keyword: bool = True,
                    target_name: str | None = None, **unexpected: Any) -> CCDData:
    """
    Resample ``source`` onto the pixel grid of ``target``.

    Parameters
    ----------
    transform : `~astroalign_nd.transforms.LinearTransform2D`, model or matrix
        The source-to-target transform (as `~astroalign_nd.find_transform`
        returns it).  Any 2-in/2-out astropy model, a scikit-image
        transform or a 3x3 matrix works too.  A non-linear one (projective,
        polynomial, compound...) needs an ``inverse`` and is resampled
        through its coordinate map (see `~astroalign_nd.resample.resample`);
        ``method='exact'`` takes affine transforms only.
    source : array-like, `~astropy.nddata.NDData`, HDU, path or tuple
        The image to resample (2-D, or a colour cube, channels last or
        first: the output keeps the source's layout).  A FITS
        path is read as `~astropy.nddata.CCDData.read` reads it (``MASK``,
        ``UNCERT``, ``FLAGS`` extensions, unit from ``BUNIT``); an
        ``(array, header)`` or ``(array, WCS)`` tuple as reproject takes it.
    target : array-like, `~astropy.nddata.NDData`, HDU, path or tuple
        Defines the output grid (its shape and WCS); an ``(ny, nx)`` tuple
        gives just the shape.
    order : {'nearest-neighbor', 'bilinear', 'biquadratic', 'bicubic'} or int, optional
        Interpolation, named as in reproject and ccdproc.  The default,
        'bilinear' (also reproject's and ccdproc's), is the fastest kernel
        that keeps fluxes in apertures; 'bicubic' (Keys' a=-0.5 cubic
        convolution, close to astroalign's order-3 warp) smooths the PSF
        less and costs about 3-4 times as much.
    conserve_flux : bool, optional
        False (default) keeps surface brightness (counts per pixel); True
        scales by the inverse Jacobian so that a star's total counts are
        kept when the pixel scales differ.
    fill_value : float, optional
        Value of masked output pixels (default NaN).
    method : {'interpolate', 'exact'}, optional
        'exact' uses `reproject.reproject_exact` (flux-conserving
        polygon overlap; slower).
    unit : `~astropy.units.Unit` or str, optional
        Unit of a source that has none (no ``BUNIT``, a bare array); the
        default is ``adu``.
    parallel : bool, optional
        Use both cores of the compiled kernel.
    quality : dict, optional
        Fit figures (from `~astroalign_nd.find_transform`'s
        ``transform.meta['quality']``) to record in the header; taken from
        the transform's meta when not given.
    hdu : int or str, optional
        The HDU to read from FITS paths and HDULists (index or extension
        name); by default the first one with image data.
    add_keyword : bool, optional
        Record the registration in the header (default True): the
        transform and fit keywords and HISTORY cards of
        `~astroalign_nd.io.add_provenance`.  False leaves the source's
        header as it was (without its celestial WCS cards).
    target_name : str, optional
        How the HISTORY card names the output grid ("registered a.fits onto
        the pixel grid of <target_name>"); by default the target's file
        name, or its shape when ``target`` is an ``(ny, nx)`` tuple.

    Returns
    -------
    registered : `~astropy.nddata.CCDData`
        A new object; the inputs are not modified.  After a non-linear
        transform the source's WCS is not carried (the output has the
        target's, or none), and the header records the transform when the
        model can be written there (otherwise HISTORY only: save the model
        with ASDF).

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.nddata import CCDData
    >>> from astroalign_nd.resample import apply_transform
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=20.0,
    ...                      translation=(4.0, -3.0), seed=1)
    >>> source = CCDData(pair.source, unit="adu")
    >>> registered = apply_transform(pair.transform, source, pair.target.shape)
    >>> registered.shape, registered.unit, registered.header["AATTYPE"]
    ((256, 256), Unit("adu"), 'similarity')
    >>> bool(registered.mask.any())  # target pixels the source does not cover
    True

    The brightest star now peaks where it is in the target frame:

    >>> star = pair.matched_stars()[0]
    >>> x, y = int(round(star["x_target"])), int(round(star["y_target"]))
    >>> box = registered.data[y - 3:y + 4, x - 3:x + 4]
    >>> iy, ix = np.unravel_index(np.argmax(box), box.shape)
    >>> bool(abs(x - 3 + ix - star["x_target"]) <= 1 and abs(y - 3 + iy - star["y_target"]) <= 1)
    True
    """
    if unexpected:
        raise TypeError(
            f"apply_transform got unexpected keyword argument(s) {sorted(unexpected)}; it "
            f"accepts {_ACCEPTED}.{astroalign_advice(unexpected)}")
    ResampleConfig(order=order, method=method)  # checks the order and the method
    if quality is None and isinstance(getattr(transform, "meta", None), dict):
        quality = transform.meta.get("quality")
    quality = check_quality(quality)  # before the work, not after it
    src = parse_input(source, "source", hdu=hdu, unit=unit)
    if src.is_catalog:
        raise TypeError("source is a catalog; apply_transform needs an image to resample.")
    m = _source_to_target(transform, np.shape(src.data)[:2])
    if method == "exact" and isinstance(m, _CoordinateMap):
        _parse_matrix(m, "resample_exact")  # raises: say what to use instead
    shape_out, dst = _target_grid(target, hdu)
    variance, out_kind = _source_variance(src, method)
    variance, kind, bad_unc = _usable_variance(variance, out_kind)
    if method == "exact":
        out, var_out, mask_out = resample_exact(src.data, m, shape_out, variance=variance,
                                                mask=src.mask, fill_value=fill_value,
                                                conserve_flux=conserve_flux)
        order_name = "exact (reproject)"
    else:
        out, var_out, mask_out = resample(src.data, m, shape_out, order=order,
                                          variance=variance, mask=src.mask,
                                          fill_value=fill_value, conserve_flux=conserve_flux,
                                          parallel=parallel, _variance_kind=kind,
                                          _output_kind=out_kind)
        order_name = {v: k for k, v in ORDERS.items()}[order_index(order)]
    if bad_unc is not None:
        _blank_uncertainty(var_out, mask_out, bad_unc, m, shape_out, method, order, parallel)

    out_unit = src.unit if src.unit is not None else u.Unit(unit if unit is not None else "adu")
    uncertainty = None
    if var_out is not None:
        uncertainty = _uncertainty_like(src.uncertainty, var_out, out_unit,
                                        converted=method != "exact")
    if target_name is None:  # a shape tuple: its size
        target_name = dst.name if dst is not None else f"a {shape_out[1]}x{shape_out[0]} grid"
    header = _output_header(src, dst, transform, m, quality, add_keyword, target_name,
                            order=order_name, conserve_flux=conserve_flux)
    full_mask = mask_out if out.ndim == 2 else np.broadcast_to(
        mask_out[..., None], out.shape).copy()
    flags = None if src.flags is None else _resample_flags(src.flags, m, shape_out)
    if src.channels_first:  # written back in the caller's layout, (nchan, ny, nx)
        out, full_mask, flags, uncertainty = _channels_first(out, full_mask, flags,
                                                             uncertainty)
    # The target's WCS, else the source's carried onto the target grid (a non-linear map
    # cannot be carried into a WCS here: the output has none).
    wcs = None
    if dst is not None and dst.wcs is not None:
        wcs = dst.wcs.deepcopy()
    elif src.wcs is not None and not isinstance(m, _CoordinateMap):
        wcs = _carry_wcs(src.wcs, m, shape_out)
    return CCDData(out, unit=out_unit, mask=full_mask, uncertainty=uncertainty, meta=header,
                   wcs=wcs, flags=flags)


def _channels_first(data, mask, flags, uncertainty):
    """The resampled planes of a channels-first input, back in its layout (contiguous)."""
    def first(a):
        return a if a is None or np.ndim(a) != 3 else np.ascontiguousarray(np.moveaxis(a, -1, 0))

    if uncertainty is not None:
        uncertainty = type(uncertainty)(first(uncertainty.array), unit=uncertainty.unit,
                                        copy=False)
    flags = first(flags) if isinstance(flags, np.ndarray) else flags
    return first(data), first(mask), flags, uncertainty
