"""Kalman gains: scalar closed form, python-control's dlqe (predictor form) in the stationary limit, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.control import kalman_gains
from riskplan.errors import InvalidInputError


def test_scalar_one_step(tol):
    a, h, m, n, p0 = 0.9, 2.0, 0.3, 0.5, 0.7
    K, P = kalman_gains([[[a]]], [[h]], [[m]], [[n]], [[p0]])
    pp = a * a * p0 + m
    k = pp * h / (h * h * pp + n)
    np.testing.assert_allclose(K[0, 0, 0], k, **tol["float64_ref"])
    np.testing.assert_allclose(P[0, 0, 0], (1 - k * h) * pp, **tol["float64_ref"])


def test_scalar_stationary(tol):
    # prior fixed point: s = a² s n / (h² s + n) + m  ->  h² s² + (n - a² n - m h²) s - m n = 0
    a, h, m, n = 1.05, 1.0, 0.2, 0.4
    c1 = n - a * a * n - m * h * h
    s = (-c1 + np.sqrt(c1 * c1 + 4 * h * h * m * n)) / (2 * h * h)
    K, P = kalman_gains(np.full((300, 1, 1), a), [[h]], [[m]], [[n]], [[0.0]])
    np.testing.assert_allclose(K[-1, 0, 0], s * h / (h * h * s + n), **tol["float64_ref"])
    np.testing.assert_allclose(P[-1, 0, 0], s * n / (h * h * s + n), **tol["float64_ref"])


def test_stationary_equals_dlqe_converted(rng, tol):
    control = pytest.importorskip("control")
    p, m, T = 3, 2, 400
    A = np.eye(p) + 0.1 * rng.standard_normal((p, p))
    H = rng.standard_normal((m, p))
    M = np.diag(rng.uniform(0.01, 0.1, p))
    N = np.diag(rng.uniform(0.05, 0.2, m))
    Lp, Pprior, _ = control.dlqe(A, np.eye(p), H, M, N)  # predictor gain A K, prior covariance
    K, P = kalman_gains(np.broadcast_to(A, (T, p, p)), H, M, N, np.eye(p))
    np.testing.assert_allclose(A @ K[-1], Lp, **tol["float64_ref"])
    Kf = Pprior @ H.T @ np.linalg.inv(H @ Pprior @ H.T + N)
    np.testing.assert_allclose(K[-1], Kf, **tol["float64_ref"])
    np.testing.assert_allclose(P[-1], (np.eye(p) - Kf @ H) @ Pprior, **tol["float64_ref"])


def test_time_varying_H_broadcast(rng, tol):
    T, p, m = 4, 2, 1
    A = rng.standard_normal((T, p, p))
    H = rng.standard_normal((m, p))
    K1, P1 = kalman_gains(A, H, 0.1 * np.eye(p), [[0.2]], np.eye(p))
    K2, P2 = kalman_gains(
        A,
        np.broadcast_to(H, (T, m, p)),
        np.broadcast_to(0.1 * np.eye(p), (T, p, p)),
        [[0.2]],
        np.eye(p),
    )
    np.testing.assert_allclose(K1, K2, **tol["float64_exact"])
    np.testing.assert_allclose(P1, P2, **tol["float64_exact"])


@pytest.mark.parametrize(
    "kw, match",
    [
        (dict(N=[[0.0]]), "N"),
        (dict(M=[[-1.0, 0], [0, 1]]), "M"),
        (dict(P0=np.ones((3, 3))), "P0"),
        (dict(H=np.ones((1, 3))), "H"),
    ],
)
def test_bad_input(kw, match):
    args = dict(A=np.ones((2, 2, 2)), H=np.ones((1, 2)), M=np.eye(2), N=[[1.0]], P0=np.eye(2))
    args.update(kw)
    with pytest.raises(InvalidInputError, match=match):
        kalman_gains(**args)


def test_overflowing_recursion_names_the_step():
    """A = 1e200 I (finite) overflows the covariance recursion at its first step: a
    NumericalError, never all-NaN gains."""
    from riskplan.errors import NumericalError

    T, n = 50, 2
    eye = np.eye(n)
    with pytest.raises(NumericalError, match="step 0") as exc:
        kalman_gains(np.broadcast_to(1e200 * eye, (T, n, n)), eye, eye, eye, eye)
    assert exc.value.step == 0
    # an unobserved component growing by 1e100 per step overflows later: the step named is
    # the first bad one (the horizon just before it is finite)
    A = np.broadcast_to(1e50 * eye, (T, n, n))
    H, N = eye[:1], np.eye(1)
    with pytest.raises(NumericalError) as exc:
        kalman_gains(A, H, eye, N, eye)
    t = exc.value.step
    assert t > 0
    K, P = kalman_gains(A[:t], H, eye, N, eye)
    assert np.isfinite(K).all() and np.isfinite(P).all()
