"""Numeric tolerances in tests come from the TOL table in tests/conftest.py.

An AST scan of every test module flags two kinds of bare tolerance literal:

* a number passed as ``rtol=``, ``atol=``, ``rel=``, ``abs=``, ``rel_tol=`` or ``abs_tol=``
  (``np.testing.assert_allclose``, ``np.isclose``, ``pytest.approx``, ``math.isclose`` ...),
  or a float factor in such an argument (``atol=1e-12 * np.abs(K).max()``);
* a float of magnitude below 1e-3 that is an operand of a comparison (``err < 1e-6``,
  ``x >= -1e-10``, ``r <= 1e-8 * f + 1e-12``), reached through arithmetic only, not through a
  call's arguments (``solve(x, 1e-12) == OK`` passes a solver setting, not a tolerance).

Zero (``rtol=0``) is never flagged: it says "this part of the tolerance is off", not how large.
Literals that are physical quantities or statistical thresholds stay readable where they are and
are listed in ``EXCEPTIONS`` with the reason; a new bare tolerance makes this test fail.
"""

from __future__ import annotations

import ast
import math
from collections import Counter
from pathlib import Path

import pytest

from tests.conftest import TOL

TESTS = Path(__file__).parent
KEYWORDS = {"rtol", "atol", "rel", "abs", "rel_tol", "abs_tol"}
SMALL = 1e-3

#: (file relative to tests/, enclosing function, literal as written) -> why it stays a literal
EXCEPTIONS: dict[tuple[str, str, str], str] = {
    (
        "deformable/test_hyperelastic.py",
        "test_tolerance_that_accepts_any_start_is_rejected",
        "1.0",
    ): "an invalid solver tolerance the constructor must reject, not a comparison tolerance",
    (
        "datasets/test_generate.py",
        "test_clouds_lie_on_the_robot_and_spread_with_the_path",
        "0.0005",
    ): "camera noise sd (m) in a bound on the cloud's distance, a physical quantity",
    (
        "datasets/test_generate.py",
        "test_clouds_lie_on_the_robot_and_spread_with_the_path",
        "0.0001",
    ): "tip spread (m) that path dependence must exceed, a physical threshold",
    (
        "planning/test_validate.py",
        "test_tube_clearance_between_coarse_samples",
        "0.0001",
    ): "length (m) at the test's sampling resolution of the backbone (2e-4 m), not round-off",
    (
        "planning/test_validate.py",
        "test_single_configuration_matches_training_data_physics",
        "0.0001",
    ): "hysteresis spread of the reach (m) that must show, a physical threshold",
    (
        "robots/test_geometry.py",
        "test_whole_surface_is_on_the_union_boundary",
        "2e-05",
    ): "geometric bound kappa r t / 2 = 18 um on the disk rim's dip into the tube (m)",
    (
        "bench/test_tissue_bench.py",
        "test_bench_times_the_scenarios_public_step",
        "0.0001",
    ): "displacement (m) a timed step must produce to count as real work, a physical threshold",
    (
        "scenarios/test_needle.py",
        "test_car_steer_lands_on_target",
        "1e-06",
    ): "distance (m) by which two steps must miss a target that needs three, a physical threshold",
    (
        "scenarios/test_needle.py",
        "test_car_steer_random_targets_in_bounds_and_exact_when_feasible",
        "0.0001",
    ): "0.1 mm grid-search reach that marks a target as feasible, a physical threshold",
}


def _number(node: ast.AST) -> float | None:
    """Value of a literal number (possibly negated or combined by arithmetic), else None."""
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        return float(node.value)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        v = _number(node.operand)
        return None if v is None else (-v if isinstance(node.op, ast.USub) else v)
    if isinstance(node, ast.BinOp):
        a, b = _number(node.left), _number(node.right)
        if a is None or b is None:
            return None
        try:
            return float(eval(compile(ast.Expression(node), "<literal>", "eval")))
        except ArithmeticError:
            return None
    return None


