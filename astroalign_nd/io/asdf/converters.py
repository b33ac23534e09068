# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
ASDF converters of the astroalign_nd transform models.

One implementation, `TransformConverter`, on asdf's public
``asdf.extension.Converter`` API, serves every model class; `CONVERTERS`
holds one per entry of the transform registry
(`~astroalign_nd.transforms.TRANSFORM_REGISTRY`) with an ASDF tag: its
class, tag and check of the values read come from the entry.  asdf matches
Python types exactly, so each class has its own converter instance and tag.

A node holds every model parameter as a plain number (for
`~astroalign_nd.PolynomialTransform` also its ``degree`` and ``domain``),
and the properties common to astropy models that the transform schemas of
asdf-transform-schemas define: ``name``, ``inputs``/``outputs``, a
user-assigned ``inverse``, ``bounding_box``, ``fixed``, ``bounds`` and
``input_units_equivalencies``.  The analytic (or fitted) inverse is not
written: it is rebuilt on reading.
"""

import importlib

import numpy as np
from asdf.extension import Converter

# The registry names its classes by import path and imports nothing heavy:
# asdf loads this module at start-up (``asdf.AsdfFile()``), and the model
# classes are imported only when a model is read or written.
from astroalign_nd.transforms.registry import TRANSFORM_REGISTRY

__all__ = ["TransformConverter", "CONVERTERS"]

_TAG_BASE = "asdf://astroalign-nd.org/astroalign_nd/tags"

_DAMAGED = "The file is damaged or was not written by astroalign_nd."


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
        raise ValueError(f"the {tag} node's {name} must be one finite number; got {value!r}. "
                         + _DAMAGED)
    return float(array)


class TransformConverter(Converter):
    """
    ASDF converter of one astroalign_nd transform class.

    Parameters
    ----------
    class_path : str
        Fully qualified name of the model class, e.g.
        ``'astroalign_nd.transforms.linear.AffineTransform'``; the module is
        imported only when a model is read or written.
    tag_name : str
        The tag's name, e.g. ``'affine_transform'`` (every ``1.*`` version
        is read).
    check : callable, optional
        ``check(values)`` raises a ValueError (that says why) if the
        parameter values read from a file do not make a usable transform.
    degrees : tuple of int, optional
        The degrees of a model that takes a ``degree`` (the polynomial's,
        which it checks itself); empty for the others.

    Examples
    --------
    >>> from asdf.extension import Converter
    >>> from astroalign_nd.io.asdf.converters import CONVERTERS
    >>> [c.types[0].rsplit(".", 1)[1] for c in CONVERTERS]  # doctest: +NORMALIZE_WHITESPACE
    ['TranslationTransform', 'EuclideanTransform', 'SimilarityTransform', 'AffineTransform',
     'ProjectiveTransform', 'PolynomialTransform']
    >>> CONVERTERS[3].tags[0]
    'asdf://astroalign-nd.org/astroalign_nd/tags/affine_transform-1.*'
    >>> all(isinstance(c, Converter) for c in CONVERTERS)
    True
    """

    def __init__(self, class_path, tag_name, check=None, degrees=()):
        self._class_path = class_path
        self._tags = (f"{_TAG_BASE}/{tag_name}-1.*",)
        self._check = check
        self._degrees = tuple(degrees)
        self._class = None

    @classmethod
    def for_type(cls, entry):
        """
        The converter of a transform type of the registry (it must have an ``asdf_tag``).

        Parameters
        ----------
        entry : `~astroalign_nd.transforms.TransformType`

        Returns
        -------
        converter : `TransformConverter`

        Examples
        --------
        >>> from astroalign_nd.io.asdf.converters import TransformConverter
        >>> from astroalign_nd.transforms import TRANSFORM_REGISTRY
        >>> TransformConverter.for_type(TRANSFORM_REGISTRY["euclidean"]).types
        ('astroalign_nd.transforms.linear.EuclideanTransform',)
        """
        if not entry.asdf_tag:
            raise ValueError(f"transform type {entry.name!r} has no asdf_tag.")

        def check(values):
            # Looked up when a file is read: resolving it imports the model's module.
            if entry.check_values is not None:
                entry.check_values(values)

        return cls(entry.class_path, entry.asdf_tag, check, entry.degrees)

    @property
    def tags(self):
        """Tag patterns read and written (every ``1.*`` version of the tag)."""
        return self._tags

    @property
    def types(self):
        """The model class, by fully qualified name."""
        return (self._class_path,)

    @property
    def model_class(self):
        """The model class (imported on first use)."""
        if self._class is None:
            module, name = self._class_path.rsplit(".", 1)
            self._class = getattr(importlib.import_module(module), name)
        return self._class

    # -- writing ---------------------------------------------------------------------------
    def to_yaml_tree(self, obj, tag, ctx):
        """
        Convert a model to a node: its parameters and the common model properties.

        Parameters
        ----------
        obj : astropy model
            The transform to write.
        tag : str
            The tag being written.
        ctx : ``asdf.extension.SerializationContext``
            The serialization context.

        Returns
        -------
        node : dict
        """
        node = {name: _scalar(obj, name) for name in obj.param_names}
        if hasattr(obj, "degree"):  # PolynomialTransform: which parameters exist
            node["degree"] = int(obj.degree)
            if obj.domain is not None:
                node["domain"] = [float(v) for v in obj.domain]
        if obj.name is not None:
            node["name"] = obj.name
        node["inputs"] = list(obj.inputs)
        node["outputs"] = list(obj.outputs)
        if obj.has_user_inverse:
            node["inverse"] = obj.inverse
        try:
            node["bounding_box"] = obj.bounding_box  # a user-assigned one: ours have no default
        except NotImplementedError:
            pass
        fixed = {k: True for k, f in obj.fixed.items() if f}
        if fixed:
            node["fixed"] = fixed
        bounds = {k: list(b) for k, b in obj.bounds.items() if any(v is not None for v in b)}
        if bounds:
            node["bounds"] = bounds
        if obj.input_units_equivalencies:
            node["input_units_equivalencies"] = obj.input_units_equivalencies
        return node

    # -- reading ---------------------------------------------------------------------------
    def from_yaml_tree(self, node, tag, ctx):
        """
        Build the model from a node.

        A node that is not a valid transform raises a ValueError that says
        what is wrong (asdf reports it as an ``AsdfConversionWarning`` and
        leaves the node unconverted, unless its ``warn_on_failed_conversion``
        setting is off).  A model with a user-assigned inverse is returned
        through a generator, so that an inverse referring back to the model
        resolves.

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
        model : astropy model, or a generator of it
            The transform.
        """
        model = self._build(node, tag)
        if "inverse" not in node:
            return model
        return self._with_inverse(model, node)

    @staticmethod
    def _with_inverse(model, node):
        yield model
        model.inverse = node["inverse"]

    def _build(self, node, tag):
        cls = self.model_class
        kwargs = {}
        if "degree" in node:
            if not self._degrees:
                raise ValueError(f"the {tag} node has a degree, which a {cls.__name__} does not "
                                 "take. " + _DAMAGED)
            try:  # (the model checks its degree)
                names = cls(degree=node["degree"]).param_names
            except (TypeError, ValueError) as exc:
                raise ValueError(f"the {tag} node's degree is not valid: {exc} " + _DAMAGED
                                 ) from None
            kwargs["degree"] = int(node["degree"])
            if node.get("domain") is not None:
                kwargs["domain"] = self._read_domain(node["domain"], tag)
        else:
            names = cls.param_names
            if self._degrees:
                raise ValueError(f"the {tag} node has no degree. " + _DAMAGED)
        missing = [name for name in names if name not in node]
        if missing:
            raise ValueError(
                f"the {tag} node has no {', '.join(missing)}; every parameter of "
                f"{cls.__name__} ({', '.join(names)}) is required.")
        extra = [k for k in node if k[:2] in ("A_", "B_") and k not in names]
        if extra:
            raise ValueError(f"the {tag} node has {extra}, terms beyond its degree "
                             f"{kwargs.get('degree')}. " + _DAMAGED)
        values = {name: _read_number(node[name], tag, name) for name in names}
        if self._check is not None:
            try:
                self._check(values)
            except ValueError as exc:
                raise ValueError(f"the {tag} node is not a valid {cls.__name__}: {exc}. "
                                 + _DAMAGED) from None
        model = cls(**kwargs, **values)

        if "name" in node:
            model.name = node["name"]
        if "inputs" in node:
            model.inputs = tuple(node["inputs"])
        if "outputs" in node:
            model.outputs = tuple(node["outputs"])
        if "bounding_box" in node:
            bbox = node["bounding_box"]
            # asdf-astropy reads a bounding box as a callable of the model; older
            # files hold a plain list of intervals.
            model.bounding_box = bbox(model) if callable(bbox) else bbox
        for key in ("fixed", "bounds"):
            unknown = [k for k in (node.get(key) or {}) if k not in names]
            if unknown:
                raise ValueError(f"the {tag} node's {key} names {unknown}, which are not "
                                 f"parameters of {cls.__name__}. " + _DAMAGED)
        for name, value in (node.get("fixed") or {}).items():
            getattr(model, name).fixed = bool(value)
        for name, value in (node.get("bounds") or {}).items():
            getattr(model, name).bounds = tuple(value)
        if node.get("input_units_equivalencies"):
            model.input_units_equivalencies = node["input_units_equivalencies"]
        return model

    @staticmethod
    def _read_domain(domain, tag):
        items = np.ravel(np.asarray(domain, dtype=object))
        values = [_read_number(v, tag, "domain") for v in items]
        if len(values) != 4 or not (values[1] > values[0] and values[3] > values[2]):
            raise ValueError(f"the {tag} node's domain must be [x_min, x_max, y_min, y_max] "
                             f"with x_max > x_min and y_max > y_min; got {domain!r}. "
                             + _DAMAGED)
        return tuple(values)


#: The converters of the extension: one per registered type with an ASDF tag.
CONVERTERS = tuple(TransformConverter.for_type(e) for e in TRANSFORM_REGISTRY.values()
                   if e.asdf_tag)
