# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Kept so that code written for earlier releases still runs: these names now
live in `astroalign_nd.transforms`.
"""

from .transforms import ProjectiveTransform, PolynomialTransform

__all__ = ['ProjectiveTransform', 'PolynomialTransform']
