"""The 3-D needle's reduced-state frames and tissue Jacobians: the methods of
:class:`riskplan.scenarios.needle3d.Needle3DScenario` that read the tip in the world or the
material frame (:data:`riskplan.scenarios.FRAMES`, the module docstring of
:mod:`riskplan.scenarios.needle3d`)
and differentiate the tissue response in the material pose — ``with_frame``, ``measure``,
``observation_jacobian``, ``state_obstacles``, ``state_goal`` and ``goal_jacobian`` — and
the affine images of the deformed bodies with the tip's gauge in each (the collision and
goal tests). A mixin, so the scenario keeps one class."""

from __future__ import annotations

import math

import numpy as np

from riskplan.geometry3d import ConvexBody
from riskplan.scenarios import base
from riskplan.scenarios.base import SimParams, gaussian_noise
from riskplan.scenarios.needle3d_config import Needle3DState

__all__ = ["JACOBIAN_STEP"]

#: Central-difference step of :meth:`Needle3DFrames.observation_jacobian` and
#: :meth:`Needle3DFrames.goal_jacobian` (the response is quadratic in the material pose
#: within an element, so central differences are exact up to round-off there).
JACOBIAN_STEP = 1e-6


class Needle3DFrames:
    """Frame and Jacobian methods of the 3-D needle scenario (module docstring)."""

    # the frame switch shared with the 2-D needle (:mod:`riskplan.scenarios.base`)
    with_frame = base.with_frame

    def measure(self, state: Needle3DState, noise=None, rng=None) -> np.ndarray:
        """``z = x_world + n``, the sensed world tip position of ``state`` (both frames; in
        the world frame equal to ``observe(reduced(state))``, the same noise draws).

        Parameters
        ----------
        state : Needle3DState
            The full state.
        noise : array_like, shape (3,), optional
            The sensing noise to add; drawn with ``rng`` when ``None``.
        rng : int, numpy.random.Generator or None
            Seeds the drawn noise.

        Returns
        -------
        numpy.ndarray, shape (3,)
            The measured tip position.
        """
        return np.array(state.pose[:3]) + gaussian_noise(self.sensing_cov, noise, rng, 3)

    def observation_jacobian(
        self, state: Needle3DState, params: SimParams | None = None
    ) -> np.ndarray:
        """``H (3, 12)`` of the measurement with respect to the reduced state.

        World frame: the constant ``[I₃ 0]``. Material frame: ``∂(X + u(X; e₃, s))/∂x`` by
        central differences (:data:`JACOBIAN_STEP`) of the tissue response at perturbed
        material positions and axes (``e₁``, ``e₂`` do not enter the push: zero columns);
        ``[I₃ 0]`` where nothing pushes (``t = 0``, no force, the tip outside the block).

        Parameters
        ----------
        state : Needle3DState
            The full state.
        params : SimParams or None
            The simulation parameters (``None``: :attr:`nominal_params`).

        Returns
        -------
        numpy.ndarray, shape (3, 12)
            The observation Jacobian.
        """
        if self.frame == "world":
            return np.array(self.observation_matrix)
        params = params or self.nominal_params
        H = np.array(self.observation_matrix)
        diff = self._material_differences(state, params)
        if diff is not None:
            H[:, (0, 1, 2, 9, 10, 11)] = diff[1]
        return H

    def _material_differences(self, state: Needle3DState, params: SimParams):
        """``(∂c/∂m (3, 6), ∂x/∂m (3, 6))``: central differences of the deformed target
        centre and of the world tip position in the material position and axis
        ``m = (X, e₃)``; ``None`` where nothing pushes or a step leaves the block."""
        self._check_state(state, params)
        mat = np.array(state.material, dtype=np.float64)
        d = self.mesh_data(params.n_elements)
        if state.t == 0 or params.force_scale == 0.0 or not d.block.contains(mat[:3]):
            return None
        a = d.slices[-1][0]
        h = JACOBIAN_STEP
        Jc, Jx = np.zeros((3, 6)), np.zeros((3, 6))
        for k, i in enumerate((0, 1, 2, 9, 10, 11)):
            resp = []
            for sgn in (1.0, -1.0):
                m = mat.copy()
                m[i] += sgn * h
                if not d.block.contains(m[:3]):
                    return None  # on the block's surface: no two-sided difference
                tracked, pose = self._tissue_response(m, params)
                resp.append((tracked[a], pose[:3]))
            Jc[:, k] = (resp[0][0] - resp[1][0]) / (2 * h)
            Jx[:, k] = (resp[0][1] - resp[1][1]) / (2 * h)
        return Jc, Jx

    def state_obstacles(self, state: Needle3DState) -> list[ConvexBody]:
        """The obstacles in the reduced state's coordinates (what LQG-MP checks ``x[:3]``
        against): the deformed bodies (world frame, :meth:`obstacles`) or the balls and
        boxes of material points (material frame).

        Parameters
        ----------
        state : Needle3DState
            The full state.

        Returns
        -------
        list of ConvexBody
            The obstacles.
        """
        if self.frame == "world":
            return self.obstacles(state)
        d = self._data(state)
        return [ConvexBody(k, c, A) for k, c, A in zip(d.kinds, d.centres, d.shapes)][:-1]

    def state_goal(self, state: Needle3DState) -> ConvexBody:
        """The target in the reduced state's coordinates: the deformed ellipsoid (world
        frame, :meth:`goal`) or the ball of material points (material frame).

        Parameters
        ----------
        state : Needle3DState
            The full state.

        Returns
        -------
        ConvexBody
            The target.
        """
        if self.frame == "world":
            return self.goal(state)
        d = self._data(state)
        return ConvexBody(d.kinds[-1], d.centres[-1], d.shapes[-1])

    def goal_jacobian(self, state: Needle3DState, params: SimParams | None = None) -> np.ndarray:
        """``J (3, 12)``: how the target's centre, in the reduced state's coordinates, moves
        with the reduced state, ``δc ≈ J δx`` (for :func:`riskplan.control.lqgmp3d.lqgmp_3d`'s
        goal test).

        World frame: the push sits at the tip's material point ``X`` along its axis ``e₃``,
        so the deformed target's displacement is a function of ``m = (X, e₃)``, and the
        world position one of ``m`` too, ``x = X + u(X)``. By central differences
        (:data:`JACOBIAN_STEP`) of the tissue response::

            J_m = ∂c/∂m (3, 6),   D = ∂(x, e₃)/∂m = [[∂x/∂X, ∂x/∂e₃], [0, I]],
            J[:, (0, 1, 2, 9, 10, 11)] = J_m D⁻¹,

        zero for ``e₁``, ``e₂`` (the push does not depend on them), and zero where nothing
        pushes. Material frame: zero (the target's material points do not move).

        Parameters
        ----------
        state : Needle3DState
            The full state (its material pose is differentiated at).
        params : SimParams or None
            The simulation parameters (``None``: :attr:`nominal_params`).

        Returns
        -------
        numpy.ndarray, shape (3, 12)
            ``∂c/∂x``.
        """
        params = params or self.nominal_params
        J = np.zeros((3, 12))
        if self.frame == "material":
            self._check_state(state, params)
            return J
        diff = self._material_differences(state, params)
        if diff is None:
            return J
        Jm, Jx = diff
        D = np.eye(6)
        D[:3] = Jx
        J[:, (0, 1, 2, 9, 10, 11)] = np.linalg.solve(D.T, Jm.T).T
        return J

    def _affine(self, state: Needle3DState):
        """``(centres (B, 3), shapes (B, 3, 3))`` of the deformed bodies (obstacles, then
        the target): ``c + u(c)`` and ``(I + G) A`` with ``G ≈ ∇u`` fitted to the body's
        samples (module docstring); cached on the state."""
        cached = state.__dict__.get("_affine")
        if cached is not None:
            return cached
        d = self._data(state)
        B = len(d.kinds)
        centres, shapes = np.empty((B, 3)), np.empty((B, 3, 3))
        for i, (c, A, fit, (a, b)) in enumerate(zip(d.centres, d.shapes, d.fit, d.slices)):
            u = state.displacement[a:b]
            G = (fit @ (u[1:] - u[0])).T  # ∇u ≈ G
            centres[i] = c + u[0]
            shapes[i] = A + G @ A
        state.__dict__["_affine"] = out = (centres, shapes)  # a function of the fields
        return out

    def _gauges(self, state: Needle3DState) -> np.ndarray:
        """``(B,)`` the world tip's gauge in each deformed body (``≤ 1``: inside;
        :meth:`riskplan.geometry3d.ConvexBody.norm`), all bodies in one batched solve."""
        centres, shapes = self._affine(state)
        s = np.linalg.solve(shapes, (state.pose[:3] - centres)[:, :, None])[:, :, 0]
        kinds = self._data(state).kinds
        return np.array(
            [
                math.sqrt(float(v @ v)) if k == "ellipsoid" else float(np.abs(v).max())
                for k, v in zip(kinds, s)
            ]
        )
