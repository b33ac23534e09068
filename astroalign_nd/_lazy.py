# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
A package's public names, imported on first use (PEP 562).

``import astroalign_nd`` must stay cheap: the command line's ``--help``
and every worker process start with it, while the stages behind the public
names import astropy.modeling, scipy and photutils, which take seconds on a
cold machine.  The ``__init__`` of the package, of its stages, of
``sequence`` and of ``stacking`` therefore only declare, in a ``_LAZY``
table, which submodule defines each public name, and `attach` gives them
the module-level ``__getattr__`` and ``__dir__`` (PEP 562) that import that
submodule when the name is first read, and their ``__all__``.  This is
scientific Python's SPEC 1 (``lazy_loader.attach(package, submod_attrs)``,
used by scikit-image), without the dependency.

To add a public name, add it to its submodule's list in the package's
``_LAZY`` table; a static ``from astroalign_nd import name`` works as usual.
"""

import importlib
import sys

__all__ = ["attach"]


def attach(package, submodule_names, submodules=()):
    """
    A lazily imported package's ``__getattr__``, ``__dir__`` and ``__all__``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    submodule_names : dict
        Submodule, relative to ``package`` as in a relative import
        (``".linear"``) -> the list of public names it defines.
    submodules : iterable of str, optional
        Submodules reachable as attributes without an explicit import.

    Returns
    -------
    getattr, dir : callable
        To assign to the package's ``__getattr__`` and ``__dir__``.
    all : list of str
        Every public name of ``submodule_names``, in its order.

    Examples
    --------
    >>> import astroalign_nd
    >>> "find_transform" in dir(astroalign_nd), "importlib" in dir(astroalign_nd)
    (True, False)
    >>> astroalign_nd.no_such_name
    Traceback (most recent call last):
    ...
    AttributeError: module 'astroalign_nd' has no attribute 'no_such_name'
    """
    if not all(module.startswith(".") for module in submodule_names):
        raise ValueError(f"{package}: submodules are named relative to it: '.name'")
    names = {name: module for module, defined in submodule_names.items() for name in defined}
    if len(names) < sum(map(len, submodule_names.values())):
        raise ValueError(f"{package}: a public name is listed under two submodules")
    submodules = frozenset(submodules)

    def __getattr__(name):
        if name in submodules:  # the import binds it on the package: asked once
            return importlib.import_module(f".{name}", package)
        if name in names:
            value = getattr(importlib.import_module(names[name], package), name)
            setattr(sys.modules[package], name, value)  # later look-ups skip this function
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__():
        return sorted(set(vars(sys.modules[package])) | set(names) | submodules)

    return __getattr__, __dir__, list(names)
