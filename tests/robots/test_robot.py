"""TendonRobot facade: contract, batching, displacement <-> tension round trip, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.errors import ConvergenceError, InvalidInputError, RobotDescriptionError
from riskplan.robots import RodShape, load_robot, robot_from_toml
from riskplan.robots import actuation as actuation_module
from riskplan.robots.rod_tables import LOCAL_TOL
from tests.conftest import TOL


@pytest.fixture(scope="module")
def paper():
    return load_robot("paper")


def test_contract(paper):
    assert paper.name == "paper" and paper.n_tendons == 4
    np.testing.assert_array_equal(paper.displacement_limits, [[-0.01, 0.04]] * 4)
    np.testing.assert_array_equal(paper.tension_limits, [9.73, 9.73, 9.73, 16.81])
    shape = paper.solve_tensions([0.0, 0.0, 0.0, 0.0])
    assert isinstance(shape, RodShape)
    assert (
        shape.s.shape == (41,)
        and shape.positions.shape == (41, 3)
        and shape.rotations.shape == (41, 3, 3)
    )
    np.testing.assert_allclose(shape.tip, [0, 0, 0.2], **TOL["float64_exact"])
    np.testing.assert_allclose(paper.tendon_rest_lengths[:3], 0.2, **TOL["float64_exact"])
    # helical tendon: rest length = int sqrt(1 + (r theta')^2) ds
    np.testing.assert_allclose(
        paper.tendon_rest_lengths[3], 0.2 * np.hypot(1, 0.008 * 47.124), **TOL["float64_exact_rel"]
    )


def test_tension_direction_convention(paper):
    """Tension in the theta = 0 tendon bends the tip towards +x (DESIGN.md)."""
    tip = paper.solve_tensions([2.0, 0, 0, 0]).tip
    assert tip[0] > 0.03 and abs(tip[1]) < TOL["float64_abs"]["atol"]


def test_toml_text_rebuilds_the_robot(paper, tmp_path):
    again = robot_from_toml(paper.toml_text())
    tau = [1.0, 2.0, 0.0, 3.0]
    np.testing.assert_array_equal(
        again.solve_tensions(tau).positions, paper.solve_tensions(tau).positions
    )
    f = tmp_path / "mine.toml"
    f.write_text(paper.toml_text().replace('name = "paper"', 'name = "mine"'))
    assert load_robot(str(f)).name == "mine"


def test_unknown_robot():
    with pytest.raises(RobotDescriptionError, match="neither a packaged robot"):
        load_robot("no-such-robot")


@pytest.mark.parametrize("method", ["solve_tensions", "solve_displacements"])
def test_batch_equals_loop(paper, rng, method):
    if method == "solve_tensions":
        x = rng.uniform(0, 1, (2, 3, 4)) * paper.tension_limits * 0.6
    else:
        x = rng.uniform(-0.01, 0.025, (2, 3, 4))
    batch = getattr(paper, method)(x)
    assert batch.positions.shape == (2, 3, 41, 3) and batch.tensions.shape == (2, 3, 4)
    for i in range(2):
        for j in range(3):
            one = getattr(paper, method)(x[i, j])
            np.testing.assert_allclose(batch.positions[i, j], one.positions, **TOL["float64_exact"])
            np.testing.assert_allclose(batch.rotations[i, j], one.rotations, **TOL["float64_exact"])
            np.testing.assert_allclose(batch.tensions[i, j], one.tensions, **TOL["float64_exact"])
            np.testing.assert_allclose(batch[i, j].tip, one.tip, **TOL["float64_exact"])


def test_displacement_tension_round_trip(paper, rng):
    d = rng.uniform(-0.01, 0.03, (20, 4))
    shape = paper.solve_displacements(d)
    tau = shape.tensions
    assert np.all(tau >= 0)
    back = paper.displacements_for_tensions(np.minimum(tau, paper.tension_limits), validate=False)
    taut = tau > 0
    np.testing.assert_allclose(back[taut], d[taut], **TOL["displacement_solve"])
    assert np.all(
        back[~taut] >= d[~taut] - TOL["displacement_solve"]["atol"]
    )  # slack: the tendon has length to spare
    # and from tensions to displacements to tensions
    tau0 = rng.uniform(0.2, 1.0, (5, 4)) * paper.tension_limits * 0.5
    d0 = paper.displacements_for_tensions(tau0)
    np.testing.assert_allclose(paper.tensions_for_displacements(d0), tau0, **TOL["tension_solve"])
    # the displacement solve integrates its own node strains (solved midpoints), shape_free
    # interpolates the midpoints: the same shape up to the O(h^4) difference of the two passes
    np.testing.assert_allclose(
        paper.solve_displacements(d0).positions,
        paper.solve_tensions(tau0).positions,
        **TOL["node_strain_shape"],
    )


def test_slack_tendons_carry_no_tension(paper):
    s = paper.solve_displacements([-0.01, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(s.tensions, 0.0)
    np.testing.assert_allclose(s.tip, [0, 0, 0.2], **TOL["float64_exact"])
    s = paper.solve_displacements([0.02, -0.01, -0.01, -0.01])
    assert s.tensions[0] > 0 and np.all(s.tensions[1:] == 0.0)


def test_displacement_with_gravity_round_trip(paper):
    robot = paper.with_gravity(True, (9.81, 0, 0))
    d = np.array([0.01, 0.0, 0.003, 0.005])
    tau = robot.tensions_for_displacements(d)
    back = robot.displacements_for_tensions(tau)
    np.testing.assert_allclose(back[tau > 0], d[tau > 0], **TOL["displacement_roundtrip"])


@pytest.mark.parametrize(
    "method, value, match",
    [
        ("solve_tensions", [1.0, 0.0, np.nan, 0.0], "tensions: contains NaN"),
        ("solve_tensions", [1.0, 0.0, np.inf, 0.0], "tensions: contains NaN or inf"),
        ("solve_tensions", [1.0, 0.0, 0.0], "tensions: expected last dimension 4"),
        ("solve_tensions", [1.0, 0.0, 0.0, 20.0], r"tensions <= 16.81"),
        ("solve_tensions", [-1.0, 0.0, 0.0, 0.0], r"tensions >= 0"),
        ("solve_displacements", [0.05, 0.0, 0.0, 0.0], r"displacements <= 0.04"),
        ("solve_displacements", [0.0, -0.02, 0.0, 0.0], r"displacements >= -0.01"),
        (
            "solve_displacements",
            [[0.0, 0.0, 0.0, 0.0, 0.0]],
            "displacements: expected last dimension 4",
        ),
        ("solve_displacements", "abc", "displacements: cannot convert"),
    ],
)
def test_bad_input(paper, method, value, match):
    with pytest.raises(InvalidInputError, match=match):
        getattr(paper, method)(value)


@pytest.mark.parametrize(
    "row, match",
    [
        ([np.nan, 0.0, 0.0, 0.0], "tensions: contains NaN"),
        ([0.0, 0.0, 0.0, -np.inf], "tensions: contains NaN or inf"),
        ([15.0, 0.0, 0.0, 0.0], r"tensions <= 9.73"),  # within tendon 3's limit, not tendon 0's
        ([0.0, 0.0, 0.0, -1e-12], r"tensions >= 0"),
    ],
)
def test_bad_array_input_in_a_batch(paper, row, match):
    """float64 arrays take the compiled fast check; a bad entry anywhere still gets the named error."""
    x = np.full((3, 5, 4), 1.0)
    x[2, 4] = row
    with pytest.raises(InvalidInputError, match=match):
        paper.solve_tensions(x)
    with pytest.raises(InvalidInputError, match=match):
        paper.solve_tensions(x[2, 4].copy())
    with pytest.raises(InvalidInputError, match=match):
        paper.solve_tensions(np.asfortranarray(x))  # not C-contiguous: the numpy path


def test_fast_limit_check_matches_numpy(paper, rng):
    from riskplan.robots.robot import in_limits

    low, high = paper._dlo, paper._dhi
    for _ in range(200):
        x = rng.uniform(-0.015, 0.045, (int(rng.integers(1, 4)), 4))
        if rng.random() < 0.2:
            x.flat[int(rng.integers(x.size))] = rng.choice([np.nan, np.inf, -np.inf])
        expect = bool(np.all(np.isfinite(x)) and np.all(x >= low) and np.all(x <= high))
        # flat, as the facade calls it (the signature `riskplan warm` compiles)
        assert in_limits(x.reshape(-1), low, high) is expect


def test_single_equals_batch_with_base_pose(paper, rng):
    robot = paper.with_base_pose((0.1, -0.2, 0.05), rpy=(0.3, -0.2, 1.1))
    x = rng.uniform(0, 1, (8, 4)) * paper.tension_limits * 0.6
    batch = robot.solve_tensions(x)
    for i in range(8):
        one = robot.solve_tensions(x[i])
        np.testing.assert_array_equal(one.positions, batch.positions[i])
        np.testing.assert_array_equal(one.rotations, batch.rotations[i])
    assert not np.shares_memory(one.tensions, x)  # the shape owns a copy


def test_non_convergence_raises_with_residual(paper, monkeypatch):
    monkeypatch.setattr(actuation_module, "DISP_MAXIT", 1)
    with pytest.raises(ConvergenceError) as info:
        paper.solve_displacements([0.03, 0.0, 0.01, 0.02])
    assert info.value.residual is not None and info.value.residual > 0


@pytest.mark.parametrize("call", ["single", "small_batch", "kernel_batch", "lengths"])
def test_local_solve_failure_names_node_and_residual(paper, monkeypatch, call):
    import riskplan.robots.batch_kernel as batch_module

    # the single-shape path and the batch kernel each read the iteration cap where they run
    monkeypatch.setattr(actuation_module, "LOCAL_MAXIT", 1)
    monkeypatch.setattr(batch_module, "LOCAL_MAXIT", 1)
    tau = np.array([6.0, 0.0, 2.0, 9.0])
    with pytest.raises(ConvergenceError, match=r"failed at s = 0 m .*scaled residual") as info:
        if call == "single":
            paper.solve_tensions(tau)
        elif call == "small_batch":
            paper.solve_tensions(np.tile(tau, (3, 1)))
        elif call == "kernel_batch":
            paper.solve_tensions(np.tile(tau, (actuation_module.BATCH_KERNEL_MIN + 2, 1)))
        else:
            paper.tendon_lengths(tau)
    assert info.value.residual > LOCAL_TOL and info.value.iterations == 1


def test_shapes_cannot_corrupt_the_robot(paper):
    shape = paper.solve_tensions([1.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError):
        shape.s[:] = 0.0
    np.testing.assert_allclose(paper.solve_tensions([1.0, 0.0, 0.0, 0.0]).s[-1], 0.2)


def test_base_pose_validation(paper):
    with pytest.raises(InvalidInputError, match="rotation"):
        paper.with_base_pose((0, 0, 0), rotation=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(InvalidInputError, match="position"):
        paper.with_base_pose((0, 0))


FOUR_INEXTENSIBLE = """
name = "four"
[backbone]
length = 0.2
outer_radius = 0.003
youngs_modulus = 9.1e7
""" + "".join(
    f"""
