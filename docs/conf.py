# Sphinx configuration of the lensdual documentation.
#
# Build with ``tox -e build_docs`` (``sphinx-build -W --keep-going -b html . _build/html``).
# The build needs no network access: no intersphinx, no remote images.

import datetime

import lensdual

# -- Project information -------------------------------------------------------

project = "lensdual"
author = "lensdual developers"
copyright = f"{datetime.date.today().year}, {author}"

# The full version, including alpha/beta/rc/dev tags, and the short X.Y version.
release = lensdual.__version__
version = ".".join(release.split(".")[:2])

# -- General configuration -----------------------------------------------------

extensions = [
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "sphinx_automodapi.automodapi",
    "sphinx_automodapi.smart_resolver",
    "numpydoc",
    "matplotlib.sphinxext.plot_directive",
]

# Figures are computed during the build (``.. plot::``), never downloaded.
plot_include_source = True
plot_html_show_source_link = False
plot_html_show_formats = False
plot_formats = [("png", 100)]
plot_rcparams = {"figure.dpi": 100}

exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
templates_path = []
source_suffix = {".rst": "restructuredtext"}
root_doc = "index"

# Unresolved cross-references (e.g. to numpy or astropy, without intersphinx)
# render as plain text instead of producing warnings.
nitpicky = False

# Single backticks are cross-references to Python objects.
default_role = "obj"

# -- numpydoc ------------------------------------------------------------------

# automodapi writes its own member summaries; numpydoc must not add another.
numpydoc_show_class_members = False
numpydoc_show_inherited_class_members = False
numpydoc_class_members_toctree = False
# Do not let numpydoc turn every "type" in a Parameters section into a link.
numpydoc_xref_param_type = False
# Docstring validation during the build: every documented callable names all
# its parameters, documents no parameter it does not have, and says what it
# returns (tests/test_docstrings.py runs the same checks, plus GL08, in the
# test suite). Enum classes are left out (their "parameters" are the Enum
# machinery's), as are the methods inherited from Python and numpy.
numpydoc_validation_checks = {"PR01", "PR02", "RT01"}
numpydoc_validation_exclude = {
    r"\.PhotometryFlag$",
    r"\.__[a-z]+__$",
    # module constants: numpydoc would validate their classes' docstrings
    r"\.DEFAULT_[A-Z_]+$",
}

# -- sphinx-automodapi ---------------------------------------------------------

automodapi_toctreedirnm = "api/generated"
automodapi_writereprocessed = False
automodsumm_inherited_members = False
# graphviz is not a dependency; every automodapi uses :no-inheritance-diagram:.
automodapi_inheritance_diagram = False

# -- Options for HTML output ---------------------------------------------------

try:
    import pydata_sphinx_theme  # noqa: F401
except ImportError:  # pragma: no cover - fallback when the docs extra is missing
    html_theme = "alabaster"
    html_theme_options = {}
else:
    html_theme = "pydata_sphinx_theme"
    html_theme_options = {
        "navigation_with_keys": False,
        "show_toc_level": 2,
        "use_edit_page_button": False,
        # no icon links: they would fetch remote resources
        "icon_links": [],
        # the navbar shows the short name (the version string of html_title ran
        # into the search box at 1280 px)
        "logo": {"text": "lensdual"},
    }
    # every page is a top-level entry of the toctree, so the primary sidebar's
    # "Section Navigation" would be empty: leave it out (the page's own contents
    # stay in the secondary sidebar)
    html_sidebars = {"**": []}

html_title = f"{project} {release}"
html_static_path = []
html_show_sourcelink = False

# Substitutions used in astropy docstrings that automodapi pulls in (e.g. the
# SkyCoord documentation of a module-level SkyCoord constant).
rst_epilog = """
.. |SkyCoord| replace:: :class:`~astropy.coordinates.SkyCoord`
.. |Quantity| replace:: :class:`~astropy.units.Quantity`
.. |Table| replace:: :class:`~astropy.table.Table`
.. |QTable| replace:: :class:`~astropy.table.QTable`
"""
