"""Needle / car scenario (paper V-A): kinematics against closed forms, tissue coupling
against the FEM model and an independent interpolation (scikit-fem probes), snapshot /
restore, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from riskplan import geometry2d as geo
from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import SimParams, rollout
from riskplan.scenarios.needle import NeedleConfig, NeedleScenario, car_steer, car_step
from tests.conftest import TOL

TAU, RMIN, PHIMAX = 0.1, 0.25, math.pi / 3


def test_straight_line_for_zero_steering(tol):
    pose = np.array([0.1, 0.2, 0.7])
    for _ in range(9):
        pose = car_step(pose, 0.4, 0.0)
    expected = np.array([0.1, 0.2]) + 9 * TAU * 0.4 * np.array([math.cos(0.7), math.sin(0.7)])
    np.testing.assert_allclose(pose[:2], expected, **tol["float64_ref"])
    assert pose[2] == 0.7


@pytest.mark.parametrize("phi", [0.3, -0.8, PHIMAX])
def test_constant_steering_vertices_lie_on_circle(phi, tol):
    """Euler steps of constant length s and heading increment Δ are the vertices of a
    regular polygon inscribed in a circle of radius R = s / (2 sin(Δ/2))."""
    v = 0.45
    s = TAU * v
    delta = s * math.tan(phi) / (RMIN * math.tan(PHIMAX))
    th0 = 0.4
    p = np.array([0.3, 0.3, th0])
    pts = [p[:2]]
    for _ in range(30):
        p = car_step(p, v, phi)
        pts.append(p[:2])
    pts = np.array(pts)
    R = s / (2 * math.sin(abs(delta) / 2))
    # centre: perpendicular to the chord direction (θ0 + Δ/2) at distance R cos(Δ/2) from the chord midpoint
    side = math.copysign(1.0, delta)
    mid = 0.5 * (pts[0] + pts[1])
    a = th0 + side * math.pi / 2
    centre = mid + R * math.cos(delta / 2) * np.array([math.cos(a), math.sin(a)])
    np.testing.assert_allclose(np.linalg.norm(pts - centre, axis=1), R, **tol["float64_ref"])
    np.testing.assert_allclose(p[2], th0 + 30 * delta, **tol["float64_ref"])
    # continuous-time radius L = r_min tan φ_max / tan φ is the s -> 0 limit
    L = RMIN * math.tan(PHIMAX) / abs(math.tan(phi))
    assert abs(R - L) / L < s**2 / (20 * L**2)


def test_minimum_turning_radius_at_bound(tol):
    """At |φ| = φ_max the curvature is exactly 1/r_min: heading changes by s / r_min."""
    pose = car_step(np.array([0.0, 0.0, 0.0]), 0.5, PHIMAX)
    np.testing.assert_allclose(pose[2], TAU * 0.5 / RMIN, **tol["float64_ref"])
    pose = car_step(np.array([0.0, 0.0, 0.0]), 0.5, -PHIMAX)
    np.testing.assert_allclose(pose[2], -TAU * 0.5 / RMIN, **tol["float64_ref"])


def test_car_step_batch_equals_loop(rng, tol):
    poses = rng.uniform(-1, 1, (7, 3))
    v = rng.uniform(0, 0.5, 7)
    phi = rng.uniform(-PHIMAX, PHIMAX, 7)
    batch = car_step(poses, v, phi)
    loop = np.array([car_step(poses[i], v[i], phi[i]) for i in range(7)])
    np.testing.assert_allclose(batch, loop, **tol["float64_exact"])


# the RRT's sampling bounds: 2σ of the actuation noise inside [0, 0.5] x [-φ_max, φ_max]
STEER_BOUNDS = np.array([[0.1, 0.4], [-PHIMAX + math.radians(10), PHIMAX - math.radians(10)]])


@pytest.mark.parametrize(
    ("bearing", "dist", "steps"),
    [(0.0, 0.05, 2), (0.0, 0.11, 3), (0.01, 0.03, 2), (0.05, 0.06, 3), (-0.04, 0.09, 3)],
)
def test_car_steer_lands_on_target(bearing, dist, steps, tol):
    """Inside the bounds the control, held for the fewest possible steps, puts the Euler
    car exactly on the target (the oracle is car_step itself)."""
    pose = np.array([0.3, 0.4, 0.7])
    a = pose[2] + bearing
    target = pose[:2] + dist * np.array([math.cos(a), math.sin(a)])
    u = car_steer(pose, target, STEER_BOUNDS, 3)
    assert np.all((u >= STEER_BOUNDS[:, 0]) & (u <= STEER_BOUNDS[:, 1]))
    p, path = pose, []
    for _ in range(3):
        p = car_step(p, u[0], u[1])
        path.append(p[:2])
    np.testing.assert_allclose(path[steps - 1], target, **tol["float64_ref"])
    if steps == 3:  # two steps were not enough within the bounds
        assert np.linalg.norm(path[1] - target) > 1e-6


def test_car_steer_random_targets_in_bounds_and_exact_when_feasible(rng):
    """Random targets: the control is always inside the bounds; whenever a constant control
    well inside the bounds (a dense grid, two cells in from each bound) puts the 2nd or
    3rd state within 0.1 mm of the target, car_steer's control hits it exactly."""
    lo, hi = STEER_BOUNDS[:, 0], STEER_BOUNDS[:, 1]
    cell = (hi - lo) / 120
    V, PHI = np.meshgrid(
        np.linspace(lo[0] + 2 * cell[0], hi[0] - 2 * cell[0], 117),
        np.linspace(lo[1] + 2 * cell[1], hi[1] - 2 * cell[1], 117),
    )
    n_exact = 0
    for _ in range(80):
        pose = np.r_[rng.uniform(0.2, 0.8, 2), rng.uniform(-math.pi, math.pi)]
        a = pose[2] + rng.uniform(-0.12, 0.12)
        target = pose[:2] + rng.uniform(0.01, 0.14) * np.array([math.cos(a), math.sin(a)])
        u = car_steer(pose, target, STEER_BOUNDS, 3)
        assert np.all((u >= lo) & (u <= hi))
        p, miss = pose, []
        for _ in range(3):
            p = car_step(p, u[0], u[1])
            miss.append(np.linalg.norm(p[:2] - target))
        q, best = np.broadcast_to(pose, V.shape + (3,)), np.inf
        for j in range(3):
            q = car_step(q, V, PHI)
            if j >= 1:
                best = min(best, np.linalg.norm(q[..., :2] - target, axis=-1).min())
        if best < 1e-4:
            assert min(miss[1:]) < TOL["float64_abs"]["atol"]
            n_exact += 1
    assert n_exact >= 10, n_exact  # the check above was exercised


