r"""Iterative LQR around a nominal plan (Li & Todorov, ICINCO 2004; Tassa, Erez & Todorov,
IROS 2012 for the regularisation and line search), on the simulator's numerical
linearisation (:func:`~riskplan.control.linearize`); beyond the deformable-planning paper,
whose nominal plan is the RRT's and is only tracked.

Cost of the controls ``u_0 .. u_{T-1}`` rolled out on the simulator (nominal parameters)
from the plan's start, with the plan ``(x*, u*)`` as reference and a goal ``g``::

    J = Σ_{t<T} (x_t − x*_t)ᵀ Q (x_t − x*_t) + (u_t − u*_t)ᵀ R (u_t − u*_t)
        + (x_T − x*_T)ᵀ Q_final (x_T − x*_T) + (x_T − g)ᵀ Q_goal (x_T − g)
        + Σ_{1≤t≤T} Σ_j Σ_{O ∈ 𝒪_t} w exp(−d_O(P_j x_t) / δ)

.. math::

    J(u) = \sum_{t<T} \bigl(\|x_t - x^*_t\|_Q^2 + \|u_t - u^*_t\|_R^2\bigr)
        + \|x_T - x^*_T\|_{Q_f}^2 + \|x_T - g\|_{Q_g}^2
        + \sum_{t=1}^{T} \sum_j \sum_{O \in \mathcal{O}_t} w\, e^{-d_O(P_j x_t)/\delta}

The last term is the obstacle barrier (optional, ``obstacles``): ``P_j x_t`` the ``j``-th
2-D collision point of the reduced state (``points``, the scenario's
``collision_point_indices``), ``𝒪_t`` the obstacle polygons of step ``t`` in the reduced
state's coordinates (the reference plan's: held fixed while iterating, as LQG-MP reads them
at ``y*_t``), ``d_O`` the signed distance to polygon ``O`` (negative inside), ``w`` the
weight and ``δ`` the length over which it decays (``obstacle_barrier``). Its gradient is
``φ'(d) n`` with ``n = ∇d`` the unit normal from the nearest boundary point and
``φ'(d) = −φ(d)/δ``; its Hessian is taken in the Gauss–Newton form ``φ''(d) n nᵀ``
(``φ'' = φ/δ² ≥ 0``, so ``Q_xx`` stays positive semi-definite), which omits
``φ'(d) ∇²d = φ'(d) (I − n nᵀ)/|P_j x_t − c|`` where the nearest boundary point ``c`` is a
vertex (zero along an edge; negative semi-definite since ``φ' < 0``). The goal enters as
the terminal ``(x_T − g)ᵀ Q_goal (x_T − g)`` (``scenario_terms`` (:mod:`riskplan.control.ilqr_cost`) builds ``g``,
``Q_goal`` and the obstacles from a scenario). Against 3-D convex bodies (the 3-D needle's
deformed ellipsoids and parallelepipeds) the same term uses the exact Euclidean signed
distance of :mod:`riskplan.control.ilqr_cost3d`.

The expected cost under the linearised noise, ``x_{t+1} = A_t x_t + B_t u_t + m_t``,
``m_t ~ N(0, M_t)``, adds ``Σ_t tr(S_{t+1} M_t)``; with ``M_t`` held at the plan's (not
re-fitted along each iterate) that term does not depend on the controls, so minimising
``J`` minimises the expected cost of this model (iLQG with additive noise).

Iteration ``i``: linearise about the current trajectory ``(x̄, ū)`` (``A_t``, ``B_t``),
backward pass (``V_x``, ``V_xx`` from ``T``, where they are the terminal terms' gradient and Hessian plus
the barrier's ``b_x``, ``b_xx``; ``μ`` the Levenberg–Marquardt regularisation)::

    Q_u = R (ū_t − u*_t) + B_tᵀ V_x,    Q_x = Q (x̄_t − x*_t) + b_x(x̄_t) + A_tᵀ V_x
    Q_uu = R + B_tᵀ V_xx B_t + μ I,    Q_ux = B_tᵀ V_xx A_t,    Q_xx = Q + b_xx(x̄_t) + A_tᵀ V_xx A_t
    k_t = −Q_uu⁻¹ Q_u,   K_t = −Q_uu⁻¹ Q_ux
    V_x ← Q_x + K_tᵀ Q_uu k_t + K_tᵀ Q_u + Q_uxᵀ k_t,   V_xx ← Q_xx + K_tᵀ Q_uu K_t + K_tᵀ Q_ux + Q_uxᵀ K_t

forward pass with line search ``α ∈ {1, ½, ¼, …}``:
``u_t = clip(ū_t + α k_t + K_t (x_t − x̄_t))`` rolled out on the simulator; the first ``α``
that lowers ``J`` is accepted (``μ`` shrinks), none raises ``μ ×10``. It stops when the
relative decrease is below ``tol`` or after ``max_iter`` iterations. The cost therefore
never increases from one accepted iterate to the next (the property the tests check).

On a linear system with quadratic cost the backward pass is exact, so one iteration with
``α = 1`` reaches the optimum and ``K_t`` equals :func:`~riskplan.control.lqr_gains` with
``Q_final + Q_goal`` (the tests' oracle, against the least-squares solution of the
stacked problem as well).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan.control.ilqr_cost import BARRIER_SCALE, BARRIER_WEIGHT, _make_barrier
from riskplan.control.plan import NominalPlan
from riskplan.errors import ConvergenceError, InvalidInputError, SimulationError

__all__ = ["ILQRResult", "ilqr", "tracking_controller"]

#: Regularisation at which the search gives up on a descent step: the iterate is then a
#: local minimum of ``J`` to the model's accuracy.
MU_MAX = 1e4


@dataclass(frozen=True, eq=False)
class ILQRResult:
    """Result of :func:`ilqr`: the re-optimised ``plan``, the feedback ``K (T, q, p)`` of
    the last backward pass (``u_t = u_t + K_t (x_t − x̄_t)``), ``costs`` the cost of every
    accepted iterate (``costs[0]`` the input plan's), ``iterations``, ``converged``, and
    ``n_linearizations`` (the extra computation: one simulator linearisation each)."""

    plan: NominalPlan
    K: np.ndarray
    costs: np.ndarray
    iterations: int
    converged: bool
    n_linearizations: int


def _cost(x, u, ref, Q, R, Qf, goal, Qg, barrier=None):
    dx, du = x[:-1] - ref.reduced[:-1], u - ref.controls
    e, g = x[-1] - ref.reduced[-1], x[-1] - goal
    b = 0.0 if barrier is None else barrier.terms(x, derivatives=False)
    return float(
        np.einsum("ti,ij,tj->", dx, Q, dx)
        + np.einsum("ti,ij,tj->", du, R, du)
        + e @ Qf @ e
        + g @ Qg @ g
        + b
    )


def _backward(A, B, x, u, ref, Q, R, Qf, goal, Qg, mu, bx, bxx):
    T, p, q = B.shape
    Vx = Qf @ (x[-1] - ref.reduced[-1]) + Qg @ (x[-1] - goal) + bx[-1]
    Vxx = Qf + Qg + bxx[-1]
    k = np.empty((T, q))
    K = np.empty((T, q, p))
    for t in range(T - 1, -1, -1):
        At, Bt = A[t], B[t]
        Qu = R @ (u[t] - ref.controls[t]) + Bt.T @ Vx
        Qx = Q @ (x[t] - ref.reduced[t]) + bx[t] + At.T @ Vx
        Quu = R + Bt.T @ Vxx @ Bt
        Qux = Bt.T @ Vxx @ At
        Qxx = Q + bxx[t] + At.T @ Vxx @ At
        try:
            np.linalg.cholesky(Quu + mu * np.eye(q))
        except np.linalg.LinAlgError:
            return None
        sol = -np.linalg.solve(Quu + mu * np.eye(q), np.column_stack([Qu, Qux]))
        k[t], K[t] = sol[:, 0], sol[:, 1:]
        Vx = Qx + K[t].T @ Quu @ k[t] + K[t].T @ Qu + Qux.T @ k[t]
        Vxx = Qxx + K[t].T @ Quu @ K[t] + K[t].T @ Qux + Qux.T @ K[t]
        Vxx = 0.5 * (Vxx + Vxx.T)
    return k, K


def _rollout(sim, plan, x, u, k, K, alpha, lo, hi):
    y = plan.states[0]
    states, xs, us = [y], [np.asarray(sim.reduced(y), dtype=np.float64)], np.empty_like(u)
    for t in range(u.shape[0]):
        us[t] = np.clip(u[t] + alpha * k[t] + K[t] @ (xs[t] - x[t]), lo, hi)
        y = sim.step(y, us[t], plan.params)
        xt = np.asarray(sim.reduced(y), dtype=np.float64)
        if not np.all(np.isfinite(xt)):
            raise SimulationError(f"step {t}: non-finite reduced state")
        states.append(y)
        xs.append(xt)
    return NominalPlan(states=tuple(states), controls=us, reduced=np.stack(xs), params=plan.params)


def _nominal_linearizer(sim):
    """``A_t``, ``B_t`` of :func:`~riskplan.control.linearize` on a plan's own parameters."""
    from riskplan.control.linearize import linearize

    def lin(pl):
        res = linearize(sim, pl, [pl.params], seed=0)
        return res.A, res.B

    return lin


def _search(sim, cur, A, B, weights, bterms, cost, c_prev, mu, lo, hi):
    """One iteration's backward passes and line searches (module docstring): the first
    ``(candidate, its cost, K, μ)`` that lowers the cost below ``c_prev``, raising ``μ``
    ×10 until one does; ``(None, None, K, μ)`` once ``μ`` reaches :data:`MU_MAX`."""
    x, u = np.asarray(cur.reduced), np.asarray(cur.controls)
    T, q = u.shape
    K = np.zeros((T, q, x.shape[1]))
    while mu < MU_MAX:
        bw = _backward(A, B, x, u, *weights, mu, *bterms)
        if bw is None:
            mu *= 10.0
            continue
        k, K = bw
        for alpha in 0.5 ** np.arange(6):
            try:
                cand = _rollout(sim, cur, x, u, k, K, alpha, lo, hi)
            except (ConvergenceError, SimulationError):
                continue
            c = cost(cand)
            if c < c_prev:
                return cand, c, K, max(mu / 10.0, 1e-12)
        mu *= 10.0
    return None, None, K, mu


def ilqr(
    sim,
    plan: NominalPlan,
    Q,
    R,
    Q_final=None,
    goal=None,
    Q_goal=None,
    *,
    linearizer=None,
    max_iter: int = 10,
    tol: float = 1e-4,
    mu0: float = 1e-6,
    obstacles=None,
    points=((0, 1),),
    body=None,
    barrier_weight: float = BARRIER_WEIGHT,
    barrier_scale: float = BARRIER_SCALE,
) -> ILQRResult:
    """Re-optimise ``plan`` by iLQR on the simulator (module docstring).

    Parameters
    ----------
    sim : Simulator
        Rolled out under ``plan.params``.
    plan : NominalPlan
        The reference ``(x*, u*)`` and the first iterate.
    Q : array_like
        ``(p, p)`` state cost about ``x*``.
    R : array_like
        ``(q, q)`` control cost about ``u*``, positive definite.
    Q_final : array_like, optional
        ``(p, p)`` final cost about ``x*_T`` (default ``Q``).
    goal : array_like, optional
        ``(p,)`` goal ``g`` (default ``x*_T``).
    Q_goal : array_like, optional
        ``(p, p)`` goal cost (default zero).
    linearizer : callable, optional
        ``linearizer(plan) -> (A (T, p, p), B (T, p, q))``; default the ``A``, ``B`` of
        :func:`~riskplan.control.linearize` on the nominal parameters.
    max_iter : int
        Most iterations.
    tol : float
        Relative cost decrease that counts as converged.
    mu0 : float
        Initial regularisation ``μ``.
    obstacles : sequence, optional
        ``T + 1`` lists of obstacle polygons ``(m, 2)`` in the reduced state's coordinates,
        one per step (entry 0 unused): the barrier term (default none). Lists of 3-D
        :class:`~riskplan.geometry3d.ConvexBody` (ellipsoids, parallelepipeds) give the
        3-D barrier of :mod:`riskplan.control.ilqr_cost3d`.
    points : array_like
        ``(k, 2)`` indices of the reduced state's 2-D collision points (default ``x[:2]``;
        ``(k, 3)`` against 3-D bodies).
    body : sequence, optional
        ``T + 1`` pairs ``(base (n, 2), W (n, k))`` (``(n, 3)`` in 3-D): the points checked at step ``t`` are
        ``base + W (x_t[points] − x*_t[points])`` (a body wider than its collision points,
        e.g. :func:`~riskplan.control.lqgmp.body_points`' outline); default the collision
        points themselves.
    barrier_weight : float
        ``w`` of the barrier.
    barrier_scale : float
        ``δ`` of the barrier (length units of the points).

    Returns
    -------
    ILQRResult
        Plan, feedback, cost history, iterations, convergence flag.
    """
    if not isinstance(plan, NominalPlan):
        raise InvalidInputError(f"plan: expected a NominalPlan, got {type(plan).__name__}")
    T, q = plan.controls.shape
    p = plan.reduced.shape[1]
    Q = np.asarray(Q, dtype=np.float64).reshape(p, p)
    R = np.asarray(R, dtype=np.float64).reshape(q, q)
    Qf = Q if Q_final is None else np.asarray(Q_final, dtype=np.float64).reshape(p, p)
    Qg = np.zeros((p, p)) if Q_goal is None else np.asarray(Q_goal, dtype=np.float64).reshape(p, p)
    goal = plan.reduced[-1] if goal is None else np.asarray(goal, dtype=np.float64).reshape(p)
    linearizer = linearizer or _nominal_linearizer(sim)
    barrier = None
    if obstacles is not None:
        barrier = _make_barrier(plan, obstacles, points, body, barrier_weight, barrier_scale)

    def terms(x):  # the barrier's gradient and Hessian along x
        return barrier.terms(x)[1:] if barrier else (np.zeros((T + 1, p)), np.zeros((T + 1, p, p)))

    def cost(pl):
        return _cost(pl.reduced, pl.controls, ref, Q, R, Qf, goal, Qg, barrier)

    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    lo, hi = bounds[:, 0], bounds[:, 1]
    ref, cur = plan, plan
    costs = [cost(cur)]
    mu, converged, n_lin, K = mu0, False, 0, np.zeros((T, q, p))
    for _ in range(max_iter):
        A, B = linearizer(cur)
        n_lin += 1
        x = np.asarray(cur.reduced)
        cand, c, K, mu = _search(
            sim, cur, A, B, (ref, Q, R, Qf, goal, Qg), terms(x), cost, costs[-1], mu, lo, hi
        )
        if cand is None:
            converged = True  # no descent direction left at any regularisation
            break
        cur = cand
        costs.append(c)
        if costs[-2] - c <= tol * max(costs[-2], 1e-300):
            converged = True
            break
    return ILQRResult(
        plan=cur,
        K=K,
        costs=np.array(costs),
        iterations=n_lin,
        converged=converged,
        n_linearizations=n_lin,
    )


def tracking_controller(
    sim,
    plan: NominalPlan,
    distribution=None,
    *,
    controller: str = "lqr",
    goal=None,
    Q_goal=None,
    terms=None,
    max_iter: int = 5,
    n_samples: int = 16,
    seed=0,
):
    """The plan to execute and its LQG gains: the plan as given (``"lqr"``, the paper's) or
    re-optimised by :func:`ilqr` first (``"ilqr"``) with the default Bryson weights of
    :func:`~riskplan.control.lqg_controller`, then linearised under ``distribution``.

    Parameters
    ----------
    sim : Simulator
        The simulator.
    plan : NominalPlan
        The (RRT) plan.
    distribution : object, optional
        Parameter distribution for ``M_t`` (:func:`~riskplan.control.linearize`).
    controller : {"lqr", "ilqr"}
        Track the plan, or re-optimise it first.
    goal, Q_goal : array_like, optional
        The goal term of :func:`ilqr`.
    terms : dict, optional
        More keyword arguments of :func:`ilqr` (the goal and obstacle terms of
        ``scenario_terms`` (:mod:`riskplan.control.ilqr_cost`); they take precedence over ``goal``, ``Q_goal``).
    max_iter : int
        iLQR iterations at most.
    n_samples : int
        Parameter draws of the linearisation.
    seed : int
        Seed of the linearisation.

    Returns
    -------
    plan : NominalPlan
        The plan executed.
    lqg : LQGController
        Its gains.
    info : ILQRResult or None
        The iLQR result (``None`` for ``"lqr"``).
    """
    from riskplan.control.linearize import linearize
    from riskplan.control.lqg import bryson_weights, lqg_controller

    if controller not in ("lqr", "ilqr"):
        raise InvalidInputError(f"controller: expected 'lqr' or 'ilqr', got {controller!r}")
    info = None
    if controller == "ilqr":
        lin0 = linearize(sim, plan, [plan.params], seed=seed)  # only for the scales
        p, q = plan.reduced.shape[1], plan.controls.shape[1]
        Q = (
            np.eye(p)
            if lin0.state_scale is None
            else bryson_weights(lin0.state_scale, np.ones(1))[0]
        )
        R = (
            np.eye(q)
            if lin0.control_scale is None
            else bryson_weights(np.ones(1), lin0.control_scale)[1]
        )
        kw = {"goal": goal, "Q_goal": Q_goal, **(terms or {})}
        info = ilqr(sim, plan, Q, R, max_iter=max_iter, **kw)
        plan = info.plan
    lin = linearize(sim, plan, distribution, n_samples=n_samples, seed=seed)
    return plan, lqg_controller(lin), info
