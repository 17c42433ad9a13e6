r"""LQG-MP's a-priori distribution of the 3-D needle by Monte Carlo of the reduced closed loop,
without the Gaussian closure: the final tip's distribution is skewed, and its tail is what
the goal test counts.

**Why.** The bevel's material step ``m' = K(u) m`` is linear in the pose but not in the
control: the noisy roll turns the direction the needle bends in, so a roll error ``φ``
moves the tip by ``∝ sin φ`` across the bend and ``∝ 1 − cos φ`` (always the same sign)
within it. The second-order model (:mod:`riskplan.control.lqgmp3d_moments`) carries the
mean shift of those terms but closes the distribution as a Gaussian. Measured on the
3-D needle (docs/results.md): the executions' final tip relative to the deformed target has
skewness −0.51 and −0.34 across the plan (standard error 0.04), already in the material
pose, and a Gaussian with the executions' own moments puts 0.013 more of it in the target
than the executions reach.

**The recursion** (per particle, ``t = 0 .. T−1``; the controller's gains ``L_t``, Kalman
gains ``K_t`` and model ``A_t, B_t, H_t``; the tip maps ``Φ_t, Δ_t, R_t`` of the
:class:`~riskplan.control.lqgmp3d_moments.SecondOrderModel`)::

    ū_t   = clip(u*_t + L_t x̂_t) − u*_t                      (clip: the control bounds)
    u_t   = clip(u*_t + ū_t + w_t),   w_t ~ N(0, Σ_w)        (the actuation noise)
    m_{t+1} = K(u_t) m_t                                      (``step="exact"``)
    x_{t+1} = x*_{t+1} + Δ_t + Φ_t δm_{t+1} + ε_t,   ε_t ~ N(0, R_t)
    z̄_{t+1} = x_{t+1} − x*_{t+1} + n_t,   n_t ~ N(0, N)
    x̂_{t+1} = x̂⁻ + K_t (z̄_{t+1} − H_t x̂⁻),   x̂⁻ = A_t x̂_t + B_t ū_t

as :func:`riskplan.control.lqg.execute` runs it, with the tissue's tip map statistically
linearised (the model's) instead of solved per particle. ``step="quadratic"`` takes the
material step to second order in ``δu`` (the expansion the second-order model's mean
uses: ``K δm + B_m δu + Σ_k K_k δu_k δm + ½ Σ_kl K_kl m* δu_k δu_l``), ``step="linear"``
to first. A particle collides where its ``x_{t+1}`` lies in one of the plan's deformed
obstacles at ``t + 1``; it succeeds where it never collides and its final tip relative
to the moving target (the model's goal map) lies in the plan's deformed target.

**Precision.** With ``p_se`` the particles are drawn in batches of ``batch`` until the
binomial standard error of ``P(success)``, ``sqrt(p̃(1 − p̃)/n)`` with ``p̃ = (k + 1)/(n + 2)``
(``riskplan.control.lqgmp3d.binomial_se``), is at most ``p_se``, at most
``n_particles`` in all (:func:`draw_until`); without it, one batch of ``n_particles``.

Cost: ``T`` batched screw exponentials of ``n`` controls; 30,000 particles of a 23-step
plan take about 0.8 s of CPU (the screw exponentials 0.26 s; the normal draws, 8 per particle
and step, 0.1 s); the per-step moments of ``ξ_t`` (``keep_moments``) about 0.15 s more.
Scope: the world frame (the checked position is the sensed tip), the actuation case (the
second-order model's scope).
"""

from __future__ import annotations

import math

import numpy as np

from riskplan._validation import (
    as_array,
    as_generator,
    check_choice,
    check_count,
    check_instance,
    check_psd,
)
from riskplan.control.lqgmp3d import _goal, _obstacles, binomial_se, draw_until
from riskplan.control.lqgmp3d_moments import SecondOrderModel
from riskplan.control.lqgmp_common import LQGMPResult, _factor
from riskplan.errors import InvalidInputError

__all__ = ["STEPS", "draw_until", "lqgmp_particles"]

#: How the particles' material step is taken (module docstring).
STEPS = ("exact", "quadratic", "linear")


