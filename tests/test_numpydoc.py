"""Every public function and method of the packages' ``__all__`` has numpydoc
``Parameters`` (naming each argument) and ``Returns`` (or ``Yields``) sections.

Names that do not yet are listed in ``tests/numpydoc_pending.txt``; the list may only
shrink: a name on it that has gained its sections fails the test until it is removed."""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

import pytest

numpydoc = pytest.importorskip("numpydoc.docscrape")

PACKAGES = (
    "robots",
    "datasets",
    "kinematics",
    "collision",
    "planning",
    "deformable",
    "scenarios",
    "control",
    "tissue_planning",
)
PENDING = Path(__file__).with_name("numpydoc_pending.txt")


def _public_callables():
    seen = set()
    for pkg in PACKAGES:
        mod = importlib.import_module(f"riskplan.{pkg}")
        for name in getattr(mod, "__all__", ()):
            obj = getattr(mod, name)
            if id(obj) in seen:
                continue
            seen.add(id(obj))
            if inspect.isfunction(obj):
                yield f"riskplan.{pkg}.{name}", obj
            elif inspect.isclass(obj):
                for m, v in vars(obj).items():
                    if m.startswith("_"):
                        continue
                    if isinstance(v, (classmethod, staticmethod)):
                        v = v.__func__
                    if inspect.isfunction(v):
                        yield f"riskplan.{pkg}.{name}.{m}", v


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
    if ret not in (inspect.Signature.empty, None, "None") and not (doc["Returns"] or doc["Yields"]):
        out.append("no Returns")
    return out


def _pending() -> set[str]:
    lines = PENDING.read_text(encoding="utf-8").splitlines()
    return {s.strip() for s in lines if s.strip() and not s.startswith("#")}


def test_public_callables_have_parameters_and_returns():
    pending = _pending()
    missing, fixed, seen = [], [], set()
    for name, fn in _public_callables():
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
