# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Cross-match whole catalogs: every star of two lists paired under the transform.

``cross_match`` = read both sides (arrays, tables, images: the stars
detected) -> find the transform on the brightest stars
(`~astroalign_nd.find_match`, or the caller's ``transform=``) -> pair every
star and refit on all the pairs until they are stable
(`~astroalign_nd.matching.allpairs.pair_all`) -> a table of the pairs,
by rows of the caller's inputs.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np
from astropy.io import fits
from astropy.nddata import NDData
from astropy.table import Table

from .io.read import parse_input, position_columns
from ._kernels import num_threads
from .config import RegistrationConfig
from .detection import find_sources
from .io.header import transform_to_header
from .matching.allpairs import bounds, pair_all
from .options import Real, convert
from .registration import find_match_from_config
from .transforms.convert import as_matrix
from .transforms.registry import transform_type_of

__all__ = ["cross_match", "CrossMatch", "read_catalog"]

#: `cross_match`'s radii: pixels > 0, or None (chosen from the match).
_RADIUS = Real(0, lo_open=True, none=True, unit="pixels")

#: Brightest stars of each side handed to a search for a distortion model:
#: the stars it is grown on (`~astroalign_nd.matching.extend_match`).  A
#: linear search gets ``2 * max_sources``, the most its escalation reads.
DISTORTION_SEARCH_STARS = 2000

#: Below this many sources, the nearest targets are looked up in one thread (starting
#: threads costs more than they save).
THREADED_QUERY = 1 << 18

#: Stars detected in an image input at most (all of them, in practice).
MAX_DETECTIONS = 1_000_000

#: Target stars expected per cell of the grid that measures the local
#: density of the chance-coincidence probability.
DENSITY_CELL_STARS = 30

#: The first pairing radius is this many times the search's residual
#: scatter (per axis), and at least ``MIN_TOLERANCE`` pixels.
TOLERANCE_SIGMAS = 6.0
MIN_TOLERANCE = 0.5

#: The first pairing radius without a search (``transform=`` given).
GIVEN_TOLERANCE = 2.0

_TEXT_SUFFIXES = (".txt", ".dat", ".cat", ".csv", ".ecsv", ".tsv", ".xy", ".coo")


@dataclasses.dataclass
class _Side:
    """One side of the cross-match: its positions and the rows they came from."""

    points: np.ndarray  # (K, 2) finite positions
    rows: np.ndarray  # (K,) their rows in the caller's input
    flux: np.ndarray | None
    catalog: Table | None  # the detected stars, for an image input
    n_rows: int


@dataclasses.dataclass
class CrossMatch:
    """
    The outcome of `cross_match`.

    Attributes
    ----------
    transform : astropy Model
        The source-to-target transform refitted on all the pairs;
        ``transform.meta['quality']`` holds ``n_matches``, ``rms`` (pixels),
        ``covariance``, ``radius`` and ``sigma``.
    table : `~astropy.table.Table`
        One row per pair: ``source_index`` and ``target_index`` (rows of
        the inputs as given, or of `source_catalog` / `target_catalog` for
        images), ``x_source``, ``y_source``, ``x_target``, ``y_target``,
        ``dx``, ``dy`` (``transform(source) - target``), ``residual``
        (pixels) and ``p_chance``: the probability that an unrelated target
        star lies this close to the predicted position (``1 - exp(-pi r**2
        density)``, with the target stars' local density).  Its ``meta``
        holds ``TRANSFRM``, ``NPAIRS``, ``RMS``, ``RADIUS``, ``SIGMA``,
        ``NITER`` and ``CONVERGD`` (FITS keyword names), and the transform's
        type and parameters as `~astroalign_nd.io.transform_to_header`
        writes them (``AATTYPE``...): written to a file, the table keeps
        the transform, which `~astroalign_nd.io.transform_from_header`
        rebuilds from its ``meta``.
    source_unmatched, target_unmatched : ndarray of int
        The rows of each input with no pair (rows without finite positions
        included).
    radius : float
        The final pairing radius (pixels), set by the residuals.
    sigma : float
        The residual scatter per axis (robust), pixels.
    n_iterations : int
        Pairings made before the pairs repeated.
    converged : bool
        True if they did repeat (False: ``max_iterations`` was reached).
    match : `~astroalign_nd.matching.MatchResult` or None
        The search on the brightest stars (None with ``transform=``).
    source_catalog, target_catalog : `~astropy.table.Table` or None
        The stars detected in an image input (None for catalogs).

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd import cross_match
    >>> from astroalign_nd.simulate import simulate_catalogs
    >>> cats = simulate_catalogs(3000, seed=4)
    >>> out = cross_match(cats.source, cats.target)
    >>> out.n_matches == len(out.table), out.converged
    (True, True)
    >>> n_rows = out.n_matches + len(out.source_unmatched)  # every row, once
    >>> n_rows == len(cats.source)
    True
    """

    transform: Any
    table: Table
    source_unmatched: np.ndarray
    target_unmatched: np.ndarray
    radius: float
    sigma: float
    n_iterations: int
    converged: bool
    match: Any = None
    source_catalog: Table | None = None
    target_catalog: Table | None = None

    @property
    def n_matches(self) -> int:
        """Number of pairs."""
        return len(self.table)

    def __repr__(self):
        return (f"<CrossMatch {type(self.transform).__name__}: {self.n_matches} pairs, "
                f"RMS {float(self.transform.meta['quality']['rms']):.3f} px, radius "
                f"{self.radius:.3f} px>")


def read_catalog(path: str | os.PathLike, *, format: str | None = None) -> Table:
    """
    Read a star catalog: ECSV, a FITS table, or whitespace-separated text columns.

    Parameters
    ----------
    path : str or path-like
    format : str, optional
        An `astropy.table.Table.read` format; by default ECSV for ``.ecsv``,
        the first table HDU of a FITS file, and for other files ASCII text
        (a header line names the columns; without one the columns are
        ``col1``, ``col2``...; lines starting with ``#`` are comments).

    Returns
    -------
    `~astropy.table.Table`

    Raises
    ------
    ValueError
        If the file does not exist or is not a table.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from astroalign_nd.crossmatch import read_catalog
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "stars.txt"
    >>> _ = path.write_text("x y flux\\n10.5 20.25 300\\n30 40 200\\n")
    >>> read_catalog(path).colnames
    ['x', 'y', 'flux']
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"catalog not found: {os.fspath(path)!r}.")
    try:
        if format is not None:
            return Table.read(path, format=format)
        if path.suffix.lower() == ".ecsv":
            return Table.read(path, format="ascii.ecsv")
        if _is_fits(path):
            with fits.open(path, memmap=False) as hdul:
                index = next((i for i, hdu in enumerate(hdul)
                              if isinstance(hdu, (fits.BinTableHDU, fits.TableHDU))), None)
            if index is None:
                raise ValueError("the FITS file holds no table HDU")
            return Table.read(path, format="fits", hdu=index)
        # Text: with a header when its first line that is not a comment names columns
        # (is not all numbers).
        header = False
        with open(path, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                words = line.split()
                if words and not words[0].startswith("#"):
                    try:
                        [float(w) for w in words]
                    except ValueError:
                        header = True
                    break
        return Table.read(path, format="ascii.basic" if header else "ascii.no_header")
    except (OSError, ValueError, TypeError, IndexError) as exc:
        raise ValueError(f"could not read {os.fspath(path)!r} as a catalog "
                         f"({type(exc).__name__}: {exc}). Pass an ECSV file, a FITS table, "
                         "or text columns.") from None


def _is_fits(path):
    with open(path, "rb") as fh:
        return fh.read(9) == b"SIMPLE  ="


def _flux_name(flux, which):
    """The flux column asked for on one side (0 source, 1 target): a name, None or False."""
    if flux is None or flux is False or isinstance(flux, str):
        return flux
    if (isinstance(flux, (tuple, list)) and len(flux) == 2
            and all(f is None or isinstance(f, str) for f in flux)):
        return flux[which]
    raise TypeError(f"flux must be a column name, a (source, target) pair of names, None (a "
                    f"'flux' column if there is one) or False (row order); got {flux!r}.")


def _table_side(table, name, columns, flux_col):
    xc, yc = position_columns(table, name, columns)
    x, y = table[xc], table[yc]
    bad = np.ma.getmaskarray(x) | np.ma.getmaskarray(y)
    try:
        pts = np.column_stack([np.ma.getdata(x).astype(float), np.ma.getdata(y).astype(float)])
    except (TypeError, ValueError):
        raise TypeError(f"the position columns {xc!r}, {yc!r} of {name} must hold numbers; got "
                        f"{x.dtype} and {y.dtype}.") from None
    if flux_col is None and "flux" in table.colnames:
        flux_col = "flux"
    flux = None
    if flux_col:
        if flux_col not in table.colnames:
            raise ValueError(f"{name} has no flux column {flux_col!r}; it has {table.colnames}. "
                             "Pass flux=<its name>, or flux=False for row order.")
        col = table[flux_col]
        flux = np.where(np.ma.getmaskarray(col), -np.inf,
                        np.ma.getdata(col).astype(float)).astype(float)
        flux[~np.isfinite(flux)] = -np.inf  # brightest first: unknown fluxes last
    return _finite_side(pts, bad, flux, None, len(table))


def _finite_side(pts, bad, flux, catalog, n_rows):
    good = np.isfinite(pts[:, 0]) & np.isfinite(pts[:, 1]) & ~bad
    if good.all():  # (the usual case: no copy)
        return _Side(pts, np.arange(len(pts)), flux, catalog, n_rows)
    rows = np.flatnonzero(good)
    return _Side(pts[rows], rows, None if flux is None else flux[rows], catalog, n_rows)


def _array_side(obj, name):
    arr = np.asarray(np.ma.getdata(obj))
    if arr.dtype.kind not in "biuf":
        raise TypeError(f"{name} must hold numbers; got dtype {arr.dtype}.")
    bad = (np.ma.getmaskarray(obj).any(axis=1) if np.ma.isMaskedArray(obj)
           else np.zeros(len(arr), bool))
    return _finite_side(arr.astype(float), bad, None, None, len(arr))


def _read_side(obj, name, columns, flux_col, config, hdu):
    """The positions of any accepted input: a `_Side`."""
    # A catalog file: a text table, or a FITS file with a table and no image.
    if isinstance(obj, (str, os.PathLike)):
        path = Path(obj)
        if path.suffix.lower() in _TEXT_SUFFIXES:
            obj = read_catalog(obj)
        elif path.is_file() and _is_fits(path):
            with fits.open(path, memmap=False) as hdul:
                has_image = any(getattr(h, "is_image", False) and h.data is not None
                                and np.ndim(h.data) >= 2 for h in hdul)
                has_table = any(isinstance(h, (fits.BinTableHDU, fits.TableHDU)) for h in hdul)
            if has_table and not has_image:
                obj = read_catalog(obj)
    if isinstance(obj, Table):
        return _table_side(obj, name, columns, flux_col)
    if columns is not None:
        raise TypeError(f"{name}_columns names the columns of a Table; the {name} is a "
                        f"{type(obj).__name__}.")
    is_array = (isinstance(obj, (np.ndarray, list, tuple)) and not isinstance(obj, NDData)
                and np.ndim(obj) == 2 and np.shape(obj)[1] == 2)
    if is_array:
        return _array_side(obj, name)
    if obj is None:
        raise TypeError(f"{name} is None; pass an (N, 2) array of positions, a Table, an "
                        "image, or a path to either.")
    parsed = parse_input(obj, name, hdu=hdu)
    if parsed.is_catalog:  # (a Reference of a catalog)
        return _array_side(parsed.points, name)
    det = {f.name: getattr(config.detection, f.name)
           for f in dataclasses.fields(config.detection)}
    table = find_sources(parsed.detection_image, mask=parsed.mask, n_sources=MAX_DETECTIONS,
                         **det)
    side = _table_side(table, f"the stars detected in the {name}", ("x", "y"), "flux")
    side.catalog = table
    return side


def _brightest(side, n):
    """Indices (into ``side.points``) of its ``n`` brightest stars, brightest first."""
    if side.flux is None:
        return np.arange(min(n, len(side.points)))
    if n >= len(side.flux):
        return np.argsort(-side.flux, kind="stable")
    top = np.argpartition(-side.flux, n - 1)[:n]
    return top[np.argsort(-side.flux[top], kind="stable")]


def _find(src, dst, config):
    """The search on the brightest stars: (start model, MatchResult, first radius)."""
    n = 2 * config.max_sources
    if config.model.nonlinear:
        n = max(n, DISTORTION_SEARCH_STARS)
    i_src, i_dst = _brightest(src, n), _brightest(dst, n)
    result = find_match_from_config(src.points[i_src], dst.points[i_dst], config)
    sigma = float(result.rms) / np.sqrt(2.0)
    tolerance = max(TOLERANCE_SIGMAS * sigma, MIN_TOLERANCE)
    return result.transform, result, tolerance


def _check_transform(transform):
    """The caller's starting transform: a 3x3 matrix, a package model or astropy model."""
    if isinstance(transform, (np.ndarray, list, tuple)):
        try:
            m = as_matrix(np.asarray(transform, float))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"transform must be a 3x3 (or 2x3) matrix or a transform model; "
                             f"{exc}") from None
        if not np.all(np.isfinite(m)):
            raise ValueError("transform must be finite.")
        return m
    if not callable(transform) or getattr(transform, "n_inputs", 2) != 2:
        raise TypeError(f"transform must be a transform model (e.g. from find_transform) or a "
                        f"3x3 matrix; got {type(transform).__name__}.")
    return transform


