# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Geometric transforms between the pixel grids of two images.

Every transform is an `astropy.modeling.Model` with two inputs and two
outputs, ``(x, y) -> (x', y')``, mapping *source* pixel coordinates to
*target* pixel coordinates (0-based, ``x`` along columns, as photutils and
astropy use them).  They compose with any other astropy model
(``Shift(1) & Shift(2) | SimilarityTransform(...)``), have an analytic
``inverse``, and expose the attributes that scikit-image and astroalign
users know: ``params`` / ``matrix`` (3x3 homogeneous matrix), ``scale``,
``rotation`` and ``translation``.

Angles are in degrees, counter-clockwise, as in astropy's
`~astropy.modeling.rotations.Rotation2D`; an angle can also be given as a
`~astropy.units.Quantity` (``rotation=0.3 * u.rad``), which is converted to
degrees.  (scikit-image's transforms use radians: `to_skimage` and
`from_skimage` convert through the matrix.)

Mirrored (reflected) transforms are represented, not rejected: the
rotation-like models carry a fixed ``parity`` parameter, +1 for a proper
transform and -1 for one that includes a reflection of the y axis *before*
the rotation.  Any other value of ``parity`` is refused.

To refit a transform on matched positions of your own (astropy's fitters
do not fit models with two outputs), use ``from_points`` with optional
weights, or `fit_transform` for the parameter covariance too.

The non-linear models, `ProjectiveTransform` (a homography) and
`PolynomialTransform` (SIP-style distortion), are defined in
`astroalign_nd.nonlinear` and importable from here too.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from astropy import units as u
from astropy.modeling import Model, Parameter
from numpy.typing import ArrayLike

__all__ = [
    "LinearTransform2D",
    "TranslationTransform",
    "EuclideanTransform",
    "SimilarityTransform",
    "AffineTransform",
    "ProjectiveTransform",
    "PolynomialTransform",
    "TRANSFORM_TYPES",
    "LINEAR_TYPES",
    "transform_class",
    "fit_transform",
    "as_matrix",
    "from_matrix",
    "to_skimage",
    "from_skimage",
    "to_astropy_affine",
    "from_astropy_affine",
]


def _as_points(points, name):
    try:
        pts = np.asarray(points, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be an (N, 2) array of (x, y) positions (numbers); got "
                        f"{type(points).__name__}.") from None
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(
            f"{name} must be an (N, 2) array of (x, y) positions; got an array of shape "
            f"{pts.shape}."
        )
    if not np.all(np.isfinite(pts)):
        raise ValueError(f"{name} contains NaN or infinite positions; remove them first.")
    return pts


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
    if not np.all(np.isin(values, (1.0, -1.0))):
        raise ValueError(
            f"parity must be +1 (proper) or -1 (mirrored); got {parity!r}. A mirrored "
            "transform is parity=-1 with the rotation that follows the flip of the y axis."
        )


