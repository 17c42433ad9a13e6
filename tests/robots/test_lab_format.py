"""The Kuntz lab's robot files (both layouts), base rotation and retraction."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from riskplan.errors import InvalidInputError, RobotDescriptionError
from riskplan.robots import load_robot
from riskplan.robots.description import parse_robot_toml
from riskplan.robots.robot import TendonRobot
from riskplan.robots.shape import rotation_z, shift_polynomial
from tests.conftest import TOL

LAB = Path(__file__).resolve().parents[1] / "data" / "kuntz-lab"
TASK = LAB / "task-0001.toml"

NESTED = """
max_tension = 3.5
min_tension_change = 0.005
start = [0.0, 0.0, 0.0]
goal = [1.0, 0.5, 2.0]
[robot]
  radius = 3e-3
  enable_rotation = true
  enable_retraction = true
  [robot.backbone_specs]
    E = 2.1e6
    length = 0.12
    length_discretization = 0.00059
    nu = 0.3
    ri = 0.0
    ro = 0.003
  [[robot.tendons]]
    C = [0.0, 0.0]
    D = [0.0025]
    max_tension = 3.5
    min_length = -0.029
    max_length = 0.048
  [[robot.tendons]]
    C = [1.571, 50.0]
    D = [0.0025]
    max_tension = 3.5
    min_length = -0.027
    max_length = 0.046
  [[robot.tendons]]
    C = [-1.571, -50.0]
    D = [0.0025]
    max_tension = 3.5
    min_length = -0.027
    max_length = 0.046
