# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The joint least squares of `~astroalign_nd.solve_sequence`: every frame's
transform to the reference frame at once.

Two problems, both sparse and solved by Gauss-Newton with SuperLU
(`scipy.sparse.linalg.splu`), or with a dense Cholesky factor when the
frames are so interlinked that the matrix is nearly full:

* the link adjustment: the frame transforms alone, from the matched pairs
  of every link (``T_a(p_a) = T_b(p_b)``); its misfit per link is what
  rejects a link that disagrees with the rest;
* the bundle adjustment: the frame transforms and every star's position in
  the common frame (``T_f(p) = X_s`` for each detection of each star), the
  star positions eliminated by their Schur complement (each is the weighted
  mean of its detections), so the reduced system holds only the frames'
  parameters.  Its inverse is the parameters' covariance.

Each frame's parameters act on its pixel coordinates centred on the frame
(and with y flipped for a mirrored frame), which keeps the problem well
conditioned.  The reference frame is held fixed at the identity.  The
parameters, their Jacobian and their matrix are those of the transform
type's parameter layer (`~astroalign_nd.transforms.layers`): any linear
type of the registry is solved.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, sparse
from scipy.sparse.linalg import splu

from ..transforms.registry import transform_class

__all__ = []

#: A normal matrix fuller than this (fraction of its elements) is factored as a dense one:
#: a long sequence whose frames all share the reference's stars couples every frame.
_DENSE_FILL = 0.2
#: ... up to this many parameters (a dense factor of 6000 x 6000 is 288 MB).
_DENSE_MAX = 6000
#: Star columns per dense product when the reduced matrix is formed dense
#: (bounds the dense copy of the coupling: 6000 x 2048 is 98 MB).
_DENSE_CHUNK = 2048
#: Conjugate gradients (`bundle_step` with a preconditioner): relative
#: tolerance on the preconditioned residual's norm, and the iteration cap.
_PCG_TOL, _PCG_MAX = 1e-10, 60


@dataclass
class Frames:
    """The frames' parametrisation: centres, parities, parameters."""

    kind: str
    centres: np.ndarray  # (F, 2)
    parity: np.ndarray  # (F,) +1 or -1
    theta: np.ndarray  # (F, k)
    reference: int
    #: Frames without parameters of their own (besides the reference): those not solved.
    #: Free parameters that no detection constrains would make the normal matrix singular.
    fixed: frozenset = frozenset()

    @property
    def layer(self):
        """The parameter layer of the frames' transform type (`layer_of`)."""
        return layer_of(self.kind)

    def local(self, f, pts):
        """Frame ``f``'s pixel positions in its centred (and unmirrored) coordinates."""
        q = np.asarray(pts, float) - self.centres[f]
        q[:, 1] *= self.parity[f]
        return q

    def index(self):
        """Column offset of each frame's parameters (-1 for the reference and fixed ones)."""
        k = self.layer.k
        cols = np.full(len(self.theta), -1)
        free = [f for f in range(len(self.theta)) if f != self.reference and f not in self.fixed]
        cols[free] = np.arange(len(free)) * k
        return cols, len(free) * k


def layer_of(kind):
    """
    The parameter layer of a linear transform type, as the solve adjusts
    it: on a frame's centred coordinates, whose y axis is already flipped
    for a mirrored frame (parity 1).
    """
    return transform_class(kind).layer()


def jacobian(layer, theta, q):
    """(n, 2, k): the derivative of the prediction with respect to ``theta`` (one
    frame's (k,), or one row per point (n, k))."""
    # (One row per point, as the bundle step has them: the same arithmetic
    # whichever step asks.)
    return layer.design(q, np.broadcast_to(theta, (len(q), layer.k)))


def theta_from_matrix(layer, m, centre, parity):
    """The parameters of the 3x3 pixel-to-common matrix ``m`` (its nearest of the layer's type)."""
    flip = np.diag([1.0, parity])
    lin = m[:2, :2] @ flip
    t = m[:2, :2] @ centre + m[:2, 2]
    return layer.from_parts(lin, t)


def matrix_from_theta(layer, theta, centre, parity):
    """The 3x3 pixel-to-common matrix of the parameters ``theta``."""
    flip = np.diag([1.0, parity])
    lin, t = layer.to_parts(theta)
    m = np.eye(3)
    m[:2, :2] = lin @ flip
    m[:2, 2] = t - lin @ flip @ centre
    return m


def _normal_terms(frames, f, q, w, cols):
    """(jacobian (n, 2, k), its normal block k x k, the prediction) of frame ``f``'s points."""
    layer = frames.layer
    jac = jacobian(layer, frames.theta[f], q)
    block = np.einsum("nik,n,nil->kl", jac, w, jac)
    return jac, block, layer.predict(frames.theta[f], q)


