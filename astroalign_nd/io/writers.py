# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Output formats: one `Writer` per format, chosen by the file name's ending.

A writer writes a registered frame (a `~astropy.nddata.CCDData`)
atomically, and reads back what a resumed batch needs of a complete file
it wrote: its header and its data shape.  `~astroalign_nd.register_batch`
(output names and resume) and the command line (``register -o``) find the
writer of a path with `writer_for`, so a new output format is one
`Writer` subclass, added with `register_writer`.  FITS (`FITSWriter`) is
the one built in, and the default.
"""

import abc
import os
import warnings

import numpy as np
from astropy.io import fits

from .write import FITS_EXTENSIONS, write_ccddata

__all__ = ["Writer", "FITSWriter", "WRITERS", "register_writer", "writer_for",
           "output_suffixes", "write_output"]


class Writer(metaclass=abc.ABCMeta):
    """
    One output format: how a registered frame is written and read back.

    A subclass sets `name` and `suffixes` and implements `write` and
    `read_done`.  Writers are shipped to worker processes with a batch's
    configuration: they must pickle (a class at module level, holding
    plain attributes, does).

    Examples
    --------
    A format that stores the pixels and header in a NumPy ``.npz`` file:

    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.io import fits
    >>> from astropy.nddata import CCDData
    >>> from astroalign_nd.io import Writer, atomic_write
    >>> class NpzWriter(Writer):
    ...     name, suffixes = "npz", (".npz",)
    ...     def write(self, ccd, path, *, overwrite=False):
    ...         with atomic_write(path, overwrite=overwrite) as tmp, open(tmp, "wb") as f:
    ...             np.savez(f, data=ccd.data, header=fits.Header(ccd.meta).tostring())
    ...     def read_done(self, path):
    ...         with open(path, "rb") as fh, np.load(fh) as f:
    ...             return fits.Header.fromstring(str(f["header"])), f["data"].shape
    >>> ccd = CCDData(np.ones((4, 5)), unit="adu", meta={"AATTYPE": "translation"})
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "frame.npz")
    ...     NpzWriter().write(ccd, path)
    ...     header, shape = NpzWriter().read_done(path)
    >>> header["AATTYPE"], shape
    ('translation', (4, 5))
    """

    #: The format's name, its key in `WRITERS`.
    name = None

    #: File name endings of the format (matched without regard to case); the
    #: first is given to new outputs.
    suffixes = ()

    def matches(self, path):
        """
        Whether ``path`` (or a bare ending such as ``'_aligned.fits'``) is of this format.

        Parameters
        ----------
        path : str or path-like

        Returns
        -------
        bool
        """
        return os.fspath(path).lower().endswith(tuple(s.lower() for s in self.suffixes))

    @abc.abstractmethod
    def write(self, ccd, path, *, overwrite=False):
        """
        Write ``ccd`` to ``path``, atomically (see `~astroalign_nd.io.atomic_write`).

        Parameters
        ----------
        ccd : `~astropy.nddata.CCDData`
            The registered frame, its header (``ccd.meta``) holding the
            transform keywords that `read_done` must give back.
        path : str
        overwrite : bool, optional
            Replace an existing file (default False: `FileExistsError`).
        """

    @abc.abstractmethod
    def read_done(self, path):
        """
        The header and data shape of a complete file written by `write`.

        Parameters
        ----------
        path : str

        Returns
        -------
        header : `~astropy.io.fits.Header` or dict-like
            The frame's header as written (``ccd.meta``).
        shape : tuple of int or None
            The shape of its data; None if it has none.

        Raises
        ------
        Exception
            Any exception when the file is incomplete or cannot be read: a
            resumed batch then redoes the frame (or refuses to replace it).
        """

    def __repr__(self):
        return f"<{type(self).__name__} {self.name!r} {', '.join(self.suffixes)}>"


class FITSWriter(Writer):
    """
    FITS: ``CCDData.write`` with ``MASK``, ``UNCERT`` and ``FLAGS`` extensions.

    Examples
    --------
    The mask goes to its own extension; `read_done` reads the primary header:

    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.io import fits
    >>> from astropy.nddata import CCDData
    >>> from astroalign_nd.io import FITSWriter
    >>> mask = np.zeros((4, 5), dtype=bool)
    >>> ccd = CCDData(np.ones((4, 5)), unit="adu", mask=mask, meta={"AATTYPE": "affine"})
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "frame.fits")
    ...     FITSWriter().write(ccd, path)
    ...     with fits.open(path) as hdul:
    ...         extensions = [hdu.name for hdu in hdul]
    ...     header, shape = FITSWriter().read_done(path)
    >>> extensions, header["AATTYPE"], shape
    (['PRIMARY', 'MASK'], 'affine', (4, 5))
    """

    name = "fits"
    suffixes = FITS_EXTENSIONS

    def write(self, ccd, path, *, overwrite=False):
        """
        Write ``ccd`` with `~astroalign_nd.io.write_ccddata`.

        Parameters
        ----------
        ccd : `~astropy.nddata.CCDData`
        path : str
        overwrite : bool, optional
        """
        # FLAGS as an extension, so that CCDData.read(..., hdu_flags='FLAGS') reads it back.
        write_ccddata(ccd, path, overwrite=overwrite, hdu_flags="FLAGS")

    def read_done(self, path):
        """
        The primary header and data shape, every data block read in full.

        Parameters
        ----------
        path : str

        Returns
        -------
        header : `~astropy.io.fits.Header`
        shape : tuple of int or None
            The first two axes of the primary data.

        Raises
        ------
        Exception
            If the file cannot be read, or reading it warns (a truncated
            file): the warning is raised.
        """
        path = os.fspath(path)
        # A warning ("file may have been truncated") counts as incomplete.  It
        # is recorded, not raised: raised inside fits.open it would leave the
        # file open; here the file is ours to close, whatever happens.
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with open(path, "rb") as fh, fits.open(
                    fh, memmap=not path.lower().endswith(".gz")) as hdul:
                hdul.readall()
                for hdu in hdul:  # every data block is there, in full
                    if hdu.data is not None:
                        np.asarray(hdu.data).ravel()[-1:].copy()
                header = hdul[0].header
                shape = hdul[0].data.shape[:2] if hdul[0].data is not None else None
        if caught:
            raise caught[0].message
        return header, shape


#: The output formats by name, the default (FITS) first.
WRITERS = {FITSWriter.name: FITSWriter()}


def register_writer(writer):
    """
    Add an output format (or replace the one of the same name).

    Parameters
    ----------
    writer : `Writer`
        An instance; its ``suffixes`` must not be another format's.

    Returns
    -------
    writer : `Writer`

    Raises
    ------
    TypeError
        If ``writer`` is not a `Writer`.
    ValueError
        If it has no name or suffixes, or shares a suffix with another format.

    Examples
    --------
    >>> from astroalign_nd.io import FITSWriter, WRITERS, register_writer, writer_for
    >>> class PlainFITS(FITSWriter):
    ...     name, suffixes = "plain-fits", (".pfits",)
    >>> _ = register_writer(PlainFITS())
    >>> writer_for("out/m31_aligned.pfits").name
    'plain-fits'
    >>> del WRITERS["plain-fits"]  # as it was
    """
    if not isinstance(writer, Writer):
        raise TypeError(f"writer must be an instance of astroalign_nd.io.Writer; got "
                        f"{writer!r}.")
    if not writer.name or not writer.suffixes:
        raise ValueError(f"the writer {writer!r} needs a name and at least one suffix.")
    mine = {s.lower() for s in writer.suffixes}
    for other in WRITERS.values():
        shared = mine & {s.lower() for s in other.suffixes}
        if other.name != writer.name and shared:
            raise ValueError(f"the writer {writer.name!r} shares the suffix(es) "
                             f"{', '.join(sorted(shared))} with {other.name!r}.")
    WRITERS[writer.name] = writer
    return writer


def writer_for(path, writers=None):
    """
    The writer of a file name, by its ending.

    Parameters
    ----------
    path : str or path-like
        A file name, or a bare ending (``'_aligned.fits'``).
    writers : dict, optional
        The formats to choose from (default `WRITERS`).

    Returns
    -------
    writer : `Writer`

    Raises
    ------
    ValueError
        If no format has the name's ending.

    Examples
    --------
    >>> from astroalign_nd.io import writer_for
    >>> writer_for("out/m31_aligned.fits.gz").name
    'fits'
    """
    writers = WRITERS if writers is None else writers
    low = os.fspath(path).lower()
    # The longest matching ending wins (".fits.gz" before a ".gz" of another format).
    best, length = None, 0
    for writer in writers.values():
        for suffix in writer.suffixes:
            if low.endswith(suffix.lower()) and len(suffix) > length:
                best, length = writer, len(suffix)
    if best is None:
        raise ValueError(f"no output format for {os.fspath(path)!r}: give a name ending in "
                         f"one of {', '.join(output_suffixes(writers))}.")
    return best


def output_suffixes(writers=None):
    """
    Every output file name ending, the default format's first.

    Parameters
    ----------
    writers : dict, optional
        The formats (default `WRITERS`).

    Returns
    -------
    suffixes : tuple of str

    Examples
    --------
    >>> from astroalign_nd.io import output_suffixes
    >>> output_suffixes()[:2]
    ('.fits', '.fit')
    """
    writers = WRITERS if writers is None else writers
    return tuple(s for w in writers.values() for s in w.suffixes)


def write_output(ccd, path, *, overwrite=False):
    """
    Write a registered frame in the format of its file name's ending.

    Parameters
    ----------
    ccd : `~astropy.nddata.CCDData`
    path : str or path-like
    overwrite : bool, optional
        Replace an existing file (default False: `FileExistsError`).

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.nddata import CCDData
    >>> from astroalign_nd.io import write_output
    >>> ccd = CCDData(np.ones((4, 5)), unit="adu")
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     write_output(ccd, os.path.join(folder, "aligned.fits"))
    ...     print(os.listdir(folder))
    ['aligned.fits']
    """
    path = os.fspath(path)
    writer_for(path).write(ccd, path, overwrite=overwrite)
