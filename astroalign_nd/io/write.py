# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Writing output files so that a crash never leaves half a file.

Every file the package writes goes first to a hidden temporary file in the
same folder, which is then renamed onto the final name (`os.replace`, atomic
on POSIX and Windows within one file system).  So:

* a run killed during a write leaves no partial file under the final name
  (at most a hidden ``.<name>.aat-tmp-*`` file, which shell globs such as
  ``*.fits`` do not match);
* an existing output is replaced only when the new one is complete;
* without ``overwrite``, an existing file is never replaced, even by a
  concurrent writer (the final rename is then a hard link, which fails if
  the name exists).
"""

import contextlib
import os
import tempfile

__all__ = ["atomic_write", "write_ccddata", "check_output_path", "check_output_dir",
           "FITS_EXTENSIONS"]

#: File name endings taken as FITS by `write_ccddata` and the command line.
FITS_EXTENSIONS = (".fits", ".fit", ".fts", ".fits.gz", ".fit.gz", ".fts.gz")

_TMP_TAG = ".aat-tmp-"


def _read_umask():
    # os.umask can only be read by setting it; do that once, at import.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: Permissions of new files, as ``open()`` would give them (mkstemp's are 0600).
_FILE_MODE = 0o666 & ~_read_umask()


def _temp_path(path):
    folder, base = os.path.split(os.path.abspath(path))
    # The final name is kept as the suffix, so writers that pick a format or
    # compression from the ending (``.fits.gz``) behave as for the final name.
    fd, tmp = tempfile.mkstemp(prefix=f".{base}{_TMP_TAG}", suffix=f"-{base}", dir=folder)
    try:
        os.fchmod(fd, _FILE_MODE)
    except (AttributeError, OSError):  # pragma: no cover - Windows
        pass
    os.close(fd)
    return tmp


def _publish(tmp, path, overwrite):
    """Move the complete ``tmp`` onto ``path``."""
    if overwrite:
        os.replace(tmp, path)
        return
    try:
        os.link(tmp, path)  # fails if ``path`` exists: no check-then-write race
    except FileExistsError:
        raise FileExistsError(
            f"{path} exists; pass overwrite=True (or --overwrite) to replace it.") from None
    except OSError:
        # File systems without hard links (FAT, some network shares).
        if os.path.lexists(path):
            raise FileExistsError(
                f"{path} exists; pass overwrite=True (or --overwrite) to replace it.") from None
        os.replace(tmp, path)
        return
    os.unlink(tmp)


@contextlib.contextmanager
def atomic_write(path, overwrite=False):
    """
    Context manager giving a temporary path that becomes ``path`` on success.

    Write the whole file to the yielded path; when the block ends without
    an exception, the file is renamed onto ``path``.  On any exception
    (including `KeyboardInterrupt`) the temporary file is removed and
    ``path`` is left as it was.

    Parameters
    ----------
    path : str or path-like
        The final file name.  Its folder must exist.
    overwrite : bool, optional
        Replace ``path`` if it exists (default False: `FileExistsError`,
        raised before anything is written when ``path`` already exists).

    Yields
    ------
    tmp : str
        Where to write (a hidden file in the same folder as ``path``).

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.io.write import atomic_write
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "notes.txt")
    ...     with atomic_write(path) as tmp:
    ...         with open(tmp, "w") as f:
    ...             _ = f.write("complete")
    ...     with open(path) as f:
    ...         print(f.read(), os.listdir(folder))
    complete ['notes.txt']
    """
    path = os.fspath(path)
    if not overwrite and os.path.lexists(path):
        raise FileExistsError(
            f"{path} exists; pass overwrite=True (or --overwrite) to replace it.")
    tmp = _temp_path(path)
    try:
        yield tmp
        _publish(tmp, path, overwrite)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_ccddata(ccd, path, *, overwrite=False, **kwargs):
    """
    Write a `~astropy.nddata.CCDData` to a FITS file, atomically.

    Same as ``ccd.write(path, overwrite=overwrite)``, except that the file
    appears under ``path`` only once it is complete, and an existing file
    is replaced only by a complete new one (see `~astroalign_nd.io.atomic_write`).

    Parameters
    ----------
    ccd : `~astropy.nddata.CCDData`
    path : str or path-like
        Output FITS file (``.fits``, ``.fit``, ``.fts``, optionally ``.gz``).
    overwrite : bool, optional
        Replace an existing file (default False: `FileExistsError`).
    **kwargs
        Passed to `~astropy.nddata.CCDData.write` (e.g. ``hdu_mask``).

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from astropy.nddata import CCDData
    >>> from astroalign_nd.io import write_ccddata
    >>> ccd = CCDData(np.ones((4, 5), dtype=np.float32), unit="adu")
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "frame.fits")
    ...     write_ccddata(ccd, path)
    ...     back = CCDData.read(path)
    ...     try:
    ...         write_ccddata(ccd, path)  # never replaced without overwrite=True
    ...     except FileExistsError:
    ...         print("exists")
    ...     write_ccddata(ccd, path, overwrite=True)
    ...     print(os.listdir(folder))
    exists
    ['frame.fits']
    >>> back.shape, back.unit, back.data.dtype
    ((4, 5), Unit("adu"), dtype('>f4'))
    """
    with atomic_write(path, overwrite=overwrite) as tmp:
        ccd.write(tmp, overwrite=True, format="fits", **kwargs)


def check_output_path(path, overwrite=False, *, extensions=FITS_EXTENSIONS):
    """
    Check, before any work, that a file can be written at ``path``.

    Parameters
    ----------
    path : str or path-like
        The output file name.
    overwrite : bool, optional
        Accept an existing file (default False).
    extensions : sequence of str, optional
        Accepted name endings (default ``FITS_EXTENSIONS``); empty or None
        accepts any name.

    Raises
    ------
    ValueError
        If the name does not end in one of ``extensions`` or is a folder.
    FileExistsError
        If the file exists and ``overwrite`` is False.
    OSError
        If the folder does not exist or cannot be written to.

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.io.write import check_output_path
    >>> with tempfile.TemporaryDirectory() as folder:  # doctest: +ELLIPSIS
    ...     check_output_path(os.path.join(folder, "aligned.fits"))  # fine: returns None
    ...     try:
    ...         check_output_path(os.path.join(folder, "aligned.png"))
    ...     except ValueError as exc:
    ...         print(exc)
    ...     print(os.listdir(folder))  # the check leaves nothing behind
    output file '...aligned.png' must end in one of .fits, .fit, ... (e.g. '...aligned.png.fits').
    []
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise ValueError(f"output {path!r} is a folder; give a file name such as "
                         f"{os.path.join(path, 'aligned.fits')!r}.")
    if extensions and not path.lower().endswith(tuple(extensions)):
        raise ValueError(f"output file {path!r} must end in one of {', '.join(extensions)} "
                         f"(e.g. {path + extensions[0]!r}).")
    if os.path.lexists(path) and not overwrite:
        raise FileExistsError(f"output file {path!r} already exists; pass --overwrite "
                              "(overwrite=True) to replace it.")
    _check_writable_dir(os.path.dirname(os.path.abspath(path)))


