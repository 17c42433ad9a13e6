"""Monte Carlo execution of trajectories on the simulated robot (riskplan.planning.validate)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from riskplan.collision import Environment, trajectory_bound
from riskplan.errors import InvalidInputError
from riskplan.kinematics.robot_mixture import arc_backbone
from riskplan.planning.clearance import tube_clearance
from riskplan.planning.validate import (
    default_radius,
    execute_on_robot,
    mixture_monte_carlo,
    validation_markdown,
    validation_table,
)
from tests.conftest import TOL, approx_tol


def box_env(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return Environment.from_meshes([m])


@pytest.fixture(scope="module")
def robot():
    from riskplan.robots import load_robot

    return load_robot("paper")


# --------------------------------------------------------------------------- tube test
@pytest.mark.parametrize("margin", [-1e-3, -3e-4, 3e-4, 1e-3])
def test_tube_clearance_between_coarse_samples(margin):
    # straight backbone along z sampled only at z = 0, 0.1, 0.2; a slab x >= a spans z in
    # [0.04, 0.06], so the closest approach lies between samples: clearance = a - r exactly
    r = 0.01
    a = r + margin
    env = box_env([a, -0.05, 0.04], [a + 0.05, 0.05, 0.06])
    bb = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1], [0.0, 0.0, 0.2]])
    c = tube_clearance(env, bb, r, resolution=2e-4)
    assert (c < 0) == (margin < 0)
    assert abs(c - margin) <= 1e-4 + TOL["float64_abs"]["atol"]


def test_tube_clearance_arc_against_half_space(tol):
    # constant-curvature arc bending to +x: max x = (1 - cos(kL)) / k at the tip; slab x >= c
    k, L, r = 4.0, 0.2, 0.01
    bb = arc_backbone(k, 0.0, L, 81)
    xmax = (1 - np.cos(k * L)) / k
    for gap in (-2e-3, 2e-3, 0.03):
        c = xmax + r + gap
        env = box_env([c, -0.5, -0.5], [c + 0.5, 0.5, 0.5])
        got = tube_clearance(env, bb, r)
        np.testing.assert_allclose(got, gap, **tol["float64_ref"])
    # batch == loop
    env = box_env([xmax + r, -0.5, -0.5], [xmax + r + 0.5, 0.5, 0.5])
    bbs = arc_backbone(np.array([1.0, 4.0, 6.0]), 0.0, L, 81)
    batch = tube_clearance(env, bbs, r)
    loop = np.array([tube_clearance(env, b, r) for b in bbs])
    np.testing.assert_allclose(batch, loop, **tol["float64_exact"])
    assert batch[0] > 0 and batch[2] < 0


# ------------------------------------------------------------- robot Monte Carlo
def test_single_configuration_matches_training_data_physics(robot):
    """Oracle: the data generator's own arrival code (random start, straight path through the
    hysteresis model, per-run variation) gives the distribution of the body's reach; a slab
    placed at its median must be hit with the same probability by the validation Monte Carlo."""
    from riskplan.datasets.generate import arrive, to_base_frame
    from riskplan.datasets.protocol import random_starts, straight_path

    target = np.array([0.02, 0.0, 0.0, 0.0])
    lim = robot.displacement_limits
    r = default_radius(robot)
    N = 160
    ss = np.random.SeedSequence(987).spawn(N)
    parts = [c.spawn(2) for c in ss]
    starts = np.stack([random_starts(lim, 1, np.random.default_rng(p[0]))[0] for p in parts])
    paths = np.stack([straight_path(s, target, 16) for s in starts])
    _, shape = arrive(robot, paths, [p[1] for p in parts])
    P, _ = to_base_frame(robot, shape.positions, shape.rotations)
    reach = P[..., 0].max(axis=-1) + r  # furthest extent of the body along +x
    c = float(np.median(reach))
    assert np.ptp(reach) > 1e-4  # the hysteresis spread is what is being tested
    p_oracle = float(np.mean(reach > c))
    env = box_env([c, -0.5, -0.5], [c + 0.5, 0.5, 0.5])
    n = 160
    res = execute_on_robot(robot, target[None], env, n, seed=5, backend="serial")
    p = float(res.trajectory.probability)
    sigma = np.sqrt(max(p_oracle * (1 - p_oracle), 0.05) * (1 / n + 1 / N))
    assert abs(p - p_oracle) <= 3.5 * sigma, (p, p_oracle)
    np.testing.assert_array_equal(res.per_configuration.hits, [res.trajectory.hits])
    assert res.trajectory.low <= p <= res.trajectory.high


def test_any_configuration_counts_and_known_cases(robot):
    # straight at home: the slab beyond the reach of the robot is never touched, a slab the
    # bent configuration crosses deeply is always hit; the trajectory counts either
    env = box_env([0.05, -0.5, -0.5], [0.55, 0.5, 0.5])
    traj = np.array([[0.0, 0.0, 0.0, 0.0], [0.03, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    res = execute_on_robot(robot, traj, env, 12, seed=1, backend="serial", chunk=5)
    np.testing.assert_array_equal(res.per_configuration.hits, [0, 12, 0])
    assert int(res.trajectory.hits) == 12 and res.clearance.shape == (12, 3)
    far = execute_on_robot(robot, traj[[0, 2]], env, 12, seed=1, backend="serial")
    assert int(far.trajectory.hits) == 0 and np.all(far.clearance > 0.02)


def test_same_seed_same_result_across_backends_and_chunks(robot):
    env = box_env([0.03, -0.5, -0.5], [0.53, 0.5, 0.5])
    traj = np.array([[0.0, 0.0, 0.0, 0.0], [0.018, 0.004, 0.0, 0.0]])
    a = execute_on_robot(robot, traj, env, 8, seed=3, backend="serial", chunk=3)
    b = execute_on_robot(robot, traj, env, 8, seed=3, backend="serial", chunk=8)
    c = execute_on_robot(robot, traj, env, 8, seed=3, backend="local", workers=2, chunk=4)
    np.testing.assert_array_equal(a.clearance, b.clearance)
    np.testing.assert_array_equal(a.clearance, c.clearance)
    d = execute_on_robot(robot, traj, env, 8, seed=4, backend="serial")
    assert not np.array_equal(a.clearance, d.clearance)


def test_bad_input_names_the_argument(robot):
    env = box_env([0.05, -0.5, -0.5], [0.55, 0.5, 0.5])
    ok = np.zeros((2, 4))
    with pytest.raises(InvalidInputError, match="trajectory"):
        execute_on_robot(robot, np.zeros((2, 3)), env, 2, backend="serial")
    with pytest.raises(InvalidInputError, match="trajectory"):
        execute_on_robot(robot, np.zeros(4), env, 2, backend="serial")
    with pytest.raises(InvalidInputError, match="trajectory"):
        execute_on_robot(robot, np.full((2, 4), 0.5), env, 2, backend="serial")
    with pytest.raises(InvalidInputError, match="trajectory"):
        execute_on_robot(robot, np.array([[np.nan, 0, 0, 0]]), env, 2, backend="serial")
    with pytest.raises(InvalidInputError, match=r"^n"):
        execute_on_robot(robot, ok, env, 0, backend="serial")
    with pytest.raises(InvalidInputError, match="seed"):
        execute_on_robot(robot, ok, env, 2, seed=-1, backend="serial")
    with pytest.raises(InvalidInputError, match="backend"):
        execute_on_robot(robot, ok, env, 2, backend="threads")
    with pytest.raises(InvalidInputError, match="radius"):
        execute_on_robot(robot, ok, env, 2, radius=-0.01, backend="serial")
    with pytest.raises(InvalidInputError, match="environment: expected a 3-D Environment"):
        execute_on_robot(robot, ok, "chest", 2, backend="serial")
    square = Environment.from_polygons([[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]])
    with pytest.raises(
        InvalidInputError, match="environment: expected a 3-D Environment, got a 2-D"
    ):
        execute_on_robot(robot, ok, square, 2, backend="serial")


# ------------------------------------------------------------ mixtures of the model
def test_mixture_monte_carlo_below_eq10_bound_and_table(robot):
    from riskplan.kinematics import load_model

    model = load_model("paper")
    env = box_env([0.045, -0.5, -0.5], [0.545, 0.5, 0.5])
    traj = np.linspace([0.0, 0.0, 0.0, 0.0], [0.03, 0.0, 0.0, 0.0], 4)
    mc = mixture_monte_carlo(model, traj, env, 20_000, seed=2)
    bound = float(trajectory_bound(model.predict(traj), env))
    assert 0 < mc.trajectory.probability < 1
    assert mc.trajectory.low <= bound  # eq. 10 over eq. 9 bounds independent draws
    assert mc.per_configuration.probability.shape == (4,)
    assert mc.trajectory.high >= mc.per_configuration.low.max()
    again = mixture_monte_carlo(model, traj, env, 20_000, seed=2)
    assert int(again.trajectory.hits) == int(mc.trajectory.hits)
    with pytest.raises(InvalidInputError, match="trajectory"):
        mixture_monte_carlo(model, np.zeros((3, 2)), env, 10)
    rows = validation_table(
        model, {"a": traj[:2], "b": traj}, env, n_robot=4, n_mixture=2000, backend="serial"
    )
    assert [r["name"] for r in rows] == ["a", "b"]
    assert rows[1]["bound"] == pytest.approx(bound, **approx_tol("float64_exact"))
    assert all(r["bound_union"] >= r["bound"] for r in rows)  # ignoring the weights can only add
    assert all(0 <= r["robot_low"] <= r["robot_mc"] <= r["robot_high"] <= 1 for r in rows)
    # the tube of the disk radius contains the backbone and the disks: it collides whenever they do
    assert all(r["robot_disks_hits"] <= r["robot_hits"] for r in rows)
    assert "| b |" in validation_markdown(rows)


def test_disks_body_hits_a_slab_at_a_disk_but_not_between_disks(robot):
    # near home the body is straight along z: the 10 mm disks (at s = k * 0.2 / 9) reach a slab at
    # x >= 6 mm facing disk 4, the 3 mm backbone does not; a slab in the gap between disks 4 and 5
    # is touched only by the conservative 10 mm tube
    from riskplan.robots.geometry import BodyGeometry

    geom = BodyGeometry.from_params(robot.params)
    z4, z5 = geom.disk_s[3], geom.disk_s[4]
    at_disk = box_env([0.006, -0.05, z4 - 0.003], [0.1, 0.05, z4 + 0.003])
    gap = box_env([0.006, -0.05, z4 + 0.004], [0.1, 0.05, z5 - 0.004])
    traj = np.zeros((1, 4))
    for env, disks_hit in ((at_disk, 6), (gap, 0)):
        d = execute_on_robot(robot, traj, env, 6, seed=0, body="disks", backend="serial")
        t = execute_on_robot(robot, traj, env, 6, seed=0, backend="serial")
        assert (
            int(d.trajectory.hits) == disks_hit
            and d.radius == geom.backbone_radius
            and d.body == "disks"
        )
        assert int(t.trajectory.hits) == 6
    with pytest.raises(InvalidInputError, match="body"):
        execute_on_robot(robot, traj, gap, 2, body="capsule", backend="serial")


def test_disk_clearance_closed_form(robot, tol):
    # straight body along z with identity frames: every disk's rim reaches x = R, so a slab
    # x >= a gives a clearance a - R (a ring sample lies exactly on the +x rim)
    from riskplan.planning.clearance import disk_clearance
    from riskplan.robots.geometry import BodyGeometry

    geom = BodyGeometry.from_params(robot.params)
    s = np.linspace(0.0, 0.2, 41)
    P = np.stack([np.zeros_like(s), np.zeros_like(s), s], axis=-1)
    R = np.broadcast_to(np.eye(3), (41, 3, 3))
    for a in (0.0095, 0.0105):
        env = box_env([a, -0.5, -0.5], [a + 0.5, 0.5, 0.5])
        got = disk_clearance(env, s, np.stack([P, P]), np.stack([R, R]), geom)
        assert got.shape == (2,)
        np.testing.assert_allclose(got, a - geom.disk_radius, **tol["float64_ref"])


def test_endpoint_warnings_name_a_colliding_start_or_goal():
    from riskplan.planning.validate import endpoint_warnings

    rows = [
        {"name": "nominal", "n_robot": 50, "robot_per_config": [0.0, 0.4, 1.0]},
        {"name": "optimised", "n_robot": 50, "robot_per_config": [0.6, 0.0, 0.2]},
        {"name": "clear", "n_robot": 50, "robot_per_config": [0.0, 0.0, 0.49]},
    ]
    lines = endpoint_warnings(rows)
    assert len(lines) == 2
    assert lines[0].startswith("nominal: the goal configuration") and "100 % of 50" in lines[0]
    assert lines[1].startswith("optimised: the start configuration") and "60 %" in lines[1]
    # a one-configuration trajectory is reported once; a lower threshold catches more
    assert len(endpoint_warnings([{"name": "x", "n_robot": 5, "robot_per_config": [1.0]}])) == 1
    assert len(endpoint_warnings(rows, threshold=0.2)) == 4
    with pytest.raises(InvalidInputError, match="threshold"):
        endpoint_warnings(rows, threshold=0.0)


def test_base_rotation_and_retraction_executions(tmp_path):
    """A robot with base motion runs (T, n_config) trajectories: the tendons through the play
    operator, the base as commanded. Oracles: turning the base by phi and the scene by Rz(phi)
    gives the same clearances (common seeds); a retraction rho moves a slab's contact as the
    exposed length L - rho: the straight robot hits a slab at z = 0.09 m when exposed 0.12 m,
    never when exposed 0.07 m."""
    from pathlib import Path

    from riskplan.robots import load_robot

    rob = load_robot(Path(__file__).parents[1] / "data" / "kuntz-lab" / "task-0001.toml")
    m = rob.n_tendons
    # the body: the lab's rod radius, not the paper robot's 10 mm separator disks
    assert default_radius(rob) == 0.003 and default_radius(load_robot("paper")) == 0.01
    d = rob.displacements_for_tensions(np.array([[0.0, 0.0, 0.0], [0.8, 0.0, 0.0]]))
    phi = 0.7
    traj0 = np.c_[d, [0.0, 0.0], [0.0, 0.0]]
    traj1 = np.c_[d, [phi, phi], [0.0, 0.0]]
    # a slab on the side the bent robot's tip moves to, 4 mm inside its nominal tip (the play
    # operator leaves the executions short of the nominal shape)
    tip = rob.solve_displacements(d[1]).positions[-1]
    u = tip[:2] / np.linalg.norm(tip[:2])
    e = np.array([[u[0], -u[1], 0.0], [u[1], u[0], 0.0], [0.0, 0.0, 1.0]])  # x -> u
    near = float(np.linalg.norm(tip[:2])) - 0.004
    slab0 = box_env([near, -0.05, 0.0], [near + 0.05, 0.05, 0.2])
    side = Environment(slab0.vertices @ e.T, slab0.faces, validate=False)
    c, s = np.cos(phi), np.sin(phi)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    turned = Environment(side.vertices @ Rz.T, side.faces, validate=False)
    a = execute_on_robot(rob, traj0, side, 6, seed=2, backend="serial", radius=0.003)
    b = execute_on_robot(rob, traj1, turned, 6, seed=2, backend="serial", radius=0.003)
    np.testing.assert_allclose(a.clearance, b.clearance, **TOL["float64_ref"])
    assert np.all(a.clearance[:, 0] > 0) and np.any(a.clearance[:, 1] < 0)  # the bend reaches
    # retraction: a slab across the robot's axis above the exposed tip
    slab = box_env([-0.05, -0.05, 0.09], [0.05, 0.05, 0.2])
    zero = rob.displacements_for_tensions(np.zeros((1, m)))
    full = execute_on_robot(rob, np.c_[zero, [0.0], [0.0]], slab, 4, seed=2, radius=0.003)
    short = execute_on_robot(rob, np.c_[zero, [0.0], [0.05]], slab, 4, seed=2, radius=0.003)
    assert int(full.trajectory.hits) == 4 and int(short.trajectory.hits) == 0
    with pytest.raises(InvalidInputError, match=r"\(T, 3\) or \(T, 5\)"):
        execute_on_robot(rob, np.zeros((2, 4)), slab, 2)