class LinearTransform2D(Model):
    """
    Base class of the package's 2-D linear (affine-family) transforms.

    Subclasses define their parameters, ``evaluate`` and the two class
    methods ``_from_matrix`` and ``_linear_fit``; everything else (``matrix``,
    ``inverse``, ``from_points``, skimage-style attributes) is shared.

    Examples
    --------
    >>> from astroalign_nd.transforms import LinearTransform2D, EuclideanTransform
    >>> t = EuclideanTransform(rotation=90.0, translation_x=2.0, translation_y=0.0)
    >>> isinstance(t, LinearTransform2D)
    True
    >>> t.matrix.round(12)
    array([[ 0., -1.,  2.],
           [ 1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    >>> t.translation, t.mirrored
    (array([2., 0.]), False)
    """

    n_inputs = 2
    n_outputs = 2
    _separable = False
    fittable = False
    linear = False

    #: Minimum number of point pairs that determine the transform.
    min_points = 3

    def __init__(self, *args, **kwargs):
        if "rotation" in kwargs:
            kwargs["rotation"] = _as_degrees(kwargs["rotation"])
        if "parity" in kwargs:
            _check_parity_value(kwargs["parity"])
        super().__init__(*args, **kwargs)
        self.inputs = ("x", "y")
        self.outputs = ("x", "y")

    def __setattr__(self, name, value):
        # Keep the conventions when a parameter is set after construction.
        if name == "rotation" and "rotation" in getattr(type(self), "param_names", ()):
            value = _as_degrees(value)
        elif name == "parity" and "parity" in getattr(type(self), "param_names", ()):
            _check_parity_value(value)
        super().__setattr__(name, value)
    #: Degrees of freedom (number of free parameters).
    n_dof = 6

    # -- matrix representation -------------------------------------------------
    @property
    def matrix(self):
        """The 3x3 homogeneous matrix ``[[a, b, tx], [c, d, ty], [0, 0, 1]]``."""
        lin, shift = self._linear_part()
        m = np.eye(3)
        m[:2, :2] = lin
        m[:2, 2] = shift
        return m

    @property
    def params(self):
        """Alias of `matrix`, the name scikit-image transforms use."""
        return self.matrix

    @property
    def translation(self):
        """The translation ``(tx, ty)`` in target pixels."""
        return self.matrix[:2, 2].copy()

    @property
    def rotation_deg(self):
        """The rotation in degrees (counter-clockwise), as a float."""
        rotation = self.rotation
        return float(np.ravel(getattr(rotation, "value", rotation))[0])

    @property
    def mirrored(self):
        """True if the transform contains a reflection (negative determinant)."""
        return bool(np.linalg.det(self.matrix[:2, :2]) < 0)

    def _linear_part(self):
        # Evaluate the model on the unit basis: works for every subclass.  The
        # translation parameters are zeroed for that and used directly as the
        # shift, so that the matrix is exact (differencing ``A e + t`` and ``t``
        # loses the low bits of ``A`` when the shift is much larger).
        values = {
            name: float(np.asarray(getattr(self, name).value).ravel()[0])
            for name in self.param_names
        }
        shift = None
        if "translation_x" in values and "translation_y" in values:
            shift = np.array([values["translation_x"], values["translation_y"]])
            values["translation_x"] = values["translation_y"] = 0.0
        x = np.array([0.0, 1.0, 0.0])
        y = np.array([0.0, 0.0, 1.0])
        xo, yo = self.evaluate(x, y, *[values[name] for name in self.param_names])
        if shift is None:
            shift = np.array([xo[0], yo[0]])
        lin = np.array([[xo[1] - xo[0], xo[2] - xo[0]], [yo[1] - yo[0], yo[2] - yo[0]]])
        return lin, shift

    @property
    def parameters_list(self):
        """Parameter values in ``param_names`` order."""
        return [getattr(self, name).value for name in self.param_names]

    @property
    def inverse(self):
        """The analytic inverse, a model of the same class (target -> source)."""
        m = self.matrix
        _check_invertible(m, type(self).__name__)
        return type(self).from_matrix(np.linalg.inv(m))

    # -- construction ----------------------------------------------------------
    @classmethod
    def from_matrix(cls, matrix: ArrayLike) -> LinearTransform2D:
        """
        Build the transform from a 2x3 or 3x3 homogeneous matrix.

        Raises
        ------
        ValueError
            If the matrix cannot be represented by this class (for example a
            sheared matrix given to `SimilarityTransform`).
        """
        m = _as_3x3(matrix)
        if not np.allclose(m[2], [0.0, 0.0, 1.0]):
            raise ValueError(
                "matrix is projective (last row is not [0, 0, 1]); only affine-family "
                "transforms are supported."
            )
        return cls._from_matrix(m)

    @classmethod
    def from_points(cls, src: ArrayLike, dst: ArrayLike, *, weights: ArrayLike | None = None,
                    parity: int | None = None) -> LinearTransform2D:
        """
        Least-squares transform that maps ``src`` onto ``dst``.

        Parameters
        ----------
        src, dst : (N, 2) array-like
            Corresponding (x, y) positions in the source and target frames.
        weights : (N,) array-like, optional
            Non-negative weights of the point pairs, e.g. inverse variances
            ``1 / sigma**2`` of the positions; pairs with weight 0 are left
            out.  Equal weights by default.
        parity : {None, 1, -1}, optional
            For rotation-like transforms: force a proper (+1) or mirrored
            (-1) solution.  `None` (default) picks whichever fits better.

        Returns
        -------
        transform : `LinearTransform2D`
            An instance of the class it is called on.

        Notes
        -----
        This is how to refit a transform on a matched catalog of your own:
        astropy's fitters (`~astropy.modeling.fitting`) fit models with one
        output only.  For the parameter covariance as well, use
        `fit_transform`.

        Examples
        --------
        >>> import numpy as np
        >>> from astroalign_nd import SimilarityTransform
        >>> truth = SimilarityTransform(scale=1.02, rotation=30.0, translation_x=5.0,
        ...                             translation_y=-2.0)
        >>> src = np.random.default_rng(0).uniform(0, 500, (40, 2))
        >>> dst = np.column_stack(truth(*src.T))
        >>> dst[0] += 50.0  # a bad match...
        >>> weights = np.ones(40)
        >>> weights[0] = 0.0  # ...left out
        >>> t = SimilarityTransform.from_points(src, dst, weights=weights)
        >>> round(t.rotation_deg, 6), round(float(t.scale.value), 6)
        (30.0, 1.02)
        """
        model, _, _ = cls._fit(src, dst, weights=weights, parity=parity)
        return model

    @classmethod
    def fit_matrix(cls, src, dst, weights, parity=1):
        """
        Weighted least-squares fit as a matrix, without checks (the fast path).

        What `from_points` does after its checks, for one parity, without
        building a model: for loops that fit thousands of times (the
        matching's refinement).  Inputs are not validated: give finite
        ``(N, 2)`` float arrays and ``N`` non-negative weights, with enough
        points for the model (``cls.min_points``).

        Parameters
        ----------
        src, dst : (N, 2) ndarray
            Matched positions.
        weights : (N,) ndarray
            Per-pair weights (inverse variances).
        parity : {1, -1}, optional
            Mirrored (-1) or not; used by the models with a parity.

        Returns
        -------
        matrix : (3, 3) ndarray
            The fitted homogeneous matrix (source to target).
        design : (2N, k) ndarray
            The fit's design matrix (rows x, y per pair) in the model's
            ``k`` linear parameters, for their covariance.

        Examples
        --------
        >>> import numpy as np
        >>> from astroalign_nd.transforms import TranslationTransform
        >>> src = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
        >>> m, _ = TranslationTransform.fit_matrix(src, src + [2.0, -1.0], np.ones(3))
        >>> m[:2, 2]
        array([ 2., -1.])
        """
        matrix, design, _ = cls._linear_fit(src, dst, weights, parity)
        return matrix, design

    @classmethod
    def _design(cls, src, weights, parity=1):
        """
        The design matrix `fit_matrix` returns for ``src``, weights and
        parity, as if fitting ``src`` onto itself (it does not depend on the
        target for the models linear in their parameters, which override
        this to skip the fit).
        """
        return cls._linear_fit(src, src, weights, parity)[1]

    @classmethod
    def _fit(cls, src, dst, *, weights=None, parity=None):
        """Fit and also return the linear parameter covariance and residuals."""
        src = _as_points(src, "src")
        dst = _as_points(dst, "dst")
        if len(src) != len(dst):
            raise ValueError(
                f"src and dst must have the same length; got {len(src)} and {len(dst)}."
            )
        need = cls.min_points
        if len(src) < need:
            raise ValueError(
                f"{cls.__name__} needs at least {need} point pairs; got {len(src)}."
            )
        w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float)
        if w.shape != (len(src),) or np.any(w < 0) or not np.all(np.isfinite(w)):
            raise ValueError(
                f"weights must be a finite, non-negative array of shape ({len(src)},), one "
                f"per point pair; got shape {w.shape}."
            )
        if np.count_nonzero(w) < need:
            raise ValueError(
                f"{cls.__name__} needs at least {need} point pairs with non-zero weight; got "
                f"{np.count_nonzero(w)}."
            )
        if parity is not None:
            _check_parity(parity)
        parities = [parity] if parity is not None else cls._parities
        best = None
        for p in parities:
            matrix, design, theta = cls._linear_fit(src, dst, w, p)
            resid = _apply(matrix, src) - dst
            sse = float(np.sum(w * np.sum(resid**2, axis=1)))
            if best is None or sse < best[0] - 1e-12 * max(1.0, best[0]):
                best = (sse, matrix, design, resid)
        sse, matrix, design, resid = best
        _check_spread(cls, src[w > 0], "src")
        _check_invertible(matrix, cls.__name__, fitted=True)
        return cls._from_matrix(matrix), design, resid

    _parities = (1,)


