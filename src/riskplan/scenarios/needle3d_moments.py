r"""The 3-D needle's step and tip maps for moment propagation beyond first order
(:func:`riskplan.control.lqgmp3d_moments.second_order_model`, for
:func:`riskplan.control.lqgmp3d.lqgmp_3d` ``moments=``).

**The step in the material pose.** With the reduced material pose ``m = (X, e₁, e₂, e₃)``
(12,), the screw step ``g_{t+1} = g_t exp(τ ξ̂(u))`` is *linear in m* for a fixed control:
``m' = K(u) m`` with ``K(u)`` :func:`riskplan.scenarios.bevel.pose_step_jacobian`. The only
nonlinearity of the kinematics is in the control, which carries the actuation noise and the
feedback. ``Needle3DMoments.material_step_derivatives`` returns ``K(u*)``, ``∂K/∂u_k``
and ``∂²K/∂u_k∂u_l`` (central differences of the closed form, step :data:`riskplan.scenarios.CONTROL_STEP`), so

.. math::

    \delta m' = K \delta m + \sum_k K_k m^* \delta u_k + \sum_k K_k \delta u_k \delta m
        + \tfrac12 \sum_{kl} K_{kl} m^* \delta u_k \delta u_l + O(\delta^3)

is exact to second order (the bilinear term is the roll of the noise about the *actual*
axis, not the planned one).

**The tip through the tissue.** The world tip is ``x = X + u(X; e₃)``, the quasi-static push
at the material point: within a tetrahedron a quadratic function of ``X`` (barycentric
weights on both the load and the read-out), with a gradient that jumps from element to
element (``‖∂u/∂X‖`` from 0.1 to 0.7 along a plan on the planning mesh). A predicted spread
of a few hundredths covers several tetrahedra, so the gradient at the plan's point is not the
slope the spread sees. ``Needle3DMoments.tip_moments`` gives the statistical
linearisation over ``N(m* + μ, Σ)`` instead: the unscented points ``m̄ ± √n σ_i v_i`` on the
``n ≤ 6`` non-degenerate principal directions of the ``(X, e₃)`` block (the push does not
depend on ``e₁``, ``e₂``), weights ``1/(2n)``, and

.. math::

    \Phi = C_{xm} \Sigma^{+}, \qquad \Delta = \bar x - x(m^*) - \Phi \mu, \qquad
    R = C_{xx} - \Phi \Sigma \Phi^\top

(``x(m* + δ) ≈ x(m*) + Δ + Φ δ + ε``, ``ε ~ N(0, R)`` the part no affine map explains).
"""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array
from riskplan.errors import InvalidInputError
from riskplan.scenarios.base import SimParams
from riskplan.scenarios.bevel import se3_exp_batch
from riskplan.scenarios.needle3d_config import Needle3DState

__all__ = ["CONTROL_STEP", "TIP_KINDS"]

#: Central-difference step in the control for ``∂K/∂u`` and ``∂²K/∂u²`` (``K(u)`` is smooth:
#: its entries are trigonometric in ``τ ω`` and polynomial in ``τ κ v``)
CONTROL_STEP = 1e-4

#: What ``Needle3DMoments.tip_moments`` linearises: the sensed world tip, the position
#: the reduced state reads (world tip, or ``X`` in the material frame), or that position
#: relative to the target's (deformed) centre
TIP_KINDS = ("measured", "position", "relative")

#: the material coordinates the push depends on: X and e₃
_PUSHED = np.array([0, 1, 2, 9, 10, 11])


