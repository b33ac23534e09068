# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The transform types by name: one `TransformType` entry each, in `TRANSFORM_REGISTRY`.

An entry holds what the package needs to know of a type beyond its model
class: its name (the ``transform_type`` keyword, the ``AATTYPE`` header
value, the command line's ``--transform-type``), whether it is linear (the
triangle search fits it directly) or grown from a linear match (the
distortion stage), whether it carries a ``parity`` (mirrored or not), the
polynomial degrees it accepts, and its FITS-header and ASDF hooks.  Every
list of type names derives from the registry: `TRANSFORM_TYPES`,
`LINEAR_TYPES`, `NONLINEAR_TYPES`, the header's type names, the ASDF
converters and the command line's choices.

Adding a type is one module with its model class and one
`register_transform_type` call.  A linear type subclasses
`~astroalign_nd.transforms.LinearTransform2D` (its ``_from_matrix`` and
``_linear_fit``); it is then matched, fitted, stored in headers and
resampled like the others.  Only the two non-linear families the
distortion stage knows (projective, polynomial) are grown from a match.

This module imports nothing heavy: the built-in entries name their classes
and hooks by import path (``'module:attribute'``), imported on first use,
so that the names are cheap to read (``astroalign-nd --help`` lists them).
"""

from __future__ import annotations

import importlib
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

__all__ = ['TransformType', 'HeaderHooks', 'TRANSFORM_REGISTRY', 'TRANSFORM_TYPES',
           'LINEAR_TYPES', 'NONLINEAR_TYPES', 'register_transform_type',
           'unregister_transform_type', 'transform_class', 'transform_type_of', 'check_degree']


def _resolve(ref):
    """An object given as itself or as an import path ``'module:attribute'``."""
    if not isinstance(ref, str):
        return ref
    module, _, attr = ref.partition(":")
    return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True)
class HeaderHooks:
    """
    How `~astroalign_nd.io.transform_to_header` stores a type that its 3x3
    matrix does not determine (the polynomial), and how it reads it back.

    A type without hooks is stored as its ``matrix`` (``AATM00`` ...) and
    rebuilt with its ``from_matrix``.

    Attributes
    ----------
    matrix : callable
        ``matrix(model)``: the 3x3 matrix written as the ``M`` keywords.
    cards : callable
        ``cards(model)``: its other keywords, in order, as ``(suffix, value,
        comment, exact)``; ``exact`` adds a ``<suffix>S`` card holding all
        the digits.  It includes the readable cards (``TX``, ``TY``...).
    read : callable
        ``read(reader)``: the model, from a reader of the header with
        ``key(suffix)``, ``has(suffix)``, ``get(suffix)``, ``exact(suffix,
        what)`` (a number from the float card and its exact string) and
        ``matrix()`` (the ``M`` keywords).
    suffixes : tuple of str
        Every suffix ``cards`` may write: they are removed before writing,
        and the keyword prefix must leave room for the longest.

    Examples
    --------
    >>> from astroalign_nd.transforms.registry import TRANSFORM_REGISTRY
    >>> hooks = TRANSFORM_REGISTRY["polynomial"].header
    >>> hooks.suffixes[:3]
    ('DEG', 'CRP1', 'CRP1S')
    """

    matrix: Callable
    cards: Callable
    read: Callable
    suffixes: tuple


class TransformType:
    """
    One transform type of the registry.

    Parameters
    ----------
    name : str
        The ``transform_type`` name (lower case letters, digits and ``_``).
    cls : type or str
        The model class (an astropy ``Model`` with 2 inputs and 2 outputs),
        or its import path ``'module:ClassName'``, imported on first use.
    linear : bool
        True for the affine family (a
        `~astroalign_nd.transforms.LinearTransform2D` subclass, fitted by the
        triangle search); False for a model grown from a linear match.
    parity : bool, optional
        True if the model holds a fixed ``parity`` parameter (+1 or -1):
        its fits take the parity of the triangle match, and mirrored
        solutions are fitted as such.  Default: whether ``cls`` has one.
    conformal : bool, optional
        True if its linear part is a scaled rotation (translation,
        Euclidean, similarity): the header's readable cards give one scale
        and a rotation, and the distortion stage's ``degree='auto'`` also
        compares a similarity.
    degrees : tuple of int, optional
        The polynomial degrees it accepts (its ``degree`` keyword); empty
        for a type without one.
    matrix_rows : int, optional
        Rows of its 3x3 matrix stored in a header: 2 (default for a linear
        type) or 3 (the default otherwise: a homography).
    asdf_tag : str, optional
        Its ASDF tag name, e.g. ``'affine_transform'`` (the converter reads
        every ``1.*`` version); None: not serialized by the package.
    check_values : callable or str, optional
        ``check_values(values)`` raises a ValueError (that says why) if the
        parameter values read from an ASDF file do not make a usable model.
    header : `HeaderHooks` or str, optional
        For a type its matrix does not determine.

    Examples
    --------
    >>> from astroalign_nd.transforms import TRANSFORM_REGISTRY
    >>> entry = TRANSFORM_REGISTRY["similarity"]
    >>> entry.cls.__name__, entry.linear, entry.parity, entry.asdf_tag
    ('SimilarityTransform', True, True, 'similarity_transform')
    """

    def __init__(self, name: str, cls: type | str, *, linear: bool, parity: bool | None = None,
                 conformal: bool = False, degrees: tuple = (), matrix_rows: int | None = None,
                 asdf_tag: str | None = None, check_values: Callable | str | None = None,
                 header: HeaderHooks | str | None = None):
        if not isinstance(name, str) or not name or name != name.lower() or not (
                name.replace("_", "").isalnum() and name.isascii()):
            raise ValueError(f"a transform type's name must be lower case letters, digits and "
                             f"'_'; got {name!r}.")
        if not isinstance(cls, (type, str)):
            raise TypeError(f"cls must be a model class or its import path 'module:Class'; got "
                            f"{type(cls).__name__}.")
        self.name = name
        self._cls = cls
        self.linear = bool(linear)
        self._parity = parity
        self.conformal = bool(conformal)
        self.degrees = tuple(int(d) for d in degrees)
        self.matrix_rows = (2 if self.linear else 3) if matrix_rows is None else int(matrix_rows)
        self.asdf_tag = asdf_tag
        self._check_values = check_values
        self._header = header

    @property
    def cls(self) -> type:
        """The model class (imported on first use)."""
        if isinstance(self._cls, str):
            self._cls = _resolve(self._cls)
        return self._cls

    @property
    def class_path(self) -> str:
        """The class's fully qualified name, ``'package.module.ClassName'``."""
        if isinstance(self._cls, str):
            return self._cls.replace(":", ".")
        return f"{self._cls.__module__}.{self._cls.__qualname__}"

    @property
    def parity(self) -> bool:
        """True if the model holds a fixed ``parity`` parameter."""
        if self._parity is None:
            names = getattr(self.cls, "param_names", ())
            self._parity = isinstance(names, tuple) and "parity" in names
        return bool(self._parity)

    @property
    def check_values(self) -> Callable | None:
        """The check of parameter values read from a file, or None."""
        return _resolve(self._check_values)

    @property
    def header(self) -> HeaderHooks | None:
        """The `HeaderHooks` of a type its matrix does not determine, or None."""
        return _resolve(self._header)

    def __repr__(self):
        return (f"<TransformType {self.name!r}: {self.class_path}, "
                f"{'linear' if self.linear else 'non-linear'}>")


