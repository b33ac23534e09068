# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Resampling of data, mask and variance through a transform."""

from dataclasses import dataclass
import numpy as np
from .._kernels import compiled_kernels, run_split
from .coordinate_map import _CoordinateMap, _inverse_coefficients, _parse_matrix, _resample_map
from .interpolation import _resample_numpy
from .options import order_index

__all__ = ['resample', 'working_dtype']

# Output rows per thread, at least: below ~256x256 output pixels one thread does
# it all (waking a second one costs more than the work).
_MIN_PIXELS_PER_THREAD = 1 << 15


def _parse_shape_out(shape_out, nchan):
    try:
        shape = tuple(int(s) for s in shape_out)
        if any(s != t for s, t in zip(shape, shape_out)):
            raise ValueError
    except (TypeError, ValueError):
        raise TypeError(
            f"shape_out must be a tuple of integers (ny, nx); got {shape_out!r}."
        ) from None
    if len(shape) == 3 and nchan is not None and shape[2] == nchan:
        shape = shape[:2]
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(
            f"shape_out must be the (ny, nx) shape of the target image; got {shape_out!r}."
        )
    return shape


def working_dtype(dtype):
    """
    The type an image of ``dtype`` is resampled (and returned) in.

    float64 (and longer floats) stay float64; everything else (integers of
    any size, booleans, float16, float32, either byte order) runs in
    float32: a resampled value is no longer an integer, float32 holds every
    16-bit value exactly and keeps 7 significant digits (far below any
    pixel's noise), and the output is half the size of float64.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.resample.core import working_dtype
    >>> working_dtype(np.int16), working_dtype(">f4"), working_dtype(np.float64)
    (<class 'numpy.float32'>, <class 'numpy.float32'>, <class 'numpy.float64'>)
    """
    dtype = np.dtype(dtype)
    return np.float64 if dtype.kind == "f" and dtype.itemsize >= 8 else np.float32


def _prepare(data, variance, mask, shape_out, keep_var_dtype=False):
    """
    Check the inputs.

    Returns channel-first contiguous ``(nchan, ny, nx)`` data and variance (the
    kernels work on one C-contiguous 2-D channel at a time), the 2-D bad-pixel
    mask, the output shape, whether the input was multichannel and the dtype.
    """
    if isinstance(data, np.ma.MaskedArray):
        mask = np.ma.getmaskarray(data) if mask is None else (
            np.asarray(mask, bool) | np.ma.getmaskarray(data)
        )
        data = data.data
    arr = np.asarray(data)
    if arr.dtype.kind not in "biuf":
        raise TypeError(
            f"data must be a real numeric array; got dtype {arr.dtype}. Convert it, "
            "e.g. np.asarray(data, dtype=float)."
        )
    if arr.ndim not in (2, 3):
        raise ValueError(
            "data must be a 2-D image (ny, nx) or a channels-last 3-D array "
            f"(ny, nx, nchan); got an array of shape {arr.shape}."
        )
    if arr.size == 0:
        # (The compiled kernels index the first pixel: there must be one.)
        raise ValueError(f"data is empty (shape {arr.shape}); pass an image with pixels.")
    dtype = working_dtype(arr.dtype)
    multichannel = arr.ndim == 3

    def channels_first(a, keep_dtype=False):
        return np.ascontiguousarray(np.moveaxis(a, -1, 0) if multichannel else a[None],
                                    dtype=None if keep_dtype else dtype)

    data_cf = channels_first(arr)
    var_cf = None
    if variance is not None:
        var = np.asarray(variance)
        if multichannel and var.shape == arr.shape[:2]:
            var = np.broadcast_to(var[..., None], arr.shape)  # same variance per channel
        if var.shape != arr.shape:
            raise ValueError(
                f"variance must have the same shape as data {arr.shape}; got {var.shape}."
            )
        # (A standard deviation or inverse variance keeps its type: it is
        # converted band by band, see `resample`.)
        var_cf = channels_first(var, keep_var_dtype and var.dtype.kind in "biuf")
    bad = None
    if mask is not None:
        mk = np.asarray(mask)
        if mk.shape == arr.shape and multichannel:
            mk = mk.any(axis=-1)  # one mask for all channels
        if mk.shape != arr.shape[:2]:
            raise ValueError(
                f"mask must have the image shape {arr.shape[:2]} (True = bad pixel); "
                f"got {mk.shape}."
            )
        bad = np.ascontiguousarray(mk, dtype=bool)
    shape = _parse_shape_out(shape_out, arr.shape[2] if multichannel else None)
    return data_cf, var_cf, bad, shape, multichannel, dtype


