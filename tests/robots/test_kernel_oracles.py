"""The compiled robot kernels against their own Python source: each kernel's ``py_func`` run by
the interpreter, with every kernel it calls replaced by its Python source too (so nothing in the
oracle is compiled). What the compiler is told (inline helpers, ``error_model="numpy"``, the
stations of ``shape_free`` in one loop, the displacement solve's helpers inlined) must change no
result. float64 throughout: the interpreter does the same IEEE operations in the same order, so
the two agree to the last bit (the tolerance allows one rounding)."""

from __future__ import annotations

import numpy as np
import pytest
from numba.core.registry import CPUDispatcher

from riskplan.robots import (
    displacement,
    integration,
    linalg6,
    load_robot,
    robot_from_toml,
    rod_tables,
    strains,
    tendon_lengths,
)
from riskplan.robots.rod_tables import DISP_MAXIT, DISP_TOL, LOCAL_MAXIT, LOCAL_TOL
from tests.conftest import TOL
from tests.robots.test_batch_kernel import ODD_TOML

MODULES = (linalg6, rod_tables, strains, tendon_lengths, integration, displacement)


def interpret(monkeypatch) -> None:
    """Replace every kernel of the robot solver by its Python source, in its own module (a
    kernel's Python source finds its callees there)."""
    for mod in MODULES:
        for name, obj in list(vars(mod).items()):
            if isinstance(obj, CPUDispatcher):
                monkeypatch.setattr(mod, name, obj.py_func)


def same(a, b) -> None:
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), **TOL["float64_bits"])


@pytest.fixture(scope="module", params=["paper", "odd"])
def robot(request):
    return load_robot("paper") if request.param == "paper" else robot_from_toml(ODD_TOML)


def _tensions(robot, seed):
    rng = np.random.default_rng(seed)
    tau = rng.uniform(0.0, 0.6, robot.n_tendons) * robot.tension_limits
    tau[rng.integers(robot.n_tendons)] = 0.0  # a slack tendon (the kernels skip its terms)
    return tau


def _shape_free(robot, tau):
    n, m = robot.n_stations, robot.n_tendons
    out = (np.empty((n, 3)), np.empty((n, 3, 3)), np.empty((n, 6)), np.empty(m))
    st = integration.shape_free(tau, *robot.tables, LOCAL_TOL, LOCAL_MAXIT, *out)
    return (st, *out)


def _lengths(robot, tau):
    m = robot.n_tendons
    out = (np.empty(m), np.empty((m, m)), np.empty((2 * robot.n_stations - 1, 6)))
    st = tendon_lengths.lengths_and_jacobian(tau, *robot.tables, LOCAL_TOL, LOCAL_MAXIT, *out)
    return (st, *out)


def _node_pose(robot, tau):
    # the shape solve_displacements takes: the length pass's node strains, integrated
    st, _, _, xs = _lengths(robot, tau)
    n = robot.n_stations
    P, R = np.empty((n, 3)), np.empty((n, 3, 3))
    integration.pose_from_node_strains(xs, robot.params.backbone.length / (n - 1), n - 1, P, R)
    return st, P, R


def _displacement(robot, d):
    m, n = robot.n_tendons, robot.n_stations
    tau, info, xs = np.empty(m), np.empty(2), np.empty((2 * n - 1, 6))
    st = displacement.solve_displacement_tensions(
        d, robot._kinv, robot._l0, np.zeros(m), *robot.tables, LOCAL_TOL, LOCAL_MAXIT,
        DISP_TOL, DISP_MAXIT, tau, info, xs,
    )  # fmt: skip
    return st, tau, info, xs


def _loaded(robot, tau):
    n, m = robot.n_stations - 1, robot.n_tendons
    f = np.array([0.0, 0.0, -9.81 * robot._lam])
    Y = np.empty((n + 1, 18 + m))
    N0 = -f * robot.params.backbone.length
    M0 = np.array([0.001, -0.002, 0.0])
    st = integration.shape_loaded(
        tau, *robot.tables, f, N0, M0, LOCAL_TOL, LOCAL_MAXIT, Y
    )  # fmt: skip
    return st, Y


@pytest.mark.parametrize(
    "run",
    [_shape_free, _lengths, _node_pose, _loaded],
    ids=["shape_free", "lengths", "node_pose", "loaded"],
)
def test_tension_kernels_equal_their_python_source(robot, run, monkeypatch):
    for seed in (0, 1):
        tau = _tensions(robot, seed)
        compiled = run(robot, tau)
        with monkeypatch.context() as mp:
            interpret(mp)
            python = run(robot, tau)
        assert compiled[0] == python[0] == 0  # converged, both
        for a, b in zip(compiled[1:], python[1:], strict=True):
            same(a, b)


