"""The repeated-code measure (docs/architecture.md "Measures"): the rule that takes the
declarations out (tests/duplicates_measure.py), and the count itself where the stand-alone
``duplicates`` tool is installed (it is not on PyPI)."""

from __future__ import annotations

import itertools
import shutil
import textwrap

import pytest

from tests import duplicates_measure as dm

#: the measured count (the measure: at most 4; docs/architecture.md "Measures" names the four);
#: it may only shrink
KNOWN_REPEATED_BLOCKS = 4

SAMPLE = textwrap.dedent(
    '''\
    from riskplan.errors import (
        InvalidInputError,
    )

    __all__ = [
        "f",
    ]


    @decorator
    def f(
        a,
        b=1,
    ):
        """Doc.

        Parameters
        ----------
        a : int
        """
        x = g(
            "text",
            h(a),
            a=a,
            b=cfg.b,
        )
        d = {
            "name": a,
            "len": len(a),
        }
        opt: int = typer.Option(
            0, "--opt", help="an option"
        )
        return x + 1
    '''
)


def test_declaration_lines(tmp_path, monkeypatch):
    (tmp_path / "m.py").write_text(SAMPLE, encoding="utf-8")
    monkeypatch.setattr(dm, "SRC", tmp_path)
    dm.declaration_lines.cache_clear()
    try:
        decl = dm.declaration_lines("m.py")
    finally:
        dm.declaration_lines.cache_clear()
    lines = SAMPLE.splitlines()
    kept = [lines[n - 1].strip() for n in range(1, len(lines) + 1) if n not in decl]
    # what stays is code: the calls themselves, arguments that compute, the return
    assert [k for k in kept if k] == [
        "x = g(",
        "h(a),",
        ")",
        "d = {",
        '"len": len(a),',
        "}",
        "return x + 1",
    ]


def test_markers_differ_and_stand_for_blocks(tmp_path, monkeypatch):
    markers = {dm.marker(k) for k in range(2000)}
    assert len(markers) == 2000
    (tmp_path / "m.py").write_text(SAMPLE, encoding="utf-8")
    monkeypatch.setattr(dm, "SRC", tmp_path)
    dm.declaration_lines.cache_clear()
    try:
        out = dm.blanked(tmp_path / "m.py", itertools.count(), root=tmp_path).splitlines()
    finally:
        dm.declaration_lines.cache_clear()
    assert len(out) == len(SAMPLE.splitlines())  # line numbers kept
    assert out[0] == dm.marker(0) and out[1] == out[2] == ""  # one marker per block


def test_parse_rows():
    text = (
        "3 pairs of places (2 files read), ...\n"
        "D1 a.py:10-24 ~ b.py:40-54 shape (+2 more runs)\n"
        "D2 a.py:1-6 ~ a.py:8-13 shape boilerplate\n"
        "left out: 1 run\n"
    )
    rows = dm.parse_rows(text)
    assert [str(r) for r in rows] == [
        "a.py:10-24 ~ b.py:40-54 shape (+2 more runs)",
        "a.py:1-6 ~ a.py:8-13 shape boilerplate",
    ]
    assert [str(r) for r in dm.counted(text)] == ["a.py:10-24 ~ b.py:40-54 shape (+2 more runs)"]


@pytest.mark.skipif(
    shutil.which("duplicates") is None, reason="the duplicates tool is not installed"
)
def test_repeated_code_does_not_grow():
    _, kept = dm.measure()
    rows = dm.counted(kept)
    assert "incomplete:" not in kept, kept
    assert len(rows) <= KNOWN_REPEATED_BLOCKS, "repeated blocks:\n" + "\n".join(map(str, rows))
