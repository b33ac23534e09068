# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The polynomial distortion model."""

from __future__ import annotations


import numpy as np
from astropy.modeling import Model, Parameter
from numpy.typing import ArrayLike
from ._matrix import check_invertible
from .linear import AffineTransform
from ._pairs import _check_pairs, _scalar_values
from .registry import TRANSFORM_REGISTRY, HeaderHooks, _check_degree
from .layers import PolynomialLayer, monomials, polynomial_terms

__all__ = ['PolynomialTransform']

#: The polynomial degrees a `PolynomialTransform` accepts (its registry entry's).
DEGREES = TRANSFORM_REGISTRY["polynomial"].degrees

# -- polynomial (SIP) ------------------------------------------------------------------


def _exponents(degree):
    """The (p, q) of the distortion terms, 2 <= p + q <= degree."""
    return polynomial_terms(degree, lowest=2)


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
    @classmethod
    def layer(cls, parity=1, degree=None):
        """The parameters and design of the degree (default 3): a ``PolynomialLayer``."""
        return PolynomialLayer(3 if degree is None else int(degree))

    fit_layer = layer

    @classmethod
    def iterated_exactly(cls):
        """True: `fit_layer` is the model's own least-squares problem."""
        return True

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
        full = polynomial_terms(degree)
        design = monomials(u[:, 0] / s, u[:, 1] / s, full)
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
        check_invertible(m, f"degree-{degree} PolynomialTransform's linear part", fitted=True)
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


# -- the FITS header keywords (`astroalign_nd.io.header`) ---------------------------------

_DOMAIN_SUFFIXES = ("DXMIN", "DXMAX", "DYMIN", "DYMAX")
_COEFF_SUFFIXES = tuple(f"{ab}{p}{q}" for ab in "AB" for p, q in _exponents(DEGREES[-1]))


def _header_matrix(model):
    """The linear part about ``crpix``, with the shift of ``crpix``: the ``M`` keywords."""
    matrix = np.eye(3)
    matrix[:2, :2] = model.linear_matrix
    matrix[:2, 2] = [model.translation_x.value, model.translation_y.value]
    return matrix


def _header_cards(model):
    """The degree, reference pixel, domain and coefficients, and the readable shift."""
    cards = [("DEG", model.degree, "degree of the polynomial distortion", False)]
    for i, value in enumerate(model.crpix, start=1):
        cards.append((f"CRP{i}", value, f"[px] reference pixel {'xy'[i - 1]}, 0-based", True))
    for suffix, value in zip(_DOMAIN_SUFFIXES, model.domain or ()):
        cards.append((suffix, value, "[px] domain of the fitted inverse", False))
    coef_a, coef_b = model.coefficients
    for ab, coefs in (("A", coef_a), ("B", coef_b)):
        for (p, q), value in coefs.items():
            cards.append((f"{ab}{p}{q}", value, f"distortion coefficient {ab}_{p}_{q}", True))
    m = _header_matrix(model)
    return cards + [(f"T{axis}", float(m[i, 2]), f"[px] translation along {axis.lower()} of "
                     "the reference pixel", False) for i, axis in enumerate("XY")]


def _from_header(reader):
    """The `PolynomialTransform` of a header's keywords (``reader``: see `HeaderHooks`)."""
    try:
        degree = _check_degree(reader.get("DEG"))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"header keyword {reader.key('DEG')} must be the polynomial's degree "
                         f"({exc})") from None
    m = reader.matrix()
    params = {"a11": m[0, 0], "a12": m[0, 1], "a21": m[1, 0], "a22": m[1, 1],
              "translation_x": m[0, 2], "translation_y": m[1, 2]}
    crpix = [reader.exact(f"CRP{i}", "the reference pixel") for i in (1, 2)]
    for ab in "AB":
        for p, q in _exponents(degree):
            params[f"{ab}_{p}_{q}"] = reader.exact(f"{ab}{p}{q}",
                                                   f"the degree-{degree} polynomial")
    extra = [reader.key(c) for c in _COEFF_SUFFIXES
             if reader.has(c) and int(c[1]) + int(c[2]) > degree]
    if extra:
        raise ValueError(f"header has {extra}, terms beyond {reader.key('DEG')} = {degree}; was "
                         f"{reader.key('DEG')} edited?")
    present = [reader.has(k) for k in _DOMAIN_SUFFIXES]
    domain = None
    if any(present):
        if not all(present):
            raise ValueError(f"header has only some of {[reader.key(k) for k in _DOMAIN_SUFFIXES]}"
                             "; give all four (the inverse's domain) or none.")
        domain = [reader.get(k) for k in _DOMAIN_SUFFIXES]
    try:
        model = PolynomialTransform(degree=int(degree), crpix=crpix, domain=domain, **params)
        check_invertible(_header_matrix(model), "PolynomialTransform's linear part")
    except (ValueError, TypeError) as exc:
        raise ValueError(f"the header's polynomial keywords are not a valid "
                         f"PolynomialTransform ({exc}).") from None
    return model


#: How `~astroalign_nd.io.transform_to_header` stores a `PolynomialTransform`.
HEADER_HOOKS = HeaderHooks(
    matrix=_header_matrix, cards=_header_cards, read=_from_header,
    suffixes=("DEG", "CRP1", "CRP1S", "CRP2", "CRP2S", *_DOMAIN_SUFFIXES, *_COEFF_SUFFIXES,
              *(c + "S" for c in _COEFF_SUFFIXES), "TX", "TY"))
