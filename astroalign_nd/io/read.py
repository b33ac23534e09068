# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The ONE input parser: everything the public functions accept becomes a
`ParsedInput`.

Accepted: 2-D ndarrays and colour cubes (channels last, ``(ny, nx, 3)``,
or channels first, ``(3, ny, nx)``, as stacked colour FITS files hold them;
`is_channels_first`), numpy masked arrays,
`~astropy.nddata.NDData` / `~astropy.nddata.CCDData`, FITS HDUs and
HDULists, ``(array, header)`` and ``(array, WCS)`` tuples (as reproject
takes them), file paths (FITS read as `~astropy.nddata.CCDData.read` reads
them: data, ``MASK``, ``UNCERT`` and ``FLAGS``, unit from ``BUNIT``;
JPEG/PNG/TIFF through scikit-image, rows flipped so that row 0 is the
bottom row as in FITS, `bottom_up`), and catalogs: an
`~astropy.table.Table` with x/y columns or an (N, 2) array of positions.
The caller's objects are never modified: arrays are only read, and
anything derived is a new array.

`batch_frames` turns the ``sources`` of a batch (a list, a generator, an
`~ccdproc.ImageFileCollection`) into ``(frame, label)`` pairs: a list when
the sources are already in memory (or are a collection's files), else an
iterator taken one frame at a time, so that a batch never holds a
generator's frames in memory all at once.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.nddata import FlagCollection, NDData
from astropy.table import Table
from astropy.wcs import WCS, FITSFixedWarning

__all__ = ["ParsedInput", "parse_input", "image_and_mask", "iter_frames", "batch_frames",
           "bottom_up", "FLIP_HISTORY", "is_channels_first", "position_columns",
           "read_rows", "image_shape_unit"]

_X_NAMES = ("x", "x_centroid", "xcentroid", "x_0", "x_fit", "xcen", "X_IMAGE")
_Y_NAMES = ("y", "y_centroid", "ycentroid", "y_0", "y_fit", "ycen", "Y_IMAGE")
_IMAGE_EXT = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".gif")


@dataclass
class ParsedInput:
    """
    A common form of every accepted input.

    Attributes
    ----------
    data : ndarray or None
        Image data, 2-D or (ny, nx, nchan); None for catalogs.
    mask : bool ndarray or None
        The caller's mask (True for bad pixels), shape (ny, nx).  Non-finite
        pixels are not included: every stage treats them as masked itself.
    uncertainty : `~astropy.nddata.NDUncertainty` or None
    unit : `~astropy.units.Unit` or None
    flags : ndarray, `~astropy.nddata.FlagCollection` or None
        Per-pixel flags (resampled by nearest neighbour).
    wcs : `~astropy.wcs.WCS` or None
    meta : dict-like
        A copy of the header/meta.
    points : (N, 2) ndarray or None
        Catalog positions (brightest first) for catalog input.
    kind : str
        'array', 'masked', 'nddata', 'fits', 'tuple', 'image-file' or 'catalog'.
    name : str
        A short description for messages and history.
    channels_first : bool
        The input was a channels-first cube ``(nchan, ny, nx)``; ``data``
        holds it channels last, as every stage takes it, and the output is
        written back channels first.
    """

    data: object = None
    mask: object = None
    uncertainty: object = None
    unit: object = None
    flags: object = None
    wcs: object = None
    meta: dict = field(default_factory=dict)
    points: object = None
    kind: str = "array"
    name: str = "array"
    channels_first: bool = False

    @property
    def is_catalog(self):
        return self.points is not None

    @property
    def shape(self):
        """(ny, nx) of the image, or None for catalogs."""
        return None if self.data is None else self.data.shape[:2]

    @property
    def detection_image(self):
        """The 2-D image used for detection (channel mean for multichannel)."""
        if self.data.ndim == 3:
            return self.data.mean(axis=2, dtype=np.float32)
        return self.data


def is_channels_first(arr):
    """
    True for a channels-first cube, ``(nchan, ny, nx)`` with 1 to 4 channels.

    Stacked colour FITS files hold their planes first (``NAXIS3 = 3``);
    image files and most arrays hold them last, ``(ny, nx, nchan)``.  A
    cube counts as channels-first when its first axis has 1 to 4 planes
    and its last axis is longer than 4 (a channels-last image has 1 to 4
    there).

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.io.read import is_channels_first
    >>> is_channels_first(np.zeros((3, 50, 60))), is_channels_first(np.zeros((50, 60, 3)))
    (True, False)
    """
    shape = np.shape(arr)
    return len(shape) == 3 and shape[0] in (1, 2, 3, 4) and shape[2] > 4