def _pair_table(src, dst, fit):
    """The table of the pairs, by rows of the caller's inputs."""
    si, dj = fit.source_index, fit.target_index
    # (np.take: rows gathered 15 times faster than by [])
    s, d, r = np.take(src.points, si, axis=0), np.take(dst.points, dj, axis=0), fit.residuals
    resid = np.sqrt(r[:, 0] ** 2 + r[:, 1] ** 2)  # (hypot is ten times slower)
    # The target stars per square pixel around each predicted position (a grid count).
    lo, hi = bounds(dst.points)
    area = max(float(np.prod(hi - lo)), 1.0)
    cell = max(np.sqrt(DENSITY_CELL_STARS * area / max(len(dst.points), 1)), 1e-3)
    shape = np.maximum(np.ceil((hi - lo) / cell).astype(int), 1)

    def index(p):
        ij = np.clip(((p - lo) / cell).astype(int), 0, shape - 1)
        return ij[:, 1] * shape[0] + ij[:, 0]

    counts = np.bincount(index(dst.points), minlength=int(np.prod(shape)))
    rho = counts[index(d + r)] / cell ** 2
    table = Table({"source_index": src.rows[si], "target_index": dst.rows[dj],
                   "x_source": s[:, 0], "y_source": s[:, 1],
                   "x_target": d[:, 0], "y_target": d[:, 1],
                   "dx": r[:, 0], "dy": r[:, 1], "residual": resid,
                   "p_chance": -np.expm1(-np.pi * resid ** 2 * rho)}, copy=False)
    table["residual"].unit = table["dx"].unit = table["dy"].unit = "pix"
    table["residual"].description = "distance of transform(source) from target, pixels"
    table["p_chance"].description = ("probability that an unrelated target star lies this "
                                     "close (local density)")
    return table


