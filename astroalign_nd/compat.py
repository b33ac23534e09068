# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
astroalign 2.6's public API, run on the astroalign_nd engine.

A one-line migration for code written for `astroalign
<https://github.com/quatrope/astroalign>`_::

    from astroalign_nd import compat as aa

``find_transform``, ``apply_transform`` and ``register`` keep astroalign
2.6.2's signatures and return types: plain NumPy arrays and a
``(aligned_image, footprint)`` pair, transforms as
`skimage.transform.SimilarityTransform` objects (``.params``, ``.scale``,
``.rotation``, ``.translation``, ``.inverse``, callable on (N, 2) arrays).
Underneath, detection is `~astroalign_nd.find_sources` (photutils) and
matching is `~astroalign_nd.registration.find_match`; astroalign itself is
neither imported nor copied.

What the engine does better carries over: mirrored images (returned as a
`skimage.transform.AffineTransform`, since a skimage similarity cannot hold
a reflection), hot pixels and cosmic rays (rejected by detection), wide or
sparse fields (adaptive threshold and tolerance), NaN pixels (reported in
the footprint instead of spreading), a deterministic answer, and a
`~astroalign_nd.PoorFitWarning` for an uncertain fit.  Where the engine
finds nothing it trusts, astroalign's own detection criterion and
acceptance rule are tried before `MaxIterError` is raised (see
`find_transform`).  Where the two differ on purpose, this module follows
astroalign's documented behaviour; the migration page of the
documentation lists the differences.

The module constants are read at every call, as in astroalign:
``PIXEL_TOL`` (matching tolerance, pixels), ``MIN_MATCHES_FRACTION`` and
``NUM_NEAREST_NEIGHBORS`` (stars per triangle neighbourhood, the star
itself included).  Left at their defaults, the engine's own (adaptive)
settings apply.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from ._validate import check_count
from .detection import SegmentationFinder
from .exceptions import TooFewSourcesError, TransformNotFoundError, warn
from .matching import bounding_frame, match_points, overlap_counts, search_tolerance
from .registration import Reference, find_match
from .resample import resample
from .transforms import as_matrix

__all__ = [
    "MIN_MATCHES_FRACTION",
    "MaxIterError",
    "NUM_NEAREST_NEIGHBORS",
    "PIXEL_TOL",
    "apply_transform",
    "estimate_transform",
    "find_transform",
    "matrix_transform",
    "register",
]

#: The version of astroalign whose API this module reproduces.
_ASTROALIGN_API_VERSION = "2.6.2"

PIXEL_TOL = 2
"""The pixel distance tolerance to assume two points are the same.

Default: 2.  At the default the engine picks its own matching radius (3 px,
or half the stellar FWHM for wide stars); any other value is used as the
matching radius.  It is also the largest residual allowed by the fallback
acceptance rule (see `find_transform`)."""

MIN_MATCHES_FRACTION = 0.8
"""The minimum fraction of matches to accept a transformation.

Default: 0.8.  Used only by the fallback acceptance rule for lists too
small for the engine's false-alarm test (see `find_transform`): the fraction
of the stars in the overlap that must agree within ``PIXEL_TOL``."""

NUM_NEAREST_NEIGHBORS = 5
"""The number of nearest neighbours of a star (itself included) that form
its triangles.

Default: 5 (the engine's ``n_neighbors=4``)."""

# astroalign's defaults, which select the engine's adaptive behaviour.
_DEFAULT_SIGMA = 5
_DEFAULT_PIXEL_TOL = 2
_DEFAULT_NN = 5
# Matrix entries this close to an integer are rounded: a rotation by 90 degrees
# computed in floating point (cos = 6e-17) must land on pixel centres.
_SNAP = 1e-12


class MaxIterError(TransformNotFoundError, RuntimeError):
    """No transformation was found (astroalign's exception).

    Also a `~astroalign_nd.TransformNotFoundError`, whose message says how
    many sources each image gave and how many matches were tried.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd import compat as aa
    >>> rng = np.random.default_rng(0)
    >>> a, b = rng.uniform(0, 500, (20, 2)), rng.uniform(0, 500, (20, 2))
    >>> try:
    ...     aa.find_transform(a, b)  # two unrelated star lists
    ... except aa.MaxIterError:
    ...     print("refused")
    refused
    """