class _DenseFactor:
    """A Cholesky factor of a dense normal matrix, with SuperLU's ``solve``."""

    def __init__(self, factor):
        self.factor = factor

    def solve(self, rhs):
        return linalg.cho_solve(self.factor, rhs)

    def inverse(self):
        """The whole inverse (LAPACK ``potri``: a third of the solves' cost)."""
        c, lower = self.factor
        inv, info = linalg.lapack.dpotri(c, lower=lower)
        if info != 0:  # cannot happen for a successful factor
            raise linalg.LinAlgError(f"potri failed ({info})")
        # potri fills one triangle: mirror it.
        tri = np.tril(inv) if lower else np.triu(inv)
        return tri + tri.T - np.diag(np.diag(tri))


def _solve(normal, rhs):
    """
    ``normal @ x = rhs`` (symmetric positive definite: sparse, or an
    ndarray when already dense); None if singular.
    """
    p = normal.shape[0]
    if p == 0:
        return np.zeros(0), None
    dense = isinstance(normal, np.ndarray)
    if dense or (p <= _DENSE_MAX and normal.nnz > _DENSE_FILL * p * p):
        try:
            full = normal if dense else normal.toarray()
            lu = _DenseFactor(linalg.cho_factor(full, check_finite=False))
        except linalg.LinAlgError:  # not positive definite: singular
            return None, None
        return lu.solve(rhs), lu
    try:
        lu = splu(sparse.csc_matrix(normal))
    except RuntimeError:  # singular: a frame with too few constraints
        return None, None
    return lu.solve(rhs), lu


def link_step(frames, pairs):
    """
    One Gauss-Newton step of the link adjustment.

    ``pairs``: one ``(a, b, qa, qb, w)`` per link, ``qa``/``qb`` the matched
    points (frames' local coordinates), ``w`` their weights.  Returns the
    parameter change (F, k) and each link's residuals (common frame pixels).
    """
    cols, p = frames.index()
    k = frames.layer.k
    rows_i, cols_i, vals, rhs, resid = [], [], [], np.zeros(p), []
    grid = np.arange(k)
    for a, b, qa, qb, w in pairs:
        ja, _, pa = _normal_terms(frames, a, qa, w, cols)
        jb, _, pb = _normal_terms(frames, b, qb, w, cols)
        r = pa - pb
        resid.append(r)
        for f, jf, sf in ((a, ja, 1.0), (b, jb, -1.0)):
            if cols[f] < 0:
                continue
            rhs[cols[f] + grid] -= sf * np.einsum("nik,n,ni->k", jf, w, r)
            for g, jg, sg in ((a, ja, 1.0), (b, jb, -1.0)):
                if cols[g] < 0:
                    continue
                blk = sf * sg * np.einsum("nik,n,nil->kl", jf, w, jg)
                rr, cc = np.meshgrid(cols[f] + grid, cols[g] + grid, indexing="ij")
                rows_i.append(rr.ravel())
                cols_i.append(cc.ravel())
                vals.append(blk.ravel())
    normal = (sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows_i),
                                                        np.concatenate(cols_i))),
                                shape=(p, p)).tocsc()
              if vals else sparse.csc_matrix((p, p)))
    delta, _ = _solve(normal, rhs)
    return _unpack(frames, delta, cols), resid


def _unpack(frames, delta, cols):
    if delta is None:
        return None
    k = frames.layer.k
    out = np.zeros_like(frames.theta)
    for f in range(len(out)):
        if cols[f] >= 0:
            out[f] = delta[cols[f]:cols[f] + k]
    return out


@dataclass
class Observations:
    """The detections of the stars: frame, track (star), local position, weight."""

    frame: np.ndarray
    track: np.ndarray
    q: np.ndarray
    w: np.ndarray
    n_tracks: int
    var: np.ndarray = None  # the detections' own variances (per axis), before any jitter


def jitter(r2, var, dof):
    """
    Extra variance ``j2`` (per axis) so that ``sum(r2 / (var + j2)) = dof``
    (0 when none is needed): what the detections' own errors leave out.
    """
    if dof <= 0 or np.sum(r2 / var) <= dof:
        return 0.0
    lo, hi = 0.0, float(np.max(r2)) + 1e-12
    for _ in range(50):  # bisection: the sum decreases as j2 grows
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.sum(r2 / (var + mid)) > dof else (lo, mid)
    return hi


