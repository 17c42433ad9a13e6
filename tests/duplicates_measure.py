"""The repeated-code measure of docs/architecture.md ("Measures"), counted the same way by
anyone: ``python -m tests.duplicates_measure`` (or ``make duplicates``).

It runs the stand-alone ``duplicates`` tool (every pair of places sharing six or more lines,
the same or of the same shape) twice: over ``src`` as it is, and over a copy of ``src`` in
which the **declarations that must be literal** are taken out (line numbers kept; each block
becomes one line unlike any other, so that the code around it does not join into one run):

* function signatures, from ``def`` to the body (the parameter lists of sibling entry points;
  sharing them would hide the parameters behind ``**kwargs``), and the fields of a class
  written one per line as ``name: type`` or ``name: type = constant`` (a dataclass's fields
  are its constructor's signature);
* docstrings (the numpydoc ``Parameters`` sections of sibling functions);
* imports written over several lines (the tool passes over one-line imports only) and
  ``__all__`` lists;
* decorators, and ``typer.Option`` / ``typer.Argument`` calls (typer reads a command's options
  from its signature, so they cannot come from a table);
* the arguments of a call, and the entries of a dict, list, tuple or set, written one per
  line, that only hand a value on (``seed=seed,``, ``workers=cfg.workers,``, ``"name": r.name,``): the tool sees every
  such line as the same shape, so two calls that forward six arguments each make a pair though
  they share no logic.

A pair of the second run counts unless the tool itself marks it ``boilerplate`` (what it
shares is thin: punctuation, keywords, or a shape that recurs across a folder). Both runs'
counts are printed, and the rows that count.
"""

from __future__ import annotations

import argparse
import ast
import itertools
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from functools import cache
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
ROW = re.compile(r"^D\d+ (\S+):(\d+)-(\d+) ~ (\S+):(\d+)-(\d+)(.*)$")
#: one argument (or dict, list, tuple or set entry) on its own line that hands a name, an
#: attribute or a constant on (``seed=seed,``, ``n_samples=cfg.n_samples,``, ``workers,``,
#: ``**goal,``, ``"name": r.name,``): every such line has the same shape, so any two calls with
#: six of them form a pair of "same shape" lines
FORWARD = re.compile(
    r"(?:\w+=|\*\*|(?:'[^']*'|\"[^\"]*\"): )?(?:[\w.]+|'[^']*'|\"[^\"]*\"|-?\d[\d.e_+-]*),?"
)
#: what the tool is run with (docs/architecture.md "Measures")
ARGS = ("--most", "200", "--seconds", "120")


@dataclass(frozen=True)
class Pair:
    """One row of the tool: two places (file, first line, last line) and the tool's marks."""

    a: tuple[str, int, int]
    b: tuple[str, int, int]
    marks: str

    def __str__(self) -> str:
        (fa, a0, a1), (fb, b0, b1) = self.a, self.b
        return f"{fa}:{a0}-{a1} ~ {fb}:{b0}-{b1}{self.marks}"


def parse_rows(text: str) -> list[Pair]:
    """The pairs of the tool's output ``text`` (rows ``D1 a.py:10-24 ~ b.py:40-54 ...``)."""
    out = []
    for line in text.splitlines():
        m = ROW.match(line.strip())
        if m:
            fa, a0, a1, fb, b0, b1, marks = m.groups()
            out.append(Pair((fa, int(a0), int(a1)), (fb, int(b0), int(b1)), marks))
    return out


