"""Plans out (riskplan.planning.export): CSV, JSON and ROS 2 JointTrajectory YAML round trips,
tissue controls and gains, and the quaternion order of --base-pose."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from riskplan.collision.mesh_files import BasePose
from riskplan.errors import InvalidInputError
from riskplan.planning.export import (
    TendonPlan,
    plan_times,
    read_tendon_plan,
    read_tissue_plan,
    tendon_plan,
    write_tendon_plan,
    write_tissue_plan,
)
from riskplan.robots import load_robot
from tests.conftest import TOL

yaml = pytest.importorskip("yaml")


@pytest.fixture(scope="module")
def robot():
    return load_robot("paper")


@pytest.fixture
def trajectory(rng, robot):
    lim = robot.displacement_limits
    # a random walk inside the limits, as a planner's interpolated path
    steps = rng.uniform(-0.002, 0.002, size=(12, robot.n_tendons))
    d = np.clip(np.cumsum(steps, axis=0), lim[:, 0], lim[:, 1])
    return d, rng.uniform(0, 0.05, size=len(d))


def test_times_follow_the_fastest_tendon(trajectory):
    d, _ = trajectory
    t = plan_times(d, 0.004)
    expected = [0.0]
    for i in range(1, len(d)):  # the loop the vectorised form must equal
        expected.append(expected[-1] + max(abs(d[i] - d[i - 1])) / 0.004)
    np.testing.assert_allclose(t, expected, **TOL["float64_exact"])
    with pytest.raises(InvalidInputError, match="tendon_speed"):
        plan_times(d, 0.0)


@pytest.mark.parametrize("with_robot", [True, False])
def test_csv_json_yaml_round_trip(tmp_path, robot, trajectory, with_robot):
    d, risk = trajectory
    plan = tendon_plan(
        robot if with_robot else None, d, risk, trajectory_risk=0.07, name="optimised"
    )
    files = write_tendon_plan(plan, tmp_path)
    assert {p.name for p in files.values()} == {
        "optimised.csv",
        "optimised.json",
        "optimised.joint_trajectory.yaml",
    }
    for kind in ("csv", "json"):
        back = read_tendon_plan(files[kind])
        np.testing.assert_array_equal(back.times, plan.times)
        np.testing.assert_array_equal(back.displacements, plan.displacements)
        np.testing.assert_array_equal(back.risk, plan.risk)
        assert back.tendon_names == plan.tendon_names
        if with_robot:
            np.testing.assert_array_equal(back.tensions, plan.tensions)
        else:
            assert back.tensions is None
    assert read_tendon_plan(files["json"]).trajectory_risk == 0.07
    ros = read_tendon_plan(files["ros"])
    np.testing.assert_array_equal(ros.displacements, plan.displacements)
    np.testing.assert_allclose(ros.times, plan.times, **TOL["ros_duration"])
    if with_robot:
        np.testing.assert_array_equal(ros.tensions, plan.tensions)


def test_joint_trajectory_message_layout(tmp_path, robot, trajectory):
    """The YAML is a trajectory_msgs/msg/JointTrajectory: joint names = tendon names, positions =
    displacements, effort = the model's tensions, time_from_start = {sec, nanosec}."""
    d, risk = trajectory
    plan = tendon_plan(robot, d, risk, name="nominal")
    msg = yaml.safe_load(write_tendon_plan(plan, tmp_path)["ros"].read_text())
    assert set(msg) == {"header", "joint_names", "points"}
    assert msg["header"] == {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
    assert msg["joint_names"] == ["straight-0", "straight-120", "straight-240", "helical"]
    assert len(msg["points"]) == len(d)
    for i, p in enumerate(msg["points"]):
        assert set(p) == {"positions", "velocities", "accelerations", "effort", "time_from_start"}
        assert p["positions"] == d[i].tolist()
        tfs = p["time_from_start"]
        assert isinstance(tfs["sec"], int) and 0 <= tfs["nanosec"] < 1_000_000_000
    # effort: tensions that realise the displacements on the robot model, and back
    tau = np.array([p["effort"] for p in msg["points"]])
    np.testing.assert_array_equal(tau, robot.tensions_for_displacements(d))
    taut = (tau > 0).all(axis=1)  # a slack tendon's displacement is not a function of tension
    np.testing.assert_allclose(
        robot.displacements_for_tensions(tau[taut]), d[taut], **TOL["displacement_roundtrip"]
    )


def test_bad_plans_are_refused(trajectory):
    d, risk = trajectory
    with pytest.raises(InvalidInputError, match="risk: expected shape"):
        TendonPlan(np.zeros(len(d)), d, None, risk[:-1], [f"t{j}" for j in range(4)])
    with pytest.raises(InvalidInputError, match="times: must not decrease"):
        TendonPlan(-np.arange(len(d), dtype=float), d, None, risk, [f"t{j}" for j in range(4)])
    with pytest.raises(InvalidInputError, match="distinct names"):
        TendonPlan(np.zeros(len(d)), d, None, risk, ["a", "a", "b", "c"])


@pytest.mark.parametrize("dt", [0.1, None])
def test_tissue_controls_and_gains_round_trip(tmp_path, rng, dt):
    T, q, p, n = 7, 2, 3, 2
    plan = SimpleNamespace(controls=rng.normal(size=(T, q)), reduced=rng.normal(size=(T + 1, p)))
    lin = SimpleNamespace(**{k: rng.normal(size=(T, 3, 3)) for k in ("A", "B", "M", "H", "N")})
    ctl = SimpleNamespace(
        L=rng.normal(size=(T, q, p)),
        K=rng.normal(size=(T, p, n)),
        P=rng.normal(size=(T, p, p)),
        lin=lin,
    )
    risk = rng.uniform(0, 0.1, size=T)
    files = write_tissue_plan(tmp_path, plan, ctl, dt=dt, risk=risk)
    back = read_tissue_plan(files["controls"], files["gains"])
    np.testing.assert_array_equal(back["risk"], risk)
    np.testing.assert_array_equal(back["controls"], plan.controls)
    np.testing.assert_array_equal(back["reduced"], plan.reduced[:-1])
    if dt is None:
        assert back["time_s"] is None
    else:
        np.testing.assert_allclose(back["time_s"], dt * np.arange(T), **TOL["float64_exact"])
    g = back["gains"]
    for key in ("L", "K", "P"):
        np.testing.assert_array_equal(g[key], getattr(ctl, key))
    for key in ("A", "B", "M", "H", "N"):
        np.testing.assert_array_equal(g[key], getattr(lin, key))
    np.testing.assert_array_equal(g["reduced"], plan.reduced)


def test_base_pose_quaternion_orders_are_explicit(rng):
    from scipy.spatial.transform import Rotation

    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    R = Rotation.from_quat(q, scalar_first=True).as_matrix()  # independent oracle
    w, x, y, z = (float(v) for v in q)
    p = "0.1,-0.2,0.3"
    a = BasePose.parse(f"{p},{w!r},{x!r},{y!r},{z!r}")
    b = BasePose.parse(f"wxyz:{p},{w!r},{x!r},{y!r},{z!r}")
    c = BasePose.parse(f"xyzw:{p},{x!r},{y!r},{z!r},{w!r}")
    for pose in (a, b, c):
        np.testing.assert_allclose(pose.rotation, R, **TOL["orthonormality"])
        np.testing.assert_array_equal(pose.position, [0.1, -0.2, 0.3])
    # the same numbers in the other order are another rotation
    d = BasePose.parse(f"xyzw:{p},{w!r},{x!r},{y!r},{z!r}")
    assert not np.allclose(d.rotation, R, **TOL["orthonormality"])
    with pytest.raises(InvalidInputError, match="xyzw:x,y,z,qx,qy,qz,qw"):
        BasePose.parse("xyzw:1,2,3")


@pytest.fixture(scope="module")
def lab_robot():
    """The lab's task robot: 3 tendons, base rotation and retraction enabled."""
    from pathlib import Path

    rob = load_robot(Path(__file__).parents[1] / "data" / "kuntz-lab" / "task-0001.toml")
    assert rob.n_config == rob.n_tendons + 2
    return rob


def test_base_rotation_and_retraction_are_joints(tmp_path, rng, lab_robot):
    """A robot with base motion exports rotation and retraction as the joints ``base_rotation``
    (rad) and ``base_retraction`` (m) after the tendons; CSV and JSON round-trip bit for bit,
    the YAML's positions too, and its times to the nanosecond."""
    lim = lab_robot.configuration_limits
    T, m = 9, lab_robot.n_tendons
    # reachable configurations: tensions inside their limits, base motion inside its limits
    v = lim[:, 0] + rng.uniform(0.1, 0.9, size=(T, lab_robot.n_config)) * np.ptp(lim, axis=1)
    v[:, :m] = rng.uniform(0.0, 0.5, size=(T, m)) * lab_robot.tension_limits
    q = lab_robot.configuration_to_displacements(v)
    risk = rng.uniform(0, 0.05, size=T)
    plan = tendon_plan(lab_robot, q, risk, trajectory_risk=0.1, name="optimised")
    np.testing.assert_array_equal(plan.displacements, q[:, :m])
    np.testing.assert_array_equal(plan.rotation, q[:, m])
    np.testing.assert_array_equal(plan.retraction, q[:, m + 1])
    # tensions of the robot retracted by each row's retraction: those the rows were made from
    np.testing.assert_allclose(plan.tensions, v[:, :m], **TOL["tension_solve"])
    files = write_tendon_plan(plan, tmp_path)
    msg = yaml.safe_load(files["ros"].read_text())
    names = [t.name for t in lab_robot.params.tendons]
    assert msg["joint_names"] == names + ["base_rotation", "base_retraction"]
    for i, p in enumerate(msg["points"]):
        assert p["positions"] == q[i].tolist()
        assert p["effort"] == plan.tensions[i].tolist() + [0.0, 0.0]
    for kind in ("csv", "json", "ros"):
        back = read_tendon_plan(files[kind])
        assert back.tendon_names == plan.tendon_names
        for key in ("displacements", "tensions", "rotation", "retraction"):
            np.testing.assert_array_equal(getattr(back, key), getattr(plan, key))
        if kind == "ros":
            np.testing.assert_allclose(back.times, plan.times, **TOL["ros_duration"])
        else:
            np.testing.assert_array_equal(back.times, plan.times)
            np.testing.assert_array_equal(back.risk, plan.risk)
    # a robot without base motion has no base joints and keeps its layout
    assert read_tendon_plan(files["json"]).trajectory_risk == 0.1


def test_base_motion_sets_the_step_time(lab_robot):
    """Each step lasts as long as its slowest actuator: a pure rotation of pi/2 takes
    (pi/2) / ROTATION_SPEED, a pure retraction of 20 mm 0.02 / RETRACTION_SPEED, and a rotation
    across +-pi is taken the short way round."""
    from riskplan.planning.export import RETRACTION_SPEED, ROTATION_SPEED

    d = np.zeros((4, 3))
    rot = np.array([0.0, np.pi / 2, np.pi / 2, np.pi / 2])
    ret = np.array([0.0, 0.0, 0.02, 0.02])
    t = plan_times(d, rotation=rot, retraction=ret)
    np.testing.assert_allclose(
        np.diff(t),
        [np.pi / 2 / ROTATION_SPEED, 0.02 / RETRACTION_SPEED, 0.0],
        **TOL["float64_exact"],
    )
    wrap = plan_times(np.zeros((2, 3)), rotation=np.array([np.pi - 0.1, -np.pi + 0.1]))
    np.testing.assert_allclose(wrap[-1], 0.2 / ROTATION_SPEED, **TOL["float64_exact"])
    with pytest.raises(InvalidInputError, match="rotation_speed"):
        plan_times(d, rotation=rot, rotation_speed=0.0)


def test_a_tendon_named_like_a_base_joint_is_refused():
    d = np.zeros((2, 2))
    with pytest.raises(InvalidInputError, match="base_rotation"):
        TendonPlan(np.zeros(2), d, None, np.zeros(2), ["a", "base_rotation"])
