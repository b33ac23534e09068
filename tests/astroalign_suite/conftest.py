# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Run astroalign 2.6.2's own tests against `astroalign_nd.compat`.

``test_align.py`` (astroalign's tests, see README.md) does ``import astroalign
as aa``.  While that module is collected, ``astroalign`` resolves to
`astroalign_nd.compat`; the alias is removed afterwards, so that nothing else
in the session (benchmarks comparing against the real astroalign) sees it.
"""

import sys

import pytest

# doctestplus imports every .py file; this one must not clash with tests/conftest.py.
collect_ignore = ["conftest.py"]

try:
    import sep  # noqa: F401 - the upstream suite counts stars with it
except ImportError:
    HAVE_SEP = False
else:
    HAVE_SEP = True

try:
    import PIL  # noqa: F401 - imported by the upstream suite (scikit-image needs it too)
except ImportError:
    collect_ignore.append("test_align.py")


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    if getattr(collector, "path", None) is None or collector.path.name != "test_align.py":
        yield
        return
    from astroalign_nd import compat

    saved = sys.modules.get("astroalign")
    sys.modules["astroalign"] = compat
    try:
        yield
    finally:
        if saved is None:
            sys.modules.pop("astroalign", None)
        else:
            sys.modules["astroalign"] = saved


def pytest_collection_modifyitems(config, items):
    skip = pytest.mark.skip(reason="astroalign's suite needs sep (pip install sep) to count "
                                   "the stars of the aligned images")
    # astroalign never warns; compat warns (PoorFitWarning) when a fit of a few
    # stars is uncertain to more than 0.3 px, as the suite's 3-6 star fits are.
    quiet = pytest.mark.filterwarnings("ignore::astroalign_nd.PoorFitWarning")
    for item in items:
        if item.path.name == "test_align.py" and item.path.parent.name == "astroalign_suite":
            item.add_marker(quiet)
            if not HAVE_SEP:
                item.add_marker(skip)
