"""The planning benchmark runs (quick) and reports the issue's keys (no timing assertions)."""

from __future__ import annotations

from riskplan.bench.planning import run


def test_bench_keys():
    f = run(quick=True)
    keys = {
        "bound_reduction",
        "bo_50_iterations_s",
        "prm_build_s",
        "bound_eval_ms_per_trajectory",
        "nominal_bound",
        "optimised_bound",
        "cpu_model",
        "cpu_cores",
        "new_robot_end_to_end_s",
    }
    assert keys <= set(f)
    assert 0 <= f["optimised_bound"] <= f["nominal_bound"] <= 1
    assert 0 <= f["bound_reduction"] <= 1
    assert f["prm_build_s"] > 0 and f["bound_eval_ms_per_trajectory"] > 0 and f["bo_run_s"] > 0
    # the lab's task from an empty model cache, stage by stage (tiny preset when quick)
    stages = f["new_robot_end_to_end_stages_s"]
    assert {"dataset_s", "training_s", "evaluation_s", "roadmap_s", "optimise_s"} <= set(stages)
    assert f["new_robot_end_to_end_s"] >= max(stages.values())
    assert f["new_robot_preset"] == "tiny"
