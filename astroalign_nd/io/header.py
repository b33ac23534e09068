# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Write a 2-D transform into a FITS header and read it back.

The transform is stored as ``<prefix>*`` keywords (``AAT*`` by default):

==============  ===========================================================
Keyword         Content
==============  ===========================================================
``AATTYPE``     Transform class: 'translation', 'euclidean', 'similarity',
                'affine', 'projective' or 'polynomial'
``AATM00`` ...  The elements ``(i, j)`` of the 3x3 homogeneous matrix
``AATM12``      ``[[M00, M01, M02], [M10, M11, M12], [0, 0, 1]]`` (floats);
                for 'projective' also ``AATM20``, ``AATM21`` (the last
                row is ``[M20, M21, 1]``); for 'polynomial' the linear part
                ``[[a11, a12, translation_x], [a21, a22, translation_y]]``
``AATM00S`` ..  The same elements as strings with all 17 significant
``AATM12S``     digits (``repr``): a FITS float card holds 20 characters,
                which astropy fills by rounding the mantissa
``AATDEG``      'polynomial' only: the degree, 2 to 5
``AATCRP1``,    'polynomial' only: the reference pixel ``crpix1, crpix2``
``AATCRP2``     (0-based), with ``AATCRP1S``, ``AATCRP2S`` exact strings
``AATA20`` ...  'polynomial' only: the coefficients ``A_p_q``, ``B_p_q``
``AATB05``      (``AATApq``, ``AATBpq``), each with an exact ``...S`` string
``AATDXMIN``,   'polynomial' only, when the model has a domain: the box
``AATDXMAX``,   of source pixels (x min and max, y min and max) the
``AATDYMIN``,   inverse is fitted over
``AATDYMAX``
``AATSCALE``    Scale (translation, euclidean, similarity), or
``AATSCALX``,   scale along x and y (affine)
``AATSCALY``
``AATROT``      Rotation in degrees, counter-clockwise
``AATSHEAR``    Shear in degrees (affine only)
``AATTX``       Translation along x, target pixels
``AATTY``       Translation along y, target pixels
``AATPAR``      Parity: +1 proper, -1 mirrored
==============  ===========================================================

`add_provenance` adds, for a registered frame, the quality of the fit
(`QUALITY_KEYWORDS`: ``AATNMAT``, ``AATRMS``, ``AATLFA``) and ``HISTORY``
cards saying what was done.  These are all the keywords astroalign_nd
writes; ``add_keyword=False`` (`~astroalign_nd.register`,
`~astroalign_nd.apply_transform`) leaves every one of them out, as
ccdproc's ``add_keyword`` does.

The transform is rebuilt from ``AATTYPE`` and the matrix (the strings when
present, else the floats), with the polynomial's keywords; the other
keywords are for people reading the header.  The matrix maps 0-based source
pixel coordinates ``(x, y)`` onto target pixel coordinates, like the models
of `astroalign_nd.transforms`.