def _check(sim, plan, controller, moments, actuation_cov, n, step):
    """Validate the arguments; return ``Σ_w (q, q)``."""
    from riskplan.control.lqg import LQGController
    from riskplan.control.plan import NominalPlan

    check_instance(plan, NominalPlan, "plan")
    T = plan.n_steps
    ok = isinstance(controller, LQGController) and controller.n_steps == T
    if not ok or controller.disturbance:
        raise InvalidInputError(
            "controller: expected the LQGController of this plan (same number of steps, "
            "no disturbance state)"
        )
    if not isinstance(moments, SecondOrderModel) or moments.n_steps != T:
        raise InvalidInputError(f"moments: expected the SecondOrderModel of this plan ({T} steps)")
    check_choice(step, STEPS, "step")
    check_count(n, "n_particles", 1, integral=True)
    if not getattr(sim, "position_is_measured", False):
        raise InvalidInputError("sim: the checked position must be the sensed tip (world frame)")
    hook = "material_step_batch" if step == "exact" else "material_step_derivatives"
    if not callable(getattr(sim, hook, None)):
        raise InvalidInputError(f"sim: has no {hook}() (see riskplan.scenarios.needle3d)")
    q = plan.controls.shape[1]
    W = as_array(actuation_cov, "actuation_cov", shape=(q, q))
    check_psd(W, "actuation_cov", definite=False)
    return W


def _material_step(sim, plan, t, dm, du, step, derivs):
    """``δm_{t+1} (n, 12)`` of each particle from ``δm_t`` and ``δu_t`` (module docstring)."""
    if step == "exact":
        m = plan.states[t].material + dm
        return sim.material_step_batch(m, plan.controls[t] + du) - plan.states[t + 1].material
    ms, K0, dK, d2K = derivs
    new = dm @ K0.T + du @ np.einsum("kij,j->ik", dK, ms).T
    if step == "quadratic":
        q = du.shape[1]
        for k in range(q):
            new += du[:, k, None] * (dm @ dK[k].T)
            for j in range(q):
                new += 0.5 * (du[:, k] * du[:, j])[:, None] * (d2K[k, j] @ ms)[None]
    return new


def lqgmp_particles(
    sim,
    plan,
    controller,
    moments,
    actuation_cov,
    *,
    n_particles: int = 20_000,
    step: str = "exact",
    clip: bool = True,
    seed=None,
    p_se: float | None = None,
    batch: int = 2000,
    keep_moments: bool = True,
) -> LQGMPResult:
    """``P(success)`` of ``plan`` under ``controller`` by Monte Carlo of the reduced closed
    loop (module docstring).

    Parameters
    ----------
    sim : Simulator
        The 3-D needle in the world frame (``material_step_batch``,
        ``material_step_derivatives``, ``control_bounds``, ``sensing_cov``, the deformed
        obstacles and target of the plan's states).
    plan : NominalPlan
        The plan (its states hold the material poses ``m*_t``).
    controller : LQGController
        The plan's controller (not the disturbance-state one).
    moments : SecondOrderModel
        :func:`~riskplan.control.lqgmp3d_moments.second_order_model` of this plan and
        controller: its tip maps ``Φ_t, Δ_t, R_t`` and its goal map.
    actuation_cov : array_like, shape (q, q)
        ``Σ_w``.
    n_particles : int
        Particles; with ``p_se``, the cap on them.
    step : {"exact", "quadratic", "linear"}
        The material step (module docstring).
    clip : bool
        Clip the feedback and the noisy control at ``sim.control_bounds`` as the simulator
        does.
    seed : int, numpy.random.Generator or None
        Seeds the draws.
    p_se : float or None
        Target standard error of ``p_success``: batches of ``batch`` particles until
        ``riskplan.control.lqgmp3d.binomial_se(k, n) <= p_se`` (:func:`draw_until`);
        ``None``: one batch of ``n_particles``.
    batch : int
        Particles per batch with ``p_se``.
    keep_moments : bool
        Compute the particles' moments of ``ξ_t`` at every step (``mean``, ``cov``); else
        those are NaN (``cov[0]`` the prior), which ``p_success`` does not need.

    Returns
    -------
    LQGMPResult
        ``method="particles"``; ``p_goal`` is ``P(goal | no collision)``; ``mean``/``cov``
        the particles' moments of ``ξ_t = (δm_t, x̂_t)`` (all particles, pooled over the
        batches); ``n_goal_samples`` the particles; ``p_success_se`` their binomial standard
        error.
    """
    W = _check(sim, plan, controller, moments, actuation_cov, n_particles, step)
    if p_se is not None:
        if not (isinstance(p_se, (int, float)) and math.isfinite(p_se) and p_se > 0):
            raise InvalidInputError(f"p_se: expected a finite number > 0, got {p_se!r}")
        check_count(batch, "batch", 1, integral=True)
    gen = as_generator(seed)

    def run_batch(m):
        alive, in_goal, surv, sums, _ = _run(
            sim, plan, controller, moments, W, m, step, clip, gen, keep_moments
        )
        return np.count_nonzero(alive & in_goal), (surv, sums)

    k, n, extras = draw_until(run_batch, int(batch), p_se, int(n_particles))
    surv = np.sum([e[0] for e in extras], axis=0)
    n_free = int(surv[-1])
    mean, cov = _pooled([e[1] for e in extras], n, np.asarray(moments.P0), plan.n_steps)
    before = surv[:-1]
    return LQGMPResult(
        p_success=k / n,
        p_collision_free=n_free / n,
        p_goal=k / n_free if n_free else 0.0,
        p_free_steps=np.divide(surv[1:], before, out=np.zeros(before.shape), where=before > 0),
        mean=mean,
        cov=cov,
        method="particles",
        n_goal_samples=n,
        p_success_se=binomial_se(k, n),
    )


