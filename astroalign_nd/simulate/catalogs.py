# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
`simulate_catalogs`: two star catalogs of one field related by a known
transform, with position noise, missing and spurious rows (for cross-matching).
"""

from dataclasses import dataclass

import numpy as np
from astropy.table import Table

from astroalign_nd.transforms.linear import LinearTransform2D, SimilarityTransform
from astroalign_nd.simulate.stars import (
    _check_count, _check_flux_range, _check_real, _check_shape, _draw_fluxes, _spawn,
    _star_table,
)

__all__ = ["SimulatedCatalogs", "simulate_catalogs"]


@dataclass(eq=False)
class SimulatedCatalogs:
    """
    Two star catalogs of one field with a known source-to-target transform.

    Attributes
    ----------
    source, target : `~astropy.table.Table`
        Columns ``x``, ``y`` (pixels), ``flux`` and ``id`` (the star's
        identifier, -1 for a spurious entry), brightest first.
    transform : `~astroalign_nd.transforms.SimilarityTransform`
        The true source-to-target transform.
    n_true_pairs : int
        Stars present in both catalogs (entries with the same ``id``).

    Examples
    --------
    `simulate_catalogs` makes one; the truth maps a star's source position
    onto its target position, to the noise:

    >>> import numpy as np
    >>> from astroalign_nd.simulate import simulate_catalogs
    >>> cats = simulate_catalogs(500, noise=0.0, seed=3)
    >>> src = cats.source[cats.source["id"] == 7]
    >>> dst = cats.target[cats.target["id"] == 7]
    >>> bool(np.allclose(cats.transform(src["x"], src["y"]), (dst["x"], dst["y"])))
    True
    """

    source: Table
    target: Table
    transform: LinearTransform2D
    n_true_pairs: int


def _catalog_rows(rng, xy, flux, ids, noise, n_spurious, box, lo, hi, alpha):
    """A catalog: the given stars with position noise, plus spurious entries in ``box``."""
    x0, x1, y0, y1 = box
    sx = rng.uniform(x0, x1, n_spurious)
    sy = rng.uniform(y0, y1, n_spurious)
    x = np.concatenate([xy[:, 0], sx]) + rng.normal(0.0, noise, len(ids) + n_spurious)
    y = np.concatenate([xy[:, 1], sy]) + rng.normal(0.0, noise, len(ids) + n_spurious)
    f = np.concatenate([flux, _draw_fluxes(rng, n_spurious, lo, hi, alpha)])
    # Photometric noise: the two epochs do not rank the stars quite alike.
    f = f * np.exp(rng.normal(0.0, 0.05, f.size))
    return _star_table(x, y, f, np.concatenate([ids, np.full(n_spurious, -1)]))


def simulate_catalogs(n_stars=10_000, *, shape=(4096, 4096), rotation=None, scale=None,
                      noise=0.1, missing_fraction=0.2, spurious_fraction=0.1,
                      flux_range=(300.0, 3e5), flux_index=1.5, seed=None):
    """
    Simulate two catalogs of one star field related by a similarity transform.

    ``n_stars`` stars are drawn uniformly over a ``shape`` frame; each
    catalog loses a random ``missing_fraction`` of them (independently),
    gains ``spurious_fraction * n_stars`` entries at random positions, and
    measures every position with Gaussian noise of ``noise`` pixels per
    axis.  The target catalog holds the stars' positions mapped through the
    transform (the whole mapped frame: nothing is cropped), so about
    ``(1 - missing_fraction)**2 * n_stars`` true pairs exist.

    Parameters
    ----------
    n_stars : int, optional
        Stars of the field.
    shape : (int, int), optional
        The source frame ``(ny, nx)``.
    rotation : float, optional
        Degrees; uniform in [-180, 180) by default.
    scale : float, optional
        Log-uniform in [0.8, 1.25] by default.
    noise : float, optional
        Position noise per axis (pixels, each catalog in its own frame).
    missing_fraction, spurious_fraction : float, optional
        As above.
    flux_range, flux_index
        The luminosity function (`draw_fluxes`).
    seed : int, `numpy.random.Generator` or None, optional
        Random seed; the same seed gives identical catalogs.

    Returns
    -------
    `SimulatedCatalogs`

    Examples
    --------
    >>> from astroalign_nd.simulate import simulate_catalogs
    >>> cats = simulate_catalogs(2000, seed=1)
    >>> cats.source.colnames
    ['x', 'y', 'flux', 'id']
    >>> bool(abs(cats.n_true_pairs - 0.64 * 2000) < 100)
    True
    """
    n_stars = _check_count(n_stars, "n_stars")
    shape = _check_shape(shape)
    noise = _check_real(noise, "noise", minimum=0.0)
    missing = _check_real(missing_fraction, "missing_fraction", minimum=0.0, maximum=1.0,
                          strict_max=True)
    spurious = _check_real(spurious_fraction, "spurious_fraction", minimum=0.0)
    (lo, hi), alpha = _check_flux_range(flux_range, flux_index)
    rng_field, rng_src, rng_dst = _spawn(seed, 3)
    ny, nx = shape
    rot = rng_field.uniform(-180.0, 180.0) if rotation is None else float(rotation)
    sc = (float(np.exp(rng_field.uniform(np.log(0.8), np.log(1.25)))) if scale is None
          else float(scale))
    shift = rng_field.uniform(-0.1, 0.1, 2) * (nx, ny)
    truth = SimilarityTransform(scale=sc, rotation=rot, translation_x=shift[0],
                                translation_y=shift[1])
    xy = np.column_stack([rng_field.uniform(-0.5, nx - 0.5, n_stars),
                          rng_field.uniform(-0.5, ny - 0.5, n_stars)])
    flux = _draw_fluxes(rng_field, n_stars, lo, hi, alpha)
    ids = np.arange(n_stars)
    keep_src = rng_src.random(n_stars) >= missing
    keep_dst = rng_dst.random(n_stars) >= missing
    n_spur = int(round(spurious * n_stars))
    src = _catalog_rows(rng_src, xy[keep_src], flux[keep_src], ids[keep_src], noise, n_spur,
                        (-0.5, nx - 0.5, -0.5, ny - 0.5), lo, hi, alpha)
    mapped = np.column_stack(truth(xy[:, 0], xy[:, 1]))
    # Spurious target entries over the mapped frame: uniform source-frame points, mapped.
    box = np.column_stack([rng_dst.uniform(-0.5, nx - 0.5, n_spur),
                           rng_dst.uniform(-0.5, ny - 0.5, n_spur)])
    spur = np.column_stack(truth(box[:, 0], box[:, 1]))
    dst = _catalog_rows(rng_dst, np.concatenate([mapped[keep_dst], spur]),
                        np.concatenate([flux[keep_dst], _draw_fluxes(rng_dst, n_spur, lo, hi,
                                                                     alpha)]),
                        np.concatenate([ids[keep_dst], np.full(n_spur, -1)]), noise, 0,
                        (0.0, 1.0, 0.0, 1.0), lo, hi, alpha)
    return SimulatedCatalogs(src, dst, truth, int(np.sum(keep_src & keep_dst)))