SIP distortion (`~astroalign_nd.io.distorted_wcs`) is in
``astroalign_nd.io.sip``.
"""

from __future__ import annotations

import datetime
import re
from collections.abc import Mapping
import textwrap
import warnings

import numpy as np
from astropy.io import fits
from astropy.modeling import Model
from astropy.utils.exceptions import AstropyUserWarning

from .. import __version__
from ..exceptions import warn
from ..transforms.polynomial import PolynomialTransform
from ..transforms.projective import ProjectiveTransform
from ..transforms.registry import TRANSFORM_REGISTRY, transform_type_of
from ..transforms.linear import AffineTransform, EuclideanTransform, SimilarityTransform
from ..transforms.convert import as_matrix

__all__ = ["transform_to_header", "transform_from_header", "add_provenance",
           "QUALITY_KEYWORDS", "header_from_meta", "header_without_wcs", "fits_text",
           "check_quality"]

#: The fit-quality keywords of a registered frame: suffix (after the prefix),
#: the ``transform.meta['quality']`` entry, decimals kept, and comment.
QUALITY_KEYWORDS = (
    ("NMAT", "n_matches", None, "astroalign_nd: matched stars"),
    ("RMS", "rms", 6, "astroalign_nd: fit RMS [px]"),
    ("LFA", "log10_false_alarm", 3, "astroalign_nd: log10 false-alarm probability"),
)

# The elements of the 3x3 matrix, row by row (a type's ``matrix_rows`` of them are stored).
_MATRIX_ROWS = (("00", "01", "02"), ("10", "11", "12"), ("20", "21"))
_MATRIX_INDICES = _MATRIX_ROWS[0] + _MATRIX_ROWS[1]
_HUMAN_SUFFIXES = ("SCALE", "SCALX", "SCALY", "ROT", "SHEAR", "TX", "TY", "PAR")
_PREFIX_RE = re.compile(r"^[A-Z0-9_-]+$")
_FITS_KEY = re.compile(r"^[A-Z0-9_-]{1,8}$")
# The float cards round to >= 13 significant digits; the exact strings must agree.
_CONSISTENCY_RTOL = 1e-12


def _suffixes():
    """Every keyword suffix this module may write (the registered types' hooks' too)."""
    indices = [ij for row in _MATRIX_ROWS for ij in row]
    hooks = [e.header for e in TRANSFORM_REGISTRY.values() if e.header is not None]
    return list(dict.fromkeys(["TYPE", *(f"M{ij}" for ij in indices),
                               *(f"M{ij}S" for ij in indices), *_HUMAN_SUFFIXES,
                               *(s for h in hooks for s in h.suffixes)]))


def _check_prefix(prefix):
    if not isinstance(prefix, str):
        raise TypeError(f"prefix must be a string; got {type(prefix).__name__}.")
    upper = prefix.upper()
    # Every suffix must fit the 8-character FITS keyword with the prefix.
    max_prefix = 8 - max(len(s) for s in _suffixes())
    if not (1 <= len(upper) <= max_prefix) or not _PREFIX_RE.match(upper):
        raise ValueError(
            f"prefix must be 1 to {max_prefix} characters among A-Z, 0-9, '_' and '-' so "
            f"that every keyword (e.g. {upper or 'AAT'}SCALE) fits the 8-character FITS "
            f"limit; got {prefix!r}."
        )
    return upper


def _indices(entry):
    """The matrix elements stored for a type."""
    return tuple(ij for row in _MATRIX_ROWS[:entry.matrix_rows] for ij in row)


def _model_matrix(model):
    if not isinstance(model, Model):
        raise TypeError(
            "model must be an astropy model (an astroalign_nd transform or an affine "
            f"2-D astropy model); got {type(model).__name__}. To store a matrix, build a "
            "transform first with astroalign_nd.transforms.from_matrix."
        )
    if len(model) != 1:
        raise ValueError(
            f"model holds {len(model)} parameter sets; a FITS header stores a single "
            "transform."
        )
    entry = transform_type_of(model)
    if entry is None:  # any other astropy model, which must be affine
        try:
            matrix = as_matrix(model)
        except (TypeError, ValueError) as exc:
            raise ValueError(
                f"only the astroalign_nd transforms and linear 2-D astropy models (2 inputs, 2 "
                f"outputs, affine) can go into a FITS header; {type(model).__name__} is not one "
                f"({exc}). Save it to an ASDF file instead: asdf.AsdfFile({{'transform': "
                "model}).write_to('transform.asdf')."
            ) from None
    elif entry.header is not None:
        matrix = entry.header.matrix(model)  # (a polynomial: its linear part about crpix)
    else:
        matrix = model.matrix
    if not np.all(np.isfinite(matrix)):
        raise ValueError("the transform's matrix contains NaN or infinite values.")
    return matrix


def _degrees(angle):
    """Angle in degrees wrapped to (-180, 180]."""
    if -180.0 < angle <= 180.0:
        return float(angle)  # unchanged, so that it reads back bit for bit
    rad = np.deg2rad(angle)
    degrees = float(np.degrees(np.arctan2(np.sin(rad), np.cos(rad))))
    return 180.0 if degrees == -180.0 else degrees


def _human_cards(entry, model, matrix):
    """The readable ``(suffix, value, comment)`` cards of the transform."""
    if not entry.linear:
        return [("TX", float(matrix[0, 2]), "[px] translation along x"),
                ("TY", float(matrix[1, 2]), "[px] translation along y")]
    if not entry.conformal:
        affine = AffineTransform.from_matrix(matrix)
        sx, sy = affine.scale
        cards = [
            ("SCALX", float(sx), "[tgt px / src px] scale along x"),
            ("SCALY", float(sy), "[tgt px / src px] scale along y"),
            ("ROT", _degrees(affine.rotation), "[deg] rotation of the x axis, CCW"),
            ("SHEAR", _degrees(affine.shear), "[deg] shear angle"),
        ]
    else:
        # (A Parameter on the models that fit them, a number on the others.)
        scale = getattr(model.scale, "value", model.scale)
        rotation = getattr(model.rotation, "value", model.rotation)
        cards = [
            ("SCALE", float(scale), "[tgt px / src px] scale factor"),
            ("ROT", _degrees(rotation), "[deg] rotation, counter-clockwise"),
        ]
    parity = -1 if np.linalg.det(matrix[:2, :2]) < 0 else 1
    cards += [
        ("TX", float(matrix[0, 2]), "[px] translation along x"),
        ("TY", float(matrix[1, 2]), "[px] translation along y"),
        ("PAR", parity, "parity: +1 proper, -1 mirrored"),
    ]
    return cards


def transform_to_header(model: Model, header: fits.Header | Mapping | None = None, *,
                        prefix: str = "AAT", copy: bool = True) -> fits.Header:
    """
    Store a 2-D transform in a FITS header.

    Parameters
    ----------
    model : `~astropy.modeling.Model`
        The transform.  An astroalign_nd transform keeps its class
        (including `~astroalign_nd.ProjectiveTransform` and
        `~astroalign_nd.PolynomialTransform`); any other astropy model with
        2 inputs and 2 outputs that is affine (e.g. ``Shift(1) & Shift(2) |
        Rotation2D(30)`` or
        `~astropy.modeling.projections.AffineTransformation2D`) is stored
        as ``'affine'``.
    header : `~astropy.io.fits.Header` or dict-like, optional
        Header to start from.  It is copied, never modified; existing
        ``<prefix>*`` transform keywords in it are replaced.
    prefix : str, optional
        Keyword prefix, 1 to 3 characters (default ``'AAT'``), so that the
        keywords stay within the 8-character FITS limit.
    copy : bool, optional
        If False and ``header`` is a `~astropy.io.fits.Header`, add the
        keywords to it and return it (no copy: for a header of many
        thousand cards that the caller made itself).  Default True.

    Returns
    -------
    header : `~astropy.io.fits.Header`
        A new header with the transform keywords added (``header`` itself
        if ``copy=False``).

    Raises
    ------
    ValueError
        If the model is neither an astroalign_nd transform nor an affine 2-D
        astropy model (use ASDF for those), or the prefix is not valid.
    TypeError
        If ``model`` is not an astropy model.

    Notes
    -----
    Only the forward transform is stored: a user-assigned ``inverse`` is
    dropped with a warning (the analytic inverse is rebuilt on reading; a
    polynomial's inverse is fitted again over its stored domain, which
    gives the same inverse).

    Examples
    --------
    >>> from astroalign_nd.transforms import SimilarityTransform
    >>> from astroalign_nd.io import transform_to_header, transform_from_header
    >>> t = SimilarityTransform(scale=1.5, rotation=30.0, translation_x=3.0,
    ...                         translation_y=-2.0)
    >>> hdr = transform_to_header(t)
    >>> hdr["AATTYPE"]
    'similarity'
    >>> t2 = transform_from_header(hdr)
    >>> type(t2).__name__
    'SimilarityTransform'

    A polynomial model, with its distortion coefficients:

    >>> from astroalign_nd import PolynomialTransform
    >>> p = PolynomialTransform(degree=2, crpix=(511.5, 511.5), translation_x=500.0,
    ...                         translation_y=520.0, A_2_0=1e-6, B_1_1=-3e-7)
    >>> hdr = transform_to_header(p)
    >>> hdr["AATTYPE"], hdr["AATDEG"], hdr["AATA20"], hdr["AATB11"]
    ('polynomial', 2, 1e-06, -3e-07)
    >>> transform_from_header(hdr)(100.0, 200.0) == p(100.0, 200.0)
    True
    """
    prefix = _check_prefix(prefix)
    matrix = _model_matrix(model)
    if getattr(model, "has_user_inverse", False):
        warn(
            "the model has a user-assigned inverse, which a FITS header cannot hold; only "
            "the forward transform is stored (save to ASDF to keep the inverse).",
            AstropyUserWarning,
        )
    # Any other (affine) astropy model is stored as 'affine'.
    entry = transform_type_of(model) or TRANSFORM_REGISTRY["affine"]

    if header is None:
        out = fits.Header()
    elif isinstance(header, fits.Header):
        out = header.copy() if copy else header
    else:
        try:
            out = fits.Header(header)
        except (TypeError, ValueError, AttributeError, KeyError) as exc:
            raise TypeError(
                "header must be an astropy.io.fits.Header, a dict-like of keywords or None; "
                f"got {type(header).__name__} ({exc})."
            ) from None
    present = set(out.keys())  # (looking up all ~100 keywords costs more)
    for key in (prefix + name for name in _suffixes()):
        if key in present:
            out.remove(key, remove_all=True)

    out[prefix + "TYPE"] = (entry.name, "astroalign_nd transform class")
    indices = _indices(entry)
    what = "linear part (about AATCRP)" if entry.header is not None else "transform matrix"
    for ij in indices:
        value = float(matrix[int(ij[0]), int(ij[1])])
        out[f"{prefix}M{ij}"] = (value, f"{what} element ({ij[0]},{ij[1]})")
    for ij in indices:
        value = float(matrix[int(ij[0]), int(ij[1])])
        out[f"{prefix}M{ij}S"] = (repr(value), f"{prefix}M{ij}, all digits")
    if entry.header is not None:
        cards = entry.header.cards(model)
    else:
        cards = [(*card, False) for card in _human_cards(entry, model, matrix)]
    for suffix, value, comment, exact in cards:
        out[prefix + suffix] = (value, comment)
        if exact:
            out[prefix + suffix + "S"] = (repr(value), f"{prefix}{suffix}, all digits")
    return out


class _Reader:
    """A header's keywords by suffix, for a type's `HeaderHooks.read`."""

    def __init__(self, header, prefix):
        self.header, self.prefix = header, prefix

    def key(self, suffix):
        return self.prefix + suffix

    def has(self, suffix):
        return self.prefix + suffix in self.header

    def get(self, suffix, default=None):
        return self.header.get(self.prefix + suffix, default)

    def exact(self, suffix, what):
        return _read_exact(self.header, self.prefix + suffix, self.prefix + "TYPE", what)

    def matrix(self):
        return _read_matrix(self.header, self.prefix)


def _read_matrix(header, prefix, indices=_MATRIX_INDICES):
    matrix = np.eye(3)
    for ij in indices:
        matrix[int(ij[0]), int(ij[1])] = _read_exact(header, f"{prefix}M{ij}",
                                                     f"{prefix}TYPE", "the transform matrix")
    return matrix


def _read_exact(header, key, type_key, what):
    """A number stored as a float card ``key`` and (optionally) an exact string ``key + 'S'``."""
    skey = key + "S"
    if key not in header and skey not in header:
        raise ValueError(f"header has {type_key} but no {key}: {what} is incomplete.")
    exact = None
    if skey in header:
        try:
            exact = float(header[skey])
        except (TypeError, ValueError):
            raise ValueError(
                f"header keyword {skey} must hold a number as a string; got "
                f"{header[skey]!r}."
            ) from None
    rounded = header.get(key)
    if rounded is not None and (
        isinstance(rounded, bool) or not isinstance(rounded, (int, float, np.number))
    ):
        raise ValueError(f"header keyword {key} must be a real number; got {rounded!r}.")
    if exact is not None and rounded is not None:
        if abs(float(rounded) - exact) > _CONSISTENCY_RTOL * max(abs(exact), 1e-300):
            raise ValueError(
                f"header keywords {key} = {rounded!r} and {skey} = {header[skey]!r} "
                f"disagree; was one of them edited? Fix or remove {skey}."
            )
    value = exact if exact is not None else float(rounded)
    if not np.isfinite(value):
        raise ValueError(f"header keyword {key} must be a finite number; got {value!r}.")
    return value


def fits_text(text):
    """
    ``text`` with every character a FITS header cannot hold escaped.

    FITS cards hold printable ASCII only; other characters (a non-ASCII
    file name, a newline) become Python escapes such as ``\\xe9``.

    Examples
    --------
    >>> from astroalign_nd.io.header import fits_text
    >>> print(fits_text("caf\\u00e9\\nnoir"))
    caf\\xe9\\nnoir
    >>> fits_text("M 31")
    'M 31'
    """
    text = str(text)
    return "".join(c if 32 <= ord(c) < 127 else ascii(c)[1:-1] for c in text)


def _meta_card(key, value, escaped):
    """The FITS card of one meta entry, or None if a card cannot hold it."""
    if not isinstance(key, str) or not key or fits_text(key) != key or "=" in key:
        return None
    # Keys that are not standard FITS keywords (ccdproc's ``subtract_bias``,
    # long or lower-case names) become HIERARCH cards rather than being lost.
    card_key = key if _FITS_KEY.match(key.upper()) else f"HIERARCH {key}"
    comment = None
    if isinstance(value, tuple) and len(value) == 2 and isinstance(value[1], str):
        # astropy's (value, comment) convention, as ccdproc stores its steps.
        value, comment = value[0], fits_text(value[1])
    if isinstance(value, (np.generic,)):
        value = value.item()
    if isinstance(value, str):
        safe = fits_text(value)
        if safe != value:
            escaped.append(key)
        value = safe
    elif isinstance(value, float) and not np.isfinite(value):
        return None
    elif not isinstance(value, (bool, int, float)):
        return None
    if not isinstance(value, str) and not card_key.startswith("HIERARCH") and comment is None:
        return fits.Card(card_key, value)  # a number on a FITS keyword: always a valid card
    card = _checked_card(card_key, value, comment)
    if card is None and isinstance(value, str) and card_key.startswith("HIERARCH"):
        # A HIERARCH card cannot continue: a long value (ccdproc's
        # ``subtract_bias`` history) is shortened to fit one card.
        room = 80 - len(card_key) - 6
        if room >= 8:
            card = _checked_card(card_key, value[:room - 3] + "...", None)
    return card


def _checked_card(key, value, comment):
    """``fits.Card(key, value, comment)``, formatted once to check it, or None if it cannot be."""
    try:
        card = fits.Card(key, value, comment)
        card.image  # noqa: B018 - formatting is where a card that cannot be written fails
        return card
    except (ValueError, TypeError, KeyError):
        return None


def header_from_meta(meta):
    """
    A FITS header holding what a FITS header can of ``meta``.

    A `~astropy.io.fits.Header` is copied as it is.  From another mapping
    (e.g. ``NDData.meta``), keys that are not standard FITS keywords become
    HIERARCH cards (a string too long for one is shortened), ``(value,
    comment)`` tuples become commented cards; entries whose key is not
    printable ASCII or whose value a card cannot hold (NaN, infinity,
    nested containers, objects) are skipped, and strings with non-ASCII
    characters are escaped (`fits_text`), with one warning that lists them:
    a registration is never lost at the end for a header card.

    Returns
    -------
    header : `~astropy.io.fits.Header`

    Examples
    --------
    >>> from astroalign_nd.io.header import header_from_meta
    >>> hdr = header_from_meta({"OBJECT": "M31", "exposure_time": (60.0, "seconds")})
    >>> hdr["OBJECT"], hdr["exposure_time"], hdr.comments["exposure_time"]
    ('M31', 60.0, 'seconds')
    >>> list(hdr.keys())
    ['OBJECT', 'exposure_time']
    """
    if isinstance(meta, fits.Header):
        return meta.copy()
    out = fits.Header()
    skipped, escaped = [], []
    try:
        items = list(dict(meta or {}).items())
    except (TypeError, ValueError):
        warn(f"meta of type {type(meta).__name__} is not a mapping; the output header "
             "starts empty.")
        return out
    cards, where = [], {}
    for key, value in items:
        card = _meta_card(key, value, escaped)
        if card is None:
            skipped.append(key)
        elif card.keyword in where and card.keyword not in ("HISTORY", "COMMENT", ""):
            cards[where[card.keyword]] = card  # 'object' then 'OBJECT': one card, as assigned
        else:
            where[card.keyword] = len(cards)
            cards.append(card)
    # One header from all the cards: assigning them one at a time looks every keyword up
    # again (20,000 keys took 28 s).
    out = fits.Header(cards)
    if skipped or escaped:
        parts = []
        if skipped:
            parts.append(f"skipped {skipped} (not FITS keywords, or values such as NaN, "
                         "infinity or containers that a card cannot hold)")
        if escaped:
            parts.append(f"escaped the non-ASCII characters of {escaped}")
        warn("writing meta into the FITS header: " + "; ".join(parts) + ".")
    return out


#: The fit figures `check_quality` requires, and their types.
# Keywords that start a celestial WCS description.
_WCS_PREFIXES = ("CTYPE", "CRPIX", "CRVAL", "CDELT", "CUNIT", "CROTA", "CD1_", "CD2_", "PC1_",
                 "PC2_", "WCSAXES", "A_", "B_", "AP_", "BP_", "LONPOLE", "LATPOLE", "RADESYS",
                 "EQUINOX", "PV1_", "PV2_", "PS1_", "PS2_")


def header_without_wcs(header: fits.Header, *, copy: bool = True) -> fits.Header:
    """
    A copy of ``header`` without its celestial WCS cards.

    A resampled frame's WCS is the target's (or the source's, carried
    through the transform): the source's cards describe the old pixel grid.

    Parameters
    ----------
    header : `~astropy.io.fits.Header`
    copy : bool, optional
        If False, remove the cards from ``header`` itself and return it.
        Default True (``header`` is not modified).

    Returns
    -------
    header : `~astropy.io.fits.Header`
        A new header; ``header`` is not modified.

    Examples
    --------
    >>> from astropy.io import fits
    >>> from astroalign_nd.io.header import header_without_wcs
    >>> hdr = fits.Header({"OBJECT": "M31", "CTYPE1": "RA---TAN", "CTYPE2": "DEC--TAN",
    ...                    "CRVAL1": 10.7, "CRVAL2": 41.3, "CRPIX1": 128.0, "CRPIX2": 128.0,
    ...                    "CDELT1": -3e-4, "CDELT2": 3e-4})
    >>> list(header_without_wcs(hdr).keys())
    ['OBJECT']
    >>> len(hdr)  # the original keeps its WCS
    9
    """
    from astropy.wcs import WCS, FITSFixedWarning

    h = header.copy() if copy else header
    if not any(k.startswith(_WCS_PREFIXES) for k in h.keys()):
        return h  # nothing to strip (and parsing a WCS costs ~1.5 ms)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FITSFixedWarning)
            wcs_cards = WCS(h).to_header(relax=True)
    except (ValueError, KeyError, TypeError, MemoryError):
        # An unparsable WCS (astropy.wcs raises WcsError, a ValueError):
        # its cards describe the old grid all the same; remove them by name.
        wcs_cards = [k for k in h.keys() if k.startswith(_WCS_PREFIXES)]
    for key in wcs_cards:
        h.remove(key, ignore_missing=True, remove_all=True)
    for key in ("CD1_1", "CD1_2", "CD2_1", "CD2_2", "A_ORDER", "B_ORDER"):
        h.remove(key, ignore_missing=True, remove_all=True)
    return h


QUALITY_KEYS = ("n_matches", "rms", "log10_false_alarm")


def check_quality(quality):
    """
    Check a ``quality`` dict (as ``transform.meta['quality']`` holds it).

    Returns
    -------
    quality : dict or None
        With ``n_matches`` an int and ``rms``, ``log10_false_alarm`` floats.

    Raises
    ------
    TypeError, ValueError
        If it is not a dict or lacks one of `QUALITY_KEYS`.

    Examples
    --------
    >>> from astroalign_nd.io.header import check_quality
    >>> check_quality({"n_matches": "42", "rms": 0.05, "log10_false_alarm": -80})
    {'n_matches': 42, 'rms': 0.05, 'log10_false_alarm': -80.0}
    >>> check_quality(None) is None
    True
    >>> check_quality({"rms": 0.05})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: quality lacks ['n_matches', 'log10_false_alarm']; it needs ...
    """
    if quality is None:
        return None
    if not isinstance(quality, dict):
        raise TypeError(f"quality must be a dict (transform.meta['quality']) or None; got "
                        f"{type(quality).__name__}.")
    missing = [k for k in QUALITY_KEYS if k not in quality]
    if missing:
        raise ValueError(
            f"quality lacks {missing}; it needs {list(QUALITY_KEYS)} (as find_transform "
            "puts in transform.meta['quality']), or pass quality=None.")
    out = dict(quality)
    try:
        out["n_matches"] = int(quality["n_matches"])
        out["rms"] = float(quality["rms"])
        out["log10_false_alarm"] = float(quality["log10_false_alarm"])
    except (TypeError, ValueError):
        raise ValueError(
            f"quality's {list(QUALITY_KEYS)} must be numbers; got "
            f"{[quality[k] for k in QUALITY_KEYS]!r}.") from None
    if not all(np.isfinite(out[k]) for k in QUALITY_KEYS[1:]):
        raise ValueError("quality's rms and log10_false_alarm must be finite numbers.")
    return out


def transform_from_header(header: fits.Header | Mapping, *,
                          prefix: str = "AAT") -> Model:
    """
    Rebuild a transform stored by `transform_to_header`.

    Parameters
    ----------
    header : `~astropy.io.fits.Header` or dict-like
        The header (e.g. ``hdu.header`` or ``ccddata.meta``).
    prefix : str, optional
        Keyword prefix used when writing (default ``'AAT'``).

    Returns
    -------
    transform : astropy model
        An instance of the class named by ``<prefix>TYPE`` (a
        `~astroalign_nd.transforms.LinearTransform2D`,
        `~astroalign_nd.ProjectiveTransform` or
        `~astroalign_nd.PolynomialTransform`), built from the stored
        keywords.

    Raises
    ------
    ValueError
        If the header has no transform keywords, or they are incomplete or
        inconsistent.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.io import transform_from_header, transform_to_header
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, seed=1)
    >>> hdr = transform_to_header(pair.transform)
    >>> t = transform_from_header(hdr)
    >>> type(t) is type(pair.transform), bool(np.allclose(t.matrix, pair.truth_matrix))
    (True, True)
    >>> transform_from_header({"OBJECT": "M31"})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: header has no astroalign_nd transform keywords (AATTYPE, ...
    """
    prefix = _check_prefix(prefix)
    if not isinstance(header, fits.Header):
        try:
            items = dict(header).items()
        except (TypeError, ValueError, AttributeError, KeyError) as exc:
            raise TypeError(
                "header must be an astropy.io.fits.Header or a dict-like of keywords; got "
                f"{type(header).__name__} ({exc})."
            ) from None
        # Only this transform's keywords: another key may hold a value a FITS
        # header cannot (NaN, a nested dict), which is no concern here.
        header = fits.Header()
        for key, value in items:
            if isinstance(key, str) and key.upper().startswith(prefix):
                try:
                    header[key] = value
                except (ValueError, TypeError, KeyError):
                    continue
    type_key = prefix + "TYPE"
    if type_key not in header:
        raise ValueError(
            f"header has no astroalign_nd transform keywords ({type_key}, {prefix}M00 ... "
            f"{prefix}M12); write them with transform_to_header, or pass the prefix used "
            "when writing."
        )
    type_name = header[type_key]
    if not isinstance(type_name, str) or type_name.strip().lower() not in TRANSFORM_REGISTRY:
        raise ValueError(
            f"header keyword {type_key} must be one of {sorted(TRANSFORM_REGISTRY)}; got "
            f"{type_name!r}."
        )
    entry = TRANSFORM_REGISTRY[type_name.strip().lower()]
    if entry.header is not None:
        return entry.header.read(_Reader(header, prefix))
    cls = entry.cls
    matrix = _read_matrix(header, prefix, _indices(entry))
    try:
        model = cls.from_matrix(matrix)
    except ValueError as exc:
        raise ValueError(
            f"the matrix in the header is not a valid {cls.__name__} ({exc})."
        ) from None
    return _from_written_parameters(header, prefix, model, matrix)


def _from_written_parameters(header, prefix, model, matrix):
    """
    The model rebuilt from its written rotation and scale, when that gives the stored matrix.

    ``from_matrix`` recovers a rotation through ``arctan2``, which can differ
    from the written one in the last bit; the readable ROT/SCALE cards hold
    the model's own parameters, so they are preferred when they reproduce
    the stored matrix exactly (else the matrix wins).
    """
    if not isinstance(model, (EuclideanTransform, SimilarityTransform)):
        return model
    rot, scale = header.get(prefix + "ROT"), header.get(prefix + "SCALE", 1.0)
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (rot, scale)):
        return model
    params = dict(rotation=float(rot), translation_x=matrix[0, 2], translation_y=matrix[1, 2],
                  parity=int(model.parity.value))
    if isinstance(model, SimilarityTransform):
        params["scale"] = float(scale)
    try:
        written = type(model)(**params)
    except (ValueError, TypeError):
        return model
    return written if np.array_equal(written.matrix, matrix) else model


def add_history(header, text):
    """
    HISTORY cards wrapped at word boundaries (FITS cuts long ones mid-word).

    Examples
    --------
    >>> from astropy.io import fits
    >>> from astroalign_nd.io.header import add_history
    >>> header = fits.Header()
    >>> add_history(header, "word " * 30)
    >>> len(header["HISTORY"])
    3
    """
    for line in textwrap.wrap(text, 70, subsequent_indent="  "):
        header.add_history(line)


def add_provenance(header: fits.Header, model: Model, *,
                   quality: dict | None = None, source_name: str = "source",
                   target_name: str = "target", order: str | None = None,
                   conserve_flux: bool = False, prefix: str = "AAT",
                   copy: bool = True) -> fits.Header:
    """
    Record a registration in a header: transform, fit quality and HISTORY.

    Parameters
    ----------
    header : `~astropy.io.fits.Header`
        Copied, never modified.
    model : astropy model
        The source-to-target transform (stored by `transform_to_header`):
        an astroalign_nd transform, linear or not, or an affine astropy
        model.
    quality : dict, optional
        ``transform.meta['quality']``; adds the `QUALITY_KEYWORDS`.
    source_name, target_name : str, optional
        What was registered onto what, for the HISTORY cards.
    order : str, optional
        The resampling kernel.
    conserve_flux : bool, optional
    prefix : str, optional
        Keyword prefix (default ``'AAT'``).
    copy : bool, optional
        If False, add the keywords to ``header`` itself and return it (see
        `transform_to_header`).  Default True.

    Returns
    -------
    header : `~astropy.io.fits.Header`
        A new header (``header`` itself if ``copy=False``).

    Examples
    --------
    >>> from astropy.io import fits
    >>> from astroalign_nd.io import add_provenance
    >>> from astroalign_nd.transforms import SimilarityTransform
    >>> t = SimilarityTransform(scale=1.5, rotation=30.0, translation_x=3.0,
    ...                         translation_y=-2.0)
    >>> hdr = fits.Header({"OBJECT": "M31"})
    >>> out = add_provenance(hdr, t, source_name="a.fits", target_name="b.fits",
    ...                      quality={"n_matches": 42, "rms": 0.05, "log10_false_alarm": -80.0})
    >>> out["AATTYPE"], out["AATSCALE"], out["AATNMAT"], out["AATRMS"]
    ('similarity', 1.5, 42, 0.05)
    >>> print(str(out["HISTORY"][2]).strip())
    astroalign_nd transform: SimilarityTransform scale=1.500000
    >>> "AATTYPE" in hdr  # the given header is not modified
    False
    """
    quality = check_quality(quality)
    out = transform_to_header(model, header, prefix=prefix, copy=copy)
    m = _model_matrix(model)  # for a polynomial, its linear part about crpix
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")
    # File names may hold characters a FITS card cannot (escaped, not fatal).
    add_history(out, f"astroalign_nd {__version__} {now} UTC: registered "
                     f"{fits_text(source_name)} onto the pixel grid of "
                     f"{fits_text(target_name)}")
    det = np.linalg.det(m[:2, :2])
    desc = (f"{type(model).__name__} scale={np.sqrt(abs(det)):.6f}"
            f" rot={np.degrees(np.arctan2(m[1, 0], m[0, 0])):.5f}deg"
            f" shift=({m[0, 2]:.3f},{m[1, 2]:.3f})px{' mirrored' if det < 0 else ''}")
    if isinstance(model, ProjectiveTransform):
        desc += f" h31={m[2, 0]:.4g} h32={m[2, 1]:.4g}"
    elif isinstance(model, PolynomialTransform):
        desc += (f" (linear part about crpix=({model.crpix[0]:.2f},{model.crpix[1]:.2f}))"
                 f" degree={model.degree} distortion")
    add_history(out, f"astroalign_nd transform: {desc}")
    if order is not None:
        add_history(out, f"astroalign_nd resampling: {order}, conserve_flux={conserve_flux}")
    if quality:
        add_history(out, f"astroalign_nd fit: {quality['n_matches']} matched stars, "
                         f"RMS {quality['rms']:.4f} px, log10 false-alarm "
                         f"{quality['log10_false_alarm']:.1f}")
        for suffix, key, decimals, comment in QUALITY_KEYWORDS:
            value = quality[key]
            value = int(value) if decimals is None else round(float(value), decimals)
            out[_check_prefix(prefix) + suffix] = (value, comment)
    return out
