# Licensed under a 3-clause BSD style license - see LICENSE.rst

"""Resampling of a source image onto the pixel grid of a target image.

`resample` interpolates a source image at the positions of the target
pixels, given the *source -> target* pixel transform: the 3x3 homogeneous
matrix of an affine transform (the ``matrix`` of the transforms in
`astroalign_nd.transforms`), or any 2-in 2-out model (projective,
polynomial, an astropy compound model...) that has an ``inverse``.
In the same pass it propagates a per-pixel variance image and a bad-pixel
mask, so the three outputs are always consistent with each other.

`resample_exact` does the same through `reproject.reproject_exact`
(flux-conserving spherical-polygon overlap), which is slower but exact for
the drizzle-like "how much of each source pixel falls into each target
pixel" question.

Conventions
-----------
Pixel coordinates are 0-based with pixel centres at integers, ``x`` along
columns and ``y`` along rows, as everywhere in this package.  For an
output (target) pixel ``(x', y')`` the source position is
``(x, y) = A^-1 ((x', y') - t)`` where ``A`` and ``t`` are the linear part and
the translation of ``matrix``.

Non-linear transforms
---------------------
A model that is not affine (or a projective 3x3 matrix) is resampled
through a *coordinate map*: the source position of every target pixel,
computed one band of output rows at a time (``_MAP_BAND_PIXELS`` pixels, a
few MB) and shared by all channels.  The model's ``inverse`` gives the first
guess; the forward model checks it, and positions whose round trip misses by
more than 1e-6 px (a fitted inverse, as SIP's AP/BP terms are) get Newton
steps on the forward model, at most 4: the first with the Jacobian of the
inverse map from differences between neighbouring target pixels (no model
evaluation), the next ones with the forward model's, by finite differences.  A
position still off by more than 1e-4 px (no source position: outside the
region where the model can be inverted), or NaN, gives a masked output
pixel.  The compiled kernel then interpolates data, variance and mask from
the map with the same kernels, footprint and mask rules as below.  A linear
model always takes the affine path (same bits as its matrix).

Interpolation kernels
---------------------
All kernels are separable (``w_ij = wy_i * wx_j``), local and interpolating
(a source position on a pixel centre returns that pixel's value exactly):

``'nearest-neighbor'`` (0)
    The pixel at ``floor(x + 0.5)`` (ties round up).
``'bilinear'`` (1)
    Linear interpolation between the 2 pixels ``floor(x)``, ``floor(x) + 1``.
``'biquadratic'`` (2)
    Dodgson's (1997) interpolating quadratic kernel on the 3 pixels around
    ``c = floor(x + 0.5)``: with ``t = x - c`` in ``[-0.5, 0.5)`` the weights
    of pixels ``c - 1, c, c + 1`` are ``t (t - 1/2)``, ``1 - 2 t^2``,
    ``t (t + 1/2)``.  It reproduces constants and straight lines.
``'bicubic'`` (3)
    Keys (1981) cubic convolution with ``a = -0.5`` on the 4 pixels
    ``floor(x) - 1 ... floor(x) + 2`` (third-order accurate, interpolating;
    *not* the B-spline of `scipy.ndimage`, which is not local).

Footprint and mask rules
------------------------
A source pixel is *used* by an output pixel when its weight is nonzero
(so a position exactly on a pixel centre uses that single pixel for every
order, and bilinear at ``x = 2.5`` uses two pixels whatever the order of
the other axis).  An output pixel is *bad* -- ``mask_out`` True, data set to
``fill_value``, variance set to ``+inf`` -- when

* any pixel it would use lies outside the source image (so near the edges
  the valid region shrinks by the kernel half-width: for bilinear a source
  position must satisfy ``0 <= x <= nx - 1``; for nearest-neighbour the
  whole pixel area ``-0.5 <= x <= nx - 0.5`` is accepted);
* any pixel it uses is flagged in ``mask``, or is NaN/inf in ``data`` (any
  channel: the mask is shared by all channels) or in ``variance``.  A
  bicubic kernel therefore spreads one bad source pixel to up to 4x4 output
  pixels (3x3 for biquadratic, 2x2 for bilinear, 1 for nearest, at
  magnification 1);
* the interpolated value or variance is not finite (overflow).

(Internally masked pixels are set to NaN and an output pixel is bad exactly
when its weighted sum is not finite, which implements the two rules above.)

Variance
--------
``variance_out = sum_ij w_ij**2 var_ij``: exact for the variance of each
output pixel given independent input pixels.  Resampling however makes
neighbouring *output* pixels correlated (they share input pixels), and this
covariance is not returned: summing ``variance_out`` over a large aperture
underestimates the variance of the aperture sum, at unit scale and averaged
over sub-pixel phases by a factor ~2.25 for bilinear, ~1.6 for biquadratic
and ~1.5 for bicubic (1 for nearest-neighbour, which copies pixels).

Flux conservation
-----------------
By default (``conserve_flux=False``) the output is a *surface brightness*
resampling: a flat sky of 100 counts/pixel stays 100.  With
``conserve_flux=True`` the output is multiplied by ``1 / |det A|`` (the
ratio target-pixel area / source-pixel area, measured in source pixels) so
that total counts are preserved: a transform that magnifies by ``s``
spreads each star over ``s**2`` more pixels, each holding ``1 / s**2`` of
the counts.  The variance is multiplied by ``1 / det(A)**2``.  Through a
coordinate map the factor is the local ``|det|`` of the map's Jacobian
(central differences between neighbouring target pixels), pixel by pixel.

Names are imported on first use (``astroalign_nd._lazy``): reading the
options class (`ResampleConfig`) does not import the stage.
"""

from .._lazy import attach

# submodule (relative, as in an import) -> the public names it defines
_LAZY = {
    ".options": ["ORDERS", "METHODS", "order_index", "ResampleConfig"],
    ".core": ["resample", "working_dtype"],
    ".exact": ["resample_exact"],
    ".nddata": ["apply_transform"],
}

__getattr__, __dir__, __all__ = attach(__name__, _LAZY)
del attach
