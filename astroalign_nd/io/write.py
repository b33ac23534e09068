# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Writing output files so that a crash never leaves half a file.

Every file the package writes goes first to a temporary file in a new
private folder beside the output (mode 0700: nobody else can read it or swap
it for a link), which is then moved onto the final name (`os.replace` or
`os.link`, atomic on POSIX and Windows within one file system, never
following a link).  So:

* a run killed during a write leaves no partial file under the final name
  (at most a hidden ``.aat-tmp-*`` folder, which shell globs such as
  ``*.fits`` do not match);
* an existing output is replaced only when the new one is complete;
* without ``overwrite``, an existing file is never replaced, even by a
  concurrent writer (the final rename is then a hard link, which fails if
  the name exists).
"""

import contextlib
import errno
import gzip
import io
import os
import shutil
import signal
import stat
import tempfile
import threading

__all__ = ["atomic_write", "atomic_open", "write_ccddata", "write_table", "check_output_path",
           "check_output_dir", "make_output_dir", "remove_empty_dirs", "check_not_input",
           "FITS_EXTENSIONS", "interrupts_held"]

#: File name endings taken as FITS by `write_ccddata` and the command line.
FITS_EXTENSIONS = (".fits", ".fit", ".fts", ".fits.gz", ".fit.gz", ".fts.gz")

_TMP_TAG = ".aat-tmp-"


#: File operations that can work relative to a directory's descriptor (POSIX): with them,
#: a temporary folder renamed or replaced by another user cannot redirect a write.
#: (``os.rename`` is POSIX rename(2), which replaces the destination as ``os.replace`` does;
#: ``os.replace`` itself is missing from ``os.supports_dir_fd`` although it takes the argument.)
_DIR_FD = all(f in os.supports_dir_fd for f in (os.open, os.stat, os.unlink, os.link, os.rename))

#: Longest name ending kept on the temporary file (``.fits.gz`` and the like).
_MAX_SUFFIX = 16


class _PrivateFolder:
    """
    A folder only this user can enter (``mkdtemp``: mode 0700, a fresh random name), made
    beside the output, holding the one temporary file of an atomic write.

    On POSIX the folder is held by a descriptor: the file is created, checked, published and
    removed relative to it, so renaming the folder or planting a link in its place (which
    anyone who can write to a shared folder without the sticky bit can do) cannot redirect
    the write.  On Windows, which has no such calls, names are used.
    """

    @classmethod
    @contextlib.contextmanager
    def publishing(cls, path, overwrite):
        """
        A new private folder beside ``path`` (refused first if ``path`` exists and not
        ``overwrite``): its file, once the block has written and checked it, is moved onto
        ``path``; the folder is removed in any case.  A failed write is one clear `OSError`.
        """
        path = os.fspath(path)
        if not overwrite and os.path.lexists(path):
            raise FileExistsError(
                f"{path} exists; pass overwrite=True (or --overwrite) to replace it.")
        with _clear_write_errors(path):
            private = cls(path)
        try:
            with _clear_write_errors(path):
                yield private
                private.publish(path, overwrite)
        finally:
            private.close()

    def __init__(self, path):
        folder, base = os.path.split(os.path.abspath(path))
        if not os.path.isdir(folder):
            raise FileNotFoundError(f"cannot write {path!r}: its folder {folder!r} does not "
                                    "exist; create it first, or give a path in an existing "
                                    "folder.")
        # The final name's ending is kept, so writers that choose a format or a compression
        # from it (``.fits.gz``) behave as for the final name; the length stays bounded.
        # (the ending of 'm31.fits.gz' is '.fits.gz')
        dot = base.find(".", 1)
        suffix = base[dot:] if dot > 0 else ""
        while len(suffix) > _MAX_SUFFIX and "." in suffix[1:]:
            suffix = suffix[suffix.index(".", 1):]
        self.name = "part" + (suffix if len(suffix) <= _MAX_SUFFIX else "")
        self.fd = None
        for attempt in range(5):
            self.path = tempfile.mkdtemp(prefix=_TMP_TAG, dir=folder)
            self.temp = os.path.join(self.path, self.name)
            if not _DIR_FD or self._hold():
                return
        raise OSError(f"a private folder made in {folder!r} was replaced as soon as it was "
                      "made, 5 times: someone is tampering with this folder; nothing was "
                      "written.")

    def _hold(self):
        """Open the new folder; False (and nothing held) if it is no longer the one made."""
        flags = os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_NOFOLLOW", 0)
        try:
            fd = os.open(self.path, flags)
        except OSError:
            return False
        st = os.fstat(fd)
        if st.st_uid != os.geteuid() or stat.S_IMODE(st.st_mode) != 0o700 or \
                os.listdir(fd):
            os.close(fd)
            return False
        self.fd = fd
        # Where the system can name a file through an open folder (Linux), writers given a
        # path reach the file through the descriptor too, not through the folder's name.
        # By this process's id, not ``self``: the path then works for other programs of the
        # same user (a subprocess writing the file), and still never for another user.
        proc = f"/proc/{os.getpid()}/fd/{fd}"
        if os.path.isdir(proc):
            self.temp = os.path.join(proc, self.name)
        return True

    def open(self):
        """Create the temporary file (never through a link) and return it open for writing."""
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) \
            | getattr(os, "O_BINARY", 0)
        if self.fd is None:
            return os.fdopen(os.open(self.temp, flags, 0o666), "wb")
        return os.fdopen(os.open(self.name, flags, 0o666, dir_fd=self.fd), "wb")

    def _stat(self):
        if self.fd is None:
            return os.lstat(self.temp)
        return os.stat(self.name, dir_fd=self.fd, follow_symlinks=False)

    def check(self, opened=None):
        """Raise unless the temporary file is a regular file (the one ``opened``, if given)."""
        try:
            st = self._stat()
        except FileNotFoundError:
            raise OSError(f"the temporary file {self.temp!r} was removed or its folder "
                          "replaced before it was complete; nothing was written.") from None
        if not stat.S_ISREG(st.st_mode) or (
                opened is not None and (st.st_ino, st.st_dev) != (opened.st_ino, opened.st_dev)):
            raise OSError(f"the temporary file {self.temp!r} was replaced (by a link or "
                          "another file) before it was published; nothing was written.")

    def publish(self, path, overwrite):
        """Move the complete temporary file onto ``path`` (replacing a link there, unfollowed)."""
        src = dict(src_dir_fd=self.fd) if self.fd is not None else {}
        name = self.name if self.fd is not None else self.temp
        move = os.rename if self.fd is not None else os.replace
        if overwrite:
            move(name, path, **src)
            return
        try:
            # Fails if ``path`` exists, even as a dangling link: no check-then-write race.
            os.link(name, path, follow_symlinks=False, **src)
        except FileExistsError:
            raise FileExistsError(
                f"{path} exists; pass overwrite=True (or --overwrite) to replace it.") from None
        except (OSError, NotImplementedError):
            # File systems without hard links (FAT, some network shares).
            if os.path.lexists(path):
                raise FileExistsError(
                    f"{path} exists; pass overwrite=True (or --overwrite) to replace it.") \
                    from None
            move(name, path, **src)

    def close(self):
        """Remove what is left: the temporary file (if not published) and the folder."""
        with contextlib.suppress(OSError):
            if self.fd is None:
                os.unlink(self.temp)
            else:
                os.unlink(self.name, dir_fd=self.fd)
        if self.fd is not None:
            os.close(self.fd)
        with contextlib.suppress(OSError):
            os.rmdir(self.path)


#: What to do about a write that failed, by the system's error.
_WRITE_ADVICE = {
    errno.ENOSPC: "the disk is full; free some space or write to another disk",
    errno.EDQUOT: "the disk quota is exceeded; free some space or write to another disk",
    errno.EACCES: "permission denied; choose a folder you can write to",
    errno.EPERM: "the operation is not permitted there; choose a folder you can write to",
    errno.EROFS: "the file system is read-only; choose a folder you can write to",
    errno.ENOENT: "the folder was removed while writing; create it again or give another one",
}


def _write_failure(exc, path):
    """
    A clear `OSError` for a write of ``path`` that failed with ``exc``, or None.

    Writers of other libraries can fail on their own objects while they handle a full disk
    (astropy.io.fits raises ``AttributeError: 'list' object has no attribute '_file'`` when
    it checks the free space of a file object): the system's error is found in the chain.
    """
    os_error, seen = exc, set()  # the OSError that exc is, or was raised while handling
    while os_error is not None and not isinstance(os_error, OSError):
        if id(os_error) in seen:
            return None
        seen.add(id(os_error))
        os_error = os_error.__cause__ or os_error.__context__
    if os_error is None:
        return None
    code = os_error.errno
    if code is None:
        # A short write (numpy's "N requested and M written") carries no error number.
        with contextlib.suppress(OSError):
            if shutil.disk_usage(os.path.dirname(os.path.abspath(path))).free < 65536:
                code = errno.ENOSPC
    if code is None:
        return OSError(f"cannot write {path}: {os_error}; nothing was written.")
    advice = _WRITE_ADVICE.get(code, os.strerror(code))
    clear = OSError(f"cannot write {path}: {advice} ({os.strerror(code)}); nothing was written.")
    clear.errno = code  # the message stays as written (no "[Errno N]" prefix)
    return clear


@contextlib.contextmanager
def _clear_write_errors(path):
    """Re-raise a failed write as one clear `OSError` (what, where, what to do)."""
    try:
        yield
    except (FileExistsError, FileNotFoundError):
        raise
    except Exception as exc:
        clear = _write_failure(exc, path)
        if clear is None:
            raise
        raise clear from exc


@contextlib.contextmanager
def atomic_write(path, overwrite=False):
    """
    Context manager giving a temporary path that becomes ``path`` on success.

    Write the whole file to the yielded path; when the block ends without
    an exception, the file is moved onto ``path``.  On any exception
    (including `KeyboardInterrupt`) the temporary file is removed and
    ``path`` is left as it was.

    The temporary file lives in a new folder beside ``path`` that only this
    user can enter (mode 0700), so nobody else can read the data while it
    is written or swap the file for a link; before the move, the file is
    checked to be a regular file, and the move never follows a link.  The
    temporary name has a bounded length, whatever the length of ``path``.

    The yielded path is for writers that take only a name (another
    program).  On Linux it names the file through the folder's open
    descriptor; on other systems it goes through the folder's name, which
    another user of a shared folder without the sticky bit could rename, so
    a writer that takes a file object is safer with `atomic_open` (the
    package's own writers use it).

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
        Where to write (a file in a private folder beside ``path``).

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
    with _PrivateFolder.publishing(path, overwrite) as private:
        yield private.temp
        private.check()


@contextlib.contextmanager
def atomic_open(path, overwrite=False):
    """
    Context manager giving a binary file, open for writing, that becomes ``path`` on success.

    As `atomic_write`, but the package creates and opens the temporary file
    itself (never through a link; on POSIX relative to the private folder's
    descriptor), so not even renaming that folder can redirect the data.

    Parameters
    ----------
    path : str or path-like
        The final file name.  Its folder must exist.
    overwrite : bool, optional
        Replace ``path`` if it exists (default False: `FileExistsError`).

    Yields
    ------
    file : file object
        Open in ``"wb"`` mode; closed when the block ends.

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.io.write import atomic_open
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "notes.bin")
    ...     with atomic_open(path) as f:
    ...         _ = f.write(b"complete")
    ...     with open(path, "rb") as f:
    ...         print(f.read(), os.listdir(folder))
    b'complete' ['notes.bin']
    """
    with _PrivateFolder.publishing(path, overwrite) as private:
        with private.open() as f:
            opened = os.fstat(f.fileno())
            yield f
        private.check(opened)


def write_ccddata(ccd, path, *, overwrite=False, extra_hdus=(), **kwargs):
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
    extra_hdus : sequence of `~astropy.io.fits.ImageHDU`, optional
        Written after the CCDData's own extensions (a drizzle's ``WEIGHT``).
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
    path = os.fspath(path)
    if extra_hdus:
        hdul = ccd.to_hdu(**kwargs)
        hdul.extend(extra_hdus)

        def write(fh):
            hdul.writeto(fh)
    else:
        def write(fh):
            ccd.write(fh, format="fits", **kwargs)
    with atomic_open(path, overwrite=overwrite) as f:
        if path.lower().endswith(".gz"):
            # astropy compresses by the file name's ending; a file object needs the wrapper.
            name = os.path.basename(path)[:-3]
            with gzip.GzipFile(filename=name, mode="wb", fileobj=f) as gz:
                write(gz)
        else:
            write(f)


