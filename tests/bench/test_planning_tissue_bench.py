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


def test_needle3d_is_measured_on_5k_tetrahedra():
    """The 3-D needle's figures are those of the issue's setting: its RRT and selection on
    the 5040-tetrahedra block, not the 1296 of the planning mesh."""
    figures = planning_tissue.measure("needle3d", 1, workers=1)
    assert figures["needle3d_tetrahedra"] == 5040
    assert figures["needle3d_plans_found"] == 1
    assert figures["needle3d_rrt_1_s"] > 0 and figures["needle3d_selection_s"] > 0
    assert figures["needle3d_rrt_cpu_s"] > 0 and figures["needle3d_selection_cpu_s"] > 0
    assert 0.0 <= figures["needle3d_best_p_success"] <= 1.0