def estimate_transform(*args: Any, **kwargs: Any) -> Any:
    """
    `skimage.transform.estimate_transform`, imported on first use.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd import compat as aa
    >>> src = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    >>> t = aa.estimate_transform("similarity", src, src + [5.0, -2.0])
    >>> np.round(t.translation, 6).tolist()
    [5.0, -2.0]
    """
    return _skimage("estimate_transform")(*args, **kwargs)


def matrix_transform(*args: Any, **kwargs: Any) -> Any:
    """
    `skimage.transform.matrix_transform`, imported on first use: a 3x3
    homogeneous matrix applied to (N, 2) points.

    Examples
    --------
    A shift by (3, 4):

    >>> from astroalign_nd import compat as aa
    >>> shift = [[1.0, 0.0, 3.0], [0.0, 1.0, 4.0], [0.0, 0.0, 1.0]]
    >>> aa.matrix_transform([[1.0, 1.0]], shift).tolist()
    [[4.0, 5.0]]
    """
    return _skimage("matrix_transform")(*args, **kwargs)


def _skimage(name):
    """A function of `skimage.transform`, imported on first use (a slow import)."""
    import skimage.transform

    return getattr(skimage.transform, name)


# -- inputs, as astroalign reads them --------------------------------------------

def _data(image):
    """The bare array: ``image.data`` when it is an ndarray, else ``np.asarray(image)``."""
    if hasattr(image, "data") and isinstance(image.data, np.ndarray):
        return image.data
    return np.asarray(image)


def _mask(image):
    """A 2-D bool mask (any channel) or None."""
    mask = getattr(image, "mask", None)
    if mask is None or mask is np.ma.nomask:
        return None
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim == 3:
        mask = mask.any(axis=-1)
    return mask


def _is_catalog(arr):
    # astroalign's rule: rows of two numbers are (x, y) pairs.
    return arr.ndim == 2 and arr.shape[1] == 2


def _control_input(obj, name):
    """What the engine gets: an (N, 2) catalog, or a 2-D masked image."""
    try:
        arr = _data(obj)
        if arr.dtype == object or arr.dtype.kind not in "biuf":
            raise TypeError
    except (TypeError, ValueError):
        raise TypeError(
            f"Input type for {name} not supported: pass a 2-D NumPy array, NDData/CCDData, "
            f"a PIL image or an (N, 2) list of (x, y) positions; got {type(obj).__name__}."
        ) from None
    if _is_catalog(arr):
        return np.array(arr, dtype=float)
    if arr.ndim == 3:
        arr = arr.mean(axis=-1)  # astroalign detects on the channel mean
    elif arr.ndim != 2:
        raise TypeError(
            f"Input type for {name} not supported: an image must be 2-D or (ny, nx, "
            f"channels); got shape {arr.shape}."
        )
    mask = _mask(obj)
    if mask is not None and mask.shape != arr.shape:
        raise ValueError(f"the {name}'s mask has shape {mask.shape}, its image {arr.shape}; "
                         "pass a mask of the image's shape (True for bad pixels).")
    return np.ma.MaskedArray(np.asarray(arr, dtype=float), mask=mask)


def _engine_options(detection_sigma):
    """astroalign's knobs as engine options (defaults leave the engine adaptive)."""
    opts = {}
    if detection_sigma != _DEFAULT_SIGMA:
        opts["nsigma"] = float(detection_sigma)
    if PIXEL_TOL != _DEFAULT_PIXEL_TOL:
        opts["tolerance"] = float(PIXEL_TOL)
    if NUM_NEAREST_NEIGHBORS != _DEFAULT_NN:
        if NUM_NEAREST_NEIGHBORS < 3:
            raise ValueError(
                f"NUM_NEAREST_NEIGHBORS must be at least 3 (a triangle); got "
                f"{NUM_NEAREST_NEIGHBORS}.")
        opts["n_neighbors"] = int(NUM_NEAREST_NEIGHBORS) - 1
    return opts