def write_table(table, path, *, format, overwrite=False):
    """
    Write an `~astropy.table.Table` atomically, through the file the
    package opened itself (`atomic_open`): no name of the temporary file is
    ever handed to another library, on any system.

    Parameters
    ----------
    table : `~astropy.table.Table`
    path : str or path-like
        The final file name.  Its folder must exist.
    format : str
        The `~astropy.table.Table.write` format (``"ascii.ecsv"``,
        ``"ascii.csv"``, ``"fits"``, ...).
    overwrite : bool, optional
        Replace ``path`` if it exists (default False: `FileExistsError`).

    Raises
    ------
    TypeError
        If ``table`` is not a `~astropy.table.Table`.
    ValueError
        If astropy cannot write ``format``.  Nothing is written.
    FileExistsError
        If ``path`` exists and ``overwrite`` is False.

    Examples
    --------
    >>> import os, tempfile
    >>> from astropy.table import Table
    >>> from astroalign_nd.io.write import write_table
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = os.path.join(folder, "pairs.ecsv")
    ...     write_table(Table({"x": [1.5, 2.5]}), path, format="ascii.ecsv")
    ...     print(Table.read(path)["x"].tolist())
    [1.5, 2.5]
    """
    from astropy.io import registry
    from astropy.table import Table

    if not isinstance(table, Table):
        raise TypeError(f"table must be an astropy Table, not {type(table).__name__}; "
                        "wrap columns with astropy.table.Table(...).")
    formats = [str(f) for f in registry.get_formats(Table, "Write")["Format"]]
    if not isinstance(format, str) or format not in formats:
        raise ValueError(f"format {format!r} is not a Table format astropy can write; "
                         "pass one of 'ascii.ecsv', 'ascii.csv', 'fits', 'votable', ...")
    with atomic_open(path, overwrite=overwrite) as f:
        if format.startswith("ascii"):
            # The ASCII writers write text: a wrapper over the binary file,
            # detached (not closed) so that atomic_open checks and closes it.
            text = io.TextIOWrapper(f, encoding="utf-8", newline="")
            table.write(text, format=format)
            text.flush()
            text.detach()
        else:
            table.write(f, format=format)


