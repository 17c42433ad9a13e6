"""Docs that run: every ```python block of README.md and docs/*.md, and every docstring
example (``>>>``) in the package, is executed here, so the documentation cannot rot.

The blocks of one Markdown file run in order in one namespace (like a notebook), in a fresh
working directory. A block that must not run (it needs a cluster, or it is a fragment of a
larger program) is preceded by the line ``<!-- not executed: REASON -->``; the reason is
required and shown in the test id.
"""

from __future__ import annotations

import doctest
import importlib
import os
import re
from pathlib import Path

import pytest

import riskplan

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_BLOCK = re.compile(
    r"^(?:<!-- not executed: (?P<why>[^>]+?) -->\n)?```python\n(?P<code>.*?)^```", re.S | re.M
)


def python_blocks(path: Path) -> list[tuple[str, str | None, int]]:
    """``(code, reason_not_executed_or_None, line)`` for each ```python block of ``path``."""
    text = path.read_text(encoding="utf-8")
    return [
        (m["code"], m["why"], text.count("\n", 0, m.start()) + 1) for m in _BLOCK.finditer(text)
    ]


def test_block_parser_sees_markers(tmp_path):
    md = tmp_path / "x.md"
    md.write_text(
        "a\n```python\nx = 1\n```\n<!-- not executed: needs a cluster -->\n```python\ny\n```\n"
    )
    assert python_blocks(md) == [("x = 1\n", None, 2), ("y\n", "needs a cluster", 5)]


@pytest.mark.parametrize(
    "path", [p for p in DOCS if python_blocks(p)], ids=lambda p: p.relative_to(ROOT).as_posix()
)
def test_markdown_python_blocks_run(path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": f"docs:{path.name}"}
    for code, why, line in python_blocks(path):
        if why is not None:
            continue
        try:
            exec(compile(code, f"{path.relative_to(ROOT)}:{line}", "exec"), namespace)
        except Exception as exc:  # report the block, not this helper
            pytest.fail(
                f"{path.relative_to(ROOT)}, block at line {line}: {type(exc).__name__}: {exc}"
            )


def _modules_with_examples() -> list[str]:
    src = Path(riskplan.__file__).parent
    names = []
    for p in sorted(src.rglob("*.py")):
        if ">>>" in p.read_text(encoding="utf-8"):
            rel = p.relative_to(src.parent).with_suffix("")
            names.append(".".join(part for part in rel.parts if part != "__init__"))
    return names


@pytest.mark.parametrize("module", _modules_with_examples())
def test_docstring_examples_run(module, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    os.environ.setdefault("MPLBACKEND", "Agg")
    mod = importlib.import_module(module)
    result = doctest.testmod(
        mod, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False
    )
    assert result.failed == 0, (
        f"{module}: {result.failed} of {result.attempted} docstring examples failed"
    )
