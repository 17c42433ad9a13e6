"""The calibration stage of ``riskplan reproduce`` at a tiny size: its key numbers are what
they say (metrics recomputed from the rows, measured rates re-executed one by one on the
same seeds, the picked plans at the stated ranks), it resumes to the same numbers, and it
runs as its own stage into results.json and the report."""

from __future__ import annotations

import json

import numpy as np
import pytest

from riskplan.app.reproduce.calibration import (
    CONTROLLER_OF,
    ESTIMATORS,
    CalibrationScale,
    run_calibration,
)
from riskplan.app.store import ResultStore
from riskplan.errors import InvalidInputError
from tests.conftest import approx_tol

TINY = CalibrationScale(
    n_candidates=3,
    n_plans=2,
    n_executions=6,
    batch_size=3,
    lin_samples=2,
    goal_samples=50,
    plans_per_tree=2,
    cases=("actuation",),
)
CONFIG = {"test": "calibration", "seed": 5}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    root = tmp_path_factory.mktemp("cal")
    return root, run_calibration(
        "needle", TINY, ResultStore(root, CONFIG), seed=5, backend="serial"
    )


def test_key_numbers(reference):
    from riskplan.app.reproduce.deformable import BlobStore, _seed_for
    from riskplan.control.lqg import execute
    from riskplan.parallel import spawn_seeds
    from riskplan.scenarios.registry import make_scenario
    from riskplan.tissue_planning.calibration import calibration_metrics, evenly_spaced_ranks

    root, cal = reference
    rows = cal["rows"]
    assert len(rows) == min(TINY.n_plans, cal["n_usable"]["actuation"])
    # the picked ranks are the evenly spaced ones of the σ ranking
    assert [r["rank"] for r in rows] == evenly_spaced_ranks(cal["n_usable"]["actuation"], 2)
    blobs = BlobStore(ResultStore(root, CONFIG))
    sig = [blobs.get(f"calibration.needle.sigma.actuation.{j:03d}") for j in range(3)]
    order = sorted(
        (j for j in range(3) if sig[j]["error"] is None), key=lambda j: (-sig[j]["p"]["sigma"], j)
    )
    assert [r["candidate"] for r in rows] == [order[r["rank"]] for r in rows]
    assert cal["estimators"] == list(ESTIMATORS)  # the needle has the material frame
    for e in ESTIMATORS:
        m = cal[e]
        k = CONTROLLER_OF[e]
        p = [r["predicted"][e] for r in rows]
        y = [r["measured"][k]["rate"] for r in rows]
        assert m["n_plans"] == len(rows)
        assert m["mae"] == pytest.approx(
            np.mean(np.abs(np.subtract(p, y))), **approx_tol("float64_exact")
        )
        assert m["measured_spread"] == pytest.approx(np.ptp(y), **approx_tol("float64_exact"))
        assert m == {**calibration_metrics(p, y).as_dict(), "by_case": m["by_case"]}
        assert all(0.0 <= v <= 1.0 for v in p + y)
    # measured rates: the same executions, one by one, from the stated seeds
    plans = blobs.get("calibration.needle.plans")
    sim = make_scenario("needle", "actuation")
    seeds = spawn_seeds(_seed_for(5, "needle", "calibration", "execute", "actuation"), 6)
    row = rows[0]
    est = blobs.get(f"calibration.needle.estimate.actuation.{row['candidate']:03d}")
    for k in ("lqg", "dist", "mat", "matdist"):
        hits = 0
        # the material-frame controllers run on the same plan with the reduced state in
        # the tissue's material frame
        msim = sim.with_frame("material") if k.startswith("mat") else sim
        plan = plans[row["candidate"]].reframed(msim)
        for s in seeds:
            gen = np.random.default_rng(s)
            ex = execute(msim, plan, est[k], sim.distribution.sample(gen), seed=gen)
            hits += int(ex.success)
        assert row["measured"][k]["successes"] == hits
        assert row["measured"][k]["n"] == 6
        assert row["measured"][k]["low"] <= row["measured"][k]["rate"] <= row["measured"][k]["high"]
    assert row["a_norm_max"] == pytest.approx(
        max(np.linalg.norm(a, 2) for a in est["lqg"].lin.A), **approx_tol("float64_exact")
    )
    # step 3 recomputes σ from the same seed: identical to the ranking's value
    assert row["predicted"]["sigma"] == sig[row["candidate"]]["p"]["sigma"]