def _operands(node: ast.AST, low: float, high: float):
    """Float constants with ``low < |value| < high`` reached from ``node`` through arithmetic
    (not through calls, subscripts or attributes)."""
    if isinstance(node, ast.Constant) and type(node.value) is float:
        if low < abs(node.value) < high:
            yield node
    elif isinstance(node, ast.UnaryOp):
        yield from _operands(node.operand, low, high)
    elif isinstance(node, ast.BinOp):
        yield from _operands(node.left, low, high)
        yield from _operands(node.right, low, high)


def bare_tolerances(path: Path) -> list[tuple[str, str, str, int]]:
    """(enclosing function, literal, kind, line) of each bare tolerance literal in one file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []

    def visit(node: ast.AST, func: str) -> None:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            func = node.name
        if isinstance(node, ast.keyword) and node.arg in KEYWORDS:
            v = _number(node.value)
            if v is not None:
                if v != 0.0:
                    found.append((func, ast.unparse(node.value), f"{node.arg}=", node.lineno))
            else:  # e.g. atol=1e-12 * np.abs(K).max(): the literal factor is the tolerance
                for c in _operands(node.value, 0.0, math.inf):
                    found.append((func, repr(c.value), f"{node.arg}=", c.lineno))
        if isinstance(node, ast.Compare):
            for operand in (node.left, *node.comparators):
                for c in _operands(operand, 0.0, SMALL):
                    found.append((func, repr(c.value), "comparison", c.lineno))
        for child in ast.iter_child_nodes(node):
            visit(child, func)

    visit(tree, "<module>")
    return found


def _test_files() -> list[Path]:
    return sorted(p for p in TESTS.rglob("*.py") if p != TESTS / "conftest.py")


def test_no_bare_tolerance_literals():
    problems, used = [], Counter()
    for path in _test_files():
        rel = path.relative_to(TESTS).as_posix()
        for func, literal, kind, line in bare_tolerances(path):
            key = (rel, func, literal)
            if key in EXCEPTIONS:
                used[key] += 1
            else:
                problems.append(f"tests/{rel}:{line} ({func}): {kind} {literal}")
    assert not problems, (
        "bare tolerance literals; name them in TOL (tests/conftest.py) or, for a physical "
        "quantity or statistical threshold, add them to EXCEPTIONS with the reason:\n"
        + "\n".join(problems)
    )
    stale = sorted(set(EXCEPTIONS) - set(used))
    assert not stale, f"EXCEPTIONS entries that match nothing any more: {stale}"


@pytest.mark.parametrize(
    "source,n",
    [
        ("np.testing.assert_allclose(a, b, rtol=1e-9, atol=0)", 1),
        ("pytest.approx(x, abs=1e-12)", 1),
        ("math.isclose(a, b, rel_tol=-(1e-9))", 1),
        ("assert err < 1e-6", 1),
        ("assert r <= 1e-8 * f + 1e-12", 2),
        ("assert lam.min() >= -1e-10", 1),
        ("np.testing.assert_allclose(a, b, **TOL['solver'])", 0),
        ("assert fn(x, 1e-12) == OK", 0),
        ("assert d > 1e-3", 0),
        ("np.testing.assert_allclose(a, b, atol=1e-12 * np.abs(b).max())", 1),
        ("np.testing.assert_allclose(a, b, atol=TOL['x']['atol'] * np.abs(b).max())", 0),
        ("assert err < TOL['solver']['atol']", 0),
    ],
)
def test_the_scan_finds_what_it_should(tmp_path, source, n):
    f = tmp_path / "t.py"
    f.write_text(f"def test():\n    {source}\n")
    assert len(bare_tolerances(f)) == n


def test_table_entries_are_tolerances():
    """Every entry names both parts; none is negative; comments give the reason in conftest.py."""
    for name, t in TOL.items():
        assert set(t) == {"rtol", "atol"}, name
        assert t["rtol"] >= 0 and t["atol"] >= 0, name
        assert t["rtol"] > 0 or t["atol"] > 0, name
    text = (TESTS / "conftest.py").read_text(encoding="utf-8")
    for name in TOL:
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(f'"{name}"'))
        assert "#" in line, f"TOL[{name!r}] has no reason"
