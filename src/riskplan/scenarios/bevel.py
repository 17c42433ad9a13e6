"""Kinematics of a bevel-tip steerable needle in SE(3): the nonholonomic unicycle model of
Webster, Kim, Cowan, Chirikjian & Okamura, "Nonholonomic modeling of needle steering",
IJRR 25(5-6), 2006 (section 3, eq. 2-4, the "unicycle" variant with the bicycle's
front-wheel offset set to zero), with duty-cycled curvature as in Minhas, Engh, Fenske &
Riviere (EMBS 2007) as an option.

Tip frame ``g = (R, p) ∈ SE(3)``: ``p`` the tip position, ``R = [e₁ e₂ e₃]`` with ``e₃``
the needle axis (direction of insertion) and ``e₁`` the axis the bevel bends about. Body
twist (Webster et al. 2006, eq. 3 with ``ℓ₂ = 0``), ``g⁻¹ ġ = ξ̂``::

    ξ = (v_b, ω_b),   v_b = (0, 0, v),   ω_b = (ρ κ v, 0, ω)

with ``v`` the insertion speed, ``ω`` the axial rotation rate, ``κ`` the needle's
curvature (``1 / r``) and ``ρ ∈ [0, 1]`` the duty-cycled fraction of that curvature (1: the
plain bevel tip, which always bends by ``κ`` about its ``e₁``; duty cycling spins the needle
for a fraction ``1 − ρ`` of the insertion, which straightens the path on average; the model
is its continuous average). A step holds ``(v, ω, ρ)`` for ``τ``: ``g_{t+1} = g_t exp(τ ξ̂)``,
a screw motion, integrated exactly with the SE(3) exponential (:func:`se3_exp`; Murray, Li &
Sastry 1994, eq. 2.36)::

    exp(ξ̂) = [[exp([ω]×), V v], [0, 1]],
    V = I + (1 − cos θ)/θ² [ω]× + (θ − sin θ)/θ³ [ω]×²,   θ = |ω|.

Pose vector (what the scenario's reduced state holds): ``(p, e₁, e₂, e₃)`` ``(12,)``. For a
fixed control the step is *linear* in that vector: ``p' = p + R d``, ``R' = R E`` with
``(E, d) = exp(τ ξ̂)`` (right multiplication by a constant), so the exact Jacobian of the
kinematic step is known (:func:`pose_step_jacobian`).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = [
    "bevel_twist",
    "hat",
    "needle_step",
    "pose_from_vector",
    "pose_step_jacobian",
    "pose_vector",
    "rk4_needle",
    "se3_exp",
    "se3_exp_batch",
]


def hat(w) -> np.ndarray:
    """``[w]× (3, 3)``: the skew matrix with ``[w]× a = w × a``.

    Parameters
    ----------
    w : array_like, shape (3,)
        The vector.

    Returns
    -------
    numpy.ndarray, shape (3, 3)
        The skew-symmetric matrix of ``w``.
    """
    x, y, z = (float(c) for c in w)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def bevel_twist(v: float, omega: float, kappa: float, rho: float = 1.0) -> np.ndarray:
    """Body twist ``ξ (6,)`` = ``(v_b, ω_b)`` of the unicycle model (module docstring):
    ``(0, 0, v, ρ κ v, 0, ω)``.

    Parameters
    ----------
    v : float
        Insertion speed along e₃ (length per unit time).
    omega : float
        Spin rate about e₃ (rad per unit time).
    kappa : float
        Curvature κ of the bevel tip (1 / length).
    rho : float
        Duty-cycle factor ρ ∈ [0, 1] scaling the curvature.

    Returns
    -------
    numpy.ndarray, shape (6,)
        The twist ``(v_b, ω_b)``.
    """
    return np.array([0.0, 0.0, float(v), float(rho) * float(kappa) * float(v), 0.0, float(omega)])


def se3_exp(xi) -> tuple[np.ndarray, np.ndarray]:
    """``(E (3, 3), d (3,))`` = ``exp(ξ̂)`` for a twist ``ξ = (v, ω) (6,)`` (module
    docstring; series expansions of the coefficients below θ = 1e-4, where the closed
    forms lose digits).

    Parameters
    ----------
    xi : array_like, shape (6,)
        The twist: linear part ``v`` then angular part ``ω``.

    Returns
    -------
    E : numpy.ndarray, shape (3, 3)
        The rotation of ``exp(ξ̂)``.
    d : numpy.ndarray, shape (3,)
        Its translation.
    """
    v = np.asarray(xi[:3], dtype=np.float64)
    w = np.asarray(xi[3:], dtype=np.float64)
    th2 = float(w @ w)
    th = math.sqrt(th2)
    W = hat(w)
    W2 = W @ W
    if th < 1e-4:
        a = 1.0 - th2 / 6.0  # sin θ / θ
        b = 0.5 - th2 / 24.0  # (1 − cos θ) / θ²
        c = 1.0 / 6.0 - th2 / 120.0  # (θ − sin θ) / θ³
    else:
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / th2
        c = (th - math.sin(th)) / (th2 * th)
    E = np.eye(3) + a * W + b * W2
    V = np.eye(3) + b * W + c * W2
    return E, V @ v


def se3_exp_batch(xi) -> tuple[np.ndarray, np.ndarray]:
    """:func:`se3_exp` over a batch ``xi (n, 6)``: ``(E (n, 3, 3), d (n, 3))``.

    Parameters
    ----------
    xi : array_like, shape (n, 6)
        The twists, one per row.

    Returns
    -------
    E : numpy.ndarray, shape (n, 3, 3)
        The rotations.
    d : numpy.ndarray, shape (n, 3)
        The translations.
    """
    xi = np.asarray(xi, dtype=np.float64)
    v, w = xi[:, :3], xi[:, 3:]
    th2 = np.einsum("ij,ij->i", w, w)
    th = np.sqrt(th2)
    small = th < 1e-4
    ts = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(ts) / ts)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ts)) / ts**2)
    c = np.where(small, 1.0 / 6.0 - th2 / 120.0, (ts - np.sin(ts)) / ts**3)
    W = np.zeros((len(xi), 3, 3))
    W[:, 0, 1], W[:, 0, 2], W[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    W[:, 1, 0], W[:, 2, 0], W[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    W2 = W @ W
    eye = np.eye(3)
    E = eye + a[:, None, None] * W + b[:, None, None] * W2
    V = eye + b[:, None, None] * W + c[:, None, None] * W2
    return E, np.einsum("nij,nj->ni", V, v)


def needle_step(R, p, v, omega, *, tau: float, kappa: float, rho: float = 1.0):
    """One exact step ``g_{t+1} = g_t exp(τ ξ̂)`` of the unicycle model: ``(R' (3, 3), p' (3,))``.

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Tip frame before the step (columns e₁, e₂, e₃).
    p : array_like, shape (3,)
        Tip position before the step.
    v : float
        Insertion speed (length per unit time).
    omega : float
        Spin rate (rad per unit time).
    tau : float
        Step duration.
    kappa : float
        Curvature κ (1 / length).
    rho : float
        Duty-cycle factor ρ scaling the curvature.

    Returns
    -------
    R : numpy.ndarray, shape (3, 3)
        Tip frame after the step.
    p : numpy.ndarray, shape (3,)
        Tip position after the step.
    """
    E, d = se3_exp(tau * bevel_twist(v, omega, kappa, rho))
    R = np.asarray(R, dtype=np.float64)
    return R @ E, np.asarray(p, dtype=np.float64) + R @ d


def rk4_needle(R, p, v, omega, *, tau: float, kappa: float, rho: float = 1.0, n: int = 1000):
    """``ġ = g ξ̂`` integrated with ``n`` classical Runge–Kutta steps (the independent
    oracle of :func:`needle_step`; the rotation drifts off SO(3) by O(h⁴)).

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Tip frame at the start.
    p : array_like, shape (3,)
        Tip position at the start.
    v : float
        Insertion speed (length per unit time).
    omega : float
        Spin rate (rad per unit time).
    tau : float
        Duration integrated over.
    kappa : float
        Curvature κ (1 / length).
    rho : float
        Duty-cycle factor ρ scaling the curvature.
    n : int
        Number of Runge–Kutta steps (each ``τ / n`` long).

    Returns
    -------
    R : numpy.ndarray, shape (3, 3)
        Tip frame at the end.
    p : numpy.ndarray, shape (3,)
        Tip position at the end.
    """
    xi = bevel_twist(v, omega, kappa, rho)
    W, vb = hat(xi[3:]), xi[:3]
    h = tau / n
    R = np.array(R, dtype=np.float64)
    p = np.array(p, dtype=np.float64)

    def f(Rk):
        return Rk @ W, Rk @ vb

    for _ in range(n):
        k1R, k1p = f(R)
        k2R, k2p = f(R + 0.5 * h * k1R)
        k3R, k3p = f(R + 0.5 * h * k2R)
        k4R, k4p = f(R + h * k3R)
        R = R + h / 6.0 * (k1R + 2 * k2R + 2 * k3R + k4R)
        p = p + h / 6.0 * (k1p + 2 * k2p + 2 * k3p + k4p)
    return R, p


def pose_vector(R, p) -> np.ndarray:
    """``(12,)`` = ``(p, e₁, e₂, e₃)``, the columns of ``R`` after the position.

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Frame (columns e₁, e₂, e₃).
    p : array_like, shape (3,)
        Position.

    Returns
    -------
    numpy.ndarray, shape (12,)
        The pose vector.
    """
    return np.concatenate(
        [np.asarray(p, dtype=np.float64), np.asarray(R, dtype=np.float64).T.ravel()]
    )


def pose_from_vector(x) -> tuple[np.ndarray, np.ndarray]:
    """``(R (3, 3), p (3,))`` of a pose vector ``(12,)`` (no re-orthonormalisation).

    Parameters
    ----------
    x : array_like, shape (12,)
        Pose vector ``(p, e₁, e₂, e₃)``.

    Returns
    -------
    R : numpy.ndarray, shape (3, 3)
        Frame with columns e₁, e₂, e₃.
    p : numpy.ndarray, shape (3,)
        Position.
    """
    x = np.asarray(x, dtype=np.float64)
    return x[3:12].reshape(3, 3).T.copy(), x[:3].copy()


def pose_step_jacobian(v, omega, *, tau: float, kappa: float, rho: float = 1.0) -> np.ndarray:
    """``(12, 12)`` exact Jacobian of the pose vector after one step with respect to the pose
    vector before it (the step is linear in it for a fixed control, module docstring):
    ``p' = p + Σ_j d_j e_j``, ``e'_k = Σ_j E_jk e_j``.

    Parameters
    ----------
    v : float
        Insertion speed (length per unit time).
    omega : float
        Spin rate (rad per unit time).
    tau : float
        Step duration.
    kappa : float
        Curvature κ (1 / length).
    rho : float
        Duty-cycle factor ρ scaling the curvature.

    Returns
    -------
    numpy.ndarray, shape (12, 12)
        The Jacobian ``∂x' / ∂x``.
    """
    E, d = se3_exp(tau * bevel_twist(v, omega, kappa, rho))
    J = np.zeros((12, 12))
    J[:3, :3] = np.eye(3)
    for j in range(3):
        J[:3, 3 + 3 * j : 6 + 3 * j] = d[j] * np.eye(3)
        for k in range(3):
            J[3 + 3 * k : 6 + 3 * k, 3 + 3 * j : 6 + 3 * j] = E[j, k] * np.eye(3)
    return J


@nb.njit(cache=True)
def _pose_vector_step(m, v, omega, tau, kappa, rho):
    """:func:`needle_step` on the pose vector ``m = (p, e₁, e₂, e₃) (12,)``, compiled (the
    simulator's hot path: one call instead of a dozen small array operations; the same
    formulas as :func:`se3_exp`, summed in another order, so equal to rounding)."""
    wx = tau * rho * kappa * v
    wz = tau * omega
    vz = tau * v
    th2 = wx * wx + wz * wz
    if th2 < 1e-8:  # θ < 1e-4
        a = 1.0 - th2 / 6.0
        b = 0.5 - th2 / 24.0
        c = 1.0 / 6.0 - th2 / 120.0
    else:
        th = math.sqrt(th2)
        a = math.sin(th) / th
        b = (1.0 - math.cos(th)) / th2
        c = (th - math.sin(th)) / (th2 * th)
    # W = [ω]× for ω = (wx, 0, wz); W² = ω ωᵀ − θ² I
    W = np.array([[0.0, -wz, 0.0], [wz, 0.0, -wx], [0.0, wx, 0.0]])
    w = np.array([wx, 0.0, wz])
    out = np.empty(12)
    for j in range(3):
        for i in range(3):
            Eij = a * W[i, j] + b * (w[i] * w[j] - (th2 if i == j else 0.0))
            if i == j:
                Eij += 1.0
            # R' = R E: e'_j = Σ_i E_ij e_i
            for r in range(3):
                if i == 0:
                    out[3 + 3 * j + r] = Eij * m[3 + r]
                else:
                    out[3 + 3 * j + r] += Eij * m[3 + 3 * i + r]
        # d = V v_b with v_b = (0, 0, vz): d_j = V_j2 vz; p' = p + R d
        Vj2 = b * W[j, 2] + c * (w[j] * w[2] - (th2 if j == 2 else 0.0))
        if j == 2:
            Vj2 += 1.0
        d_j = Vj2 * vz
        for r in range(3):
            if j == 0:
                out[r] = m[r] + d_j * m[3 + r]
            else:
                out[r] += d_j * m[3 + 3 * j + r]
    return out
