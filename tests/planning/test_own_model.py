"""The kinematics-model seam from a user's side: a robot type written here, outside the
package, with no torch and no learned network, is planned for by ``plan_chest`` (PRM, eq.-9/10
risk, Bayesian optimisation) without any change to ``riskplan.planning``.

The robot is a constant-curvature continuum robot of length ``L`` with two antagonistic tendon
pairs at radius ``r`` (the usual analytic model of a tendon robot): tendon displacements
``q = (q_x, q_y)`` bend it with curvature vector ``kappa = q / (r L)`` in the base frame's
``x``-``y`` directions. Its body at ``K`` equally spaced arc lengths ``s_k`` is

    p(s) = ((1 - cos(|kappa| s)) / |kappa|) * kappa / |kappa| + (sin(|kappa| s) / |kappa|) e_z,

and the model's mixture puts an isotropic Gaussian of standard deviation ``SIGMA`` at each
(weights ``1 / K``). The scene is a large box whose near face cuts through the straight
robot's tip (3 mm below it), so the move from bending one way to bending the other cannot pass
through the straight robot: the roadmap must detour around it. The oracles: the plan's
trajectory is valid for *this* model (every component mean outside the box) although the
straight line between its ends is not; its reported per-configuration risks are eq. 9 of this
model's mixture (recomputed here); and at the riskiest configuration a Monte Carlo of the same
mixture against the box lies within its confidence interval of the bound: an upper bound, here
nearly tight, since only the box's one face is near the body.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from riskplan.collision import Environment, monte_carlo_probability, probability_of_collision
from riskplan.errors import InvalidInputError
from riskplan.gaussian_mixture import NumpyMixture
from riskplan.kinematics_model import KinematicsModel, check_kinematics_model
from riskplan.planning import OptimiserConfig, plan_chest
from tests.conftest import TOL

LENGTH = 0.1  # m
TENDON_RADIUS = 0.005  # m
SIGMA = 0.002  # m, the model's spread at every point of the body
N_POINTS = 8


class ConstantCurvatureModel:
    """A user's kinematics model: ``limits`` and ``predict``, nothing else."""

    def __init__(self, q_max: float = 0.01):
        self.limits = np.array([[-q_max, q_max], [-q_max, q_max]])
        self.calls = 0

    def backbone(self, q) -> np.ndarray:
        """``(N, 2)`` displacements -> ``(N, K, 3)`` points at ``s_k = L k / K``, ``k = 1..K``."""
        q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        kappa = q / (TENDON_RADIUS * LENGTH)  # (N, 2), 1/m
        k = np.linalg.norm(kappa, axis=1)[:, None]  # (N, 1)
        s = LENGTH * np.arange(1, N_POINTS + 1) / N_POINTS  # (K,)
        # (1 - cos(k s)) / k = (k s^2 / 2) sinc^2(k s / 2) and sin(k s) / k = s sinc(k s), with
        # sinc(x) = sin(x) / x: no division, exact for the straight robot (k = 0)
        half = np.sinc(k * s / (2 * np.pi))  # numpy's sinc(x) is sin(pi x) / (pi x)
        lateral = 0.5 * s**2 * half**2  # (N, K): radial offset / k
        axial = s * np.sinc(k * s / np.pi)
        return np.concatenate([lateral[..., None] * kappa[:, None, :], axial[..., None]], axis=-1)

    def predict(self, configurations) -> NumpyMixture:
        self.calls += 1
        mu = self.backbone(configurations)
        n, k, _ = mu.shape
        w = np.full((n, k), 1.0 / k)
        u = np.broadcast_to(np.eye(3) / SIGMA, (n, k, 3, 3))  # precision Cholesky of SIGMA^2 I
        return NumpyMixture(w, mu, u.copy())


def _scene() -> Environment:
    # a large box whose near face lies 3 mm below the straight robot's tip (z = L): the
    # straight robot is invalid, a robot bent by more than about 0.4 rad is free
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.1))
    box.apply_translation((0.0, 0.0, LENGTH - 0.003 + 0.05))
    return Environment.from_meshes([box], names=["wall"])


def test_the_model_is_a_kinematics_model():
    model = ConstantCurvatureModel()
    assert isinstance(model, KinematicsModel)
    np.testing.assert_array_equal(check_kinematics_model(model), model.limits)
    # the closed form: a quarter circle at kappa L = pi / 2 ends at (2L/pi, 0, 2L/pi)
    q = np.pi / 2 * TENDON_RADIUS
    tip = model.backbone([[q, 0.0]])[0, -1]
    np.testing.assert_allclose(
        tip, [2 * LENGTH / np.pi, 0.0, 2 * LENGTH / np.pi], **TOL["float64_ref"]
    )


@pytest.fixture(scope="module")
def planned():
    model = ConstantCurvatureModel()
    env = _scene()
    plan = plan_chest(
        model,
        env,
        start=[0.008, 0.0],
        goal=[-0.008, 0.0],
        n_milestones=60,
        optimiser=OptimiserConfig(iterations=3, n_candidates=32, radius=0.004),
        seed=0,
    )
    return model, env, plan