def check_output_dir(folder):
    """
    Check, before any work, that files can be created in ``folder``.

    Parameters
    ----------
    folder : str or path-like
        An existing folder.

    Raises
    ------
    NotADirectoryError
        If ``folder`` does not exist or is not a folder.
    PermissionError
        If no file can be created in it.

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.io.write import check_output_dir
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     check_output_dir(folder)  # fine: returns None, leaves nothing behind
    ...     try:
    ...         check_output_dir(os.path.join(folder, "missing"))
    ...     except NotADirectoryError:
    ...         print("no such folder")
    ...     print(os.listdir(folder))
    no such folder
    []
    """
    _check_writable_dir(os.fspath(folder))


def _check_writable_dir(folder):
    """Raise `OSError` with a clear message unless files can be created in ``folder``."""
    if not os.path.isdir(folder):
        what = "is not a folder" if os.path.exists(folder) else "does not exist"
        raise NotADirectoryError(f"output folder {folder!r} {what}.")
    try:
        fd, probe = tempfile.mkstemp(prefix=f"{_TMP_TAG}probe-", dir=folder)
    except OSError as exc:
        raise PermissionError(f"cannot write to output folder {folder!r}: "
                              f"{exc.strerror or exc}.") from None
    os.close(fd)
    os.unlink(probe)
