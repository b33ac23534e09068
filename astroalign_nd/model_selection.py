# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Kept so that code written for earlier releases still runs: these names now
live in `astroalign_nd.transforms` and `astroalign_nd.matching`.
"""

from .matching import extend_match, fit_nonlinear
from .transforms import NONLINEAR_TYPES, check_degree, DistortionFit

__all__ = ['NONLINEAR_TYPES', 'check_degree', 'fit_nonlinear', 'extend_match', 'DistortionFit']
