# Licensed under a 3-clause BSD style license - see LICENSE.rst

"""Register many frames onto one reference: in this process, in a local pool
of worker processes, or on dask.distributed.

The reference's stars and triangles are computed once.  A bad frame does
not stop the batch: it is reported in the result, with the reason.  Output
names are fixed, and made unique, before any work; every file is written
atomically (`~astroalign_nd.io.atomic_write`), so an interrupted
night can be resumed with ``skip_existing=True``.  With ``solve='global'``
the frames' transforms are solved together (`~astroalign_nd.sequence`).
"""

from .results import FrameResult, BatchResult
from .core import register_batch
from .planning import plan_outputs
from .canvas import union_canvas
from .reference import reference_on_canvas, write_reference

__all__ = ['FrameResult', 'BatchResult', 'register_batch', 'plan_outputs', 'union_canvas',
           'reference_on_canvas', 'write_reference']
