"""The usage block of docs/control.md runs (docs that cannot rot)."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

DOC = Path(__file__).resolve().parents[2] / "docs" / "control.md"


def test_usage_block_runs():
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    assert blocks
    ns: dict = {}
    with warnings.catch_warnings():
        warnings.simplefilter(
            "ignore"
        )  # the needle's rank-deficiency warning is expected (see the doc)
        exec(compile(blocks[0], str(DOC), "exec"), ns)
    assert 0.0 <= ns["est"].p_success <= 1.0
    assert ns["mc"].low <= ns["mc"].probability <= ns["mc"].high
