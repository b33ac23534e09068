# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The ASDF extension of astroalign_nd.

`get_extensions` and `get_resource_mappings` are the targets of the
``asdf.extensions`` and ``asdf.resource_mappings`` entry points declared in
``pyproject.toml``.  Both build their objects when asdf calls them, not at
import, so loading this module is cheap.
"""

import importlib.resources

__all__ = [
    "ASTROALIGN_ND_MANIFEST_URIS",
    "ASTROALIGN_ND_TAG_URIS",
    "get_converters",
    "get_extensions",
    "get_resource_mappings",
]

_URI_BASE = "asdf://astroalign-nd.org/astroalign_nd"

#: Manifests of the extension, newest first (asdf writes with the first; files
#: written with an older one, 1.0.0 without the non-linear models, still read).
ASTROALIGN_ND_MANIFEST_URIS = [
    f"{_URI_BASE}/manifests/astroalign_nd-1.1.0",
    f"{_URI_BASE}/manifests/astroalign_nd-1.0.0",
]

#: Tag of each transform class in the current manifest.
ASTROALIGN_ND_TAG_URIS = {
    "TranslationTransform": f"{_URI_BASE}/tags/translation_transform-1.0.0",
    "EuclideanTransform": f"{_URI_BASE}/tags/euclidean_transform-1.0.0",
    "SimilarityTransform": f"{_URI_BASE}/tags/similarity_transform-1.0.0",
    "AffineTransform": f"{_URI_BASE}/tags/affine_transform-1.0.0",
    "ProjectiveTransform": f"{_URI_BASE}/tags/projective_transform-1.0.0",
    "PolynomialTransform": f"{_URI_BASE}/tags/polynomial_transform-1.0.0",
}


def get_converters():
    """
    Build the converters of the astroalign_nd transforms.

    Returns
    -------
    converters : list of ``asdf.extension.Converter``
        One ``astroalign_nd.io.asdf.converters.TransformConverter`` per
        transform class (the table ``converters._TABLE``).
    """
    from .converters import _TABLE, TransformConverter

    return [TransformConverter(*row) for row in _TABLE]


def get_extensions():
    """
    Build the astroalign_nd ASDF extensions.

    This function is registered with the ``asdf.extensions`` entry point.
    It needs the resources of `get_resource_mappings` to be registered
    with asdf (the ``asdf.resource_mappings`` entry point does that).

    Returns
    -------
    extensions : list of ``asdf.extension.ManifestExtension``
        One extension per manifest in `ASTROALIGN_ND_MANIFEST_URIS`.
    """
    from asdf.extension import ManifestExtension

    converters = get_converters()
    return [
        ManifestExtension.from_uri(uri, converters=converters)
        for uri in ASTROALIGN_ND_MANIFEST_URIS
    ]


def get_resource_mappings():
    """
    Map the astroalign_nd schema and manifest URIs to the package files.

    This function is registered with the ``asdf.resource_mappings`` entry
    point.

    Returns
    -------
    mappings : list of ``asdf.resource.DirectoryResourceMapping``
        The mappings of the ``schemas`` and ``manifests`` directories.
    """
    from asdf.resource import DirectoryResourceMapping

    root = importlib.resources.files(__package__) / "resources"
    return [
        DirectoryResourceMapping(root / "schemas", f"{_URI_BASE}/schemas", recursive=True),
        DirectoryResourceMapping(root / "manifests", f"{_URI_BASE}/manifests"),
    ]
