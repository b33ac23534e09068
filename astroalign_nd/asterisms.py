# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Kept so that code written for earlier releases still runs: these names now
live in `astroalign_nd.matching`.
"""

from .matching import Asterisms, build_asterisms, check_triangle_budget

__all__ = ['Asterisms', 'build_asterisms', 'check_triangle_budget']
