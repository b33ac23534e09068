# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Least-squares fits of the linear models to point pairs, with their covariance."""

from __future__ import annotations

import numpy as np
from astropy.modeling import Model
from numpy.typing import ArrayLike
from .polynomial import PolynomialTransform
from .linear import EuclideanTransform, SimilarityTransform
from ._matrix import _check_parity, _check_spread, apply_matrix, check_invertible
from .registry import transform_class

__all__ = ['fit_transform']


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


def fit_from_matrix(transform_type, matrix, src, dst, parity=1):
    """
    `fit_transform`'s (model, covariance, residuals) of a linear model whose
    unweighted least-squares matrix on these pairs is already known.

    For callers that solved the same problem another way (the whole-catalog
    cross-match, through its normal equations in normalised coordinates):
    the model, the checks and the covariance of `fit_transform`, without a
    second solve.  Only for 'translation', 'similarity' and 'affine' (the
    models linear in their parameters, whose design does not depend on the
    fit), with ``parity`` fixed.
    """
    cls = transform_class(transform_type)
    resid = apply_matrix(matrix, src) - dst
    _check_spread(cls, src, "src")
    check_invertible(matrix, cls.__name__, fitted=True)
    model = cls._from_matrix(matrix)
    design = cls._design(src, None, parity)
    return model, _covariance(model, design, resid, None), resid


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