def _as_3x3(matrix):
    """A finite 3x3 float matrix from a 3x3 or 2x3 (affine) array-like."""
    m = np.asarray(matrix, dtype=float)
    if m.shape == (2, 3):
        m = np.vstack([m, [0.0, 0.0, 1.0]])
    if m.shape != (3, 3):
        raise ValueError(f"matrix must have shape (3, 3) or (2, 3); got {m.shape}.")
    if not np.all(np.isfinite(m)):
        raise ValueError("matrix contains NaN or infinite values.")
    return m


def _apply(matrix, pts):
    return pts @ matrix[:2, :2].T + matrix[:2, 2]


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


def _check_invertible(matrix, name, fitted=False):
    """Refuse a singular linear part (zero scale, or points squashed onto a line)."""
    lin = np.asarray(matrix, float)[:2, :2]
    with np.errstate(over="ignore", invalid="ignore"):
        det = float(np.linalg.det(lin))
        norm2 = float(np.sum(lin**2))
    if not (np.isfinite(det) and np.isfinite(norm2)) or abs(det) <= 1e-12 * max(norm2, 1e-300):
        why = ("the dst points are collinear or coincide, so the fit squashes the plane "
               "onto a line" if fitted else "its scale is zero or its matrix singular")
        raise ValueError(f"the {name} is singular ({why}); it has no inverse and cannot "
                         "register an image.")


def _weighted_lstsq(a, b, w):
    sw = np.sqrt(np.repeat(w, a.shape[0] // len(w)))
    theta, *_ = np.linalg.lstsq(a * sw[:, None], b * sw, rcond=None)
    return theta


class TranslationTransform(LinearTransform2D):
    """
    A pure shift: ``x' = x + tx``, ``y' = y + ty``.

    Parameters
    ----------
    translation_x, translation_y : float
        The shift in target pixels.

    Examples
    --------
    >>> from astroalign_nd.transforms import TranslationTransform
    >>> t = TranslationTransform(translation_x=3.0, translation_y=-1.5)
    >>> t(10.0, 20.0)
    (13.0, 18.5)
    >>> t.inverse(13.0, 18.5)
    (10.0, 20.0)
    >>> t.scale, t.rotation
    (1.0, 0.0)
    """

    translation_x = Parameter(default=0.0, description="Shift along x (pixels)")
    translation_y = Parameter(default=0.0, description="Shift along y (pixels)")
    min_points = 1
    n_dof = 2

    @staticmethod
    def evaluate(x, y, translation_x, translation_y):
        return x + translation_x, y + translation_y

    @property
    def scale(self):
        """Always 1."""
        return 1.0

    @property
    def rotation(self):
        """Always 0 (degrees)."""
        return 0.0

    @classmethod
    def _from_matrix(cls, m):
        if not np.allclose(m[:2, :2], np.eye(2), rtol=0.0, atol=1e-9):
            raise ValueError(
                "matrix has a rotation, scale or shear part; use SimilarityTransform or "
                "AffineTransform instead of TranslationTransform."
            )
        return cls(translation_x=m[0, 2], translation_y=m[1, 2])

    @classmethod
    def _linear_fit(cls, src, dst, w, parity):
        shift = np.sum(w[:, None] * (dst - src), axis=0) / np.sum(w)
        m = np.eye(3)
        m[:2, 2] = shift
        return m, cls._design(src, w, parity), shift

    @classmethod
    def _design(cls, src, weights, parity=1):
        return np.tile(np.eye(2), (len(src), 1))


def _rotation_matrix(angle, parity):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s * parity], [s, c * parity]])