def _plane_shape(arr):
    """``(ny, nx)`` of an image in either layout."""
    return tuple(arr.shape[1:]) if is_channels_first(arr) else tuple(arr.shape[:2])


def _check_image_array(arr, name):
    if arr.dtype.kind not in "biuf":
        raise TypeError(
            f"{name} must hold numbers; got dtype {arr.dtype}. Pass a numeric image, an "
            "NDData/CCDData, a FITS path, or a catalog (Table with x/y columns or (N, 2) array)."
        )
    if arr.ndim == 3 and arr.shape[2] in (1, 2, 3, 4) and min(arr.shape[:2]) > 4:
        pass  # channels last (RGB, RGBA...)
    elif is_channels_first(arr) and min(arr.shape[1:]) > 4:
        pass  # channels first, as stacked colour FITS files hold them
    elif arr.ndim != 2:
        raise ValueError(
            f"{name} must be a 2-D image, a colour image (ny, nx, nchan) or (nchan, ny, nx) "
            f"with 1 to 4 channels, or an (N, 2) array of positions; got shape {arr.shape}."
        )
    if min(_plane_shape(arr)) < 8:
        raise ValueError(
            f"{name} is too small to find stars in (shape {arr.shape}); images need at least "
            "8x8 pixels. For a list of positions pass an (N, 2) array."
        )
    return arr


def _user_mask(data, mask):
    """
    The caller's mask as a 2-D bool array (None if there is none).

    Non-finite pixels are not added here: detection and resampling find
    them in the same pass that reads the data, which saves a full-frame
    pass over large images.
    """
    if mask is None or np.ndim(mask) == 0:
        return None if mask is None or not bool(mask) else np.ones(_plane_shape(data), bool)
    m = np.asarray(mask, dtype=bool)
    if m.ndim == 3:  # one mask for every channel: bad in one is bad in all
        m = m.any(axis=0 if is_channels_first(data) else 2)
    if m.shape != _plane_shape(data):
        raise ValueError(
            f"mask shape {np.shape(mask)} does not match the image shape {data.shape}."
        )
    return m if m.any() else None


def position_columns(table, name="catalog", columns=None):
    """
    The names of a table's x and y position columns.

    Parameters
    ----------
    table : `~astropy.table.Table`
    name : str
        Names the table in error messages.
    columns : (str, str), optional
        The caller's names; by default the first of ``x``, ``x_centroid``
        (photutils 3), ``xcentroid`` (older photutils), ``x_0``, ``x_fit``,
        ``xcen``, ``X_IMAGE`` (and the same for y), in any case.

    Raises
    ------
    ValueError
        If the columns are not in the table.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from astroalign_nd.io.read import position_columns
    >>> position_columns(Table(names=["id", "x_centroid", "y_centroid"]))
    ('x_centroid', 'y_centroid')
    """
    if columns is not None:
        if (isinstance(columns, str) or not hasattr(columns, "__len__") or len(columns) != 2
                or not all(isinstance(c, str) for c in columns)):
            raise TypeError(f"the columns of {name} must be two column names (x, y); got "
                            f"{columns!r}.")
        missing = [c for c in columns if c not in table.colnames]
        if missing:
            raise ValueError(f"{name} has no column(s) {missing}; it has {table.colnames}.")
        return tuple(columns)
    cols = {c.lower(): c for c in table.colnames}
    xc = next((cols[n.lower()] for n in _X_NAMES if n.lower() in cols), None)
    yc = next((cols[n.lower()] for n in _Y_NAMES if n.lower() in cols), None)
    if xc is None or yc is None:
        raise ValueError(
            f"{name} is a Table without position columns; it needs columns named 'x' and "
            f"'y' (or one of {_X_NAMES}), or name them; it has {table.colnames}."
        )
    return xc, yc


