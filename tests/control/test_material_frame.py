"""The needle's material-frame linearisation (beyond the paper): the car's own A_t and B_t
with the tissue pushing, H_t against finite differences and the 1/E law of linear
elasticity, bounded conditioning, seed stability, the measurement-bias state, and the
world frame left bit for bit as it was."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from riskplan.control import NominalPlan, execute, linearize, lqg_controller, lqgmp
from riskplan.control.linearize import RankDeficiencyWarning, fit_measurement_bias
from riskplan.errors import InvalidInputError
from riskplan.scenarios.needle import NeedleScenario
from riskplan.scenarios.registry import make_scenario
from tests.conftest import TOL

from .test_linearize import Without


def _car_jacobians(cfg, pose, u):
    k = 1.0 / (cfg.r_min * math.tan(cfg.phi_max))
    th = pose[2]
    v, phi = u
    A = np.array(
        [[1, 0, -cfg.tau * v * math.sin(th)], [0, 1, cfg.tau * v * math.cos(th)], [0, 0, 1]]
    )
    B = np.array(
        [
            [cfg.tau * math.cos(th), 0],
            [cfg.tau * math.sin(th), 0],
            [cfg.tau * math.tan(phi) * k, cfg.tau * v * k / math.cos(phi) ** 2],
        ]
    )
    return A, B


@pytest.fixture(scope="module")
def pushed():
    """A needle plan with the tissue pushing (force 1), in both frames."""
    sim = NeedleScenario()
    u = sim.random_controls(8, seed=4)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    mat = sim.with_frame("material")
    return sim, plan, mat, plan.reframed(mat)


def _lin(sim, plan, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RankDeficiencyWarning)
        return linearize(sim, plan, **kw)


def test_frame_is_checked():
    with pytest.raises(InvalidInputError, match="frame"):
        NeedleScenario(frame="body")
    with pytest.raises(InvalidInputError, match="frame"):
        NeedleScenario().with_frame("tissue")


def test_material_frame_A_B_are_the_cars_with_the_tissue_pushing(pushed):
    # the world frame's fit is not the car's here (the tissue moves the robot); the
    # material frame's is, whatever the tissue does
    sim, plan, mat, pm = pushed
    assert np.abs(plan.reduced - pm.reduced).max() > 1e-3  # the tissue does move the robot
    lin = _lin(mat, pm, n_a_runs=2 * mat.state_dim, seed=0)
    for t in range(1, plan.n_steps):
        A, B = _car_jacobians(sim.config, pm.reduced[t], plan.controls[t])
        np.testing.assert_allclose(lin.B[t], B, **TOL["needle_car_B"])
        np.testing.assert_allclose(lin.A[t], A, **TOL["needle_car_A"])


def test_material_frame_H_against_finite_differences_and_the_stiffness_law(pushed):
    sim, plan, mat, pm = pushed
    lin = _lin(mat, pm, seed=0)
    params = plan.params
    h = 1e-5  # forward differences, 10x the step of the central ones
    for t in (2, 5, 7):
        y = plan.states[t + 1]
        base = mat._tissue_response(np.array(y.material), params)[1][:2]
        fd = np.empty((2, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            fd[:, k] = (mat._tissue_response(np.array(y.material) + e, params)[1][:2] - base) / h
        # forward vs central differences: O(h) of a curvature of order 1
        np.testing.assert_allclose(lin.H[t], fd, **TOL["fd_forward_force"])
        # linear elasticity: u scales with 1/E, so H - [I 0] halves when E doubles
        stiff = mat.observation_jacobian(
            y, params.replace(youngs_modulus=2 * params.youngs_modulus)
        )
        H0 = np.array(sim.observation_matrix)
        np.testing.assert_allclose(stiff - H0, 0.5 * (lin.H[t] - H0), **TOL["fd_jacobian"])
        assert np.abs(lin.H[t] - H0).max() > 1e-3  # the tissue is in H_t
    # no push, nothing moves: H is the world frame's
    free = params.replace(force_scale=0.0)
    np.testing.assert_allclose(
        mat.observation_jacobian(plan.states[3], free),
        sim.observation_matrix,
        **TOL["fd_jacobian"],  # central differences of X + 0 at step 1e-6: rounding only
    )


def test_material_frame_is_well_conditioned_and_seed_stable(pushed):
    _sim, _plan, _mat, pm = pushed
    case = make_scenario("needle", "actuation")
    m = case.with_frame("material")
    a, b = (_lin(m, pm, n_samples=6, seed=s) for s in (0, 1))
    # the car: |A_t| <= 1 + τ v_max = 1.05 (plus the fit's second order)
    assert np.linalg.norm(a.A, ord=2, axis=(1, 2)).max() < 1.1
    # the A-fit does not depend on the perturbations' seed beyond second order
    np.testing.assert_allclose(a.A, b.A, **TOL["linearize_second_order"])
    np.testing.assert_array_equal(a.H, b.H)


def test_world_frame_stays_bit_identical(pushed):
    # the per-step H_t and the measurement-bias path give the world frame exactly the
    # constant H and N of before (the explicit H/N arguments take the old path)
    _sim, plan, _, _ = pushed
    case = make_scenario("needle", "material-high")
    new = _lin(case, plan, n_samples=4, seed=3, disturbance=True)
    old = _lin(
        case,
        plan,
        n_samples=4,
        seed=3,
        disturbance=True,
        H=case.observation_matrix,
        N=case.sensing_cov,
    )
    for name in ("A", "B", "M", "H", "N", "drift"):
        np.testing.assert_array_equal(getattr(new, name), getattr(old, name))
    assert new.disturbance.C is None
    np.testing.assert_array_equal(new.disturbance.cov, old.disturbance.cov)
    # execution: measure(y) is observe(reduced(y)) in the world frame, draw for draw
    ctrl = lqg_controller(new, disturbance=True)
    params = case.distribution.sample(np.random.default_rng(0))
    a = execute(case, plan, ctrl, params, seed=11)
    b = execute(Without(case, "measure"), plan, ctrl, params, seed=11)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.estimates, b.estimates)


def test_measurement_bias_of_the_force_is_one_direction(pushed):
    # the tissue's offset is linear in the force: one bias direction explains it, and the
    # plan's sensing noise is all that is left
    _, plan, _, _ = pushed
    case = make_scenario("needle", "force").with_frame("material")
    pm = plan.reframed(case)
    lin = _lin(case, pm, n_samples=8, seed=2, disturbance=True)
    d = lin.disturbance
    assert d.n_bias == 1 and d.C.shape == (plan.n_steps, 2, 1)
    assert d.bias_cov[0, 0] > 0
    np.testing.assert_array_equal(d.cov, 0.0)  # nothing moves the material pose
    np.testing.assert_allclose(d.N, lin.N * 0 + case.sensing_cov, **TOL["float64_abs"])
    # the paper's reading puts the bias spread into N_t instead
    assert (lin.N[:, 0, 0] > case.sensing_cov[0, 0]).all()
    ctrl = lqg_controller(lin, disturbance=True)
    assert ctrl.L.shape == (plan.n_steps, 2, 3 + 2 + 1)
    np.testing.assert_array_equal(ctrl.L[:, :, -1], 0.0)  # e is not steered
    r = lqgmp(case, pm, ctrl, method="sampling", n_goal_samples=200, seed=0)
    assert r.mean.shape[1] == 2 * (3 + 2 + 1)
    ex = execute(case, pm, ctrl, case.distribution.sample(np.random.default_rng(4)), seed=1)
    assert ex.disturbance.shape[1] == 2


def test_fit_measurement_bias_recovers_a_known_direction(rng):
    T, n, m = 5, 40, 2
    c = rng.normal(size=(T, m))
    e = rng.normal(size=n) * 0.3
    Pb = e[None, :, None] * c[:, None, :]
    noise = rng.normal(size=(T, n, m)) * 1e-3
    N = np.broadcast_to(np.eye(m) * 1e-4, (T, m, m))
    C, Se, Nr, fits = fit_measurement_bias(Pb, Pb + noise, N)
    assert C.shape == (T, m, 1)
    np.testing.assert_allclose(np.einsum("tmr,nr->tnm", C, fits), Pb, **TOL["float64_ref"])
    np.testing.assert_allclose(Se[0, 0], (fits**2).mean(), **TOL["float64_exact"])
    resid = np.einsum("tni,tnj->tij", noise, noise) / n
    np.testing.assert_allclose(Nr, N + resid, **TOL["float64_exact"])
    # no bias: no state
    C0, Se0, _Nr0, _f0 = fit_measurement_bias(np.zeros((T, n, m)), noise, N)
    assert C0.shape == (T, m, 0) and Se0.shape == (0, 0)


def test_plan_tissue_selection_setup(pushed):
    from riskplan.tissue_planning.plan import SELECTIONS, selection_setup

    sim, plan, _, pm = pushed
    s, ps, method, dist = selection_setup(sim, [plan], "material")
    entry = SELECTIONS["material"]["needle"]
    assert s.frame == entry["frame"] and (method, dist) == (entry["method"], entry["disturbance"])
    np.testing.assert_array_equal(ps[0].reduced, pm.reduced)
    assert ps[0].states is plan.states
    s, ps, method, dist = selection_setup(sim, [plan], "paper")
    assert s is sim and ps[0] is plan and (method, dist) == ("sigma", False)
    s, ps, method, dist = selection_setup(sim, [plan], "calibrated")
    assert s is sim and ps[0] is plan and method == SELECTIONS["calibrated"]["needle"]["method"]
    with pytest.raises(InvalidInputError, match="selection"):
        selection_setup(sim, [plan], "best")