_ENTRIES: dict[str, TransformType] = {}


class _Registry(Mapping):
    """A read-only view: name -> value of each entry (in registration order)."""

    def __init__(self, value, doc):
        self._value = value
        self.__doc__ = doc

    def __getitem__(self, name):
        return self._value(_ENTRIES[name])

    def __iter__(self):
        return iter(list(_ENTRIES))

    def __len__(self):
        return len(_ENTRIES)

    def __repr__(self):
        return repr(dict(self))


class _Names(Sequence):
    """A read-only, live tuple of the names of the entries that pass a test."""

    def __init__(self, test, doc):
        self._test = test
        self.__doc__ = doc

    def _names(self):
        return tuple(n for n, e in _ENTRIES.items() if self._test(e))

    def __getitem__(self, i):
        return self._names()[i]

    def __len__(self):
        return len(self._names())

    def __contains__(self, name):
        return name in self._names()

    def __eq__(self, other):
        if isinstance(other, (_Names, tuple, list)):
            return self._names() == tuple(other)
        return NotImplemented

    def __hash__(self):
        return hash(self._names())

    def __add__(self, other):
        return self._names() + tuple(other)

    def __radd__(self, other):
        return tuple(other) + self._names()

    def __repr__(self):
        return repr(self._names())


#: Every registered type: name -> `TransformType`.  Change it with
#: `register_transform_type` and `unregister_transform_type`.
TRANSFORM_REGISTRY = _Registry(lambda e: e, "name -> TransformType, in registration order.")

#: The ``transform_type`` names accepted by `~astroalign_nd.find_transform`,
#: and their model classes (a read-only mapping, kept up to date with the registry).
TRANSFORM_TYPES = _Registry(lambda e: e.cls, "name -> model class, in registration order.")

