# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
What the result records of a batch and of a joint solution share.

A leaf module: it imports no other module of the package, so that
``batch`` (`~astroalign_nd.batch.BatchResult`) and ``sequence``
(`~astroalign_nd.sequence.SequenceSolution`), which does not import
``batch``, both use it.
"""

__all__ = ["status_list"]


def status_list(items, status, doc):
    """
    A read-only property: the elements of the list attribute ``items`` with a given ``status``.

    Parameters
    ----------
    items : str
        The name of the attribute that holds the list (of objects with a ``status``).
    status : str
        The status kept.
    doc : str
        The property's docstring.

    Returns
    -------
    property
        A new list at each read, in the order of ``items``.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> class Night:
    ...     frames = [SimpleNamespace(name="a", status="failed"),
    ...               SimpleNamespace(name="b", status="registered")]
    ...     failed = status_list("frames", "failed", "The frames that failed.")
    >>> [f.name for f in Night().failed], Night.failed.__doc__
    (['a'], 'The frames that failed.')
    """
    def with_status(self):
        return [item for item in getattr(self, items) if item.status == status]

    return property(with_status, doc=doc)
