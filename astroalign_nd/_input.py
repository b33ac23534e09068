# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The ONE input parser: everything the public functions accept becomes a
`ParsedInput`.

Accepted: 2-D (or channels-last 3-D) ndarrays, numpy masked arrays,
`~astropy.nddata.NDData` / `~astropy.nddata.CCDData`, FITS HDUs and
HDULists, file paths (FITS through astropy's readers; JPEG/PNG/TIFF through
scikit-image), and catalogs: an `~astropy.table.Table` with x/y columns or
an (N, 2) array of positions.  The caller's objects are never modified:
arrays are only read, and anything derived is a new array.
"""

import os
from dataclasses import dataclass, field

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.nddata import NDData
from astropy.table import Table

__all__ = ["ParsedInput", "parse_input"]

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
    wcs : `~astropy.wcs.WCS` or None
    meta : dict-like
        A copy of the header/meta.
    points : (N, 2) ndarray or None
        Catalog positions (brightest first) for catalog input.
    kind : str
        'array', 'masked', 'nddata', 'fits', 'image-file' or 'catalog'.
    name : str
        A short description for messages and history.
    """

    data: object = None
    mask: object = None
    uncertainty: object = None
    unit: object = None
    wcs: object = None
    meta: dict = field(default_factory=dict)
    points: object = None
    kind: str = "array"
    name: str = "array"

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


def _check_image_array(arr, name):
    if arr.dtype.kind not in "biuf":
        raise TypeError(
            f"{name} must hold numbers; got dtype {arr.dtype}. Pass a numeric image, an "
            "NDData/CCDData, a FITS path, or a catalog (Table with x/y columns or (N, 2) array)."
        )
    if arr.ndim == 3 and arr.shape[2] in (1, 2, 3, 4) and min(arr.shape[:2]) > 4:
        pass  # channels last (RGB, RGBA...)
    elif arr.ndim != 2:
        raise ValueError(
            f"{name} must be a 2-D image, a channels-last (ny, nx, nchan) image, or an (N, 2) "
            f"array of positions; got shape {arr.shape}."
        )
    if min(arr.shape[:2]) < 8:
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
        return None if mask is None or not bool(mask) else np.ones(data.shape[:2], bool)
    m = np.asarray(mask, dtype=bool)
    if m.ndim == 3:
        m = m.any(axis=2)
    if m.shape != data.shape[:2]:
        raise ValueError(
            f"mask shape {np.shape(mask)} does not match the image shape {data.shape}."
        )
    return m if m.any() else None


def _catalog_points(obj, name):
    if isinstance(obj, Table):
        cols = {c.lower(): c for c in obj.colnames}
        xc = next((cols[n.lower()] for n in _X_NAMES if n.lower() in cols), None)
        yc = next((cols[n.lower()] for n in _Y_NAMES if n.lower() in cols), None)
        if xc is None or yc is None:
            raise ValueError(
                f"{name} is a Table without position columns; it needs columns named 'x' and "
                f"'y' (or one of {_X_NAMES}); it has {obj.colnames}."
            )
        pts = np.column_stack([np.asarray(obj[xc], float), np.asarray(obj[yc], float)])
    else:
        pts = np.asarray(obj, dtype=float)
    good = np.all(np.isfinite(pts), axis=1)
    return pts[good].copy()


def _from_hdu(hdu, name):
    data = hdu.data
    if data is None:
        raise ValueError(f"{name} has no image data.")
    header = hdu.header.copy()
    unit = None
    if "BUNIT" in header:
        try:
            unit = u.Unit(header["BUNIT"], parse_strict="silent")
        except (ValueError, TypeError):
            unit = None
    wcs = None
    try:
        from astropy.wcs import WCS, FITSFixedWarning
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FITSFixedWarning)
            w = WCS(header)
        if w.has_celestial:
            wcs = w
    except Exception:  # a broken WCS must not stop registration
        wcs = None
    # The HDU's data array belongs to the caller: work on a copy.
    arr = np.array(data)
    return ParsedInput(data=_check_image_array(arr, name), mask=None,
                       unit=unit, wcs=wcs, meta=header, kind="fits", name=name)