def _segment_sources(image, mask, detection_sigma, min_area):
    """
    astroalign's detection criterion: `~astroalign_nd.detection.SegmentationFinder`.

    Sources are groups of at least ``min_area`` connected pixels above
    ``detection_sigma`` times the background's standard deviation (after
    subtracting a 64-pixel background map), as astroalign documents its
    keywords.  Returns (x, y) centroids, brightest (largest segment flux)
    first.
    """
    finder = SegmentationFinder(nsigma=detection_sigma, min_area=max(int(min_area), 1))
    if mask is np.ma.nomask:
        mask = None
    found = finder(np.asarray(image, dtype=float), mask=mask)
    return np.column_stack([np.asarray(found["x"], float), np.asarray(found["y"], float)])


# -- find_transform ------------------------------------------------------------------

def find_transform(source: Any, target: Any, max_control_points: int = 50,
                   detection_sigma: int = 5, min_area: int = 5) -> tuple[Any, tuple]:
    """
    Estimate the transform between ``source`` and ``target``.

    astroalign 2.6's ``find_transform``, on the astroalign_nd engine.

    Parameters
    ----------
    source, target
        2-D NumPy arrays (or ``(ny, nx, channels)``; detection uses the
        channel mean), NDData/CCDData or masked arrays (their masks are
        honoured), PIL images, or iterables of (x, y) control points,
        brightest first.
    max_control_points : int, optional
        The maximum number of control points (brightest sources) whose
        triangles are matched (the engine's ``n_sources``; no escalation
        beyond it).  More detected stars may refine the fit.
    detection_sigma : int, optional
        Detection threshold in units of the background noise.  At the
        default (5) the engine keeps its adaptive threshold: 5 sigma, or
        down to 3 sigma when the field has too few stars.
    min_area : int, optional
        Minimum number of connected pixels of a source, used by the
        astroalign-style detection that is tried when the engine's finds
        no trusted match (see Notes); the engine's own detection rejects
        hot pixels and cosmic rays by their shape instead.

    Returns
    -------
    T : `skimage.transform.SimilarityTransform`
        Maps source pixel ``(x, y)`` to target pixel ``(x, y)``: ``T.params``,
        ``T.scale``, ``T.rotation`` (radians), ``T.translation``.  A
        mirrored solution comes as a `skimage.transform.AffineTransform`.
    (source_pos_array, target_pos_array) : tuple of (K, 2) ndarray
        The matched star positions.

    Raises
    ------
    TypeError
        If ``source`` or ``target`` is not a supported input.
    ValueError
        If fewer than 3 stars are found in either input
        (`~astroalign_nd.TooFewSourcesError`).
    MaxIterError
        If no transformation is found.

    Warns
    -----
    `~astroalign_nd.PoorFitWarning`
        If the transform is uncertain (few stars) or a similarity does not
        describe the pair; astroalign returns such answers silently.

    Notes
    -----
    The engine (`~astroalign_nd.find_sources` and
    `~astroalign_nd.registration.find_match`) answers first, and only with
    a match that its false-alarm test vouches for.  When it finds none,
    what astroalign would have done is tried: sources detected by
    astroalign's criterion (at least ``min_area`` connected pixels above
    ``detection_sigma`` background standard deviations, with photutils
    segmentation), matched by the engine; and for lists of a handful of
    stars, which no false-alarm test can vouch for, a solution is accepted
    when at least ``MIN_MATCHES_FRACTION`` of the stars in the overlap (and
    at least 4, or all 3 of a 3-star list) agree within ``PIXEL_TOL``
    pixels.

    Examples
    --------
    >>> from astroalign_nd import compat as aa
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> T, (src, dst) = aa.find_transform(pair.source, pair.target)
    >>> round(float(T.rotation * 180 / 3.141592653589793), 1)
    30.0
    """
    n = check_count(max_control_points, "max_control_points")
    opts = _engine_options(detection_sigma)
    det = {"nsigma": opts.pop("nsigma")} if "nsigma" in opts else {}
    inputs = (_control_input(source, "source"), _control_input(target, "target"))
    refs = tuple(Reference(x, _role=role, **det) for x, role in zip(inputs, ("source", "target")))
    try:
        result = find_match(*refs, n_sources=n, max_sources=n, **opts)
    except (TransformNotFoundError, TooFewSourcesError) as exc:
        result = _fallback(inputs, refs, n, detection_sigma, min_area, opts, exc)
    # A skimage SimilarityTransform (an AffineTransform if mirrored), as astroalign returns.
    from skimage.transform import AffineTransform, SimilarityTransform

    m = np.array(result.transform.matrix, dtype=float)
    model = SimilarityTransform if np.linalg.det(m[:2, :2]) > 0 else AffineTransform
    return model(matrix=m), (result.source_points, result.target_points)


