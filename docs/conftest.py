# Not test modules: Sphinx's conf.py, and this file (doctestplus would otherwise import every
# conftest.py as a module named "conftest" and clash with tests/conftest.py).
collect_ignore = ["conf.py", "conftest.py"]
