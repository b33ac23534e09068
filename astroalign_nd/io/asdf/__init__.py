# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
ASDF serialization of the `astroalign_nd.transforms` models.

The extension is registered with asdf through the ``asdf.extensions`` and
``asdf.resource_mappings`` entry points (see ``astroalign_nd.io.asdf.extension``),
so once the package is installed a transform -- alone or inside an astropy
compound model -- is written and read like any other astropy model::

    import asdf
    asdf.AsdfFile({"transform": transform}).write_to("transform.asdf")
    with asdf.open("transform.asdf") as af:
        transform = af["transform"]

Nothing is imported here: asdf loads ``astroalign_nd.io.asdf.extension``
itself, only when it needs it.
"""

__all__ = []