def test_resumes_to_the_same_numbers(reference, tmp_path):
    import shutil

    root, cal = reference
    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    # lose one batch of executions: it is recomputed, the rest read back
    rec = sorted((copy / "records").glob("calibration.needle.exec.*.json"))
    rec[-1].unlink()
    again = run_calibration("needle", TINY, ResultStore(copy, CONFIG), seed=5, backend="serial")
    assert json.dumps(again, sort_keys=True) == json.dumps(cal, sort_keys=True)


def test_bad_input(tmp_path):
    with pytest.raises(InvalidInputError):
        CalibrationScale(n_candidates=0, n_plans=1, n_executions=1, batch_size=1)
    with pytest.raises(InvalidInputError):
        run_calibration("nope", TINY, ResultStore(tmp_path, CONFIG))


def test_reproduce_stage_is_selectable(tmp_path, monkeypatch):
    """``stages=("calibration",)`` runs the calibration alone into results.json and the report."""
    from riskplan.app.reproduce import pipeline as rep

    monkeypatch.setitem(
        rep._CALIBRATION_FOR, "smoke", "tiny"
    )  # the named sizes, shrunk for the test
    from riskplan.app.reproduce.calibration import CALIBRATION_SCALES

    monkeypatch.setitem(CALIBRATION_SCALES, "tiny", {"needle": TINY, "manipulation": TINY})
    with pytest.raises(InvalidInputError):
        rep.reproduce(tmp_path / "bad", paper="deformable", stages=("nope",))
    out = tmp_path / "out"
    res = rep.reproduce(out, paper="deformable", stages=("calibration",), backend="serial")
    saved = json.loads((out / "results.json").read_text())
    for name in ("needle", "manipulation"):
        cal = saved["deformable"][name]["calibration"]
        assert set(saved["deformable"][name]) == {"calibration"}  # the figures did not run
        for e in cal["estimators"]:
            assert set(cal[e]) >= {"mae", "spearman", "n_plans", "measured_spread"}
            assert 0.0 <= cal[e]["mae"] <= 1.0 and 0.0 <= cal[e]["measured_spread"] <= 1.0
    assert res["deformable"]["needle"]["calibration"]["sigma"]["n_plans"] >= 1
    html = (out / "report.html").read_text()
    assert "LQG-MP calibration: needle" in html and (out / "calibration_needle.png").exists()
    # one scenario as its own stage, into the same store: the same numbers, read back
    one = rep.reproduce(out, paper="deformable", stages=("calibration-needle",), backend="serial")
    assert set(one["deformable"]) == {"needle"}
    assert json.dumps(one["deformable"]["needle"], sort_keys=True) == json.dumps(
        res["deformable"]["needle"], sort_keys=True
    )
    # where the time went, in timings.json (not results.json: it differs between runs)
    cost = json.loads((out / "timings.json").read_text())["calibration_needle_cost"]
    assert cost["executions_cpu_s"] > 0.0 and cost["sigma_ranking_cpu_s"] > 0.0
    n_rows = res["deformable"]["needle"]["calibration"]["sigma"]["n_plans"]
    n_controllers = len(set(CONTROLLER_OF.values()))  # the needle runs all four
    assert cost["n_executions"] == n_rows * n_controllers * TINY.n_executions


def test_a_degenerate_lqgmp_fails_the_candidate_not_the_run(monkeypatch):
    """A NumericalError from LQG-MP (an overflowing propagation, a position covariance
    without a Cholesky factor) marks the candidate as failed in Fig. 6's and the
    calibration's evaluations, as a failed linearisation does, instead of ending the run."""
    import importlib

    from riskplan.app.reproduce.calibration import estimate_candidate
    from riskplan.app.reproduce.deformable import evaluate_candidate
    from riskplan.control import NominalPlan
    from riskplan.errors import NumericalError
    from riskplan.scenarios.registry import make_scenario

    sim = make_scenario("needle", "actuation")
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), sim.random_controls(4, seed=1))

    def broken(*args, **kwargs):
        raise NumericalError("LQG-MP: the position covariance at step 2 has no Cholesky factor")

    monkeypatch.setattr(importlib.import_module("riskplan.control.lqgmp"), "lqgmp", broken)
    got = evaluate_candidate((sim, plan, 2, 20, 0))
    assert got["p_success"] == 0.0 and got["controller"] is None
    assert "Cholesky" in got["error"]
    est = estimate_candidate((sim, plan, 2, 20, 0, ("sigma",)))
    assert est["error"].startswith("NumericalError") and est["p"] == {}