def _catalog_points(obj, name):
    """(N, 2) finite positions; masked entries (Table or masked array) are left out."""
    if isinstance(obj, Table):
        xc, yc = position_columns(obj, name)
        masked = np.ma.getmaskarray(obj[xc]) | np.ma.getmaskarray(obj[yc])
        pts = np.column_stack([np.ma.getdata(obj[xc]).astype(float),
                               np.ma.getdata(obj[yc]).astype(float)])
    else:
        pts = np.asarray(np.ma.getdata(obj), dtype=float)
        masked = (np.ma.getmaskarray(obj).any(axis=1) if np.ma.isMaskedArray(obj)
                  else np.zeros(len(pts), bool))
    good = np.all(np.isfinite(pts), axis=1) & ~masked
    return pts[good].copy()


def _header_unit(header, name):
    """
    The unit of a header's BUNIT (None when absent), as CCDData.read parses it.

    A unit astropy does not know (``W/m^2-sr``) is kept as it is written,
    as an `~astropy.units.UnrecognizedUnit`: registration does not need it,
    and the output's BUNIT keeps it.
    """
    from astropy.nddata import CCDData

    value = header.get("BUNIT")
    if value is None or not str(value).strip():
        return None
    text = str(value).strip()
    if text.lower() == "adu":
        text = "adu"
    text = CCDData.known_invalid_fits_unit_strings.get(text, text)
    return u.Unit(text, parse_strict="silent")


