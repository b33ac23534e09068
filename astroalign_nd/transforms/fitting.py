# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Least-squares fits of the linear models to point pairs, with their covariance."""

from __future__ import annotations

import numpy as np
from astropy.modeling import Model
from numpy.typing import ArrayLike
from .._kernels import median as _median
from .polynomial import PolynomialTransform
from .linear import EuclideanTransform, SimilarityTransform
from ._matrix import _check_parity, _check_spread, apply_matrix, check_invertible
from .registry import transform_class

__all__ = ['fit_transform', 'checked_weights']


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
    model, design, resid = _fit_design(cls, src, dst, weights, parity, degree, crpix, domain)
    return model, _covariance(model, design, resid, weights), resid


def _fit_design(cls, src, dst, weights, parity, degree=None, crpix=None, domain=None):
    """The model, its linear design (2 rows a pair, x then y) and its residuals."""
    if parity is not None:
        _check_parity(parity)
    if cls is PolynomialTransform:
        return cls._fit(src, dst, weights=weights, crpix=crpix, domain=domain,
                        degree=3 if degree is None else degree)
    given = [k for k, v in (("degree", degree), ("crpix", crpix), ("domain", domain))
             if v is not None]
    if given:
        raise ValueError(
            f"{', '.join(given)} are for transform_type='polynomial' only; got them with "
            f"{cls.__name__}.")
    return cls._fit(src, dst, weights=weights, parity=parity)


#: Mixing fractions tried between the claimed variances (0) and equal ones (1).
_MIX_GRID = np.concatenate([[0.0], np.logspace(-4.0, 0.0, 33)])

#: The floor taken is the largest whose -2 log-likelihood is within this of
#: the best one's (the upper end of its 68% interval).
_FLOOR_INTERVAL = 1.0


def _checked_fit(fit, n):
    """``checked_weights``' ``fit``, checked: (matrix, design) of ``n`` (a 1-tuple) pairs."""
    n = n[0] if len(n) else 0
    try:
        matrix, design = (np.asarray(a, dtype=float) for a in fit)
    except (TypeError, ValueError):
        matrix = design = None
    if (matrix is None or matrix.shape != (3, 3) or design.ndim != 2
            or design.shape[0] != 2 * n):
        raise ValueError(f"fit must be (matrix, design) from fit_matrix on these {n} pairs: a "
                         "3x3 matrix and a design of 2 rows per pair; or None to fit them "
                         "here.")
    return matrix, design