@contextlib.contextmanager
def interrupts_held():
    """
    Hold SIGINT and SIGTERM (and Windows' SIGBREAK) until the block is done, then
    raise them as their handlers do: what the block changes is changed entirely or not
    at all.  Only signals with a Python handler are held (a default SIGTERM still ends
    the process at once: the files are written atomically, the old ones stay).

    Examples
    --------
    A Ctrl-C during the block is raised once both counters have changed:

    >>> import signal
    >>> from astroalign_nd.io.write import interrupts_held
    >>> counts = {"frames": 0, "pixels": 0}
    >>> try:
    ...     with interrupts_held():
    ...         counts["frames"] += 1
    ...         signal.raise_signal(signal.SIGINT)
    ...         counts["pixels"] += 100
    ... except KeyboardInterrupt:
    ...     print("interrupted after", counts)
    interrupted after {'frames': 1, 'pixels': 100}
    """
    if threading.current_thread() is not threading.main_thread():
        yield  # handlers can only be set, and signals only arrive, in the main thread
        return
    caught, old = [], {}
    for name in ("SIGINT", "SIGTERM", "SIGBREAK"):
        signum = getattr(signal, name, None)
        handler = None if signum is None else signal.getsignal(signum)
        if callable(handler):
            old[signum] = signal.signal(signum, lambda num, frame: caught.append((num, frame)))
    try:
        yield
    finally:
        for signum, handler in old.items():
            signal.signal(signum, handler)
        if caught:
            old[caught[0][0]](*caught[0])


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
    check_writable_dir(os.path.dirname(os.path.abspath(path)))


