# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Diagnostic plots of a registration.

* `plot_matches`: the matched stars on both frames, each pair in its own
  colour (figure 2 of the astroalign paper);
* `plot_invariants`: the triangles of the matched stars in invariant space,
  ``L2/L1`` against ``L1/L0``, with the boundary ``y = 1/(x - 1)`` where
  triangles become flat (figure 1 of the paper);
* `plot_residuals`: the residual of each matched star after the fit, as a
  vector field;
* `plot_difference`: the registered frame minus the target, with a zscale
  stretch;
* `plot_registration`: all of them in one figure, and
  `save_diagnostic_figure`, which writes it to a file (the command line's
  ``register --plot``, and ``batch --plot DIR`` for each frame);
* `plot_night`: a batch's drift, rotation, RMS and matched stars against
  frame, and `save_night_figure` (``batch --plot DIR``'s night summary);
* `plot_frame_quality`: a night's seeing, elongation, transparency, sky
  noise and weights against time (`~astroalign_nd.frame_quality`'s table),
  the frames left out marked.

The functions take what `~astroalign_nd.find_transform` and
`~astroalign_nd.register` return (the transform, the matched points, the
registered `~astropy.nddata.CCDData`) and the images as
`~astroalign_nd.find_transform` accepts them.  They draw on the Axes given
(``ax=``/``axes=``/``fig=``) or on new ones, and return them.

matplotlib is an optional dependency, imported only when a function is
called: ``pip install matplotlib`` (or the ``plot`` extra,
``pip install "astroalign_nd[plot]"``).
"""

import dataclasses
import os

import numpy as np

from .io.read import parse_input
from .resample.options import ResampleConfig
from .io.write import atomic_open, check_not_input, check_output_path
from .matching.asterisms import build_asterisms
from .registration import find_transform
from .resample.nddata import apply_transform

__all__ = ["plot_matches", "plot_invariants", "plot_residuals", "plot_difference",
           "plot_registration", "save_diagnostic_figure", "match_colors", "plot_night",
           "save_night_figure", "plot_frame_quality", "NO_DATA_COLOR"]

#: Options of `plot_registration` used to resample the source (when ``aligned`` is not
#: given) rather than to find the transform.
_APPLY_KEYS = tuple(f.name for f in dataclasses.fields(ResampleConfig)) + ("unit",)

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def _matplotlib():
    """Import matplotlib, or say how to install it."""
    try:
        import matplotlib
    except ImportError:
        raise ImportError(
            "astroalign_nd.visualization needs matplotlib, which is not installed: "
            'pip install matplotlib (or pip install "astroalign_nd[plot]").'
        ) from None
    return matplotlib


def _subplots(fig, figsize, *args, **kwargs):
    """``fig`` (cleared first) or a new pyplot figure of ``figsize``, and its new Axes."""
    if fig is None:
        _matplotlib()
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=figsize, layout="constrained")
    else:
        fig.clear()
    return fig, fig.subplots(*args, **kwargs)


def _new_axes(ax, ncols=1):
    """``ax`` if given, else new Axes on a new pyplot figure."""
    if ax is not None:
        return ax
    _matplotlib()
    import matplotlib.pyplot as plt

    _, axes = plt.subplots(1, ncols, figsize=(4.5 * ncols, 4.2), layout="constrained")
    return axes


def match_colors(n):
    """
    ``n`` distinct colours, one per matched star.

    Hues step by the golden ratio, so that neighbouring indices (stars of
    similar brightness, often neighbours on the sky) get well separated
    colours, and no colour repeats however many stars are matched.

    Parameters
    ----------
    n : int
        Number of colours.

    Returns
    -------
    colors : (n, 4) ndarray
        RGBA colours.

    Examples
    --------
    >>> from astroalign_nd.visualization import match_colors
    >>> match_colors(3).shape
    (3, 4)
    """
    _matplotlib()
    from matplotlib.colors import hsv_to_rgb

    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be a non-negative integer; got {n!r}.")
    hsv = np.column_stack([(np.arange(n) * _GOLDEN) % 1.0, np.full(n, 0.85),
                           np.full(n, 0.95)])
    return np.column_stack([hsv_to_rgb(hsv).reshape(n, 3), np.ones(n)])


def _points_pair(points):
    """Check ``(source_points, target_points)`` as find_transform returns them."""
    try:
        src, dst = points
    except (TypeError, ValueError):
        raise TypeError("points must be (source_points, target_points), the second value "
                        "find_transform returns; got "
                        f"{type(points).__name__}.") from None
    src = _points(src, "source_points")
    dst = _points(dst, "target_points")
    if len(src) != len(dst):
        raise ValueError(f"source_points and target_points must pair up; got {len(src)} "
                         f"and {len(dst)} points.")
    return src, dst


def _points(points, name):
    try:
        arr = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be an (N, 2) array of (x, y) positions; got "
                        f"{type(points).__name__}.") from None
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name} must be an (N, 2) array of (x, y) positions; got shape "
                         f"{arr.shape}.")
    return arr


def _image(image, name):
    """A 2-D float array to display (masked pixels as NaN), or None for a catalog."""
    parsed = parse_input(image, name)
    if parsed.is_catalog:
        return None
    data = np.array(parsed.detection_image, dtype=float)  # a copy: the caller's is kept
    if parsed.mask is not None:
        data[parsed.mask] = np.nan
    return data


#: The colour of pixels without data (masked, or outside the source's footprint).
NO_DATA_COLOR = "#4a6fa5"


def _show(ax, data, cmap="gray", norm=None):
    """``data`` with a zscale stretch (or ``norm``), and a legend entry for its no-data pixels."""
    import matplotlib
    from matplotlib.patches import Patch

    if norm is None:
        from astropy.visualization import ImageNormalize, ZScaleInterval

        good = data[np.isfinite(data)]
        norm = ImageNormalize(good if good.size else np.zeros(1), interval=ZScaleInterval())
    cmap = matplotlib.colormaps[cmap].with_extremes(bad=NO_DATA_COLOR)
    im = ax.imshow(data, origin="lower", cmap=cmap, norm=norm, interpolation="nearest")
    if not np.all(np.isfinite(data)):
        ax.legend(handles=[Patch(facecolor=NO_DATA_COLOR, label="no data (masked)")],
                  loc="lower right", fontsize="small", framealpha=0.8)
    return im


def _display_name(image, default):
    """A file's name (or a parsed input's), for titles; ``default`` for arrays."""
    if isinstance(image, (str, os.PathLike)):
        return os.path.basename(os.fspath(image))
    name = getattr(image, "name", None)
    if getattr(image, "kind", None) in ("fits", "image-file") and name:
        return name
    return default


def plot_matches(source, target, points, *, axes=None, marker_size=80.0, show_images=True):
    """
    Show the matched stars on both frames, each matched pair in its own colour.

    Parameters
    ----------
    source, target : array-like, `~astropy.nddata.NDData`, path or catalog
        The two frames, as `~astroalign_nd.find_transform` takes them.
        For a catalog, only the stars are drawn.
    points : tuple of two (K, 2) array-like
        ``(source_points, target_points)``, the matched positions that
        `~astroalign_nd.find_transform` returns.
    axes : sequence of two `~matplotlib.axes.Axes`, optional
        Where to draw the source and the target; new ones by default.
    marker_size : float, optional
        Area of the circles, in points squared.
    show_images : bool, optional
        Draw the images under the stars (default True).

    Returns
    -------
    axes : tuple of two `~matplotlib.axes.Axes`
        The source's and the target's.  Each holds one scatter collection
        of K circles, in the colours of `match_colors`, the same on both.

    Examples
    --------
    >>> from astroalign_nd import find_transform
    >>> from astroalign_nd.simulate import simulate_pair
    >>> from astroalign_nd.visualization import plot_matches
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> transform, points = find_transform(pair.source, pair.target)
    >>> ax_source, ax_target = plot_matches(pair.source, pair.target, points)
    """
    src, dst = _points_pair(points)
    ax_src, ax_dst = _new_axes(axes, ncols=2) if axes is None else axes
    colors = match_colors(len(src))
    for ax, image, pts, name in ((ax_src, source, src, "source"),
                                 (ax_dst, target, dst, "target")):
        data = _image(image, name) if show_images else None
        if data is not None:
            _show(ax, data)
        ax.scatter(pts[:, 0], pts[:, 1], s=marker_size, facecolors="none",
                   edgecolors=colors, linewidths=1.5)
        ax.set_aspect("equal")
        if data is not None:
            ax.set_xlim(-0.5, data.shape[1] - 0.5)
            ax.set_ylim(-0.5, data.shape[0] - 0.5)
        shown = _display_name(image, name)
        _label(ax, f"{name}{'' if shown == name else ' ' + shown}\n{len(pts)} matched stars")
    return ax_src, ax_dst


def _label(ax, title, frame=""):
    """Title and pixel axis labels (``frame``: which frame's pixels, if not obvious)."""
    ax.set_title(title)
    ax.set_xlabel(f"x [px]{frame}")
    ax.set_ylabel(f"y [px]{frame}")


def plot_invariants(source_points, target_points=None, *, ax=None, n_neighbors=4):
    """
    Plot triangles in the invariant space of the method: ``L2/L1`` against ``L1/L0``.

    ``L0 <= L1 <= L2`` are a triangle's sides.  The triangle inequality
    ``L2 <= L0 + L1`` confines every triangle to ``y <= 1 / (x - 1)``; on that
    boundary the triangle is flat (its three stars collinear), and near it a
    small centroid error moves the invariants a long way, which is why the
    method compares invariants with a tolerance (see :doc:`/method`).

    Parameters
    ----------
    source_points : (N, 2) array-like
        Star positions; their nearest-neighbour triangles are built as the
        method builds them (`~astroalign_nd.matching.build_asterisms`).
    target_points : (M, 2) array-like, optional
        A second set (the target's), drawn with another marker.  With the
        matched points of `~astroalign_nd.find_transform`, each triangle of
        the source falls on its counterpart in the target.
    ax : `~matplotlib.axes.Axes`, optional
        Where to draw; new Axes by default.
    n_neighbors : int, optional
        Neighbours per star (4, the method's default, gives 10 triangles
        per star).

    Returns
    -------
    ax : `~matplotlib.axes.Axes`
        With one scatter collection per point set (one point per triangle)
        and the boundary line.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.visualization import plot_invariants
    >>> stars = np.random.default_rng(0).uniform(0, 500, size=(40, 2))
    >>> ax = plot_invariants(stars)
    """
    sets = [(_points(source_points, "source_points"), "source", "o")]
    if target_points is not None:
        sets.append((_points(target_points, "target_points"), "target", "x"))
    ax = _new_axes(ax)
    from matplotlib.ticker import FormatStrFormatter

    hi = 5.0
    for pts, label, marker in sets:
        # The asterisms keep log(L2/L1), log(L1/L0); the paper plots the ratios.
        ratios = np.exp(build_asterisms(pts, n_neighbors=n_neighbors).invariants)
        if len(ratios):
            hi = max(hi, float(np.percentile(ratios[:, 1], 99)) * 1.2)
        style = dict(facecolors="none", edgecolors="C0") if marker == "o" else dict(c="C1")
        ax.scatter(ratios[:, 0], ratios[:, 1], s=18, marker=marker, linewidths=1.0,
                   label=f"{label}: {len(ratios)} triangles", **style)
    # Flat triangles: L2 = L0 + L1, i.e. y = 1 / (x - 1); since L1/L0 >= 1, x <= 2.
    x = np.linspace(1.0 + 1.0 / hi, 2.0, 400)
    ax.plot(x, 1.0 / (x - 1.0), color="k", lw=1.2, label="collinear: y = 1/(x-1)")
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax.yaxis.set_minor_formatter(FormatStrFormatter("%g"))
    ax.set_xlim(0.98, 2.05)
    ax.set_ylim(0.95, hi)
    ax.set_xlabel("L2 / L1")
    ax.set_ylabel("L1 / L0")
    ax.set_title("triangle invariants")
    ax.legend(loc="upper right", fontsize="small")
    return ax


#: Residuals (px) below which a fit is exact (rounding): drawn without magnification.
_NO_RESIDUAL = 1e-3


def plot_residuals(transform, points, *, ax=None, scale=None, shape=None):
    """
    Draw the residual of each matched star after the fit, as an arrow.

    The arrow of a star starts at its position in the target and points
    from where the transform puts the source star to where the target star
    is, magnified by ``scale``.  A pattern in the arrows (a swirl, arrows
    growing towards the edges) is distortion that the linear model does not
    follow; see :doc:`/limits`.

    Parameters
    ----------
    transform : `~astroalign_nd.transforms.LinearTransform2D` or callable
        The source-to-target transform (``transform(x, y)`` gives target
        positions), as `~astroalign_nd.find_transform` returns it.
    points : tuple of two (K, 2) array-like
        ``(source_points, target_points)``, the matched positions.
    ax : `~matplotlib.axes.Axes`, optional
        Where to draw; new Axes by default.
    scale : float, optional
        Magnification of the arrows; by default the median arrow is drawn
        about 5% of the field across (residuals all below 0.001 px, an
        exact fit such as a frame onto itself, are not magnified).
    shape : (ny, nx), optional
        The target frame's shape, to set the limits of the plot.

    Returns
    -------
    ax : `~matplotlib.axes.Axes`
        With one `~matplotlib.quiver.Quiver` of K arrows.

    Examples
    --------
    Matched positions 0.1 px off a known transform:

    >>> import numpy as np
    >>> from astroalign_nd import SimilarityTransform
    >>> from astroalign_nd.visualization import plot_residuals
    >>> t = SimilarityTransform(rotation=10.0, translation_x=3.0, translation_y=-2.0)
    >>> src = np.random.default_rng(2).uniform(0, 256, (30, 2))
    >>> dst = np.column_stack(t(src[:, 0], src[:, 1])) + 0.1
    >>> ax = plot_residuals(t, (src, dst), shape=(256, 256))
    >>> len(ax.collections[0].U)  # one arrow per pair
    30
    """
    src, dst = _points_pair(points)
    if not callable(transform):
        raise TypeError("transform must be a transform model (find_transform's first value); "
                        f"got {type(transform).__name__}.")
    ax = _new_axes(ax)
    xy = np.column_stack([np.asarray(v, dtype=float) for v in transform(src[:, 0], src[:, 1])])
    resid = dst - xy
    size = np.hypot(resid[:, 0], resid[:, 1])
    rms = float(np.sqrt(np.mean(size ** 2))) if len(size) else float("nan")
    if shape is not None:
        extent = float(max(shape))
    elif len(dst):
        extent = float(np.ptp(dst, axis=0).max()) or 1.0
    else:
        extent = 1.0
    typical = float(np.median(size)) if len(size) else 0.0
    # Below a thousandth of a pixel the residuals are rounding (a frame registered onto
    # itself): nothing to magnify, and no key arrow scaled from them.
    exact = scale is None and not typical >= _NO_RESIDUAL
    if scale is None:
        scale = 1.0 if exact else 0.05 * extent / typical
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"scale must be a positive number; got {scale!r}.")
    q = ax.quiver(dst[:, 0], dst[:, 1], resid[:, 0] * scale, resid[:, 1] * scale,
                  color=match_colors(len(dst)), angles="xy", scale_units="xy", scale=1.0,
                  width=0.006)
    ax.set_aspect("equal")
    if shape is not None:
        ax.set_xlim(-0.5, shape[1] - 0.5)
        ax.set_ylim(-0.5, shape[0] - 0.5)
    if exact:
        _label(ax, f"residuals: all below {_NO_RESIDUAL:g} px (RMS {rms:.3f} px)", " (target)")
        return ax
    _label(ax, f"residuals x{scale:.3g}: RMS {rms:.3f} px", " (target)")
    # The key: a round length near the typical residual, so its arrow is about as long as
    # the median arrow (5% of the field) and stays inside the panel.
    key = float(f"{typical:.1g}") if typical > 0 else 1.0
    ax.quiverkey(q, 0.75, 0.05, scale * key, f"{key:.2g} px", labelpos="E",
                 coordinates="axes")
    return ax


def plot_difference(aligned, target, *, ax=None, colorbar=True):
    """
    Show the registered frame minus the target, centred and on a symmetric scale.

    The median of the difference is subtracted (a sky level that differs
    between the frames), and the colour scale runs from ``-v`` to ``+v``
    (``v`` from a zscale of the difference), so that mid-grey is zero.
    Stars that are well registered cancel to noise (if the two frames have
    the same seeing and exposure); a misregistration leaves pairs of
    positive and negative residuals.  Pixels masked in either frame (outside
    the source's footprint) are drawn in blue, named in the legend.

    Parameters
    ----------
    aligned : `~astropy.nddata.CCDData`, array-like or path
        The registered frame, on the target's pixel grid (what
        `~astroalign_nd.register` returns).
    target : `~astropy.nddata.NDData`, array-like or path
        The target frame.
    ax : `~matplotlib.axes.Axes`, optional
        Where to draw; new Axes by default.
    colorbar : bool, optional
        Add a colour bar (default True).

    Returns
    -------
    ax : `~matplotlib.axes.Axes`
        With one image, normalized by `~astropy.visualization.ImageNormalize`
        symmetric about zero.

    Examples
    --------
    >>> import astroalign_nd
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> aligned = astroalign_nd.register(pair.source, pair.target)
    >>> ax = astroalign_nd.visualization.plot_difference(aligned, pair.target)
    >>> ax.get_title()
    'aligned - target'
    """
    a = _image(aligned, "aligned")
    t = _image(target, "target")
    if a is None or t is None:
        raise TypeError("plot_difference needs two images, not catalogs.")
    if a.shape != t.shape:
        raise ValueError(f"aligned (shape {a.shape}) is not on the target's pixel grid (shape "
                         f"{t.shape}); pass the output of register(source, target).")
    ax = _new_axes(ax)
    diff = a - t
    if np.isfinite(diff).any():
        diff -= np.nanmedian(diff)
    # A colour scale symmetric about 0, as wide as the zscale range of the difference.
    from astropy.visualization import ImageNormalize, ZScaleInterval

    good = diff[np.isfinite(diff)]
    lo, hi = ZScaleInterval().get_limits(good) if good.size else (-1.0, 1.0)
    half = max(abs(lo), abs(hi)) or 1.0
    im = _show(ax, diff, norm=ImageNormalize(vmin=-half, vmax=half))
    if colorbar:
        ax.figure.colorbar(im, ax=ax, shrink=0.8, label="aligned - target - median")
    _label(ax, "aligned - target")
    return ax


def _quality_text(transform):
    """The transform's parameters and fit quality, one per line."""
    meta = getattr(transform, "meta", None)
    q = meta.get("quality", {}) if isinstance(meta, dict) else {}
    lines = [type(transform).__name__]
    for name, fmt, unit in (("scale", "{:.6f}", ""), ("rotation_deg", "{:.4f}", " deg"),
                            ("translation", "{:.3f}", " px")):
        value = getattr(transform, name, None)  # a Parameter, a float or a tuple
        try:
            values = np.atleast_1d(np.asarray(getattr(value, "value", value),
                                              dtype=float)).ravel()
        except (TypeError, ValueError):
            continue
        if value is not None and values.size:
            lines.append(f"{name}: " + ", ".join(fmt.format(v) for v in values) + unit)
    if q:
        lines += [f"matched stars: {q['n_matches']}", f"RMS: {q['rms']:.3f} px",
                  f"log10 false alarm: {q['log10_false_alarm']:.1f}"]
    return "\n".join(lines)


def plot_registration(source, target, transform=None, points=None, aligned=None, *,
                      fig=None, **options):
    """
    One figure with every diagnostic of a registration.

    Top row: the matched stars on the source and on the target
    (`plot_matches`), and the difference image (`plot_difference`).  Bottom
    row: the invariant space (`plot_invariants`), the residuals
    (`plot_residuals`) and the transform with its quality figures.

    Parameters
    ----------
    source, target : array-like, `~astropy.nddata.NDData` or path
        The two frames, as `~astroalign_nd.find_transform` takes them.
    transform, points : optional
        What `~astroalign_nd.find_transform` returned; found here (with
        ``options``) when not given.
    aligned : `~astropy.nddata.CCDData`, optional
        What `~astroalign_nd.register` returned; computed here with
        `~astroalign_nd.apply_transform` when not given.
    fig : `~matplotlib.figure.Figure`, optional
        The figure to draw on (cleared first); a new pyplot figure by
        default.
    **options
        Options of `~astroalign_nd.find_transform` (``transform_type``,
        ``fwhm``, ``hdu``...) and of `~astroalign_nd.apply_transform`
        (``order``, ``conserve_flux``...), used for what is not given.

    Returns
    -------
    fig : `~matplotlib.figure.Figure`

    Examples
    --------
    >>> from astroalign_nd.simulate import simulate_pair
    >>> from astroalign_nd.visualization import plot_registration
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> fig = plot_registration(pair.source, pair.target)
    >>> len(fig.axes)  # six panels and the difference image's colour bar
    7
    """
    apply_options = {k: options.pop(k) for k in _APPLY_KEYS if k in options}
    # Read the frames once (files too), for the search, the resampling and the plots.
    hdu = options.pop("hdu", None)
    source = parse_input(source, "source", hdu=hdu)
    target = parse_input(target, "target", hdu=hdu)
    if (transform is None) != (points is None):
        raise TypeError("pass transform and points together (both values find_transform "
                        "returns), or neither.")
    if transform is None:
        transform, points = find_transform(source, target, **options)
    if aligned is None:
        aligned = apply_transform(transform, source, target, **apply_options)
    fig, axes = _subplots(fig, (14, 9), 2, 3)
    plot_matches(source, target, points, axes=axes[0, :2])
    plot_difference(aligned, target, ax=axes[0, 2])
    plot_invariants(*points, ax=axes[1, 0])
    plot_residuals(transform, points, ax=axes[1, 1], shape=target.shape)
    axes[1, 2].axis("off")
    axes[1, 2].text(0.02, 0.98, _quality_text(transform), va="top", ha="left",
                    family="monospace", transform=axes[1, 2].transAxes)
    axes[1, 2].set_title("transform (source -> target)")
    fig.suptitle(f"{_display_name(source, 'source')} -> {_display_name(target, 'target')}")
    return fig


def check_plot_path(path, overwrite=False):
    """
    Check, before any work, that a figure can be written at ``path``.

    Parameters
    ----------
    path : str or path-like
        The image file; its ending must be a format matplotlib writes.
    overwrite : bool, optional
        Accept an existing file (default False: `FileExistsError`).

    Raises
    ------
    ImportError
        If matplotlib is not installed.
    ValueError, FileExistsError, OSError
        If the file cannot be written there.

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.visualization import check_plot_path
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     check_plot_path(os.path.join(folder, "check.png"))
    """
    _matplotlib()
    from matplotlib.backend_bases import FigureCanvasBase

    extensions = tuple("." + e for e in sorted(FigureCanvasBase.get_supported_filetypes()))
    check_output_path(path, overwrite, extensions=extensions)


def save_diagnostic_figure(path, source, target, aligned=None, *, overwrite=False, dpi=100,
                           **options):
    """
    Write the figure of `plot_registration` to a file.

    No pyplot window is opened (the figure is drawn with the Agg backend),
    and the file is written atomically.

    Parameters
    ----------
    path : str or path-like
        The image file; its ending gives the format (``.png``, ``.pdf``,
        ``.svg``...).
    source, target, aligned
        As in `plot_registration`.
    overwrite : bool, optional
        Replace ``path`` if it exists (default False: `FileExistsError`).
    dpi : float, optional
        Resolution of raster formats.
    **options
        As in `plot_registration` (``transform``, ``points``, options of
        `~astroalign_nd.find_transform`).

    Returns
    -------
    path : str
        The file written.

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.simulate import simulate_pair
    >>> from astroalign_nd.visualization import save_diagnostic_figure
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     out = save_diagnostic_figure(os.path.join(folder, "check.png"),
    ...                                  pair.source, pair.target)
    ...     os.path.getsize(out) > 0
    True
    """
    check_not_input(path, (source, target))
    check_plot_path(path, overwrite)
    fig = _agg_figure((14, 9))
    plot_registration(source, target, aligned=aligned, fig=fig, **options)
    return _save(fig, path, overwrite, dpi)


def plot_night(result, *, fig=None):
    """
    A batch at a glance: drift, rotation, RMS and matched stars against frame.

    Four panels share the frame axis (input order): the shift of each frame
    onto the reference (x and y, px), its rotation (deg), the RMS of the
    fit (px) and the number of matched stars.  Failed frames leave a gap,
    marked by a red cross on the frame axis.

    Parameters
    ----------
    result : `~astroalign_nd.batch.BatchResult` or `~astropy.table.Table`
        What `~astroalign_nd.register_batch` returned, or its ``to_table()``
        (a ``--summary`` file read back).
    fig : `~matplotlib.figure.Figure`, optional
        The figure to draw on (cleared first); a new pyplot figure by default.

    Returns
    -------
    fig : `~matplotlib.figure.Figure`
        With four Axes.

    Examples
    --------
    >>> from astroalign_nd.batch import register_batch
    >>> from astroalign_nd.simulate import simulate_pair
    >>> from astroalign_nd.visualization import plot_night
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=3.0, seed=1)
    >>> fig = plot_night(register_batch([pair.source, pair.source], pair.target))
    >>> [ax.get_ylabel() for ax in fig.axes]
    ['shift [px]', 'rotation [deg]', 'RMS [px]', 'matched stars']
    """
    table = result.to_table() if hasattr(result, "to_table") else result
    missing = {"name", "status", "n_matches", "rms", "shift_x", "shift_y", "rotation"} - set(
        getattr(table, "colnames", ()))
    if missing:
        raise TypeError("plot_night needs a BatchResult or its to_table(); got "
                        f"{type(result).__name__} without the columns {sorted(missing)}.")
    fig, axes = _subplots(fig, (8, 9), 4, 1, sharex=True)
    k = np.arange(len(table))
    failed = np.asarray(table["status"]) == "failed"
    axes[0].plot(k, table["shift_x"], "o-", label="x")
    axes[0].plot(k, table["shift_y"], "s-", label="y")
    axes[0].legend(loc="best", fontsize="small")
    for ax, col, label in ((axes[1], "rotation", "rotation [deg]"),
                           (axes[2], "rms", "RMS [px]"),
                           (axes[3], "n_matches", "matched stars")):
        values = np.asarray(table[col], dtype=float)
        if col == "n_matches":
            values = np.where(failed, np.nan, values)
        ax.plot(k, values, "o-", color="C2" if col == "rms" else "C0")
        ax.set_ylabel(label)
    axes[0].set_ylabel("shift [px]")
    for ax in axes:
        if failed.any():
            ax.plot(k[failed], np.zeros(failed.sum()), "x", color="red",
                    transform=ax.get_xaxis_transform(), clip_on=False)
        ax.grid(alpha=0.3)
    if len(k) <= 20:  # the frames' names, when they fit
        axes[-1].set_xticks(k, [str(n) for n in table["name"]], rotation=60, ha="right",
                            fontsize="small")
    axes[-1].set_xlabel("frame")
    n_ok = int((~failed).sum())
    fig.suptitle(f"{n_ok} of {len(k)} frames registered"
                 + (f", {int(failed.sum())} failed (red crosses)" if failed.any() else ""))
    return fig


def plot_frame_quality(table, *, fig=None):
    """
    A night's frames measured: FWHM, elongation, transparency, sky noise and
    weight against time, the frames left out marked.

    Five panels share the time axis (hours from the first frame, from the
    ``time`` column; the frame's place when the headers give no time): the
    median star FWHM (px, with its spread), the elongation, the
    transparency, the sky noise and the weight.  The frames used are blue
    dots; those left out red crosses, the first words of their reason
    beside them in the weight panel.

    Parameters
    ----------
    table : `~astropy.table.Table`
        As `~astroalign_nd.frame_quality` returns it (or
        `~astroalign_nd.stacking.LiveStack`'s ``quality``).
    fig : `~matplotlib.figure.Figure`, optional
        As in `plot_night`.

    Returns
    -------
    fig : `~matplotlib.figure.Figure`
        With five Axes.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from astroalign_nd.visualization import plot_frame_quality
    >>> t = Table({"name": ["a", "b", "c"], "time": [60000.0, 60000.01, 60000.02],
    ...            "fwhm": [3.0, 3.4, 6.0], "fwhm_spread": [0.1, 0.1, 0.3],
    ...            "elongation": [1.05, 1.1, 3.0], "transparency": [1.0, 0.98, 0.9],
    ...            "sky_noise": [10.0, 10.2, 10.1], "weight": [1.0, 0.8, 0.1],
    ...            "used": [True, True, False], "reason": ["", "", "trailed"]})
    >>> fig = plot_frame_quality(t)
    >>> [ax.get_ylabel() for ax in fig.axes]
    ['FWHM [px]', 'elongation', 'transparency', 'sky noise', 'weight']
    """
    needed = {"fwhm", "elongation", "transparency", "sky_noise", "weight", "used"}
    missing = needed - set(getattr(table, "colnames", ()))
    if missing:
        raise TypeError("plot_frame_quality needs frame_quality's table; got "
                        f"{type(table).__name__} without the columns {sorted(missing)}.")
    fig, axes = _subplots(fig, (8, 10), 5, 1, sharex=True)
    time = np.asarray(table["time"], dtype=float) if "time" in table.colnames else \
        np.full(len(table), np.nan)
    if np.isfinite(time).all() and len(time):
        x, xlabel = (time - time.min()) * 24.0, "hours from the first frame"
    else:
        x, xlabel = np.arange(len(table), dtype=float), "frame"
    used = np.asarray(table["used"], dtype=bool)
    spread = np.asarray(table["fwhm_spread"], float) if "fwhm_spread" in table.colnames \
        else None
    for ax, col, label in ((axes[0], "fwhm", "FWHM [px]"),
                           (axes[1], "elongation", "elongation"),
                           (axes[2], "transparency", "transparency"),
                           (axes[3], "sky_noise", "sky noise"),
                           (axes[4], "weight", "weight")):
        y = np.asarray(table[col], dtype=float)
        ax.plot(x, y, "-", color="0.75", zorder=0)
        if col == "fwhm" and spread is not None:
            ax.errorbar(x[used], y[used], yerr=spread[used], fmt="o", color="C0", ms=4)
        else:
            ax.plot(x[used], y[used], "o", color="C0", ms=4)
        ax.plot(x[~used], np.where(np.isfinite(y[~used]), y[~used], 0.0), "x", color="red",
                ms=8, mew=2)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    if "reason" in table.colnames:
        for xi, yi, why in zip(x[~used], np.asarray(table["weight"], float)[~used],
                               np.asarray(table["reason"])[~used]):
            axes[4].annotate(str(why).split(":")[0][:24], (xi, yi if np.isfinite(yi) else 0),
                             textcoords="offset points", xytext=(4, 4), fontsize="x-small",
                             color="red")
    axes[-1].set_xlabel(xlabel)
    fig.suptitle(f"{int(used.sum())} of {len(used)} frames used"
                 + (f", {int((~used).sum())} left out (red crosses)" if (~used).any() else ""))
    return fig


def _save(fig, path, overwrite, dpi):
    """Write ``fig`` to ``path`` atomically, in the format of its ending."""
    path = os.fspath(path)
    fmt = os.path.splitext(path)[1][1:].lower()
    # Through the file the package opened: no temporary name is handed to matplotlib.
    with atomic_open(path, overwrite=overwrite) as f:
        fig.savefig(f, format=fmt, dpi=dpi)
    return path


def _agg_figure(figsize):
    """A figure drawn with the Agg backend: no pyplot window, no global state."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_night_figure(path, result, *, overwrite=False, dpi=100):
    """
    Write the figure of `plot_night` to a file (atomically, without pyplot).

    Parameters
    ----------
    path, overwrite, dpi
        As in `save_diagnostic_figure`: the image file (its ending gives the
        format), whether to replace it, the resolution of raster formats.
    result : `~astroalign_nd.batch.BatchResult` or `~astropy.table.Table`
        As in `plot_night`.

    Returns
    -------
    path : str
        The file written.

    Examples
    --------
    >>> import os, tempfile
    >>> from astroalign_nd.batch import register_batch
    >>> from astroalign_nd.simulate import simulate_pair
    >>> from astroalign_nd.visualization import save_night_figure
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=3.0, seed=1)
    >>> result = register_batch([pair.source], pair.target)
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     out = save_night_figure(os.path.join(folder, "night.png"), result)
    ...     os.path.getsize(out) > 0
    True
    """
    check_plot_path(path, overwrite)
    fig = _agg_figure((8, 9))
    plot_night(result, fig=fig)
    return _save(fig, path, overwrite, dpi)