def _pooled(sums, n: int, P0: np.ndarray, T: int) -> tuple[np.ndarray, np.ndarray]:
    """``mean (T+1, 2p)``, ``cov (T+1, 2p, 2p)`` of ``ξ_t`` over all batches from their sums
    ``Σ ξ`` and ``Σ ξ ξᵀ`` (``mean[0] = 0``, ``cov[0] = P0``); NaN without sums."""
    d = P0.shape[0]
    mean, cov = np.zeros((T + 1, d)), np.zeros((T + 1, d, d))
    if any(x is None for x in sums):
        mean[1:], cov[1:] = np.nan, np.nan
    else:
        s1 = np.sum([x[0] for x in sums], axis=0)
        s2 = np.sum([x[1] for x in sums], axis=0)
        mean[1:] = s1 / n
        cov[1:] = (s2 - n * np.einsum("ti,tj->tij", mean[1:], mean[1:])) / max(n - 1, 1)
    cov[0] = P0
    return mean, cov


def _run(sim, plan, controller, moments, W, n, step, clip, gen, keep_moments=True):
    """The particles (module docstring): ``(alive (n,), in_goal (n,), surv (T+1,), sums,
    rel (n, 3))`` with ``surv[t]`` the particles free of collision after ``t`` steps,
    ``sums = (Σ ξ_t (T, 2p), Σ ξ_t ξ_tᵀ (T, 2p, 2p))`` for ``t = 1..T`` (``None`` without
    ``keep_moments``) and ``rel`` the final tip relative to the moving target, in the plan's
    target frame (``x*_T + goal offset + goal map``)."""
    A, B, H = controller.model()[:3]
    T, p = plan.n_steps, A.shape[1]
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    lo, hi = (bounds[:, 0], bounds[:, 1]) if clip else (-np.inf, np.inf)
    Lw, Ln = _factor(W), _factor(np.asarray(sim.sensing_cov, dtype=np.float64))
    dm = gen.standard_normal((n, p)) @ _factor(np.asarray(controller.P0)[:p, :p]).T
    xh = np.zeros((n, p))
    alive = np.ones(n, dtype=bool)
    surv = np.zeros(T + 1)
    surv[0] = n
    s1, s2 = np.zeros((T, 2 * p)), np.zeros((T, 2 * p, 2 * p))
    for t in range(T):
        us = plan.controls[t]
        ubar = np.clip(us + xh @ controller.L[t].T, lo, hi) - us
        du = np.clip(us + ubar + gen.standard_normal(ubar.shape) @ Lw.T, lo, hi) - us
        derivs = None if step == "exact" else sim.material_step_derivatives(plan.states[t], us)
        dm = _material_step(sim, plan, t, dm, du, step, derivs)
        eps = gen.standard_normal((n, 3)) @ _factor(moments.resid[t]).T
        dx = moments.offset[t] + dm @ moments.P[t][:, :p].T + eps  # the tip less x*_{t+1}
        xp = xh @ A[t].T + ubar @ B[t].T
        zbar = dx + gen.standard_normal((n, 3)) @ Ln.T
        xh = xp + (zbar - xp @ H[t].T) @ controller.K[t].T
        x = plan.reduced[t + 1][:3] + dx
        for body in _obstacles(sim, plan.states[t + 1]):
            alive &= ~body.contains(x)
        surv[t + 1] = np.count_nonzero(alive)
        if keep_moments:
            xi = np.hstack([dm, xh])
            s1[t], s2[t] = xi.sum(axis=0), xi.T @ xi
    eg = gen.standard_normal((n, 3)) @ _factor(moments.goal_resid).T
    rel = plan.reduced[T][:3] + moments.goal_offset + dm @ moments.goal_P[:, :p].T + eg
    in_goal = _goal(sim, plan.states[T]).contains(rel)
    return alive, in_goal, surv, (s1, s2) if keep_moments else None, rel
