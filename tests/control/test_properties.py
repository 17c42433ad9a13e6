"""Property-based tests of the control entry points (see tests/properties.py for the contract):
``lqr_gains``, ``kalman_gains`` on arbitrary and on structured but extreme matrices, and
``linearize`` / ``lqgmp`` on perturbations of the built-in needle scenario on a coarse mesh
(few examples: each runs the simulator)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from riskplan.control import NominalPlan, kalman_gains, lqg_controller, lqgmp, lqr_gains
from riskplan.control.linearize import linearize
from riskplan.scenarios.base import SimParams
from riskplan.scenarios.needle import NeedleScenario
from riskplan.scenarios.uncertainty import CASE_NAMES, get_case
from tests.properties import (
    PROPERTY,
    arrays_or_junk,
    assert_finite,
    assert_probability,
    call,
    small_budget,  # noqa: F401  (fixture: a 32 MiB memory budget)
)

#: magnitudes from tiny to near overflow: the recursions must raise, not return NaN
extreme = st.floats(-1e300, 1e300, allow_nan=False, allow_infinity=False, width=64)


@st.composite
def systems(draw):
    T, p, q = draw(st.integers(1, 5)), draw(st.integers(1, 3)), draw(st.integers(1, 3))
    A = draw(hnp.arrays(np.float64, (T, p, p), elements=extreme))
    B = draw(hnp.arrays(np.float64, (T, p, q), elements=extreme))
    scale = draw(st.sampled_from([1e-200, 1e-8, 1.0, 1e8, 1e200]))
    return A, B, scale * np.eye(p), np.eye(q), np.eye(p)


@PROPERTY
@given(sys=systems())
def test_lqr_gains_extreme_systems(sys):
    L = call(lqr_gains, *sys)
    if L is not None:
        assert_finite(L)


@PROPERTY
@given(
    A=arrays_or_junk(),
    B=arrays_or_junk(),
    Q=arrays_or_junk(),
    R=arrays_or_junk(),
    Qf=arrays_or_junk(),
)
def test_lqr_gains_arbitrary(A, B, Q, R, Qf):
    L = call(lqr_gains, A, B, Q, R, Qf)
    if L is not None:
        assert_finite(L)


@PROPERTY
@given(sys=systems(), m=st.integers(1, 3), noise=st.sampled_from([1e-200, 1e-6, 1.0, 1e200]))
def test_kalman_gains_extreme_systems(sys, m, noise):
    A = sys[0]
    p = A.shape[1]
    H = np.eye(m, p)
    if not H.any():
        return
    out = call(kalman_gains, A, H, noise * np.eye(p), np.eye(m), np.eye(p))
    if out is not None:
        assert_finite(*out)


@PROPERTY
@given(A=arrays_or_junk(), H=arrays_or_junk(), M=arrays_or_junk(), N=arrays_or_junk())
def test_kalman_gains_arbitrary(A, H, M, N):
    out = call(kalman_gains, A, H, M, N, np.eye(2))
    if out is not None:
        assert_finite(*out)


# ---- simulator-driven: the needle scenario on a 60-element mesh, three steps -------------------

NEEDLE = NeedleScenario()
COARSE = SimParams(n_elements=60)
SIM_PROPERTY = settings(PROPERTY, max_examples=6)


@st.composite
def needle_plans(draw):
    """A three-step plan of controls drawn inside (and on) the needle's bounds."""
    b = NEEDLE.control_bounds
    u = draw(
        hnp.arrays(
            np.float64,
            (3, NEEDLE.control_dim),
            elements=st.floats(0.0, 1.0, allow_nan=False, width=64),
        )
    )
    u = b[:, 0] + u * (b[:, 1] - b[:, 0])
    return NominalPlan.from_rollout(NEEDLE, NEEDLE.initial_state(COARSE), u, COARSE)


@SIM_PROPERTY
@given(
    plan=needle_plans(),
    case=st.sampled_from(CASE_NAMES),
    n=st.integers(1, 4),
    seed=st.integers(0, 2**31),
    epsilon=st.one_of(st.none(), st.floats(1e-12, 1.0), st.just(0.0), st.just(float("nan"))),
)
def test_linearize_perturbed_needle(plan, case, n, seed, epsilon):
    lin = call(
        linearize,
        NEEDLE,
        plan,
        get_case(case, base=COARSE),
        n_samples=n,
        epsilon=epsilon,
        seed=seed,
    )
    if lin is not None:
        assert_finite(lin.A, lin.B, lin.M, lin.H, lin.N)


@SIM_PROPERTY
@given(
    plan=needle_plans(),
    case=st.sampled_from(CASE_NAMES),
    method=st.sampled_from(["sigma", "truncation", "sampling", "other"]),
    goal_samples=st.integers(1, 50),
    seed=st.integers(0, 2**31),
)
def test_lqgmp_perturbed_needle(plan, case, method, goal_samples, seed):
    lin = call(linearize, NEEDLE, plan, get_case(case, base=COARSE), n_samples=2, seed=seed)
    if lin is None:
        return
    ctrl = call(lqg_controller, lin)
    if ctrl is None:
        return
    res = call(lqgmp, NEEDLE, plan, ctrl, method=method, n_goal_samples=goal_samples, seed=seed)
    if res is not None:
        assert_probability([res.p_success, res.p_collision_free, res.p_goal])
        assert_probability(res.p_free_steps)
        assert_finite(res.mean, res.cov)