def _rotation_parameters(m, det, scale, message):
    """
    Rotation (degrees), shift and parity of a matrix whose linear part is
    ``scale`` times a rotation, mirrored if ``det < 0``; else ValueError(message).
    """
    parity = 1.0 if det >= 0 else -1.0
    r = m[:2, :2] @ np.diag([1.0, parity])
    if not np.allclose(r.T @ r, scale**2 * np.eye(2), rtol=0.0, atol=1e-9 * scale**2):
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


class EuclideanTransform(LinearTransform2D):
    """
    Rotation plus shift (rigid motion), optionally mirrored.

    ``(x', y') = R(rotation) @ diag(1, parity) @ (x, y) + (tx, ty)``

    Parameters
    ----------
    rotation : float or `~astropy.units.Quantity`
        Counter-clockwise rotation in degrees (as in astropy's
        `~astropy.modeling.rotations.Rotation2D`), or an angle Quantity.
    translation_x, translation_y : float
        Shift in target pixels.
    parity : {1, -1}
        -1 for a mirrored transform (the y axis is flipped before rotating).
        Fixed, never fitted as a continuous parameter.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import EuclideanTransform
    >>> t = EuclideanTransform(rotation=90.0, translation_x=1.0, translation_y=2.0)
    >>> np.round(t(1.0, 0.0), 12)
    array([1., 3.])
    >>> m = EuclideanTransform(rotation=0.0, parity=-1)  # mirrored: y -> -y
    >>> np.round(m(1.0, 5.0), 12), m.mirrored
    (array([ 1., -5.]), True)
    """

    rotation, translation_x, translation_y, parity = _rotation_shift_parameters()
    min_points = 2
    n_dof = 3
    _parities = (1, -1)

    @staticmethod
    def evaluate(x, y, rotation, translation_x, translation_y, parity):
        theta = _radians(rotation)
        return _rotate_shift(x, y, np.cos(theta), np.sin(theta), translation_x, translation_y,
                             parity)

    @property
    def scale(self):
        """Always 1."""
        return 1.0

    @classmethod
    def _from_matrix(cls, m):
        det = np.linalg.det(m[:2, :2])
        return cls(**_rotation_parameters(
            m, det, 1.0, "matrix has a scale or shear part; use SimilarityTransform or "
            "AffineTransform instead of EuclideanTransform."))

    @classmethod
    def _linear_fit(cls, src, dst, w, parity):
        # Weighted Procrustes (Kabsch) with the reflection fixed by ``parity``.
        _check_parity(parity)
        flip = np.diag([1.0, float(parity)])
        s = src @ flip
        ws = w / np.sum(w)
        ms, md = ws @ s, ws @ dst
        cov = ((dst - md) * ws[:, None]).T @ (s - ms)
        angle = np.arctan2(cov[1, 0] - cov[0, 1], cov[0, 0] + cov[1, 1])
        rot = _rotation_matrix(angle, 1.0)
        m = np.eye(3)
        m[:2, :2] = rot @ flip
        m[:2, 2] = md - rot @ ms
        # Linearised design for the covariance: d(angle), d(tx), d(ty).
        n = len(src)
        design = np.zeros((2 * n, 3))
        design[0::2, 0] = -(s @ rot.T)[:, 1]
        design[1::2, 0] = (s @ rot.T)[:, 0]
        design[0::2, 1] = 1.0
        design[1::2, 2] = 1.0
        return m, design, np.array([angle, *m[:2, 2]])


