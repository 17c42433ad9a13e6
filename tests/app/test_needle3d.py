"""The 3-D needle study: estimators and executions on one hand-made plan, the figure, the
command's bad input."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.app.reproduce.needle3d import (
    ESTIMATORS,
    GOAL_SE,
    MAX_GOAL_SAMPLES,
    N_PARTICLES,
    evaluate_candidates,
    measure_plan,
    needle3d_figure,
)
from riskplan.app.reproduce.needle3d_checks import measure_structured
from riskplan.control import NominalPlan
from riskplan.scenarios.registry import scenario_from_config


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
        elif m == "particles":
            assert n_m == N_PARTICLES and 0.0 < se < 1.0
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


def test_structured_check_executes_on_the_same_draws(straight):
    """The structured linearisation's controller: its prediction, executions counted with a
    Wilson interval, CPU seconds; a case beyond the actuation noise is left alone."""
    from riskplan.app.reproduce.needle3d import PlanRow

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
    from riskplan.app.reproduce.needle3d import Needle3DResult, write_outputs

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


def test_material_frame_outputs_execute_in_their_frame(straight, tmp_path):
    """A material-frame controller is executed on the material-frame scenario, and the
    figure's executed paths are world tip positions (beside the world plan)."""
    from riskplan.app.reproduce.needle3d import Needle3DResult, needle3d_figure, write_outputs

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
    from riskplan.app.reproduce.needle3d import PlanRow
    from riskplan.app.reproduce.report_deformable import _needle3d_section

    est = dict.fromkeys(ESTIMATORS, 0.9)
    checked = PlanRow(0, 20, est, {}, n=100, closed=93, closed_ci=(0.86, 0.97))
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
    assert "0.9000 ± 0.0003 (12,000 draws)" in text
    checked.estimate_se, checked.estimate_n = {"truncation": 1e-10}, {"truncation": 0}
    r["rows"] = [checked.as_dict()]
    rep = Report(tmp_path)
    _needle3d_section(rep, r)
    text = " ".join(str(b) for sec in rep.sections for b in sec.blocks)
    assert "0.9000 (exact goal test)" in text
