# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The projective (homography) model."""

from __future__ import annotations

import numpy as np
from astropy.modeling import Model, Parameter
from numpy.typing import ArrayLike
from ._matrix import as_3x3, is_singular
from ._pairs import _check_pairs, _scalar_values
from .layers import ParameterLayer

__all__ = ['ProjectiveTransform', 'ProjectiveLayer']

# -- projective ------------------------------------------------------------------------


class ProjectiveTransform(Model):
    """
    A homography (projective transform) with ``h33 = 1``.

    ``x' = (h11 x + h12 y + h13) / (h31 x + h32 y + 1)``, and
    ``y' = (h21 x + h22 y + h23) / (h31 x + h32 y + 1)``, from source to
    target pixels.  With ``h31 = h32 = 0`` it is an affine transform.

    Parameters
    ----------
    h11, h12, h13, h21, h22, h23, h31, h32 : float
        The elements of the 3x3 matrix ``[[h11, h12, h13], [h21, h22, h23],
        [h31, h32, 1]]`` (default: the identity).

    Notes
    -----
    The model is undefined on the line ``h31 x + h32 y + 1 = 0`` (the
    "horizon"), which must lie outside the frames it maps.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd import ProjectiveTransform
    >>> t = ProjectiveTransform(h11=1.01, h13=5.0, h22=0.99, h31=1e-5, h32=-2e-5)
    >>> x, y = t(100.0, 200.0)
    >>> round(x, 6), round(y, 6)
    (106.318957, 198.595787)
    >>> [round(v, 9) for v in t.inverse(x, y)]
    [100.0, 200.0]
    >>> src = np.random.default_rng(0).uniform(0, 1000, (20, 2))
    >>> fit = ProjectiveTransform.from_points(src, np.column_stack(t(*src.T)))
    >>> bool(np.allclose(fit.matrix, t.matrix, rtol=0, atol=1e-9))
    True
    """

    n_inputs = 2
    n_outputs = 2
    _separable = False
    fittable = False
    linear = False

    h11 = Parameter(default=1.0)
    h12 = Parameter(default=0.0)
    h13 = Parameter(default=0.0)
    h21 = Parameter(default=0.0)
    h22 = Parameter(default=1.0)
    h23 = Parameter(default=0.0)
    h31 = Parameter(default=0.0)
    h32 = Parameter(default=0.0)

    #: Minimum number of point pairs that determine the transform.
    min_points = 4
    #: Degrees of freedom (number of free parameters).
    n_dof = 8

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.inputs = ("x", "y")
        self.outputs = ("x", "y")

    @staticmethod
    def evaluate(x, y, h11, h12, h13, h21, h22, h23, h31, h32):
        den = h31 * x + h32 * y + 1.0
        return (h11 * x + h12 * y + h13) / den, (h21 * x + h22 * y + h23) / den

    @property
    def matrix(self):
        """The 3x3 homogeneous matrix, with ``matrix[2, 2] == 1``."""
        h = _scalar_values(self)
        return np.array([h[0:3], h[3:6], [h[6], h[7], 1.0]])

    @property
    def inverse(self):
        """The analytic inverse, a `ProjectiveTransform` (target -> source)."""
        m = self.matrix
        _check_homography(m)
        inv = np.linalg.inv(m)
        if abs(inv[2, 2]) <= 1e-14 * np.max(np.abs(inv)):
            raise ValueError(
                "the inverse of this homography sends pixel (0, 0) to infinity and cannot be "
                "written with h33 = 1.")
        return type(self).from_matrix(inv / inv[2, 2])

    @classmethod
    def from_matrix(cls, matrix: ArrayLike) -> ProjectiveTransform:
        """
        Build the transform from a 3x3 (or 2x3 affine) matrix.

        The matrix is scaled so that its element ``[2, 2]`` is 1.

        Raises
        ------
        ValueError
            If the matrix is not finite, singular, or has ``[2, 2] == 0``
            (a homography that sends the origin to infinity).

        Examples
        --------
        >>> from astroalign_nd import ProjectiveTransform
        >>> t = ProjectiveTransform.from_matrix([[2.0, 0.0, 4.0], [0.0, 2.0, 0.0],
        ...                                      [0.0, 0.002, 2.0]])
        >>> t.matrix.tolist()
        [[1.0, 0.0, 2.0], [0.0, 1.0, 0.0], [0.0, 0.001, 1.0]]
        """
        m = as_3x3(matrix)
        scale = np.max(np.abs(m))
        if scale == 0 or abs(m[2, 2]) <= 1e-14 * scale:
            raise ValueError(
                "matrix[2, 2] is 0: the homography sends pixel (0, 0) to infinity, which a "
                "ProjectiveTransform (h33 = 1) cannot hold.")
        m = m / m[2, 2]
        _check_homography(m)
        return cls(h11=m[0, 0], h12=m[0, 1], h13=m[0, 2], h21=m[1, 0], h22=m[1, 1],
                   h23=m[1, 2], h31=m[2, 0], h32=m[2, 1])

    @classmethod
    def layer(cls, parity=1, degree=None):
        """The parameters and design of the homography: a ``ProjectiveLayer``."""
        return ProjectiveLayer()

    fit_layer = layer

    @classmethod
    def iterated_exactly(cls):
        """True: `fit_layer` is the model's own least-squares problem."""
        return True

    @classmethod
    def from_points(cls, src: ArrayLike, dst: ArrayLike, *,
                    weights: ArrayLike | None = None) -> ProjectiveTransform:
        """
        Weighted least-squares homography that maps ``src`` onto ``dst``.

        A normalised direct linear transform (DLT) gives the start, which a
        weighted least-squares fit of the positions in target pixels then
        polishes.

        Parameters
        ----------
        src, dst : (N, 2) array-like
            Corresponding (x, y) positions, N >= 4, no 3 of the first 4 on
            one line.
        weights : (N,) array-like, optional
            Non-negative weights (e.g. inverse variances); 0 leaves a pair
            out.  Equal by default.

        Returns
        -------
        transform : `ProjectiveTransform`

        Raises
        ------
        ValueError
            Too few points, points that do not determine a homography
            (collinear), or a singular fit.

        Examples
        --------
        >>> import numpy as np
        >>> from astroalign_nd import ProjectiveTransform
        >>> src = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [0.0, 100.0]])
        >>> dst = np.array([[0.0, 0.0], [110.0, 5.0], [105.0, 98.0], [-2.0, 95.0]])
        >>> t = ProjectiveTransform.from_points(src, dst)
        >>> bool(np.allclose(np.column_stack(t(*src.T)), dst))
        True
        """
        model, _, _ = cls._fit(src, dst, weights=weights)
        return model

    @classmethod
    def _fit(cls, src, dst, *, weights=None, parity=None):
        """Fit; also return the Jacobian of the positions and the residuals."""
        src, dst, w = _check_pairs(cls.__name__, src, dst, weights, cls.min_points)
        keep = w > 0
        h0 = _dlt(src[keep], dst[keep], w[keep])
        h = _polish_homography(h0, src[keep], dst[keep], w[keep])
        _check_homography(h, fitted=True)
        den = h[2, 0] * src[keep, 0] + h[2, 1] * src[keep, 1] + 1.0
        if np.any(den <= 0):
            raise ValueError(
                "the fitted homography puts its horizon (where it maps to infinity) among "
                "the src points; the matches do not describe one projective mapping. Check "
                "them, or fit an AffineTransform.")
        model = cls.from_matrix(h)
        jac = _homography_jacobian(h, src)
        resid = np.column_stack(model(src[:, 0], src[:, 1])) - dst
        return model, jac, resid


