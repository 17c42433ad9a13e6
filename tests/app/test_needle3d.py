"""The 3-D needle study: estimators and executions on one hand-made plan, the figure, the
command's bad input."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.app.reproduce.needle3d import needle3d_figure
from riskplan.control import NominalPlan
from riskplan.scenarios.registry import scenario_from_config
from riskplan.tissue_planning.needle3d import (
    ESTIMATORS,
    GOAL_SE,
    MAX_GOAL_SAMPLES,
    MAX_PARTICLES,
    PARTICLES_BATCH,
    PARTICLES_SE,
    evaluate_candidates,
    measure_plan,
)
from riskplan.tissue_planning.needle3d_checks import measure_structured


@pytest.fixture(scope="module")
def straight():
    sim = scenario_from_config("needle3d", None, "actuation")
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), np.tile([0.5, 10.0], (16, 1)))
    assert sim.in_goal(plan.states[-1]) and not any(sim.in_collision(s) for s in plan.states)
    return sim, plan


def test_estimators_and_executions_on_common_draws(straight):
    sim, plan = straight
    ctrls, rows = evaluate_candidates(sim, [plan], seed=0, n_goal_samples=500)
    row = rows[0]
    assert ctrls[0] is not None and set(row.estimates) == set(ESTIMATORS)
    assert all(0.0 <= p <= 1.0 for p in row.estimates.values())
    # every estimate but sampling with the exact goal test (no draws, its error bound), and
    # the comparison with the goal test drawn to GOAL_SE (or the cap), in batches of 500
    for m in ESTIMATORS:
        n_m, se = row.estimate_n[m], row.estimate_se[m]
        if m == "sampling":
            assert n_m == 500
        elif m == "particles":  # whole batches to the target standard error
            assert n_m % PARTICLES_BATCH == 0 and 0.0 < se < 1.0
            assert se <= PARTICLES_SE or n_m == MAX_PARTICLES
        else:
            assert n_m == 0 and 0.0 <= se <= GOAL_SE
    d = row.draws
    assert d["n"] % 500 == 0 and (d["se"] <= GOAL_SE or d["n"] == MAX_GOAL_SAMPLES)
    assert abs(d["truncation"] - row.estimates["truncation"]) <= 4.5 * d["se"] + GOAL_SE
    assert d["cpu_s"] > 0.0 and 0.0 <= d["linear"] <= 1.0
    assert len(row.estimate_cpu_s["truncation_repeats"]) == 2
    # sigma's chi-square factor is conservative against the truncation's half-spaces
    assert row.estimates["sigma"] <= row.estimates["truncation"]
    measure_plan(sim, plan, ctrls[0], row, n=4, seed=1)
    assert row.n == 4
    for mode in ("closed", "open"):
        outcomes = getattr(row, f"outcomes_{mode}")
        assert sum(outcomes.values()) == 4
        assert outcomes.get("success", 0) == getattr(row, mode)
        lo, hi = getattr(row, f"{mode}_ci")
        assert lo <= getattr(row, mode) / 4 <= hi
        assert getattr(row, f"target_error_{mode}") >= 0.0


def test_accuracy_checks_and_speed_ratios():
    """Within ±2 points of all executions, inside the Wilson interval of the first ones
    (here [0.8763, 0.9552] for 92 of 100), the counterfactual on each side; speed ratios."""
    from riskplan.tissue_planning.needle3d_checks import (
        CHECK_POINTS,
        accuracy_checks,
        speed_ratios,
    )

    assert CHECK_POINTS == 0.02
    est = {"a": 0.915, "b": 0.8949, "c": 0.8951, "d": 0.96, "e": float("nan")}
    got = accuracy_checks(est, 9150, 10_000, 92, 100)
    assert [got[m]["within_points"] for m in "abcde"] == [True, False, True, False, False]
    assert [got[m]["inside_first"] for m in "abcde"] == [True, True, True, False, False]
    assert got["a"]["error"] == 0.915 - 0.915 and got["b"]["error"] == 0.8949 - 0.915
    sp = speed_ratios({"truncation": 0.5, "truncation_repeats": [0.4, 0.5], "x": 0.0}, 100.0, 10.0)
    assert sp == {"truncation": {"all": 200.0, "first": 20.0}}


def test_split_executions_equal_one_process(straight, monkeypatch):
    """The executions split into tasks (3 draws each, a task across the open-loop edge)
    give what one process gives on the same draws: counts, intervals, targeting errors."""
    import riskplan.tissue_planning.needle3d_checks as checks
    from riskplan.tissue_planning.needle3d import PlanRow

    sim, plan = straight
    ctrls, rows = evaluate_candidates(sim, [plan], seed=0, n_goal_samples=200)
    one = measure_plan(sim, plan, ctrls[0], PlanRow(0, 16, {}, {}), n=7, seed=3, n_open=4)
    assert (one.n, one.n_open) == (7, 4)
    assert sum(one.outcomes_closed.values()) == 7 and sum(one.outcomes_open.values()) == 4
    assert one.closed_first <= one.closed and one.closed_first_cpu_s <= one.closed_cpu_s
    monkeypatch.setattr(checks, "DRAWS_PER_TASK", 3)
    (split,) = checks.measure_checked(
        sim, [plan], ctrls, [rows[0]], n=7, n_open=4, seed=3, structured=False, workers=1
    )
    for name in ("n", "n_open", "closed", "closed_ci", "closed_first", "closed_first_ci"):
        assert getattr(split, name) == getattr(one, name), name
    for name in ("open", "open_ci", "outcomes_closed", "outcomes_open"):
        assert getattr(split, name) == getattr(one, name), name
    for name in ("target_error_closed", "target_error_open", "end_error_open"):
        assert getattr(split, name) == getattr(one, name), name
    assert set(split.checks) == set(ESTIMATORS) and "truncation" in split.speed


def test_structured_check_executes_on_the_same_draws(straight):
    """The structured linearisation's controller: its prediction, executions counted with a
    Wilson interval, CPU seconds; a case beyond the actuation noise is left alone."""
    from riskplan.tissue_planning.needle3d import PlanRow

    sim, plan = straight
    row = measure_structured(sim, plan, PlanRow(0, plan.n_steps, {}, {}), n=4, seed=1)
    st = row.structured
    assert 0.0 <= st["prediction"] <= 1.0 and 0 <= st["closed"] <= 4
    lo, hi = st["closed_ci"]
    assert lo <= st["closed"] / 4 <= hi
    assert st["lin_cpu_s"] > 0.0 and st["cpu_s"] > 0.0 and st["closed_cpu_s"] > 0.0
    other = scenario_from_config("needle3d", None, "material-high")
    assert measure_structured(other, plan, PlanRow(0, 16, {}, {}), n=4).structured == {}


def test_figure_has_block_bodies_and_plans(straight):
    sim, plan = straight
    fig = needle3d_figure(sim, [plan, plan], executed=[plan.reduced[:, :3]], highlight=0)
    names = [t.name for t in fig.data]
    assert "target" in names and sum(n.startswith("obstacle") for n in names if n) == 3
    assert "executed" in names


def test_outputs_are_written_whole(straight, tmp_path):
    from riskplan.app.reproduce.needle3d import write_outputs
    from riskplan.tissue_planning.needle3d import Needle3DResult

    sim, plan = straight
    ctrls, rows = evaluate_candidates(sim, [plan], seed=0, n_goal_samples=200)
    res = Needle3DResult([plan], rows, 0, ctrls[0], {"rrt_s": 0.0}, {"case": "actuation"})
    files = write_outputs(res, tmp_path, n_executed=1)
    with np.load(files["selected"]) as z:
        np.testing.assert_array_equal(z["controls"], plan.controls)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "needle3d.html",
        "selected.npz",
        "summary.json",
    ]


def test_plan_needle3d_rejects_a_bad_case(tmp_path):
    from typer.testing import CliRunner

    from riskplan.cli import app

    res = CliRunner().invoke(
        app, ["plan", "needle3d", "--case", "nope", "--out", str(tmp_path / "o")]
    )
    assert res.exit_code != 0
    assert "--case" in (res.output + str(res.exception))


def test_plan_needle3d_rejects_bad_run_counts():
    from riskplan.errors import InvalidInputError
    from riskplan.tissue_planning.needle3d import plan_needle3d

    with pytest.raises(InvalidInputError, match="open_runs"):
        plan_needle3d(check_runs=10, open_runs=0)
    with pytest.raises(InvalidInputError, match="check_runs"):
        plan_needle3d(check_runs=-1)
    # checked before any work: an unknown frame no longer waits for the RRT to fail
    with pytest.raises(InvalidInputError, match="frame"):
        plan_needle3d(frame="body")
    with pytest.raises(InvalidInputError, match="case"):
        plan_needle3d("nope")
    with pytest.raises(InvalidInputError, match="check_plans"):
        plan_needle3d(check_plans=0)


def test_summary_rows_show_checked_and_unchecked_plans():
    """The command's table: a checked plan's counts, interval and ±2-point check; an
    unchecked one (and an estimate that does not apply) shows "-"."""
    from riskplan.app.reproduce.needle3d import SUMMARY_HEADER, summary_rows
    from riskplan.tissue_planning.needle3d import Needle3DResult, PlanRow

    est = dict.fromkeys(ESTIMATORS, 0.9)
    checked = PlanRow(3, 20, est, {}, n=100, closed=93, closed_ci=(0.86, 0.97), open=40)
    checked.n_open, checked.closed_first = 50, 45
    checked.checks = {"truncation": {"within_points": False}}
    unchecked = PlanRow(1, 22, dict(est, particles=float("nan")), {})
    res = Needle3DResult([], [checked, unchecked], 3, None, {}, {})
    rows = summary_rows(res)
    assert all(len(r) == len(SUMMARY_HEADER) for r in rows)
    assert rows[0] == (
        "3", "20", "0.900", "0.900", "0.900", "0.900", "0.900",
        "93/100", "[0.860, 0.970]", "no", "45/50", "40/50",
    )  # fmt: skip
    assert rows[1] == ("1", "22", *["0.900"] * 4, "-", "-", "-", "-", "-", "-")


def test_material_frame_outputs_execute_in_their_frame(straight, tmp_path):
    """A material-frame controller is executed on the material-frame scenario, and the
    figure's executed paths are world tip positions (beside the world plan)."""
    from riskplan.app.reproduce.needle3d import needle3d_figure, write_outputs
    from riskplan.tissue_planning.needle3d import Needle3DResult

    sim, plan = straight
    mat = sim.with_frame("material")
    ctrls, rows = evaluate_candidates(mat, [plan.reframed(mat)], seed=0, n_goal_samples=200)
    assert rows[0].estimates["truncation"] > 0.0
    res = Needle3DResult(
        [plan], rows, 0, ctrls[0], {"rrt_s": 0.0}, {"case": "actuation", "frame": "material"}
    )
    files = write_outputs(res, tmp_path, n_executed=1)
    assert files["figure"].stat().st_size > 0
    fig = needle3d_figure(sim, [plan], executed=[sim.path(plan.states)])
    assert "executed" in [t.name for t in fig.data]