def _header_wcs(header):
    """A celestial WCS from a header, or None (a broken WCS must not stop registration)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FITSFixedWarning)
            w = WCS(header)
    except (ValueError, KeyError, TypeError, MemoryError):
        # astropy.wcs raises WcsError (a ValueError) and its subclasses on
        # invalid keywords; KeyError/TypeError for malformed cards.
        return None
    return w if w.has_celestial else None


def _from_hdu(hdu, name, unit=None):
    data = hdu.data
    if data is None:
        raise ValueError(f"{name} has no image data.")
    header = hdu.header.copy()
    file_unit = _header_unit(header, name)
    # The HDU's data array belongs to the caller: work on a copy.
    arr = np.array(data)
    return ParsedInput(data=_check_image_array(arr, name), mask=None,
                       unit=file_unit if file_unit is not None else _as_unit(unit),
                       wcs=_header_wcs(header), meta=header, kind="fits", name=name)


def _add_extensions(p, hdul):
    """
    The MASK, UNCERT and FLAGS extensions of an in-memory HDUList, as
    `~astropy.nddata.CCDData.read` reads them from a file.
    """
    from astropy.nddata import InverseVariance, StdDevUncertainty, VarianceUncertainty

    names = {h.name for h in hdul}
    shape = _plane_shape(p.data)
    if "MASK" in names and np.shape(hdul["MASK"].data)[:2] == shape:
        p.mask = _user_mask(p.data, np.asarray(hdul["MASK"].data).astype(bool))
    if "UNCERT" in names and np.shape(hdul["UNCERT"].data) == p.data.shape:
        cls = {"StdDevUncertainty": StdDevUncertainty, "VarianceUncertainty": VarianceUncertainty,
               "InverseVariance": InverseVariance}.get(
            hdul["UNCERT"].header.get("UTYPE"), StdDevUncertainty)
        p.uncertainty = cls(np.array(hdul["UNCERT"].data))
    if "FLAGS" in names and _plane_shape(np.asarray(hdul["FLAGS"].data)) == shape:
        p.flags = np.array(hdul["FLAGS"].data)


def _as_unit(unit):
    if unit is None:
        return None
    try:
        return u.Unit(unit)
    except (ValueError, TypeError):
        # astropy's own message advises u.def_unit: a new unit is seldom what was meant.
        raise ValueError(f"unit must be a unit astropy knows, such as 'adu', 'electron' or "
                         f"'photon'; got {unit!r}.") from None


def _image_hdu_index(hdul, hdu, name, where):
    """Index of the HDU to read: ``hdu`` if given, else the first one with image data."""
    if hdu is not None:
        try:
            index = hdul.index_of(hdu)
            h = hdul[index]
        except (KeyError, IndexError):
            names = [h.name for h in hdul]
            raise ValueError(
                f"{name}: {where} has no HDU {hdu!r}; it has {len(hdul)} HDUs named "
                f"{names}. Pass hdu= as an index or an extension name."
            ) from None
        if not getattr(h, "is_image", False) or h.data is None or np.ndim(h.data) < 2:
            raise ValueError(
                f"{name}: HDU {hdu!r} of {where} holds no image (it is a "
                f"{type(h).__name__} with data of shape {np.shape(h.data)})."
            )
        return index
    for index, h in enumerate(hdul):
        if getattr(h, "is_image", False) and h.data is not None and np.ndim(h.data) >= 2:
            return index
    raise ValueError(f"{name}: {where} has no image HDU.")


def _read_fits(path, name, hdu, unit):
    """Read a FITS file as `~astropy.nddata.CCDData.read` does, HDU chosen by ``hdu``."""
    from astropy.nddata import CCDData

    try:
        # Our own file object: fits.open leaves its file open when a damaged
        # header (e.g. NAXIS = 3 without NAXIS3) fails while it is read.
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with open(path, "rb") as fh, fits.open(fh) as hdul:
                index = _image_hdu_index(hdul, hdu, name, repr(path))
                header = hdul[index].header
                primary = hdul[0].header.copy() if index != 0 and hdu is None else None
                file_unit = _header_unit(header, name)
                ext_names = {h.name for h in hdul}
        # astropy's "may have been truncated" is an error; the other warnings pass on.
        for w in caught:
            if "truncated" in str(w.message):
                raise ValueError(
                    f"{name}: could not read the data of {path!r}: the file is truncated "
                    f"({w.message}). Copy the file again from its source, or pass another "
                    "frame.")
        for w in caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    except TypeError as exc:  # numpy: "buffer is too small for requested array"
        raise ValueError(
            f"{name}: could not read the data of {path!r}: the file is truncated or its "
            f"header does not match its data ({exc}). Copy the file again from its source, "
            "or pass another frame.") from None
    except OSError as exc:
        raise ValueError(
            f"{name}: could not read {path!r} as FITS ({exc}). Pass a FITS, JPEG, PNG or TIFF "
            "file, an array, or an NDData/CCDData."
        ) from None
    has_flags = "FLAGS" in ext_names or any(n.startswith("FLAGS_") for n in ext_names)
    # CCDData needs a unit: a file without BUNIT gets the caller's (or adu),
    # but is reported as unit-less so that the output's default applies.
    if isinstance(file_unit, u.UnrecognizedUnit):
        read_unit = file_unit  # CCDData.read refuses it; given, it is kept as written
    else:
        read_unit = None if file_unit is not None else _as_unit("adu" if unit is None else unit)
    with warnings.catch_warnings():
        # Non-standard WCS keywords are fixed silently, not warned about per frame.
        warnings.simplefilter("ignore", FITSFixedWarning)
        # Read into memory, not memory-mapped: FITS data are big-endian, and a
        # map would be copied to native order by detection and again by the
        # resampling, while its pages also count in the resident memory; the
        # array read is ours, and is swapped to native order in place.
        ccd = CCDData.read(path, hdu=index, unit=read_unit,
                           hdu_flags="FLAGS" if has_flags else None, memmap=False)
    if primary is not None:
        # As CCDData.read does for an empty primary HDU: the extension's
        # header, completed by the primary's keywords.
        ccd.meta.extend(primary, unique=True)
    p = _from_nddata(ccd, name)
    p.data = _native_in_place(p.data)
    p.unit = file_unit if file_unit is not None else _as_unit(unit)
    p.kind = "fits"
    return p


def _native_in_place(arr):
    """
    ``arr`` in native byte order, swapped in place when it can be.

    Only for arrays this module read from a file itself (nobody else holds
    them).  The compiled kernels need native order; swapping in place
    avoids a second full copy of the frame.
    """
    if arr.dtype.isnative or arr.dtype.byteorder == "|":
        return arr
    if arr.flags.writeable and arr.flags.c_contiguous:
        arr.byteswap(inplace=True)
        return arr.view(arr.dtype.newbyteorder("="))
    return arr.astype(arr.dtype.newbyteorder("="))


#: The HISTORY card of an image read from a JPEG/PNG/TIFF file (see `bottom_up`).
FLIP_HISTORY = "astroalign_nd: image-file rows flipped, row 0 = bottom (as in FITS)"


def bottom_up(arr):
    """
    The rows of an image file's array in FITS order: row 0 at the bottom.

    JPEG, PNG, TIFF, BMP and GIF files store the top row first; FITS (and
    DS9, and ``imshow(origin='lower')``) put row 0 at the bottom.  Flipped
    once, here, so that an image file registers, plots and is written as
    it looks (a new C-contiguous array: the reader's is not kept).

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.io.read import bottom_up
    >>> bottom_up(np.array([[1, 2], [3, 4]]))
    array([[3, 4],
           [1, 2]])
    """
    return np.ascontiguousarray(arr[::-1])


def _read_path(path, name, hdu=None, unit=None):
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"{name}: file not found: {path!r}; check the path (it is "
                                "read relative to the current folder).")
    low = path.lower()
    if low.endswith(_IMAGE_EXT):
        from skimage.io import imread

        try:
            arr = np.asarray(imread(path))
        except Exception as exc:  # each image library fails in its own way
            raise ValueError(f"{name}: could not read {path!r} as an image "
                             f"({type(exc).__name__}: {exc}).") from None
        if arr.ndim == 3 and arr.shape[2] == 4:
            arr = arr[..., :3]  # drop alpha
        _check_image_array(arr, name)
        header = fits.Header()
        header["HISTORY"] = FLIP_HISTORY
        return ParsedInput(data=bottom_up(arr), mask=None, unit=_as_unit(unit),
                           meta=header, kind="image-file",
                           name=os.path.basename(path))
    try:
        p = _read_fits(path, name, hdu, unit)
    except (OSError, KeyError, IndexError, SyntaxError, fits.VerifyError) as exc:
        # A damaged header (e.g. NAXIS = 3 without NAXIS3) fails in astropy.
        raise ValueError(
            f"{name}: could not read {path!r} as FITS ({type(exc).__name__}: {exc}). Pass a "
            "FITS, JPEG, PNG or TIFF file, an array, or an NDData/CCDData."
        ) from None
    p.name = os.path.basename(path)
    return p


def _from_nddata(obj, name):
    arr = np.asarray(obj.data)
    _check_image_array(arr, name)
    meta = obj.meta.copy() if obj.meta is not None else {}
    unc = obj.uncertainty
    if unc is not None:
        # A new object (detached from the caller's NDData) on the same array:
        # the array is only read, and a copy costs a full plane.
        unc = unc.__class__(unc.array, unit=unc.unit, copy=False)
    flags = getattr(obj, "flags", None)
    if isinstance(flags, FlagCollection):
        copied = FlagCollection(shape=flags.shape)
        for key, value in flags.items():
            copied[key] = np.array(value)
        flags = copied
    elif flags is not None:
        flags = np.array(flags)
    return ParsedInput(
        data=arr, mask=_user_mask(arr, obj.mask), uncertainty=unc, unit=obj.unit, flags=flags,
        wcs=obj.wcs if getattr(obj.wcs, "has_celestial", False) else None,
        meta=meta, kind="nddata", name=type(obj).__name__)


def _is_header_tuple(obj):
    return (isinstance(obj, tuple) and len(obj) == 2
            and isinstance(obj[1], (fits.Header, WCS)))


def _from_tuple(obj, name, unit):
    """reproject's ``(array, header)`` and ``(array, WCS)`` forms."""
    data, desc = obj
    if isinstance(data, (NDData, str, os.PathLike, fits.HDUList, fits.PrimaryHDU,
                         fits.ImageHDU)):
        raise TypeError(
            f"{name}: the first element of an (array, header) tuple must be an array; got "
            f"{type(data).__name__}. Pass that object on its own."
        )
    if np.ma.isMaskedArray(data):
        arr, mask = np.asarray(np.ma.getdata(data)), np.ma.getmaskarray(data)
    else:
        arr, mask = np.asarray(data), None
    _check_image_array(arr, name)
    if isinstance(desc, fits.Header):
        meta = desc.copy()
        file_unit = _header_unit(meta, name)
        wcs = _header_wcs(meta)
    else:
        meta, file_unit = fits.Header(), None
        wcs = desc.deepcopy() if desc.has_celestial else None
    if wcs is not None and wcs.pixel_n_dim != 2:
        wcs = wcs.celestial if wcs.celestial.pixel_n_dim == 2 else None
    return ParsedInput(data=arr, mask=_user_mask(arr, mask),
                       unit=file_unit if file_unit is not None else _as_unit(unit),
                       wcs=wcs, meta=meta, kind="tuple", name="array")


def parse_input(obj: Any, name: str = "input", *, hdu: int | str | tuple | None = None,
                unit: Any = None) -> ParsedInput:
    """
    Turn any accepted input into a `ParsedInput`.

    Parameters
    ----------
    obj : object
        See the module docstring for what is accepted.
    name : str
        Used in error messages ('source', 'target').
    hdu : int, str or (str, int), optional
        The HDU of a FITS path or `~astropy.io.fits.HDUList` to read (an
        index or an extension name, as in `~astropy.nddata.CCDData.read`);
        by default the first HDU with image data.
    unit : `~astropy.units.Unit` or str, optional
        The unit of an input that has none (no ``BUNIT``, a bare array).

    Raises
    ------
    TypeError, ValueError
        With a message that says what was wrong and what to pass instead.
    """
    if isinstance(obj, ParsedInput):
        return obj
    if isinstance(getattr(obj, "_parsed", None), ParsedInput):  # a Reference
        return obj._parsed
    p = _parse(obj, name, hdu, unit)
    # The pixel arrays in native byte order (big-endian arrays are copied): every
    # computation then sees the same numbers whatever the caller's byte order (the
    # compiled kernels need native order, and the NumPy paths sum in a different order
    # on swapped arrays).  The caller's arrays are never changed.
    p.data = _native_copy(p.data)
    p.mask = _native_copy(p.mask)
    p.flags = _native_copy(p.flags)
    unc = p.uncertainty
    if unc is not None and isinstance(getattr(unc, "array", None), np.ndarray) \
            and not unc.array.dtype.isnative:
        p.uncertainty = unc = type(unc)(_native_copy(unc.array), unit=unc.unit, copy=False)
    if p.data is None or not is_channels_first(p.data):
        return p
    # A channels-first cube as every stage takes it: ``(ny, nx, nchan)`` views of its
    # data, uncertainty and flags, with ``channels_first`` set so that the output is
    # written back in the input's layout.
    p.data = np.moveaxis(p.data, 0, -1)
    if unc is not None and is_channels_first(getattr(unc, "array", None)):
        p.uncertainty = type(unc)(np.moveaxis(unc.array, 0, -1), unit=unc.unit, copy=False)
    if isinstance(p.flags, np.ndarray) and is_channels_first(p.flags):
        p.flags = np.moveaxis(p.flags, 0, -1)
    if p.wcs is not None and p.wcs.pixel_n_dim != 2:  # a cube's WCS: its sky axes
        celestial = p.wcs.celestial
        p.wcs = celestial if celestial.pixel_n_dim == 2 else None
    p.channels_first = True
    return p


def _native_copy(arr):
    """``arr`` in native byte order: itself if it already is, else a converted copy."""
    if not isinstance(arr, np.ndarray) or arr.dtype.isnative or arr.dtype.byteorder == "|":
        return arr
    return arr.astype(arr.dtype.newbyteorder("="))


def _parse(obj, name, hdu, unit):
    if obj is None:
        raise TypeError(f"{name} is None; pass an image, NDData/CCDData, FITS path or catalog.")
    if isinstance(obj, (str, os.PathLike)):
        return _read_path(obj, name, hdu, unit)
    if isinstance(obj, fits.HDUList):
        p = _from_hdu(obj[_image_hdu_index(obj, hdu, name, "the HDUList")], name, unit)
        _add_extensions(p, obj)
        return p
    if isinstance(obj, (fits.PrimaryHDU, fits.ImageHDU, fits.CompImageHDU)):
        return _from_hdu(obj, name, unit)
    if isinstance(obj, Table):
        return ParsedInput(points=_catalog_points(obj, name), kind="catalog", name="catalog")
    if isinstance(obj, NDData):
        p = _from_nddata(obj, name)
        if p.unit is None:
            p.unit = _as_unit(unit)
        return p
    if _is_header_tuple(obj):
        return _from_tuple(obj, name, unit)
    if isinstance(obj, np.ma.MaskedArray):
        arr = np.asarray(obj.data)
        if arr.ndim == 2 and arr.shape[1] == 2 and arr.dtype.kind in "iuf":
            return ParsedInput(points=_catalog_points(obj, name), kind="catalog",
                               name="catalog")
        _check_image_array(arr, name)
        m = np.ma.getmaskarray(obj)
        return ParsedInput(data=arr, mask=_user_mask(arr, m), unit=_as_unit(unit),
                           kind="masked", name="masked array")
    if isinstance(obj, (list, tuple)) or hasattr(obj, "__array__"):
        try:
            arr = np.asarray(obj)
        except ValueError:
            raise TypeError(
                f"{name} is a {type(obj).__name__} that is not an array. Pass a 2-D array, an "
                "(array, header) or (array, WCS) tuple, an NDData/CCDData, a FITS path or a "
                "catalog."
            ) from None
        if arr.ndim == 2 and arr.shape[1] == 2 and arr.dtype.kind in "iuf":
            return ParsedInput(points=_catalog_points(arr, name), kind="catalog",
                               name="catalog")
        _check_image_array(arr, name)
        return ParsedInput(data=arr, mask=None, unit=_as_unit(unit), kind="array",
                           name="array")
    raise TypeError(
        f"{name} of type {type(obj).__name__} is not supported. Pass a 2-D array, a masked "
        "array, an NDData/CCDData, a FITS HDU or path, an (array, header) or (array, WCS) "
        "tuple, or a catalog (Table with x/y columns or an (N, 2) array of positions)."
    )


def image_and_mask(image, mask=None, name="image"):
    """
    The 2-D detection image and the combined mask of any image input.

    Plain arrays pass through unchanged (their checks are the caller's);
    paths, NDData, HDUs, tuples and masked arrays are parsed, and their own
    mask is combined (OR) with ``mask``.
    """
    if isinstance(image, np.ndarray) and not np.ma.isMaskedArray(image):
        return image, mask
    if not isinstance(image, (str, os.PathLike, NDData, fits.HDUList, fits.PrimaryHDU,
                              fits.ImageHDU, fits.CompImageHDU, np.ma.MaskedArray,
                              Table, ParsedInput)) and not _is_header_tuple(image):
        return image, mask
    p = parse_input(image, name)
    if p.is_catalog:
        raise TypeError(f"{name} is a catalog; sources are found in images.")
    own = p.mask
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != p.shape:
            raise ValueError(
                f"mask shape {mask.shape} does not match the image shape {p.shape}."
            )
        own = mask if own is None else (own | mask)
    return p.detection_image, own


def _labelled(item):
    """``(frame, label)``: the label is a path as given, a pair's file name, or None."""
    if (isinstance(item, tuple) and len(item) == 2 and isinstance(item[1], str)
            and not isinstance(item[0], (str, os.PathLike))):
        # ``(frame, file name)``, as ``ImageFileCollection.ccds(return_fname=True)`` yields.
        return item[0], item[1]
    if isinstance(item, (str, os.PathLike)):
        return item, os.fspath(item)
    return item, None


def iter_frames(sources: Iterable[Any]) -> Iterator[tuple[Any, str | None]]:
    """
    Yield ``(frame, label)`` for each item of ``sources``, one at a time.

    ``label`` names the frame's output: the path as given for a path, the
    file name of a ``(frame, file name)`` pair (as
    ``ImageFileCollection.ccds(return_fname=True)`` yields them), None for
    an in-memory frame.  Nothing is read here: frames are parsed where they
    are registered.
    """
    for item in sources:
        yield _labelled(item)


def batch_frames(sources: Any, hdu: int | str | tuple | None = None
                 ) -> tuple[list | Iterator, int | str | tuple | None]:
    """
    The frames of a batch, and the HDU to read from their files.

    Parameters
    ----------
    sources : iterable or `~ccdproc.ImageFileCollection`
        Paths, arrays, NDData/CCDData, ``(frame, file name)`` pairs, a
        generator of any of these, or an ``ImageFileCollection`` (its
        files, with the collection's ``ext`` as the default HDU).
    hdu : int, str or (str, int), optional
        As in `parse_input`.

    Returns
    -------
    frames : list or iterator of ``(frame, label)``
        A list when ``sources`` is already held in memory (a list, tuple
        or array) or is a collection (its file paths); an iterator, taken
        one frame at a time, for generators and other iterators.
    hdu : int, str, tuple or None
        ``hdu``, or the collection's ``ext`` when ``hdu`` is None.

    Raises
    ------
    TypeError
        For a single path, or anything that is not iterable.
    """
    if isinstance(sources, (str, os.PathLike)):
        raise TypeError(
            f"sources must be a list of frames; got the single path {os.fspath(sources)!r}. "
            "Pass [path], or an ImageFileCollection for a folder."
        )
    # A ccdproc.ImageFileCollection (duck-typed: ccdproc is optional).
    if hasattr(sources, "files_filtered") and hasattr(sources, "location"):
        # ccdproc.ImageFileCollection: its (filtered) files, read one at a
        # time by whoever registers them.  ext=0 is ccdproc's default and
        # CCDData.read's "first HDU with data"; other values choose an HDU.
        ext = getattr(sources, "ext", None)
        if hdu is None and ext not in (None, 0):
            hdu = ext
        paths = list(sources.files_filtered(include_path=True)) if sources.files else []
        return [_labelled(p) for p in paths], hdu
    if isinstance(sources, Iterator) or not hasattr(sources, "__len__"):
        try:
            iterator = iter(sources)
        except TypeError:
            raise TypeError(
                f"sources must be an iterable of frames (a list, a generator, an "
                f"ImageFileCollection); got {type(sources).__name__}."
            ) from None
        return iter_frames(iterator), hdu
    # Already in memory (list, tuple, array of frames): a list of references.
    return [_labelled(item) for item in sources], hdu


def frame_name(label, i):
    """A frame's short name: its file name, or ``frame<i>`` in memory."""
    return os.path.basename(label) if label is not None else f"frame{i}"


def display_names(items):
    """
    The names of `batch_frames`' ``(frame, label)`` items as reports show
    them: basenames, or the label as given where two inputs share a
    basename, and ``#2``, ``#3``... after a frame given again.
    """
    base = [frame_name(label, i) for i, (_, label) in enumerate(items)]
    counts = {}
    for b in base:
        counts[b] = counts.get(b, 0) + 1
    names = [label if label is not None and counts[b] > 1 else b
             for (_, label), b in zip(items, base)]
    seen, out = {}, []
    for n in names:  # the same path given twice
        k = seen.get(n, 0)
        seen[n] = k + 1
        out.append(n if k == 0 else f"{n}#{k + 1}")
    return out


# Registered frames on disk, read a strip of rows at a time through a memory
# map (the stack's combination never holds whole frames in memory).

def image_shape_unit(path):
    """
    The shape and unit (``BUNIT``) of a FITS file's primary image, data not read.

    Parameters
    ----------
    path : str

    Returns
    -------
    shape : tuple of int
    unit : str or None
    """
    with fits.open(path, memmap=True) as hdul:
        return hdul[0].data.shape, hdul[0].header.get("BUNIT")


def read_rows(path, r0, r1):
    """
    Rows ``r0:r1`` of a registered frame: values, variance (or None) and validity.

    Parameters
    ----------
    path : str
    r0, r1 : int

    Returns
    -------
    data : (rows, nx) float64 ndarray
    variance : (rows, nx) float64 ndarray or None
    valid : (rows, nx) bool ndarray
        Unmasked, with a finite value (and a finite, non-negative variance).
    """
    with fits.open(path, memmap=True) as hdul:
        data = np.array(hdul[0].data[r0:r1], dtype=np.float64)
        valid = np.isfinite(data)
        if "MASK" in hdul:
            valid &= ~np.asarray(hdul["MASK"].data[r0:r1]).astype(bool)
        var = None
        if "UNCERT" in hdul:  # as a variance, from the UTYPE the extension holds
            utype = str(hdul["UNCERT"].header.get("UTYPE", "StdDevUncertainty"))
            kinds = {"StdDevUncertainty": "std", "VarianceUncertainty": "var",
                     "InverseVariance": "ivar"}
            kind = next((v for k, v in kinds.items() if k in utype), None)
            if kind is None:
                raise ValueError(f"unknown uncertainty type {utype!r} in {hdul.filename()}; a "
                                 "stack needs StdDevUncertainty, VarianceUncertainty or "
                                 "InverseVariance.")
            var = np.asarray(hdul["UNCERT"].data[r0:r1], dtype=np.float64)
            if kind == "std":
                var = var * var
            elif kind == "ivar":
                with np.errstate(divide="ignore"):
                    var = np.where(var > 0, 1.0 / np.where(var > 0, var, 1.0), np.inf)
            else:
                var = var.copy()
    if var is not None:
        valid &= np.isfinite(var) & (var >= 0)
    return data, var, valid