class SimilarityTransform(LinearTransform2D):
    """
    Uniform scale, rotation and shift, optionally mirrored.

    ``(x', y') = scale * R(rotation) @ diag(1, parity) @ (x, y) + (tx, ty)``

    This is the default model of `~astroalign_nd.find_transform`, and the
    transform of the astroalign paper.

    Parameters
    ----------
    scale : float
        Magnification from source to target pixels.
    rotation : float or `~astropy.units.Quantity`
        As for `~astroalign_nd.transforms.EuclideanTransform`:
        counter-clockwise, in degrees or as an angle Quantity.
    translation_x, translation_y : float
        Shift in target pixels, applied after the rotation and scaling.
    parity : {1, -1}
        -1 for a mirrored transform (the y axis is flipped before rotating
        and scaling).  Fixed, never fitted as a continuous parameter.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd import SimilarityTransform
    >>> t = SimilarityTransform(scale=2.0, rotation=90.0,
    ...                         translation_x=10.0, translation_y=0.0)
    >>> np.round(t(1.0, 0.0), 12)
    array([10.,  2.])
    >>> float(t.rotation.value)  # degrees, as in astropy's Rotation2D
    90.0
    >>> np.allclose(t.inverse(*t(3.0, 4.0)), (3.0, 4.0))
    True
    """

    scale = Parameter(default=1.0, description="Scale factor")
    rotation, translation_x, translation_y, parity = _rotation_shift_parameters()
    min_points = 2
    n_dof = 4
    _parities = (1, -1)

    @staticmethod
    def evaluate(x, y, scale, rotation, translation_x, translation_y, parity):
        theta = _radians(rotation)
        return _rotate_shift(x, y, scale * np.cos(theta), scale * np.sin(theta), translation_x,
                             translation_y, parity)

    @classmethod
    def _from_matrix(cls, m):
        lin = m[:2, :2]
        det = np.linalg.det(lin)
        if det == 0:
            raise ValueError("matrix is singular; it cannot be a similarity transform.")
        scale = np.sqrt(abs(det))
        return cls(scale=scale, **_rotation_parameters(
            m, det, scale, "matrix has a shear or anisotropic scale; use AffineTransform "
            "instead of SimilarityTransform."))

    @classmethod
    def _linear_fit(cls, src, dst, w, parity):
        # Linear in (a, b, tx, ty): x' = a x - b p y + tx ; y' = b x + a p y + ty.
        _check_parity(parity)
        design = cls._design(src, w, parity)
        a, b, tx, ty = _weighted_lstsq(design, dst.ravel(), w)
        m = np.array([[a, -b * parity, tx], [b, a * parity, ty], [0.0, 0.0, 1.0]])
        return m, design, np.array([a, b, tx, ty])

    @classmethod
    def _design(cls, src, weights, parity=1):
        x, y = src[:, 0], float(parity) * src[:, 1]
        design = np.zeros((2 * len(src), 4))
        design[0::2, 0], design[0::2, 1], design[0::2, 2] = x, -y, 1.0
        design[1::2, 0], design[1::2, 1], design[1::2, 3] = y, x, 1.0
        return design


class AffineTransform(LinearTransform2D):
    """
    General affine transform: ``(x', y') = A @ (x, y) + (tx, ty)``.

    Parameters
    ----------
    a11, a12, a21, a22 : float
        The elements of the 2x2 linear part ``A``.
    translation_x, translation_y : float
        Shift in target pixels.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import AffineTransform
    >>> t = AffineTransform(a11=2.0, a12=0.5, a21=0.0, a22=1.0,
    ...                     translation_x=1.0, translation_y=-1.0)
    >>> t(1.0, 2.0)
    (4.0, 1.0)
    >>> np.allclose(t.inverse(*t(3.0, 4.0)), (3.0, 4.0))
    True
    >>> src = np.random.default_rng(0).uniform(0, 100, (10, 2))
    >>> fit = AffineTransform.from_points(src, np.column_stack(t(*src.T)))
    >>> bool(np.allclose(fit.matrix, t.matrix))
    True
    """

    a11 = Parameter(default=1.0)
    a12 = Parameter(default=0.0)
    a21 = Parameter(default=0.0)
    a22 = Parameter(default=1.0)
    translation_x = Parameter(default=0.0, description="Shift along x (pixels)")
    translation_y = Parameter(default=0.0, description="Shift along y (pixels)")
    min_points = 3
    n_dof = 6

    @staticmethod
    def evaluate(x, y, a11, a12, a21, a22, translation_x, translation_y):
        return a11 * x + a12 * y + translation_x, a21 * x + a22 * y + translation_y

    @property
    def scale(self):
        """Scale along the two axes ``(sx, sy)``, as scikit-image defines it."""
        lin = self.matrix[:2, :2]
        # scikit-image: sy is the length of the second column times |cos(shear)|.
        return np.array([
            np.hypot(lin[0, 0], lin[1, 0]),
            np.hypot(lin[0, 1], lin[1, 1]) * abs(np.cos(np.deg2rad(self.shear))),
        ])

    @property
    def rotation(self):
        """Rotation of the x axis, degrees (scikit-image's definition, in degrees)."""
        lin = self.matrix[:2, :2]
        return float(np.degrees(np.arctan2(lin[1, 0], lin[0, 0])))

    @property
    def shear(self):
        """Shear angle in degrees (scikit-image's definition, in degrees)."""
        lin = self.matrix[:2, :2]
        return float(np.degrees(np.arctan2(-lin[0, 1], lin[1, 1]))) - self.rotation

    @classmethod
    def _from_matrix(cls, m):
        return cls(
            a11=m[0, 0], a12=m[0, 1], a21=m[1, 0], a22=m[1, 1],
            translation_x=m[0, 2], translation_y=m[1, 2],
        )

    @classmethod
    def _linear_fit(cls, src, dst, w, parity):
        design = cls._design(src, w, parity)
        a11, a12, a21, a22, tx, ty = _weighted_lstsq(design, dst.ravel(), w)
        m = np.array([[a11, a12, tx], [a21, a22, ty], [0.0, 0.0, 1.0]])
        return m, design, np.array([a11, a12, a21, a22, tx, ty])

    @classmethod
    def _design(cls, src, weights, parity=1):
        design = np.zeros((2 * len(src), 6))
        design[0::2, 0:2] = src
        design[0::2, 4] = 1.0
        design[1::2, 2:4] = src
        design[1::2, 5] = 1.0
        return design


