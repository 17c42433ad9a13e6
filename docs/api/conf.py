"""Sphinx configuration of the API reference (``make docs``; ``make test`` builds it with
warnings as errors). The pages are generated from the docstrings: one page per package."""

from __future__ import annotations

import inspect

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
# Every cross-reference must resolve (make docs and tests/test_api_reference.py fail otherwise).
nitpicky = True
# Names of other projects: without network there is no intersphinx inventory to resolve them
# against (numpy, scipy and torch publish theirs only online), so they stay plain text. Only
# names under these packages are ignored; a riskplan name that does not resolve still fails.
nitpick_ignore_regex = [(r"py:.*", r"(numpy|scipy|torch)(\..+)?")]
html_theme = "alabaster"
exclude_patterns = ["_build"]


def _resolve_by_name(app, env, node, contnode):
    """Resolve a cross-reference written with a short or module-internal path (``InvalidInputError``,
    ``riskplan.control.lqg.lqg_controller``, ``NeedleScenario.planning_space``) to the one
    documented object whose dotted name ends the same way: first by the last name alone, then by
    the last two parts (class and member). Canonical aliases of an object (the defining module's
    path beside the package's) count once. Anything else stays unresolved (and fails the build)."""
    if node.get("refdomain") != "py":
        return None
    target = node.get("reftarget", "").lstrip("~.")
    domain = env.get_domain("py")
    if target in domain.objects:
        return None
    parts = target.split(".")
    real = [full for full, obj in domain.objects.items() if not obj.aliased]
    hits = []
    for depth in (1, 2):
        if depth > len(parts):
            break
        tail = parts[-depth:]
        hits = [full for full in real if full.split(".")[-depth:] == tail]
        if len(hits) <= 1:
            break
    if len(hits) != 1:
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


def _plain_signature(app, what, name, obj, options, signature, return_annotation):
    """Drop the annotations autodoc leaves in the signatures of dataclasses (their generated
    ``__init__`` carries string annotations such as ``'tuple[Tendon, ...]'``, which the signature
    parser splits at the comma); the types are in the numpydoc sections."""
    if what != "class" or not signature or ":" not in signature:
        return None
    try:
        sig = inspect.signature(obj)
    except (TypeError, ValueError):
        return None
    empty = inspect.Parameter.empty
    params = [p.replace(annotation=empty) for p in sig.parameters.values()]
    return str(sig.replace(parameters=params, return_annotation=empty)), return_annotation


def setup(app):
    app.connect("missing-reference", _resolve_by_name)
    # before numpydoc's own handler (priority 500), which answers first otherwise
    app.connect("autodoc-process-signature", _plain_signature, priority=400)
