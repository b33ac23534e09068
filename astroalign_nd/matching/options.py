# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
How the triangles are matched and a match verified: `MatchingConfig`, the
settings of `~astroalign_nd.matching.match_points` (each default, range,
message and flag once, in the package's checking system,
``astroalign_nd.options``).
"""

import dataclasses

from ..options import Bool, Int, Pair, Real, check_fields, option

__all__ = ["MatchingConfig", "DEFAULT_TOLERANCE", "DEFAULT_NEIGHBORS"]

#: `~astroalign_nd.matching.match_points`' matching radius (pixels); a
#: registration's search widens it for wide stars (`MatchingConfig`'s ``tolerance``).
DEFAULT_TOLERANCE = 3.0

#: Neighbours per star of `~astroalign_nd.matching.match_points`' triangles;
#: a registration tries 6 and 8 for sparse lists (`MatchingConfig`'s ``n_neighbors``).
DEFAULT_NEIGHBORS = 4


@dataclasses.dataclass(frozen=True)
class MatchingConfig:
    """
    How the triangles are matched and a match verified (the settings of
    `~astroalign_nd.matching.match_points`).

    Parameters
    ----------
    tolerance : float, optional
        Matching radius (target pixels) while searching.  None: a
        registration's search uses the larger of ``DEFAULT_TOLERANCE`` and
        half the target stars' FWHM.
    min_tolerance : float, optional
        Smallest radius the refinement may shrink to.
    invariant_radius : float, optional
        Radius of triangle matches in (log) invariant space.
    n_neighbors : int, optional
        Neighbours per star of the triangles.  None: ``DEFAULT_NEIGHBORS``,
        and a registration tries more for sparse star lists.
    allow_mirror : bool, optional
        Consider mirrored solutions.
    scale_range : (float, float), optional
        Allowed source-to-target scale.
    max_false_alarm : float, optional
        Largest accepted probability that the match is chance.
    accept_matches : int, optional
        Early acceptance once a hypothesis has this many matched stars.
    batch_size, max_hypotheses : int, optional
        Hypotheses scored per batch, and at most in total.

    Examples
    --------
    >>> from astroalign_nd.matching import MatchingConfig
    >>> cfg = MatchingConfig(tolerance=2)
    >>> cfg.tolerance, cfg.max_false_alarm
    (2.0, 1e-06)
    >>> sorted(cfg.match_kwargs())[:3]
    ['accept_matches', 'allow_mirror', 'batch_size']
    """

    tolerance: float | None = option(
        None, Real(0, 1e6, lo_open=True, unit="pixels"), auto=True,
        help="largest distance (px) for a star to count as matched",
        flag="--tolerance", type=float, metavar="PX")
    min_tolerance: float = option(0.5, Real(0, 1e6, lo_open=True, unit="pixels"))
    invariant_radius: float = option(0.1, Real(0, 10, lo_open=True))
    n_neighbors: int | None = option(None, Int(2, 16), auto=True)
    scale_range: tuple | None = option(None, Pair(Real(0, lo_open=True)))
    max_false_alarm: float = option(
        1e-6, Real(0, 1, lo_open=True),
        "largest false-alarm probability accepted (default: {default})",
        flag="--max-false-alarm", type=float, metavar="P", cli_default=None)
    allow_mirror: bool = option(
        True, Bool(), "do not consider mirrored (flipped) solutions",
        flag="--no-mirror", action="store_false", cli_default=None)
    accept_matches: int = option(10, Int(3, None))
    batch_size: int = option(512, Int(1, 1_000_000))
    max_hypotheses: int = option(20_000, Int(1, 10_000_000))

    def __post_init__(self):
        check_fields(self)

    def match_kwargs(self):
        """
        The keywords of `~astroalign_nd.matching.match_points` (its defaults
        for the fields left to the search: ``tolerance``, ``n_neighbors``).
        """
        kwargs = dataclasses.asdict(self)
        if kwargs["tolerance"] is None:
            kwargs["tolerance"] = DEFAULT_TOLERANCE
        if kwargs["n_neighbors"] is None:
            kwargs["n_neighbors"] = DEFAULT_NEIGHBORS
        return kwargs
