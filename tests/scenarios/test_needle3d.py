"""3-D bevel-tip needle: SE(3) kinematics against RK4 and closed forms, the scenario's
tissue coupling against an independent interpolation of a full FEM solve, determinism,
outcomes and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import SimParams
from riskplan.scenarios.bevel import (
    needle_step,
    pose_step_jacobian,
    pose_vector,
    rk4_needle,
    se3_exp,
    se3_exp_batch,
)
from riskplan.scenarios.needle3d import Needle3DConfig, Needle3DScenario


def _rotation(seed):
    q = np.random.default_rng(seed).standard_normal(4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@pytest.fixture(scope="module")
def sim():
    return Needle3DScenario()


@pytest.mark.parametrize(
    "v, omega, rho", [(0.5, 0.0, 1.0), (0.3, 7.0, 1.0), (0.5, -10.0, 0.4), (0.2, 1e-6, 1.0)]
)
def test_exact_step_matches_rk4(tol, v, omega, rho):
    R0, p0 = _rotation(1), np.array([0.1, 0.2, 0.3])
    R1, p1 = needle_step(R0, p0, v, omega, tau=0.1, kappa=2.0, rho=rho)
    R2, p2 = rk4_needle(R0, p0, v, omega, tau=0.1, kappa=2.0, rho=rho, n=200)
    np.testing.assert_allclose(R1, R2, **tol["rk4_closed_form"])
    np.testing.assert_allclose(p1, p2, **tol["rk4_closed_form"])
    np.testing.assert_allclose(R1.T @ R1, np.eye(3), **tol["float64_abs"])


def test_constant_curvature_arc_closed_form(tol):
    # no rotation: the tip follows a circle of radius 1/κ bending towards −e₂
    kappa, v, n = 2.0, 0.5, 7
    R, p = np.eye(3), np.zeros(3)
    for _ in range(n):
        R, p = needle_step(R, p, v, 0.0, tau=0.1, kappa=kappa)
    s = n * 0.1 * v
    expected = np.array([0.0, -(1 - math.cos(kappa * s)) / kappa, math.sin(kappa * s) / kappa])
    np.testing.assert_allclose(p, expected, **tol["float64_ref"])


@pytest.mark.parametrize("theta", [0.0, 0.99e-4, 1.01e-4, 0.3, 2.5])
def test_se3_exp_against_matrix_exponential(tol, theta):
    """The closed form (and its series below θ = 1e-4) against scipy's expm of ξ̂ (4 × 4)."""
    from scipy.linalg import expm

    w = theta * np.array([0.6, -0.8, 0.0])
    xi = np.concatenate([[0.1, -0.2, 0.3], w])
    X = np.zeros((4, 4))
    X[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    X[:3, 3] = xi[:3]
    ref = expm(X)
    E, d = se3_exp(xi)
    np.testing.assert_allclose(E, ref[:3, :3], **tol["float64_ref"])
    np.testing.assert_allclose(d, ref[:3, 3], **tol["float64_ref"])
    Eb, db = se3_exp_batch(np.stack([xi, xi]))
    np.testing.assert_allclose(Eb[1], E, **tol["float64_exact"])
    np.testing.assert_allclose(db[1], d, **tol["float64_exact"])


def test_pose_step_is_linear_with_exact_jacobian(tol):
    R0, p0 = _rotation(3), np.array([0.4, 0.1, -0.2])
    J = pose_step_jacobian(0.4, 3.0, tau=0.1, kappa=2.0)
    R1, p1 = needle_step(R0, p0, 0.4, 3.0, tau=0.1, kappa=2.0)
    np.testing.assert_allclose(J @ pose_vector(R0, p0), pose_vector(R1, p1), **tol["float64_exact"])


def test_world_pose_rides_on_the_tissue(sim, tol):
    """World position = X + u(X), with u from a full nodal solve interpolated by scikit-fem."""
    from skfem import Basis, ElementTetP1, ElementVector

    y = sim.initial_state()
    for u in ([0.5, 2.0], [0.4, -3.0], [0.5, 0.0]):
        y = sim.step(y, u)
    X = y.material[:3]
    U = sim.nodal_displacement(y)
    d = sim.mesh_data(y.n_elements)
    basis = Basis(d.block.mesh.to_skfem(), ElementVector(ElementTetP1()))
    flat = np.zeros(basis.N)
    flat[np.asarray(basis.nodal_dofs).T.ravel()] = U.ravel()
    probe = basis.probes(X[:, None])
    uX = (probe @ flat).reshape(3)  # skfem interleaves components per node
    np.testing.assert_allclose(y.pose[:3], X + uX, **tol["interpolation"])
    assert np.linalg.norm(uX) > 0.01  # the tissue does carry the tip
    # the frame is the material frame
    np.testing.assert_array_equal(y.pose[3:], y.material[3:])


def test_linear_elasticity_scales_with_E(sim, tol):
    ctrl = [[0.5, 2.0], [0.5, -1.0]]
    offs = []
    for E in (50.0, 150.0):
        p = SimParams(youngs_modulus=E, n_elements=sim.nominal_params.n_elements)
        y = sim.initial_state(p)
        for u in ctrl:
            y = sim.step(y, u, p)
        offs.append(y.pose[:3] - y.material[:3])
    np.testing.assert_allclose(offs[1], offs[0] / 3.0, **tol["float64_ref"])


def test_no_force_world_is_material(sim):
    p = SimParams(force_scale=0.0, n_elements=sim.nominal_params.n_elements)
    y = sim.initial_state(p)
    for _ in range(3):
        y = sim.step(y, [0.5, 1.0], p)
    np.testing.assert_array_equal(y.pose, y.material)
    assert not np.any(y.displacement)


def test_step_is_deterministic_and_pure(sim):
    params = SimParams(
        n_elements=sim.nominal_params.n_elements,
        actuation_cov=sim.actuation_cov(),
        actuation_seed=5,
    )
    y0 = sim.initial_state(params)
    a = sim.step(y0, [0.4, 2.0], params)
    b = Needle3DScenario().step(y0, [0.4, 2.0], params)
    assert a.identical(b)
    assert y0.t == 0 and not np.any(y0.displacement)
    assert not np.array_equal(a.applied, [0.4, 2.0])  # actuation noise applied


def test_deformed_obstacle_contains_its_deformed_centre(sim):
    y = sim.initial_state()
    for _ in range(6):
        y = sim.step(y, [0.5, 10.0])
    for b in sim.obstacles(y):
        assert b.contains(b.centre)
    g = sim.goal(y)
    assert sim.goal_distance(y) == pytest.approx(float(np.linalg.norm(y.pose[:3] - g.centre)))


def test_leaving_the_tissue_is_an_outcome(sim):
    from riskplan.control import NominalPlan
    from riskplan.control.lqg import execute

    cfg = Needle3DConfig(start=(0.9, 0.5, 0.5), obstacles=())
    s = Needle3DScenario(cfg)
    y0 = s.initial_state()
    plan = NominalPlan.from_rollout(s, y0, np.tile([0.5, 10.0], (6, 1)))
    ex = execute(s, plan, None, s.nominal_params)
    assert ex.outcome == "left_tissue" and "left the body" in ex.reason


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(target_center=(1.2, 0.5, 0.5)), "target"),
        (dict(target_center=(0.97, 0.5, 0.5)), "target"),
        (dict(start=(-0.1, 0.5, 0.5)), "start"),
        (dict(obstacles=(("sphere", (0.95, 0.5, 0.5), 0.1),)), "obstacles"),
        (dict(obstacles=(("cone", (0.5, 0.5, 0.5), 0.1),)), "obstacles"),
        (dict(obstacles=(("box", (0.5, 0.5, 0.5), (0.4, 0.6, 0.6)),)), "obstacles"),
        (dict(start_axis=(0, 0, 1), start_bevel=(0, 0, 2)), "start_axis"),
        (dict(curvature=0.0), "curvature"),
        (dict(poissons_ratio=0.5), "poissons_ratio"),
    ],
)
def test_bad_config(kw, match):
    with pytest.raises(InvalidInputError, match=match):
        Needle3DConfig(**kw)