def _fallback(inputs, refs, n, detection_sigma, min_area, opts, exc):
    """
    What astroalign would have done, when the engine finds nothing it trusts.

    1. Images are detected again by astroalign's criterion
       (`_segment_sources`): the engine's matched filter can be misled
       where the noise is correlated (smoothed or compressed images).
    2. The engine's matcher with its false-alarm test, on those lists.
    3. Lists of a handful of stars cannot pass that test: as astroalign
       would, the best solution is accepted when at least
       ``MIN_MATCHES_FRACTION`` of the stars in the overlap (and at least
       4, or all 3 of a 3-star list) agree within ``PIXEL_TOL`` pixels.

    Raises `MaxIterError` (or the engine's `TooFewSourcesError`) otherwise.
    """
    lists = []
    for inp, ref in zip(inputs, refs):
        if ref.shape is None:  # a catalog
            pts = ref.stars(n)[0]
            frame = bounding_frame(pts) if len(pts) else None
        else:
            pts = _segment_sources(inp.data, np.ma.getmask(inp), detection_sigma,
                                   min_area)[:2 * n]
            ny, nx = inp.shape
            frame = (-0.5, nx - 0.5, -0.5, ny - 0.5)
        if len(pts) < 3:
            if isinstance(exc, TooFewSourcesError):
                raise exc
            raise MaxIterError(str(exc)) from exc
        lists.append((pts, frame))
    (src_pts, src_frame), (dst_pts, dst_frame) = lists
    common = dict(n_neighbors=opts.get("n_neighbors", 4), source_frame=src_frame,
                  target_frame=dst_frame, n_control=(n, n),
                  prior_trials=getattr(exc, "n_hypotheses", 0))
    try:
        return match_points(src_pts, dst_pts,
                            tolerance=opts.get("tolerance", search_tolerance()), **common)
    except TransformNotFoundError:
        pass
    # The candidate's warnings (an uncertain fit) are shown only if the rule accepts it.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result = match_points(src_pts, dst_pts, tolerance=float(PIXEL_TOL),
                                  max_false_alarm=1.0, **common)
        except TransformNotFoundError:
            raise MaxIterError(str(exc)) from exc
    m = result.transform.matrix
    n_in = max(overlap_counts(m, src_pts, dst_pts, src_frame, dst_frame))
    need = 3 if n_in == 3 else max(4, math.ceil(MIN_MATCHES_FRACTION * n_in - 1e-9))
    resid = np.hypot(*np.asarray(result.residuals, float).reshape(-1, 2).T)
    if result.n_matches < need or np.max(resid, initial=0.0) >= PIXEL_TOL:
        raise MaxIterError(
            f"{exc} Nor does astroalign's rule accept a solution: {result.n_matches} "
            f"of the {n_in} stars in the overlap agree (at least {need} needed, within "
            f"PIXEL_TOL={PIXEL_TOL} px).") from exc
    for w in caught:
        warn(str(w.message), w.category)
    return result


# -- apply_transform and register ------------------------------------------------------