class ProjectiveLayer(ParameterLayer):
    """
    The homography's h11 .. h32 (h33 = 1): not linear in them (Gauss-Newton).

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms.projective import ProjectiveLayer
    >>> layer = ProjectiveLayer()
    >>> h = layer.from_affine(np.array([1.0, 2.0, 0.0, -1.0, 0.0, 2.0]))
    >>> layer.predict(h, np.array([[1.0, 1.0]]))
    array([[3., 1.]])
    """

    name, k, linear = "projective", 8, False

    @staticmethod
    def _matrix(params):
        h = params
        return np.array([h[0:3], h[3:6], [h[6], h[7], 1.0]])

    def predict(self, params, q):
        return np.column_stack(_homography_apply(self._matrix(params), q[:, 0], q[:, 1]))

    def design(self, q, params=None):
        return _homography_jacobian(self._matrix(params), q).reshape(len(q), 2, 8)

    @staticmethod
    def from_affine(c):
        """The homography equal to the affine map of ``PolynomialLayer(1)``'s parameters."""
        # x: 1, u, v ; y: 1, u, v
        return np.array([c[1], c[2], c[0], c[4], c[5], c[3], 0.0, 0.0])


def _check_homography(m, fitted=False):
    if is_singular(m):
        why = ("the dst points are collinear or coincide" if fitted
               else "its matrix has no inverse")
        raise ValueError(f"the ProjectiveTransform is singular ({why}); it cannot register "
                         "an image.")


def _check_values(values):
    """Refuse parameter values (read from a file) that make a singular homography."""
    h = [values[f"h{i}{j}"] for i in (1, 2, 3) for j in (1, 2, 3) if (i, j) != (3, 3)]
    try:
        _check_homography(np.array([h[0:3], h[3:6], [h[6], h[7], 1.0]]))
    except ValueError as exc:
        raise ValueError(f"it holds a singular homography ({exc})") from None


