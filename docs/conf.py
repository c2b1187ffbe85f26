"""Sphinx configuration of the ssamb documentation (``sphinx-build -W docs docs/_build``)."""
from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

project = "ssamb"
author = "the ssamb developers"
copyright = "the ssamb developers"
release = version = __import__("ssamb").__version__

extensions = [
    "myst_parser",            # the pages are Markdown, like the README
    "sphinx.ext.autodoc",     # the API reference from the docstrings
    "sphinx.ext.mathjax",     # the docstrings' equations
    "numpydoc",               # their numpydoc sections
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build"]
myst_enable_extensions = ["dollarmath", "deflist"]
myst_heading_anchors = 3

autodoc_member_order = "bysource"
autodoc_typehints = "none"           # the numpydoc sections state the types
numpydoc_show_class_members = False  # members are documented by autodoc, once
numpydoc_validation_checks: set = set()
nitpicky = False

html_theme = "alabaster"
html_title = "ssamb"
html_theme_options = {"page_width": "1100px", "sidebar_width": "230px"}
