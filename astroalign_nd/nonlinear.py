# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Non-linear transforms between the pixel grids of two images.

Two astropy models, ``(x, y) -> (x', y')`` from source to target pixels
(0-based), like the linear models of `astroalign_nd.transforms`:

* `ProjectiveTransform`: a homography (8 degrees of freedom), for a
  tilted focal plane or a frame taken through a different projection.
  Its inverse is analytic.
* `PolynomialTransform`: a linear part plus polynomial distortion terms of
  degree 2 to 5 in the form of the FITS SIP convention (lens distortion,
  wide fields).  Its inverse is fitted, as SIP's AP/BP terms are, over the
  model's ``domain``, and its accuracy is reported as ``inverse_error``.

Both fit matched positions with ``from_points`` (optionally weighted), or
with `~astroalign_nd.transforms.fit_transform` for the parameter covariance
too, compose with any astropy model, and are saved to ASDF and FITS
headers by `astroalign_nd.io`.
"""

from __future__ import annotations

import numpy as np
from astropy.modeling import Model, Parameter
from numpy.typing import ArrayLike

__all__ = ["ProjectiveTransform", "PolynomialTransform"]

#: The polynomial degrees a `PolynomialTransform` accepts.
DEGREES = (2, 3, 4, 5)


def _check_pairs(cls_name, src, dst, weights, need):
    """Validated (src, dst, weights) for a fit needing ``need`` point pairs."""
    from .transforms import _as_points

    src = _as_points(src, "src")
    dst = _as_points(dst, "dst")
    if len(src) != len(dst):
        raise ValueError(
            f"src and dst must have the same length; got {len(src)} and {len(dst)}.")
    if len(src) < need:
        raise ValueError(f"{cls_name} needs at least {need} point pairs; got {len(src)}.")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (len(src),) or np.any(w < 0) or not np.all(np.isfinite(w)):
        raise ValueError(
            f"weights must be a finite, non-negative array of shape ({len(src)},), one "
            f"per point pair; got shape {w.shape}.")
    if np.count_nonzero(w) < need:
        raise ValueError(
            f"{cls_name} needs at least {need} point pairs with non-zero weight; got "
            f"{np.count_nonzero(w)}.")
    return src, dst, w


def _scalar_values(model):
    return [float(np.ravel(getattr(model, name).value)[0]) for name in model.param_names]


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
        return type(self).from_matrix(_invert_homography(self.matrix))

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
        from .transforms import _as_3x3

        m = _as_3x3(matrix)
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


def _check_homography(m, fitted=False):
    with np.errstate(over="ignore", invalid="ignore"):
        det = float(np.linalg.det(m))
    norm = float(np.linalg.norm(m))
    if not np.isfinite(det) or abs(det) <= 1e-12 * norm ** 3:
        why = ("the dst points are collinear or coincide" if fitted
               else "its matrix has no inverse")
        raise ValueError(f"the ProjectiveTransform is singular ({why}); it cannot register "
                         "an image.")


def _invert_homography(m):
    _check_homography(m)
    inv = np.linalg.inv(m)
    if abs(inv[2, 2]) <= 1e-14 * np.max(np.abs(inv)):
        raise ValueError(
            "the inverse of this homography sends pixel (0, 0) to infinity and cannot be "
            "written with h33 = 1.")
    return inv / inv[2, 2]


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


def _homography_jacobian(h, src):
    """d(x', y') / d(h11 ... h32), rows interleaved (x'_0, y'_0, x'_1, ...)."""
    x, y = src[:, 0], src[:, 1]
    den = h[2, 0] * x + h[2, 1] * y + 1.0
    xp = (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / den
    yp = (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / den
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
        den = m[2, 0] * src[:, 0] + m[2, 1] * src[:, 1] + 1.0
        xp = (m[0, 0] * src[:, 0] + m[0, 1] * src[:, 1] + m[0, 2]) / den
        yp = (m[1, 0] * src[:, 0] + m[1, 1] * src[:, 1] + m[1, 2]) / den
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


# -- polynomial (SIP) ------------------------------------------------------------------


def _exponents(degree):
    """The (p, q) of the distortion terms, 2 <= p + q <= degree, by degree then p descending."""
    return [(p, n - p) for n in range(2, degree + 1) for p in range(n, -1, -1)]


def _check_degree(degree):
    if isinstance(degree, (bool, np.bool_)) or not isinstance(degree, (int, np.integer)):
        raise TypeError(f"degree must be an integer from 2 to 5; got {degree!r}.")
    if int(degree) not in DEGREES:
        raise ValueError(
            f"degree must be from 2 to 5 (the polynomial distortion terms); got {degree}. "
            "For degree 1 use an AffineTransform.")
    return int(degree)


def _check_domain(domain):
    if domain is None:
        return None
    try:
        d = np.asarray(domain, dtype=float)
    except (TypeError, ValueError):
        d = None
    if d is None or d.shape != (4,) or not np.all(np.isfinite(d)) or not (
            d[1] > d[0] and d[3] > d[2]):
        raise ValueError(
            "domain must be (x_min, x_max, y_min, y_max), finite, with x_max > x_min and "
            f"y_max > y_min: the source pixels the inverse must cover; got {domain!r}.")
    return tuple(float(v) for v in d)


class _PerDegree:
    """A figure of the instance's degree, or of the default degree 3 on the class."""

    def __init__(self, function):
        self._function = function

    def __get__(self, obj, objtype=None):
        return self._function(3 if obj is None else obj.degree)


class _NoInverseDomain(ValueError, NotImplementedError):
    """No domain to fit the inverse over (a NotImplementedError for astropy's has_inverse)."""


class PolynomialTransform(Model):
    """
    A linear transform plus polynomial distortion, in the FITS SIP form.

    With ``u = x - crpix1`` and ``v = y - crpix2`` (0-based source pixels),
    ``f(u, v) = sum A_p_q u^p v^q`` and ``g(u, v) = sum B_p_q u^p v^q``
    over ``2 <= p + q <= degree``::

        x' = a11 (u + f) + a12 (v + g) + translation_x
        y' = a21 (u + f) + a22 (v + g) + translation_y

    As in a SIP WCS, the polynomial corrects the source pixels before the
    linear part (the ``CD`` matrix's role) maps them onto the target.
    ``(translation_x, translation_y)`` is where ``crpix`` lands, so with
    the defaults the model is the identity only for ``crpix = (0, 0)``.

    Parameters
    ----------
    degree : int, optional
        Degree of the distortion polynomial, 2 to 5 (default 3).  Not a
        parameter: it fixes which parameters exist.
    crpix : (float, float), optional
        The reference pixel ``(crpix1, crpix2)`` (0-based) about which the
        polynomial is written; default ``(0, 0)``.  Stored as the fixed
        parameters ``crpix1``, ``crpix2`` (which can also be given by name).
    domain : (x_min, x_max, y_min, y_max), optional
        The source pixels over which the inverse is fitted (the frame: ``(0,
        width - 1, 0, height - 1)``).  ``from_points`` sets the points' box.
    **params : float
        ``a11, a12, a21, a22`` (default the identity), ``translation_x``,
        ``translation_y`` (default 0), and the coefficients ``A_p_q``,
        ``B_p_q`` (default 0).

    Attributes
    ----------
    inverse_error : float
        Largest distance in source pixels between a point of ``domain`` and
        ``inverse(forward(point))`` (computed with the inverse).

    Notes
    -----
    The inverse (`inverse`) is another `PolynomialTransform` of degree
    5 (the largest) fitted by least squares on a grid over
    ``domain`` (SIP's AP/BP terms are fitted the same way): accurate where
    the forward model is, not an exact inverse.  It is cached until a
    parameter or the domain changes.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd import PolynomialTransform
    >>> t = PolynomialTransform(degree=2, crpix=(512.0, 512.0), translation_x=10.0,
    ...                         A_2_0=1e-5, B_0_2=-2e-5, domain=(0, 1023, 0, 1023))
    >>> t(612.0, 512.0)  # u = 100: x' = 100 + 1e-5 * 100**2 + 10
    (110.1, 0.0)
    >>> x, y = t.inverse(*t(100.0, 900.0))
    >>> bool(abs(x - 100.0) < 1e-3 and abs(y - 900.0) < 1e-3)
    True
    >>> bool(t.inverse_error < 1e-3)  # pixels, over the domain
    True
    >>> t.param_names[:8]
    ('crpix1', 'crpix2', 'a11', 'a12', 'a21', 'a22', 'translation_x', 'translation_y')
    >>> t.param_names[8:]
    ('A_2_0', 'A_1_1', 'A_0_2', 'B_2_0', 'B_1_1', 'B_0_2')
    """

    n_inputs = 2
    n_outputs = 2
    _separable = False
    fittable = False
    linear = False
    _param_names = ()

    _LINEAR_NAMES = ("crpix1", "crpix2", "a11", "a12", "a21", "a22", "translation_x",
                     "translation_y")
    _DEFAULTS = {"a11": 1.0, "a22": 1.0}

    def __init__(self, degree=3, crpix=None, *, domain=None, name=None, meta=None, **params):
        degree = _check_degree(degree)
        self._degree = degree
        self._exps = _exponents(degree)
        names = (*self._LINEAR_NAMES, *(f"A_{p}_{q}" for p, q in self._exps),
                 *(f"B_{p}_{q}" for p, q in self._exps))
        unknown = [k for k in params if k not in names and k not in ("fixed", "bounds")]
        if unknown:
            raise TypeError(
                f"PolynomialTransform(degree={degree}) has no parameter(s) {unknown}; its "
                f"parameters are {', '.join(names)}.")
        if crpix is not None:
            if "crpix1" in params or "crpix2" in params:
                raise TypeError("give either crpix=(x0, y0) or crpix1/crpix2, not both.")
            try:
                c = np.asarray(crpix, dtype=float)
            except (TypeError, ValueError):
                c = None
            if c is None or c.shape != (2,) or not np.all(np.isfinite(c)):
                raise ValueError(f"crpix must be two finite numbers (x0, y0); got {crpix!r}.")
            params["crpix1"], params["crpix2"] = float(c[0]), float(c[1])
        self._param_names = names
        for pname in names:
            # As astropy's own polynomial models do: per-degree parameters are registered
            # before Model.__init__ copies them onto the instance.
            self._parameters_[pname] = Parameter(
                pname, default=self._DEFAULTS.get(pname, 0.0),
                fixed=pname in ("crpix1", "crpix2"))
        super().__init__(name=name, meta=meta, **params)
        self.inputs = ("x", "y")
        self.outputs = ("x", "y")
        self._domain = _check_domain(domain)
        self._inverse_cache = None

    @property
    def param_names(self):
        """The parameter names of this instance (they depend on ``degree``)."""
        return self._param_names

    @property
    def degree(self):
        """Degree of the distortion polynomial (2 to 5)."""
        return self._degree

    @property
    def crpix(self):
        """The reference pixel ``(crpix1, crpix2)``, 0-based source pixels."""
        return (float(np.ravel(self.crpix1.value)[0]), float(np.ravel(self.crpix2.value)[0]))

    @property
    def domain(self):
        """Source-pixel box ``(x_min, x_max, y_min, y_max)`` the inverse is fitted over."""
        return self._domain

    @domain.setter
    def domain(self, value):
        self._domain = _check_domain(value)
        self._inverse_cache = None

    def __repr__(self):
        return self._format_repr(args=[self.degree], kwargs={"domain": self.domain})

    def evaluate(self, x, y, *params):
        crpix1, crpix2, a11, a12, a21, a22, tx, ty = params[:8]
        n = len(self._exps)
        coef_a, coef_b = params[8:8 + n], params[8 + n:8 + 2 * n]
        u = x - crpix1
        v = y - crpix2
        f, g = _distortion(u, v, self._exps, coef_a, coef_b)
        uf, vg = u + f, v + g
        return a11 * uf + a12 * vg + tx, a21 * uf + a22 * vg + ty

    def _values(self):
        vals = dict(zip(self.param_names, _scalar_values(self)))
        return vals

    @property
    def coefficients(self):
        """``(A, B)``: dicts ``{(p, q): value}`` of the distortion terms."""
        vals = self._values()
        return ({(p, q): vals[f"A_{p}_{q}"] for p, q in self._exps},
                {(p, q): vals[f"B_{p}_{q}"] for p, q in self._exps})

    @property
    def linear_matrix(self):
        """The 2x2 linear part ``[[a11, a12], [a21, a22]]`` (SIP's CD matrix role)."""
        v = self._values()
        return np.array([[v["a11"], v["a12"]], [v["a21"], v["a22"]]])

    @property
    def linear_part(self):
        """
        The `~astroalign_nd.transforms.AffineTransform` this model is without its
        distortion terms, in source pixels ``(x, y)``: ``x' = a (x - crpix) + t``.
        """
        from .transforms import AffineTransform

        v = self._values()
        lin = self.linear_matrix
        shift = np.array([v["translation_x"], v["translation_y"]]) - lin @ np.array(
            [v["crpix1"], v["crpix2"]])
        return AffineTransform(a11=lin[0, 0], a12=lin[0, 1], a21=lin[1, 0], a22=lin[1, 1],
                               translation_x=shift[0], translation_y=shift[1])

    # -- inverse -------------------------------------------------------------------------
    def _fit_inverse(self):
        key = (tuple(_scalar_values(self)), self._domain)
        if self._inverse_cache is not None and self._inverse_cache[0] == key:
            return self._inverse_cache[1:]
        if self._domain is None:
            raise _NoInverseDomain(
                "this PolynomialTransform has no domain, the source pixels over which its "
                "inverse is fitted; set it first: model.domain = (0, width - 1, 0, "
                "height - 1).")
        x0, x1, y0, y1 = self._domain
        gx, gy = np.meshgrid(np.linspace(x0, x1, 41), np.linspace(y0, y1, 41))
        src = np.column_stack([gx.ravel(), gy.ravel()])
        dst = np.column_stack(self(src[:, 0], src[:, 1]))
        if not np.all(np.isfinite(dst)):
            raise ValueError("the model maps part of its domain to NaN or infinity; it has no "
                             "inverse there.")
        v = self._values()
        inverse_degree = DEGREES[-1]
        inv, _, _ = type(self)._fit(dst, src, degree=inverse_degree,
                                    crpix=(v["translation_x"], v["translation_y"]))
        # Check on a different, denser grid (including the edges) than the fit used.
        cx, cy = np.meshgrid(np.linspace(x0, x1, 67), np.linspace(y0, y1, 67))
        back = np.column_stack(inv(*self(cx.ravel(), cy.ravel())))
        error = float(np.max(np.hypot(back[:, 0] - cx.ravel(), back[:, 1] - cy.ravel())))
        inv.meta["inverse_error"] = error
        self._inverse_cache = (key, inv, error)
        return inv, error

    @property
    def inverse(self):
        """
        The fitted inverse (target -> source), a `PolynomialTransform`.

        Fitted over the forward image of ``domain``; see `inverse_error`.
        """
        inv, _ = self._fit_inverse()
        return inv.copy()

    @property
    def inverse_error(self):
        """Largest round-trip error ``|inverse(forward(p)) - p|`` over ``domain``, pixels."""
        return self._fit_inverse()[1]

    # -- fitting -------------------------------------------------------------------------
    @staticmethod
    def min_points_for(degree):
        """
        Point pairs that determine a model of ``degree``: ``(degree + 1)(degree + 2) / 2``.

        Examples
        --------
        >>> from astroalign_nd import PolynomialTransform
        >>> [PolynomialTransform.min_points_for(d) for d in (2, 3, 4, 5)]
        [6, 10, 15, 21]
        """
        degree = _check_degree(degree)
        return (degree + 1) * (degree + 2) // 2

    #: Point pairs that determine the model: `min_points_for` the instance's degree
    #: (on the class, for the default degree 3).
    min_points = _PerDegree(lambda degree: (degree + 1) * (degree + 2) // 2)

    #: Degrees of freedom (free parameters), ``6 + 2 * (number of A_p_q terms)``: of the
    #: instance's degree (on the class, of the default degree 3).
    n_dof = _PerDegree(lambda degree: 6 + 2 * len(_exponents(degree)))

    @classmethod
    def from_points(cls, src: ArrayLike, dst: ArrayLike, degree: int = 3, *,
                    weights: ArrayLike | None = None, crpix=None,
                    domain=None) -> PolynomialTransform:
        """
        Weighted least-squares polynomial transform that maps ``src`` onto ``dst``.

        The model is linear in a re-parametrisation (a full polynomial of
        ``degree`` in each output), so the fit is one weighted linear least
        squares; the result is then written in the SIP form.

        Parameters
        ----------
        src, dst : (N, 2) array-like
            Corresponding (x, y) positions; N >= ``(degree + 1)(degree + 2) / 2``.
        degree : int, optional
            2 to 5 (default 3).
        weights : (N,) array-like, optional
            Non-negative weights (e.g. inverse variances); 0 leaves a pair out.
        crpix : (float, float), optional
            Reference pixel; default the centre of the src points' bounding box.
        domain : (x_min, x_max, y_min, y_max), optional
            Where the inverse is fitted; default the src points' bounding box.
            Pass the frame, ``(0, width - 1, 0, height - 1)``, to invert
            over all of it.

        Returns
        -------
        transform : `PolynomialTransform`

        Raises
        ------
        ValueError
            Bad degree, too few points, or points that do not determine the
            polynomial (e.g. all on a line or a few lines).

        Examples
        --------
        >>> import numpy as np
        >>> from astroalign_nd import PolynomialTransform
        >>> truth = PolynomialTransform(degree=3, crpix=(500.0, 500.0), a11=1.01,
        ...                             translation_x=3.0, A_3_0=2e-8, B_1_2=-1e-8)
        >>> src = np.random.default_rng(1).uniform(0, 1000, (60, 2))
        >>> dst = np.column_stack(truth(*src.T))
        >>> fit = PolynomialTransform.from_points(src, dst, degree=3, crpix=(500.0, 500.0))
        >>> grid = np.mgrid[0:1000:50, 0:1000:50].reshape(2, -1)
        >>> err = np.hypot(*(np.array(fit(*grid)) - np.array(truth(*grid))))
        >>> bool(err.max() < 1e-6)  # pixels, over the whole frame
        True
        """
        model, _, _ = cls._fit(src, dst, degree=degree, weights=weights, crpix=crpix,
                               domain=domain)
        return model

    @classmethod
    def _fit(cls, src, dst, *, degree=3, weights=None, crpix=None, domain=None, parity=None):
        """Fit; also return the Jacobian of the positions and the residuals."""
        from .transforms import _check_invertible

        degree = _check_degree(degree)
        need = cls.min_points_for(degree)
        src, dst, w = _check_pairs(f"A degree-{degree} PolynomialTransform", src, dst,
                                   weights, need)
        keep = w > 0
        box = (float(src[keep, 0].min()), float(src[keep, 0].max()),
               float(src[keep, 1].min()), float(src[keep, 1].max()))
        if crpix is None:
            crpix = (0.5 * (box[0] + box[1]), 0.5 * (box[2] + box[3]))
        if domain is None:
            domain = box if box[1] > box[0] and box[3] > box[2] else None
        c = np.asarray(crpix, dtype=float)
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise ValueError(f"crpix must be two finite numbers (x0, y0); got {crpix!r}.")
        u = src[keep] - c
        # Scale to ~1 so that the monomials up to degree 5 stay well conditioned.
        s = max(float(np.max(np.abs(u))), 1.0)
        full = [(p, n - p) for n in range(degree + 1) for p in range(n, -1, -1)]
        design = np.column_stack([(u[:, 0] / s) ** p * (u[:, 1] / s) ** q for p, q in full])
        sw = np.sqrt(w[keep])
        coef, _, _, sv = np.linalg.lstsq(design * sw[:, None], dst[keep] * sw[:, None],
                                         rcond=None)
        if sv[-1] <= 1e-10 * sv[0]:
            raise ValueError(
                f"the src points do not determine a degree-{degree} polynomial (they lie on "
                "a line or a few lines, or cluster); give points spread over the frame, or "
                "fit a lower degree or an AffineTransform.")
        coef = coef / np.array([s ** (p + q) for p, q in full])[:, None]
        t = coef[0]
        lin = np.array([[coef[1, 0], coef[2, 0]], [coef[1, 1], coef[2, 1]]])
        m = np.eye(3)
        m[:2, :2] = lin
        _check_invertible(m, f"degree-{degree} PolynomialTransform's linear part",
                          fitted=True)
        high = np.linalg.solve(lin, coef[3:].T)  # (2, n_terms): rows f, g
        exps = _exponents(degree)
        params = {"a11": lin[0, 0], "a12": lin[0, 1], "a21": lin[1, 0], "a22": lin[1, 1],
                  "translation_x": t[0], "translation_y": t[1]}
        for k, (p, q) in enumerate(exps):
            params[f"A_{p}_{q}"] = high[0, k]
            params[f"B_{p}_{q}"] = high[1, k]
        model = cls(degree=degree, crpix=(float(c[0]), float(c[1])), domain=domain, **params)
        jac = model._jacobian(src)
        resid = np.column_stack(model(src[:, 0], src[:, 1])) - dst
        return model, jac, resid

    def _jacobian(self, pts):
        """d(x', y') / d(free parameters), rows interleaved (x'_0, y'_0, x'_1, ...)."""
        v = self._values()
        u = pts[:, 0] - v["crpix1"]
        w = pts[:, 1] - v["crpix2"]
        coef_a, coef_b = self.coefficients
        f, g = _distortion(u, w, self._exps, [coef_a[e] for e in self._exps],
                           [coef_b[e] for e in self._exps])
        n, k = len(pts), len(self._exps)
        jac = np.zeros((2 * n, 6 + 2 * k))
        jac[0::2, 0], jac[0::2, 1] = u + f, w + g      # a11, a12
        jac[1::2, 2], jac[1::2, 3] = u + f, w + g      # a21, a22
        jac[0::2, 4] = 1.0                             # translation_x
        jac[1::2, 5] = 1.0                             # translation_y
        for i, (p, q) in enumerate(self._exps):
            mono = u ** p * w ** q
            jac[0::2, 6 + i] = v["a11"] * mono          # A_p_q
            jac[1::2, 6 + i] = v["a21"] * mono
            jac[0::2, 6 + k + i] = v["a12"] * mono      # B_p_q
            jac[1::2, 6 + k + i] = v["a22"] * mono
        return jac


def _distortion(u, v, exps, coef_a, coef_b):
    """The SIP terms ``f = sum A_pq u^p v^q`` and ``g = sum B_pq u^p v^q``."""
    # In place: resampling evaluates this on every output pixel (twice per
    # Newton step), and temporaries per term cost more than the arithmetic.
    degree = max(p + q for p, q in exps)
    upow = [None, u]
    vpow = [None, v]
    for _ in range(2, degree + 1):
        upow.append(upow[-1] * u)
        vpow.append(vpow[-1] * v)
    shape = np.broadcast(u, v).shape
    f, g = np.zeros(shape), np.zeros(shape)
    mono, term = np.empty(shape), np.empty(shape)
    for (p, q), a, b in zip(exps, coef_a, coef_b):
        if q == 0 or p == 0:
            m = upow[p] if q == 0 else vpow[q]
        else:
            m = np.multiply(upow[p], vpow[q], out=mono)
        f += np.multiply(m, a, out=term)
        g += np.multiply(m, b, out=term)
    return f, g
