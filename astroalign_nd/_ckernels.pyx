# Licensed under a 3-clause BSD style license - see LICENSE.rst
# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False, nonecheck=False, embedsignature=True
"""
Compiled loops for the passes that touch every pixel or every hypothesis.

Each function works on a range of output rows (or hypotheses) and releases
the GIL, so the Python wrappers in `astroalign_nd._kernels` and
`astroalign_nd.resample` split the work over a few threads.  Threads never
write the same output element, so results do not depend on the number of
threads.  Every function here has a NumPy twin in those wrappers that gives
the same result; the tests compare the two.

This is plain C once compiled: there is no JIT, nothing to cache, and
nothing heavy to import.
"""

from libc.math cimport exp, fabs, floor, isfinite, isnan, sqrt, sqrtf, INFINITY, NAN
from libc.string cimport memcpy

import numpy as np

ctypedef fused real:
    float
    double


cdef inline double _floor(double u) noexcept nogil:
    """floor(u) for |u| < 2**62, inline (libm's floor is a function call without SSE4.1)."""
    cdef double t = <double>(<long long>u)  # truncates toward zero
    return t - 1.0 if u < t else t


# -- detection -------------------------------------------------------------------

cdef inline bint _any_set(const unsigned char* row, Py_ssize_t n) noexcept nogil:
    """Whether any byte of ``row[:n]`` is nonzero, read 32 bytes at a time."""
    cdef Py_ssize_t q = 0, k
    cdef unsigned long long w[4]
    while q + 32 <= n:
        memcpy(w, row + q, 32)
        if (w[0] | w[1] | w[2] | w[3]) != 0:
            return True
        q += 32
    for k in range(q, n):
        if row[k]:
            return True
    return False


cdef void _bin_despike_rows(const real* d, const unsigned char* mk, Py_ssize_t nx_in,
                            Py_ssize_t b, double fill, float* o, Py_ssize_t nx,
                            Py_ssize_t row0, Py_ssize_t row1, double* tot, double* t,
                            double* p) noexcept nogil:
    # `_bin_despike_one` for every block of output rows ``row0:row1``, the
    # same sums in the same order, but with the output columns innermost:
    # their running sums are independent, so the adds no longer wait on each
    # other.  A masked pixel (``mk`` not NULL) is read as ``fill`` (a select,
    # not a branch; only in image rows that have one).  A block with a
    # non-finite unmasked pixel ends with a non-finite total (float pixels
    # cannot overflow a double sum of a few hundred) and is redone by
    # `_bin_despike_one`.
    cdef Py_ssize_t i, j, di, dj
    cdef const real* r
    cdef const unsigned char* mr
    cdef double v
    cdef double inv = 1.0 / (b * b - 1)
    for i in range(row0, row1):
        for j in range(nx):
            tot[j] = 0.0
            p[j] = -INFINITY
        for di in range(b):
            r = d + (i * b + di) * nx_in
            for j in range(nx):
                t[j] = 0.0
            if mk != NULL and _any_set(mk + (i * b + di) * nx_in, nx * b):
                mr = mk + (i * b + di) * nx_in
                for dj in range(b):
                    for j in range(nx):
                        v = r[j * b + dj]
                        v = fill if mr[j * b + dj] else v
                        t[j] += v
                        p[j] = v if v > p[j] else p[j]
            else:
                for dj in range(b):
                    for j in range(nx):
                        v = r[j * b + dj]
                        t[j] += v
                        # An unconditional store: a max instruction, not a branch
                        # that noise makes unpredictable.
                        p[j] = v if v > p[j] else p[j]
            for j in range(nx):
                tot[j] += t[j]
        for j in range(nx):
            if isfinite(tot[j]):
                o[i * nx + j] = <float>((tot[j] - p[j]) * inv)
            else:
                _bin_despike_one(d, mk, nx_in, b, fill, o + i * nx + j, i, j)


cdef void _bin_despike_one(const real* d, const unsigned char* mk, Py_ssize_t nx_in,
                           Py_ssize_t b, double fill, float* o, Py_ssize_t i,
                           Py_ssize_t j) noexcept nogil:
    # One block of `astroalign_nd._kernels.bin_despike`: its pixels summed
    # row by row, in order, and the maximum dropped.  Non-finite pixels, and
    # masked ones when ``mk`` is not NULL, count as fill.
    cdef Py_ssize_t di, dj, k
    cdef double total = 0.0, t, v, p = -INFINITY
    for di in range(b):
        k = (i * b + di) * nx_in + j * b
        t = 0.0
        for dj in range(b):
            v = d[k + dj]
            if not isfinite(v) or (mk != NULL and mk[k + dj]):
                v = fill
            t += v
            if v > p:
                p = v
        total += t
    o[0] = <float>((total - p) * (1.0 / (b * b - 1)))


def bin_despike_rows(const real[:, ::1] data, const unsigned char[:, ::1] mask,
                     bint use_mask, Py_ssize_t b, double fill, float[:, ::1] out,
                     Py_ssize_t row0, Py_ssize_t row1):
    """Rows ``row0:row1`` of `astroalign_nd._kernels.bin_despike`."""
    cdef Py_ssize_t nx = out.shape[1], nx_in = data.shape[1]
    cdef const real* d = &data[0, 0]
    cdef const unsigned char* mk = &mask[0, 0]
    cdef float* o = &out[0, 0]
    if use_mask and (mask.shape[0] != data.shape[0] or mask.shape[1] != data.shape[1]):
        raise ValueError("mask must have the data's shape.")
    cdef double[:, ::1] work = np.empty((3, max(nx, 1)))
    with nogil:
        _bin_despike_rows(d, mk if use_mask else NULL, nx_in, b, fill, o, nx, row0, row1,
                          &work[0, 0], &work[1, 0], &work[2, 0])


