# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Simulated star fields, image pairs, sequences and catalogs with a known
ground truth.

These functions produce realistic test data for the registration code, its
tests, documentation and benchmarks:

* `render_stars` adds pixel-integrated point-spread functions to an image,
  fast enough for tens of thousands of stars;
* `simulate_image` makes one noisy CCD-like frame (sky background, optional
  gradient, stars, Poisson and read noise, saturation, hot pixels and cosmic
  rays) from a list of star positions;
* `simulate_field` draws a random star field and renders it;
* `simulate_pair` draws a star field, maps it through a (random or given)
  source -> target transform and renders both frames, returning the images,
  the true transform and the per-frame star catalogs in a `SimulatedPair`;
* `simulate_sequence` makes a dithered run of frames to stack, and
  `add_satellite_trail` crosses a frame with a trail;
* `simulate_views` renders one sky through known transforms (from
  `mosaic_transforms` or `dither_transforms`), for the global solution;
* `simulate_night` makes a night of frames whose seeing, transparency and
  trailing vary, for frame quality and weights;
* `bayer_mosaic` makes a raw one-shot-colour frame (a Bayer mosaic);
* `simulate_catalogs` makes two catalogs of one field, for cross-matching.

The modules: ``stars`` (rendering, single frames, star fields and the
argument checks), ``pairs``, ``sequences`` and ``catalogs``.

Conventions are those of the rest of the package: positions are 0-based
``(x, y)`` with ``x`` the column index, pixel ``(i, j)`` (row ``i``, column
``j``) covers ``x`` in ``[j - 0.5, j + 0.5]`` and ``y`` in
``[i - 0.5, i + 0.5]``, image shapes are numpy's ``(ny, nx)``, and transforms
map *source* pixel coordinates to *target* pixel coordinates.

Every random draw comes from ``numpy.random.default_rng(seed)``: the same
``seed`` gives bit-identical arrays and tables.
"""

from astroalign_nd.simulate.catalogs import SimulatedCatalogs, simulate_catalogs
from astroalign_nd.simulate.pairs import SimulatedPair, simulate_pair
from astroalign_nd.simulate.sequences import (
    SimulatedSequence, SimulatedViews, add_satellite_trail, dither_transforms,
    mosaic_transforms, simulate_night, simulate_sequence, simulate_views,
)
from astroalign_nd.simulate.stars import (
    bayer_mosaic, draw_fluxes, render_stars, simulate_field, simulate_image,
)

__all__ = [
    "SimulatedPair",
    "render_stars",
    "simulate_image",
    "simulate_field",
    "simulate_pair",
    "draw_fluxes",
    "simulate_sequence",
    "SimulatedSequence",
    "add_satellite_trail",
    "SimulatedCatalogs",
    "simulate_catalogs",
    "SimulatedViews",
    "simulate_views",
    "mosaic_transforms",
    "dither_transforms",
    "simulate_night",
    "bayer_mosaic",
]
