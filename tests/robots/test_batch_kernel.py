"""Batched (SIMD across configurations) tension solve == the scalar kernel, configuration by configuration."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.robots import batch_kernel, load_robot, robot_from_toml
from riskplan.robots.rod_tables import LOCAL_MAXIT, LOCAL_TOL
from tests.conftest import TOL

# the lockstep kernel repeats the scalar kernel's operations in the same order, so the
# agreement is to rounding (bit for bit in practice); these bounds leave room for that only

# five tendons, tapered radius, two helices (one with a quadratic twist), 10 mm step
ODD_TOML = """
name = "odd"

[backbone]
length = 0.2
outer_radius = 0.003
inner_radius = 0.001
youngs_modulus = 9.1e7
poisson_ratio = 0.3
density = 1300.0
step = 0.01

[disks]
count = 9
radius = 0.01
thickness = 0.002
density = 1200.0

[[tendons]]
name = "tapered-0"
theta = [0.0]
radius = [0.008, -0.02]
stiffness = 400.0
displacement_limits = [-0.01, 0.04]
max_tension = 8.0

[[tendons]]
name = "tapered-120"
theta = [2.0944]
radius = [0.008, -0.02]
stiffness = 400.0
displacement_limits = [-0.01, 0.04]
max_tension = 8.0

[[tendons]]
name = "straight-240"
theta = [-2.0944]
radius = [0.007]
stiffness = 400.0
displacement_limits = [-0.01, 0.04]
max_tension = 8.0

[[tendons]]
name = "helical"
theta = [-2.0944, -47.124]
radius = [0.008]
stiffness = 400.0
displacement_limits = [-0.01, 0.04]
max_tension = 12.0

[[tendons]]
name = "helical-quadratic-tapered"
theta = [1.0, 20.0, 150.0]
radius = [0.006, 0.01, -0.05]
stiffness = 400.0
displacement_limits = [-0.01, 0.04]
max_tension = 6.0

[gravity]
enabled = false
vector = [0.0, 0.0, -9.81]

[base]
position = [0.0, 0.0, 0.0]
rpy = [0.0, 0.0, 0.0]
"""


@pytest.fixture(scope="module")
def paper():
    return load_robot("paper")


@pytest.fixture(scope="module")
def odd():
    return robot_from_toml(ODD_TOML)


def _tensions(robot, rng, B):
    """Uniform within the limits, with exact zeros (slack tendons) and exact maxima mixed in."""
    lim = robot.tension_limits
    tau = rng.uniform(0.0, 1.0, (B, robot.n_tendons)) * lim
    u = rng.uniform(size=tau.shape)
    tau[u < 0.25] = 0.0
    tau = np.where(u > 0.85, lim, tau)
    tau[0] = 0.0
    if B > 1:
        tau[1] = lim
    return tau


def _check(robot, tau, P, R):
    ref = robot.solve_tensions(tau)  # scalar kernel, one configuration after another
    assert P.shape == ref.positions.shape and R.shape == ref.rotations.shape
    np.testing.assert_allclose(P, ref.positions, **TOL["batch_vs_scalar"])
    np.testing.assert_allclose(R, ref.rotations, **TOL["batch_vs_scalar"])


@pytest.mark.parametrize("which", ["paper", "odd"])
@pytest.mark.parametrize("B", [1, 7, 129])
@pytest.mark.parametrize("parallel", [False, True])
def test_batch_equals_scalar(request, rng, which, B, parallel):
    robot = request.getfixturevalue(which)
    tau = _tensions(robot, rng, B)
    P, R = batch_kernel.solve_tensions_batch(robot, tau, parallel=parallel)
    assert P.shape == (B, robot.n_stations, 3) and R.shape == (
        B,
        robot.n_stations,
        3,
        3,
    )
    _check(robot, tau, P, R)


def test_zero_tension_is_straight(paper):
    P, R = batch_kernel.solve_tensions_batch(paper, np.zeros((3, 4)))
    np.testing.assert_allclose(
        P[:, :, 2], np.broadcast_to(paper.s, (3, paper.n_stations)), **TOL["round_off"]
    )
    np.testing.assert_allclose(P[:, :, :2], 0.0, **TOL["round_off"])
    np.testing.assert_allclose(R, np.broadcast_to(np.eye(3), R.shape), **TOL["round_off"])


def test_kernel_flags_unconverged_configurations(paper, rng):
    """With one chord step allowed, loaded configurations cannot meet the tolerance: they are
    flagged for the scalar fallback, unloaded ones (straight rod, exact start) are not."""
    tau = _tensions(paper, rng, 40)
    tau[5] = 0.0
    n = paper.n_stations
    P, R, st = (
        np.empty((40, n, 3)),
        np.empty((40, n, 3, 3)),
        np.zeros(40, dtype=np.int64),
    )
    args = (*paper.tables, LOCAL_TOL)
    batch_kernel._solve_serial(tau, *args, 1, P, R, st)
    loaded = np.any(tau > 0, axis=1)
    assert np.all(st[loaded] == 1) and np.all(st[~loaded] == 0)
    batch_kernel._solve_serial(tau, *args, LOCAL_MAXIT, P, R, st)
    assert np.all(st == 0)


def test_fallback_results_are_merged(paper, rng, monkeypatch):
    """Configurations flagged by the lockstep kernel are re-solved by the scalar kernel in place."""
    real = batch_kernel._solve_serial

    def flag_some(*args):
        real(*args)
        P, _, status = args[-3:]
        P[::3] = np.nan  # what the fallback must overwrite
        status[::3] = 1

    monkeypatch.setattr(batch_kernel, "_solve_serial", flag_some)
    tau = _tensions(paper, rng, 10)
    P, R = batch_kernel.solve_tensions_batch(paper, tau, parallel=False)
    _check(paper, tau, P, R)


def test_unvalidated_tensions_above_the_limit(paper, rng):
    """``validate=False`` (the path ``solve_displacements`` takes) accepts tensions above max_tension."""
    tau = rng.uniform(1.0, 1.3, (5, 4)) * paper.tension_limits
    P, R = batch_kernel.solve_tensions_batch(paper, tau, validate=False)
    ref = paper.solve_tensions(tau, validate=False)
    np.testing.assert_allclose(P, ref.positions, **TOL["batch_vs_scalar"])
    np.testing.assert_allclose(R, ref.rotations, **TOL["batch_vs_scalar"])


def test_bad_input(paper):
    with pytest.raises(InvalidInputError, match="tensions"):
        batch_kernel.solve_tensions_batch(paper, np.full((2, 4), -1.0))
    with pytest.raises(InvalidInputError, match="tensions"):
        batch_kernel.solve_tensions_batch(paper, np.zeros((2, 3)))
    with pytest.raises(InvalidInputError, match=r"\(B, 4\)"):
        batch_kernel.solve_tensions_batch(paper, np.zeros(4))
    with pytest.raises(InvalidInputError, match="gravity"):
        batch_kernel.solve_tensions_batch(paper.with_gravity(True), np.zeros((2, 4)))
    P, R = batch_kernel.solve_tensions_batch(paper, np.zeros((0, 4)))
    assert P.shape == (0, paper.n_stations, 3) and R.shape == (
        0,
        paper.n_stations,
        3,
        3,
    )