def peaks(const float[:, ::1] img, double threshold, Py_ssize_t border):
    """
    Strict 3x3 local maxima above ``threshold`` in raster order, and the sum
    of each one's 3x3 neighbourhood (see `astroalign_nd._kernels.peak_candidates`).
    """
    cdef Py_ssize_t ny = img.shape[0], nx = img.shape[1]
    # Strict maxima cannot touch each other: at most one per 2x2 block.
    cdef Py_ssize_t cap = ((ny + 1) // 2) * ((nx + 1) // 2) + 1
    ys_arr = np.empty(cap, dtype=np.intp)
    xs_arr = np.empty(cap, dtype=np.intp)
    sc_arr = np.empty(cap, dtype=np.float64)
    cdef Py_ssize_t[::1] ys = ys_arr
    cdef Py_ssize_t[::1] xs = xs_arr
    cdef double[::1] sc = sc_arr
    cdef Py_ssize_t i, j, ii, jj, n = 0
    cdef int di, dj
    cdef double v, w, s
    cdef bint is_max
    with nogil:
        for i in range(border, ny - border):
            for j in range(border, nx - border):
                v = img[i, j]
                if v <= threshold:
                    continue
                is_max = True
                s = 0.0
                for di in range(-1, 2):
                    for dj in range(-1, 2):
                        ii = i + di
                        jj = j + dj
                        if ii < 0 or ii >= ny or jj < 0 or jj >= nx:
                            continue
                        w = img[ii, jj]
                        s += w
                        if di == 0 and dj == 0:
                            continue
                        # Ties go to the first pixel in raster order.
                        if w > v or (w == v and (di < 0 or (di == 0 and dj < 0))):
                            is_max = False
                if is_max and n < cap:
                    ys[n] = i
                    xs[n] = j
                    sc[n] = s
                    n += 1
    return ys_arr[:n].copy(), xs_arr[:n].copy(), sc_arr[:n].copy()


cdef void _window_sums(const double* im, Py_ssize_t size, const double* wx,
                       const double* wy, const double* ex, const double* ey, int p,
                       double* col, double* out) noexcept nogil:
    # Sums of a Gaussian-windowed cutout, the window separable, with
    # w = wy[i] * wx[j] and im[i, j] (row-major):
    # out = [sum w, sum w*ex, sum w*ey**p, sum w*ex^2].  The rows are
    # collapsed first into two column sums (weights wy and wy*ey**p): a
    # loop without a reduction, which the compiler vectorises.
    cdef Py_ssize_t i, j
    cdef double a, c, t
    cdef double* ca = col
    cdef double* cc = col + size
    cdef const double* r
    for j in range(size):
        ca[j] = 0.0
        cc[j] = 0.0
    for i in range(size):
        a = wy[i]
        c = a * ey[i] if p == 1 else a * (ey[i] * ey[i])
        r = im + i * size
        for j in range(size):
            t = r[j]
            ca[j] += a * t
            cc[j] += c * t
    out[0] = out[1] = out[2] = out[3] = 0.0
    for j in range(size):
        t = wx[j] * ex[j]
        out[0] += wx[j] * ca[j]
        out[1] += t * ca[j]
        out[2] += wx[j] * cc[j]
        out[3] += wx[j] * (ex[j] * ex[j]) * ca[j]


cdef inline void _gauss_weights(double* w, const double* e, Py_ssize_t size,
                                double sigma) noexcept nogil:
    # w[j] = exp(-0.5 * (e[j] / sigma)**2) for offsets e[j] one pixel apart,
    # with three exponentials instead of one per pixel: from the pixel
    # nearest the centre outwards, each weight is the last times a ratio,
    # and each ratio the last times exp(-1 / sigma**2).  Going outwards the
    # weights only shrink, so none underflows before its true value would.
    cdef Py_ssize_t j, jc = 0
    cdef double inv = 1.0 / (sigma * sigma), t, r, q
    for j in range(1, size):
        if fabs(e[j]) < fabs(e[jc]):
            jc = j
    t = e[jc] / sigma
    w[jc] = exp(-0.5 * (t * t))
    q = exp(-inv)
    r = exp(-(e[jc] + 0.5) * inv)
    for j in range(jc + 1, size):
        w[j] = w[j - 1] * r
        r *= q
    r = exp((e[jc] - 0.5) * inv)
    for j in range(jc - 1, -1, -1):
        w[j] = w[j + 1] * r
        r *= q


cdef inline void _xwin_step(const double* im, Py_ssize_t size, double x, double y,
                            double sigma, double* buf, double* sx, double* sy) noexcept nogil:
    # One XWIN step of one cutout ``im`` (size x size) from (x, y): the
    # unclipped shifts, 0 where the window holds no flux.  ``buf`` holds
    # (7, size) doubles.
    cdef Py_ssize_t j
    cdef double s[4]
    for j in range(size):
        buf[2 * size + j] = j - x
        buf[3 * size + j] = j - y
    _gauss_weights(buf, buf + 2 * size, size, sigma)
    _gauss_weights(buf + size, buf + 3 * size, size, sigma)
    _window_sums(im, size, buf, buf + size, buf + 2 * size, buf + 3 * size, 1,
                 buf + 4 * size, s)
    # The factor 2 is the XWIN update for a Gaussian window.
    sx[0] = 2.0 * s[1] / s[0] if s[0] > 0 else 0.0
    sy[0] = 2.0 * s[2] / s[0] if s[0] > 0 else 0.0


cdef inline double _clip1(double v) noexcept nogil:
    # np.clip(v, -1, 1), NaN kept.
    return -1.0 if v < -1.0 else (1.0 if v > 1.0 else v)


def windowed_centroid(const double[:, :, ::1] img, double[::1] x, double[::1] y,
                      const double[::1] sigma, int n_iter):
    """
    Iterative Gaussian-windowed centroids (SExtractor's XWIN) of cutouts,
    updating ``x`` and ``y`` (pixels in the cutouts) in place.

    The iterations stop when no star moved by 1e-4 px or more, as in
    `astroalign_nd._kernels.windowed_centroid`'s NumPy version.
    """
    cdef Py_ssize_t n = img.shape[0], size = img.shape[1], k, it
    cdef double[:, ::1] buf = np.empty((7, size))
    cdef double[::1] sx = np.empty(n), sy = np.empty(n)
    cdef bint moving
    with nogil:
        for it in range(n_iter):
            moving = False
            for k in range(n):
                _xwin_step(&img[k, 0, 0], size, x[k], y[k], sigma[k], &buf[0, 0],
                           &sx[k], &sy[k])
            for k in range(n):
                if not (fabs(sx[k]) < 1e-4 and fabs(sy[k]) < 1e-4):
                    moving = True
                x[k] += _clip1(sx[k])
                y[k] += _clip1(sy[k])
            if not moving:
                break


def mirrored_windowed_centroid(const double[:, :, ::1] img, const unsigned char[:, :, ::1] bad,
                               double[::1] x, double[::1] y, const double[::1] sigma,
                               int n_iter):
    """
    Windowed centroids of stars cut by bad pixels, each bad pixel filled
    from the star's mirror image through the current centre, updating
    ``x`` and ``y`` in place; ``img`` has its bad pixels at zero.

    `astroalign_nd._kernels.mirrored_windowed_centroid`'s NumPy version, one
    star at a time: the same operations in the same order, so the same
    floats.  A star stops once it moved less than 1e-4 px on both axes.
    """
    cdef Py_ssize_t n = img.shape[0], size = img.shape[1], npix = size * size
    cdef Py_ssize_t k, q, m, nb, it, i
    # The bilinear taps' strides (one pixel: all four taps on it).
    cdef Py_ssize_t dx = 1 if size > 1 else 0, dy = size if size > 1 else 0
    cdef double hi = size - 1.0, last = size - 2.0 if size > 1 else 0.0
    cdef double[:, ::1] buf = np.empty((7, size))
    cdef double[::1] filled = np.empty(max(npix, 1))
    cdef Py_ssize_t[::1] at = np.empty(max(npix, 1), dtype=np.intp)
    cdef const double* im
    cdef const unsigned char* bd
    cdef double cy, cx, fy, fx, ty, tx, uy, ux, v, w, sx, sy, x1, y1
    with nogil:
        for k in range(n):
            im = &img[k, 0, 0]
            bd = &bad[k, 0, 0]
            nb = 0
            for q in range(npix):
                filled[q] = im[q]
                if bd[q]:
                    at[nb] = q
                    nb += 1
            for it in range(n_iter):
                for m in range(nb):
                    q = at[m]
                    cy = 2.0 * y[k] - <double>(q // size)
                    cx = 2.0 * x[k] - <double>(q % size)
                    # Zero beyond [0, size - 1] (and at a NaN centre).
                    if not (cy >= 0.0 and cy <= hi and cx >= 0.0 and cx <= hi):
                        filled[q] = 0.0
                        continue
                    # floor, then np.maximum / np.minimum's selects (libm's
                    # floor keeps -0.0 as NumPy's does).
                    fy = floor(cy)
                    fy = fy if fy >= 0.0 else 0.0
                    fy = fy if fy <= last else last
                    fx = floor(cx)
                    fx = fx if fx >= 0.0 else 0.0
                    fx = fx if fx <= last else last
                    ty = cy - fy
                    tx = cx - fx
                    uy = 1.0 - ty
                    ux = 1.0 - tx
                    i = <Py_ssize_t>(fy * size + fx)
                    v = (uy * (ux * im[i] + tx * im[i + dx])
                         + ty * (ux * im[i + dy] + tx * im[i + dy + dx]))
                    # The good-pixel weight at the mirror image: one that
                    # touches a bad pixel is not the star's.
                    w = (uy * (ux * (0.0 if bd[i] else 1.0) + tx * (0.0 if bd[i + dx] else 1.0))
                         + ty * (ux * (0.0 if bd[i + dy] else 1.0)
                                 + tx * (0.0 if bd[i + dy + dx] else 1.0)))
                    filled[q] = v if w > 0.999 else 0.0
                _xwin_step(&filled[0], size, x[k], y[k], sigma[k], &buf[0, 0], &sx, &sy)
                x1 = x[k] + _clip1(sx)
                y1 = y[k] + _clip1(sy)
                cx = fabs(x1 - x[k])
                cy = fabs(y1 - y[k])
                x[k] = x1
                y[k] = y1
                if cx < 1e-4 and cy < 1e-4:
                    break


def adaptive_sigma(const double[:, :, ::1] img, const double[::1] dx, const double[::1] dy,
                   double sigma0, int n_iter):
    """
    Gaussian sigma of each cutout's star from Gaussian-weighted second
    moments, iterating the window's width to the star's (NaN where the
    moments fail); `astroalign_nd._kernels.adaptive_fwhm` converts it.
    """
    cdef Py_ssize_t n = img.shape[0], size = img.shape[1], half = size // 2, k, j, it
    cdef double[:, ::1] buf = np.empty((7, size))
    cdef double[::1] out = np.empty(n)
    cdef double s[4]
    cdef double sw, sig, s2, inv, hi = half / 3.0
    with nogil:
        for k in range(n):
            sw = sigma0
            sig = sw
            for j in range(size):
                buf[2, j] = (j - half) - dx[k]
                buf[3, j] = (j - half) - dy[k]
            for it in range(n_iter):
                _gauss_weights(&buf[0, 0], &buf[2, 0], size, sw)
                _gauss_weights(&buf[1, 0], &buf[3, 0], size, sw)
                _window_sums(&img[k, 0, 0], size, &buf[0, 0], &buf[1, 0], &buf[2, 0],
                             &buf[3, 0], 2, &buf[4, 0], s)
                s2 = 0.5 * (s[3] + s[2]) / s[0]
                inv = 1.0 / s2 - 1.0 / (sw * sw)
                sig = 1.0 / sqrt(fabs(inv)) if (s[0] > 0 and inv > 0) else NAN
                sw = hi if isnan(sig) else sig
                sw = 0.5 if sw < 0.5 else (hi if sw > hi else sw)
            out[k] = sig
    return np.asarray(out)


def count_nonfinite(const real[::1] flat, Py_ssize_t start, Py_ssize_t stop):
    """Number of NaN or infinite values in ``flat[start:stop]``."""
    cdef Py_ssize_t i, n = 0
    with nogil:
        for i in range(start, stop):
            if not isfinite(flat[i]):
                n += 1
    return n


def finite_sample(const real[:, :] data, const unsigned char[:, :] mask, bint use_mask,
                  Py_ssize_t step, real[::1] out):
    """
    The finite (and, with ``use_mask``, unmasked) pixels of
    ``data[::step, ::step]`` in row-major order, copied to the start of
    ``out``; returns how many.
    """
    cdef Py_ssize_t i, j, k = 0, ny = data.shape[0], nx = data.shape[1]
    cdef Py_ssize_t nyo = (ny + step - 1) // step, nxo = (nx + step - 1) // step
    cdef real v
    if step < 1 or (use_mask and (mask.shape[0] != ny or mask.shape[1] != nx)):
        raise ValueError("step must be positive and mask must have the data's shape.")
    if out.shape[0] < nyo * nxo:
        raise ValueError("out must hold every sampled pixel.")
    with nogil:
        for i in range(nyo):
            for j in range(nxo):
                v = data[i * step, j * step]
                out[k] = v
                k += isfinite(v) and not (use_mask and mask[i * step, j * step])
    return k



def extract_cutouts(const real[:, :] data, const unsigned char[:, :] mask, bint use_mask,
                    const Py_ssize_t[::1] xc, const Py_ssize_t[::1] yc, Py_ssize_t half,
                    double fill, double[:, :, ::1] cut, unsigned char[:, :, ::1] bad):
    """
    The (2 half + 1)^2 cutouts of ``data`` centred on the integer pixels
    (xc, yc), as float64 into ``cut``; ``bad`` set (and ``cut`` = ``fill``)
    for pixels beyond the frame, masked (with ``use_mask``) or not finite.
    `astroalign_nd.detection.candidates._extract_cutouts`' NumPy version
    gives the same values.
    """
    cdef Py_ssize_t n = xc.shape[0], size = 2 * half + 1, ny = data.shape[0], nx = data.shape[1]
    cdef Py_ssize_t k, i, j, y, x0, j0, j1
    cdef double v
    cdef bint b
    cdef double* c
    cdef unsigned char* bd
    cdef const real* row
    cdef const unsigned char* mrow
    # Steps along a row, in elements (negative for a reversed view).
    cdef Py_ssize_t sx = data.strides[1] // <Py_ssize_t>sizeof(real)
    cdef Py_ssize_t mx = mask.strides[1] if use_mask else 0
    if (yc.shape[0] != n or cut.shape[0] != n or bad.shape[0] != n or cut.shape[1] != size
            or cut.shape[2] != size or bad.shape[1] != size or bad.shape[2] != size
            or (use_mask and (mask.shape[0] != ny or mask.shape[1] != nx))):
        raise ValueError("cut and bad must be (n, 2 half + 1, 2 half + 1) and mask the data's "
                         "shape.")
    with nogil:
        for k in range(n):
            x0 = xc[k] - half
            j0 = 0 if x0 >= 0 else -x0  # the row's part inside the frame: [j0, j1)
            j1 = size if x0 + size <= nx else nx - x0
            for i in range(size):
                y = yc[k] - half + i
                c = &cut[k, i, 0]
                bd = &bad[k, i, 0]
                if y < 0 or y >= ny or j1 <= j0:
                    for j in range(size):
                        c[j] = fill
                        bd[j] = 1
                    continue
                for j in range(j0):
                    c[j] = fill
                    bd[j] = 1
                row = &data[y, x0 + j0] - j0 * sx
                if use_mask:
                    mrow = &mask[y, x0 + j0] - j0 * mx
                    for j in range(j0, j1):
                        v = row[j * sx]
                        b = not isfinite(v) or mrow[j * mx]
                        c[j] = fill if b else v
                        bd[j] = b
                else:
                    for j in range(j0, j1):
                        v = row[j * sx]
                        b = not isfinite(v)
                        c[j] = fill if b else v
                        bd[j] = b
                for j in range(j1, size):
                    c[j] = fill
                    bd[j] = 1


# -- matching --------------------------------------------------------------------

def count_inliers_range(const double[:, :, ::1] mats, const double[:, ::1] src,
                        const double[:, ::1] pts, const Py_ssize_t[::1] start,
                        double ox, double oy, double cell, Py_ssize_t nx, Py_ssize_t ny,
                        double r2, Py_ssize_t[::1] out, Py_ssize_t h0, Py_ssize_t h1):
    """Hypotheses ``h0:h1`` of `astroalign_nd._kernels.count_inliers`."""
    cdef Py_ssize_t h, k, i, j, q, cx, cy, cid, n
    cdef double a, b, c, d, e, f, x, y, fx, fy, dx, dy
    cdef bint found
    with nogil:
        for h in range(h0, h1):
            a = mats[h, 0, 0]
            b = mats[h, 0, 1]
            c = mats[h, 0, 2]
            d = mats[h, 1, 0]
            e = mats[h, 1, 1]
            f = mats[h, 1, 2]
            n = 0
            for k in range(src.shape[0]):
                x = a * src[k, 0] + b * src[k, 1] + c
                y = d * src[k, 0] + e * src[k, 1] + f
                if not (x == x and y == y):
                    continue
                fx = (x - ox) / cell
                fy = (y - oy) / cell
                if fx < -1.0 or fy < -1.0 or fx > nx or fy > ny:
                    continue
                cx = <Py_ssize_t>_floor(fx)
                cy = <Py_ssize_t>_floor(fy)
                found = False
                for j in range(max(cy - 1, 0), min(cy + 2, ny)):
                    for i in range(max(cx - 1, 0), min(cx + 2, nx)):
                        cid = j * nx + i
                        for q in range(start[cid], start[cid + 1]):
                            dx = pts[q, 0] - x
                            dy = pts[q, 1] - y
                            if dx * dx + dy * dy < r2:
                                found = True
                                break
                        if found:
                            break
                    if found:
                        break
                if found:
                    n += 1
            out[h] = n


def two_nearest_range(const double[:, ::1] pts, const Py_ssize_t[::1] start, double ox,
                      double oy, double cell, Py_ssize_t nx, Py_ssize_t ny,
                      const double[:, ::1] query, double bound, Py_ssize_t[:, ::1] j_out,
                      double[:, ::1] d_out, Py_ssize_t q0, Py_ssize_t q1):
    """Queries ``q0:q1`` of `astroalign_nd._kernels.two_nearest`."""
    cdef Py_ssize_t k, j, q, x0, x1, y0, y1, j1, j2, n = pts.shape[0]
    cdef double x, y, fx, fy, dx, dy, d2, d1sq, d2sq, b2 = bound * bound, rc = bound / cell
    with nogil:
        for k in range(q0, q1):
            x = query[k, 0]
            y = query[k, 1]
            j1 = n
            j2 = n
            d1sq = INFINITY
            d2sq = INFINITY
            fx = (x - ox) / cell
            fy = (y - oy) / cell
            # Only the cells the disk of radius `bound` overlaps (one to four, for a
            # cell over twice the bound); NaN fails every comparison and finds nothing.
            if fx + rc >= 0.0 and fy + rc >= 0.0 and fx - rc < nx and fy - rc < ny:
                x0 = max(<Py_ssize_t>_floor(fx - rc), 0) if fx - rc > 0.0 else 0
                x1 = min(<Py_ssize_t>_floor(fx + rc), nx - 1) if fx + rc < nx else nx - 1
                y0 = max(<Py_ssize_t>_floor(fy - rc), 0) if fy - rc > 0.0 else 0
                y1 = min(<Py_ssize_t>_floor(fy + rc), ny - 1) if fy + rc < ny else ny - 1
                for j in range(y0, y1 + 1):
                    # The cells x0..x1 of a row hold consecutive points.
                    for q in range(start[j * nx + x0], start[j * nx + x1 + 1]):
                        dx = pts[q, 0] - x
                        dy = pts[q, 1] - y
                        d2 = dx * dx + dy * dy
                        if d2 < d2sq and d2 < b2:
                            if d2 < d1sq:
                                j2, d2sq = j1, d1sq
                                j1, d1sq = q, d2
                            else:
                                j2, d2sq = q, d2
            j_out[k, 0] = j1
            j_out[k, 1] = j2
            d_out[k, 0] = sqrt(d1sq)
            d_out[k, 1] = sqrt(d2sq)


# -- resampling ------------------------------------------------------------------
# The kernels, footprint and mask rules are documented in astroalign_nd.resample;
# `_resample_numpy` there is the same computation in NumPy, tap for tap.

cdef inline void _linear_weights(double f, double* w) noexcept nogil:
    w[0] = 1.0 - f
    w[1] = f
    w[2] = 0.0
    w[3] = 0.0


cdef inline void _quadratic_weights(double t, double* w) noexcept nogil:
    # Dodgson's interpolating quadratic, taps c-1, c, c+1 with t = x - c in [-0.5, 0.5).
    w[0] = t * (t - 0.5)
    w[1] = 1.0 - 2.0 * t * t
    w[2] = t * (t + 0.5)
    w[3] = 0.0


cdef inline void _keys_weights(double f, double* w) noexcept nogil:
    # Keys cubic convolution, a = -0.5, taps floor(x)-1 .. floor(x)+2.
    w[0] = ((-0.5 * f + 1.0) * f - 0.5) * f
    w[1] = (1.5 * f - 2.5) * f * f + 1.0
    w[2] = ((-1.5 * f + 2.0) * f + 0.5) * f
    w[3] = (0.5 * f - 0.5) * f * f


cdef inline bint _axis_taps(double u, Py_ssize_t n, int order, Py_ssize_t* i0,
                            double* w) noexcept nogil:
    """
    First tap index and weights along one axis; False if a used tap is outside.

    Every path sets all four weights: the caller reads them only when both
    axes return True, but the C compiler cannot see that through the ``and``
    of the two calls (it warned ``wx[k]`` "may be used uninitialized").
    """
    cdef double fl
    cdef Py_ssize_t k
    cdef bint ok
    if order == 0:
        w[0] = 1.0
        w[1] = 0.0
        w[2] = 0.0
        w[3] = 0.0
        if not (u >= -0.5 and u <= n - 0.5):  # written so that NaN is rejected too
            i0[0] = 0
            return False
        i0[0] = <Py_ssize_t>_floor(u + 0.5)
        if i0[0] > n - 1:  # u == n - 0.5 exactly
            i0[0] = n - 1
        return True
    # Guard before converting to an integer: far-away positions would overflow.
    if not (u > -3.0 and u < n + 2.0):
        i0[0] = 0
        w[0] = 0.0
        w[1] = 0.0
        w[2] = 0.0
        w[3] = 0.0
        return False
    if order == 1:
        fl = _floor(u)
        _linear_weights(u - fl, w)
        i0[0] = <Py_ssize_t>fl
    elif order == 2:
        fl = _floor(u + 0.5)
        _quadratic_weights(u - fl, w)
        i0[0] = <Py_ssize_t>fl - 1
    else:
        fl = _floor(u)
        _keys_weights(u - fl, w)
        i0[0] = <Py_ssize_t>fl - 1
    ok = i0[0] >= 0 and i0[0] + order <= n - 1
    if not ok:
        # Near an edge only the taps with nonzero weight have to be inside.
        ok = True
        for k in range(order + 1):
            if w[k] != 0.0 and (i0[0] + k < 0 or i0[0] + k > n - 1):
                ok = False
    return ok


# Output columns per tile: each thread walks its rows one tile of columns at a
# time, so that the source rows a rotated or scaled map reads stay in the cache
# between neighbouring output rows (every output pixel is computed exactly as
# without tiles: the order of the pixels does not change any value).
cdef enum:
    TILE = 512


cdef inline double _variance_tap(real v, int kind) noexcept nogil:
    """
    Variance of one input pixel from its plane's value: ``kind`` 0 is a
    variance, 1 a standard deviation (squared), 2 an inverse variance.

    The square or reciprocal is rounded to the plane's own type, as NumPy's
    ``np.square(std)`` or ``1 / ivar`` on the whole plane would round it, so
    the result is the same to the bit without a variance copy of the frame.
    """
    if kind == 1:
        return <real>(v * v)
    if kind == 2:
        return <real>(1.0 / v)
    return v


cdef inline void _store(Py_ssize_t k, bint good, double acc, double accv, bint has_var,
                        int out_kind, double fill, double sd, double sv, real* o, real* ov,
                        unsigned char* om) noexcept nogil:
    """
    Write output pixel ``k``: the value and variance, or fill/inf and the mask.

    ``out_kind`` 1 stores the standard deviation and 2 the inverse variance
    instead of the variance: the square root or reciprocal of the variance
    *rounded to the output type*, as NumPy's ``np.sqrt`` or ``1 / var`` on
    the variance plane would give it (the same bits, without that pass).
    """
    cdef real var
    om[k] = not good
    if good:
        o[k] = <real>(acc * sd)
        if has_var:
            var = <real>(accv * sv)
            if out_kind == 1:
                # sqrtf for float32: correctly rounded, as NumPy's float32 sqrt
                # (and as the double root rounded to float); the cheaper instruction.
                if real is float:
                    ov[k] = sqrtf(var)
                else:
                    ov[k] = sqrt(var)
            elif out_kind == 2:
                ov[k] = <real>(1.0 / var)
            else:
                ov[k] = var
    else:
        o[k] = <real>fill
        if has_var:
            ov[k] = <real>(0.0 if out_kind == 2 else INFINITY)


cdef inline void _resample_block(const real* d, const real* dv, bint has_var, int var_kind,
                                 int out_kind, const unsigned char* mk, bint has_mask,
                                 Py_ssize_t ny, Py_ssize_t nx, const double* m,
                                 const double* xs, const double* ys, const double* jac,
                                 const int order, double fill, double sd, double sv,
                                 real* o, real* ov, unsigned char* om, Py_ssize_t nx_out,
                                 Py_ssize_t row0, Py_ssize_t row1) noexcept nogil:
    # Called with a literal ``order``: the C compiler specialises the loop for
    # each order (fixed tap counts, unrolled), ~2x faster than a runtime count.
    # Source positions come from the affine coefficients ``m``, or, when ``xs``
    # is not NULL, from the coordinate maps ``xs``/``ys`` (one value per output
    # pixel), with ``jac`` (if not NULL) the per-pixel flux factor.
    cdef Py_ssize_t iy, ix, jx, jy, kx, ky, row, k, t0, ti
    cdef int nt = order + 1
    cdef double ux = 0.0, vy = 0.0, u, v, acc, accv, w, wyk, wxk, sdk, svk
    cdef double wx[4]
    cdef double wy[4]
    cdef bint good, masked
    for ti in range((nx_out + TILE - 1) // TILE):
        t0 = ti * TILE
        for iy in range(row0, row1):
            if xs == NULL:
                # Same operation order as the NumPy path, so both give identical positions.
                ux = m[1] * iy + m[2]
                vy = m[4] * iy + m[5]
            for ix in range(t0, min(t0 + TILE, nx_out)):
                k = iy * nx_out + ix
                if xs == NULL:
                    u = m[0] * ix + ux
                    v = m[3] * ix + vy
                else:
                    u = xs[k]
                    v = ys[k]
                good = _axis_taps(u, nx, order, &jx, wx)
                good = _axis_taps(v, ny, order, &jy, wy) and good
                acc = 0.0
                accv = 0.0
                masked = False
                if good:
                    for ky in range(nt):
                        wyk = wy[ky]
                        if wyk != 0.0:  # zero-weight taps are not used (may be outside)
                            row = (jy + ky) * nx + jx
                            for kx in range(nt):
                                wxk = wx[kx]
                                if wxk != 0.0:
                                    w = wyk * wxk
                                    acc += w * d[row + kx]
                                    if has_var:
                                        accv += w * w * _variance_tap(dv[row + kx], var_kind)
                                    if has_mask and mk[row + kx]:
                                        masked = True
                    # A NaN/inf pixel with nonzero weight makes the sum non-finite:
                    # with the mask test, this is the whole mask propagation.
                    good = isfinite(acc) and isfinite(accv) and not masked
                if jac == NULL:
                    sdk = sd
                    svk = sv
                else:
                    sdk = sd * jac[k]
                    svk = sdk * sdk
                _store(k, good, acc, accv, has_var, out_kind, fill, sdk, svk, o, ov, om)


cdef inline void _dispatch(const real* d, const real* dv, bint has_var, int var_kind,
                           int out_kind, const unsigned char* mk, bint has_mask,
                           Py_ssize_t ny, Py_ssize_t nx, const double* m,
                           const double* xs, const double* ys, const double* jac,
                           int order, double fill, double sd, double sv,
                           real* o, real* ov, unsigned char* om, Py_ssize_t nx_out,
                           Py_ssize_t row0, Py_ssize_t row1) noexcept nogil:
    # One literal order per call, see `_resample_block`.
    if order == 0:
        _resample_block(d, dv, has_var, var_kind, out_kind, mk, has_mask, ny, nx, m, xs, ys, jac,
                        0, fill, sd, sv, o, ov, om, nx_out, row0, row1)
    elif order == 1:
        _resample_block(d, dv, has_var, var_kind, out_kind, mk, has_mask, ny, nx, m, xs, ys, jac,
                        1, fill, sd, sv, o, ov, om, nx_out, row0, row1)
    elif order == 2:
        _resample_block(d, dv, has_var, var_kind, out_kind, mk, has_mask, ny, nx, m, xs, ys, jac,
                        2, fill, sd, sv, o, ov, om, nx_out, row0, row1)
    else:
        _resample_block(d, dv, has_var, var_kind, out_kind, mk, has_mask, ny, nx, m, xs, ys, jac,
                        3, fill, sd, sv, o, ov, om, nx_out, row0, row1)


def _check_kinds(int order, int var_kind, int out_kind):
    if order not in (0, 1, 2, 3):
        raise ValueError(f"order must be 0-3; got {order}.")
    for name, kind in (("var_kind", var_kind), ("out_kind", out_kind)):
        if kind not in (0, 1, 2):
            raise ValueError(f"{name} must be 0 (variance), 1 (stddev) or 2 (inverse); "
                             f"got {kind}.")


def resample_rows(const real[:, ::1] data, const real[:, ::1] var, bint has_var, int var_kind,
                  int out_kind, const unsigned char[:, ::1] mask, bint has_mask,
                  const double[::1] m, int order, double fill, double sd, double sv,
                  real[:, ::1] out, real[:, ::1] out_var, unsigned char[:, ::1] out_mask,
                  Py_ssize_t row0, Py_ssize_t row1):
    """
    Output rows ``row0:row1`` of `astroalign_nd.resample.resample` for one
    channel: data, variance and mask in one pass.

    ``m`` holds the target -> source coefficients ``(a, b, c, d, e, f)``:
    the source position of output pixel ``(ix, iy)`` is
    ``(a ix + b iy + c, d ix + e iy + f)``.  ``var`` holds a variance,
    standard deviation or inverse variance (``var_kind`` 0, 1, 2); ``mask``
    (uint8, nonzero = bad) is read only if ``has_mask``.
    """
    _check_kinds(order, var_kind, out_kind)
    # Raw pointers: C-contiguous arrays, and no per-pixel memoryview overhead.
    with nogil:
        _dispatch(&data[0, 0], &var[0, 0], has_var, var_kind, out_kind, &mask[0, 0], has_mask,
                  data.shape[0], data.shape[1], &m[0], NULL, NULL, NULL, order, fill, sd, sv,
                  &out[0, 0], &out_var[0, 0], &out_mask[0, 0], out.shape[1], row0, row1)


def map_rows(const real[:, ::1] data, const real[:, ::1] var, bint has_var, int var_kind,
             int out_kind, const unsigned char[:, ::1] mask, bint has_mask,
             const double[:, ::1] xs, const double[:, ::1] ys, const double[:, ::1] jac,
             bint has_jac, int order, double fill, double sd,
             real[:, ::1] out, real[:, ::1] out_var, unsigned char[:, ::1] out_mask,
             Py_ssize_t row0, Py_ssize_t row1):
    """
    `resample_rows` through a coordinate map: output pixel ``(ix, iy)``
    reads the source at ``(xs[iy, ix], ys[iy, ix])`` (NaN: outside), and
    its value is scaled by ``sd * jac[iy, ix]`` (variance by its square)
    when ``has_jac``, by ``sd`` otherwise.  ``xs``, ``ys``, ``jac`` and the
    outputs have the same shape (a band of output rows).
    """
    _check_kinds(order, var_kind, out_kind)
    if xs.shape[0] != out.shape[0] or xs.shape[1] != out.shape[1] or \
            ys.shape[0] != out.shape[0] or ys.shape[1] != out.shape[1]:
        raise ValueError("the coordinate maps must have the output's shape.")
    if has_jac and (jac.shape[0] != out.shape[0] or jac.shape[1] != out.shape[1]):
        raise ValueError("the Jacobian map must have the output's shape.")
    cdef const double* jp = &jac[0, 0] if has_jac else NULL
    with nogil:  # (raw pointers, as in `resample_rows`)
        _dispatch(&data[0, 0], &var[0, 0], has_var, var_kind, out_kind, &mask[0, 0], has_mask,
                  data.shape[0], data.shape[1], NULL, &xs[0, 0], &ys[0, 0], jp, order, fill,
                  sd, sd * sd, &out[0, 0], &out_var[0, 0], &out_mask[0, 0], out.shape[1], row0,
                  row1)


cdef inline void _bilinear_block(const real* d, const real* dv, const bint has_var,
                                 const int var_kind, int out_kind, const unsigned char* mk,
                                 const bint has_mask, Py_ssize_t ny, Py_ssize_t nx,
                                 const double* m, double fill, double sd, double sv,
                                 real* o, real* ov, unsigned char* om, Py_ssize_t nx_out,
                                 Py_ssize_t row0, Py_ssize_t row1) noexcept nogil:
    # Called with literal ``has_var``, ``var_kind`` and ``has_mask``: the C
    # compiler drops the branches that do not apply.
    cdef Py_ssize_t iy, ix, jx, jy, k, t0, t1, ti
    cdef double ux, vy, u, v, acc, accv, w, fx, fy, flx, fly, wx0, wx1, wy0, wy1
    cdef bint good, okx, oky, masked
    cdef double a0 = m[0], a3 = m[3]
    cdef double xmax = nx - 1, ymax = ny - 1
    for ti in range((nx_out + TILE - 1) // TILE):
        t0 = ti * TILE
        t1 = min(t0 + TILE, nx_out)
        for iy in range(row0, row1):
            ux = m[1] * iy + m[2]
            vy = m[4] * iy + m[5]
            for ix in range(t0, t1):
                u = a0 * ix + ux
                v = a3 * ix + vy
                acc = 0.0
                accv = 0.0
                if u >= 0.0 and u < xmax and v >= 0.0 and v < ymax:
                    # Interior (almost every pixel): all four taps are inside,
                    # and truncation is floor for u, v >= 0.
                    jx = <Py_ssize_t>u
                    jy = <Py_ssize_t>v
                    fx = u - <double>jx
                    fy = v - <double>jy
                    good = True
                else:
                    good = u > -3.0 and u < nx + 2.0 and v > -3.0 and v < ny + 2.0
                    if good:
                        flx = _floor(u)
                        fly = _floor(v)
                        jx = <Py_ssize_t>flx
                        jy = <Py_ssize_t>fly
                        fx = u - flx
                        fy = v - fly
                        # Only taps with nonzero weight must lie inside the image.
                        okx = (jx >= 0 and jx <= nx - 2) or (fx == 0.0 and jx >= 0
                                                             and jx <= nx - 1)
                        oky = (jy >= 0 and jy <= ny - 2) or (fy == 0.0 and jy >= 0
                                                             and jy <= ny - 1)
                        good = okx and oky
                if good:
                    k = jy * nx + jx
                    wx0 = 1.0 - fx
                    wx1 = fx
                    wy0 = 1.0 - fy
                    wy1 = fy
                    masked = has_mask and mk[k]
                    w = wy0 * wx0
                    acc += w * d[k]
                    if has_var:
                        accv += w * w * _variance_tap(dv[k], var_kind)
                    if wx1 != 0.0:
                        w = wy0 * wx1
                        acc += w * d[k + 1]
                        if has_var:
                            accv += w * w * _variance_tap(dv[k + 1], var_kind)
                        masked = masked or (has_mask and mk[k + 1])
                    if wy1 != 0.0:
                        w = wy1 * wx0
                        acc += w * d[k + nx]
                        if has_var:
                            accv += w * w * _variance_tap(dv[k + nx], var_kind)
                        masked = masked or (has_mask and mk[k + nx])
                        if wx1 != 0.0:
                            w = wy1 * wx1
                            acc += w * d[k + nx + 1]
                            if has_var:
                                accv += w * w * _variance_tap(dv[k + nx + 1], var_kind)
                            masked = masked or (has_mask and mk[k + nx + 1])
                    good = isfinite(acc) and isfinite(accv) and not masked
                _store(iy * nx_out + ix, good, acc, accv, has_var, out_kind, fill, sd, sv, o,
                       ov, om)


cdef inline void _bilinear_masked(
        const real* d, const real* dv, const bint has_var, const int var_kind, int out_kind,
        const unsigned char* mk, bint has_mask, Py_ssize_t ny, Py_ssize_t nx, const double* m,
        double fill, double sd, double sv, real* o, real* ov, unsigned char* om,
        Py_ssize_t nx_out, Py_ssize_t row0, Py_ssize_t row1) noexcept nogil:
    # `_bilinear_block` with a literal ``has_mask`` (the caller's ``has_var``
    # and ``var_kind`` are literals already): inlined, each call is compiled
    # for its own combination.
    if has_mask:
        _bilinear_block(d, dv, has_var, var_kind, out_kind, mk, True, ny, nx, m, fill, sd, sv,
                        o, ov, om, nx_out, row0, row1)
    else:
        _bilinear_block(d, dv, has_var, var_kind, out_kind, mk, False, ny, nx, m, fill, sd, sv,
                        o, ov, om, nx_out, row0, row1)

def bilinear_rows(const real[:, ::1] data, const real[:, ::1] var, bint has_var, int var_kind,
                  int out_kind, const unsigned char[:, ::1] mask, bint has_mask,
                  const double[::1] m, double fill, double sd, double sv,
                  real[:, ::1] out, real[:, ::1] out_var, unsigned char[:, ::1] out_mask,
                  Py_ssize_t row0, Py_ssize_t row1):
    """
    `resample_rows` for order 1, written out: the same positions, weights,
    tap order and mask rule (so the same bits), without the generic tap
    machinery, which costs several times more per pixel.
    """
    _check_kinds(1, var_kind, out_kind)
    cdef Py_ssize_t ny = data.shape[0], nx = data.shape[1], nx_out = out.shape[1]
    cdef const real* d = &data[0, 0]
    cdef const real* dv = &var[0, 0]
    cdef const unsigned char* mk = &mask[0, 0]
    cdef real* o = &out[0, 0]
    cdef real* ov = &out_var[0, 0]
    cdef unsigned char* om = &out_mask[0, 0]
    cdef const double* mp = &m[0]
    # One literal combination of the options per call, see `_bilinear_block`:
    # the variance's here, the mask's in `_bilinear_masked`.
    with nogil:
        if not has_var:
            _bilinear_masked(d, dv, False, 0, out_kind, mk, has_mask, ny, nx, mp, fill, sd, sv,
                             o, ov, om, nx_out, row0, row1)
        elif var_kind == 0:
            _bilinear_masked(d, dv, True, 0, out_kind, mk, has_mask, ny, nx, mp, fill, sd, sv,
                             o, ov, om, nx_out, row0, row1)
        elif var_kind == 1:
            _bilinear_masked(d, dv, True, 1, out_kind, mk, has_mask, ny, nx, mp, fill, sd, sv,
                             o, ov, om, nx_out, row0, row1)
        else:
            _bilinear_masked(d, dv, True, 2, out_kind, mk, has_mask, ny, nx, mp, fill, sd, sv,
                             o, ov, om, nx_out, row0, row1)
