"""The tissue demo stage at small scale: files, tables and the steering helpers."""

from __future__ import annotations

import numpy as np

from riskplan.app.demo import tissue as demo_tissue
from riskplan.app.report import Report
from riskplan.scenarios.base import rollout
from riskplan.scenarios.manipulation import ManipulationScenario
from riskplan.scenarios.needle import NeedleScenario


def test_demo_stage_small(tmp_path, monkeypatch):
    monkeypatch.setattr(demo_tissue, "NEEDLE_SAMPLES", 2)
    monkeypatch.setattr(demo_tissue, "MANIP_SAMPLES", 1)
    monkeypatch.setattr(demo_tissue, "MANIP_MESH_CAP", 120)
    report = Report(tmp_path)
    ctx = {"out": tmp_path}
    demo_tissue.run(report, ctx, seed=0, workers=1)
    for name in (
        "tissue_needle.gif",
        "tissue_manipulation.gif",
        "tissue_needle_frames.png",
        "tissue_manipulation_frames.png",
    ):
        assert (tmp_path / name).is_file(), name
    html = report.write().read_text()
    assert html.count("material-high") == 2 and "tissue_needle.gif" in html
    assert ctx["tissue_needle_controls"].shape[1] == 2


def test_needle_steering_reaches_goal_without_collision():
    sim = NeedleScenario()
    p = sim.nominal_params
    u = demo_tissue.greedy_needle_controls(sim, p, 40)
    states = rollout(sim, sim.initial_state(p), u, p)
    assert sim.in_goal(states[-1])
    assert not any(sim.in_collision(s) for s in states)
    assert all(sim.inside(s) for s in states)


def test_needle_steering_with_speed_margin_ends_inside_the_goal():
    sim = NeedleScenario()
    p = sim.nominal_params
    u = demo_tissue.greedy_needle_controls(sim, p, 40, speed=0.8, depth=0.5)
    np.testing.assert_array_equal(u[:, 0], 0.8 * sim.config.v_max)
    states = rollout(sim, sim.initial_state(p), u, p)
    assert sim.goal_distance(states[-1]) <= 0.5 * sim.config.goal_radius
    assert not any(sim.in_collision(s) for s in states)
    assert all(sim.goal_distance(s) > 0.5 * sim.config.goal_radius for s in states[:-1])


def test_manipulation_steering_reaches_goal_without_collision():
    sim = ManipulationScenario()
    p = sim.nominal_params
    u = demo_tissue.greedy_manipulation_controls(sim, p, 14)
    states = rollout(sim, sim.initial_state(p), u, p)
    assert sim.in_goal(states[-1])
    assert not any(sim.in_collision(s) for s in states)
    dist, reached, collided = demo_tissue.open_loop_outcome(sim, u, p)
    assert (
        reached and not collided and np.isclose(dist, sim.goal_distance(states[-1]), rtol=0, atol=0)
    )
