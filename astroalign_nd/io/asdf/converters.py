# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
ASDF converters of the `astroalign_nd.transforms` models.

Each converter subclasses asdf-astropy's
``asdf_astropy.converters.transform.core.TransformConverterBase``, which
handles the properties common to every astropy model (``name``,
``inputs``/``outputs``, a user-assigned ``inverse``, ``bounding_box``,
``fixed`` and ``bounds``); the converters here only write and read the
parameters.  asdf matches Python types exactly, so each class has its own
converter and tag.
"""

import numpy as np
from asdf_astropy.converters.transform.core import TransformConverterBase

__all__ = [
    "LinearTransformConverterBase",
    "TranslationTransformConverter",
    "EuclideanTransformConverter",
    "SimilarityTransformConverter",
    "AffineTransformConverter",
]

_TAG_BASE = "asdf://astroalign-nd.org/astroalign_nd/tags"


def _scalar(model, name):
    value = getattr(model, name)
    if value.unit is not None:
        raise ValueError(
            f"{type(model).__name__}.{name} has unit {value.unit}; the astroalign_nd "
            "transforms work in pixels and are serialized without units."
        )
    array = np.asarray(value.value, dtype=float)
    if array.size != 1:
        raise ValueError(
            f"{type(model).__name__} holds {array.size} parameter sets; only a single "
            "transform (len(model) == 1) can be written to ASDF."
        )
    return float(array.ravel()[0])


def _read_number(value, tag, name):
    """
    A parameter read from a file: one finite real number.

    asdf does not validate files against their schemas on reading by
    default, so a file may hold anything; it is checked here.
    """
    if isinstance(value, (bool, np.bool_)):
        value = None
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != () or not np.isfinite(array):
        raise ValueError(
            f"the {tag} node's {name} must be one finite number; got {value!r}. The file "
            "is damaged or was not written by astroalign_nd.")
    return float(array)


def _check_values(cls, values, tag):
    """Parameter values that give a valid, invertible transform of ``cls``."""
    if "parity" in values and values["parity"] not in (1.0, -1.0):
        raise ValueError(
            f"the {tag} node's parity must be +1 (proper) or -1 (mirrored); got "
            f"{values['parity']!r}. The file is damaged or was not written by astroalign_nd.")
    if "scale" in values and not values["scale"] > 0:
        raise ValueError(
            f"the {tag} node's scale must be > 0; got {values['scale']!r}. The file is "
            "damaged or was not written by astroalign_nd.")
    if "a11" in values:
        lin = np.array([[values["a11"], values["a12"]], [values["a21"], values["a22"]]])
        with np.errstate(over="ignore", invalid="ignore"):
            det = float(np.linalg.det(lin))
            norm2 = float(np.sum(lin**2))
        if not (np.isfinite(det) and np.isfinite(norm2) and abs(det) > 1e-12 * norm2):
            raise ValueError(
                f"the {tag} node holds a singular or overflowing matrix (a11 a22 - a12 a21 "
                f"= {det:g}); it cannot map an image. The file is damaged or was not "
                "written by astroalign_nd.")


class LinearTransformConverterBase(TransformConverterBase):
    """
    Shared converter of the astroalign_nd transforms.

    Subclasses set ``tags``, ``types`` (the fully qualified class name, so
    that the model module is imported only when a model is read or
    written) and ``_class_name``.  Every parameter of the model is written
    as a plain number and every one is required on reading.
    """

    _class_name = None

    @property
    def _model_class(self):
        from astroalign_nd import transforms

        return getattr(transforms, self._class_name)

    def to_yaml_tree_transform(self, model, tag, ctx):
        """
        Convert the model's parameters to a dictionary of numbers.

        Parameters
        ----------
        model : `~astroalign_nd.transforms.LinearTransform2D`
            The transform to write.
        tag : str
            The tag being written.
        ctx : ``asdf.extension.SerializationContext``
            The serialization context.

        Returns
        -------
        node : dict
            ``{parameter name: float}``.
        """
        return {name: _scalar(model, name) for name in model.param_names}

    def from_yaml_tree_transform(self, node, tag, ctx):
        """
        Build the model from its parameters.

        Parameters
        ----------
        node : dict
            The tagged node read from the file.
        tag : str
            The tag being read.
        ctx : ``asdf.extension.SerializationContext``
            The serialization context.

        Returns
        -------
        model : `~astroalign_nd.transforms.LinearTransform2D`
            The transform.
        """
        cls = self._model_class
        missing = [name for name in cls.param_names if name not in node]
        if missing:
            raise ValueError(
                f"the {tag} node has no {', '.join(missing)}; every parameter of "
                f"{cls.__name__} ({', '.join(cls.param_names)}) is required."
            )
        values = {name: _read_number(node[name], tag, name) for name in cls.param_names}
        _check_values(cls, values, tag)
        return cls(**values)


class TranslationTransformConverter(LinearTransformConverterBase):
    """ASDF converter of `~astroalign_nd.transforms.TranslationTransform`."""

    tags = (f"{_TAG_BASE}/translation_transform-1.*",)
    types = ("astroalign_nd.transforms.TranslationTransform",)
    _class_name = "TranslationTransform"


class EuclideanTransformConverter(LinearTransformConverterBase):
    """ASDF converter of `~astroalign_nd.transforms.EuclideanTransform`."""

    tags = (f"{_TAG_BASE}/euclidean_transform-1.*",)
    types = ("astroalign_nd.transforms.EuclideanTransform",)
    _class_name = "EuclideanTransform"


class SimilarityTransformConverter(LinearTransformConverterBase):
    """ASDF converter of `~astroalign_nd.transforms.SimilarityTransform`."""

    tags = (f"{_TAG_BASE}/similarity_transform-1.*",)
    types = ("astroalign_nd.transforms.SimilarityTransform",)
    _class_name = "SimilarityTransform"


class AffineTransformConverter(LinearTransformConverterBase):
    """ASDF converter of `~astroalign_nd.transforms.AffineTransform`."""

    tags = (f"{_TAG_BASE}/affine_transform-1.*",)
    types = ("astroalign_nd.transforms.AffineTransform",)
    _class_name = "AffineTransform"
