# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Kept so that code written for earlier releases still runs: these names now
live in `astroalign_nd.resample`.
"""

from .resample import apply_transform

__all__ = ['apply_transform']
