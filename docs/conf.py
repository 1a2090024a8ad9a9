"""Sphinx configuration of torch_grid's documentation: Markdown pages (myst-parser), the API
reference from the docstrings (autodoc, autosummary, napoleon) and an example gallery whose scripts
run at every build (sphinx-gallery).

    sphinx-build -W --keep-going -b html docs /tmp/docs_html
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # torch_grid from this checkout, installed or not
sys.path.insert(0, str(Path(__file__).resolve().parent / "_ext"))
os.environ.setdefault("MUJOCO_GL", "egl")  # the rendering example draws offscreen
os.environ.setdefault("MPLBACKEND", "Agg")

import torch  # noqa: E402

import torch_grid  # noqa: E402

# The gallery's batches are small: one thread runs them, where a second one, woken for a few samples,
# can wait milliseconds for a core on a busy machine (bench/RESULTS.md, thread scaling).
torch.set_num_threads(1)

project = "torch_grid"
author = "torch_grid contributors"
copyright = "torch_grid contributors"
release = version = torch_grid.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx_gallery.gen_gallery",
    "plain_docstrings",  # docs/_ext: the plain-text docstrings as reStructuredText
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "gallery/GALLERY_HEADER.rst", "**/sg_execution_times.rst", "sg_execution_times.rst"]
myst_enable_extensions = ["dollarmath", "colon_fence"]
myst_heading_anchors = 3

# API reference: signatures as written, members in source order, type hints in the signature only
default_role = "code"  # `x` in a docstring is code, as in its plain text
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_preserve_defaults = True
autosummary_generate = False
napoleon_google_docstring = True
napoleon_numpy_docstring = False

# The gallery: docs/gallery/*.py run at every build (a robot already in the kernel cache loads in a
# fraction of a second); their figures and output make the pages under docs/auto_examples/.
sphinx_gallery_conf = {
    "examples_dirs": "gallery",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "write_computation_times": False,
}

html_theme = "furo"
html_title = f"torch_grid {release}"
