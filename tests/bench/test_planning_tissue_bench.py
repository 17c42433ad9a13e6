"""The tissue-planning benchmark measures real runs (keys, plans found); no timing assertions."""

from __future__ import annotations

from riskplan.bench import planning_tissue


def test_measure_keys_small():
    figures = planning_tissue.measure("manipulation", 1, workers=1)
    assert figures["manipulation_plans_found"] == 1 and figures["manipulation_trees"] == 1
    assert figures["manipulation_rrt_1_s"] > 0 and figures["manipulation_selection_s"] > 0
    assert figures["manipulation_rrt_cpu_s"] > 0 and figures["manipulation_selection_cpu_s"] > 0
    assert 0.0 <= figures["manipulation_best_p_success"] <= 1.0


def test_cpu_model():
    assert isinstance(planning_tissue.cpu_model(), str) and planning_tissue.cpu_model()