# The non-linear models need the helpers above; they import them when called.
from .nonlinear import PolynomialTransform, ProjectiveTransform  # noqa: E402

#: The ``transform_type`` names accepted by `~astroalign_nd.find_transform`.
TRANSFORM_TYPES = {
    "translation": TranslationTransform,
    "euclidean": EuclideanTransform,
    "similarity": SimilarityTransform,
    "affine": AffineTransform,
    "projective": ProjectiveTransform,
    "polynomial": PolynomialTransform,
}

#: The linear ones among `TRANSFORM_TYPES` (subclasses of `LinearTransform2D`).
LINEAR_TYPES = ("translation", "euclidean", "similarity", "affine")


def transform_class(transform_type: str | type) -> type[Model]:
    """
    Return the model class for a ``transform_type`` name or class.

    Parameters
    ----------
    transform_type : str or type
        One of ``'translation'``, ``'euclidean'``, ``'similarity'``,
        ``'affine'``, ``'projective'``, ``'polynomial'``, or one of the
        classes themselves.

    Returns
    -------
    cls : type
        A subclass of `LinearTransform2D`, or `ProjectiveTransform` or
        `PolynomialTransform`.

    Raises
    ------
    ValueError
        For any other name or class.

    Examples
    --------
    >>> from astroalign_nd.transforms import transform_class, AffineTransform
    >>> transform_class("Similarity").__name__
    'SimilarityTransform'
    >>> transform_class(AffineTransform) is AffineTransform
    True
    """
    if isinstance(transform_type, type) and issubclass(
            transform_type, (LinearTransform2D, ProjectiveTransform, PolynomialTransform)):
        return transform_type
    if isinstance(transform_type, str) and transform_type.lower() in TRANSFORM_TYPES:
        return TRANSFORM_TYPES[transform_type.lower()]
    raise ValueError(
        f"transform_type must be one of {sorted(TRANSFORM_TYPES)} (or one of their "
        f"classes); got {transform_type!r}."
    )


def fit_transform(src: ArrayLike, dst: ArrayLike, transform_type: str | type = "similarity", *,
                  weights: ArrayLike | None = None, parity: int | None = None,
                  degree: int | None = None, crpix: ArrayLike | None = None,
                  domain: ArrayLike | None = None) -> tuple[Model, np.ndarray, np.ndarray]:
    """
    Least-squares fit of a transform, with its parameter covariance.

    Parameters
    ----------
    src, dst : (N, 2) array-like
        Matched (x, y) positions in the source and target frames.
    transform_type : str or type, optional
        See `transform_class`.
    weights : (N,) array-like, optional
        Non-negative weights of the point pairs (e.g. inverse variances);
        see `LinearTransform2D.from_points`.
    parity : {None, 1, -1}, optional
        Force a proper or mirrored solution for rotation-like models.
        The projective and polynomial models take a reflection from the
        data and ignore it.
    degree : int, optional
        Degree of a ``'polynomial'`` model, 2 to 5 (default 3); only for
        that type.
    crpix, domain : optional
        The reference pixel and the inverse's domain of a ``'polynomial'``
        model; see `PolynomialTransform.from_points`.

    Returns
    -------
    transform : `LinearTransform2D`, `ProjectiveTransform` or `PolynomialTransform`
    covariance : ndarray
        Covariance matrix of the model's free parameters (in the order of
        ``transform.param_names``, without the fixed ``parity``, ``crpix1``
        and ``crpix2``; a rotation in degrees), scaled by the residual
        variance.  NaN where there are no spare degrees of freedom.
    residuals : (N, 2) ndarray
        ``transform(src) - dst`` in target pixels.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import EuclideanTransform, fit_transform
    >>> truth = EuclideanTransform(rotation=12.0, translation_x=4.0, translation_y=-7.0)
    >>> rng = np.random.default_rng(1)
    >>> src = rng.uniform(0, 256, (50, 2))
    >>> dst = np.column_stack(truth(*src.T)) + rng.normal(0, 0.1, (50, 2))
    >>> t, cov, resid = fit_transform(src, dst, "euclidean")
    >>> bool(abs(t.rotation_deg - 12.0) < 0.01)
    True
    >>> cov.shape, resid.shape  # rotation, translation_x, translation_y
    ((3, 3), (50, 2))
    >>> bool(np.sqrt(cov[1, 1]) < 0.1)  # 1-sigma error of translation_x, pixels
    True

    A polynomial model (the covariance of its 6 linear and 2 x 3 distortion terms):

    >>> from astroalign_nd.transforms import PolynomialTransform
    >>> truth = PolynomialTransform(degree=2, crpix=(128.0, 128.0), A_2_0=1e-4)
    >>> dst = np.column_stack(truth(*src.T)) + rng.normal(0, 0.05, (50, 2))
    >>> t, cov, resid = fit_transform(src, dst, "polynomial", degree=2)
    >>> t.degree, cov.shape
    (2, (12, 12))
    >>> bool(abs(t.A_2_0.value - 1e-4) < 5 * np.sqrt(cov[6, 6]))
    True
    """
    cls = transform_class(transform_type)
    if parity is not None:
        _check_parity(parity)
    if cls is PolynomialTransform:
        model, design, resid = cls._fit(src, dst, weights=weights, crpix=crpix, domain=domain,
                                        degree=3 if degree is None else degree)
    else:
        given = [k for k, v in (("degree", degree), ("crpix", crpix), ("domain", domain))
                 if v is not None]
        if given:
            raise ValueError(
                f"{', '.join(given)} are for transform_type='polynomial' only; got them with "
                f"{cls.__name__}.")
        model, design, resid = cls._fit(src, dst, weights=weights, parity=parity)
    return model, _covariance(model, design, resid, weights), resid


