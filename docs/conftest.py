# Not test modules: Sphinx's conf.py, and this file (doctestplus would otherwise import every
# conftest.py as a module named "conftest" and clash with tests/conftest.py).  The notebook
# tutorials (tutorials/*.md) are executed by the documentation build, not by pytest.
collect_ignore = [
    "conf.py",
    "conftest.py",
]
collect_ignore_glob = [
    "_build/*",
    "api/*",
    "tutorials/*.md",
]
