"""The house's size measures (issue #21), read from the source's syntax tree:

* no module longer than 600 lines;
* no function longer than 120 lines (nested functions count toward the one they are
  defined in; a method is a function);
* no import circle between modules (a package's ``__init__.py`` that hands names on is
  followed to the module that defines them).
"""

from __future__ import annotations

import ast
from pathlib import Path

import riskplan

SRC = Path(riskplan.__file__).parent
MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 120

# What still exceeds a measure, with its size when the measure was introduced: an entry may
# only shrink; the test fails when one grows, when a new one appears, and when one is within
# the measure again (then strike it from the list). Empty lists are the goal (issue #21).
# baseline: main after the last merges of the session that introduced the measures (many grew
# or appeared in those merges; each is to be split)
KNOWN_LONG_FILES: dict[str, int] = {}
KNOWN_LONG_FUNCTIONS: dict[str, int] = {}
KNOWN_CIRCLES = []


def _files() -> list[Path]:
    return sorted(SRC.rglob("*.py"))


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _ratchet(found: dict, known: dict, what: str) -> None:
    new = {k: v for k, v in found.items() if k not in known}
    grown = {k: (known[k], v) for k, v in found.items() if k in known and v > known[k]}
    fixed = sorted(k for k in known if k not in found)
    assert not new, f"{what}: {new}"
    assert not grown, f"{what}, grown (listed, now): {grown}"
    assert not fixed, f"within the measure now, strike from the list in tests/test_size.py: {fixed}"


def test_no_file_over_600_lines():
    long = {
        str(p.relative_to(SRC)): n
        for p in _files()
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_FILE_LINES
    }
    _ratchet(long, KNOWN_LONG_FILES, f"files over {MAX_FILE_LINES} lines")


def _functions(tree: ast.AST, prefix: str = ""):
    """(qualified name, lines) of every outermost function, methods included: a function's
    nested functions are part of its lines and are not listed apart."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield prefix + node.name, node.end_lineno - node.lineno + 1
        elif isinstance(node, ast.ClassDef):
            yield from _functions(node, prefix + node.name + ".")
        else:
            yield from _functions(node, prefix)


def test_no_function_over_120_lines():
    long = {}
    for p in _files():
        tree = ast.parse(p.read_text(encoding="utf-8"))
        for name, n in _functions(tree):
            if n > MAX_FUNCTION_LINES:
                long[f"{p.relative_to(SRC)}:{name}"] = n
    _ratchet(long, KNOWN_LONG_FUNCTIONS, f"functions over {MAX_FUNCTION_LINES} lines")


def test_the_ratchet_fails_on_growth_and_on_fixed_entries():
    import pytest

    with pytest.raises(AssertionError, match="grown"):
        _ratchet({"a.py": 700}, {"a.py": 650}, "files")
    with pytest.raises(AssertionError, match="strike"):
        _ratchet({}, {"a.py": 650}, "files")
    with pytest.raises(AssertionError, match="files"):
        _ratchet({"b.py": 601}, {}, "files")
    _ratchet({"a.py": 640}, {"a.py": 650}, "files")


def _function_counter_example():
    # the measure counts nested functions toward the outer one
    code = "def f():\n" + "    def g():\n" + "        x = 1\n" * 130 + "    return g\n"
    return dict(_functions(ast.parse(code)))


def test_the_function_measure_counts_nested_functions():
    sizes = _function_counter_example()
    assert set(sizes) == {"f"} and sizes["f"] > MAX_FUNCTION_LINES


def _import_graph() -> dict[str, set[str]]:
    """module -> the riskplan modules it imports (anywhere in the file). ``from pkg import
    name`` points at ``pkg.name`` when that is a module, else at the module that ``pkg``'s
    ``__init__`` takes ``name`` from, else at ``pkg`` itself."""
    trees = {_module_name(p): (p, ast.parse(p.read_text(encoding="utf-8"))) for p in _files()}
    packages = {m for m, (p, _) in trees.items() if p.name == "__init__.py"}

    def absolute(mod: str, node: ast.ImportFrom) -> str:
        if not node.level:
            return node.module or ""
        base = mod.split(".") if mod in packages else mod.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        return ".".join(base + ([node.module] if node.module else []))

    def raw(mod: str) -> list[tuple[str, str | None]]:
        out = []
        for node in ast.walk(trees[mod][1]):
            if isinstance(node, ast.ImportFrom):
                src = absolute(mod, node)
                out += [(src, a.name) for a in node.names]
            elif isinstance(node, ast.Import):
                out += [(a.name, None) for a in node.names]
        return [(s, n) for s, n in out if s == "riskplan" or s.startswith("riskplan.")]

    def provider(pkg: str, name: str, seen=()) -> str:
        if f"{pkg}.{name}" in trees:
            return f"{pkg}.{name}"
        if pkg in packages and pkg not in seen:
            for src, n in raw(pkg):
                if n == name and src != pkg:
                    return provider(src, name, (*seen, pkg)) if src in packages else src
        return pkg

    graph = {}
    for mod in trees:
        deps = set()
        for src, name in raw(mod):
            target = provider(src, name) if name else src
            if target in trees and target != mod:
                deps.add(target)
        graph[mod] = deps
    return graph


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_circle():
    graph = _import_graph()
    # package faces that only hand names on are followed, not counted: a face that imports
    # its own modules is no circle
    faces = {m for m in graph if (SRC.parent / m.replace(".", "/") / "__init__.py").exists()}
    for f in faces:
        graph[f] = set()
    circles = _circles(graph)
    new = [c for c in circles if c not in KNOWN_CIRCLES]
    fixed = [c for c in KNOWN_CIRCLES if c not in circles]
    assert not new, f"import circles: {new}"
    assert not fixed, f"no longer a circle, strike from KNOWN_CIRCLES: {fixed}"


def test_the_circle_finder_finds_a_circle():
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