def checked_weights(src: ArrayLike, dst: ArrayLike, weights: ArrayLike,
                    transform_type: str | type = "similarity", *, parity: int | None = None,
                    degree: int | None = None, crpix: ArrayLike | None = None,
                    domain: ArrayLike | None = None, fit: tuple | None = None) -> np.ndarray:
    """
    Weights checked against the scatter of the residuals they give.

    Weights from estimated position errors (``1 / sigma**2``) are only as
    good as those errors: on faint, low-S/N frames, or when the two frames'
    centroids differ by more than their noise (another band, another PSF, a
    cosmic ray on a star), a few stars can claim errors far below their
    real scatter and pin the fit, which is then worse than an unweighted
    one.  Here the variance of pair ``i`` is modelled as ``s ((1 - f) c_i +
    f)``, with ``c_i`` the claimed variances (``1 / weights``, relative to
    their median): ``f = 0`` trusts them up to a scale, ``f = 1`` is equal
    weights, and between them ``f`` is an error floor.  ``s`` and ``f`` are
    fitted by restricted maximum likelihood to the residuals, which allows
    for the fit pulling a heavily weighted pair's residual towards zero:
    such a pair cannot hide its own error.  Claimed errors that the
    residuals bear out keep their weight; claims far below the scatter
    give way to a floor, up to equal weights.  Of the floors the residuals
    allow (a 68% likelihood interval), the largest is taken: a floor
    estimated from few pairs is noisy, and erring towards the claims lets
    a few stars pin the fit, while erring towards equal weights costs
    little.

    Parameters
    ----------
    src, dst : (N, 2) array-like
        Matched (x, y) positions in the source and target frames.
    weights : (N,) array-like
        Claimed non-negative weights (inverse variances); pairs with weight 0
        stay out of the fit.
    transform_type, parity, degree, crpix, domain
        The model, as for `fit_transform`.
    fit : tuple, optional
        For the linear types: ``(matrix, design)`` of
        `~astroalign_nd.transforms.LinearTransform2D.fit_matrix` on these
        pairs and weights (at ``parity``, or 1 if it is None), when the caller
        has made it (the matching's refinement): it is not made again (the
        pairs are still checked).

    Returns
    -------
    weights : (N,) ndarray
        The checked weights: inverse variances in squared target pixels per
        axis, scaled to the residuals (0 where the given weight was 0).
        The given weights when there are too few pairs to judge them (fewer
        than twice as many pairs as the model has parameters).

    Examples
    --------
    Twenty pairs with 0.2 px errors, five of which claim 0.01 px but have a
    0.2 px error too: the claim is not borne out, the weights become equal.

    >>> import numpy as np
    >>> from astroalign_nd.transforms import checked_weights
    >>> rng = np.random.default_rng(3)
    >>> src = rng.uniform(0, 500, (20, 2))
    >>> dst = src + [5.0, -3.0] + rng.normal(0, 0.2, (20, 2))
    >>> claimed = np.r_[np.full(5, 0.01), np.full(15, 0.2)] ** -2
    >>> w = checked_weights(src, dst, claimed)
    >>> bool(np.ptp(w) < 1e-9 * w.max())
    True

    With errors as claimed (a 20 times range), the weights are kept:

    >>> sigma = np.r_[np.full(5, 0.01), np.full(15, 0.2)]
    >>> dst = src + [5.0, -3.0] + rng.normal(0, 1, (20, 2)) * sigma[:, None]
    >>> w = checked_weights(src, dst, sigma ** -2)
    >>> bool(w[0] / w[-1] > 100)
    True
    """
    cls = transform_class(transform_type)
    w0 = np.asarray(weights, dtype=float)
    # fit_transform's own checks say what is wrong with bad input.
    if hasattr(cls, "_fit_parts") and degree is None and crpix is None and domain is None:
        # (The linear types: their design and residuals without building a model.)
        made = None if fit is None else (1 if parity is None else parity,
                                         *_checked_fit(fit, np.shape(src)[:1]))
        _, design, resid = cls._fit_parts(src, dst, weights=weights, parity=parity, fit=made)
    else:
        _, design, resid = _fit_design(cls, src, dst, weights, parity, degree, crpix, domain)
    used = w0 > 0
    n, k = int(used.sum()), design.shape[1]
    if design.shape[0] != 2 * len(w0) or n < 2 * k:
        return w0.copy()  # too few spare residuals to judge the weights by
    claimed = 1.0 / w0[used]
    claimed /= float(_median(claimed))  # (numpy.median's value, faster)
    f, scale = _floor_fraction(design.reshape(len(w0), 2, k)[used], resid[used], claimed)
    out = np.zeros(len(w0))
    out[used] = 1.0 / (scale * ((1.0 - f) * claimed + f))
    return out


