"""Sphinx configuration of the lcpbench documentation: the user guide, the reference pages
(docs/*.md, read by myst-parser) and the API reference built from the docstrings (docs/api/).

Build it with ``sphinx-build -W -b html docs docs/_build`` after ``pip install -e ".[docs]"``
(``.ci/run`` builds it with warnings as errors); open ``docs/_build/index.html``.
"""

import re
from pathlib import Path

import lcpbench

project = "lcpbench"
author = "the lcpbench developers"
copyright = "2026, the lcpbench developers"
release = lcpbench.__version__
version = release

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon"]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"

# Markdown pages: `page.md#a-heading` links resolve to the headings of levels 1-4.
myst_heading_anchors = 4

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

exclude_patterns = ["_build", "api/_build", "examples"]
html_theme = "alabaster"
html_title = f"lcpbench {release}"

DOCS = Path(__file__).resolve().parent
_LINK = re.compile(r"\]\((?!https?:|mailto:|#|path:)([^)#\s]+)(#[^)\s]*)?\)")


def _link_outside_the_site(app, docname, source):
    """Links to repository files that are not pages of this site (reports/paper/README.md, a
    source file) become download links to that file, so that they work on the site as on
    the repository; a link to a missing file is left as it is, and Sphinx warns about it."""
    path = Path(app.env.doc2path(docname))
    if path.suffix != ".md":
        return
    here = path.parent

    def fix(match):
        target = (here / match.group(1)).resolve()
        in_site = target.suffix in (".md", ".rst") and DOCS in target.parents
        if in_site or not target.is_file():
            return match.group(0)
        return f"](path:{match.group(1)})"

    source[0] = _LINK.sub(fix, source[0])


def setup(app):
    app.connect("source-read", _link_outside_the_site)
