# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The linear models: translation, Euclidean, similarity and affine.

Each is an `astropy.modeling.Model` with two inputs and two outputs; see
`astroalign_nd.transforms` for the conventions they share.
"""

from __future__ import annotations

import numpy as np
from astropy.modeling import Model, Parameter
from numpy.typing import ArrayLike
from ._matrix import (apply_matrix, as_3x3, check_invertible, is_singular, _as_degrees, _close,
                      _check_parity, _check_parity_value, _check_spread, _radians,
                      _rotate_shift, _rotation_matrix, _rotation_parameters,
                      _rotation_shift_parameters)
from ._pairs import _check_pairs
from .layers import ParameterLayer, PolynomialLayer
from .registry import transform_type_of

__all__ = ['LinearTransform2D', 'TranslationTransform', 'EuclideanTransform',
           'SimilarityTransform', 'AffineTransform']

#: NumPy's least-squares kernel (the gufunc `numpy.linalg.lstsq` calls), if it has one.
_LSTSQ = getattr(getattr(np.linalg, "_umath_linalg", None), "lstsq", None)
_EPS = float(np.finfo(float).eps)


def _lstsq(a, b):
    """
    ``np.linalg.lstsq(a, b, rcond=None)[0]`` of each (..., M, K) ``a`` and
    (..., M) ``b``.

    Float64 inputs go to its kernel as it calls it, all at once (the same
    numbers, without the checks and conversions that cost a third of a small
    fit); `numpy.linalg.lstsq` itself (which raises its own errors), one at a
    time, for other inputs, or if the kernel fails or is not the one this
    expects.
    """
    if (_LSTSQ is not None and a.ndim >= 2 and a.ndim == b.ndim + 1 and a.shape[-2] > 0
            and a.dtype == b.dtype == np.float64):
        try:
            with np.errstate(invalid="raise", over="ignore", divide="ignore", under="ignore"):
                return _LSTSQ(a, b[..., None], _EPS * max(a.shape[-2:]),  # lstsq's rcond
                              signature="ddd->ddid")[0][..., 0]
        except (FloatingPointError, TypeError, ValueError):
            pass  # (an SVD that did not converge, or a NumPy whose private gufunc differs)
    if a.ndim > 2:
        return np.array([_lstsq(ai, bi) for ai, bi in zip(a, b)])
    return np.linalg.lstsq(a, b, rcond=None)[0]


class LinearTransform2D(Model):
    """
    Base class of the package's 2-D linear (affine-family) transforms.

    Subclasses define their parameters, ``evaluate``, the class method
    ``_from_matrix`` and their parameter layer (``_layer``, a
    `~astroalign_nd.transforms.layers.ParameterLayer` class: parameters,
    design matrix, matrix conversions), whose least squares is their
    ``_linear_fit`` unless they override it (a rotation's angle is not
    linear); everything else (``matrix``, ``inverse``, ``from_points``,
    skimage-style attributes) is shared.

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
        values = {
            name: float(np.asarray(getattr(self, name).value).ravel()[0])
            for name in self.param_names
        }
        return type(self)._parts_of(values)

    @classmethod
    def _parts_of(cls, values):
        """
        The linear part and shift of the model with these parameter values
        (``{name: float}``): what `matrix` holds, without a model.
        """
        # Evaluate the model on the unit basis: works for every subclass.  The
        # translation parameters are zeroed for that and used directly as the
        # shift, so that the matrix is exact (differencing ``A e + t`` and ``t``
        # loses the low bits of ``A`` when the shift is much larger).
        values = dict(values)
        shift = None
        if "translation_x" in values and "translation_y" in values:
            shift = np.array([values["translation_x"], values["translation_y"]])
            values["translation_x"] = values["translation_y"] = 0.0
        x = np.array([0.0, 1.0, 0.0])
        y = np.array([0.0, 0.0, 1.0])
        xo, yo = cls.evaluate(x, y, *[values[name] for name in cls.param_names])
        if shift is None:
            shift = np.array([xo[0], yo[0]])
        lin = np.array([[xo[1] - xo[0], xo[2] - xo[0]], [yo[1] - yo[0], yo[2] - yo[0]]])
        return lin, shift

    @classmethod
    def _matrix_of(cls, values):
        """The `matrix` of the model with these parameter values, without a model."""
        lin, shift = cls._parts_of(values)
        m = np.eye(3)
        m[:2, :2] = lin
        m[:2, 2] = shift
        return m

    @classmethod
    def _from_matrix(cls, m):
        """The model of this type whose `matrix` is ``m`` (raises ValueError when
        none is); a type says its parameters in ``_values_from_matrix``."""
        own = next(k for k in cls.__mro__ if "_values_from_matrix" in vars(k))
        if own is LinearTransform2D:  # (that one builds the model with this method)
            raise NotImplementedError(f"{cls.__name__} defines neither _from_matrix nor "
                                      "_values_from_matrix")
        return cls(**cls._values_from_matrix(m))

    @classmethod
    def _values_from_matrix(cls, m):
        """
        The parameter values (``{name: float}``, every parameter) of
        ``_from_matrix(m)``, raising as it does.

        The built-in types say them without building a model (an astropy
        model costs milliseconds to build: the matching's fit loop works
        on values and matrices); another subclass builds one.
        """
        model = cls._from_matrix(m)
        return {name: float(np.asarray(getattr(model, name).value).ravel()[0])
                for name in cls.param_names}

    @classmethod
    def _model_values(cls, m):
        """
        `_values_from_matrix`, when the class that defines the type's
        ``_from_matrix`` also defines it; else those of the model that
        ``_from_matrix`` builds (a subclass may build its model otherwise).
        """
        own = next(k for k in cls.__mro__ if "_from_matrix" in vars(k))
        if "_values_from_matrix" in vars(own):
            return cls._values_from_matrix(m)
        return LinearTransform2D._values_from_matrix.__func__(cls, m)

    @classmethod
    def _with_defaults(cls, values):
        """``values`` with every parameter, its default for those not given, as floats."""
        return {name: float(values[name]) if name in values else
                float(getattr(cls, name).default) for name in cls.param_names}

    @property
    def inverse(self):
        """The analytic inverse, a model of the same class (target -> source)."""
        m = self.matrix
        check_invertible(m, type(self).__name__)
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
        m = as_3x3(matrix)
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

    #: The `~astroalign_nd.transforms.layers.ParameterLayer` class of the type's
    #: parameters (set by each subclass).
    _layer = None

    @classmethod
    def layer(cls, parity=1, degree=None):
        """
        The type's parameters, design matrix and matrix conversions: a
        `~astroalign_nd.transforms.layers.ParameterLayer` (for ``parity``,
        of the models that hold one).
        """
        if cls._layer is None:
            raise NotImplementedError(
                f"{cls.__name__} has no parameter layer: set its _layer to a "
                "ParameterLayer subclass (astroalign_nd.transforms.layers).")
        return cls._layer(parity)

    @classmethod
    def fit_layer(cls, parity=1, degree=None):
        """
        The layer the normalised solvers (model selection, the whole-catalog
        pairing) iterate for this type: its own when linear in its
        parameters; else (a rotation) the nearest one that is, the
        similarity's.  An affine type is iterated as the polynomial of
        degree 1, the distortion stage's own affine candidate.
        """
        if cls._layer is None:  # a type without a layer: the nearest of the built-in ones
            entry = transform_type_of(cls)
            return (SimilarityLayer(parity) if entry is not None and entry.conformal
                    else PolynomialLayer(1))
        return cls.layer(parity) if cls.layer(parity).linear else SimilarityLayer(parity)

    @classmethod
    def iterated_exactly(cls):
        """True if `fit_layer` solves the type's own least-squares problem."""
        return cls._layer is not None and cls.layer().linear

    @classmethod
    def _design(cls, src, weights, parity=1):
        """
        The design matrix `fit_matrix` returns for ``src``, weights and
        parity (rows x, y per point), as if fitting ``src`` onto itself: the
        layer's, for the models linear in their parameters (it does not
        depend on the target); else the fit's own.
        """
        if cls._layer is None or not cls._layer.linear:
            return cls._linear_fit(src, src, weights, parity)[1]
        return cls.layer(parity).design(src).reshape(2 * len(src), -1)

    @classmethod
    def _fit(cls, src, dst, *, weights=None, parity=None):
        """Fit and also return the linear parameter covariance and residuals."""
        matrix, design, resid = cls._fit_parts(src, dst, weights=weights, parity=parity)
        return cls._from_matrix(matrix), design, resid

    @classmethod
    def _fit_parts(cls, src, dst, *, weights=None, parity=None, checked=False, fit=None):
        """
        `_fit`'s checks and fit, without the model: (matrix, design, residuals).

        ``checked``: ``src``, ``dst`` passed these checks already (another
        fit of the same pairs), and ``weights`` is a finite float array, zero
        where those checks' weights were: only the fitted matrix is checked.
        ``fit``: ``(parity, matrix, design)`` of `fit_matrix` on these pairs
        and weights, when the caller has it (that parity's fit is not made
        again; the checks are).
        """
        if checked:
            w = weights
        else:
            src, dst, w = _check_pairs(cls.__name__, src, dst, weights, cls.min_points)
        if parity is not None:
            _check_parity(parity)
        parities = [parity] if parity is not None else cls._parities
        best = None
        for p in parities:
            if fit is not None and fit[0] == p:
                matrix, design = fit[1:]
            else:
                matrix, design, _ = cls._linear_fit(src, dst, w, p)
            resid = apply_matrix(matrix, src) - dst
            sse = float(np.sum(w * np.sum(resid**2, axis=1)))
            if best is None or sse < best[0] - 1e-12 * max(1.0, best[0]):
                best = (sse, matrix, design, resid)
        sse, matrix, design, resid = best
        if not checked:
            _check_spread(cls, src[w > 0], "src")
        check_invertible(matrix, cls.__name__, fitted=True)
        return matrix, design, resid

    _parities = (1,)

    @classmethod
    def _linear_fit(cls, src, dst, w, parity):
        """
        Weighted least squares of a type linear in its layer's parameters
        (the similarity's ``(a, b, tx, ty)``, the affine's six):
        (matrix, design, parameters).  Types not linear in them override it.
        """
        if "parity" in cls.param_names:
            _check_parity(parity)
        layer = cls.layer(parity)
        design = layer.design(src).reshape(2 * len(src), layer.k)
        sw = np.sqrt(np.repeat(w, design.shape[0] // len(w)))
        theta = _lstsq(design * sw[:, None], dst.ravel() * sw)
        return layer.to_matrix(theta), design, theta

    @classmethod
    def _leave_one_out(cls, src, dst, w, parity):
        """
        The matrices `fit_matrix` gives with each pair left out in turn,
        ``(N, 3, 3)``: for the jackknife.  The types linear in their layer's
        parameters solve the N problems in one stacked call of the
        least-squares kernel `numpy.linalg.lstsq` runs one at a time (the
        same numbers, without its per-call overhead).
        """
        n = len(src)
        rest = np.nonzero(~np.eye(n, dtype=bool))[1].reshape(n, n - 1)  # row i: all but i
        if cls._linear_fit.__func__ is LinearTransform2D._linear_fit.__func__:
            if "parity" in cls.param_names:
                _check_parity(parity)
            layer = cls.layer(parity)
            design = layer.design(src)[rest].reshape(n, 2 * (n - 1), layer.k)
            sw = np.sqrt(np.repeat(w[rest], 2, axis=1))
            return layer.to_matrices(_lstsq(design * sw[..., None],
                                            dst[rest].reshape(n, -1) * sw))
        return np.array([cls.fit_matrix(src[r], dst[r], w[r], parity)[0] for r in rest])


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
    def _values_from_matrix(cls, m):
        if not _close(m[:2, :2], np.eye(2), 1e-9):
            raise ValueError(
                "matrix has a rotation, scale or shear part; use SimilarityTransform or "
                "AffineTransform instead of TranslationTransform."
            )
        return cls._with_defaults(dict(translation_x=m[0, 2], translation_y=m[1, 2]))

    @classmethod
    def _linear_fit(cls, src, dst, w, parity):
        shift = np.sum(w[:, None] * (dst - src), axis=0) / np.sum(w)
        m = np.eye(3)
        m[:2, 2] = shift
        return m, cls._design(src, w, parity), shift


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
    def _values_from_matrix(cls, m):
        det = np.linalg.det(m[:2, :2])
        return cls._with_defaults(_rotation_parameters(
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
        theta = np.array([angle, *m[:2, 2]])
        design = cls.layer(parity).design(src, theta).reshape(2 * len(src), 3)
        return m, design, theta


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
    def _values_from_matrix(cls, m):
        lin = m[:2, :2]
        det = np.linalg.det(lin)
        if is_singular(lin):
            raise ValueError("matrix is singular; it cannot be a similarity transform.")
        scale = np.sqrt(abs(det))
        return cls._with_defaults(dict(scale=scale, **_rotation_parameters(
            m, det, scale, "matrix has a shear or anisotropic scale; use AffineTransform "
            "instead of SimilarityTransform.")))


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
    def _values_from_matrix(cls, m):
        return cls._with_defaults(dict(
            a11=m[0, 0], a12=m[0, 1], a21=m[1, 0], a22=m[1, 1],
            translation_x=m[0, 2], translation_y=m[1, 2],
        ))

    @classmethod
    def fit_layer(cls, parity=1, degree=None):
        return PolynomialLayer(1)


def _check_values(values):
    """
    Refuse parameter values (read from a file) that make no usable model: a
    parity other than +1 or -1, a scale that is not positive, a singular
    linear part ``a11 .. a22`` (the affine and polynomial models').
    """
    if "parity" in values and values["parity"] not in (1.0, -1.0):
        raise ValueError(f"its parity must be +1 (proper) or -1 (mirrored); got "
                         f"{values['parity']!r}")
    if "scale" in values and not values["scale"] > 0:
        raise ValueError(f"its scale must be > 0; got {values['scale']!r}")
    if "a11" in values:
        lin = np.array([[values["a11"], values["a12"]], [values["a21"], values["a22"]]])
        if is_singular(lin):
            with np.errstate(over="ignore", invalid="ignore"):
                det = float(np.linalg.det(lin))
            raise ValueError(f"it holds a singular or overflowing matrix (a11 a22 - a12 a21 = "
                             f"{det:g}); it cannot map an image")


# -- the parameter layers (`~astroalign_nd.transforms.layers`) -------------------------


def _flipped(q, parity):
    """``(x, parity * y)`` of the (N, 2) points ``q``."""
    return q[:, 0], float(parity) * q[:, 1]


def _unflip(lin, parity):
    """``lin @ diag(1, parity)``."""
    return lin if parity == 1 else lin @ np.diag([1.0, float(parity)])


def _stacked_matrices(lin, shift):
    """(F, 3, 3) homogeneous matrices of the linear parts ``lin`` (F, 2, 2) and
    shifts ``shift`` (F, 2): `ParameterLayer.to_matrix` of each."""
    m = np.zeros((len(lin), 3, 3))
    m[:, :2, :2], m[:, :2, 2], m[:, 2, 2] = lin, shift, 1.0
    return m


def _rotation_part(lin, parity):
    """``(a, b)`` of the scaled rotation ``[[a, -b], [b, a]]`` nearest to ``lin``
    (after its y axis is flipped, for ``parity`` -1)."""
    lin = _unflip(lin, parity)
    return (lin[0, 0] + lin[1, 1]) / 2.0, (lin[1, 0] - lin[0, 1]) / 2.0


class TranslationLayer(ParameterLayer):
    """``x' = x + tx, y' = y + ty``: parameters ``(tx, ty)``."""

    name, k, affine_in_position, adds_position, unit_scale = "translation", 2, True, True, True

    def __init__(self, parity=1):
        self.parity = parity

    def design(self, q, params=None):
        d = np.zeros((len(q), 2, 2))
        d[:, 0, 0] = d[:, 1, 1] = 1.0
        return d

    def predict(self, params, q):
        t = np.asarray(params).T
        return np.column_stack([q[:, 0] + t[0], q[:, 1] + t[1]])

    def to_parts(self, params):
        return np.eye(2), params[:2]

    def to_matrices(self, params):
        params = np.asarray(params)
        return _stacked_matrices(np.broadcast_to(np.eye(2), (len(params), 2, 2)), params[:, :2])

    def from_parts(self, lin, shift):
        return np.array(shift, float)


class EuclideanLayer(ParameterLayer):
    """A rotation (radians) and shift of ``(x, parity * y)``: ``(angle, tx, ty)``."""

    name, k, linear, unit_scale = "euclidean", 3, False, True

    def __init__(self, parity=1):
        self.parity = parity

    def design(self, q, params=None):
        """The derivatives at ``params``: (3,), or one row per point (N, 3)."""
        params = np.asarray(params, float)
        d = np.zeros((len(q), 2, 3))
        d[:, 0, 1] = d[:, 1, 2] = 1.0
        x, y = _flipped(q, self.parity)
        if params.ndim == 1:
            # Through the rotated points (a matrix product): the fit's own form.
            r = np.column_stack([x, y]) @ _rotation_matrix(params[0], 1.0).T
            d[:, 0, 0], d[:, 1, 0] = -r[:, 1], r[:, 0]
        else:
            c, s = np.cos(params[:, 0]), np.sin(params[:, 0])
            d[:, 0, 0], d[:, 1, 0] = -s * x - c * y, c * x - s * y
        return d

    def predict(self, params, q):
        t = np.asarray(params).T
        x, y = _flipped(q, self.parity)
        c, s = np.cos(t[0]), np.sin(t[0])
        return np.column_stack([c * x - s * y + t[1], s * x + c * y + t[2]])

    def to_parts(self, params):
        c, s = np.cos(params[0]), np.sin(params[0])
        return _unflip(np.array([[c, -s], [s, c]]), self.parity), params[1:]

    def from_parts(self, lin, shift):
        a, b = _rotation_part(lin, self.parity)
        return np.array([np.arctan2(b, a), *shift])


class SimilarityLayer(ParameterLayer):
    """``x' = a x - b p y + tx, y' = b x + a p y + ty``: ``(a, b, tx, ty)``, ``p`` the parity."""

    name, k, affine_in_position = "similarity", 4, True

    def __init__(self, parity=1):
        self.parity = parity

    def design(self, q, params=None):
        x, y = _flipped(q, self.parity)
        d = np.zeros((len(q), 2, 4))
        d[:, 0, 0], d[:, 0, 1], d[:, 0, 2] = x, -y, 1.0
        d[:, 1, 0], d[:, 1, 1], d[:, 1, 3] = y, x, 1.0
        return d

    def predict(self, params, q):
        t = np.asarray(params).T
        x, y = _flipped(q, self.parity)
        return np.column_stack([t[0] * x - t[1] * y + t[2], t[1] * x + t[0] * y + t[3]])

    def to_parts(self, params):
        a, b = params[0], params[1]
        return _unflip(np.array([[a, -b], [b, a]]), self.parity), params[2:]

    def to_matrices(self, params):
        params = np.asarray(params)
        a, b = params[:, 0], params[:, 1]
        lin = np.stack([np.stack([a, -b], axis=1), np.stack([b, a], axis=1)], axis=1)
        # (The flip of a parity -1 is the same product, slice by slice.)
        return _stacked_matrices(_unflip(lin, self.parity), params[:, 2:])

    def from_parts(self, lin, shift):
        return np.array([*_rotation_part(lin, self.parity), *shift])

    def area(self, params):
        t = params
        return t[:, 0] ** 2 + t[:, 1] ** 2, np.column_stack([-t[:, 0], -t[:, 1]])


class AffineLayer(ParameterLayer):
    """``x' = a11 x + a12 y + tx, y' = a21 x + a22 y + ty``: ``(a11, a12, a21, a22, tx, ty)``."""

    name, k, affine_in_position = "affine", 6, True

    def __init__(self, parity=1):
        self.parity = parity  # (not used: an affine model holds its own)

    def design(self, q, params=None):
        d = np.zeros((len(q), 2, 6))
        d[:, 0, 0:2] = q
        d[:, 0, 4] = 1.0
        d[:, 1, 2:4] = q
        d[:, 1, 5] = 1.0
        return d

    def predict(self, params, q):
        t = np.asarray(params).T
        x, y = q[:, 0], q[:, 1]
        return np.column_stack([t[0] * x + t[1] * y + t[4], t[2] * x + t[3] * y + t[5]])

    def to_parts(self, params):
        return np.asarray(params[:4]).reshape(2, 2), params[4:]

    def to_matrices(self, params):
        params = np.asarray(params)
        return _stacked_matrices(params[:, :4].reshape(-1, 2, 2), params[:, 4:])

    def from_parts(self, lin, shift):
        return np.array([*np.asarray(lin).ravel(), *shift])

    def area(self, params):
        t = params
        # d log|det| / dA = A^-T, so d log g / dA = -A^-T / 2 (times det).
        return (t[:, 0] * t[:, 3] - t[:, 1] * t[:, 2],
                0.5 * np.column_stack([-t[:, 3], t[:, 2], t[:, 1], -t[:, 0]]))


TranslationTransform._layer = TranslationLayer
EuclideanTransform._layer = EuclideanLayer
SimilarityTransform._layer = SimilarityLayer
AffineTransform._layer = AffineLayer