def _parse_fill(fill_value):
    try:
        return float(fill_value)
    except (TypeError, ValueError):
        raise TypeError(
            f"fill_value must be a number (e.g. np.nan or 0); got {fill_value!r}."
        ) from None


#: How `resample` reads its ``variance`` plane (the compiled kernels' ``var_kind``).
_VARIANCE_KINDS = {"variance": 0, "stddev": 1, "inverse": 2}


def _run_affine(kernels, data, var, has_var, kind, okind, bad8, has_mask, coeffs, order, fill, sd,
                sv, out, out_var, mask, rows_per_thread, parallel, start, n):
    """Output rows ``start:start + n`` of one channel, on the compiled affine ``kernels``."""
    if order == 1:
        kernel, extra = kernels.bilinear_rows, (fill, sd, sv)
    else:
        kernel, extra = kernels.resample_rows, (order, fill, sd, sv)
    run_split(kernel, n, (data, var, has_var, kind, okind, bad8, has_mask, coeffs) + extra
              + (out, out_var, mask.view(np.uint8)),
              min_per_thread=rows_per_thread, parallel=parallel, start=start)


# Output pixels per band when working planes are made band by band (see `resample`).
_BAND_PIXELS = 1 << 22


def _to_variance(arr, kind, dtype, out=None):
    """Variance from a standard deviation ('stddev'), inverse variance ('inverse') or itself."""
    if kind == "variance":
        return np.asarray(arr, dtype)
    if out is None:
        out = np.empty(np.shape(arr), dtype)
    # Computed in the input's own type, then stored as ``dtype`` (as
    # astropy's represent_as followed by a cast would).
    if kind == "stddev":
        return np.square(arr, out=out, casting="unsafe")
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.divide(1.0, arr, out=out, casting="unsafe")