def _floor_fraction(rows, resid, claimed):
    """
    The error floor ``f`` (a fraction of the median claimed variance) and the
    variance scale ``s``: the largest ``f`` within the 68% likelihood
    interval of the best one.

    ``rows`` are the pairs' (2, k) rows of the design and ``resid`` their
    residuals under one fit.  The model being linear in its parameters (or
    nearly so), the residuals under other weights follow from these without
    a refit, and the restricted likelihood (REML: that of the residuals,
    which the fitted parameters have already pulled towards zero, most of
    all at the heavily weighted pairs) is maximised over a grid of ``f``.
    """
    n, _, k = rows.shape
    d = rows.reshape(2 * n, k)
    d = d / np.maximum(np.linalg.norm(d, axis=0), 1e-300)  # conditioning only
    r0 = resid.reshape(2 * n)
    dof = 2 * n - k
    # Every floor of the grid at once (the stacked products and solves are
    # those of one floor at a time, slice by slice: the same numbers).
    v = (1.0 - _MIX_GRID[:, None]) * claimed + _MIX_GRID[:, None]
    w = np.repeat(1.0 / v, 2, axis=1)
    a = d.T @ (d * w[:, :, None])
    sign, logdet = np.linalg.slogdet(a)
    ok = np.flatnonzero(sign > 0)
    rhs = np.matmul(d.T, (w[ok] * r0)[..., None])
    r = r0 - np.matmul(d, np.linalg.solve(a[ok], rhs))[..., 0]
    s = np.sum(w[ok] * r * r, axis=1) / dof
    ok, s = ok[s > 0], s[s > 0]
    nll = np.full(len(_MIX_GRID), np.inf)
    scales = np.ones(len(_MIX_GRID))
    # -2 log L_R up to a constant: dof log s + log|V| + log|D' V^-1 D|.
    nll[ok] = dof * np.log(s) + 2.0 * np.sum(np.log(v[ok]), axis=1) + logdet[ok]
    scales[ok] = s
    if not np.isfinite(nll[-1]):
        return 1.0, 1.0
    # The most even weights within 1 sigma of the best (the upper end of
    # the floor's likelihood interval): a floor estimated from few pairs is
    # noisy, and erring towards the claims lets a few stars pin the fit,
    # while erring towards equal weights costs little.
    best = int(np.flatnonzero(nll <= np.min(nll) + _FLOOR_INTERVAL)[-1])
    return float(_MIX_GRID[best]), float(scales[best])


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


def _covariance(model, design, resid, weights):
    """Parameter covariance via the linear design and a numerical Jacobian."""
    fixed = model.fixed  # (a new dict at each access)
    free = [n for n in model.param_names if not fixed[n]]
    # (Only a similarity's parameters need its matrix; a polynomial has none.)
    matrix = model.matrix if isinstance(model, SimilarityTransform) else None
    return parameter_covariance(type(model), matrix, free, design, resid, weights)


def parameter_covariance(cls, matrix, free, design, resid, weights):
    """
    The covariance of the free parameters of a linear fit, without a model.

    Parameters
    ----------
    cls : type
        The model class fitted (a `~astroalign_nd.transforms.linear.LinearTransform2D`
        subclass).
    matrix : (3, 3) ndarray or None
        The fitted matrix; used for a similarity only (its scale and rotation
        are not linear parameters).
    free : list of str
        Names of the model's free parameters, in order.
    design : (2N, P) ndarray
        The linear design matrix of the fit.
    resid : (N, 2) ndarray
        The fit's residuals.
    weights : (N,) ndarray or None
        Per-point weights of the fit.

    Returns
    -------
    cov : (len(free), len(free)) ndarray
        NaN where the fit leaves no degree of freedom or is singular.
    """
    n_obs, n_lin = design.shape
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
    if issubclass(cls, SimilarityTransform):
        m = matrix
        a, b = m[0, 0], m[1, 0]
        r2 = a * a + b * b
        s = np.sqrt(r2)
        jac = np.zeros((4, 4))
        jac[0, :2] = [a / s, b / s]
        jac[1, :2] = [-b / r2 * deg, a / r2 * deg]
        jac[2, 2] = jac[3, 3] = 1.0
        return jac @ cov_lin @ jac.T
    if issubclass(cls, EuclideanTransform):
        jac = np.diag([deg, 1.0, 1.0])
        return jac @ cov_lin @ jac.T
    return cov_lin