def _area_terms(frames):
    """
    Per frame, ``g2 = 1 / |det A|`` (``A`` the linear part of its transform)
    and the derivative of ``log g`` (``g = sqrt(g2)``) with respect to its
    parameters (F, k).

    A detection's error is in its own frame's pixels, and the residual
    ``T_f(q) - X`` in the common frame is that error scaled by ``A``: a fit
    of the residuals as they are would gain by shrinking every frame but the
    reference, which scales its noise down with it.  The maximum-likelihood
    residual ``A^-1 (T_f(q) - X)`` is, for the isotropic errors of a
    detection, ``g (T_f(q) - X)`` (exactly for a similarity; for an affine
    transform, ``g`` is the isotropic part of ``A^-1``, which removes the
    first-order bias too).  A shrinking bias grows with the number of frames:
    -110 ppm in scale over 300 frames of 256 x 256 at 0.05 px, twice the
    pairwise error at the corners, before this term.
    """
    n, k = frames.theta.shape
    g2, dlog = np.ones(n), np.zeros((n, k))
    area = frames.layer.area(frames.theta)
    if area is None:
        return g2, dlog  # (translation, euclidean: |det A| = 1)
    det, grad = area
    ok = det != 0  # a frame outside the solve keeps zero parameters
    g2[ok] = 1.0 / np.abs(det[ok])
    dlog[ok, :grad.shape[1]] = grad[ok] / det[ok, None]
    return g2, dlog


def weights(frames, obs):
    """Each detection's weight in the common frame: its own, over its frame's area scale."""
    return obs.w * _area_terms(frames)[0][obs.frame]


def star_positions(frames, obs):
    """Each track's common-frame position: the weighted mean of its detections (S, 2)."""
    pred = frames.layer.predict(frames.theta[obs.frame], obs.q)
    w = weights(frames, obs)
    wsum = np.bincount(obs.track, w, obs.n_tracks)
    xs = np.column_stack([np.bincount(obs.track, w * pred[:, i], obs.n_tracks)
                          for i in range(2)])
    with np.errstate(invalid="ignore", divide="ignore"):
        return xs / wsum[:, None], pred


def _bundle_system(frames, obs):
    """
    The bundle adjustment's normal equations, the star positions not yet
    eliminated: the frames' block ``a`` (p, p), the frame-star coupling
    ``b`` (p, 2S), the stars' inverse weights ``d_inv`` (2S,), the
    right-hand side (p,) and the residuals (n, 2) at the current parameters.
    """
    cols, p = frames.index()
    k = frames.layer.k
    xs, pred = star_positions(frames, obs)
    resid = pred - xs[obs.track]
    # Every detection at once (one parameter row per detection): a loop over
    # the frames costs a pass over all detections per frame.
    jac = jacobian(frames.layer, frames.theta[obs.frame], obs.q)
    # The residuals weighed in their own frame's pixels (`_area_terms`):
    # g (T(q) - X), whose derivative adds g's own, times the residual.
    g2, dlog = _area_terms(frames)
    w = obs.w * g2[obs.frame]
    jac = jac + resid[:, :, None] * dlog[obs.frame][:, None, :]
    free = cols[obs.frame] >= 0
    wj = w[:, None, None] * jac
    grid = np.arange(k)
    # A: block diagonal (one k x k block per frame); B: frame-star coupling.
    n_frames = len(frames.theta)
    outer = np.einsum("nik,nil->nkl", wj, jac).reshape(len(jac), k * k)
    blocks = np.column_stack([np.bincount(obs.frame, outer[:, j], n_frames)
                              for j in range(k * k)]).reshape(n_frames, k, k)
    grad = np.einsum("nik,ni->nk", wj, resid)
    rhs_f = np.column_stack([np.bincount(obs.frame, grad[:, j], n_frames) for j in range(k)])
    used = np.unique(obs.frame[free])
    rhs = np.zeros(p)
    rhs[(cols[used][:, None] + grid).ravel()] = -rhs_f[used].ravel()
    rr = np.broadcast_to(cols[used][:, None, None] + grid[None, :, None], (len(used), k, k))
    cc = np.broadcast_to(cols[used][:, None, None] + grid[None, None, :], (len(used), k, k))
    a = sparse.coo_matrix((blocks[used].ravel(), (rr.ravel(), cc.ravel())),
                          shape=(p, p)).tocsc()
    idx = np.nonzero(free)[0]
    b_rows = (cols[obs.frame[idx]][:, None, None] + grid[None, None, :]).repeat(2, axis=1)
    b_cols = np.broadcast_to((2 * obs.track[idx])[:, None, None] + np.arange(2)[None, :, None],
                             b_rows.shape)
    b = sparse.coo_matrix((-wj[idx].ravel(), (b_rows.ravel(), b_cols.ravel())),
                          shape=(p, 2 * obs.n_tracks)).tocsr()
    d = np.repeat(np.bincount(obs.track, w, obs.n_tracks), 2).astype(float)
    d_inv = np.divide(1.0, d, out=np.zeros_like(d), where=d > 0)  # (a star all clipped: 0)
    return a, b, d_inv, rhs, resid