def _bands(coeffs, shape_out, ny, order):
    """
    Bands of output rows ``(r0, r1)`` with the source rows ``(s0, s1)`` they read.

    The source rows cover every tap of every output pixel in the band (the
    affine map's extremes are at the band's corners) with a margin, so that
    the kernel, given only those rows, finds each tap where the full image
    has it; where the band reaches the image's edge it stops there, as the
    image does.
    """
    ny_out, nx_out = shape_out
    step = max(16, _BAND_PIXELS // max(nx_out, 1))
    margin = 4 + order
    out = []
    for r0 in range(0, ny_out, step):
        r1 = min(r0 + step, ny_out)
        v = [coeffs[3] * x + coeffs[4] * y + coeffs[5]
             for x in (0.0, nx_out - 1.0) for y in (float(r0), r1 - 1.0)]
        s0 = min(max(int(np.floor(min(v))) - margin, 0), ny - 1)
        s1 = max(min(int(np.ceil(max(v))) + margin + 1, ny), s0 + 1)
        out.append((r0, r1, s0, s1))
    return out


@dataclass
class _Job:
    """
    The working planes of one `resample` call and what the kernels are told.

    ``data`` and ``var`` are channels first; ``kind`` and ``okind`` the
    kernels' ``var_kind`` of the variance plane read and written; ``bad8``
    the mask as bytes (a dummy when ``has_mask`` is False); ``dummy`` the
    tiny typed array the compiled kernels take for an absent plane;
    ``kernels`` the compiled module, None on the NumPy path
    (``astroalign_nd.conf.use_compiled = False``, or not built).
    """

    data: np.ndarray
    var: np.ndarray | None
    variance_kind: str
    kind: int
    okind: int
    bad8: np.ndarray
    has_mask: bool
    kernels: object
    convert: bool
    order: int
    fill: float
    sd: float
    parallel: bool
    out: np.ndarray
    out_var: np.ndarray | None
    masks: np.ndarray
    dummy: np.ndarray
    rows_per_thread: int

    @classmethod
    def make(cls, data_cf, var_cf, bad, shape, dtype, variance_kind, output_kind, is_map, order,
             fill, sd, parallel):
        """The planes and flags, with what the chosen kernels need converted first."""
        nc = data_cf.shape[0]
        has_var = var_cf is not None
        if bad is not None and not bad.any():
            bad = None
        kind = _VARIANCE_KINDS[variance_kind] if has_var else 0
        # The variance output may be stored as a standard deviation or an inverse
        # variance (``_output_kind``, for apply_transform's uncertainty classes):
        # the kernels convert each pixel as they store it, saving a pass.
        okind = _VARIANCE_KINDS[output_kind] if has_var else 0
        kernels = compiled_kernels()  # (read once: the whole call takes one path)
        if kernels is None and (kind or bad is not None):
            # NumPy path: whole-frame working copies (it is the slow path anyway).
            if kind:
                var_cf = _to_variance(var_cf, variance_kind, dtype)
            if bad is not None:
                data_cf = np.where(bad, np.array(np.nan, dtype), data_cf)
            kind, bad = 0, None
        # The compiled kernel squares a standard deviation or inverts an inverse
        # variance tap by tap, and reads the mask, so that no working copy of a
        # plane is made -- unless the uncertainty's type differs from the data's
        # (then the variance is made in the data's type: band by band on the
        # affine path, once on the coordinate-map path).
        convert = has_var and var_cf.dtype != dtype
        if convert and is_map:
            var_cf, kind, convert = _to_variance(var_cf, variance_kind, dtype), 0, False
        # The compiled kernel needs typed arrays even for absent inputs/outputs: tiny dummies.
        return cls(data=data_cf, var=var_cf, variance_kind=variance_kind, kind=kind,
                   okind=okind,
                   bad8=np.empty((1, 1), np.uint8) if bad is None else bad.view(np.uint8),
                   has_mask=bad is not None, kernels=kernels, convert=convert, order=order,
                   fill=fill, sd=sd, parallel=parallel,
                   out=np.empty((nc,) + shape, dtype=dtype),
                   out_var=np.empty((nc,) + shape, dtype=dtype) if has_var else None,
                   masks=np.empty((nc,) + shape, dtype=bool), dummy=np.empty((1, 1), dtype),
                   rows_per_thread=max(1, _MIN_PIXELS_PER_THREAD // shape[1]))

    @property
    def compiled(self):
        return self.kernels is not None

    @property
    def has_var(self):
        return self.var is not None

    def var_plane(self, c):
        """Channel ``c`` of the variance, or the dummy."""
        return self.var[c] if self.has_var else self.dummy

    def finish(self, multichannel):
        """``(data, variance, mask)`` in the caller's layout, the mask shared by all channels."""
        out, out_var, has_var = self.out, self.out_var, self.has_var
        if has_var and self.okind and not self.compiled:
            # In place: the variance to a standard deviation (1) or inverse variance (2).
            with np.errstate(divide="ignore", invalid="ignore"):
                if self.okind == 1:
                    np.sqrt(out_var, out=out_var)
                else:
                    np.divide(1.0, out_var, out=out_var)
        mask_out = self.masks[0]
        if out.shape[0] > 1:
            # The mask applies to all channels: a pixel bad in one is bad in all.
            mask_out = self.masks.any(axis=0)
            out[:, mask_out] = self.fill
            if has_var:
                out_var[:, mask_out] = 0.0 if self.okind == 2 else np.inf
        if multichannel:
            out = np.ascontiguousarray(np.moveaxis(out, 0, -1))
            out_var = None if out_var is None else np.ascontiguousarray(
                np.moveaxis(out_var, 0, -1))
        else:
            out = out[0]
            out_var = None if out_var is None else out_var[0]
        return out, out_var, mask_out


def _resample_affine_bands(job, coeffs):
    """Affine, compiled, with the variance converted into the data's type band by band."""
    # Working variance (a standard deviation squared, or an inverse variance
    # inverted, into the data's type) one band of output rows at a time, for
    # the source rows that band reads: a scratch of a fraction of a frame
    # instead of a whole-frame copy.
    bands = _bands(coeffs, job.out.shape[1:], job.data.shape[1], job.order)
    scratch = np.empty((max(s1 - s0 for _, _, s0, s1 in bands), job.data.shape[2]),
                       job.out.dtype)
    sd = job.sd
    for c in range(job.out.shape[0]):
        for r0, r1, s0, s1 in bands:
            v = _to_variance(job.var[c, s0:s1], job.variance_kind, job.out.dtype,
                             out=scratch[:s1 - s0])
            band_coeffs = coeffs.copy()
            band_coeffs[5] -= s0  # source row s0 is row 0 of the band
            _run_affine(job.kernels, job.data[c, s0:s1], v, True, 0, job.okind,
                        job.bad8[s0:s1] if job.has_mask else job.bad8, job.has_mask,
                        band_coeffs, job.order, job.fill, sd, sd * sd, job.out[c],
                        job.out_var[c], job.masks[c], job.rows_per_thread, job.parallel, r0,
                        r1 - r0)


def _resample_affine(job, coeffs):
    """Affine: each channel's rows on the compiled kernels (or the NumPy ones)."""
    sd = job.sd
    for c in range(job.out.shape[0]):
        outs = (job.out[c], job.out_var[c] if job.has_var else job.dummy)
        if not job.compiled:
            args = (job.data[c], job.var_plane(c), job.has_var, coeffs)
            _resample_numpy(*args, job.fill, sd, sd * sd, *outs, job.masks[c], order=job.order)
            continue
        _run_affine(job.kernels, job.data[c], job.var_plane(c), job.has_var, job.kind, job.okind,
                    job.bad8,
                    job.has_mask, coeffs, job.order, job.fill, sd, sd * sd, *outs, job.masks[c],
                    job.rows_per_thread, job.parallel, 0, job.out.shape[1])

# -- public API ------------------------------------------------------------------


def resample(data, matrix, shape_out, *, order="bilinear", variance=None, mask=None,
             fill_value=np.nan, conserve_flux=False, parallel=True, _variance_kind="variance",
             _output_kind="variance"):
    """
    Resample an image onto the target pixel grid, with variance and mask.

    Parameters
    ----------
    data : array-like, shape (ny, nx) or (ny, nx, nchan)
        The source image; 3-D input is channels-last (e.g. RGB) and every
        channel is resampled with the same weights.  float64 data is
        processed and returned as float64, anything else (integers,
        float32) as float32 (see `working_dtype`).  A
        `numpy.ma.MaskedArray` contributes its mask to ``mask``.
    matrix : (3, 3) or (2, 3) array-like, or transform
        The *source -> target* pixel transform: a homogeneous matrix, e.g.
        ``transform.matrix`` of an `astroalign_nd.transforms` model, or the
        model itself, a scikit-image transform, or any astropy model with 2
        inputs and 2 outputs.  An affine transform must be invertible; a
        non-linear one (a projective matrix or model, a polynomial model, a
        compound model...) is resampled through its coordinate map and
        needs an ``inverse`` (an approximate one is polished by Newton
        steps on the model; see the module docstring).
    shape_out : tuple of int
        ``(ny, nx)`` of the target grid.
    order : {'nearest-neighbor', 'bilinear', 'biquadratic', 'bicubic'} or int, optional
        Interpolation kernel, or its order 0-3.  See the module docstring
        for the exact kernels.  Default ``'bilinear'``.
    variance : array-like, optional
        Variance of ``data``, same shape (for multichannel data an
        ``(ny, nx)`` variance applies to every channel).  Propagated as
        ``sum(w**2 * var)``; see Notes.
    mask : array-like of bool, shape (ny, nx), optional
        True for bad source pixels; applies to every channel (a 3-D mask is
        reduced with ``any`` over channels).  NaN/inf pixels of ``data`` or
        ``variance`` are treated as masked without being listed here.
    fill_value : float, optional
        Value of masked output pixels in ``data_out`` (default NaN).
    conserve_flux : bool, optional
        If True, scale the result by ``1 / |det A|`` (``A`` the linear part
        of ``matrix``; for a non-linear transform, the local Jacobian
        determinant of its inverse) so that total counts, not surface
        brightness, are preserved; variance is scaled by the square.
        Default False.
    parallel : bool, optional
        Split the output rows over threads (default True): as many as the
        CPUs this process may use, or ``ASTROALIGN_ND_NUM_THREADS`` if set in
        the environment; small outputs use one.  The result does not depend
        on it.

    Returns
    -------
    data_out : ndarray, shape ``shape_out`` (+ ``(nchan,)``)
        The resampled image.
    variance_out : ndarray or None
        The propagated variance (``+inf`` where masked), or None if no
        ``variance`` was given.
    mask_out : ndarray of bool, shape ``shape_out``
        True where the output is bad: outside the source footprint (the
        whole kernel support must be inside the image), or using a masked,
        NaN or inf source pixel with nonzero weight.

    Raises
    ------
    ValueError
        For a matrix that is not 3x3/2x3 or singular, a non-linear model
        without an ``inverse``, data that is not 2-D or 3-D, an unknown
        ``order``, or mismatched shapes.
    TypeError
        For non-numeric data, matrix, shape_out or fill_value.

    Notes
    -----
    The variance formula is exact for each output pixel when the input
    pixels are independent, but resampling correlates neighbouring output
    pixels and that covariance is not returned (summing ``variance_out``
    over an aperture underestimates the variance of the sum).

    The computation runs in a compiled (Cython) kernel that produces data,
    variance and mask in one pass over the output, reading the mask and the
    uncertainty plane as they are (no working copies); a NumPy implementation
    of the same kernels gives the same results, more slowly, if the
    compiled module is missing.  Threads never share an output pixel, so
    the result is deterministic and the same for any number of threads.
    `resample` may be called from several threads at once.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.resample import resample
    >>> image = np.arange(16.0).reshape(4, 4)
    >>> shift = np.array([[1.0, 0, 1], [0, 1, 0], [0, 0, 1]])  # one pixel along +x
    >>> out, var, bad = resample(image, shift, (4, 4), order="bicubic")
    >>> out[1]
    array([nan,  4.,  5.,  6.])
    >>> bad[1]
    array([ True, False, False, False])
    """
    order = order_index(order)
    m = _parse_matrix(matrix, shape_in=np.shape(data)[:2])
    cmap = m if isinstance(m, _CoordinateMap) else None
    if _variance_kind not in _VARIANCE_KINDS or _output_kind not in _VARIANCE_KINDS:
        raise ValueError(f"unknown _variance_kind {_variance_kind!r} or _output_kind "
                         f"{_output_kind!r}")
    data_cf, var_cf, bad, shape, multichannel, dtype = _prepare(
        data, variance, mask, shape_out, keep_var_dtype=_variance_kind != "variance")
    fill = _parse_fill(fill_value)
    if cmap is None:
        coeffs, det = _inverse_coefficients(m)
        sd = 1.0 / det if conserve_flux else 1.0
    else:
        sd = 1.0  # the flux factor is the map's local Jacobian, pixel by pixel
    job = _Job.make(data_cf, var_cf, bad, shape, dtype, _variance_kind, _output_kind,
                    cmap is not None, order, fill, sd, parallel)
    if cmap is not None:
        _resample_map(job, cmap, conserve_flux)
    elif job.compiled and job.convert:
        _resample_affine_bands(job, coeffs)
    else:
        _resample_affine(job, coeffs)
    return job.finish(multichannel)