def test_bad_control_and_state(sim):
    y = sim.initial_state()
    with pytest.raises(InvalidInputError):
        sim.step(y, [0.6, 0.0])
    with pytest.raises(InvalidInputError):
        sim.step(y, [0.5, np.nan])
    with pytest.raises(InvalidInputError, match="mesh"):
        sim.step(y, [0.5, 0.0], SimParams(n_elements=500))


@pytest.mark.parametrize("n_elements, E, nu", [(1296, 50.0, 0.4), (5000, 61.3, 0.38)])
def test_green_columns_equal_the_direct_solve(sim, tol, n_elements, E, nu):
    """The step's tissue response by cached Green's columns (superposition) against one
    solve of the whole system, at random points, next to the fixed face, on the planning
    mesh and a 5k-tetrahedra mesh."""
    p = SimParams(youngs_modulus=E, poissons_ratio=nu, n_elements=n_elements)
    model, block = sim.model(p), sim.mesh_data(n_elements).block
    gen = np.random.default_rng(3)
    pts = np.vstack([gen.random((20, 3)), [[0.5, 0.5, 0.01], [0.02, 0.97, 0.0]]])
    largest = 0.0
    for X in pts:
        e, lam = block.locate(X)
        f = gen.standard_normal(3)
        fast = model.point_load(int(e[0]), lam[0], f)
        direct = model.point_load_direct(int(e[0]), lam[0], f)
        for a, b in zip(fast, direct):
            np.testing.assert_allclose(a, b, **tol["superposition"])
        largest = max(largest, float(np.abs(direct[1]).max()))
    assert largest > 1e-3  # responses were compared, not zeros


