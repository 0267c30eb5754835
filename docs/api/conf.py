"""Sphinx configuration of the lcpbench API reference (built by ``.ci/run`` with ``-W``).

Build it with ``sphinx-build -W -b html docs/api docs/api/_build`` after
``pip install -e ".[dev]"``; the pages are generated from the numpy-style docstrings.
"""

import lcpbench

project = "lcpbench"
author = "the lcpbench developers"
copyright = "2026, the lcpbench developers"
release = lcpbench.__version__
version = release

extensions = ["sphinx.ext.autodoc", "sphinx.ext.napoleon"]

# numpy-style docstrings only ("Parameters", "Returns", ... sections).
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False

autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"   # hints go into the parameter lists, not the signatures
autodoc_class_signature = "separated"

# Type fields such as "ndarray, shape (n,)" make the python domain look up "n", which several
# classes define as an attribute; those ambiguous look-ups are the only warnings it raises.
suppress_warnings = ["ref.python"]

exclude_patterns = ["_build"]
html_theme = "alabaster"
html_title = f"lcpbench {release} API reference"