def _free_params(model):
    fixed = model.fixed  # (a new dict at each access)
    return [n for n in model.param_names if not fixed[n]]


def _covariance(model, design, resid, weights):
    """Parameter covariance via the linear design and a numerical Jacobian."""
    n_obs, n_lin = design.shape
    free = _free_params(model)
    dof = n_obs - n_lin
    if dof <= 0:
        return np.full((len(free), len(free)), np.nan)
    w = np.ones(len(resid)) if weights is None else np.asarray(weights, float)
    sw = np.repeat(w, 2)
    sigma2 = float(np.sum(sw * resid.ravel() ** 2) / dof)
    xtx = design.T @ (design * sw[:, None])
    try:
        cov_lin = sigma2 * np.linalg.inv(xtx)
    except np.linalg.LinAlgError:
        return np.full((len(free), len(free)), np.nan)
    # Map linear parameters to model parameters: they coincide for
    # translation and affine; euclidean's angle goes from radians to
    # degrees; similarity goes (a, b) -> (scale, rotation in degrees).
    deg = 180.0 / np.pi
    if isinstance(model, SimilarityTransform):
        m = model.matrix
        a, b = m[0, 0], m[1, 0]
        r2 = a * a + b * b
        s = np.sqrt(r2)
        jac = np.zeros((4, 4))
        jac[0, :2] = [a / s, b / s]
        jac[1, :2] = [-b / r2 * deg, a / r2 * deg]
        jac[2, 2] = jac[3, 3] = 1.0
        return jac @ cov_lin @ jac.T
    if isinstance(model, EuclideanTransform):
        jac = np.diag([deg, 1.0, 1.0])
        return jac @ cov_lin @ jac.T
    return cov_lin


# -- interoperability ----------------------------------------------------------

def as_matrix(transform: Any) -> np.ndarray:
    """
    The 3x3 homogeneous matrix of any supported transform.

    Accepts the package's models, a 3x3 or 2x3 array, a scikit-image
    geometric transform (anything with a ``params`` matrix) or an astropy
    `~astropy.modeling.projections.AffineTransformation2D`.

    Examples
    --------
    >>> from astropy.modeling.models import Shift
    >>> from astroalign_nd.transforms import SimilarityTransform, as_matrix
    >>> as_matrix(SimilarityTransform(scale=2.0, translation_x=5.0)).round(12)
    array([[2., 0., 5.],
           [0., 2., 0.],
           [0., 0., 1.]])
    >>> as_matrix(Shift(1.0) & Shift(-2.0))  # any affine astropy model
    array([[ 1.,  0.,  1.],
           [ 0.,  1., -2.],
           [ 0.,  0.,  1.]])
    """
    from astropy.modeling.projections import AffineTransformation2D

    if isinstance(transform, LinearTransform2D):
        return transform.matrix
    if isinstance(transform, AffineTransformation2D):
        m = np.eye(3)
        m[:2, :2] = transform.matrix.value
        m[:2, 2] = transform.translation.value
        return m
    if isinstance(transform, Model):
        if transform.n_inputs == 2 and transform.n_outputs == 2:
            # Any other linear 2-D model: probe it on three points and check linearity.
            pts = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1000.0, 1000.0]])
            xo, yo = transform(pts[:, 0], pts[:, 1])
            xo, yo = np.asarray(xo, float), np.asarray(yo, float)
            m = np.eye(3)
            m[:2, 2] = [xo[0], yo[0]]
            m[:2, :2] = [[xo[1] - xo[0], xo[2] - xo[0]], [yo[1] - yo[0], yo[2] - yo[0]]]
            pred = _apply(m, pts[3:4])[0]
            if np.allclose(pred, [xo[3], yo[3]], rtol=1e-9, atol=1e-6):
                return m
            raise ValueError(f"{type(transform).__name__} is not an affine transform.")
        raise TypeError("an astropy model used as a transform must have 2 inputs and 2 outputs.")
    if (isinstance(transform, tuple) and len(transform) == 2
            and isinstance(transform[0], (Model, np.ndarray))):
        raise TypeError(
            "got a (transform, (source_points, target_points)) tuple, as find_transform "
            "returns; pass its first element: transform, _ = find_transform(...)."
        )
    params = getattr(transform, "params", transform)
    try:
        m = np.asarray(params, dtype=float)
    except (TypeError, ValueError):
        m = None
    if m is not None and m.shape == (2, 3):
        m = np.vstack([m, [0.0, 0.0, 1.0]])
    if m is None or m.shape != (3, 3):
        raise TypeError(
            "transform must be an astroalign_nd transform, an astropy model, a scikit-image "
            f"geometric transform or a 3x3 matrix; got {type(transform).__name__}."
        )
    return m