def test_plan_chest_plans_with_a_model_from_outside(planned):
    model, env, plan = planned
    assert model.calls > 0
    np.testing.assert_array_equal(plan.nominal[0], [0.008, 0.0])
    np.testing.assert_array_equal(plan.nominal[-1], [-0.008, 0.0])
    # the straight robot, halfway on the straight line between the ends, has its tip in the box;
    # the planned trajectories keep every component mean outside it (signed distance > 0)
    assert env.signed_distance(model.backbone([[0.0, 0.0]])[0]).min() < 0.0
    for trajectory in (plan.nominal, plan.optimised.trajectory):
        assert env.signed_distance(model.backbone(trajectory).reshape(-1, 3)).min() > 0.0
    # the risks reported are eq. 9 of this model's mixture along the trajectory, and eq. 10
    bounds = probability_of_collision(model.predict(plan.nominal), env)
    np.testing.assert_allclose(plan.nominal_bounds, bounds, **TOL["float64_exact"])
    np.testing.assert_allclose(
        plan.nominal_bound, 1.0 - np.prod(1.0 - bounds), **TOL["float64_exact"]
    )
    assert plan.nominal_bound > 0.0  # the path passes the wall close enough to matter
    opt = plan.optimised
    np.testing.assert_allclose(
        opt.bounds,
        probability_of_collision(model.predict(opt.trajectory), env),
        **TOL["float64_exact"],
    )


def test_reported_risk_agrees_with_monte_carlo_of_the_model(planned):
    model, env, plan = planned
    worst = plan.nominal[np.argmax(plan.nominal_bounds)]
    gm = model.predict(worst[None])
    bound = float(probability_of_collision(gm, env)[0])
    mc = monte_carlo_probability(gm, env, 200_000, seed=1, confidence=0.999)
    lo, hi = float(mc.low[0]), float(mc.high[0])
    # an upper bound ...
    assert lo <= bound
    # ... and nearly exact here (one near face of a large box): within the interval
    assert bound <= hi, (bound, lo, hi)


def test_a_tip_target_is_reached_through_the_models_farthest_mean():
    # the contract's tip: the component mean farthest from the origin, here the arc's end
    model = ConstantCurvatureModel()
    target = model.backbone([[-0.008, 0.003]])[0, -1]
    tolerance = 0.002  # m, the planner's tip tolerance asked for
    plan = plan_chest(
        model,
        _scene(),
        start=[0.008, 0.0],
        goal_tip=target,
        tip_tolerance=tolerance,
        n_milestones=60,
        optimiser=OptimiserConfig(iterations=0),
    )
    reached = model.backbone(plan.goal[None])[0, -1]
    assert np.linalg.norm(reached - target) <= tolerance
    np.testing.assert_array_equal(plan.nominal[-1], plan.goal)


def test_an_object_without_the_members_is_refused():
    class NoPredict:
        limits = np.array([[0.0, 1.0]])

    with pytest.raises(InvalidInputError, match="model: expected a kinematics model"):
        plan_chest(NoPredict(), _scene(), goal=[0.5])

    class TwoDimensional(ConstantCurvatureModel):
        def predict(self, configurations):
            gm = super().predict(configurations)
            return NumpyMixture(gm.weights, gm.means[..., :2], gm.precision_cholesky[..., :2, :2])

    with pytest.raises(InvalidInputError, match="3 dimensions"):
        plan_chest(TwoDimensional(), _scene(), start=[0.008, 0.0], goal=[-0.008, 0.0])

    with pytest.raises(InvalidInputError, match=r"start: .* is invalid"):
        plan_chest(ConstantCurvatureModel(), _scene(), start=[0.0, 0.0], goal=[-0.008, 0.0])

    bad = ConstantCurvatureModel()
    bad.limits = np.array([[0.01, -0.01], [-0.01, 0.01]])
    with pytest.raises(InvalidInputError, match="limits"):
        plan_chest(bad, _scene(), start=[0.0, 0.0], goal=[0.0, 0.0])


def test_plan_chest_probes_the_model_once():
    # the boundary check predicts at the box's centre; plan_chest hands the model on to
    # plan_robot, whose check it is: one probe per call, not one per layer
    class Recording(ConstantCurvatureModel):
        def __init__(self):
            super().__init__()
            self.limits = np.array([[-0.01, 0.006], [-0.01, 0.01]])  # centre (-0.002, 0)
            self.seen = []

        def predict(self, configurations):
            self.seen.append(np.array(configurations, dtype=np.float64))
            return super().predict(configurations)

    model = Recording()
    centre = model.limits.mean(axis=1)
    # the straight robot's start is invalid: the call stops after the boundary checks
    with pytest.raises(InvalidInputError, match=r"start: .* is invalid"):
        plan_chest(model, _scene(), start=[0.0, 0.0], goal=[-0.008, 0.0])
    probes = [q for q in model.seen if q.shape == (1, 2) and np.array_equal(q[0], centre)]
    assert len(probes) == 1