def test_report_section_shows_intervals_and_speed(tmp_path):
    """The report's 3-D needle table: the Wilson interval, whether the truncation lies in
    it, and the CPU speed ratio of the estimate against the closed-loop executions."""
    from riskplan.app.report import Report
    from riskplan.app.reproduce.report_deformable import _needle3d_section
    from riskplan.tissue_planning.needle3d import PlanRow

    est = dict.fromkeys(ESTIMATORS, 0.9)
    checked = PlanRow(0, 20, est, {}, n=100, closed=93, closed_ci=(0.86, 0.97))
    checked.n_open, checked.closed_first, checked.closed_first_ci = 50, 45, (0.79, 0.96)
    checked.estimate_cpu_s = {"truncation": 0.05, "truncation+linearise": 0.2}
    checked.closed_cpu_s = 10.0
    checked.estimate_se, checked.estimate_n = {"truncation": 3e-4}, {"truncation": 12000}
    unchecked = PlanRow(1, 22, est, {})
    r = {
        "settings": {"case": "actuation", "n_plans": 2, "n_elements": 1296, "check_runs": 100},
        "figure": "needle3d/needle3d.html",
        "rows": [checked.as_dict(), unchecked.as_dict()],
    }
    rep = Report(tmp_path)
    _needle3d_section(rep, r)
    text = " ".join(str(b) for sec in rep.sections for b in sec.blocks)
    assert "93/100 [0.860, 0.970]" in text and "200× (50×)" in text and "world frame" in text
    assert "45/50 [0.790, 0.960]" in text and "within ±2 points" in text
    assert "0.9000 ± 0.0003 (12,000 draws)" in text
    checked.estimate_se, checked.estimate_n = {"truncation": 1e-10}, {"truncation": 0}
    r["rows"] = [checked.as_dict()]
    rep = Report(tmp_path)
    _needle3d_section(rep, r)
    text = " ".join(str(b) for sec in rep.sections for b in sec.blocks)
    assert "0.9000 (exact goal test)" in text
