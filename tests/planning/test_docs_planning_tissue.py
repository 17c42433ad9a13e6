"""The code in the tissue-planning block of docs/planning.md runs (docs that cannot rot)."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

DOC = Path(__file__).resolve().parents[2] / "docs" / "planning.md"


def _blocks() -> list[str]:
    text = DOC.read_text()
    block = text[
        text.index("<!-- BEGIN planning-tissue -->") : text.index("<!-- END planning-tissue -->")
    ]
    return re.findall(r"```python\n(.*?)```", block, flags=re.S)


def test_docs_python_blocks_run():
    blocks = _blocks()
    assert blocks
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for code in blocks:
            exec(compile(code, str(DOC), "exec"), {})