def test_grid_location_equals_the_general_search(sim, tol):
    """The block's cell lookup finds a tetrahedron holding the point (the general search's
    interpolation of the node positions, on cell faces and corners too)."""
    from riskplan.deformable.tetlocate import find_points

    block = sim.mesh_data(sim.nominal_params.n_elements).block
    gen = np.random.default_rng(4)
    h = block.size / np.array(block.grid)
    pts = np.vstack([gen.random((40, 3)), h * gen.integers(0, 7, (10, 3)), [[1.0, 1.0, 1.0]]])
    for X in pts:
        e, lam = block.locate(X)
        e2, _ = find_points(block.mesh, X[None])
        assert e[0] >= 0 and e2[0] >= 0
        assert lam[0].min() >= -tol["barycentric"]["atol"]
        np.testing.assert_allclose(
            lam[0] @ block.mesh.nodes[block.tets[e[0]]], X, **tol["interpolation"]
        )


def test_gauges_agree_with_the_bodies(sim):
    """in_collision / in_goal (one batched solve) against the ConvexBody tests."""
    y = sim.initial_state()
    seen = set()
    for u in sim.random_controls(30, seed=5):
        y = sim.step(y, u)
        x = y.pose[:3]
        assert sim.in_collision(y) == any(bool(b.contains(x)) for b in sim.obstacles(y))
        assert sim.in_goal(y) == bool(sim.goal(y).contains(x))
        for body in sim._bodies(y):
            c = body.centre + 0.99 * body.A[:, 0]  # just inside each body
            g = sim._gauges(
                type(y)(
                    t=y.t,
                    displacement=y.displacement,
                    n_elements=y.n_elements,
                    pose=np.concatenate([c, y.pose[3:]]),
                    material=y.material,
                    applied=y.applied,
                )
            )
            seen.add(int(np.argmin(g)))
            assert g.min() <= 1.0
    assert len(seen) == 4  # every body was probed from inside


def _pushed(sim, n=14):
    y = sim.initial_state()
    for _ in range(n):
        y = sim.step(y, [0.5, 10.0])
    return y


def _perturbed(sim, y, k):
    """Material pose moved by 1e-7 along random (position, axis) directions: the tissue
    response there, ``(δx_world (12,), δc (3,))`` against ``y``."""
    gen = np.random.default_rng(k)
    dm = np.zeros(12)
    dm[[0, 1, 2, 9, 10, 11]] = 1e-7 * gen.standard_normal(6)
    tracked, pose = sim._tissue_response(y.material + dm, sim.nominal_params)
    a = sim.mesh_data(y.n_elements).slices[-1][0]
    return dm, pose - y.pose, tracked[a] - y.displacement[a]


