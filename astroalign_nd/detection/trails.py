# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Satellite and aircraft trails: long, thin, straight sources.

A trail crossing a frame is a ridge brighter than most stars; the binned
candidate search finds a string of peaks along it, a few pixels apart, and
ranks them first.  Taken for stars they would set the FWHM estimate (a
trail is wider than a star across, and as long as the cutout along), take
the candidates' places of faint stars, and give the matcher points on one
line.  Here such strings are found among the candidates (`find_trails`: a
Hough vote over candidate pairs, kept only when the line holds far more
candidates than the frame's density of candidates puts on it by chance)
and their pieces are dropped (`trail_pieces`), except stars on the trail:
candidates that stand above the trail on both sides along it.
"""

import numpy as np
from .._kernels import median as _median

__all__ = []

#: Candidates within this many pixels of a trail's centre line are on it.
_HALF_WIDTH = 2.5

#: The line is tested at these half widths (pixels): a trail's pieces sit
#: on its crest, most within a pixel of it, chance alignments spread over
#: the strip.
_TEST_WIDTHS = (1.0, _HALF_WIDTH)

#: A trail holds at least this many candidates ...
_MIN_PIECES = 8

#: ... and this many Poisson sigmas more than the candidates' density puts
#: on a strip of its size by chance (the best of many lines tried).
_EXCESS_SIGMAS = 6.0

#: Candidate pairs between these distances (pixels) vote for the line
#: through them: closer pairs give too poor an angle, farther ones too many pairs.
_PAIR_RANGE = (6.0, 64.0)

#: Vote bins: angle (degrees) and distance from the origin (pixels).
_BIN_DEG, _BIN_PX = 2.0, 3.0

#: At most this many trails per frame.
_MAX_TRAILS = 3

#: The ridge test: pixels this far (pixels) from the line are its sides ...
_RIDGE_OFFSET = 8.0

#: ... samples this far along the line from any candidate are between them ...
_RIDGE_CLEAR = 3.0

#: ... at least this many samples are needed ...
_RIDGE_SAMPLES = 10

#: ... and their median stands this many standard errors above the sides.
_RIDGE_NSIGMA = 5.0

#: A candidate on a trail is a star when the light across the trail there
#: exceeds the trail's this far (pixels) along it, on both sides, by this
#: many noise sigmas and this many times the trail's light ...
_STAR_OFFSET, _STAR_NSIGMA, _STAR_CONTRAST = 6.0, 5.0, 2.0

#: ... the light across the trail summed over this many pixels either side,
#: less the sky this far (pixels) either side.
_CROSS_HALF, _SKY_OFFSETS = 3, (8.0, 9.0, 10.0)


class Trail:
    """A straight trail: a point on its centre line and its unit direction."""

    def __init__(self, point, direction):
        self.point = np.asarray(point, float)
        self.direction = np.asarray(direction, float)

    def distance(self, x, y):
        """Distance (pixels) of points from the centre line."""
        dx, dy = np.asarray(x, float) - self.point[0], np.asarray(y, float) - self.point[1]
        return np.abs(dx * self.direction[1] - dy * self.direction[0])

    def __repr__(self):
        ang = np.degrees(np.arctan2(self.direction[1], self.direction[0])) % 180.0
        return f"Trail(point=({self.point[0]:.1f}, {self.point[1]:.1f}), angle={ang:.1f} deg)"


def _fit_line(x, y):
    """Total least-squares line through points: its centroid and unit direction."""
    cx, cy = x.mean(), y.mean()
    _, _, vt = np.linalg.svd(np.column_stack([x - cx, y - cy]), full_matrices=False)
    return (cx, cy), vt[0]


def _best_line(x, y, diag):
    """The line with the most votes of candidate pairs, refined on its members; or None."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(np.column_stack([x, y])).query_pairs(_PAIR_RANGE[1], output_type="ndarray")
    if len(pairs) == 0:
        return None
    dx, dy = x[pairs[:, 1]] - x[pairs[:, 0]], y[pairs[:, 1]] - y[pairs[:, 0]]
    far = np.hypot(dx, dy) >= _PAIR_RANGE[0]
    if far.sum() < _MIN_PIECES:
        return None
    pairs, dx, dy = pairs[far], dx[far], dy[far]
    theta = np.arctan2(dy, dx) % np.pi
    rho = y[pairs[:, 0]] * np.cos(theta) - x[pairs[:, 0]] * np.sin(theta)
    n_theta = int(round(180.0 / _BIN_DEG))
    n_rho = int(np.ceil(2 * diag / _BIN_PX)) + 1
    it = np.minimum((theta / np.radians(_BIN_DEG)).astype(int), n_theta - 1)
    ir = np.clip(((rho + diag) / _BIN_PX).astype(int), 0, n_rho - 1)
    votes = np.bincount(it * n_rho + ir, minlength=n_theta * n_rho)
    top = int(np.argmax(votes))
    if votes[top] < _MIN_PIECES:
        return None
    th = (top // n_rho + 0.5) * np.radians(_BIN_DEG)
    r = (top % n_rho + 0.5) * _BIN_PX - diag
    line = Trail((-r * np.sin(th), r * np.cos(th)), (np.cos(th), np.sin(th)))
    # The bins are coarse: refit on the members, twice.
    for _ in range(2):
        on = line.distance(x, y) <= _HALF_WIDTH
        if on.sum() < 3:
            return None
        line = Trail(*_fit_line(x[on], y[on]))
    return line


def _length_inside(line, shape):
    """Length (pixels) of the line's part inside the frame."""
    ny, nx = shape
    (px, py), (ux, uy) = line.point, line.direction
    lo, hi = -np.inf, np.inf
    for p, u, n in ((px, ux, nx), (py, uy, ny)):
        if abs(u) < 1e-12:
            if not -0.5 <= p <= n - 0.5:
                return 0.0
            continue
        a, b = (-0.5 - p) / u, (n - 0.5 - p) / u
        lo, hi = max(lo, min(a, b)), min(hi, max(a, b))
    return float(max(0.0, hi - lo))


def _significant(n_on, expected):
    """Are ``n_on`` candidates on a line far more than the ``expected`` by chance?"""
    # Two candidates define any line: only the others count against chance.
    return n_on >= _MIN_PIECES and n_on - 2 >= expected + _EXCESS_SIGMAS * np.sqrt(
        expected + 1.0)


def _pixels(data, mask, px, py):
    """Nearest pixels' values at ``(px, py)``, NaN outside the frame or masked."""
    ny, nx = data.shape
    ix, iy = np.rint(px).astype(int), np.rint(py).astype(int)
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    vals = np.full(len(px), np.nan)
    vals[inside] = data[iy[inside], ix[inside]]
    if mask is not None:
        vals[inside] = np.where(mask[iy[inside], ix[inside]], np.nan, vals[inside])
    return vals


def _is_ridge(data, mask, line, x, y, noise):
    """
    Is the line through the candidates ``(x, y)`` (its members) a ridge of
    light between them, not only where they are?

    Pixels on the line, a pixel apart over the members' span but away
    from the members (a string of stars is sky between its stars), less
    the mean of the pixels `_RIDGE_OFFSET` either side (a gradient
    cancels): their median must stand `_RIDGE_NSIGMA` standard errors
    above zero.
    """
    t = (x - line.point[0]) * line.direction[0] + (y - line.point[1]) * line.direction[1]
    ts = np.arange(np.floor(t.min()), np.ceil(t.max()) + 1.0)
    gap = np.min(np.abs(ts[:, None] - t[None, :]), axis=1)
    for clear in (_RIDGE_CLEAR, 1.0):  # packed pieces leave few gaps
        if np.sum(gap > clear) >= _RIDGE_SAMPLES:
            ts = ts[gap > clear]
            break
    (px, py), (ux, uy) = line.point, line.direction
    lx, ly = px + ts * ux, py + ts * uy
    on = _pixels(data, mask, lx, ly)
    side = 0.5 * (_pixels(data, mask, lx - _RIDGE_OFFSET * uy, ly + _RIDGE_OFFSET * ux)
                  + _pixels(data, mask, lx + _RIDGE_OFFSET * uy, ly - _RIDGE_OFFSET * ux))
    r = on - side
    r = r[np.isfinite(r)]
    if r.size < _RIDGE_SAMPLES:
        return False
    # Each difference has a noise of sqrt(1.5) sigmas; a median's standard
    # error is 1.25 times a mean's.
    return float(_median(r)) > _RIDGE_NSIGMA * 1.25 * np.sqrt(1.5) * noise / np.sqrt(r.size)


def find_trails(x, y, data, mask, noise):
    """
    The trails along which the candidates ``(x, y)`` of an image line up.

    A line counts as a trail when it holds at least `_MIN_PIECES`
    candidates within `_HALF_WIDTH` of it, `_EXCESS_SIGMAS` Poisson
    sigmas more than the frame's density of candidates puts on a strip of
    its size (stars line up by chance in a few, a trail's pieces by the
    dozen), and its light runs on between them (`_is_ridge`: a line of
    stars in a crowded field is sky between its stars).

    Parameters
    ----------
    x, y : 1-D arrays
        The candidates (full-resolution pixels).
    data : 2-D ndarray
        The image (background need not be subtracted).
    mask : 2-D bool ndarray or None
    noise : float
        The image's noise per pixel.

    Returns
    -------
    trails : list of `Trail`
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    shape = data.shape
    area = float(shape[0] * shape[1])
    diag = float(np.hypot(*shape))
    left = np.ones(len(x), bool)
    trails = []
    for _ in range(2 * _MAX_TRAILS):  # lines tried
        if len(trails) == _MAX_TRAILS or left.sum() < _MIN_PIECES:
            break
        idx = np.flatnonzero(left)
        line = _best_line(x[idx], y[idx], diag)
        if line is None:
            break
        dist = line.distance(x[idx], y[idx])
        on = dist <= _HALF_WIDTH
        if not any(_significant(np.sum(dist <= w), len(x) * 2.0 * w * length / area)
                   for w in _TEST_WIDTHS for length in [_length_inside(line, shape)]):
            break
        if not _is_ridge(data, mask, line, x[idx[on]], y[idx[on]], noise):
            # Not a trail: the next best line has fewer votes, but may be one.
            left[idx[on]] = False
            continue
        trails.append(line)
        left[idx[on]] = False
    return trails


def _cross_sections(data, mask, line, t):
    """
    The trail's light across it at positions ``t`` along it, less the sky.

    Bilinearly interpolated pixels are summed over `_CROSS_HALF` pixels
    either side of the centre line, less as many times the mean of the
    pixels `_SKY_OFFSETS` either side (NaN where any is outside the frame
    or masked).
    """
    from scipy.ndimage import map_coordinates

    img = np.asarray(data, float)
    if mask is not None:
        img = np.where(mask, np.nan, img)
    core = np.arange(-_CROSS_HALF, _CROSS_HALF + 1.0)
    sky = np.concatenate([-np.asarray(_SKY_OFFSETS), _SKY_OFFSETS])
    u = np.concatenate([core, sky])
    (px, py), (ux, uy) = line.point, line.direction
    xs = px + t[:, None] * ux - u[None, :] * uy
    ys = py + t[:, None] * uy + u[None, :] * ux
    ny, nx = img.shape
    inside = ((xs >= 0) & (xs <= nx - 1) & (ys >= 0) & (ys <= ny - 1)).all(axis=1)
    vals = map_coordinates(img, [ys.ravel(), xs.ravel()], order=1, mode="nearest",
                           prefilter=False).reshape(xs.shape)
    light = vals[:, :core.size].sum(axis=1) - core.size * vals[:, core.size:].mean(axis=1)
    return np.where(inside, light, np.nan)


def trail_pieces(data, mask, x, y, trails, noise):
    """
    Which candidates ``(x, y)`` are pieces of the ``trails`` (bool array).

    A candidate on a trail is kept as a star when the light across the
    trail there (`_cross_sections`: a star adds its own) exceeds the
    trail's `_STAR_OFFSET` pixels along it, on both sides, by
    `_STAR_NSIGMA` noise sigmas (of such a sum) and by `_STAR_CONTRAST`
    times the trail's own: a star that outshines the trail, whose centroid
    it barely pulls.  Each is the median of three cross-sections a pixel
    apart (a hot pixel does not make a star).
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    piece = np.zeros(len(x), bool)
    steps = np.array([-1.0, 0.0, 1.0])
    n_core = 2 * _CROSS_HALF + 1
    sigma = noise * np.sqrt(n_core + n_core ** 2 / (2.0 * len(_SKY_OFFSETS)))
    for line in trails:
        on = np.flatnonzero(~piece & (line.distance(x, y) <= _HALF_WIDTH))
        if on.size == 0:
            continue
        t = ((x[on] - line.point[0]) * line.direction[0]
             + (y[on] - line.point[1]) * line.direction[1])

        def light(offset):
            cs = _cross_sections(data, mask, line, (t[:, None] + offset + steps).ravel())
            return np.median(cs.reshape(len(t), 3), axis=1)

        trail = np.fmax(light(-_STAR_OFFSET), light(_STAR_OFFSET))
        with np.errstate(invalid="ignore"):
            star = light(0.0) - trail > np.maximum(_STAR_NSIGMA * sigma, _STAR_CONTRAST * trail)
        piece[on[~star]] = True
    return piece
