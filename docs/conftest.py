"""pytest configuration of the docs doctests: Sphinx's conf.py is not a test module."""

collect_ignore = ["conf.py"]
