# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Colour (Bayer) frames as the camera writes them: which colour each pixel
saw, and a grey version to register them on.

A one-shot-colour sensor has a 2x2 mosaic of filters (a Bayer pattern)
over its pixels; its raw frame is a 2-D image whose pixels are red, green
or blue by their place in the mosaic.  The pattern is named by the colours
of the first 2x2 cell, read row by row: ``'GRBG'`` is green, red on the
first row and blue, green on the second.

The header keywords, as capture programs write them (N.I.N.A., SharpCap,
INDI, the Seestar; Siril and PixInsight read them):

* ``BAYERPAT``: the pattern, in the order the sensor is read out (top row
  first);
* ``XBAYROFF``, ``YBAYROFF``: the pattern starts this many columns and rows
  into the mosaic (0 or 1; an odd crop moves the pattern);
* ``ROWORDER``: ``'TOP-DOWN'`` when the file's first row is the first row
  read out (most cameras, and the default when the keyword is absent, as in
  the Seestar's files: their two green sites are the ``GRBG`` ones counted
  from the file's first row), ``'BOTTOM-UP'`` when the rows were flipped on
  writing (FITS's display convention): the pattern's first row is then the
  file's *last* row, and for an even number of rows the pattern read from
  the file's first row has its two rows swapped (``RGGB`` becomes ``GBRG``).

`bayer_pattern` folds these into the pattern of the array's first cell
(``data[0:2, 0:2]``), which is all the other functions take.
"""

from __future__ import annotations

import numpy as np
from astropy.modeling.models import Scale, Shift
from scipy import ndimage

from ..stacking.options import BAYER_PATTERNS  # declared with the stack's ``bayer`` option
from ..transforms import LinearTransform2D, as_matrix, from_matrix

__all__ = ["BAYER_PATTERNS", "bayer_pattern", "bayer_channels", "balanced_grey", "superpixel",
           "superpixel_to_raw"]

#: The channels of a colour stack, in order (0 red, 1 green, 2 blue).
_CHANNELS = "RGB"
#: Superpixel (x, y) -> raw pixel: ``2 * x + 0.5`` (the centre of its 2x2 cell).
_TO_RAW = np.array([[2.0, 0.0, 0.5], [0.0, 2.0, 0.5], [0.0, 0.0, 1.0]])


def _check_pattern(pattern, where):
    if not isinstance(pattern, str):
        raise TypeError(f"the Bayer pattern must be a string such as 'GRBG'; got "
                        f"{type(pattern).__name__} ({where}).")
    p = pattern.strip().upper()
    if p not in BAYER_PATTERNS:
        raise ValueError(f"unknown Bayer pattern {pattern!r} ({where}): give one of "
                         f"{', '.join(BAYER_PATTERNS)} (the colours of the first 2x2 cell, "
                         "row by row); other mosaics (CMYG, X-Trans) are not supported.")
    return p


def _header_int(header, key):
    value = header.get(key, 0)
    try:
        k = int(value)
    except (TypeError, ValueError):
        raise ValueError(f"{key} = {value!r} in the header is not an integer offset of the "
                         "Bayer pattern (0 or 1); fix the header or pass the pattern of the "
                         "array's first cell (bayer='GRBG').") from None
    if k != value:
        raise ValueError(f"{key} = {value!r} in the header is not an integer offset of the "
                         "Bayer pattern (0 or 1).")
    return k


def _shifted(p, dx, dy):
    """The pattern of the cell that starts ``dx`` columns and ``dy`` rows further on."""
    cell = [[p[0], p[1]], [p[2], p[3]]]
    return "".join(cell[(r + dy) % 2][(c + dx) % 2] for r in (0, 1) for c in (0, 1))


def bayer_pattern(header=None, pattern=None, *, shape=None):
    """
    The Bayer pattern of an array's first 2x2 cell.

    Parameters
    ----------
    header : dict-like, optional
        The frame's header: ``BAYERPAT``, and ``XBAYROFF``, ``YBAYROFF``
        and ``ROWORDER`` when present (see the module's description).
    pattern : str, optional
        The pattern given by the user ('RGGB', 'BGGR', 'GRBG' or 'GBRG'):
        the colours of the array's first cell (``data[0:2, 0:2]``) row by
        row.  It takes precedence over the header, whose keywords are then
        not read.
    shape : (ny, nx), optional
        The frame's shape; needed for ``ROWORDER = 'BOTTOM-UP'`` (the
        pattern then starts on the last row).

    Returns
    -------
    pattern : str
        One of `BAYER_PATTERNS`.

    Raises
    ------
    ValueError
        If no pattern is given and the header has none, or the pattern is
        not one of `BAYER_PATTERNS`, or an offset is not an integer.

    Examples
    --------
    >>> from astroalign_nd.io.bayer import bayer_pattern
    >>> bayer_pattern({"BAYERPAT": "GRBG"})
    'GRBG'
    >>> bayer_pattern({"BAYERPAT": "RGGB", "XBAYROFF": 1})
    'GRBG'
    >>> bayer_pattern({"BAYERPAT": "RGGB", "ROWORDER": "BOTTOM-UP"}, shape=(1080, 1920))
    'GBRG'
    >>> bayer_pattern(pattern="bggr")
    'BGGR'
    """
    if pattern is not None:
        return _check_pattern(pattern, "given")
    header = {} if header is None else header
    if header.get("BAYERPAT") in (None, ""):
        raise ValueError("the frame has no BAYERPAT keyword: give its Bayer pattern, the "
                         f"colours of its first 2x2 cell ({', '.join(BAYER_PATTERNS)}), e.g. "
                         "bayer='GRBG' (--bayer GRBG on the command line).")
    p = _check_pattern(header["BAYERPAT"], "the header's BAYERPAT")
    p = _shifted(p, _header_int(header, "XBAYROFF"), _header_int(header, "YBAYROFF"))
    order = str(header.get("ROWORDER", "TOP-DOWN")).strip().upper()
    if order not in ("TOP-DOWN", "BOTTOM-UP"):
        raise ValueError(f"ROWORDER = {header['ROWORDER']!r} in the header: expected "
                         "'TOP-DOWN' or 'BOTTOM-UP'; fix the header or pass the pattern of "
                         "the array's first cell (bayer='GRBG').")
    if order == "BOTTOM-UP":
        if shape is None:
            raise ValueError("ROWORDER = 'BOTTOM-UP' needs the frame's shape (the pattern "
                             "starts on its last row).")
        # The file's row i is the sensor's row ny - 1 - i (a 2-row period: a shift).
        p = _shifted(p, 0, (shape[0] - 1) % 2)
    return p


def bayer_channels(shape, pattern):
    """
    The colour of each pixel of a raw frame: 0 red, 1 green, 2 blue.

    Parameters
    ----------
    shape : (ny, nx)
    pattern : str
        The pattern of the array's first cell (`bayer_pattern`).

    Returns
    -------
    channels : (ny, nx) int8 ndarray

    Examples
    --------
    >>> from astroalign_nd.io.bayer import bayer_channels
    >>> bayer_channels((2, 4), "GRBG").tolist()
    [[1, 0, 1, 0], [2, 1, 2, 1]]
    """
    p = _check_pattern(pattern, "given")
    ny, nx = shape
    cell = np.array([_CHANNELS.index(c) for c in p], dtype=np.int8).reshape(2, 2)
    return np.tile(cell, ((ny + 1) // 2, (nx + 1) // 2))[:ny, :nx]


def superpixel(data, mask=None):
    """
    The grey version of a raw colour frame: each 2x2 cell summed into one pixel.

    Each cell holds one red, two green and one blue pixel whatever the
    pattern, so the sum is a grey image of half the size, with no colour
    mosaic left in it, on which stars are found and matched as on any grey
    frame.  Superpixel ``(x, y)`` is centred on raw pixel
    ``(2 x + 0.5, 2 y + 0.5)`` (`superpixel_to_raw`).  An odd last row or
    column is left out.

    Parameters
    ----------
    data : 2-D array
        The raw frame.
    mask : 2-D bool array, optional
        True for bad pixels; a cell with any is masked.

    Returns
    -------
    grey : 2-D float32 ndarray
    grey_mask : 2-D bool ndarray or None

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.io.bayer import superpixel
    >>> grey, _ = superpixel(np.arange(16.0).reshape(4, 4))
    >>> grey.tolist()
    [[10.0, 18.0], [42.0, 50.0]]
    """
    a = np.asarray(data)
    if a.ndim != 2:
        raise ValueError(f"a raw Bayer frame is a 2-D image; got shape {a.shape}.")
    ny, nx = (a.shape[0] // 2) * 2, (a.shape[1] // 2) * 2
    if ny == 0 or nx == 0:
        raise ValueError(f"a raw Bayer frame needs at least 2x2 pixels; got {a.shape}.")
    cells = a[:ny, :nx].astype(np.float32).reshape(ny // 2, 2, nx // 2, 2)
    grey = cells.sum(axis=(1, 3), dtype=np.float32)
    if mask is None:
        return grey, None
    m = np.asarray(mask, dtype=bool)[:ny, :nx].reshape(ny // 2, 2, nx // 2, 2)
    return grey, m.any(axis=(1, 3))


def balanced_grey(data, pattern, mask=None):
    """
    The grey version of a raw colour frame at full resolution: each colour's
    pixels scaled so that starlight looks the same in all three.

    Each colour's sky (its median) is subtracted and its pixels divided by
    its response to the frame's starlight relative to green's (measured on
    the brightest 0.5 % of the 2x2 cells and around them: whole stars), then the
    green sky is added back: the stars lose the colour mosaic and keep
    their full resolution, so they are centred as precisely as on a grey
    frame (the 2x2 `superpixel` sum halves the sampling of stars that are
    already undersampled).  Pixel ``(x, y)`` is raw pixel ``(x, y)``.

    Parameters
    ----------
    data : 2-D array
        The raw frame.
    pattern : str
        The pattern of its first cell (`bayer_pattern`).
    mask : 2-D bool array, optional
        True for bad pixels (left out of the measurements).

    Returns
    -------
    grey : 2-D float32 ndarray

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.io.bayer import balanced_grey
    >>> from astroalign_nd.simulate import bayer_mosaic, simulate_field
    >>> img, _ = simulate_field((128, 128), n_stars=150, fwhm=2.5, noise=False, seed=1)
    >>> raw = bayer_mosaic(img, "RGGB", gains=(0.5, 1.0, 0.7))
    >>> grey = balanced_grey(raw.data, "RGGB")
    >>> bool(np.abs(grey - img).max() < 0.02 * img.max())  # the mosaic is gone
    True
    """
    a = np.asarray(data, dtype=np.float64)
    if a.ndim != 2 or min(a.shape) < 2:
        raise ValueError(f"a raw Bayer frame is a 2-D image of at least 2x2 pixels; got "
                         f"shape {a.shape}.")
    channels = bayer_channels(a.shape, pattern)
    good = np.isfinite(a) if mask is None else np.isfinite(a) & ~np.asarray(mask, bool)
    sky = np.array([np.median(a[good & (channels == c)]) if (good & (channels == c)).any()
                    else 0.0 for c in range(3)])
    d = np.where(good, a - sky[channels], 0.0)
    cells, _ = superpixel(d)
    # Whole stars (their brightest cells and two cells around): summed over whole stars,
    # each colour samples the same light whatever the stars' pixel phases.
    bright = ndimage.binary_dilation(cells >= np.percentile(cells, 99.5), iterations=2)
    sel = np.zeros(a.shape, bool)
    sel[:2 * cells.shape[0], :2 * cells.shape[1]] = np.kron(bright, np.ones((2, 2), bool))
    # Per cell: one red, two green, one blue pixel.
    light = np.array([d[sel & good & (channels == c)].sum() / (2.0 if c == 1 else 1.0)
                      for c in range(3)])
    gain = light / light[1]
    # Without measurable starlight in a colour, its sky stands in for its response.
    fallback = sky / sky[1] if sky[1] > 0 else np.ones(3)
    gain = np.where(np.isfinite(gain) & (gain > 0), gain, fallback)
    gain = np.where(np.isfinite(gain) & (gain > 0), gain, 1.0)
    grey = d / gain[channels] + sky[1]
    return np.where(good, grey, np.nan).astype(np.float32)


def superpixel_to_raw(transform):
    """
    A transform found between two superpixel frames, in raw pixel coordinates.

    Superpixel ``s`` is centred on raw ``r = 2 s + 0.5``, so the raw
    transform is ``r -> 2 T((r - 0.5) / 2) + 0.5``: the same rotation and
    scale, its shift doubled and corrected for the half-pixel offset of
    the cells' centres.

    Parameters
    ----------
    transform : `~astroalign_nd.transforms.LinearTransform2D` or model
        Found between superpixel frames (`superpixel`).  A linear one gives
        a linear one of the same type; any other 2-in/2-out model gives
        the astropy compound model of the conversions around it.

    Returns
    -------
    raw : `~astroalign_nd.transforms.LinearTransform2D` or `~astropy.modeling.Model`

    Examples
    --------
    >>> from astroalign_nd.io.bayer import superpixel_to_raw
    >>> from astroalign_nd.transforms import SimilarityTransform
    >>> raw = superpixel_to_raw(SimilarityTransform(translation_x=3.0))
    >>> raw.translation.tolist()
    [6.0, 0.0]
    """
    if isinstance(transform, LinearTransform2D):
        m = _TO_RAW @ as_matrix(transform) @ np.linalg.inv(_TO_RAW)
        return from_matrix(m, type(transform))
    to_cells = (Shift(-0.5) & Shift(-0.5)) | (Scale(0.5) & Scale(0.5))
    to_raw = (Scale(2.0) & Scale(2.0)) | (Shift(0.5) & Shift(0.5))
    return to_cells | transform | to_raw