def test_car_steer_target_behind_turns_hardest_at_full_speed():
    pose = np.array([0.5, 0.5, 0.0])
    u = car_steer(pose, [0.45, 0.52], STEER_BOUNDS, 3)  # behind, to the left
    np.testing.assert_array_equal(u, [0.4, STEER_BOUNDS[1, 1]])
    u = car_steer(pose, [0.45, 0.48], STEER_BOUNDS, 3)  # behind, to the right
    np.testing.assert_array_equal(u, [0.4, STEER_BOUNDS[1, 0]])


def test_material_pose_follows_car_kinematics(needle, tol):
    """The car moves in the tissue's material frame: the material pose is the paper's car
    step, whatever the tissue does."""
    s0 = needle.initial_state()
    s1 = needle.step(s0, [0.35, -0.4])
    np.testing.assert_allclose(
        s1.material, car_step(s0.material, 0.35, -0.4), **tol["float64_exact"]
    )
    np.testing.assert_allclose(needle.reduced(s1), s1.pose, **tol["float64_exact"])
    assert s1.t == 1 and s0.t == 0
    np.testing.assert_array_equal(s0.pose, s0.material)  # undeformed start


def test_world_pose_against_independent_interpolation(needle, tol):
    """World position = X + u(X) with u interpolated by scikit-fem's own probes; world_pose's
    heading of F t against F t = t + (u(X + h t) − u(X − h t)) / 2h (central difference of
    the P1 interpolant along t, exact inside one element)."""
    import skfem

    p = SimParams(youngs_modulus=45.0, poissons_ratio=0.35)
    s = needle.step(needle.initial_state(p, pose=(0.42, 0.37, 0.6)), [0.4, 0.3], p)
    mesh = needle.mesh_data(175).mesh
    basis = skfem.Basis(mesh.to_skfem(), skfem.ElementTriP1())
    X, th = s.material[:2], s.material[2]
    t = np.array([math.cos(th), math.sin(th)])
    h = 1e-6
    pts = np.stack([X, X + h * t, X - h * t])
    P = basis.probes(pts.T)
    u = np.stack([P @ s.displacement[:, 0], P @ s.displacement[:, 1]], axis=1)
    np.testing.assert_allclose(s.pose[:2], X + u[0], **tol["float64_ref"])
    assert s.pose[2] == th  # the world heading is the material heading (module docstring)
    # world_pose's deformed heading (direction of F t), measured in docs/scenarios.md
    from riskplan.scenarios.needle import world_pose

    d = needle.mesh_data(175)
    elem, lam = d.locator.locate(X)
    w = world_pose(s.material, s.displacement[d.mesh.triangles[elem]], lam, d.shape_gradients[elem])
    np.testing.assert_allclose(w[:2], s.pose[:2], **tol["float64_ref"])
    ft = t + (u[1] - u[2]) / (2 * h)
    np.testing.assert_allclose(
        w[2], th + math.atan2(t[0] * ft[1] - t[1] * ft[0], t @ ft), **tol["fd_jacobian"]
    )
    assert np.linalg.norm(s.pose[:2] - X) > 1e-3  # the tissue did carry the robot


