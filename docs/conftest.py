# Not test modules: Sphinx's conf.py, and this file (doctestplus would otherwise import every
# conftest.py as a module named "conftest" and clash with tests/conftest.py); the notebook
# tutorial and the script that builds and executes it (run by hand, see its docstring).
collect_ignore = [
    "conf.py",
    "conftest.py",
    "tutorials/make_register_and_stack.py",
    "tutorials/register_and_stack.ipynb",
]