def _normaliser(pts):
    """Similarity that moves the points' centroid to 0 and their mean distance to sqrt(2)."""
    centre = pts.mean(axis=0)
    dist = np.mean(np.hypot(*(pts - centre).T))
    s = np.sqrt(2.0) / dist if dist > 0 else 1.0
    return np.array([[s, 0.0, -s * centre[0]], [0.0, s, -s * centre[1]], [0.0, 0.0, 1.0]])


def _dlt(src, dst, w):
    """Normalised, weighted direct linear transform."""
    ts, td = _normaliser(src), _normaliser(dst)
    s = src @ ts[:2, :2].T + ts[:2, 2]
    d = dst @ td[:2, :2].T + td[:2, 2]
    n = len(s)
    a = np.zeros((2 * n, 9))
    x, y, xp, yp = s[:, 0], s[:, 1], d[:, 0], d[:, 1]
    a[0::2, 0:3] = np.column_stack([x, y, np.ones(n)])
    a[0::2, 6:9] = -np.column_stack([xp * x, xp * y, xp])
    a[1::2, 3:6] = np.column_stack([x, y, np.ones(n)])
    a[1::2, 6:9] = -np.column_stack([yp * x, yp * y, yp])
    a *= np.sqrt(np.repeat(w / np.max(w), 2))[:, None]
    _, sv, vt = np.linalg.svd(a)
    if len(sv) < 9:
        sv = np.concatenate([sv, np.zeros(9 - len(sv))])
    # A second (near-)null vector: the points do not fix the homography.
    if sv[7] <= 1e-10 * sv[0]:
        raise ValueError(
            "the src and dst points do not determine a homography (three of every four "
            "are collinear, or they coincide); give points that span an area, or fit an "
            "AffineTransform.")
    hn = vt[-1].reshape(3, 3)
    h = np.linalg.inv(td) @ hn @ ts
    if abs(h[2, 2]) <= 1e-14 * np.max(np.abs(h)):
        raise ValueError("the fitted homography sends pixel (0, 0) to infinity; it cannot be "
                         "written with h33 = 1.")
    return h / h[2, 2]


def _homography_apply(h, x, y):
    """``(x', y')`` of the homography ``h`` (3x3, ``h[2, 2] = 1``) at ``(x, y)``."""
    den = h[2, 0] * x + h[2, 1] * y + 1.0
    return (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / den, (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / den


def _homography_jacobian(h, src):
    """d(x', y') / d(h11 ... h32), rows interleaved (x'_0, y'_0, x'_1, ...)."""
    x, y = src[:, 0], src[:, 1]
    den = h[2, 0] * x + h[2, 1] * y + 1.0
    xp, yp = _homography_apply(h, x, y)
    n = len(src)
    jac = np.zeros((2 * n, 8))
    jac[0::2, 0:3] = np.column_stack([x, y, np.ones(n)]) / den[:, None]
    jac[1::2, 3:6] = np.column_stack([x, y, np.ones(n)]) / den[:, None]
    jac[0::2, 6:8] = -np.column_stack([x * xp, y * xp]) / den[:, None]
    jac[1::2, 6:8] = -np.column_stack([x * yp, y * yp]) / den[:, None]
    return jac


def _polish_homography(h, src, dst, w, iterations=20):
    """Gauss-Newton on the target-pixel residuals (the DLT minimises an algebraic error)."""
    sw = np.sqrt(np.repeat(w, 2))
    theta = np.concatenate([h[0], h[1], h[2, :2]])

    def residual(t):
        m = np.array([t[0:3], t[3:6], [t[6], t[7], 1.0]])
        xp, yp = _homography_apply(m, src[:, 0], src[:, 1])
        return m, np.column_stack([xp, yp]).ravel() - dst.ravel()

    m, r = residual(theta)
    cost = float(np.sum((sw * r) ** 2))
    for _ in range(iterations):
        jac = _homography_jacobian(m, src) * sw[:, None]
        # Column scaling keeps the normal equations well conditioned (h31 ~ 1e-5, h13 ~ 1e3).
        scale = np.linalg.norm(jac, axis=0)
        scale[scale == 0] = 1.0
        step, *_ = np.linalg.lstsq(jac / scale, -sw * r, rcond=None)
        step = step / scale
        new_theta = theta + step
        new_m, new_r = residual(new_theta)
        new_cost = float(np.sum((sw * new_r) ** 2))
        if not np.isfinite(new_cost) or new_cost >= cost:
            break
        done = cost - new_cost <= 1e-15 * max(cost, 1e-300)
        theta, m, r, cost = new_theta, new_m, new_r, new_cost
        if done:
            break
    return m
