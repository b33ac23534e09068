# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
A transform saved to, and read back from, a file of its own: ASDF or FITS.

`write_transform` and `read_transform` choose the format by the name's
ending: ``.asdf`` (the model in an ASDF tree, through this package's
extension) or a FITS ending (the transform's header keywords, as
`~astroalign_nd.io.transform_to_header` writes them, in a primary HDU
without data; gzip-compressed for a ``.gz`` name).  A file that does not
hold a valid transform is refused with a `ValueError` that names the file
and says what is wrong, never turned into a half-read object.
"""

import gzip
import os
import warnings

import asdf
from astropy.io import fits
from astropy.modeling import Model

from .header import transform_from_header, transform_to_header
from .write import FITS_EXTENSIONS, atomic_open

__all__ = ["read_transform", "write_transform"]

#: The key of the model in an ASDF file written by `write_transform`.
ASDF_KEY = "transform"


def _format(path):
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a file name (str or path-like) ending in .asdf or "
                        f".fits; got {type(path).__name__}.")
    name = os.fspath(path).lower()
    if name.endswith(".asdf"):
        return "asdf"
    if name.endswith(FITS_EXTENSIONS):
        return "fits"
    raise ValueError(f"{os.fspath(path)!r}: a transform file must end in .asdf or one of "
                     f"{', '.join(FITS_EXTENSIONS)} (e.g. 'transform.asdf').")


def write_transform(path, model, *, overwrite=False):
    """
    Save a transform to an ASDF or FITS file, atomically.

    Parameters
    ----------
    path : str or path-like
        ``.asdf`` keeps any model (compound models and a user-assigned
        inverse too); a FITS name (``.fits``, ``.fit``, ``.fts``) keeps what
        the FITS header keywords can hold (linear, projective and polynomial
        transforms, see `~astroalign_nd.io.transform_to_header`).
    model : astropy Model
        The transform.
    overwrite : bool, optional
        Replace an existing file (default False: `FileExistsError`).

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd import SimilarityTransform
    >>> from astroalign_nd.io import read_transform, write_transform
    >>> t = SimilarityTransform(scale=1.01, rotation=3.0, translation_x=5.0)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     for name in ("t.asdf", "t.fits"):
    ...         write_transform(os.path.join(folder, name), t)
    ...     a = read_transform(os.path.join(folder, "t.asdf"))
    ...     f = read_transform(os.path.join(folder, "t.fits"))
    >>> type(a).__name__, type(f).__name__, round(float(f.rotation.value), 6)
    ('SimilarityTransform', 'SimilarityTransform', 3.0)
    """
    if not isinstance(model, Model):
        raise TypeError(f"model must be an astropy Model (a transform); got "
                        f"{type(model).__name__}.")
    kind = _format(path)
    with atomic_open(path, overwrite=overwrite) as f:
        if kind == "asdf":
            asdf.AsdfFile({ASDF_KEY: model}).write_to(f)
        elif os.fspath(path).lower().endswith(".gz"):
            # As write_ccddata: astropy compresses by a name's ending, not a file object's.
            name = os.path.basename(os.fspath(path))[:-3]
            with gzip.GzipFile(filename=name, mode="wb", fileobj=f) as gz:
                fits.PrimaryHDU(header=transform_to_header(model)).writeto(gz)
        else:
            fits.PrimaryHDU(header=transform_to_header(model)).writeto(f)


def read_transform(path):
    """
    Read a transform saved by `write_transform` (or by any code, see below).

    Parameters
    ----------
    path : str or path-like
        An ``.asdf`` file whose tree holds the model under ``'transform'``
        (or holds exactly one model at its top level), or a FITS file whose
        primary header holds a transform's keywords (a registered frame
        written by `~astroalign_nd.register` does: its ``AAT*`` keywords).

    Returns
    -------
    model : astropy Model

    Raises
    ------
    ValueError
        If the file is not a readable ASDF or FITS file, or does not hold a
        valid transform (a damaged node such as ``parity: 0`` or a header
        with inconsistent keywords): the message names the file and says
        what is wrong.

    Examples
    --------
    See `write_transform`.
    """
    kind = _format(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"transform file {os.fspath(path)!r} does not exist.")
    try:
        return _read_asdf(path) if kind == "asdf" else _read_fits(path)
    except ValueError as exc:
        raise ValueError(f"{os.fspath(path)!r}: {exc}") from None


def _read_asdf(path):
    with asdf.config_context() as config:
        # asdf turns a converter's error into a warning and a raw tagged dict by default:
        # a damaged transform must be an error here.
        config.warn_on_failed_conversion = False
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error", asdf.exceptions.AsdfConversionWarning)
                with asdf.open(path, lazy_load=False, memmap=False) as af:
                    tree = {k: v for k, v in af.tree.items() if not k.startswith("asdf_")}
        except asdf.exceptions.ValidationError as exc:
            # Before asdf 6, a value the schema refuses (parity 0, a list for the
            # scale) stops here, before our converter sees it.
            where = "/".join(str(p) for p in exc.path) or "the tree"
            raise ValueError(f"a damaged ASDF transform file: {where}: {exc.message}.") from None
        except (asdf.exceptions.AsdfWarning, OSError, KeyError, TypeError) as exc:
            raise ValueError(f"not a readable ASDF transform file ({exc}).") from None
    if isinstance(tree.get(ASDF_KEY), Model):
        return tree[ASDF_KEY]
    models = [k for k, v in tree.items() if isinstance(v, Model)]
    if len(models) == 1:
        return tree[models[0]]
    raise ValueError(f"no transform under {ASDF_KEY!r}, and {len(models)} models at the top "
                     f"of the tree ({', '.join(map(repr, models)) or 'keys: ' + repr(list(tree))})"
                     "; read it with asdf.open and pick the model.")


def _read_fits(path):
    try:
        header = fits.getheader(path, 0)
    except (OSError, TypeError) as exc:
        raise ValueError(f"not a readable FITS file ({exc}).") from None
    return transform_from_header(header)
