# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
SIP distortion (the FITS ``-SIP`` convention): the one home of the package's SIP code.

* `distorted_wcs`: the TAN-SIP WCS of a polynomial transform's source frame
  from the target frame's WCS (the forward terms re-expanded exactly, the
  inverse terms fitted over the frame).
* `sip_through_linear`: a WCS's SIP terms carried through a linear map of
  its pixels (a resampled frame's WCS, a rescaled drizzle grid).
"""

from __future__ import annotations

import numpy as np
from astropy.wcs import Sip

from ..transforms.layers import monomials, polynomial_terms
from ..transforms.polynomial import PolynomialTransform

__all__ = ["distorted_wcs", "sip_through_linear"]


def sip_through_linear(sip, lin, crpix):
    """
    SIP terms rewritten for pixels ``v = lin u``: ``lin f(lin^-1 v)``, forward and inverse.

    A polynomial of a linear map is a polynomial of the same degree, so the
    re-expansion is exact.

    Parameters
    ----------
    sip : `~astropy.wcs.Sip`
    lin : (2, 2) ndarray
        The linear map of pixel offsets (old pixels to new).
    crpix : (2,) array
        The new reference pixel (FITS, 1-based).

    Returns
    -------
    sip : `~astropy.wcs.Sip`
    """
    inv = np.linalg.inv(lin)
    a, b = _terms_through(sip.a, sip.b, lin, inv)
    ap, bp = (_terms_through(sip.ap, sip.bp, lin, inv) if sip.ap is not None
              else (None, None))
    return Sip(a, b, ap, bp, crpix)


def _poly_product(p, q):
    """Product of two polynomials in (x, y) given as coefficient arrays ``c[i, j]`` of x^i y^j."""
    out = np.zeros((p.shape[0] + q.shape[0] - 1, p.shape[1] + q.shape[1] - 1))
    for i, j in zip(*np.nonzero(p)):
        out[i:i + q.shape[0], j:j + q.shape[1]] += p[i, j] * q
    return out


def _terms_through(a, b, lin, inv):
    """SIP terms ``(a, b)`` of ``u`` rewritten as those of ``v = lin u``: ``lin f(inv v)``."""
    order = a.shape[0] - 1
    # u1 and u2 as polynomials of v: the rows of ``inv``.
    u1 = np.array([[0.0, inv[0, 1]], [inv[0, 0], 0.0]])
    u2 = np.array([[0.0, inv[1, 1]], [inv[1, 0], 0.0]])
    pow1, pow2 = [np.ones((1, 1))], [np.ones((1, 1))]
    for _ in range(order):
        pow1.append(_poly_product(pow1[-1], u1))
        pow2.append(_poly_product(pow2[-1], u2))
    f1 = np.zeros((order + 1, order + 1))
    f2 = np.zeros((order + 1, order + 1))
    for i, j in zip(*np.nonzero((a != 0) | (b != 0))):
        term = _poly_product(pow1[i], pow2[j])[:order + 1, :order + 1]
        f1[:term.shape[0], :term.shape[1]] += a[i, j] * term
        f2[:term.shape[0], :term.shape[1]] += b[i, j] * term
    return lin[0, 0] * f1 + lin[0, 1] * f2, lin[1, 0] * f1 + lin[1, 1] * f2


def _solve(model, target, start, iterations=30):
    """The source pixel that ``model`` maps onto ``target`` (Newton, numerical Jacobian)."""
    p = np.array(start, dtype=float)
    h = 1e-2
    for _ in range(iterations):
        f = np.array(model(p[0], p[1]), dtype=float) - target
        jac = np.column_stack([
            (np.array(model(p[0] + h, p[1])) - np.array(model(p[0] - h, p[1]))) / (2 * h),
            (np.array(model(p[0], p[1] + h)) - np.array(model(p[0], p[1] - h))) / (2 * h)])
        step = np.linalg.solve(jac, -f)
        p = p + step
        if np.hypot(*step) < 1e-12 * max(1.0, np.hypot(*p)):
            break
    return p


def _poly_fit(d, values, degree):
    """Coefficients ``{(p, q): (cx, cy)}`` of a full polynomial of ``degree`` in ``d``."""
    s = max(float(np.max(np.abs(d))), 1.0)
    exps = polynomial_terms(degree)
    design = monomials(d[:, 0] / s, d[:, 1] / s, exps)
    coef, *_ = np.linalg.lstsq(design, values, rcond=None)
    return {e: coef[k] / s ** sum(e) for k, e in enumerate(exps)}


def distorted_wcs(model: PolynomialTransform, target_wcs, shape, *,
                  inverse_degree: int | None = None):
    """
    The source frame's celestial WCS: the target's, through a polynomial model, as TAN-SIP.

    A `~astroalign_nd.PolynomialTransform` maps source pixels onto target
    pixels; the target frame's WCS maps those onto the sky.  Their
    composition is the source frame's WCS, which this function writes in
    the FITS SIP convention (the ``-SIP`` suffix, ``A_p_q``/``B_p_q`` forward
    and ``AP_p_q``/``BP_p_q`` inverse terms) that `astropy.wcs`, ds9 and
    most astrometric software read.

    The reference pixel ``CRPIX`` of the result is the source pixel that
    the model maps onto the target's ``CRPIX``, and ``CD`` is the target's
    times the model's local linear part there; the forward terms are the
    model's polynomial re-expanded about that pixel, which is exact (a
    polynomial composed with a linear map is a polynomial of the same
    degree).  The inverse terms are fitted over the frame.

    Parameters
    ----------
    model : `~astroalign_nd.PolynomialTransform`
        Source-to-target transform.
    target_wcs : `~astropy.wcs.WCS`
        The target frame's WCS: 2-D, celestial, without distortion terms of
        its own (SIP, lookup tables).
    shape : (int, int)
        The source frame's shape ``(ny, nx)``: where the inverse terms are
        fitted, and the result's ``pixel_shape``.
    inverse_degree : int, optional
        Degree of the inverse (AP/BP) terms, up to 9; default ``2 *
        model.degree + 1`` (at most 9), which inverts a few tens of pixels
        of distortion to a few thousandths of a pixel.

    Returns
    -------
    wcs : `~astropy.wcs.WCS`
        The source frame's WCS.  ``wcs.pixel_to_world(x, y)`` equals
        ``target_wcs.pixel_to_world(*model(x, y))``.

    Raises
    ------
    TypeError
        If ``model`` is not a `~astroalign_nd.PolynomialTransform` or
        ``target_wcs`` not an astropy WCS.
    ValueError
        If the target WCS is not a 2-D celestial WCS, already has
        distortion terms, or ``shape`` is not two positive integers.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.wcs import WCS
    >>> from astroalign_nd import PolynomialTransform
    >>> from astroalign_nd.io.sip import distorted_wcs
    >>> target = WCS(naxis=2)
    >>> target.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    >>> target.wcs.crval = [150.0, 2.0]
    >>> target.wcs.crpix = [512.5, 512.5]
    >>> target.wcs.cdelt = [-2e-4, 2e-4]
    >>> model = PolynomialTransform(degree=3, crpix=(511.5, 511.5), translation_x=515.0,
    ...                             translation_y=505.0, A_3_0=-2e-9, B_0_3=-2e-9)
    >>> source = distorted_wcs(model, target, (1024, 1024))
    >>> source.wcs.ctype[0], source.sip.a_order
    ('RA---TAN-SIP', 3)
    >>> x, y = 10.0, 1000.0  # a corner, where the distortion is ~ 0.2 px
    >>> sky = source.pixel_to_world(x, y)
    >>> xt, yt = target.world_to_pixel(sky)
    >>> bool(np.hypot(xt - model(x, y)[0], yt - model(x, y)[1]) < 1e-6)
    True
    """
    from astropy.wcs import WCS

    nx, ny, inverse_degree = _check_sip_inputs(model, target_wcs, shape, inverse_degree)
    degree = model.degree
    # The source pixel that lands on the target's reference pixel (0-based).
    target_ref = np.array(target_wcs.wcs.crpix, dtype=float) - 1.0
    lin_part = model.linear_part.matrix
    ref = _solve(model, target_ref, np.linalg.solve(lin_part[:2, :2],
                                                    target_ref - lin_part[:2, 2]))
    # Re-expand model(ref + d) - target_ref = L (d + F(d)) about ref: exact on a grid of
    # (degree + 1)^2 points or more; the inverse fit needs more than its terms.
    n = max(4 * degree + 1, 3 * inverse_degree + 1)
    gx, gy = np.meshgrid(np.linspace(0, nx - 1, n), np.linspace(0, ny - 1, n))
    d = np.column_stack([gx.ravel(), gy.ravel()]) - ref
    coef = _poly_fit(d, np.column_stack(model(gx.ravel(), gy.ravel())) - target_ref, degree)
    lin = np.column_stack([coef[(1, 0)], coef[(0, 1)]])  # rows x', y'; columns d_x, d_y
    lin_inv = np.linalg.inv(lin)
    forward = {e: lin_inv @ c for e, c in coef.items() if sum(e) >= 2}
    # Inverse terms: from U = d + F(d) back to d, fitted over the frame.
    big_u = d + sum(np.outer(d[:, 0] ** p * d[:, 1] ** q, c) for (p, q), c in forward.items())
    inverse = _poly_fit(big_u, d - big_u, inverse_degree)

    hdr = target_wcs.to_header(relax=True)
    for key in list(hdr.keys()):
        if key.startswith(("PC", "CD", "CDELT", "CROTA")):
            hdr.remove(key, ignore_missing=True, remove_all=True)
    cd = target_wcs.pixel_scale_matrix @ lin
    for i in range(2):
        hdr[f"CRPIX{i + 1}"] = float(ref[i] + 1.0)
        hdr[f"CTYPE{i + 1}"] = target_wcs.wcs.ctype[i] + "-SIP"
        for j in range(2):
            hdr[f"CD{i + 1}_{j + 1}"] = float(cd[i, j])
    for x_name, y_name, order, terms in (("A", "B", degree, forward),
                                         ("AP", "BP", inverse_degree, inverse)):
        hdr[f"{x_name}_ORDER"] = hdr[f"{y_name}_ORDER"] = order
        for (p, q), c in terms.items():
            hdr[f"{x_name}_{p}_{q}"] = float(c[0])
            hdr[f"{y_name}_{p}_{q}"] = float(c[1])
    out = WCS(hdr)
    out.pixel_shape = (nx, ny)
    return out


def _check_sip_inputs(model, target_wcs, shape, inverse_degree):
    """``(nx, ny, inverse_degree)`` of `distorted_wcs`, or a clear error."""
    from astropy.wcs import WCS

    if not isinstance(model, PolynomialTransform):
        raise TypeError(
            f"model must be an astroalign_nd PolynomialTransform; got {type(model).__name__}. "
            "For a linear transform, astropy's WCS of the source frame is "
            "reproject-style: apply the transform's matrix to the target WCS's CRPIX and CD.")
    if not isinstance(target_wcs, WCS):
        raise TypeError(f"target_wcs must be an astropy.wcs.WCS; got "
                        f"{type(target_wcs).__name__}.")
    if target_wcs.naxis != 2 or not target_wcs.has_celestial:
        raise ValueError("target_wcs must be a 2-D celestial WCS (e.g. RA---TAN, DEC--TAN); "
                         f"got {target_wcs.naxis} axes {list(target_wcs.wcs.ctype)}.")
    tables = (target_wcs.cpdis1, target_wcs.cpdis2, target_wcs.det2im1, target_wcs.det2im2)
    if target_wcs.sip is not None or any(t is not None for t in tables) or any(
            c.endswith("-SIP") for c in target_wcs.wcs.ctype):
        raise ValueError("target_wcs already has distortion terms (SIP or lookup tables); "
                         "their composition with the model is not a SIP polynomial. Fit a "
                         "WCS to matched stars instead (astropy.wcs.utils."
                         "fit_wcs_from_points).")
    try:
        ny, nx = (int(v) for v in shape)
    except (TypeError, ValueError):
        ny = nx = 0
    if not (ny > 0 and nx > 0):
        raise ValueError(f"shape must be the source frame's (ny, nx), two positive integers; "
                         f"got {shape!r}.")
    if inverse_degree is None:
        inverse_degree = min(2 * model.degree + 1, 9)
    if isinstance(inverse_degree, bool) or not isinstance(inverse_degree, (int, np.integer)) \
            or not 1 <= inverse_degree <= 9:
        raise ValueError(f"inverse_degree must be an integer from 1 to 9 (SIP's limit); got "
                         f"{inverse_degree!r}.")
    return nx, ny, int(inverse_degree)