#: The linear ones among `TRANSFORM_TYPES` (subclasses of `LinearTransform2D`).
LINEAR_TYPES = _Names(lambda e: e.linear, "The names of the linear types.")

#: The others: models grown from a linear match by the distortion stage.
NONLINEAR_TYPES = _Names(lambda e: not e.linear, "The names of the non-linear types.")

#: The built-in types, which cannot be unregistered.
_BUILTIN = ("translation", "euclidean", "similarity", "affine", "projective", "polynomial")


def register_transform_type(name: str, cls: type | str, **fields: Any) -> TransformType:
    """
    Register a transform type: its name becomes a ``transform_type``.

    Parameters
    ----------
    name : str
        The new name (lower case); it must not be registered already.
    cls : type or str
        The model class, or its import path ``'module:ClassName'``.
    **fields
        The other fields of `TransformType` (``linear`` is required).

    Returns
    -------
    entry : `TransformType`

    Raises
    ------
    ValueError
        For a name that is taken, or a class that is not a 2-D model.

    Examples
    --------
    A rotation about the origin only, as a linear type:

    >>> import numpy as np
    >>> from astroalign_nd.transforms import (EuclideanTransform, LINEAR_TYPES,
    ...                                       register_transform_type,
    ...                                       unregister_transform_type, transform_class)
    >>> class Spin(EuclideanTransform):
    ...     pass
    >>> entry = register_transform_type("spin", Spin, linear=True, conformal=True)
    >>> transform_class("spin") is Spin, "spin" in LINEAR_TYPES, entry.parity
    (True, True, True)
    >>> unregister_transform_type("spin")
    >>> "spin" in LINEAR_TYPES
    False
    """
    if name in _ENTRIES:
        raise ValueError(f"transform type {name!r} is registered already (as "
                         f"{_ENTRIES[name].class_path}); unregister it first.")
    entry = TransformType(name, cls, **fields)
    if not isinstance(cls, str):  # a class given by its path is checked when imported
        from astropy.modeling import Model  # (this module stays light: see its docstring)

        if not (issubclass(cls, Model) and cls.n_inputs == 2 and cls.n_outputs == 2):
            raise ValueError(f"a transform type's class must be an astropy Model with 2 inputs "
                             f"and 2 outputs; {cls.__name__} is not.")
        if _entry_of_class(cls, exact=True) is not None:
            raise ValueError(f"{cls.__name__} is registered already, as "
                             f"{_entry_of_class(cls, exact=True).name!r}.")
    _ENTRIES[name] = entry
    return entry


def unregister_transform_type(name: str) -> None:
    """
    Remove a type added by `register_transform_type`.

    Raises
    ------
    ValueError
        For a built-in type or a name that is not registered.

    Examples
    --------
    >>> from astroalign_nd.transforms import unregister_transform_type
    >>> unregister_transform_type("affine")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: 'affine' is a built-in transform type; it cannot be removed.
    """
    if name in _BUILTIN:
        raise ValueError(f"{name!r} is a built-in transform type; it cannot be removed.")
    if name not in _ENTRIES:
        raise ValueError(f"no transform type {name!r} is registered; the types are "
                         f"{list(_ENTRIES)}.")
    del _ENTRIES[name]


def transform_class(transform_type: str | type) -> type:
    """
    Return the model class for a ``transform_type`` name or class.

    Parameters
    ----------
    transform_type : str or type
        One of the names of `TRANSFORM_TYPES` (``'translation'``,
        ``'euclidean'``, ``'similarity'``, ``'affine'``, ``'projective'``,
        ``'polynomial'``; any case), or a subclass of one of their classes.

    Returns
    -------
    cls : type
        A subclass of `LinearTransform2D`, or `ProjectiveTransform` or
        `PolynomialTransform`.

    Raises
    ------
    ValueError
        For any other name or class.

    Examples
    --------
    >>> from astroalign_nd.transforms import transform_class, AffineTransform
    >>> transform_class("Similarity").__name__
    'SimilarityTransform'
    >>> transform_class(AffineTransform) is AffineTransform
    True
    """
    if isinstance(transform_type, type):
        if _entry_of_class(transform_type) is not None:
            return transform_type
    elif isinstance(transform_type, str) and transform_type.lower() in _ENTRIES:
        return _ENTRIES[transform_type.lower()].cls
    raise ValueError(
        f"transform_type must be one of {sorted(_ENTRIES)} (or one of their "
        f"classes); got {transform_type!r}."
    )


