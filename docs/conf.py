"""Sphinx configuration of varint's documentation site: the Markdown pages of docs/ through MyST, the API reference
from the docstrings (autodoc), the gallery of the examples (docs/gallery/, made by scripts/make_gallery.py).

Build (the docs extra: pip install -e '.[docs]'):  python3 -m sphinx -W --keep-going -b html docs docs/_build/html
.ci/run builds it with warnings as errors, so a broken reference (a page, an anchor, an object) fails CI."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # the package of this checkout, whatever is installed

from varint.version import __version__  # noqa: E402

project = "varint"
author = "varint developers"
copyright = "varint developers"
release = version = __version__

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "sphinx.ext.mathjax"]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build"]
myst_heading_anchors = 3  # links to sections of a page: [theory §9](theory.md#9-the-rod)
myst_enable_extensions = ["dollarmath"]
nitpicky = True  # a reference to a missing object (a renamed function) is a warning, so an error in CI

autodoc_member_order = "bysource"
autodoc_typehints = "none"  # the docstrings say the types; the signatures stay short
napoleon_google_docstring = False  # the few structured docstrings are numpy-style (varint.Simulation)
napoleon_numpy_docstring = True
napoleon_preprocess_types = True  # "float, optional": a type and a word, not two classes

html_theme = "alabaster"
html_title = f"varint {release}"
html_static_path = []
