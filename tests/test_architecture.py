"""docs/architecture.md names every module, and library code imports no higher layer."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import riskplan

SRC = Path(riskplan.__file__).parent
DOC = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"
#: packages and modules that may import anything (the application layer)
APPLICATION = {"bench", "commands", "experiments", "cli", "__main__"}


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
        if f"`{m.name}`" not in lists.get(pkg, ""):
            missing.append(str(m))
    assert not missing, f"docs/architecture.md, section Modules, does not name: {missing}"


def test_library_never_imports_the_application_layer():
    bad = []
    for rel in _modules() + [p.relative_to(SRC) for p in SRC.rglob("__init__.py")]:
        if rel.parts[0].removesuffix(".py") in APPLICATION:
            continue
        tree = ast.parse((SRC / rel).read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for name in names:
                parts = name.split(".")
                if parts[0] == "riskplan" and len(parts) > 1 and parts[1] in APPLICATION:
                    bad.append(f"{rel}: {name}")
    assert not bad, bad


def test_array_packages_import_without_torch():
    """The mixture core and collision are array code: importing them never imports torch
    (a torch ``GaussianMixture`` is still accepted, through its ``to_numpy()``)."""
    code = (
        "import sys\n"
        "import riskplan.gaussian_mixture, riskplan.collision, riskplan.collision.robot_geometry\n"
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
