"""Eq. 9/10 along plans and the least-risk roadmap search."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.collision import probability_of_collision, trajectory_bound
from riskplan.planning.prm import MeanValidity, build_roadmap, interpolate_path
from riskplan.planning.risk import (
    ConfigurationBound,
    RiskSegmentCost,
    compare_paths,
    least_risk_path,
    risk_cost,
    trajectory_risk,
)
from tests.conftest import TOL
from tests.planning.conftest import GOAL, START


@pytest.fixture(scope="module")
def roadmap(model, scene):
    return build_roadmap(MeanValidity(model, scene), n_milestones=60, seed=1)


def test_bounds_match_collision_module(model, scene, rng, tol):
    c = rng.uniform(-0.01, 0.04, size=(7, 2))
    b = ConfigurationBound(model, scene, batch=3)
    np.testing.assert_allclose(
        b(c), probability_of_collision(model.predict(c), scene), **tol["float64_exact"]
    )
    assert b.evaluations == 7
    P, _ = trajectory_risk(b, c)
    np.testing.assert_allclose(P, trajectory_bound(model.predict(c), scene), **tol["float64_exact"])


def test_risk_cost_additive(tol):
    p = np.array([0.1, 0.0, 0.3, 0.05])
    np.testing.assert_allclose(
        risk_cost(p).sum(), -np.log(1 - (1 - np.prod(1 - p))), **tol["float64_ref"]
    )
    assert risk_cost(1.0) == np.inf


def test_least_risk_not_worse_than_shortest(roadmap, model, scene, tol):
    out = compare_paths(roadmap, ConfigurationBound(model, scene), START, GOAL)
    s, r = out["shortest"], out["least_risk"]
    assert r["bound"] <= s["bound"] + tol["float64_abs"]["atol"]
    assert r["length"] >= s["length"] - tol["float64_abs"]["atol"]
    # the scene makes the difference real: the shortest path hugs the box
    assert s["bound"] > 0.01 and r["bound"] < 0.5 * s["bound"]
    # reported bounds are eq. 10 of the trajectories, recomputed from scratch
    for v in (s, r):
        np.testing.assert_allclose(
            v["bound"],
            trajectory_bound(model.predict(v["trajectory"]), scene),
            **tol["float64_ref"],
        )
        np.testing.assert_array_equal(v["trajectory"], interpolate_path(v["path"]))


def test_least_risk_is_optimal_over_paths(roadmap, model, scene):
    # the edge-cost decomposition is exact: the path's total cost equals -log(1 - eq. 10)
    bound = ConfigurationBound(model, scene)
    out = compare_paths(roadmap, bound, START, GOAL)
    cost = RiskSegmentCost(bound)
    path = out["least_risk"]["path"]
    total = cost(path[:-1], path[1:]).sum() + 0.5 * (
        cost.costs(path[:1])[0] + cost.costs(path[-1:])[0]
    )
    np.testing.assert_allclose(
        total, -np.log1p(-out["least_risk"]["bound"]), **TOL["float64_accumulated"]
    )


def test_lazy_search_equals_full_graph(roadmap, model, scene, tol):
    # oracle: price every edge up front and run SciPy's Dijkstra on the whole graph
    bound = ConfigurationBound(model, scene)
    cost = RiskSegmentCost(bound)
    full = roadmap.search(roadmap.graph_with(START, GOAL, segment_cost=cost), START, GOAL)
    lazy_bound = ConfigurationBound(model, scene)
    lazy = least_risk_path(roadmap, lazy_bound, START, GOAL)
    P_full = trajectory_bound(model.predict(interpolate_path(full)), scene)
    P_lazy = trajectory_bound(model.predict(interpolate_path(lazy)), scene)
    np.testing.assert_allclose(P_lazy, P_full, **tol["float64_ref"])
    assert lazy_bound.evaluations < bound.evaluations  # it priced fewer configurations


def test_cloud_risk_bound_is_the_collision_module_and_deterministic(model, scene, rng):
    """The planner's cloud risk is :func:`cloud_risk` per configuration with the same draws
    (common random numbers): a deterministic function, one configuration at a time or batched."""
    from riskplan.collision.body_risk import cloud_risk
    from riskplan.planning.risk import CloudRiskBound

    c = rng.uniform(-0.01, 0.04, size=(5, 2))
    b = CloudRiskBound(model, scene, coherence=0.5, n_clouds=64, seed=3)
    got = b(c)
    assert b.evaluations == 5 and np.all((got >= 0) & (got <= 1))
    np.testing.assert_array_equal(got, b(c[::-1])[::-1])
    ref = [
        cloud_risk(model.predict(x[None]), scene, n_clouds=64, coherence=0.5, seed=3)
        .per_configuration[0]
        .item()
        for x in c
    ]
    np.testing.assert_array_equal(got, ref)


def test_make_risk_names(model, scene):
    from riskplan.errors import InvalidInputError
    from riskplan.planning.risk import RISKS, CloudRiskBound, make_risk

    assert RISKS == ("eq9", "cloud", "bodies")
    assert isinstance(make_risk("eq9", model, scene), ConfigurationBound)
    assert isinstance(make_risk("cloud", model, scene), CloudRiskBound)
    with pytest.raises(InvalidInputError, match="risk"):
        make_risk("eq11", model, scene)
    with pytest.raises(InvalidInputError, match="coherence"):
        CloudRiskBound(model, scene, coherence=-0.1)


def test_segment_cost_short_last_segment(tol):
    """A batch whose last segment is shorter than ``step`` (no interior) is priced, not an
    IndexError (a 15 mm-range robot's roadmap has such edges); an empty group elsewhere adds 0."""
    cost = RiskSegmentCost(lambda x: np.full(len(x), 0.01), step=0.0025)
    a = np.zeros((3, 3))
    b = np.array([[0.01, 0, 0], [0.001, 0, 0], [0.0, 0.0, 0.001]])
    out = cost(a, b)
    c = risk_cost(0.01)
    # 0.01 m at 2.5 mm: 4 pieces, 3 interior configurations; the short ones have none
    np.testing.assert_allclose(out, [3 * c + c, c, c], **tol["float64_exact"])
    mid = cost(a[[1, 0, 2]], b[[1, 0, 2]])
    np.testing.assert_allclose(mid, out[[1, 0, 2]], **tol["float64_exact"])


class _RobotModel:
    """The analytic model with a transmission: a robot of two tendons in the model's limits."""

    def __init__(self, model, play=0.0005, offset_std=0.0001):
        from types import SimpleNamespace

        from riskplan.robots.params import HysteresisParams

        self.base = model
        self.limits = model.limits
        self.n_tendons = model.n_tendons
        self.robot = SimpleNamespace(
            n_tendons=2,
            displacement_limits=np.asarray(model.limits),
            params=SimpleNamespace(
                hysteresis=HysteresisParams(play=play, play_variation=0.2, offset_std=offset_std)
            ),
        )

    def predict(self, d):
        return self.base.predict(d)


def _tip_gap_config(gap):
    """Displacements whose tip component mean lies ``2 SIGMA + gap`` outside the box face x = -0.03."""
    from tests.planning.conftest import GAIN, SIGMA

    return np.array([0.015 + (-0.03 - 2 * SIGMA - gap) / GAIN, 0.015])


def test_sampled_body_risk_without_transmission_is_the_ellipsoid(model, scene):
    """No play and no offset: every execution receives the command, the body is the predicted
    components at extent 2 (a 2σ ball here), and the risk is exactly 0 or 1."""
    from riskplan.planning.risk import SampledBodyRisk

    b = SampledBodyRisk(_RobotModel(model, play=0.0, offset_std=0.0), scene, n_draws=8)
    got = b(np.stack([_tip_gap_config(0.001), _tip_gap_config(-0.001)]))
    np.testing.assert_array_equal(got, [0.0, 1.0])


def test_sampled_body_risk_is_the_collision_module_on_the_transmission_draws(model, scene):
    """With the robot's play the same configuration collides in some executions only; the value
    is :func:`sampled_body_risk` on the means at the executions' displacements (same draws),
    deterministic, and the trajectory keeps each execution's draw."""
    from riskplan.collision.body_risk import sampled_body_risk
    from riskplan.gaussian_mixture import as_numpy_mixture
    from riskplan.parallel import spawn_seeds
    from riskplan.planning.executions import execution_displacements
    from riskplan.planning.risk import SampledBodyRisk

    rm = _RobotModel(model)
    b = SampledBodyRisk(rm, scene, n_draws=256, seed=5)
    x = _tip_gap_config(0.0)
    p = b(x[None])[0]
    assert 0.0 < p < 1.0
    eff = execution_displacements(rm.robot, x[None], spawn_seeds(5, 256))
    drawn = as_numpy_mixture(model.predict(eff.reshape(-1, 2))).means.reshape(256, 1, 2, 3)
    ref = sampled_body_risk(as_numpy_mixture(model.predict(x[None])), drawn, scene)
    assert p == ref.per_configuration[0]
    assert b(x[None])[0] == p and b.evaluations == 2
    traj = np.stack([x, x, _tip_gap_config(0.01)])
    assert b.trajectory(traj) >= p


def test_sampled_body_risk_errors(model, scene):
    from riskplan.errors import InvalidInputError
    from riskplan.planning.risk import SampledBodyRisk

    with pytest.raises(InvalidInputError, match="robot"):
        SampledBodyRisk(model, scene)
    with pytest.raises(InvalidInputError, match="extent"):
        SampledBodyRisk(_RobotModel(model), scene, extent=0.0)
    with pytest.raises(InvalidInputError, match="n_draws"):
        SampledBodyRisk(_RobotModel(model), scene, n_draws=1)
