"""Sphinx configuration of the API reference (``make docs``; ``make test`` builds it with
warnings as errors). The pages are generated from the docstrings: one page per package."""

from __future__ import annotations

import riskplan

project = "riskplan"
author = "riskplan developers"
release = version = riskplan.__version__

extensions = ["sphinx.ext.autodoc", "sphinx.ext.mathjax", "numpydoc"]
# No network during the build: no intersphinx; MathJax is only referenced by the pages.
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # signatures stay readable; types are in the numpydoc sections
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
default_role = "any"
html_theme = "alabaster"
exclude_patterns = ["_build"]


def _resolve_by_name(app, env, node, contnode):
    """Resolve a cross-reference written with a short or module-internal path (``InvalidInputError``,
    ``riskplan.control.lqg.lqg_controller``) to the one documented object of that name, when
    there is exactly one; anything else stays unresolved (and fails the nitpicky build)."""
    if node.get("refdomain") != "py":
        return None
    target = node.get("reftarget", "").lstrip("~.")
    name = target.rsplit(".", 1)[-1]
    domain = env.get_domain("py")
    hits = [full for full in domain.objects if full.rsplit(".", 1)[-1] == name]
    if target in domain.objects or len(hits) != 1:
        return None
    full = hits[0]
    obj = domain.objects[full]
    return domain.resolve_xref(
        env,
        node["refdoc"],
        app.builder,
        obj.objtype if obj.objtype != "method" else "meth",
        full,
        node,
        contnode,
    )


def setup(app):
    app.connect("missing-reference", _resolve_by_name)