"""

# riskplan's own format, describing the robot of task-0001.toml key by key (docs/robots.md):
# theta = pi/2 - C (the lab's tendon sits at D (sin C, cos C, 0))
NATIVE = """
name = "task-0001"
collision_radius = 0.003
[backbone]
length = 0.12
outer_radius = 0.003
inner_radius = 0.0
youngs_modulus = 2.1e6
poisson_ratio = 0.3
step = 0.00059
[[tendons]]
name = "tendon-0"
theta = [1.5707963267948966, -0.0]
radius = [0.0025]
displacement_limits = [-0.029, 0.048]
max_tension = 3.5
[[tendons]]
name = "tendon-1"
theta = [-0.00020367320510339404, -50.0]
radius = [0.0025]
displacement_limits = [-0.027, 0.046]
max_tension = 3.5
[[tendons]]
name = "tendon-2"
theta = [3.1417963267948963, 50.0]
radius = [0.0025]
displacement_limits = [-0.027, 0.046]
max_tension = 3.5
[base_motion]
rotation = true
retraction = true
"""

CONFIGS = [  # tensions (N), rotation (rad), retraction (m): the task's start and goal, and more
    ([0.0, 0.0, 0.0], 0.0, 0.119),
    ([1.0712, 0.459471, 2.81962], -0.589326, 0.0267231),
    ([3.0, 1.0, 0.0], -1.5, 0.07),
    ([0.5, 3.5, 1.5], 2.5, 0.0),
]


def lab_step(path) -> float:
    """``length_discretization`` as the file spells it."""
    import tomllib

    return tomllib.loads(Path(path).read_text())["backbone_specs"]["length_discretization"]


@pytest.fixture(scope="module")
def lab():
    return load_robot(TASK)


def test_task_file_keys(lab):
    p = lab.params
    b = p.backbone
    assert (b.length, b.outer_radius, b.inner_radius, b.youngs_modulus) == (0.12, 0.003, 0, 2.1e6)
    np.testing.assert_allclose(b.shear_modulus, 2.1e6 / 2.6, **TOL["float64_bits"])
    assert b.step == lab_step(TASK) and b.n_steps == 204 and p.disks.count == 0
    half = math.pi / 2
    assert [t.theta for t in p.tendons] == [(half, 0), (half - 1.571, -50), (half + 1.571, 50)]
    assert all(t.radius == (0.0025,) and t.max_tension == 3.5 for t in p.tendons)
    assert all(math.isinf(t.stiffness) for t in p.tendons)
    assert [t.displacement_limits for t in p.tendons] == [
        (-0.029, 0.048),
        (-0.027, 0.046),
        (-0.027, 0.046),
    ]
    assert p.collision_radius == 0.003 and lab.name == "task-0001"
    bm = p.base_motion
    assert bm.rotation and bm.retraction and lab.n_config == 5
    assert bm.rotation_limits == (-math.pi, math.pi)
    np.testing.assert_allclose(bm.retraction_limits, (0.0, 0.12 - 0.00059), **TOL["float64_abs"])


def test_nested_layout_is_the_same_robot(lab):
    nested = parse_robot_toml(NESTED, default_name="task-0001")
    assert nested == lab.params


def test_lab_and_native_files_give_identical_shapes(lab):
    native = TendonRobot(parse_robot_toml(NATIVE))
    assert native.params == lab.params
    for tau, rot, ret in CONFIGS:
        a = lab.solve_tensions(tau, rotation=rot, retraction=ret)
        b = native.solve_tensions(tau, rotation=rot, retraction=ret)
        np.testing.assert_array_equal(a.positions, b.positions)
        np.testing.assert_array_equal(a.rotations, b.rotations)
    taus = np.array([c[0] for c in CONFIGS])
    rots = np.array([c[1] for c in CONFIGS])
    rets = np.array([c[2] for c in CONFIGS])
    batch = lab.solve_tensions(taus, rotation=rots, retraction=rets)
    for k, (tau, rot, ret) in enumerate(CONFIGS):
        one = lab.solve_tensions(tau, rotation=rot, retraction=ret)
        np.testing.assert_allclose(batch.positions[k], one.positions, **TOL["batch_vs_scalar"])
        np.testing.assert_allclose(batch.s[k], one.s, **TOL["float64_abs"])


def test_retraction_shortens_the_exposed_robot(lab):
    for ret in (0.0, 0.03, 0.119):
        shape = lab.solve_tensions([0.0, 0.0, 0.0], retraction=ret)
        np.testing.assert_allclose(shape.tip, [0, 0, 0.12 - ret], **TOL["float64_abs"])
        np.testing.assert_allclose(shape.s[-1], 0.12 - ret, **TOL["float64_abs"])
        assert shape.positions.shape == (205, 3)


@pytest.mark.parametrize("ret", [0.0, 0.04, 0.1])
def test_retracted_straight_tendon_is_the_closed_form_arc(ret):
    """One straight tendon: u = tau r / EI, v3 = 1 - tau / EA over the exposed length L - ret."""
    robot = TendonRobot(
        parse_robot_toml(
            NATIVE.replace("theta = [-0.00020367320510339404, -50.0]", "theta = [0.0]")
            .replace("theta = [1.5707963267948966, -0.0]", "theta = [0.0]")
            .replace("step = 0.00059", "step = 0.0005")
        )
    )
    tau = 0.3
    b = robot.params.backbone
    shape = robot.solve_tensions([tau, 0.0, 0.0], retraction=ret)
    kappa = tau * 0.0025 / b.kbt[0]
    v3 = 1 - tau / b.kse[2]
    # tendon 1 now also sits at theta = 0 but is slack; tendon 0 bends towards +x
    s = shape.s
    arc = v3 * np.stack([(1 - np.cos(kappa * s)) / kappa, 0 * s, np.sin(kappa * s) / kappa], -1)
    np.testing.assert_allclose(shape.positions, arc, **TOL["rk4_closed_form"])
    np.testing.assert_allclose(s[-1], 0.12 - ret, **TOL["float64_abs"])


def test_retraction_shifts_the_routing_polynomials(lab):
    """The exposed arc of a retracted helical robot is a robot of length L - ret whose routing
    is theta(s' + ret): solved independently from a native file with the shifted coefficients."""
    ret = 0.05
    c1 = shift_polynomial((math.pi / 2 - 1.571, -50.0), ret)
    c2 = shift_polynomial((math.pi / 2 + 1.571, 50.0), ret)
    np.testing.assert_allclose(c1, (math.pi / 2 - 1.571 - 50 * ret, -50.0), **TOL["float64_abs"])
    text = (
        NATIVE.replace("length = 0.12", "length = 0.07")
        .replace("theta = [-0.00020367320510339404, -50.0]", f"theta = [{c1[0]!r}, -50.0]")
        .replace("theta = [3.1417963267948963, 50.0]", f"theta = [{c2[0]!r}, 50.0]")
        .replace("step = 0.00059", f"step = {0.07 / 204!r}")
        .replace("[base_motion]\nrotation = true\nretraction = true\n", "")
    )
    short = TendonRobot(parse_robot_toml(text))
    tau = [0.4, 1.2, 0.3]
    a = lab.solve_tensions(tau, retraction=ret)
    b = short.solve_tensions(tau)
    np.testing.assert_allclose(a.positions, b.positions, **TOL["float64_exact"])


def test_rotation_turns_the_shape_about_base_z(lab):
    tau = [1.0, 2.0, 0.5]
    flat = lab.solve_tensions(tau, retraction=0.02)
    for phi in (-2.0, 0.3, math.pi):
        turned = lab.solve_tensions(tau, rotation=phi, retraction=0.02)
        np.testing.assert_allclose(
            turned.positions, flat.positions @ rotation_z(phi).T, **TOL["float64_exact"]
        )
        np.testing.assert_allclose(turned.tip[2], flat.tip[2], **TOL["float64_abs"])


def test_base_motion_inputs_are_checked(lab):
    with pytest.raises(InvalidInputError, match="retraction"):
        lab.solve_tensions([0, 0, 0], retraction=0.12)
    with pytest.raises(InvalidInputError, match="rotation"):
        lab.solve_tensions([0, 0, 0], rotation=4.0)
    paper = load_robot("paper")
    with pytest.raises(InvalidInputError, match="no base rotation"):
        paper.solve_tensions([0, 0, 0, 0], rotation=0.1)
    q = np.array([1.0, 0.5, 2.0, 0.3, 0.05])
    tau, rot, ret = lab.split_configuration(q)
    assert tau.tolist() == [1.0, 0.5, 2.0] and rot == 0.3 and ret == 0.05
    with pytest.raises(InvalidInputError, match="5"):
        lab.split_configuration([1.0, 0.5, 2.0])


def test_displacements_and_tensions_convert_both_ways_with_retraction(lab):
    tau = np.array([[0.5, 1.5, 0.2], [2.0, 0.0, 1.0]])
    ret = np.array([0.03, 0.09])
    d = lab.displacements_for_tensions(tau, retraction=ret)
    back = lab.tensions_for_displacements(d, retraction=ret)
    np.testing.assert_allclose(back, tau, **TOL["tension_solve"])
    # the same tensions hold the tendons differently at another retraction
    assert not np.allclose(d[0], lab.displacements_for_tensions(tau[0], retraction=0.09))
    a = lab.solve_displacements(d, rotation=[0.1, -0.2], retraction=ret)
    b = lab.solve_tensions(tau, rotation=[0.1, -0.2], retraction=ret)
    np.testing.assert_allclose(a.positions, b.positions, **TOL["solver"])


@pytest.mark.parametrize(
    ("old", "new", "key", "hint"),
    [
        ("length_discretization", "length_discretisation", None, "length_discretization"),
        ("ro = 0.003", "ro = -0.003", "backbone_specs.ro", None),
        ("enable_rotation", "enable_rotations", None, "enable_rotation"),
        ("C = [ 1.571, 50,]", "C = []", "tendons[1].C", None),
        (
            "max_tension = 3.5\nmin_length = -0.029",
            "max_tensin = 3.5\nmin_length = -0.029",
            None,
            "max_tension",
        ),
    ],
)
def test_lab_file_errors_name_the_lab_key(old, new, key, hint):
    text = TASK.read_text()
    assert old in text
    with pytest.raises(RobotDescriptionError) as err:
        parse_robot_toml(text.replace(old, new, 1))
    if key is not None:
        assert err.value.key == key and f"'{key}'" in str(err.value)
    if hint is not None:
        assert f"did you mean '{hint}'" in str(err.value)


def test_native_unknown_key_names_the_closest():
    with pytest.raises(RobotDescriptionError, match="did you mean 'youngs_modulus'"):
        parse_robot_toml(NATIVE.replace("youngs_modulus", "young_modulus"))
    with pytest.raises(RobotDescriptionError, match="retraction_limits"):
        parse_robot_toml(NATIVE + "retraction_limits = [0.0, 0.2]\n")


def test_params_with_base_motion_round_trip_through_riskplans_format(lab):
    from riskplan.robots.params import params_to_toml

    text = params_to_toml(lab.params)
    assert "base_motion" in text and "collision_radius" in text
    assert parse_robot_toml(text) == lab.params


def test_lab_angle_convention_places_tendons_where_the_lab_does():
    """The lab's C++ model puts tendon i at ``D (sin C, cos C, 0)`` (``tendon::get_r_info``); its
    Python simulator (Kuntz-Lab/Tendon_Robot_Learning, ``simulated_data_collection.py``) writes
    the same four tendons of ``data/tendon_parameter.toml`` (C = 2.0944, 0, -2.0944 and
    -2.0944 - 47.124 s) at ``r (cos a, sin a, 0)`` with a = -pi/6, pi/2, 7 pi/6 and
    7 pi/6 + 47.124 s. The file read here must land on those angles."""
    text = """
[backbone_specs]
E = 9.1e7
length = 0.2
length_discretization = 0.005
nu = 0.3
ri = 0.0
ro = 0.003
[tendon_robot]
radius = 0.015
"""
    for c in ("[2.0944, 0.0]", "[0.0, 0.0]", "[-2.0944, 0.0]", "[-2.0944, -47.124]"):
        text += f"[[tendons]]\nC = {c}\nD = [0.008]\nmax_tension = 9.73\n"
    p = parse_robot_toml(text)
    s = np.linspace(0.0, 0.2, 9)
    sim = [-math.pi / 6 + 0 * s, math.pi / 2 + 0 * s, 7 * math.pi / 6 + 0 * s]
    sim.append(7 * math.pi / 6 + 47.124 * s)
    for t, a in zip(p.tendons, sim):
        th = np.polynomial.polynomial.polyval(s, t.theta)
        pos = np.stack([np.cos(th), np.sin(th)], -1)
        np.testing.assert_allclose(
            pos, np.stack([np.cos(a), np.sin(a)], -1), **TOL["rounded_constants"]
        )


def test_lab_tendon_at_c_zero_bends_towards_plus_y(lab):
    """C = 0 sits on the body +y axis in the lab's model, so pulling it bends the tip to +y."""
    tip = lab.solve_tensions([1.0, 0.0, 0.0]).tip
    assert tip[1] > 0.01
    np.testing.assert_allclose(tip[0], 0.0, **TOL["round_off"])


def test_lab_task_start_is_free_and_goal_crosses_on_our_model():
    """The lab's backbone check (app/reproduce/lab_tasks.py) on task-0001: the home start (1 mm
    exposed at the entry hole) keeps more than the lab's 3 mm radius from every obstacle cell;
    the goal's backbone crosses the anatomy on riskplan's model (docs/robots.md, "What the lab's
    task files mean": an open disagreement with the lab's model, not a convention). If this
    starts failing on the goal, the model now agrees with the lab's: update those docs."""
    from riskplan.app.reproduce.lab_tasks import configuration_clearance
    from riskplan.planning.problem import load_problem

    pr = load_problem(TASK)
    start, goal = configuration_clearance(pr.robot, [pr.start, pr.goal], pr.voxel_environment)
    assert not start.crosses and start.clearance > pr.robot.params.collision_radius
    assert goal.crosses and goal.clearance == 0.0
