"""docs/architecture.md names every module, and library code imports no higher layer."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import riskplan

SRC = Path(riskplan.__file__).parent
DOC = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"
#: the layers, bottom up: a shared core, two wings that never import each other (each a
#: chain: a package imports only packages before it in its wing, and the core), and the
#: application layer, which may import anything
CORE = {
    "errors",
    "io",
    "_validation",
    "threads",
    "parallel",
    "_workers",
    "budget",
    "parsing",
    "gaussian_mixture",
    "kinematics_model",
    "geometry2d",
    "_triangles",
    "geometry3d",
    "robots",
    "collision",
}
KINEMATIC_WING = ("datasets", "kinematics", "planning")
TISSUE_WING = ("deformable", "scenarios", "control", "tissue_planning")
#: ``kernels`` is the ``riskplan warm`` list: it names (and imports, to compile) the kernel
#: modules of the core and of both wings, so it sits above the wings, beside the CLI
APPLICATION = {"app", "bench", "commands", "cli", "__main__", "kernels"}


def _modules():
    return sorted(p.relative_to(SRC) for p in SRC.rglob("*.py") if p.name != "__init__.py")


def _module_lists() -> dict[str, str]:
    """The "## Modules" section of docs/architecture.md: its text per package bullet
    (``* `pkg/`: ...``) and the top-level paragraph under ``""``."""
    text = DOC.read_text(encoding="utf-8")
    section = text.split("## Modules", 1)[1].split("\n## ", 1)[0]
    out = {"": section.split("\n* ", 1)[0]}
    for bullet in section.split("\n* ")[1:]:
        pkg = bullet.split("`", 2)[1].rstrip("/")
        out[pkg] = bullet
    return out


def test_architecture_doc_lists_every_module():
    lists = _module_lists()
    missing = []
    for m in _modules():
        pkg = m.parts[0] if len(m.parts) > 1 else ""
        # a module in a sub-package is named with its folder: `demo/robot.py`
        name = "/".join(m.parts[1:]) if pkg else m.name
        if f"`{name}`" not in lists.get(pkg, ""):
            missing.append(str(m))
    assert not missing, f"docs/architecture.md, section Modules, does not name: {missing}"


def _riskplan_imports(rel: Path) -> list[str]:
    """The riskplan packages (first component after ``riskplan.``) that module ``rel`` imports:
    by an import statement, or by name — a string that is a module path (``"riskplan.x.y"``, as
    ``importlib.import_module`` takes it) or the literal start of an f-string
    (``f"riskplan.x.{name}"``) counts as an import of ``x``, so an edge cannot hide in a call."""
    return _imports_in((SRC / rel).read_text(encoding="utf-8"))


def _imports_in(text: str) -> list[str]:
    tree = ast.parse(text)
    out = []
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            if re.fullmatch(r"riskplan(\.\w+)+", node.value):
                names = [node.value]
        elif isinstance(node, ast.JoinedStr) and node.values:
            head = node.values[0]
            if isinstance(head, ast.Constant) and re.match(r"riskplan\.\w+\.", str(head.value)):
                names = [str(head.value)]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module]
            if node.module == "riskplan":
                names = [f"riskplan.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "riskplan" and len(parts) > 1:
                out.append(parts[1])
    return out


def _allowed(pkg: str) -> set[str] | None:
    """Packages ``pkg`` may import (None: anything)."""
    if pkg in APPLICATION:
        return None
    if pkg in CORE:
        return CORE
    for wing in (KINEMATIC_WING, TISSUE_WING):
        if pkg in wing:
            return CORE | set(wing[: wing.index(pkg) + 1])
    raise AssertionError(f"riskplan.{pkg} is in no layer of tests/test_architecture.py")


def test_an_import_by_name_is_an_import():
    text = (
        "import importlib\n"
        "k = importlib.import_module('riskplan.deformable.nhkernels')\n"
        "m = importlib.import_module(f'riskplan.scenarios.{name}')\n"
        "from riskplan.collision import Environment\n"
        "'riskplan plans; riskplan.robots is the robot package'  # prose, not a module path\n"
    )
    assert sorted(_imports_in(text)) == ["collision", "deformable", "scenarios"]


def test_layers_core_two_wings_and_application():
    """The import rule of docs/architecture.md: the core imports only the core; each wing
    imports the core and the packages below it in its own wing, never the other wing; library
    code never imports the application layer."""
    bad = []
    all_modules = _modules() + [p.relative_to(SRC) for p in SRC.rglob("__init__.py")]
    for rel in all_modules:
        if rel == Path("__init__.py"):
            continue  # the package's face: lazy names from every layer, checked below
        pkg = rel.parts[0].removesuffix(".py")
        allowed = _allowed(pkg)
        if allowed is None:
            continue
        bad += [f"{rel}: riskplan.{d}" for d in _riskplan_imports(rel) if d not in allowed]
    assert not bad, bad


def test_the_face_imports_no_layer_eagerly():
    """``riskplan/__init__.py`` imports no package at module level (names load lazily)."""
    tree = ast.parse((SRC / "__init__.py").read_text(encoding="utf-8"))
    eager = [
        n.module
        for n in tree.body
        if isinstance(n, ast.ImportFrom) and n.module and n.module.startswith("riskplan.")
    ]
    assert set(eager) <= {"riskplan.errors"}, eager


def test_array_packages_import_without_torch():
    """The mixture core and collision are array code: importing them never imports torch
    (a torch ``GaussianMixture`` is still accepted, through its ``to_numpy()``)."""
    code = (
        "import sys\n"
        "import riskplan.gaussian_mixture, riskplan.collision\n"
        "print(sorted(m for m in sys.modules if m == 'torch' or m.startswith('torch.')))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=os.environ
    )
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_one_version():
    # riskplan.__version__ is what data sets and model files record; it must be the installed
    # distribution's version (pyproject.toml)
    from importlib.metadata import version

    import riskplan

    assert riskplan.__version__ == version("riskplan")


def test_one_command_line():
    """The typer CLI is the one command line: no module but ``cli.py`` and ``__main__.py``
    carries a ``__main__`` block or argparse."""
    bad = []
    for rel in _modules():
        if rel.name in {"cli.py", "__main__.py"}:
            continue
        text = (SRC / rel).read_text(encoding="utf-8")
        if '__name__ == "__main__"' in text or "import argparse" in text:
            bad.append(str(rel))
    assert not bad, bad
