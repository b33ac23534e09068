# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Matrix helpers shared by every transform model.

A leaf module: it imports no other module of the package.  Its public names
(`apply_matrix`, `as_3x3`, `is_singular`, `check_invertible`) are the helpers other stages
use; `apply_matrix` is also ``astroalign_nd.transforms.apply_matrix``.  (The
one check of point lists is ``astroalign_nd._validate.check_points``.)
"""

from __future__ import annotations

import numpy as np
from astropy import units as u
from astropy.modeling import Parameter

__all__ = ['apply_matrix', 'as_3x3', 'check_invertible', 'is_singular', 'SINGULAR_RTOL']


def _as_degrees(value, name="rotation"):
    """An angle in degrees from a number (degrees) or an angle Quantity."""
    if isinstance(value, Parameter):
        value = value.quantity if value.unit is not None else value.value
    if isinstance(value, u.Quantity):
        try:
            return value.to_value(u.deg)
        except u.UnitsError:
            raise u.UnitsError(
                f"{name} must be an angle (a number of degrees or an angle Quantity); got "
                f"a Quantity in {value.unit}."
            ) from None
    return value


def _check_parity_value(parity):
    values = np.ravel(np.asarray(parity.value if isinstance(parity, Parameter) else parity,
                                 dtype=float))
    if not np.all((values == 1.0) | (values == -1.0)):  # (np.isin's answer, faster)
        raise ValueError(
            f"parity must be +1 (proper) or -1 (mirrored); got {parity!r}. A mirrored "
            "transform is parity=-1 with the rotation that follows the flip of the y axis."
        )


def as_3x3(matrix):
    """
    A finite 3x3 float matrix from a 3x3 or 2x3 (affine) array-like.

    Raises
    ------
    ValueError
        For another shape, or NaN or infinite values.

    Examples
    --------
    >>> from astroalign_nd.transforms._matrix import as_3x3
    >>> as_3x3([[1, 0, 5], [0, 1, -2]])
    array([[ 1.,  0.,  5.],
           [ 0.,  1., -2.],
           [ 0.,  0.,  1.]])
    """
    m = np.asarray(matrix, dtype=float)
    if m.shape == (2, 3):
        m = np.vstack([m, [0.0, 0.0, 1.0]])
    if m.shape != (3, 3):
        raise ValueError(f"matrix must have shape (3, 3) or (2, 3); got {m.shape}.")
    if not np.all(np.isfinite(m)):
        raise ValueError("matrix contains NaN or infinite values.")
    return m


def apply_matrix(matrix, points):
    """
    Map points through the affine part of a 3x3 homogeneous matrix.

    The fast path for loops over many points and matrices: no checks, and
    the last row of ``matrix`` is not used (a projective matrix needs its
    `~astroalign_nd.transforms.ProjectiveTransform`).

    Parameters
    ----------
    matrix : (3, 3) or (2, 3) ndarray
        Source-to-target matrix, e.g. ``transform.matrix``.
    points : (N, 2) ndarray
        ``(x, y)`` positions.

    Returns
    -------
    mapped : (N, 2) ndarray
        ``matrix[:2, :2] @ (x, y) + matrix[:2, 2]`` for each point.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import SimilarityTransform, apply_matrix
    >>> t = SimilarityTransform(scale=2.0, rotation=90.0, translation_x=10.0)
    >>> apply_matrix(t.matrix, np.array([[1.0, 0.0], [0.0, 1.0]])).round(12)
    array([[10.,  2.],
           [ 8.,  0.]])
    """
    return points @ matrix[:2, :2].T + matrix[:2, 2]


def _check_spread(cls, pts, name):
    """
    Refuse point sets that do not determine the model.

    Two coincident points fix no rotation or scale; collinear points fix
    no affine transform across their line.
    """
    if cls.n_dof <= 2 or len(pts) == 0:
        return
    centred = pts - pts.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    size = max(float(np.max(np.abs(pts))), 1.0)
    if sv[0] <= 1e-12 * size:
        raise ValueError(
            f"the {name} points all coincide; a {cls.__name__} needs at least 2 distinct "
            "points (3 not on one line for an AffineTransform).")
    if cls.n_dof >= 6 and (len(sv) < 2 or sv[1] <= 1e-9 * sv[0]):
        raise ValueError(
            f"the {name} points are collinear; an {cls.__name__} is undetermined across "
            "their line. Give points that span an area, or fit a SimilarityTransform.")


#: The one singularity threshold of the package's transforms (`is_singular`):
#: ``|det| <= SINGULAR_RTOL * |M|**n`` for the n x n matrix tested (Frobenius norm).
SINGULAR_RTOL = 1e-12


def is_singular(matrix):
    """
    True if a transform's matrix has no usable inverse (or is not finite).

    The test is ``|det L| <= SINGULAR_RTOL * |L|_F**2`` on the linear part
    ``L`` -- about a condition number above 1e12, whatever the scale.  For an
    affine matrix (a 2x2 one, or a 3x3 one with last row ``[0, 0, 1]``), ``L``
    is its 2x2 block; for a homography ``[[A, t], [v, h33]]``, ``L = h33 A -
    t v^T`` (``det H = det L / h33``), which, unlike ``H`` itself, does not
    depend on the pixel unit.  (A homography with ``h33 = 0`` is tested as a
    3x3 matrix, ``|det H| <= SINGULAR_RTOL * |H|_F**3``.)

    Examples
    --------
    >>> from astroalign_nd.transforms._matrix import is_singular
    >>> is_singular([[1.0, 2.0, 5.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    True
    >>> is_singular([[1.0, 0.0, 1e5], [0.0, 1.0, 1e5], [1e-6, 0.0, 1.0]])  # a homography
    False
    """
    m = np.asarray(matrix, dtype=float)
    lin = m[:2, :2]
    if m.shape == (3, 3) and (m[2, 0] != 0 or m[2, 1] != 0 or m[2, 2] != 1):
        lin = m if m[2, 2] == 0 else m[2, 2] * lin - np.outer(m[:2, 2], m[2, :2])
    with np.errstate(over="ignore", invalid="ignore"):
        det = float(np.linalg.det(lin))
        norm2 = float(np.sum(lin**2))
    return not (np.isfinite(det) and np.isfinite(norm2)) or (
        abs(det) <= SINGULAR_RTOL * max(norm2 ** (len(lin) / 2), 1e-300))


def check_invertible(matrix, name, fitted=False):
    """
    Refuse a singular transform (zero scale, or points squashed onto a line).

    Parameters
    ----------
    matrix : (3, 3) or (2, 2) array-like
        The matrix, tested by `is_singular`.
    name : str
        What it is, for the message (``'AffineTransform'``).
    fitted : bool, optional
        The matrix was fitted to points: the message says why it is singular.

    Raises
    ------
    ValueError
        If the matrix is singular or not finite.

    Examples
    --------
    >>> from astroalign_nd.transforms._matrix import check_invertible
    >>> check_invertible([[1.0, 2.0], [2.0, 4.0]], "AffineTransform")
    Traceback (most recent call last):
    ...
    ValueError: the AffineTransform is singular (its scale is zero or its matrix singular); it \
has no inverse and cannot register an image.
    """
    if is_singular(matrix):
        why = ("the dst points are collinear or coincide, so the fit squashes the plane "
               "onto a line" if fitted else "its scale is zero or its matrix singular")
        raise ValueError(f"the {name} is singular ({why}); it has no inverse and cannot "
                         "register an image.")


def _rotation_matrix(angle, parity):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s * parity], [s, c * parity]])


def _close(a, b, atol):
    """
    ``np.allclose(a, b, rtol=0.0, atol=atol)`` of float arrays, the same answer
    (equal infinities are close, NaN is not) for a fraction of its overhead: a
    fitted model's conversion to parameter values tests its matrix this way.
    """
    with np.errstate(invalid="ignore"):  # (inf - inf)
        return bool(np.all((a == b) | (np.abs(a - b) <= atol)))


def _rotation_parameters(m, det, scale, message):
    """
    Rotation (degrees), shift and parity of a matrix whose linear part is
    ``scale`` times a rotation, mirrored if ``det < 0``; else ValueError(message).
    """
    parity = 1.0 if det >= 0 else -1.0
    r = m[:2, :2] @ np.diag([1.0, parity])
    if not _close(r.T @ r, scale**2 * np.eye(2), 1e-9 * scale**2):
        raise ValueError(message)
    return dict(rotation=np.degrees(np.arctan2(r[1, 0], r[0, 0])), translation_x=m[0, 2],
                translation_y=m[1, 2], parity=parity)


def _check_parity(parity):
    if parity not in (1, -1, 1.0, -1.0):
        raise ValueError(f"parity must be +1 (proper) or -1 (mirrored); got {parity!r}.")


def _radians(rotation):
    """The evaluate()-time rotation (degrees, or an angle Quantity) in radians."""
    if isinstance(rotation, u.Quantity):
        return rotation.to_value(u.rad)
    return np.deg2rad(rotation)


def _rotation_shift_parameters():
    """
    New ``rotation``, ``translation_x``, ``translation_y`` and ``parity``
    Parameters, in that order: the Euclidean and similarity models' own.
    """
    return (Parameter(default=0.0, description="Rotation (degrees, counter-clockwise)"),
            Parameter(default=0.0, description="Shift along x (pixels)"),
            Parameter(default=0.0, description="Shift along y (pixels)"),
            Parameter(default=1.0, fixed=True, description="+1 proper, -1 mirrored"))


def _rotate_shift(x, y, c, s, translation_x, translation_y, parity):
    """``[[c, -s], [s, c]] @ (x, parity * y) + (tx, ty)``: the rotating models' evaluate."""
    yp = parity * y
    return c * x - s * yp + translation_x, s * x + c * yp + translation_y