def _pcg(a, b, d_inv, rhs, precond):
    """
    ``(a - b diag(d_inv) b^T) x = rhs`` by conjugate gradients, the reduced
    matrix applied without being formed, preconditioned by ``precond`` (the
    factor of a nearby system); None when it does not converge.
    """
    bt = b.T.tocsr()

    def apply(v):
        return a @ v - b @ (d_inv * (bt @ v))

    x = np.zeros_like(rhs)
    r = rhs.copy()
    z = precond.solve(r)
    d, rz = z.copy(), float(r @ z)
    stop = _PCG_TOL ** 2 * rz
    for _ in range(_PCG_MAX):
        if rz <= stop:
            return x
        q = apply(d)
        alpha = rz / float(d @ q)
        x += alpha * d
        r -= alpha * q
        z = precond.solve(r)
        rz, rz_old = float(r @ z), rz
        d = z + (rz / rz_old) * d
    return x if rz <= stop else None


def _reduced(a, b, d_inv, k):
    """
    The reduced normal matrix ``a - b diag(d_inv) b^T``.  When most frames
    share stars (a long sequence on one field) it is nearly full, and a
    dense product (BLAS) forms it several times faster than a sparse one:
    it is then returned as an ndarray, for `_solve`'s dense factor.
    """
    p = a.shape[0]
    dense = 0 < p <= _DENSE_MAX
    if dense:
        # The fraction of its frame blocks that are not zero (frames that share a
        # star), from b's pattern collapsed to frames and stars: a product 4 k^2
        # times smaller than the reduction itself.
        coo = b.tocoo()
        seen = sparse.coo_matrix((np.ones(len(coo.row)), (coo.row // k, coo.col // 2)),
                                 shape=(p // k, b.shape[1] // 2)).tocsr()
        seen.data[:] = 1.0
        dense = (seen @ seen.T).nnz * k * k / float(p * p) > _DENSE_FILL
    if not dense:
        return a - b @ sparse.diags(d_inv) @ b.T
    out = a.toarray()
    u = (b @ sparse.diags(np.sqrt(d_inv))).tocsc()
    for start in range(0, u.shape[1], _DENSE_CHUNK):
        part = u[:, start:start + _DENSE_CHUNK].toarray()
        out -= part @ part.T
    return out


def bundle_step(frames, obs, precond=None):
    """
    One Gauss-Newton step of the bundle adjustment, the star positions
    eliminated (Schur complement).

    With ``precond`` (the factor a previous step returned), the step is
    solved by preconditioned conjugate gradients and the reduced matrix is
    neither formed nor factored (a long sequence's is dense); the factor
    returned is then None.  Returns the parameter change (F, k) or None
    when the system is singular, the residuals (n, 2) at the current
    parameters, and the factor of the reduced normal matrix (for the
    covariance).
    """
    cols, _ = frames.index()
    a, b, d_inv, rhs, resid = _bundle_system(frames, obs)
    if precond is not None and len(rhs):
        delta = _pcg(a, b, d_inv, rhs, precond)
        if delta is not None:
            return _unpack(frames, delta, cols), resid, None
    reduced = _reduced(a, b, d_inv, frames.layer.k)
    # The residuals are those of the mean star positions: their gradient is
    # zero, so the reduced right-hand side is the frames' own.
    delta, lu = _solve(reduced, rhs)
    return _unpack(frames, delta, cols), resid, lu


def frame_covariances(frames, lu, scale):
    """Each frame's (k, k) parameter covariance from the reduced normal matrix's factor."""
    cols, p = frames.index()
    k = frames.layer.k
    out = np.zeros((len(frames.theta), k, k))
    if lu is None or p == 0:
        return out
    if isinstance(lu, _DenseFactor):
        inv = lu.inverse()
        for f in np.nonzero(cols >= 0)[0]:
            out[f] = inv[cols[f]:cols[f] + k, cols[f]:cols[f] + k] * scale
        return out
    step = max(k, (4096 // k) * k)  # columns per solve: bounded memory
    for start in range(0, p, step):
        eye = np.zeros((p, min(step, p - start)))
        eye[np.arange(start, start + eye.shape[1]), np.arange(eye.shape[1])] = 1.0
        inv = lu.solve(eye)
        for f in np.nonzero((cols >= start) & (cols < start + step))[0]:
            c0 = cols[f]
            out[f] = inv[c0:c0 + k, c0 - start:c0 - start + k] * scale
    return out


def predicted_error(frames, f, cov, shape):
    """Largest 1-sigma position error (common-frame px) over the corners of frame ``f``."""
    ny, nx = shape
    corners = np.array([[-0.5, -0.5], [nx - 0.5, -0.5], [-0.5, ny - 0.5],
                        [nx - 0.5, ny - 0.5]])
    jac = jacobian(frames.layer, frames.theta[f], frames.local(f, corners))
    var = np.einsum("nik,kl,nil->ni", jac, cov, jac)
    return float(np.sqrt(np.max(var.sum(axis=1))))