def test_displacement_solve_equals_its_python_source(robot, monkeypatch):
    lim = robot.displacement_limits
    rng = np.random.default_rng(2)
    for d in (
        rng.uniform(0.0, 0.5 * lim[:, 1]),
        np.r_[lim[0, 1] * 0.5, np.zeros(robot.n_tendons - 1)],
    ):
        compiled = _displacement(robot, d)
        with monkeypatch.context() as mp:
            interpret(mp)
            python = _displacement(robot, d)
        assert compiled[0] == python[0] == 0
        for a, b in zip(compiled[1:], python[1:], strict=True):  # tensions, info, node strains
            same(a, b)


def test_strain_equation_kernels_equal_their_python_source(robot, monkeypatch):
    rng = np.random.default_rng(3)
    tau = _tensions(robot, 3)
    x = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]) + rng.normal(0.0, 0.05, 6) * [
        0.01,
        0.01,
        0.01,
        1,
        1,
        1,
    ]
    rt, drt = robot.tables.offsets[5], robot.tables.offset_slopes[5]
    nb, mb = rng.normal(0.0, 0.1, 3), rng.normal(0.0, 0.01, 3)
    kse, kbt = robot.tables.kse, robot.tables.kbt

    def run():
        F, J = np.empty(6), np.empty((6, 6))
        e = strains.local_residual(x, tau, rt, drt, nb, mb, kse, kbt, F)
        strains.local_jacobian(x, tau, rt, drt, kse, kbt, J)
        L = J.copy()
        ok = linalg6.chol_factor6(L)
        b = F.copy()
        linalg6.chol_solve6(L, b)
        A, B = J[:4, :4].copy() + np.eye(4), np.stack([F[:4], F[2:]], axis=1)
        solved = linalg6.gauss_solve(A, B, 4, 2)
        return e, F, J, ok, L, b, solved, B

    compiled = run()
    with monkeypatch.context() as mp:
        interpret(mp)
        python = run()
    assert compiled[3] and python[3] and compiled[6] and python[6]
    for a, b in zip(compiled, python, strict=True):
        same(a, b)


@pytest.mark.parametrize("fb", [False, True])
def test_complementarity_system_equals_its_python_source(robot, fb, monkeypatch):
    m = robot.n_tendons
    tau = _tensions(robot, 4)
    _, lengths, dl, _ = _lengths(robot, tau)
    d = np.full(m, 0.002)

    def run():
        # slack flags as the solve passes them (float), so the test hits the warmed signature
        Jm, phi, slack = np.empty((m, m)), np.empty((m, 1)), np.zeros(m)
        res, merit = displacement.complementarity_system(
            d, robot._kinv, robot._l0, tau, lengths, dl, Jm, phi, fb, slack
        )
        return res, merit, Jm, phi, slack

    compiled = run()
    with monkeypatch.context() as mp:
        interpret(mp)
        python = run()
    for a, b in zip(compiled, python, strict=True):
        same(a, b)


def test_offset_table_equals_the_offset_kernel(robot):
    # the robot's tables are built with numpy (no compile); the compiled kernel is the oracle
    t = robot.tables
    h = t.length / t.n_steps
    rt, drt = np.empty(t.offsets.shape[1:]), np.empty(t.offsets.shape[1:])
    for j in range(t.offsets.shape[0]):
        rod_tables.tendon_offsets(robot._theta, robot._radius, j * 0.5 * h, rt, drt)
        same(t.offsets[j], rt)
        same(t.offset_slopes[j], drt)


def test_rest_lengths_in_numpy_equal_the_length_kernel(robot):
    # the robot's rest lengths and their Jacobian come from numpy (building a robot compiles
    # nothing); they are the compiled length pass at zero tension, to the bit
    m = robot.n_tendons
    st, lengths, dl, _ = _lengths(robot, np.zeros(m))
    assert st == 0
    l_np, dl_np = tendon_lengths.rest_lengths_and_jacobian(*robot.tables)
    np.testing.assert_array_equal(l_np, lengths)
    np.testing.assert_array_equal(dl_np, dl)
    np.testing.assert_array_equal(robot._l0, lengths)


def test_building_a_robot_compiles_nothing():
    # a fresh process that only builds robots calls no kernel (numba then has no signature of
    # any kernel, compiled or loaded from the cache)
    import subprocess
    import sys

    code = (
        "from riskplan.robots import load_robot; from riskplan.kernels import kernel_dispatchers; "
        "load_robot('paper').with_gravity(True); "
        "print(sorted(k for k, d in kernel_dispatchers().items() if d.signatures))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
