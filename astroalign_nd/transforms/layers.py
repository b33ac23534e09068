# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The parameter layer of a transform type: its parameters, its design
matrix (the Jacobian of its prediction with respect to them) and its
conversion to and from a matrix.

Every solver of the package that fits a model through its parameters
uses these, whatever it pairs or adjusts: the linear fits of the models
(``from_points``), the distortion stage's candidate models (model
selection), the whole-catalog pairing engine and the joint adjustment of
a sequence.  A model class gives its layer with its ``layer`` class
method; a new transform type gets one by subclassing a model class or by
defining ``layer``.

A layer acts on coordinates ``q`` as the caller gives them (pixels,
pixels centred on a frame, or coordinates normalised to a frame's half
diagonal): only the caller knows which.
"""

from __future__ import annotations

import numpy as np

__all__ = ['ParameterLayer', 'PolynomialLayer', 'layer_of', 'polynomial_terms', 'monomials']


class ParameterLayer:
    """
    The parameters of one transform type, as a solver sees them.

    Attributes
    ----------
    name : str
        What the fit is called in reports (a registry name, or
        ``'polynomial degree 3'``).
    k : int
        The number of parameters.
    linear : bool
        True if the prediction is linear in the parameters (the design does
        not depend on them: one least-squares solve is exact).
    affine_in_position : bool
        True if the design is affine in the coordinates, ``D0 + u Du + v
        Dv`` (and independent of the parameters): its normal equations
        follow from the moments of the coordinates.
    adds_position : bool
        True if the prediction is ``q + design @ params`` (a shift): the
        fixed part ``q`` is subtracted from the target before a fit.
    unit_scale : bool
        True if the type keeps the scale whatever its parameters (its
        linear part's determinant is 1 in magnitude).

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms import SimilarityTransform
    >>> layer = SimilarityTransform.layer()
    >>> layer.k, layer.linear
    (4, True)
    >>> theta = layer.from_matrix(SimilarityTransform(scale=2.0, rotation=90.0).matrix)
    >>> np.round(theta, 12)
    array([0., 2., 0., 0.])
    >>> np.round(layer.predict(theta, np.array([[1.0, 0.0]])), 12)
    array([[0., 2.]])
    """

    name = None
    k = 0
    linear = True
    affine_in_position = False
    adds_position = False
    unit_scale = False

    def design(self, q, params=None):
        """(N, 2, k): the derivatives of the predicted ``(x', y')`` of ``q``."""
        raise NotImplementedError

    def predict(self, params, q):
        """(N, 2): the predicted target positions of ``q`` (N, 2)."""
        return np.einsum("nik,k->ni", self.design(q), params)

    def to_parts(self, params):
        """(2x2 linear part, shift) of the parameters (a linear type)."""
        raise NotImplementedError(f"the {self.name} layer has no linear matrix")

    def from_parts(self, lin, shift):
        """The parameters of the nearest model of this type to ``lin``, ``shift``."""
        raise NotImplementedError(f"the {self.name} layer has no linear matrix")

    def to_matrix(self, params):
        """The 3x3 matrix of the parameters."""
        lin, shift = self.to_parts(params)
        m = np.eye(3)
        m[:2, :2], m[:2, 2] = lin, shift
        return m

    def to_matrices(self, params):
        """
        The (F, 3, 3) matrices of parameters ``params`` (F, k): `to_matrix`
        of each row (the built-in linear layers place them all at once, the
        same numbers).
        """
        return np.array([self.to_matrix(p) for p in params]).reshape(len(params), 3, 3)

    def from_matrix(self, m):
        """The parameters of the nearest model of this type to the 3x3 matrix ``m``."""
        m = np.asarray(m, float)
        return self.from_parts(m[:2, :2], m[:2, 2])

    def area(self, params):
        """
        ``(det, grad)`` of the linear part for parameters ``params`` (F,
        k): its determinant (F,) and ``det`` times the derivative of ``log
        g``, ``g = |det|**-0.5``, with respect to the first ``j``
        parameters (F, j); None if the determinant is 1 whatever the
        parameters.
        """
        return None


def layer_of(cls, parity=1, degree=None):
    """
    The parameter layer of a model class (its ``layer``), or None for a
    class that has none (a type registered without one).

    Examples
    --------
    >>> from astroalign_nd.transforms import AffineTransform
    >>> from astroalign_nd.transforms.layers import layer_of
    >>> layer_of(AffineTransform).k, layer_of(object) is None
    (6, True)
    """
    try:
        return cls.layer(parity=parity, degree=degree)
    except (AttributeError, NotImplementedError):
        return None


# -- polynomials: the terms of every polynomial design matrix of the package ---------


def polynomial_terms(degree, lowest=0):
    """
    The exponents ``(p, q)`` of the terms ``x**p y**q`` of total degree ``lowest`` to ``degree``.

    By total degree, then ``p`` descending: the order of the
    `~astroalign_nd.transforms.PolynomialTransform` coefficients
    (``lowest=2``: its distortion terms) and of every polynomial design
    matrix of the package.

    Examples
    --------
    >>> from astroalign_nd.transforms.layers import polynomial_terms
    >>> polynomial_terms(2)
    [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)]
    >>> polynomial_terms(3, lowest=3)
    [(3, 0), (2, 1), (1, 2), (0, 3)]
    """
    return [(p, n - p) for n in range(lowest, degree + 1) for p in range(n, -1, -1)]


def monomials(x, y, terms):
    """
    The design matrix of polynomial terms: column ``k`` is ``x**p * y**q`` for ``terms[k]``.

    Parameters
    ----------
    x, y : (N,) ndarray
        The coordinates (scaled by the caller to about 1, for conditioning).
    terms : list of (int, int)
        Exponents, e.g. `polynomial_terms`.

    Returns
    -------
    design : (N, len(terms)) ndarray

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms.layers import monomials, polynomial_terms
    >>> monomials(np.array([2.0]), np.array([3.0]), polynomial_terms(2))
    array([[1., 2., 3., 4., 6., 9.]])
    """
    return np.column_stack([x ** p * y ** q for p, q in terms])


class PolynomialLayer(ParameterLayer):
    """
    A full polynomial of total degree ``degree`` per axis (degree 1: an
    affine map), coefficients of `polynomial_terms` for x', then for y'.

    Examples
    --------
    >>> import numpy as np
    >>> from astroalign_nd.transforms.layers import PolynomialLayer
    >>> layer = PolynomialLayer(2)
    >>> layer.k, layer.design(np.array([[2.0, 3.0]]))[0, 0]
    (12, array([1., 2., 3., 4., 6., 9., 0., 0., 0., 0., 0., 0.]))
    """

    def __init__(self, degree):
        self.degree = degree
        self.terms = polynomial_terms(degree)
        self.k = 2 * len(self.terms)
        self.name = "affine" if degree == 1 else f"polynomial degree {degree}"
        self.affine_in_position = degree == 1

    def design(self, q, params=None):
        base = monomials(q[:, 0], q[:, 1], self.terms)
        t = len(self.terms)
        d = np.zeros((len(q), 2, self.k))
        d[:, 0, :t] = base
        d[:, 1, t:] = base
        return d