class Needle3DMoments:
    """Second-order step derivatives and statistically linearised tip maps of the 3-D
    needle (module docstring); a mixin of :class:`riskplan.scenarios.needle3d.Needle3DScenario`."""

    @property
    def position_is_measured(self) -> bool:
        """Whether the position the reduced state reads is the sensed world tip (the world
        frame), so that ``tip_moments`` of kinds ``"position"`` and ``"measured"`` agree."""
        return self.frame == "world"

    def _screw_steps(self, U: np.ndarray):
        """``(E (n, 3, 3), d (n, 3))``: the screw exponential ``exp(τ ξ̂(u))`` of each row of
        ``U (n, q)``, in one batch."""
        cfg = self.config
        n = U.shape[0]
        rho = U[:, 2] if U.shape[1] == 3 else np.ones(n)
        xi = np.zeros((n, 6))
        xi[:, 2] = cfg.tau * U[:, 0]
        xi[:, 3] = cfg.tau * rho * cfg.curvature * U[:, 0]
        xi[:, 5] = cfg.tau * U[:, 1]
        return se3_exp_batch(xi)

    def _pose_jacobians(self, U: np.ndarray) -> np.ndarray:
        """``K(u) (n, 12, 12)`` for each row of ``U (n, q)``: the structure of
        :func:`riskplan.scenarios.bevel.pose_step_jacobian` filled from one batched screw
        exponential."""
        n = U.shape[0]
        E, d = self._screw_steps(U)
        K = np.zeros((n, 12, 12))
        i3 = np.arange(3)
        K[:, i3, i3] = 1.0
        for j in range(3):
            K[:, i3, 3 + 3 * j + i3] = d[:, j, None]
            for k in range(3):
                K[:, 3 + 3 * k + i3, 3 + 3 * j + i3] = E[:, j, k, None]
        return K

    def material_step_batch(self, material, controls) -> np.ndarray:
        """The exact material step ``m' = K(u) m`` of each row (the screw step of the
        simulator, :func:`riskplan.scenarios.bevel.pose_step_jacobian`, nonlinear in ``u``),
        for Monte Carlo of the closed loop beyond any expansion in the control
        (:func:`riskplan.control.lqgmp3d_particles.lqgmp_particles`).

        Parameters
        ----------
        material : array_like, shape (n, 12)
            Material poses ``m = (X, e₁, e₂, e₃)``.
        controls : array_like, shape (n, q)
            The controls actually applied (inside the bounds).

        Returns
        -------
        numpy.ndarray, shape (n, 12)
            ``K(u_i) m_i``.
        """
        m = np.asarray(material, dtype=np.float64)
        U = np.asarray(controls, dtype=np.float64)
        if m.ndim != 2 or m.shape[1] != 12 or U.shape != (m.shape[0], self.control_dim):
            raise InvalidInputError(
                f"material, controls: expected (n, 12) and (n, {self.control_dim}), "
                f"got {m.shape} and {U.shape}"
            )
        n = U.shape[0]
        E, d = self._screw_steps(U)
        frame = m[:, 3:].reshape(n, 3, 3)  # rows e₁, e₂, e₃
        out = np.empty_like(m)
        # X' = X + Σ_j d_j e_j, e_k' = Σ_j E_jk e_j: K(u) m without the (n, 12, 12) K
        out[:, :3] = m[:, :3] + (d[:, None, :] @ frame)[:, 0]
        out[:, 3:] = (E.transpose(0, 2, 1) @ frame).reshape(n, 9)
        return out

    def material_step_derivatives(self, state: Needle3DState, control):
        """``m' = K(u) m`` and its control derivatives at ``u = control`` (module docstring).

        Parameters
        ----------
        state : Needle3DState
            The state ``y_t`` (its material pose is ``m*``).
        control : array_like, shape (q,)
            The nominal control ``u*_t``.

        Returns
        -------
        m : numpy.ndarray, shape (12,)
            The material pose ``m*``.
        K : numpy.ndarray, shape (12, 12)
            ``K(u*)``.
        dK : numpy.ndarray, shape (q, 12, 12)
            ``∂K/∂u_k``.
        d2K : numpy.ndarray, shape (q, q, 12, 12)
            ``∂²K/∂u_k∂u_l``.
        """
        if not isinstance(state, Needle3DState):
            raise InvalidInputError(f"state: expected a Needle3DState, got {type(state).__name__}")
        u = as_array(control, "control", shape=(self.control_dim,))
        q, h = u.shape[0], CONTROL_STEP
        eye = np.eye(q) * h
        # the control points: u, u ± h e_k, u ± h e_k ± h e_j (k < j)
        pairs = [(k, j) for k in range(q) for j in range(k + 1, q)]
        pts = [u] + [u + s * eye[k] for k in range(q) for s in (1.0, -1.0)]
        pts += [u + a * eye[k] + b * eye[j] for k, j in pairs for a in (1, -1) for b in (1, -1)]
        Ks = self._pose_jacobians(np.array(pts))
        K = Ks[0]
        dK = np.zeros((q, 12, 12))
        d2K = np.zeros((q, q, 12, 12))
        for k in range(q):
            Kp, Km = Ks[1 + 2 * k], Ks[2 + 2 * k]
            dK[k] = (Kp - Km) / (2 * h)
            d2K[k, k] = (Kp - 2 * K + Km) / (h * h)
        for i, (k, j) in enumerate(pairs):
            pp, pm, mp, mm = Ks[1 + 2 * q + 4 * i : 5 + 2 * q + 4 * i]
            d2K[k, j] = d2K[j, k] = (pp - pm - mp + mm) / (4 * h * h)
        return np.array(state.material, dtype=np.float64), K, dK, d2K

    def _tip_function(self, state: Needle3DState, params: SimParams, kind: str):
        """``f(m) (3,)`` for ``kind`` (:data:`riskplan.scenarios.TIP_KINDS`), or ``None`` where it is the
        identity on ``X`` (no push yet, or the material frame's reduced position)."""
        if kind != "measured" and self.frame == "material":
            return None  # X itself; the material target does not move
        if state.t == 0:
            return None
        a = self.mesh_data(params.n_elements).slices[-1][0]

        def f(m):
            tracked, pose = self._tissue_response(m, params)
            return pose[:3] - tracked[a] if kind == "relative" else pose[:3]

        return f

    def tip_moments(
        self, state: Needle3DState, mean, cov, params: SimParams | None = None, kind="measured"
    ):
        """Statistical linearisation of the tip over ``m ~ N(m* + mean, cov)`` (module
        docstring): ``f(m* + δ) ≈ f(m*) + Δ + Φ δ + ε``, ``ε ~ N(0, R)``.

        Parameters
        ----------
        state : Needle3DState
            The plan's state (``m*`` its material pose).
        mean : array_like, shape (12,)
            The mean deviation ``μ`` of the material pose.
        cov : array_like, shape (12, 12)
            Its covariance ``Σ``.
        params : SimParams or None
            The simulation parameters (``None``: :attr:`nominal_params`).
        kind : str
            One of :data:`riskplan.scenarios.TIP_KINDS`.

        Returns
        -------
        Phi : numpy.ndarray, shape (3, 12)
            The slope (zero on ``e₁``, ``e₂``).
        offset : numpy.ndarray, shape (3,)
            ``Δ``.
        resid : numpy.ndarray, shape (3, 3)
            ``R``.
        """
        if kind not in TIP_KINDS:
            raise InvalidInputError(f"kind: expected one of {TIP_KINDS}, got {kind!r}")
        params = params or self.nominal_params
        self._check_state(state, params)
        mu = as_array(mean, "mean", shape=(12,))
        S = as_array(cov, "cov", shape=(12, 12))
        Phi = np.zeros((3, 12))
        Phi[:, :3] = np.eye(3)
        f = self._tip_function(state, params, kind)
        S6 = 0.5 * (S[np.ix_(_PUSHED, _PUSHED)] + S[np.ix_(_PUSHED, _PUSHED)].T)
        w, V = np.linalg.eigh(S6)
        keep = w > 1e-12 * max(float(w[-1]), 0.0)
        if f is None or not keep.any():
            return Phi, np.zeros(3), np.zeros((3, 3))
        n = int(keep.sum())
        cols = V[:, keep] * np.sqrt(w[keep] * n)  # (6, n): the points' offsets
        m0 = np.array(state.material, dtype=np.float64)
        centre = m0 + mu
        D = np.concatenate([cols.T, -cols.T])  # (2n, 6)
        pts = np.empty((2 * n, 3))
        for i, d in enumerate(D):
            m = centre.copy()
            m[_PUSHED] += d
            pts[i] = f(m)
        xbar = pts.mean(axis=0)
        Cxm = (pts - xbar).T @ D / (2 * n)
        Cxx = (pts - xbar).T @ (pts - xbar) / (2 * n)
        Phi6 = Cxm @ np.linalg.pinv(S6, rcond=1e-12, hermitian=True)
        Phi = np.zeros((3, 12))
        Phi[:, _PUSHED] = Phi6
        R = Cxx - Phi6 @ S6 @ Phi6.T
        offset = xbar - f(m0) - Phi @ mu
        return Phi, offset, 0.5 * (R + R.T)

    def _frame_map(self, state: Needle3DState, params: SimParams) -> np.ndarray:
        """``∂x/∂m (12, 12)``: the reduced state against the material pose at ``state`` —
        the identity in the material frame, where nothing pushes, and at the start; else the
        tip's tissue Jacobian in ``(X, e₃)`` on the position rows."""
        P = np.eye(12)
        if self.frame == "world":
            diff = self._material_differences(state, params)
            if diff is not None:
                P[:3, _PUSHED] = diff[1]
        return P

    def linear_model(self, plan, actuation_cov):
        """The linear model of ``plan`` from the step's structure instead of simulator runs
        (the actuation case): ``A_t = P_{t+1} K(u*_t) P_t⁻¹``, ``B_t = P_{t+1} B_m``,
        ``M_t = B_t Σ_w B_tᵀ`` with ``P_t = ∂x/∂m`` at ``y*_t`` (the tissue's central
        differences on the tip's rows, world frame; the identity in the material frame),
        ``K`` and ``B_m = ∂(K(u) m*)/∂u`` of ``material_step_derivatives``, ``H_t`` the
        observation Jacobian and ``N`` the sensing covariance. One step costs the 12 tissue
        responses of the central differences and one batched screw exponential, where
        :func:`riskplan.control.linearize` runs the simulator ``2K + q + n_samples`` times
        (:func:`riskplan.control.lqgmp3d_moments.structured_linearization` wraps it).

        Parameters
        ----------
        plan : NominalPlan
            The plan, in this scenario's frame.
        actuation_cov : array_like, shape (q, q)
            ``Σ_w``.

        Returns
        -------
        A, B, M, H, N : numpy.ndarray
            Shapes ``(T, 12, 12)``, ``(T, 12, q)``, ``(T, 12, 12)``, ``(T, 3, 12)``,
            ``(T, 3, 3)``.
        """
        q = self.control_dim
        W = as_array(actuation_cov, "actuation_cov", shape=(q, q))
        params = plan.params
        T = plan.n_steps
        frames = [self._frame_map(y, params) for y in plan.states]
        A, B = np.empty((T, 12, 12)), np.empty((T, 12, q))
        for t in range(T):
            m, K, dK, _ = self.material_step_derivatives(plan.states[t], plan.controls[t])
            A[t] = frames[t + 1] @ K @ np.linalg.inv(frames[t])
            B[t] = frames[t + 1] @ np.einsum("kij,j->ik", dK, m)
        H = np.stack([self.observation_jacobian(y, params) for y in plan.states[1:]])
        M = np.einsum("tik,kl,tjl->tij", B, W, B)
        return A, B, M, H, np.broadcast_to(self.sensing_cov, (T, 3, 3)).copy()
