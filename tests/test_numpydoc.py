"""Every public function and method (of a public name, tests/public_api.py: a name in the
``__all__`` of a public module) has numpydoc ``Parameters`` (naming each argument) and
``Returns`` (or ``Yields``) sections.

Names that do not yet are listed in ``tests/numpydoc_pending.txt``; the list may only
shrink: a name on it that has gained its sections fails the test until it is removed."""

from __future__ import annotations

import ast
import inspect
import textwrap
from pathlib import Path

import pytest

from tests.public_api import public_callables

numpydoc = pytest.importorskip("numpydoc.docscrape")

PENDING = Path(__file__).with_name("numpydoc_pending.txt")


def _problems(fn) -> list[str]:
    sig = inspect.signature(fn)
    params = [
        p.name
        for p in sig.parameters.values()
        if p.name not in ("self", "cls")
        and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
        and not p.name.startswith("_")
    ]
    doc = numpydoc.FunctionDoc(fn)
    documented = set()
    for entry in doc["Parameters"]:
        documented |= {n.strip().lstrip("*") for n in entry.name.split(",")}
    out = []
    if params and not doc["Parameters"]:
        out.append("no Parameters")
    elif set(params) - documented:
        out.append(f"Parameters lack {sorted(set(params) - documented)}")
    ret = sig.return_annotation
    annotated = ret not in (inspect.Signature.empty, None, "None")
    if (annotated or _returns_a_value(fn)) and not (doc["Returns"] or doc["Yields"]):
        out.append("no Returns")
    return out


def _returns_a_value(fn) -> bool:
    """Whether the body of ``fn`` (not of functions nested in it) returns something other
    than None or yields: a function without a return annotation still needs ``Returns``."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(inspect.unwrap(fn)))).body[0]
    except (OSError, TypeError, SyntaxError, IndexError):
        return False
    stack = list(ast.iter_child_nodes(tree))
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            continue
        if isinstance(node, (ast.Yield, ast.YieldFrom)):
            return True
        if isinstance(node, ast.Return) and node.value is not None:
            if not (isinstance(node.value, ast.Constant) and node.value.value is None):
                return True
        stack.extend(ast.iter_child_nodes(node))
    return False


def _pending() -> set[str]:
    lines = PENDING.read_text(encoding="utf-8").splitlines()
    return {s.strip() for s in lines if s.strip() and not s.startswith("#")}


def test_public_callables_have_parameters_and_returns():
    pending = _pending()
    missing, fixed, seen = [], [], set()
    for name, fn in public_callables():
        seen.add(name)
        probs = _problems(fn)
        if probs and name not in pending:
            missing.append(f"{name}: {', '.join(probs)}")
        if not probs and name in pending:
            fixed.append(name)
    assert not missing, "numpydoc sections missing:\n" + "\n".join(missing)
    assert not fixed, f"documented now, remove from {PENDING.name}: {fixed}"
    stale = sorted(pending - seen)
    assert not stale, f"not public callables (any more), remove from {PENDING.name}: {stale}"