def test_goal_jacobian_predicts_the_target_motion(sim, tol):
    """World frame: δc ≈ J δx for small moves of the tip's material pose (the response is
    quadratic within an element, so central differences are exact up to the step's
    second-order term); material frame: J = 0 (the target's material points stay)."""
    y = _pushed(sim)
    J = sim.goal_jacobian(y)
    assert np.abs(J[:, :3]).max() > 0.01  # the target does follow the tip
    for k in range(3):
        _, dx, dc = _perturbed(sim, y, k)
        np.testing.assert_allclose(J @ dx, dc, **tol["fd_quadratic"])
    assert not np.any(sim.with_frame("material").goal_jacobian(y))
    assert not np.any(sim.goal_jacobian(sim.initial_state()))


def test_material_frame_reads_the_material_pose_and_senses_the_world(sim, tol):
    """Material frame: x = the material pose, z = the world tip + noise, H = ∂z/∂x (against
    perturbed responses); world frame: measure = observe(reduced), the same noise draws."""
    y = _pushed(sim)
    mat = sim.with_frame("material")
    np.testing.assert_array_equal(mat.reduced(y), y.material)
    np.testing.assert_array_equal(sim.reduced(y), y.pose)
    for k in range(3):
        dm, dx, _ = _perturbed(sim, y, k)
        np.testing.assert_allclose(mat.observation_jacobian(y) @ dm, dx[:3], **tol["fd_quadratic"])
    np.testing.assert_array_equal(sim.observation_jacobian(y), sim.observation_matrix)
    a = sim.measure(y, rng=np.random.default_rng(7))
    b = sim.observe(sim.reduced(y), rng=np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(mat.measure(y, rng=np.random.default_rng(7)), a)
    # LQG-MP's bodies in the material frame are the balls and boxes of material points
    assert [b.kind for b in mat.state_obstacles(y)] == ["ellipsoid", "box", "ellipsoid"]
    np.testing.assert_array_equal(mat.state_goal(y).centre, sim.config.target_center)
    with pytest.raises(InvalidInputError, match="frame"):
        sim.with_frame("tissue")


def test_material_frame_sees_a_force_draw_as_no_process_noise():
    """Case force: a draw of f_int moves the world tip (world frame: M_t > 0, fresh noise
    at every step) but not the material pose (material frame: M_t = 0; the draw biases
    the measurement instead)."""
    import warnings

    from riskplan.control import NominalPlan, linearize
    from riskplan.scenarios.registry import scenario_from_config

    world = scenario_from_config("needle3d", None, "force")
    plan = NominalPlan.from_rollout(world, world.initial_state(), np.tile([0.5, 10.0], (8, 1)))
    mat = world.with_frame("material")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lw = linearize(world, plan, world.distribution, n_samples=6, seed=0)
        lm = linearize(mat, plan.reframed(mat), mat.distribution, n_samples=6, seed=0)
    assert np.trace(lw.M[-1]) > 0.0
    assert np.abs(lm.M).max() == 0.0
    assert np.trace(lm.N[-1]) > np.trace(lw.N[-1])  # the bias enters as measurement spread


def test_element_counts_on_one_grid_share_a_model(sim):
    """Two drawn element counts that round to the same grid get the same model object, and
    a step on either is the same (the mesh case's cache); another grid, another model."""
    a, b = SimParams(n_elements=4313), SimParams(n_elements=4300)
    assert sim.mesh_data(4313) is sim.mesh_data(4300)
    assert sim.model(a) is sim.model(b)
    ys = []
    for p in (a, b):
        y = sim.initial_state(p)
        for u in ([0.5, 1.0], [0.5, -2.0]):
            y = sim.step(y, u, p)
        ys.append(y)
    np.testing.assert_array_equal(ys[0].pose, ys[1].pose)
    np.testing.assert_array_equal(ys[0].displacement, ys[1].displacement)
    assert np.any(ys[0].displacement)
    assert sim.model(SimParams(n_elements=4253)) is not sim.model(a)