def same_file(a, b):
    """True if the two paths name one file (by real path, or as hard links)."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)  # hard links, case-insensitive file systems
    except OSError:
        return False


def check_not_input(output, inputs):
    """
    Refuse an output path that is one of the inputs (compared by real path).

    Writing the result over an input would destroy it, with or without
    ``overwrite``: the source or the reference frame may be the only copy
    of a night's data.

    Parameters
    ----------
    output : str or path-like
        The output file name.
    inputs : iterable of str or path-like
        The input file names (other kinds of input are ignored).

    Raises
    ------
    ValueError
        If ``output`` names the same file as one of ``inputs`` (through a
        link, a ``..`` or a hard link too).

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.io.write import check_not_input
    >>> with tempfile.TemporaryDirectory() as folder:  # doctest: +ELLIPSIS
    ...     target = os.path.join(folder, "target.fits")
    ...     open(target, "wb").close()
    ...     check_not_input(os.path.join(folder, "aligned.fits"), [target])  # fine
    ...     try:
    ...         check_not_input(os.path.join(folder, ".", "target.fits"), [target])
    ...     except ValueError as exc:
    ...         print(exc)
    output ...target.fits is the input ...target.fits: writing it would destroy that input;
    give another output name.
    """
    output = os.fspath(output)
    for item in inputs:
        if isinstance(item, (str, os.PathLike)) and same_file(output, os.fspath(item)):
            raise ValueError(f"output {output} is the input {os.fspath(item)}: writing it "
                             "would destroy that input; give another output name.")


def check_writable_dir(folder):
    """
    Raise `OSError` with a clear message unless files can be created in ``folder``.

    Examples
    --------
    >>> import tempfile
    >>> from astroalign_nd.io.write import check_writable_dir
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     check_writable_dir(folder)
    """
    if not os.path.isdir(folder):
        what = "is not a folder" if os.path.exists(folder) else "does not exist"
        raise NotADirectoryError(f"output folder {folder!r} {what}.")
    try:
        fd, probe = tempfile.mkstemp(prefix=f"{_TMP_TAG}probe-", dir=folder)
    except OSError as exc:
        raise PermissionError(f"cannot write to output folder {folder!r}: "
                              f"{_advice(exc)}.") from None
    os.close(fd)
    os.unlink(probe)


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
    check_writable_dir(os.fspath(folder))


def make_output_dir(folder, what="output folder"):
    """
    Create ``folder`` (and its parents) if needed, and check that files can be created in it.

    Parameters
    ----------
    folder : str or path-like
    what : str, optional
        How the messages name it (``"--aligned-dir"``...).

    Returns
    -------
    created : list of str
        The folders created, the outermost first: a run that writes nothing removes them
        again (`remove_empty_dirs`).

    Raises
    ------
    OSError
        If it cannot be created or written to: what, where and what to do (not the
        system's bare ``[Errno 1] Operation not permitted``).

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.io.write import make_output_dir, remove_empty_dirs
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     created = make_output_dir(os.path.join(folder, "night", "aligned"))
    ...     print([os.path.basename(p) for p in created])
    ...     remove_empty_dirs(created)
    ...     print(os.listdir(folder))
    ['night', 'aligned']
    []
    """
    folder = os.fspath(folder)
    created, level = [], os.path.abspath(folder)
    while not os.path.lexists(level) and os.path.dirname(level) != level:
        created.insert(0, level)
        level = os.path.dirname(level)
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise NotADirectoryError(f"{what} {folder!r} is a file, not a folder; give a folder.")
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as exc:
        clear = type(exc)(f"cannot create {what} {folder!r}: {_advice(exc)}.")
        clear.errno = exc.errno
        raise clear from None
    try:
        check_writable_dir(folder)
    except OSError:
        remove_empty_dirs(created)
        raise
    return created


def remove_empty_dirs(folders):
    """
    Remove those of ``folders`` (outermost first) that are empty, innermost first.

    A folder that holds anything is kept: only ``os.rmdir`` is used.

    Parameters
    ----------
    folders : list of str
        Folders a run created, outermost first (as ``make_output_dir`` made them).

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.io.write import remove_empty_dirs
    >>> with tempfile.TemporaryDirectory() as top:
    ...     outer = os.path.join(top, "out")
    ...     inner = os.path.join(outer, "plots")
    ...     os.makedirs(inner)
    ...     remove_empty_dirs([outer, inner])
    ...     print(os.path.exists(outer))
    False
    """
    for path in reversed(folders):
        with contextlib.suppress(OSError):
            os.rmdir(path)  # only an empty folder: never anything written into it


def _advice(exc):
    """The system's reason for ``exc`` and what to do about it."""
    code = getattr(exc, "errno", None)
    if code == errno.ENOTDIR:
        return "a part of the path is a file, not a folder; give a folder"
    if code in _WRITE_ADVICE:
        return f"{_WRITE_ADVICE[code]} ({os.strerror(code)})"
    return exc.strerror or str(exc)