def test_tissue_carries_the_robot_stiffer_moves_it_less(needle, tol):
    """Same controls under E = 50 and E = 150: identical material paths, world positions
    displaced by the tissue, three times less in the stiffer tissue (linear elasticity:
    u ∝ 1/E); no interaction force: the world pose is the car's."""
    u = _controls(8, 3)
    soft, stiff = SimParams(youngs_modulus=50.0), SimParams(youngs_modulus=150.0)
    a = rollout(needle, needle.initial_state(soft), u, soft)
    b = rollout(needle, needle.initial_state(stiff), u, stiff)
    for sa, sb in zip(a[1:], b[1:]):
        np.testing.assert_array_equal(sa.material, sb.material)
        da, db = sa.pose[:2] - sa.material[:2], sb.pose[:2] - sb.material[:2]
        assert np.linalg.norm(da) > 5e-3
        np.testing.assert_allclose(db, da / 3.0, **tol["float64_ref"])
    assert np.abs(a[-1].pose - b[-1].pose).max() > 5e-3  # the pose depends on the tissue
    free = SimParams(force_scale=0.0)
    c = rollout(needle, needle.initial_state(free), u, free)
    np.testing.assert_array_equal(c[-1].pose, c[-1].material)
    np.testing.assert_array_equal(c[-1].material, a[-1].material)


def _controls(n, seed=0):
    g = np.random.default_rng(seed)
    return np.stack([g.uniform(0.2, 0.5, n), g.uniform(-0.6, 0.6, n)], axis=1)


def test_deterministic_and_snapshot_restore_bit_identical(needle):
    p = SimParams(actuation_cov=((0.01, 0.0), (0.0, 0.02)), actuation_seed=5)
    u = _controls(12)
    states = rollout(needle, needle.initial_state(p), u, p)
    snap = states[6]
    again = rollout(needle, snap, u[6:], p)
    for a, b in zip(states[6:], again):
        assert a.identical(b)
    # a fresh scenario object (empty caches) gives the same bits
    other = NeedleScenario()
    again2 = rollout(other, snap, u[6:], p)
    assert states[-1].identical(again2[-1])
    # stepping never mutates the input state
    before = snap.displacement.copy()
    needle.step(snap, u[6], p)
    assert np.array_equal(before, snap.displacement)


def test_equilibrium_residual_after_each_step(needle):
    p = SimParams()
    states = rollout(needle, needle.initial_state(p), _controls(10, 1), p)
    model = needle.model(p).model
    for s in states[1:]:
        f = needle.nodal_forces(s, p)
        r = model.residual(s.displacement, f)
        assert np.linalg.norm(r) <= TOL["linear_fem"]["atol"] * max(1.0, np.linalg.norm(f))
        np.testing.assert_allclose(np.linalg.norm(f.sum(0)), p.force_scale, **TOL["float64_exact"])


