# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The ASDF extension of astroalign_nd.

`get_extensions` and `get_resource_mappings` are the targets of the
``asdf.extensions`` and ``asdf.resource_mappings`` entry points declared in
``pyproject.toml``.  Loading this module is cheap: the converters come from
the transform registry, which names the model classes by import path; they
are imported when a model is read or written.
"""

import importlib.resources

from asdf.extension import ManifestExtension
from asdf.resource import DirectoryResourceMapping

from astroalign_nd.transforms.registry import TRANSFORM_REGISTRY
from .converters import CONVERTERS

__all__ = [
    "ASTROALIGN_ND_MANIFEST_URIS",
    "ASTROALIGN_ND_TAG_URIS",
    "get_converters",
    "get_extensions",
    "get_resource_mappings",
]

_URI_BASE = "asdf://astroalign-nd.org/astroalign_nd"


def _version(stem):
    return tuple(int(v) for v in stem.split("-")[-1].split("."))


#: Manifests of the extension, newest first (asdf writes with the first; files
#: written with an older one, 1.0.0 without the non-linear models, still read).
#: Read from the package's manifest files (``resources/manifests``): a new
#: manifest needs no edit here.
ASTROALIGN_ND_MANIFEST_URIS = [
    f"{_URI_BASE}/manifests/{stem}" for stem in sorted(
        (f.name[:-len(".yaml")]
         for f in (importlib.resources.files(__package__) / "resources" / "manifests").iterdir()
         if f.name.startswith("astroalign_nd-") and f.name.endswith(".yaml")),
        key=_version, reverse=True)]

#: Tag of each transform class in the current manifest (the built-in types of
#: the registry; a test checks them against the manifest).
ASTROALIGN_ND_TAG_URIS = {
    entry.class_path.rsplit(".", 1)[-1]: f"{_URI_BASE}/tags/{entry.asdf_tag}-1.0.0"
    for entry in TRANSFORM_REGISTRY.values() if entry.asdf_tag
}


def get_converters():
    """
    Build the converters of the astroalign_nd transforms.

    Returns
    -------
    converters : list of ``asdf.extension.Converter``
        One ``astroalign_nd.io.asdf.converters.TransformConverter`` per
        registered transform type with an ASDF tag (``converters.CONVERTERS``).
    """
    return list(CONVERTERS)


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
    root = importlib.resources.files(__package__) / "resources"
    return [
        DirectoryResourceMapping(root / "schemas", f"{_URI_BASE}/schemas", recursive=True),
        DirectoryResourceMapping(root / "manifests", f"{_URI_BASE}/manifests"),
    ]
