"""Sphinx configuration of the mpmref documentation site.

Build it with ``python docs/build.py`` (after ``pip install -e '.[docs]'``). The Markdown pages in
this folder are the chapters, read by MyST-Parser as they are; ``api.md`` documents every module with
autodoc and napoleon; ``sphinx.ext.viewcode`` renders the source with line numbers, and the local
extension ``_ext/mpmref_links.py`` turns each link whose text is a qualified name into a link to that
object's first line in the rendered source.

The equations are typeset by MathJax from the site's own copy: ``sphinx-mathjax-offline`` (the ``docs``
extra) copies MathJax 3 (its scripts and fonts) into ``_static/mathjax/`` and points ``mathjax_path`` at
it, so that a built page loads nothing from the network and reads the same on a machine without one
(``tests/test_docs_site.py`` checks both in a headless browser).
"""

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(DOCS / "_ext"))

project = "mpmref"
author = "the mpmref authors"
copyright = "the mpmref authors, MIT licence"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "sphinx.ext.mathjax",
    "sphinx-mathjax-offline",        # MathJax bundled into the site (_static/mathjax), not fetched from a CDN
    "mpmref_links",
    "mpmref_figures",
]

root_doc = "index"
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}  # .rst: the generated API pages
exclude_patterns = ["_build", "_generated"]  # _generated: fragments that figures.md includes
templates_path = ["_templates"]        # a module's API page: its docstrings, then its submodules (private too)

myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 6            # GitHub-style anchors for every heading level, as the pages link to them
myst_dmath_double_inline = True

autodoc_default_options = {"members": True, "undoc-members": True, "ignore-module-all": True}
autosummary_generate = True          # one page per module under api/ (generated, not committed)
autodoc_member_order = "bysource"
autodoc_typehints = "none"
autodoc_mock_imports = ["taichi"]    # the optional `bench` extra; only its peer module imports it
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_ivar = True             # dataclass fields listed under "Attributes" are not documented twice
viewcode_line_numbers = True
viewcode_follow_imported_members = False   # anchors by where autodoc documents an object (a mocked class too)

nitpicky = False
html_theme = "alabaster"
html_title = "mpmref: a verified reference of the Material Point Method"
html_static_path = []
