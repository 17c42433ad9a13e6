"""LQR gains: scalar Riccati closed form, python-control's dlqr in the long-horizon limit, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.control import lqr_gains
from riskplan.errors import InvalidInputError


def test_scalar_closed_form_one_step(tol):
    # T = 1: L = -b s a / (b² s + r) with s = Q_final
    a, b, r, s = 1.3, 0.7, 0.4, 2.5
    L = lqr_gains([[[a]]], [[[b]]], [[1.0]], [[r]], [[s]])
    np.testing.assert_allclose(L[0, 0, 0], -b * s * a / (b * b * s + r), **tol["float64_ref"])


def test_scalar_stationary_riccati(tol):
    # fixed point of s = q + a² s - a² b² s² / (b² s + r): b² s² + (r - a² r - q b²) s - q r = 0
    a, b, q, r = 1.1, 0.5, 1.0, 0.3
    c1 = r - a * a * r - q * b * b
    s = (-c1 + np.sqrt(c1 * c1 + 4 * b * b * q * r)) / (2 * b * b)
    T = 200
    L = lqr_gains(np.full((T, 1, 1), a), np.full((T, 1, 1), b), [[q]], [[r]], [[0.0]])
    np.testing.assert_allclose(L[0, 0, 0], -b * s * a / (b * b * s + r), **tol["float64_ref"])


def test_long_horizon_equals_negated_dlqr(rng, tol):
    control = pytest.importorskip("control")
    p, q, T = 4, 2, 400
    A = np.eye(p) + 0.1 * rng.standard_normal((p, p))
    B = rng.standard_normal((p, q))
    Q = np.diag(rng.uniform(0.5, 2.0, p))
    R = np.diag(rng.uniform(0.5, 2.0, q))
    K, _, _ = control.dlqr(A, B, Q, R)
    L = lqr_gains(np.broadcast_to(A, (T, p, p)), np.broadcast_to(B, (T, p, q)), Q, R, Q)
    np.testing.assert_allclose(L[0], -K, **tol["float64_ref"])


def test_time_varying_matches_brute_force_cost(rng, tol):
    # the gains minimise the quadratic cost: compare with the exact least-squares solution
    # of the open-loop problem from one x0 (cost is a quadratic in the stacked controls)
    p, q, T = 3, 2, 5
    A = rng.standard_normal((T, p, p)) * 0.5
    B = rng.standard_normal((T, p, q))
    Q, R, Qf = np.eye(p), 0.5 * np.eye(q), 2 * np.eye(p)
    L = lqr_gains(A, B, Q, R, Qf)
    x0 = rng.standard_normal(p)
    # closed loop controls
    x, us = x0.copy(), []
    for t in range(T):
        us.append(L[t] @ x)
        x = A[t] @ x + B[t] @ us[-1]
    # states as affine functions of stacked u: x_t = Phi_t x0 + Gam_t u
    Phi, Gam = [np.eye(p)], [np.zeros((p, T * q))]
    for t in range(T):
        Phi.append(A[t] @ Phi[-1])
        g = A[t] @ Gam[-1]
        g[:, t * q : (t + 1) * q] += B[t]
        Gam.append(g)
    H = np.zeros((T * q, T * q))
    f = np.zeros(T * q)
    for t in range(T + 1):
        W = Qf if t == T else Q
        H += Gam[t].T @ W @ Gam[t]
        f += Gam[t].T @ W @ Phi[t] @ x0
    H += np.kron(np.eye(T), R)
    u_opt = np.linalg.solve(H, -f)
    np.testing.assert_allclose(np.concatenate(us), u_opt, **tol["float64_ref"])


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(R=[[0.0]]), "R"),
        (dict(Q=[[-1.0]]), "Q"),
        (dict(Q_final=[[np.nan]]), "Q_final"),
        (dict(B=np.ones((3, 2, 1))), "B"),
    ],
)
def test_bad_input(kw, match):
    args = dict(A=np.ones((2, 1, 1)), B=np.ones((2, 1, 1)), Q=[[1.0]], R=[[1.0]], Q_final=[[1.0]])
    args.update(kw)
    with pytest.raises(InvalidInputError, match=match):
        lqr_gains(**args)


def test_nonsymmetric_rejected():
    with pytest.raises(InvalidInputError, match="symmetric"):
        lqr_gains(
            np.ones((2, 2, 2)), np.ones((2, 2, 1)), [[1.0, 0.5], [0.0, 1.0]], [[1.0]], np.eye(2)
        )


def test_overflowing_recursion_names_the_step():
    """A = 1e200 I (finite) overflows the Riccati recursion: a NumericalError naming the step,
    never partly-NaN gains."""
    from riskplan.errors import NumericalError

    T, n = 50, 2
    eye = np.eye(n)
    A = np.broadcast_to(1e200 * eye, (T, n, n))
    with pytest.raises(NumericalError, match="step 49") as exc:
        lqr_gains(A, np.broadcast_to(eye, (T, n, n)), eye, eye, eye)
    assert exc.value.step == T - 1  # the first step the backward recursion computes
