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
    }
    assert keys <= set(f)
    assert 0 <= f["optimised_bound"] <= f["nominal_bound"] <= 1
    assert 0 <= f["bound_reduction"] <= 1
    assert f["prm_build_s"] > 0 and f["bound_eval_ms_per_trajectory"] > 0 and f["bo_run_s"] > 0
