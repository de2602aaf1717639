"""Sphinx configuration for the teamkf documentation site.

Build with ``make docs`` (warnings are errors). Neither the build nor the site needs a
network: intersphinx is not used (no inventories are shipped), MathJax is copied into
the site from the ``sphinx-mathjax-offline`` package (nothing is fetched when a page is
read), and the gallery runs every reproduction at reduced size.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / "src"))  # the source tree being documented, before any installed copy
sys.path.insert(0, str(HERE / "_ext"))
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("TEAMKF_PROGRESS", "0")  # no progress bars in the build log
os.environ.setdefault("TEAMKF_RUNS", "30")  # examples/robust_jitter.py: 30 Monte Carlo runs on the site (100 when run by hand)

import teamkf_docs  # noqa: E402

import teamkf  # noqa: E402

project = "teamkf"
author = "teamkf developers"
copyright = "teamkf developers"
release = teamkf.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "matplotlib.sphinxext.plot_directive",
    "numpydoc",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
    "sphinx_copybutton",
    "sphinx-mathjax-offline",  # copies MathJax 3 into _static/mathjax: the pages typeset maths offline
    "teamkf_docs",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = [
    "_build",
    "**.ipynb_checkpoints",
    "gallery",
    "_examples",
    "api/public.rst",
    "guide/_*.md",
    "Thumbs.db",
    ".DS_Store",
]  # included by other pages
templates_path = ["_templates"]

# --- API reference --------------------------------------------------------------------------------
# api/public.rst and api/<subpackage>.rst are written at build start by teamkf_docs from
# teamkf.__all__ and the subpackages' __all__: there is no hand-kept list of names.
autosummary_generate = teamkf_docs.autosummary_sources()  # api/public.rst is included, not a page of its own
autosummary_ignore_module_all = False
autosummary_imported_members = False
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "none"  # the numpydoc sections carry the types; signatures stay readable
autoclass_content = "class"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set[str] = set()
numpydoc_xref_param_type = False

# --- offline: no intersphinx, no remote images ------------------------------------------------------
# Cross-references to numpy/scipy/networkx/dask would need their objects.inv files; the build must not
# use the network, and no inventories are shipped, so intersphinx is off. (Enable it by adding
# "sphinx.ext.intersphinx" and an intersphinx_mapping pointing at local inventories.)
suppress_warnings = [
    # numpydoc References sections list the papers without citing [1]_ in the text (module docstrings
    # such as teamkf.network.graph): the citation is rendered, only the "not referenced" check is off.
    "ref.citation",
    # docs/scenario-and-cli.md shows JSON output with "..." elisions: highlighted in relaxed mode.
    "misc.highlighting_failure",
]

# --- math ----------------------------------------------------------------------------------------------
# MathJax comes from the site itself (sphinx-mathjax-offline copies it to _static/mathjax); the path
# is relative to _static. CommonHTML output with MathJax's own web fonts, also served by the site.
mathjax_path = "mathjax/tex-chtml.js"
myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# --- gallery ---------------------------------------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": ["gallery", "_examples"],  # _examples: examples/*.py, copied by teamkf_docs
    "gallery_dirs": ["auto_gallery", "auto_examples"],
    "filename_pattern": r".*\.py$",  # execute every script
    "ignore_pattern": r"(__init__|conftest)\.py$",
    "image_scrapers": ("matplotlib", "teamkf_docs.experiment_png_scraper"),
    "capture_repr": ("_repr_html_", "__repr__"),
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "abort_on_example_error": False,
    "only_warn_on_example_error": False,
    "show_memory": False,
    "plot_gallery": "True",
    "reset_modules": ("matplotlib",),
    # "Gallery pages using X" on every API page (thumbnails), from the names the scripts use
    "doc_module": ("teamkf",),
    "backreferences_dir": "api/generated/backreferences",
    "log_level": {"backreference_missing": "debug"},  # most API pages have no gallery page: not a problem
}

# --- figures in the guide (matplotlib's plot directive, run at build time) --------------------------
plot_include_source = True
plot_html_show_source_link = False
plot_html_show_formats = False
plot_formats = [("png", 100)]
plot_rcparams = {"figure.figsize": (6, 4)}

# --- HTML --------------------------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"teamkf {release}"
html_static_path = ["_static"]
html_css_files = ["teamkf.css"]
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_show_sourcelink = False