@pytest.mark.parametrize("n_elements,dense", [(300, True), (1000, False)])
def test_response_equals_fem_solve(needle, n_elements, dense):
    """Both response paths (dense flexibility matrix, sparse factorisation) equal a
    plain FEM solve of the step's nodal forces."""
    p = SimParams(youngs_modulus=40.0, poissons_ratio=0.3, n_elements=n_elements)
    assert (needle.model(p).green is not None) == dense
    s = needle.step(needle.initial_state(p, pose=(0.4, 0.45, 0.3)), [0.5, 0.2], p)
    f = needle.nodal_forces(s, p)
    ref = needle.model(p).model.solve(f)
    np.testing.assert_allclose(s.displacement, ref, **TOL["float64_accumulated"])
    r = needle.model(p).model.residual(s.displacement, f)
    assert np.linalg.norm(r) <= TOL["linear_fem"]["atol"]


def test_force_direction_and_support_reactions(needle, tol):
    p = SimParams(force_scale=1.5)
    s = needle.step(needle.initial_state(p, pose=(0.5, 0.5, 0.0)), [0.5, 0.9], p)
    reactions = needle.model(p).model.reactions(s.displacement)
    th = s.material[2]
    np.testing.assert_allclose(
        reactions.sum(0), -1.5 * np.array([math.cos(th), math.sin(th)]), **tol["fem_reactions"]
    )
    # the tissue near the robot moves along the push
    d = needle.mesh_data(175)
    elem, lam = d.locator.locate(s.material[:2])
    u_tip = lam @ s.displacement[d.mesh.triangles[elem]]
    assert u_tip @ np.array([math.cos(th), math.sin(th)]) > 0


def test_displacement_linear_in_force_scale(needle, tol):
    s0 = needle.initial_state(pose=(0.3, 0.6, -0.2))
    u1 = needle.step(s0, [0.4, 0.1], SimParams(force_scale=1.0)).displacement
    u2 = needle.step(s0, [0.4, 0.1], SimParams(force_scale=2.0)).displacement
    np.testing.assert_allclose(u2, 2 * u1, **tol["float64_ref"])
    u0 = needle.step(s0, [0.4, 0.1], SimParams(force_scale=0.0)).displacement
    assert np.all(u0 == 0.0)


def test_obstacles_and_goal_move_with_tissue(needle, tol):
    """Embedded points follow the P1 interpolant of the FEM displacement; checked
    against scikit-fem's own interpolation (``basis.probes``)."""
    import skfem

    p = SimParams()
    s = needle.step(needle.initial_state(p, pose=(0.6, 0.6, 0.5)), [0.5, 0.0], p)
    mesh = needle.mesh_data(175).mesh
    basis = skfem.Basis(mesh.to_skfem(), skfem.ElementTriP1())
    cfg = needle.config
    ref_pts = np.concatenate([*cfg.obstacles, cfg.goal_polygon, np.asarray(cfg.goal_center)[None]])
    P = basis.probes(ref_pts.T)
    expected = ref_pts + np.stack([P @ s.displacement[:, 0], P @ s.displacement[:, 1]], axis=1)
    got = np.concatenate([*needle.obstacles(s), needle.goal(s), needle.goal_center(s)[None]])
    np.testing.assert_allclose(got, expected, **tol["float64_ref"])
    assert np.abs(got - ref_pts).max() > 1e-3  # they did move


def test_embedded_mesh_nodes_move_exactly_with_nodes(tol):
    """An obstacle whose vertices are mesh nodes moves by the nodal displacement."""
    from riskplan.deformable import mesh_polygon

    base = NeedleConfig()
    mesh = mesh_polygon(base.corners, 175)
    interior = np.flatnonzero(np.all((mesh.nodes > 0.2) & (mesh.nodes < 0.8), axis=1))[:3]
    tri = mesh.nodes[interior]
    sim = NeedleScenario(NeedleConfig(obstacles=(tri,)))
    s = sim.step(sim.initial_state(pose=(0.1, 0.5, 0.0)), [0.5, 0.3])
    np.testing.assert_allclose(
        sim.obstacles(s)[0], tri + s.displacement[interior], **tol["float64_ref"]
    )