def _read_path(path, name):
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ValueError(f"{name}: file not found: {path!r}.")
    low = path.lower()
    if low.endswith(_IMAGE_EXT):
        from skimage.io import imread

        arr = np.asarray(imread(path))
        if arr.ndim == 3 and arr.shape[2] == 4:
            arr = arr[..., :3]  # drop alpha
        p = ParsedInput(data=_check_image_array(arr, name), mask=None,
                        kind="image-file", name=os.path.basename(path))
        return p
    try:
        with fits.open(path) as hdul:
            hdu = next((h for h in hdul if getattr(h, "data", None) is not None
                        and getattr(h, "is_image", True) and np.ndim(h.data) >= 2), None)
            if hdu is None:
                raise ValueError(f"{name}: {path!r} has no image HDU.")
            p = _from_hdu(hdu, name)
    except OSError as exc:
        raise ValueError(
            f"{name}: could not read {path!r} as FITS ({exc}). Pass a FITS, JPEG, PNG or TIFF "
            "file, an array, or an NDData/CCDData."
        ) from None
    p.name = os.path.basename(path)
    return p


def parse_input(obj, name="input"):
    """
    Turn any accepted input into a `ParsedInput`.

    Parameters
    ----------
    obj : object
        See the module docstring for what is accepted.
    name : str
        Used in error messages ('source', 'target').

    Raises
    ------
    TypeError, ValueError
        With a message that says what was wrong and what to pass instead.
    """
    if obj is None:
        raise TypeError(f"{name} is None; pass an image, NDData/CCDData, FITS path or catalog.")
    if isinstance(obj, ParsedInput):
        return obj
    if isinstance(getattr(obj, "parsed", None), ParsedInput):  # a Reference
        return obj.parsed
    if isinstance(obj, (str, os.PathLike)):
        return _read_path(obj, name)
    if isinstance(obj, fits.HDUList):
        hdu = next((h for h in obj if getattr(h, "data", None) is not None
                    and np.ndim(h.data) >= 2), None)
        if hdu is None:
            raise ValueError(f"{name} is an HDUList with no image HDU.")
        return _from_hdu(hdu, name)
    if isinstance(obj, (fits.PrimaryHDU, fits.ImageHDU, fits.CompImageHDU)):
        return _from_hdu(obj, name)
    if isinstance(obj, Table):
        return ParsedInput(points=_catalog_points(obj, name), kind="catalog", name="catalog")
    if isinstance(obj, NDData):
        arr = np.asarray(obj.data)
        _check_image_array(arr, name)
        meta = obj.meta.copy() if obj.meta is not None else {}
        unc = obj.uncertainty
        if unc is not None:
            unc = unc.__class__(np.array(unc.array), unit=unc.unit)
        return ParsedInput(
            data=arr, mask=_user_mask(arr, obj.mask), uncertainty=unc, unit=obj.unit,
            wcs=obj.wcs if getattr(obj.wcs, "has_celestial", False) else None,
            meta=meta, kind="nddata", name=type(obj).__name__)
    if isinstance(obj, np.ma.MaskedArray):
        arr = np.asarray(obj.data)
        _check_image_array(arr, name)
        m = np.ma.getmaskarray(obj)
        return ParsedInput(data=arr, mask=_user_mask(arr, m), kind="masked",
                           name="masked array")
    if isinstance(obj, (list, tuple)) or hasattr(obj, "__array__"):
        arr = np.asarray(obj)
        if arr.ndim == 2 and arr.shape[1] == 2 and arr.dtype.kind in "iuf":
            return ParsedInput(points=_catalog_points(arr, name), kind="catalog",
                               name="catalog")
        _check_image_array(arr, name)
        return ParsedInput(data=arr, mask=None, kind="array", name="array")
    raise TypeError(
        f"{name} of type {type(obj).__name__} is not supported. Pass a 2-D array, a masked "
        "array, an NDData/CCDData, a FITS HDU or path, or a catalog (Table with x/y columns "
        "or an (N, 2) array of positions)."
    )
