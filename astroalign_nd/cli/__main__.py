# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""``python -m astroalign_nd.cli``: the same as the ``astroalign-nd`` command."""

import sys

from .main import main

sys.exit(main())
