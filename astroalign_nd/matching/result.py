# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The result of a match: the model, the matched pairs and their quality."""

from collections.abc import MutableMapping
from dataclasses import dataclass, field
import numpy as np

__all__ = ['MatchResult']


@dataclass
class MatchResult:
    """
    The outcome of matching two star lists.

    Attributes
    ----------
    transform : `~astroalign_nd.transforms.LinearTransform2D`
        The fitted source-to-target transform.
    source_index, target_index : ndarray of int
        Indices of the matched stars in the source and target point lists.
    residuals : (K, 2) ndarray
        ``transform(source) - target`` for the matched stars, in pixels.
    rms : float
        Root-mean-square residual distance in target pixels.
    covariance : ndarray
        Covariance of the transform's free parameters.
    log10_false_alarm : float
        log10 of the probability that this many stars match by chance
        (including a trials factor for the hypotheses tried).
    n_source, n_target : int
        Number of points in each list.
    n_triangle_matches : int
        Candidate triangle matches found in invariant space.
    n_hypotheses : int
        Hypotheses scored before the answer was accepted.
    model_misfit : float
        Largest difference (pixels) over the target frame between the
        transform and an affine fit of the same stars, when the affine fit
        is significantly better (0 otherwise).
    predicted_error : float
        Largest 1-sigma position error (pixels) over the target frame,
        propagated from the covariance.
    error_bound : float
        How far off (pixels, 3 sigma) the match's own stars say it can be
        over the overlap: the largest of leave-one-out, an affine fit of the
        same stars and the covariance.  Matches above
        ``min(tolerance, 3)`` px are refused; above 1 px a
        `~astroalign_nd.PoorFitWarning` is issued.
    source_points, target_points : (K, 2) ndarray
        The matched positions (``source_index`` and ``target_index`` rows
        of the point lists).
    n_sources_used : int or None
        The control points of the successful attempt of
        `~astroalign_nd.find_match` (None from ``match_points``).
    extra : dict-like
        The five attributes above, by name (read and write), for code
        written when they were keys of a dict.

    Examples
    --------
    `match_points` (and `~astroalign_nd.find_match`) return one:

    >>> import numpy as np
    >>> from astroalign_nd.matching import match_points
    >>> rng = np.random.default_rng(0)
    >>> src = rng.uniform(0, 200, (40, 2))
    >>> result = match_points(src, src + [10.0, -5.0])
    >>> result.n_matches, result.source_points.shape
    (40, (40, 2))
    >>> bool(result.rms < 1e-6), bool(result.log10_false_alarm < -6)
    (True, True)
    >>> sorted(result.extra)[:2]
    ['model_misfit', 'predicted_error']
    """

    transform: object
    source_index: np.ndarray
    target_index: np.ndarray
    residuals: np.ndarray
    rms: float
    covariance: np.ndarray
    log10_false_alarm: float
    n_source: int
    n_target: int
    n_triangle_matches: int
    n_hypotheses: int
    model_misfit: float = 0.0
    predicted_error: float = 0.0
    error_bound: float = 0.0
    source_points: np.ndarray = None
    target_points: np.ndarray = None
    n_sources_used: int = None
    _other: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n_matches(self):
        """Number of matched stars used in the final fit."""
        return len(self.source_index)

    @property
    def extra(self):
        """The attributes that used to be the keys of a dict ``extra`` (a live view)."""
        return _ExtraView(self)


class _ExtraView(MutableMapping):
    """``MatchResult.extra``: its fields by name; other keys are kept aside."""

    _FIELDS = ("model_misfit", "predicted_error", "source_points", "target_points",
               "n_sources_used")

    def __init__(self, result):
        self._result = result

    def _keys(self):
        return [k for k in self._FIELDS if getattr(self._result, k) is not None] + list(
            self._result._other)

    def __getitem__(self, key):
        if key in self._FIELDS and getattr(self._result, key) is not None:
            return getattr(self._result, key)
        return self._result._other[key]

    def __setitem__(self, key, value):
        if key in self._FIELDS:
            setattr(self._result, key, value)
        else:
            self._result._other[key] = value

    def __delitem__(self, key):
        if key in self._FIELDS:
            setattr(self._result, key, None)
        else:
            del self._result._other[key]

    def __iter__(self):
        return iter(self._keys())

    def __len__(self):
        return len(self._keys())