def _entry_of_class(cls, exact=False):
    """The entry of the most specific registered class among ``cls`` and its bases."""
    by_class = {e.cls: e for e in _ENTRIES.values()}
    for klass in (cls,) if exact else cls.__mro__:
        if klass in by_class:
            return by_class[klass]
    return None


def transform_type_of(transform: Any, *, exact: bool = False) -> TransformType | None:
    """
    The registry entry of a model, a model class or a ``transform_type`` name.

    Parameters
    ----------
    transform : model, type or str
        A model (its class is looked up), a class, or a name (any case).
    exact : bool, optional
        Only an entry for the class itself, not for one of its bases.

    Returns
    -------
    entry : `TransformType` or None
        None for an unknown name or a class that no entry holds.

    Examples
    --------
    >>> from astroalign_nd.transforms import AffineTransform, transform_type_of
    >>> transform_type_of(AffineTransform()).name
    'affine'
    >>> transform_type_of("Projective").linear
    False
    >>> transform_type_of("homography") is None
    True
    """
    if isinstance(transform, str):
        return _ENTRIES.get(transform.lower())
    return _entry_of_class(transform if isinstance(transform, type) else type(transform), exact)


# -- the built-in types --------------------------------------------------------------------

_T = "astroalign_nd.transforms."
for _name, _path, _kw in (
        ("translation", "linear:TranslationTransform",
         dict(linear=True, parity=False, conformal=True)),
        ("euclidean", "linear:EuclideanTransform", dict(linear=True, parity=True, conformal=True)),
        ("similarity", "linear:SimilarityTransform",
         dict(linear=True, parity=True, conformal=True)),
        ("affine", "linear:AffineTransform", dict(linear=True, parity=False)),
        ("projective", "projective:ProjectiveTransform",
         dict(linear=False, parity=False, check_values=_T + "projective:_check_values")),
        ("polynomial", "polynomial:PolynomialTransform",
         dict(linear=False, parity=False, degrees=(2, 3, 4, 5), matrix_rows=2,
              header=_T + "polynomial:HEADER_HOOKS"))):
    _kw.setdefault("check_values", _T + "linear:_check_values")
    register_transform_type(_name, _T + _path, asdf_tag=f"{_name}_transform", **_kw)
del _name, _path, _kw


# -- the degree and the kind of a requested type (light: no model is imported) --------


def _check_degree(degree, auto=False):
    """
    The degree as an int, or a TypeError or ValueError: the one check of a
    polynomial degree (``auto``: the message offers ``'auto'`` as well).
    """
    _DEGREES = TRANSFORM_REGISTRY["polynomial"].degrees
    what = f"an integer from {_DEGREES[0]} to {_DEGREES[-1]}" + (" or 'auto'" if auto else "")
    if isinstance(degree, (bool, np.bool_)) or not isinstance(degree, numbers.Integral):
        raise TypeError(f"degree must be {what}; got {degree!r}.")
    if int(degree) not in _DEGREES:
        raise ValueError(f"degree must be {what}; got {degree!r}. (Degree 1 is "
                         "transform_type='affine': an AffineTransform.)")
    return int(degree)


def check_degree(transform_type, degree):
    """
    The validated ``degree`` for ``transform_type``.

    Parameters
    ----------
    transform_type : str or type
        The requested transform type.
    degree : int, 'auto' or None
        Polynomial degree (2 to 5) or ``'auto'``; only for
        ``transform_type='polynomial'`` (None there means 3).

    Returns
    -------
    degree : int, 'auto' or None

    Raises
    ------
    ValueError, TypeError
        For a degree out of range, or given with another transform type.

    Examples
    --------
    >>> from astroalign_nd.transforms import check_degree
    >>> check_degree("polynomial", None), check_degree("polynomial", "auto")
    (3, 'auto')
    >>> check_degree("similarity", None) is None
    True
    """
    is_poly = nonlinear_name(transform_type) == "polynomial"
    if degree is None:
        return 3 if is_poly else None
    if not is_poly:
        raise ValueError(
            f"degree={degree!r} applies to transform_type='polynomial' only; got "
            f"transform_type={transform_type!r}. Pass transform_type='polynomial' or drop "
            "degree.")
    if isinstance(degree, str):
        if degree.lower() == "auto":
            return "auto"
        if degree.strip().isdigit():
            degree = int(degree)
    return _check_degree(degree, auto=True)


def nonlinear_name(transform_type):
    """The registry name of a non-linear type (a name or a class), else None."""
    if not isinstance(transform_type, (str, type)):
        return None
    entry = transform_type_of(transform_type)
    return None if entry is None or entry.linear else entry.name


def is_nonlinear(transform_type):
    """True for the transform types of this stage ('projective', 'polynomial')."""
    return nonlinear_name(transform_type) is not None