@cache
def declaration_lines(path: str) -> frozenset[int]:
    """Line numbers of ``path`` (below ``SRC``) that are declarations which must be literal:
    function signatures, docstrings, imports, ``__all__``, decorators,
    ``typer.Option``/``typer.Argument`` calls, and
    the lines of a call's arguments that only hand a value on (:data:`FORWARD`)."""
    text = (SRC / path).read_text(encoding="utf-8")
    source = text.splitlines()
    tree = ast.parse(text)
    lines: set[int] = set()

    def span(node) -> range:
        return range(node.lineno, node.end_lineno + 1)

    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            for d in node.decorator_list:
                lines.update(span(d))
            if isinstance(node, ast.ClassDef):
                # a record's fields (`name: type` or `name: type = constant`, one per line):
                # a dataclass's fields are its constructor's signature
                lines.update(
                    st.lineno
                    for st in node.body
                    if isinstance(st, ast.AnnAssign)
                    and st.lineno == st.end_lineno
                    and (st.value is None or isinstance(st.value, ast.Constant | ast.Name))
                )
            if not isinstance(node, ast.ClassDef):
                # the header: from `def` to the line before the body's first statement
                body0 = node.body[0]
                first = body0.lineno
                lines.update(range(node.lineno, first))
            body = node.body
            if (
                body
                and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)
            ):
                lines.update(span(body[0]))
        elif isinstance(node, ast.ImportFrom) or (
            isinstance(node, ast.Assign)
            and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)
        ):
            # the tool passes over import lines, but not the continuation lines of a
            # parenthesised import; `__all__` is the module's list of names
            lines.update(span(node))
        elif isinstance(node, ast.Dict | ast.List | ast.Tuple | ast.Set):
            lines.update(
                n
                for n in range(node.lineno + 1, node.end_lineno)
                if FORWARD.fullmatch(source[n - 1].strip())
            )
        elif isinstance(node, ast.Call):
            f = node.func
            if (
                isinstance(f, ast.Attribute)
                and f.attr in ("Option", "Argument")
                and isinstance(f.value, ast.Name)
                and f.value.id == "typer"
            ):
                lines.update(span(node))
            else:
                # inside the parentheses of a call written over several lines
                lines.update(
                    n
                    for n in range(node.lineno + 1, node.end_lineno)
                    if FORWARD.fullmatch(source[n - 1].strip())
                )
    return frozenset(lines)


_OPERATORS = ("+", "-", "*", "/", "%", "&", "|", "^", "<<", ">>")


def marker(k: int) -> str:
    """A line whose shape no other marker has (the ``k``-th, in base 10 over ten operators): it
    stands in for one block of declarations, so that the code before and after the block does
    not join into one run (blank lines would let it)."""
    digits = [(k // 10**i) % 10 for i in range(5)]
    return "_ = 0 " + " ".join(f"{_OPERATORS[d]} 0" for d in digits)


def blanked(path: Path, counter, root: Path = SRC) -> str:
    """The text of ``path`` with each block of declaration lines (:func:`declaration_lines`)
    replaced by a :func:`marker` line and blank lines, so that line numbers stay those of the
    source; ``counter`` numbers the markers across files."""
    decl = declaration_lines(str(path.relative_to(root)))
    lines = path.read_text(encoding="utf-8").splitlines()
    out = []
    for n, line in enumerate(lines, start=1):
        if n not in decl:
            out.append(line)
        else:
            out.append("" if n - 1 in decl else marker(next(counter)))
    return "\n".join(out) + "\n"


def run_tool(folder: Path) -> str:
    """The tool's output over ``folder``; ``FileNotFoundError`` where it is not installed."""
    exe = shutil.which("duplicates")
    if exe is None:
        raise FileNotFoundError("duplicates")
    done = subprocess.run(
        [exe, *ARGS], cwd=folder, capture_output=True, text=True, check=False, timeout=900
    )
    return done.stdout


def measure() -> tuple[str, str]:
    """The tool's output over ``src`` as it is, and over a copy of ``src`` whose declaration
    lines are blank (the rows of the second that the tool does not mark boilerplate count)."""
    whole = run_tool(SRC)
    counter = itertools.count()
    with tempfile.TemporaryDirectory() as tmp:
        for p in sorted((SRC / "riskplan").rglob("*.py")):
            out = Path(tmp) / p.relative_to(SRC)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(blanked(p, counter), encoding="utf-8")
        return whole, run_tool(Path(tmp))


def counted(text: str) -> list[Pair]:
    """The pairs of the tool's output ``text`` that it does not mark boilerplate."""
    return [p for p in parse_rows(text) if "boilerplate" not in p.marks]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.parse_args(argv)
    try:
        whole, kept = measure()
    except FileNotFoundError:
        print("duplicates: not installed here; the measure is documented in docs/architecture.md")
        return 0
    for name, text in (("src", whole), ("src without declarations", kept)):
        rows = parse_rows(text)
        print(
            f"{name}: {len(rows)} pairs, {len(counted(text))} not marked boilerplate"
            + "".join(f"; {ln}" for ln in text.splitlines() if ln.startswith("incomplete:"))
        )
    rows = counted(kept)
    print(f"{len(rows)} repeated blocks that are not boilerplate (the measure: at most 4)")
    for pair in rows:
        print(f"  {pair}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