def apply_transform(transform: Any, source: Any, target: Any, fill_value: float | None = None,
                    propagate_mask: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """
    Apply the transformation ``transform`` to ``source``.

    astroalign 2.6's ``apply_transform``, on the astroalign_nd resampler
    (`~astroalign_nd.resample.resample`, bicubic: astroalign warps with a
    cubic spline).  The output has the shape of ``target``.

    Parameters
    ----------
    transform
        A scikit-image transform (as `find_transform` returns), an
        astroalign_nd transform, an astropy affine model or a 3x3 matrix,
        mapping source pixels to target pixels.
    source
        A 2-D (or ``(ny, nx, channels)``) NumPy array, NDData/CCDData, masked
        array or PIL image: the image to transform.
    target
        The same kinds; only its shape is used.
    fill_value : float, optional
        The value of the pixels where ``footprint`` is True.  By default
        pixels outside the source are the source's median and pixels
        flagged through ``propagate_mask`` keep their interpolated value.
    propagate_mask : bool, optional
        Whether to add ``source.mask`` (transformed) to ``footprint``.

    Returns
    -------
    aligned_image : ndarray
        The transformed source, clipped to the source's range as astroalign
        does: float32 for float32 input, float64 otherwise;
        ``(ny, nx, channels)`` for multichannel input.
    footprint : (ny, nx) bool ndarray
        True where the aligned image holds no pixel information: outside
        the source, touching a NaN source pixel, and (with
        ``propagate_mask``) touching a masked source pixel.

    Examples
    --------
    >>> import numpy as np
    >>> from skimage.transform import SimilarityTransform
    >>> from astroalign_nd import compat as aa
    >>> T = SimilarityTransform(translation=(1, 0))
    >>> img = np.arange(16.0).reshape(4, 4)
    >>> aligned, footprint = aa.apply_transform(T, img, img)
    >>> aligned[0]
    array([7.5, 0. , 1. , 2. ])
    >>> footprint[0]
    array([ True, False, False, False])
    """
    # Entries within 1e-12 of an integer rounded.
    m = np.array(as_matrix(transform), dtype=float)
    r = np.round(m)
    close = np.abs(m - r) < _SNAP
    m[close] = r[close]
    data = np.asarray(_data(source))
    if data.dtype.kind not in "biuf" or data.ndim not in (2, 3):
        raise TypeError(
            "source must be a 2-D or (ny, nx, channels) image of numbers (NumPy array, "
            f"NDData/CCDData or PIL image); got {type(source).__name__} of dtype {data.dtype} "
            f"and shape {data.shape}.")
    # float32 stays float32 (as astroalign's warp returns it); anything else is float64.
    data = data.astype(np.float32 if data.dtype == np.float32 else np.float64, copy=False)
    shape_out = tuple(int(s) for s in np.shape(_data(target))[:2])
    finite = data[np.isfinite(data)]
    cval = float(np.median(finite)) if finite.size else 0.0
    aligned, _, footprint = resample(data, m, shape_out, order="bicubic", fill_value=cval)
    if finite.size:  # astroalign warps with clip=True: no overshoot beyond the input range
        np.clip(aligned, finite.min(), finite.max(), out=aligned)
    source_mask = _mask(source)
    if propagate_mask and source_mask is not None and source_mask.shape == data.shape[:2]:
        _, _, masked = resample(np.zeros(data.shape[:2]), m, shape_out, order="bicubic",
                                mask=source_mask, fill_value=0.0)
        footprint = footprint | masked
    if fill_value is not None:
        aligned[footprint] = fill_value
    return aligned, footprint


def register(source: Any, target: Any, fill_value: float | None = None,
             propagate_mask: bool = False, max_control_points: int = 50,
             detection_sigma: int = 5, min_area: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """
    Transform ``source`` to coincide pixel to pixel with ``target``.

    astroalign 2.6's ``register``: `find_transform`, then `apply_transform`.

    Parameters
    ----------
    source, target
        Images, as in `apply_transform`; ``target`` also sets the output
        shape.
    fill_value, propagate_mask
        As in `apply_transform`.
    max_control_points, detection_sigma, min_area
        As in `find_transform`.

    Returns
    -------
    aligned_image, footprint : ndarray
        As in `apply_transform`.

    Raises
    ------
    TypeError, ValueError, MaxIterError
        As in `find_transform`.

    Examples
    --------
    >>> from astroalign_nd import compat as aa
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    >>> aligned, footprint = aa.register(pair.source, pair.target)
    >>> aligned.shape, footprint.dtype
    ((256, 256), dtype('bool'))
    """
    t, _ = find_transform(source, target, max_control_points=max_control_points,
                          detection_sigma=detection_sigma, min_area=min_area)
    return apply_transform(t, source, target, fill_value=fill_value,
                           propagate_mask=propagate_mask)


def _find_sources(img: Any, detection_sigma: int = 5, min_area: int = 5,
                  mask: Any = None) -> np.ndarray:
    """
    Source positions (x, y), brightest first (astroalign's private helper).

    Groups of at least ``min_area`` connected pixels above ``detection_sigma``
    times the background's standard deviation, found with photutils
    segmentation (astroalign uses sep); returns an (N, 2) array.
    """
    return _segment_sources(img, mask, detection_sigma, min_area)