def test_robot_outside_tissue_pushes_nothing(needle):
    s = needle.initial_state(pose=(0.98, 0.5, 0.0))
    s1 = needle.step(s, [0.5, 0.0])
    assert not needle.inside(s1)
    assert np.all(s1.displacement == 0.0) and np.all(np.isfinite(s1.pose))
    np.testing.assert_array_equal(s1.pose, s1.material)  # out of the tissue nothing carries it


def test_collision_and_goal_predicates(needle):
    cfg = needle.config
    c = cfg.obstacles[0].mean(0)
    s = needle.initial_state(pose=(c[0], c[1], 0.0))
    assert needle.in_collision(s)
    g = needle.initial_state(pose=(*cfg.goal_center, 0.0))
    assert needle.in_goal(g) and not needle.in_collision(g)
    assert needle.goal_distance(g) == 0.0
    assert not needle.in_goal(needle.initial_state())


def test_observe_noise(needle, rng, tol):
    x = np.array([0.2, 0.3, 1.0])
    np.testing.assert_array_equal(needle.observe(x), [0.2, 0.3])
    np.testing.assert_allclose(
        needle.observe(x, noise=[0.01, -0.01]), [0.21, 0.29], **tol["float64_exact"]
    )
    z = np.array([needle.observe(x, rng=rng) for _ in range(3000)]) - x[:2]
    sd = needle.config.sensing_std
    assert np.all(np.abs(z.mean(0)) < 4 * sd / np.sqrt(3000))
    assert np.all(np.abs(z.var(0) / sd**2 - 1) < 4 * np.sqrt(2 / 3000))
    with pytest.raises(InvalidInputError):
        needle.observe([0.1, 0.2])


@pytest.mark.parametrize(
    "control",
    [
        [0.51, 0.0],
        [-1e-9, 0.0],
        [0.2, PHIMAX + 1e-9],
        [0.2, -PHIMAX - 0.1],
        [np.nan, 0.0],
        [0.2, np.inf],
        [0.2],
    ],
)
def test_bad_controls(needle, control):
    with pytest.raises(InvalidInputError, match="control"):
        needle.step(needle.initial_state(), control)


def test_state_mesh_mismatch_and_type(needle):
    s = needle.initial_state()
    with pytest.raises(InvalidInputError, match="n_elements"):
        needle.step(s, [0.1, 0.0], SimParams(n_elements=300))
    with pytest.raises(InvalidInputError, match="NeedleState"):
        needle.step("state", [0.1, 0.0])
    with pytest.raises(InvalidInputError):
        needle.initial_state(pose=(0.1, np.nan, 0.0))


def test_obstacle_outside_body_rejected():
    sim = NeedleScenario(NeedleConfig(obstacles=(geo.circle_polygon((1.02, 0.5), 0.05),)))
    with pytest.raises(InvalidInputError, match="outside the body"):
        sim.initial_state()


def test_mesh_case_states_are_consistent(needle):
    for n in (50, 1000):
        p = SimParams(n_elements=n)
        s = rollout(needle, needle.initial_state(p), _controls(5, n), p)[-1]
        assert s.displacement.shape == (needle.mesh_data(n).mesh.n_nodes, 2)
        assert np.all(np.isfinite(s.displacement))


def test_transfer_state_moves_the_push_to_another_mesh(needle, tol):
    """The same material pose on another mesh: its displacement is that mesh's response to
    the same push, and stepping on goes as from a start at that material pose."""
    p, q = SimParams(), SimParams(n_elements=300)
    s = rollout(needle, needle.initial_state(p), _controls(4, 7), p)[-1]
    moved = needle.transfer_state(s, q)
    assert moved.n_elements == 300 and moved.t == s.t
    np.testing.assert_array_equal(moved.material, s.material)
    ref = needle.step(needle.initial_state(q, pose=s.material), [0.0, 0.0], q)
    np.testing.assert_allclose(moved.displacement, ref.displacement, **tol["float64_exact"])
    np.testing.assert_allclose(moved.pose, ref.pose, **tol["float64_exact"])
    assert np.abs(moved.pose - s.pose).max() > 0.0  # the offset under the load is mesh-dependent
    start = needle.transfer_state(needle.initial_state(p), q)
    np.testing.assert_array_equal(start.pose, start.material)
