"""Collection settings for ``pytest`` at the repository root (tests/ and the package's docstring examples)."""

# ``eponet/run.py`` is the ``python -m eponet.run`` program; imported, it hands back the API function
# ``eponet.run`` in its place, which is not a module that pytest can collect (it holds no examples)
collect_ignore = ["eponet/run.py"]