[[tendons]]
theta = [{k * np.pi / 2!r}]
radius = [0.008]
displacement_limits = [-0.01, 0.04]
max_tension = 10
"""
    for k in range(4)
)


def test_displacement_solve_with_inextensible_antagonistic_tendons(rng):
    """Four straight inextensible tendons at 90 deg: the start matrix is singular up to round-off,
    opposite pairs are statically indeterminate, and d0 + d2 != d1 + d3 forces one tendon slack
    (the min-function Newton stalls there; the solver continues in Fischer-Burmeister form)."""
    robot = robot_from_toml(FOUR_INEXTENSIBLE)
    cases = [[0.005, 0, 0, 0], [0.01, 0, 0, 0.005], [0.03, 0.03, 0, 0], [0.02, 0, 0.01, 0]]
    cases += rng.uniform(-0.01, 0.03, (20, 4)).tolist()
    for d in cases:
        d = np.asarray(d, dtype=float)
        tau = robot.tensions_for_displacements(d)
        assert np.all(tau >= 0.0)
        g = (
            robot.displacements_for_tensions(tau, validate=False) - d
        )  # length to spare, l0 - l(tau) - d
        taut = tau > TOL["tension_solve"]["atol"]
        np.testing.assert_allclose(g[taut], 0.0, **TOL["displacement_roundtrip"])
        assert np.all(g >= -TOL["displacement_roundtrip"]["atol"])
        assert np.all(np.isfinite(robot.solve_displacements(d).positions))
