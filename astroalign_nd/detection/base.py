# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The interface of a source finder, as photutils' ``StarFinderBase``.

A finder is an object configured once (its threshold, its PSF width...)
and called on images: ``finder(data, mask=None)`` returns an
`~astropy.table.Table` of the sources found.  `SourceFinderBase` checks
the input and normalises the output, so that a new finder implements one
method, `SourceFinderBase.find_stars`.  `~astroalign_nd.detection.find_sources`
runs any finder given as ``finder=``, and through it so do
`~astroalign_nd.registration.find_transform`, ``register``, ``Reference``
and ``register_batch``.
"""

import abc

import numpy as np
from astropy.table import Table

from ..io.read import image_and_mask
from .candidates import _as_image

__all__ = ["SourceFinderBase"]

#: The columns every finder's table has (more are kept).
_REQUIRED = ("x", "y", "flux")

#: Other names of the position columns, as photutils' finders write them.
_POSITION_ALIASES = {"x": ("x_centroid", "xcentroid"), "y": ("y_centroid", "ycentroid")}


class SourceFinderBase(metaclass=abc.ABCMeta):
    """
    Abstract base class of the source finders.

    The contract, for a new finder: subclass this class and implement
    `find_stars`.

    * `find_stars` receives ``data``, a 2-D float array, and ``mask``,
      None or a bool array of its shape, True for every pixel to ignore:
      the caller's mask and every non-finite pixel (whose values are
      left as they are).
    * It returns an `~astropy.table.Table` (or None when nothing is found)
      with at least the columns ``x`` and ``y`` (0-based pixel positions;
      photutils' ``x_centroid``/``y_centroid`` are renamed) and ``flux``
      (used to rank the sources); optionally ``position_error`` (expected
      centroid error per axis, pixels; it weights the final fit of a
      registration, which takes 0.1 px without it), and in its ``meta``
      the stars' ``fwhm`` (pixels; it widens the matching radius for wide
      stars).
    * The call returns that table sorted by decreasing flux (stable), rows
      with a non-finite position or flux dropped; never None.
    * A finder keeps no state between calls: registration may run it on
      two frames at once, in two threads, and ships it to worker processes
      (it must pickle).

    Examples
    --------
    A finder that takes the brightest pixel of each 16 x 16 block:

    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from astroalign_nd.detection import SourceFinderBase
    >>> class BlockMaxima(SourceFinderBase):
    ...     def find_stars(self, data, mask=None):
    ...         data = np.where(mask, -np.inf, data) if mask is not None else data
    ...         ny, nx = (s // 16 for s in data.shape)
    ...         blocks = data[:16 * ny, :16 * nx].reshape(ny, 16, nx, 16).swapaxes(1, 2)
    ...         k = blocks.reshape(ny, nx, -1).argmax(axis=2)
    ...         by, bx = np.indices((ny, nx))
    ...         y, x = 16 * by + k // 16, 16 * bx + k % 16
    ...         return Table({"x": x.ravel(), "y": y.ravel(), "flux": data[y, x].ravel()})
    >>> image = np.zeros((32, 32))
    >>> image[5, 20] = 7.0
    >>> image[30, 3] = 9.0
    >>> found = BlockMaxima()(image)
    >>> [(int(r["x"]), int(r["y"]), float(r["flux"])) for r in found[:2]]
    [(3, 30, 9.0), (20, 5, 7.0)]
    """

    def __call__(self, data, mask=None):
        """
        Find the sources of an image.

        Parameters
        ----------
        data : 2-D array-like, `~astropy.nddata.NDData`, path, HDU or tuple
            The image, as `~astroalign_nd.detection.find_sources` takes it
            (its own mask is honoured).
        mask : 2-D bool array-like, optional
            True for pixels to ignore.

        Returns
        -------
        sources : `~astropy.table.Table`
            At least ``x``, ``y`` and ``flux``, sorted by decreasing flux.
        """
        image, mask = image_and_mask(data, mask)
        data, mask = _as_image(image, mask, caller=type(self).__name__)
        bad = ~np.isfinite(data)
        if bad.any():
            mask = bad if mask is None else (mask | bad)
        return _standard_table(self.find_stars(data, mask=mask), finder=self)

    @abc.abstractmethod
    def find_stars(self, data, mask=None):
        """
        Find the sources of a checked image (the method a finder implements).

        Parameters
        ----------
        data : 2-D float ndarray
            The image.
        mask : 2-D bool ndarray or None
            True for pixels to ignore (the caller's and non-finite ones).

        Returns
        -------
        sources : `~astropy.table.Table` or None
            At least ``x``, ``y`` and ``flux`` (see the class's contract).
        """

    def __repr__(self):
        params = ", ".join(f"{k}={v!r}" for k, v in vars(self).items() if not k.startswith("_"))
        return f"{type(self).__name__}({params})"


def _empty_sources():
    return Table(names=_REQUIRED, dtype=[float] * len(_REQUIRED))


def _standard_table(table, finder, n_sources=None):
    """
    A finder's output as every stage reads it: ``x``, ``y``, ``flux``
    present, finite, brightest first, at most ``n_sources`` rows.
    """
    if table is None:
        return _empty_sources()
    if not isinstance(table, Table):
        raise TypeError(f"the source finder {finder!r} returned {type(table).__name__}; a "
                        "finder returns an astropy Table (or None when it finds nothing).")
    table = table.copy(copy_data=False)
    for name, aliases in _POSITION_ALIASES.items():
        alias = next((a for a in aliases if a in table.colnames), None)
        if name not in table.colnames and alias is not None:
            table.rename_column(alias, name)
    missing = [c for c in _REQUIRED if c not in table.colnames]
    if missing:
        raise ValueError(f"the table of the source finder {finder!r} has no column "
                         f"{', '.join(missing)}; a finder's table has columns "
                         f"{', '.join(_REQUIRED)} (and its columns are {table.colnames}).")
    cols = {c: np.ma.filled(np.ma.asarray(table[c], dtype=float), np.nan) for c in _REQUIRED}
    ok = np.isfinite(cols["x"]) & np.isfinite(cols["y"]) & np.isfinite(cols["flux"])
    keep = np.flatnonzero(ok)[np.argsort(-cols["flux"][ok], kind="stable")][:n_sources]
    out = table[keep]
    for c in _REQUIRED:  # plain float columns, whatever the finder wrote
        out[c] = cols[c][keep]
    return out
