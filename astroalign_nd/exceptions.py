# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""Exceptions and warnings raised by astroalign_nd."""

from __future__ import annotations

import os
import sys
import warnings

from astropy.utils.exceptions import AstropyUserWarning

__all__ = [
    "AstroalignError",
    "TooFewSourcesError",
    "TransformNotFoundError",
    "PoorCoverageError",
    "AstroalignWarning",
    "PoorFitWarning",
    "SlowKernelsWarning",
]


class AstroalignError(Exception):
    """
    Base class of every registration failure raised by astroalign_nd.

    Examples
    --------
    One ``except`` clause catches every way a registration can fail:

    >>> import numpy as np
    >>> from astroalign_nd import find_transform
    >>> from astroalign_nd.exceptions import AstroalignError
    >>> blank = np.zeros((64, 64))
    >>> try:
    ...     find_transform(blank, blank)
    ... except AstroalignError as exc:
    ...     print(type(exc).__name__)
    TooFewSourcesError
    """


class TooFewSourcesError(AstroalignError, ValueError):
    """
    An image or catalog gave fewer sources than a transform needs.

    It is also a `ValueError`.

    Examples
    --------
    >>> from astroalign_nd.exceptions import TooFewSourcesError
    >>> from astroalign_nd.matching import match_points
    >>> try:
    ...     match_points([[0.0, 0.0], [5.0, 5.0]], [[1.0, 1.0], [6.0, 6.0]])
    ... except TooFewSourcesError as exc:
    ...     print(isinstance(exc, ValueError), "at least 3 are needed" in str(exc))
    True True
    """


class TransformNotFoundError(AstroalignError):
    """No transform was found, or none could be trusted.

    The message reports how many sources each image gave, how many
    triangle matches were tried and the best inlier count, so that the user
    can tell a sparse field from an unrelated pair.

    Examples
    --------
    Two unrelated star lists:

    >>> import numpy as np
    >>> from astroalign_nd.exceptions import TransformNotFoundError
    >>> from astroalign_nd.matching import match_points
    >>> rng = np.random.default_rng(0)
    >>> try:
    ...     match_points(rng.uniform(0, 200, (30, 2)), rng.uniform(0, 200, (30, 2)))
    ... except TransformNotFoundError as exc:
    ...     print("the source gave 30 sources and the target 30" in str(exc))
    True
    """


class PoorCoverageError(AstroalignError, ValueError):
    """
    The matched stars do not cover the frame well enough for the model asked for.

    A polynomial distortion model is only constrained where there are
    stars: `~astroalign_nd.find_transform` with
    ``transform_type='polynomial'`` refuses a degree whose terms the stars
    cannot pin down (too few of the cells of a grid over the frame hold a
    star, or too few stars per term).  The message says which, and what to
    pass instead (a lower degree, ``degree='auto'``, or more stars).  It is
    also a `ValueError`.

    Examples
    --------
    >>> from astroalign_nd.exceptions import AstroalignError, PoorCoverageError
    >>> issubclass(PoorCoverageError, AstroalignError), issubclass(PoorCoverageError, ValueError)
    (True, True)
    """


class AstroalignWarning(AstropyUserWarning):
    """
    Base class of astroalign_nd's warnings (an astropy user warning).

    Examples
    --------
    A pipeline that must not go on after a doubtful result can turn the
    package's warnings into errors:

    >>> import warnings
    >>> from astropy.utils.exceptions import AstropyUserWarning
    >>> from astroalign_nd.exceptions import AstroalignWarning, PoorFitWarning
    >>> issubclass(AstroalignWarning, AstropyUserWarning)
    True
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("error", AstroalignWarning)
    ...     try:
    ...         warnings.warn("residuals too large", PoorFitWarning)
    ...     except AstroalignWarning as exc:
    ...         print(type(exc).__name__, exc)
    PoorFitWarning residuals too large
    """


class PoorFitWarning(AstroalignWarning):
    """
    The fitted transform leaves residuals larger than the centroid noise.

    Examples
    --------
    Record the warnings of a call to inspect them afterwards (here one
    issued by hand):

    >>> import warnings
    >>> from astroalign_nd.exceptions import PoorFitWarning
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     warnings.warn("RMS 2.1 px for a centroid noise of 0.3 px", PoorFitWarning)
    >>> [w.category.__name__ for w in caught]
    ['PoorFitWarning']
    """


class SlowKernelsWarning(AstroalignWarning):
    """
    astroalign_nd's compiled loops are not built: it runs their NumPy
    versions (the same results, slower: ``register`` about 2 times as long
    at 1024 x 1024 and 4096 x 4096, see the Benchmarks page).

    Issued once per process, at the first registration, by an install from
    the source distribution without a C compiler (or with
    ``ASTROALIGN_ND_NO_EXTENSION=1``); its message gives the measured cost
    and the command that installs a binary wheel instead (``pip install
    --only-binary astroalign_nd astroalign_nd``).
    ``astroalign_nd.HAVE_COMPILED`` says which kernels run.

    Examples
    --------
    A pipeline that knows it runs without the compiled loops can silence it
    (here around a call, with ``warnings.catch_warnings``):

    >>> import warnings
    >>> from astroalign_nd import find_transform
    >>> from astroalign_nd.exceptions import SlowKernelsWarning
    >>> from astroalign_nd.simulate import simulate_pair
    >>> pair = simulate_pair((128, 128), n_stars=40, seed=1)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore", SlowKernelsWarning)
    ...     t, _ = find_transform(pair.source, pair.target)
    """


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn(message: str, category: type[Warning] = AstroalignWarning) -> None:
    """`warnings.warn` pointing at the user's line that called astroalign_nd."""
    # The stacklevel of the first frame outside astroalign_nd, however deep in the pipeline
    # the warning is raised (a fixed stacklevel is right for one call path only).
    frame = sys._getframe(1)  # the caller of warn()
    level = 2
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(
            _PACKAGE_DIR):
        frame = frame.f_back
        level += 1
    warnings.warn(message, category, stacklevel=level)