def _unmatched(side, index):
    """Rows of the caller's input with no pair."""
    free = np.ones(side.n_rows, bool)
    free[side.rows[index]] = False
    return np.flatnonzero(free)


def cross_match(source: Any, target: Any, *, transform: Any = None,
                transform_type: str = "similarity", degree: int | str | None = None,
                source_columns: tuple | None = None, target_columns: tuple | None = None,
                flux: str | tuple | bool | None = None, max_radius: float | None = None,
                radius: float | None = None, max_iterations: int = 10, n_sources: int = 50,
                max_sources: int = 200, hdu: int | str | None = None,
                **options: Any) -> CrossMatch:
    """
    Pair every star of ``source`` with one of ``target`` under the transform.

    The transform is found on the brightest stars (`~astroalign_nd.find_match`)
    or given (``transform=``).  Then every source star is paired with its
    nearest target star under the model (one source per target: of several
    claiming one target, the nearest keeps it), the model is refitted on all
    the pairs, the pairing radius is set from the fit's own residuals (the
    radius that loses the fewest true pairs and admits the fewest chance
    ones, between 3 and 5 sigma), and this repeats until the pairs no longer
    change.  Millions of stars per side take one grid of the targets and one
    look-up.

    Parameters
    ----------
    source, target : (N, 2) array, `~astropy.table.Table`, image or path
        Star positions: an (N, 2) array (rows in order of brightness when
        there is no flux), a Table with x/y columns (``x``/``y``, photutils
        3's ``x_centroid``/``y_centroid``, the older ``xcentroid``/
        ``ycentroid``, ``X_IMAGE``..., or named by ``source_columns`` /
        ``target_columns``), a catalog file (ECSV, FITS table, text
        columns; see `read_catalog`), or an image (anything
        `~astroalign_nd.find_transform` takes: its stars are detected).
        The two sides may be of different kinds.  Rows without finite
        positions (or masked) are left out and reported as unmatched.
    transform : model or (3, 3) array-like, optional
        A source-to-target transform to start from instead of searching
        (e.g. from `~astroalign_nd.find_transform` on another pair, or a
        WCS solution): within ``max_radius`` of the truth.
    transform_type : str, optional
        The model refitted on all the pairs (and searched for):
        'similarity' (default), 'euclidean', 'translation', 'affine',
        'projective' or 'polynomial'.
    degree : int or 'auto', optional
        Of a 'polynomial' model, 2 to 5 (default 3), or 'auto': chosen on
        the pairs (F-test, BIC and blocked cross-validation, as
        `~astroalign_nd.matching.fit_nonlinear` chooses), a linear model
        included.
    source_columns, target_columns : (str, str), optional
        The x and y columns of a Table.
    flux : str, (str, str), None or False, optional
        The flux column (of both tables, or of each) whose brightest stars
        the search uses; None: a ``flux`` column if the table has one, else
        the first rows; False: the first rows.
    max_radius : float, optional
        The first (and largest) pairing radius, pixels: by default six
        times the search's residual scatter (at least 0.5 px), or 2 px with
        ``transform=``.
    radius : float, optional
        A fixed pairing radius (pixels) instead of the one the residuals set.
    max_iterations : int, optional
        Pairings at most (default 10; the pairs are usually stable by 3).
    n_sources, max_sources, hdu, **options
        As in `~astroalign_nd.find_transform`: the search's control points
        and its detection and matching options (detection options apply to
        image inputs; ``tolerance`` is the search's matching radius).

    Returns
    -------
    `CrossMatch`
        ``transform``, ``table`` (the pairs), ``source_unmatched`` and
        ``target_unmatched`` (rows without a pair) and the iteration's
        figures.

    Raises
    ------
    TransformNotFoundError
        If the search finds no trusted transform.
    TooFewSourcesError
        If too few stars pair up under the transform.
    TypeError, ValueError
        For inputs or options of the wrong kind or out of range.

    Examples
    --------
    >>> from astroalign_nd import cross_match
    >>> from astroalign_nd.simulate import simulate_catalogs
    >>> cats = simulate_catalogs(5000, seed=2)
    >>> out = cross_match(cats.source, cats.target)
    >>> same = cats.source["id"][out.table["source_index"]] == \\
    ...     cats.target["id"][out.table["target_index"]]
    >>> bool(same.sum() >= 0.99 * cats.n_true_pairs), bool(same.mean() > 0.995)
    (True, True)
    """
    config = RegistrationConfig.from_keywords(transform_type=transform_type, degree=degree,
                                              n_sources=n_sources, max_sources=max_sources,
                                              **options)
    max_radius = convert("max_radius", _RADIUS, max_radius)
    radius = convert("radius", _RADIUS, radius)
    if isinstance(max_iterations, (bool, np.bool_)) or not isinstance(
            max_iterations, (int, np.integer)) or max_iterations < 1:
        raise ValueError(f"max_iterations must be a positive integer; got {max_iterations!r}.")
    start = None if transform is None else _check_transform(transform)
    src = _read_side(source, "source", source_columns, _flux_name(flux, 0), config, hdu)
    dst = _read_side(target, "target", target_columns, _flux_name(flux, 1), config, hdu)
    for name, side in (("source", src), ("target", dst)):
        if len(side.points) < 3:
            raise ValueError(f"the {name} has {len(side.points)} usable position(s); at least "
                             "3 are needed.")
    match = None
    if start is None:
        start, match, found_tol = _find(src, dst, config)
    else:
        found_tol = GIVEN_TOLERANCE
    model = config.model
    kind = transform_type_of(model.transform_type).name
    fit = pair_all(src.points, dst.points, start, transform_type=kind,
                   degree=model.degree if model.nonlinear else None,
                   tolerance=max_radius or found_tol, radius=radius,
                   max_iterations=int(max_iterations),
                   workers=num_threads() if len(src.points) >= THREADED_QUERY else 1)
    return _result(src, dst, fit, match)


def _result(src, dst, fit, match):
    table = _pair_table(src, dst, fit)
    rms = float(np.sqrt(np.mean(table["residual"] ** 2)))
    # FITS-keyword names: the table can be written to a FITS file as it is.
    table.meta.update(TRANSFRM=type(fit.transform).__name__, NPAIRS=len(table), RMS=rms,
                      RADIUS=fit.radius, SIGMA=fit.sigma, NITER=fit.n_iterations,
                      CONVERGD=fit.converged)
    # The transform itself, as a registered frame's header holds it (AAT* keywords):
    # transform_from_header(table.meta) rebuilds it from the written table.
    table.meta.update(transform_to_header(fit.transform))
    fit.transform.meta["quality"] = dict(n_matches=len(table), rms=rms,
                                         covariance=np.array(fit.covariance),
                                         radius=fit.radius, sigma=fit.sigma,
                                         degree=fit.degree)
    return CrossMatch(fit.transform, table, _unmatched(src, fit.source_index),
                      _unmatched(dst, fit.target_index), fit.radius, fit.sigma,
                      fit.n_iterations, fit.converged, match, src.catalog, dst.catalog)
