# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Speed of each stage on one simulated 1024x1024 pair, for airspeed velocity.

``asv run`` (from the repository root, see ``asv.conf.json``) times these
on every commit it is given, so that a slower stage shows as a step in the
history: detection (`~astroalign_nd.find_sources`), matching
(`~astroalign_nd.matching.match_points` on the detected positions),
`~astroalign_nd.find_transform`, `~astroalign_nd.register` and resampling
(`~astroalign_nd.resample.resample` with the true matrix, bilinear and
bicubic, and `~astroalign_nd.apply_transform` with its CCDData output).
Only public names are used, so that older commits run the same code.

The pair: 1,000 stars, rotated by 30 degrees, scaled by 1.02 and shifted,
Gaussian noise, float32 (seeded: every commit sees the same pixels).
"""

import warnings

import numpy as np

SIZE = 1024
N_STARS = 1000


def _pair():
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((SIZE, SIZE), n_stars=N_STARS, rotation=30.0, scale=1.02,
                         translation=(25.0, -40.0), noise="gaussian", seed=1)
    return (np.asarray(pair.source, np.float32), np.asarray(pair.target, np.float32),
            np.asarray(pair.truth_matrix, float))


class Stages:
    """The stages of ``register`` on one 1024x1024 pair."""

    timeout = 180.0

    def setup_cache(self):
        # Simulated once per environment; asv passes it to setup and every benchmark.
        return _pair()

    def setup(self, pair):
        from astroalign_nd import find_sources

        warnings.simplefilter("ignore")  # a poor-fit warning must not fail a timing
        self.source, self.target, self.matrix = pair
        self.src_xy = self._positions(find_sources(self.source))
        self.dst_xy = self._positions(find_sources(self.target))

    @staticmethod
    def _positions(table, n=50):
        return np.column_stack([table["x"], table["y"]])[:n]

    def time_detect(self, pair):
        from astroalign_nd import find_sources

        find_sources(self.source)

    def time_match(self, pair):
        from astroalign_nd.matching import match_points

        match_points(self.src_xy, self.dst_xy)

    def time_find_transform(self, pair):
        from astroalign_nd import find_transform

        find_transform(self.source, self.target)

    def time_register(self, pair):
        from astroalign_nd import register

        register(self.source, self.target)

    def peakmem_register(self, pair):
        from astroalign_nd import register

        register(self.source, self.target)


class Resample:
    """Resampling one 1024x1024 float32 frame through the pair's true matrix."""

    params = ["bilinear", "bicubic"]
    param_names = ["order"]
    timeout = 120.0

    def setup_cache(self):
        return _pair()

    def setup(self, pair, order):
        self.source, self.target, self.matrix = pair

    def time_resample(self, pair, order):
        from astroalign_nd.resample import resample

        resample(self.source, self.matrix, self.target.shape, order=order)

    def time_apply_transform(self, pair, order):
        from astroalign_nd import apply_transform

        apply_transform(self.matrix, self.source, self.target, order=order)