def from_matrix(matrix: Any, transform_type: str | type | None = None) -> LinearTransform2D:
    """
    Build a package transform from a 3x3 (or 2x3) matrix.

    With ``transform_type=None`` the simplest class that represents the
    matrix exactly is chosen (translation, then euclidean, similarity, affine);
    a projective matrix (last row not ``[0, 0, 1]``) needs
    ``transform_type='projective'``.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import from_matrix
    >>> t = from_matrix([[1.0, 0.0, 3.0], [0.0, 1.0, 4.0], [0.0, 0.0, 1.0]])
    >>> type(t).__name__, t.translation.tolist()
    ('TranslationTransform', [3.0, 4.0])
    >>> s = from_matrix(np.array([[0.0, -2.0, 0.0], [2.0, 0.0, 0.0]]))  # 2x3 is fine
    >>> type(s).__name__, round(float(s.scale.value), 12), round(s.rotation_deg, 12)
    ('SimilarityTransform', 2.0, 90.0)
    >>> type(from_matrix(np.eye(3), "affine")).__name__
    'AffineTransform'
    """
    if transform_type is not None:
        cls = transform_class(transform_type)
        if cls is PolynomialTransform:
            raise ValueError(
                "a matrix does not define a PolynomialTransform (its distortion terms); build "
                "one with PolynomialTransform(...) or PolynomialTransform.from_points.")
        if isinstance(matrix, ProjectiveTransform):
            return cls.from_matrix(matrix.matrix)  # as_matrix refuses non-affine models
        return cls.from_matrix(as_matrix(matrix))
    m = as_matrix(matrix)
    for cls in (TranslationTransform, EuclideanTransform, SimilarityTransform):
        try:
            return cls.from_matrix(m)
        except ValueError:
            continue
    return AffineTransform.from_matrix(m)


def to_skimage(transform: Any) -> Any:
    """
    Convert to the matching `skimage.transform` geometric transform.

    A mirrored transform becomes a `skimage.transform.AffineTransform`
    (scikit-image's similarity and euclidean classes cannot hold a
    reflection).  scikit-image angles are in radians.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import SimilarityTransform, to_skimage
    >>> t = SimilarityTransform(scale=1.5, rotation=90.0, translation_x=2.0)
    >>> sk = to_skimage(t)
    >>> type(sk).__name__, bool(np.isclose(sk.rotation, np.pi / 2))
    ('SimilarityTransform', True)
    >>> bool(np.allclose(sk([[1.0, 0.0]]), np.column_stack(t(1.0, 0.0))))
    True
    """
    from skimage import transform as sktf

    m = as_matrix(transform)
    if isinstance(transform, (TranslationTransform, EuclideanTransform)) and not transform.mirrored:
        return sktf.EuclideanTransform(matrix=m)
    if isinstance(transform, SimilarityTransform) and not transform.mirrored:
        return sktf.SimilarityTransform(matrix=m)
    # skimage's similarity/euclidean classes cannot hold a reflection.
    return sktf.AffineTransform(matrix=m)


def from_skimage(sk_transform: Any,
                 transform_type: str | type | None = None) -> LinearTransform2D:
    """
    Convert a scikit-image geometric transform (anything with ``params``).

    ``transform_type`` is as in `from_matrix` (default: the simplest class
    that represents the matrix).

    Examples
    --------
    >>> import numpy as np
    >>> from skimage.transform import EuclideanTransform as SkEuclidean
    >>> from astroalign_nd.transforms import from_skimage
    >>> t = from_skimage(SkEuclidean(rotation=np.pi / 6, translation=(1.0, 2.0)))
    >>> type(t).__name__, round(t.rotation_deg, 9)
    ('EuclideanTransform', 30.0)
    """
    return from_matrix(np.asarray(sk_transform.params, dtype=float), transform_type)


def to_astropy_affine(transform: Any) -> Model:
    """
    Convert to `astropy.modeling.projections.AffineTransformation2D`.

    Examples
    --------
    >>> from astroalign_nd.transforms import TranslationTransform, to_astropy_affine
    >>> a = to_astropy_affine(TranslationTransform(translation_x=2.0, translation_y=3.0))
    >>> type(a).__name__, a(1.0, 1.0)
    ('AffineTransformation2D', (3.0, 4.0))
    """
    from astropy.modeling.projections import AffineTransformation2D

    m = as_matrix(transform)
    return AffineTransformation2D(matrix=m[:2, :2], translation=m[:2, 2])


def from_astropy_affine(model: Model,
                        transform_type: str | type | None = None) -> LinearTransform2D:
    """
    Convert an `~astropy.modeling.projections.AffineTransformation2D`.

    ``transform_type`` is as in `from_matrix` (default: the simplest class
    that represents the matrix).

    Examples
    --------
    >>> from astropy.modeling.projections import AffineTransformation2D
    >>> from astroalign_nd.transforms import from_astropy_affine
    >>> a = AffineTransformation2D(matrix=[[2.0, 0.0], [0.0, 2.0]], translation=[1.0, 0.0])
    >>> t = from_astropy_affine(a)
    >>> type(t).__name__, float(t.scale.value)
    ('SimilarityTransform', 2.0)
    """
    return from_matrix(as_matrix(model), transform_type)
