"""LQG execution of a plan on the true simulator (deformable-planning paper, Patil, van den
Berg & Alterovitz, RSS 2011, section IV-C) and its Monte Carlo success rate (the check the
paper does not report: how good is LQG-MP's estimate?).

Controller (:func:`lqg_controller`): LQR gains ``L_t`` (:func:`~riskplan.control.lqr_gains`)
and Kalman gains ``K_t`` (:func:`~riskplan.control.kalman_gains`) of a
:class:`~riskplan.control.Linearization`. Execution (:func:`execute`), ``t = 0 .. T-1``,
starting from the simulator's start state under the drawn parameters ``s`` and ``x̂_0 = 0``::

    u_t       = clip(u*_t + L_t x̂_t, bounds)                  (open loop: u_t = u*_t)
    y_{t+1}   = g(y_t, u_t, s)                                  (actuation noise inside s)
    z_{t+1}   = h(x_{t+1}) + n_t,   n_t ~ N(0, N)               (sim.measure(y_{t+1}) or sim.observe)
    x̂⁻        = A_t x̂_t + B_t (u_t − u*_t)
    x̂_{t+1}   = x̂⁻ + K_t (z_{t+1} − h(x*_{t+1}) − H_t x̂⁻)

With the persistent-disturbance model (``lqg_controller(lin, disturbance=True)``, beyond the
paper) the estimate is ``(x̂_t, d̂_t)``, the feedback ``u_t = clip(u*_t + L_t x̂_t − d̂_t)``
and the filter runs on the augmented model (:func:`augmented_model`).

Every execution ends with one outcome (:data:`OUTCOMES`) and, for a failure, its reason:

* ``"solver_failure"``: the simulator's solve failed at a step (it did not converge, an
  element inverted, or the state it returned is not finite) — the drawn parameters made
  the model unusable there; never counted as a collision or a success;
* ``"left_tissue"``: the robot left the body it moves in (simulators with an
  ``inside(state)`` predicate, e.g. the needle's material point outside the tissue);
* ``"collision"``: a state in collision (``sim.in_collision``);
* ``"missed_goal"``: none of the above, and the goal test below fails;
* ``"success"``.

The run stops at the first failure, checked in that order at each state. Success (paper
V-A: "the goal region is reached and obstacles are avoided"), by ``goal_at``:

* ``"final"`` (default): no state ``y_1 .. y_T`` collides and ``y_T`` is in the (deformed)
  goal (``sim.in_goal``) — the event whose probability LQG-MP estimates from the final
  distribution (section IV-D);
* ``"any"``: the run stops at the first state ``y_t`` (``t ≤ T``) in the deformed goal, as
  a needle insertion stops at its target and as the RRT ends a plan at its first goal
  state; it succeeds if no state before collides.

Collisions are checked at the states, as the scenarios define them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from riskplan._validation import as_array, as_generator, check_count
from riskplan.control.kalman import kalman_gains
from riskplan.control.linearize import Linearization
from riskplan.control.lqr import lqr_gains
from riskplan.control.plan import NominalPlan
from riskplan.control.sensing import nominal_measurements, sense
from riskplan.control.ukf import execution_ukf
from riskplan.errors import (
    ConvergenceError,
    ElementInversionError,
    InvalidInputError,
    SimulationError,
)

__all__ = [
    "OUTCOMES",
    "Execution",
    "LQGController",
    "SuccessEstimate",
    "augmented_model",
    "bryson_weights",
    "execute",
    "lqg_controller",
    "monte_carlo_success",
]


def _block_diag(*blocks) -> np.ndarray:
    """The block-diagonal matrix of square ``blocks`` (``None`` skipped)."""
    blocks = [np.asarray(b, dtype=np.float64) for b in blocks if b is not None]
    n = sum(b.shape[0] for b in blocks)
    out = np.zeros((n, n))
    k = 0
    for b in blocks:
        out[k : k + b.shape[0], k : k + b.shape[0]] = b
        k += b.shape[0]
    return out


def augmented_model(lin: Linearization):
    r"""The linear model of the state ``(x̄_t, d)`` with a constant input disturbance
    ``d (q,)`` (beyond the paper; needs ``lin.disturbance``,
    ``linearize(..., disturbance=True)``):

    .. math::

        \begin{bmatrix} \bar x_{t+1} \\ d \end{bmatrix} =
        \begin{bmatrix} A_t & B_t \\ 0 & I \end{bmatrix}
        \begin{bmatrix} \bar x_t \\ d \end{bmatrix} +
        \begin{bmatrix} B_t \\ 0 \end{bmatrix} \bar u_t +
        \begin{bmatrix} m^r_t \\ 0 \end{bmatrix}, \qquad
        \bar z_{t+1} = [H_t \;\; 0] \begin{bmatrix} \bar x_{t+1} \\ d \end{bmatrix} + n_t,

    with :math:`m^r_t \sim N(0, M^r_t)`.

    With a persistent measurement bias in the model (``lin.disturbance.C (T, m, r)``,
    :func:`~riskplan.control.linearize.fit_measurement_bias`) the state is
    ``(x̄_t, d, e)`` of dimension ``p + q + r``, ``e`` constant too, and
    :math:`\bar z_{t+1} = H_t \bar x_{t+1} + C_t e + n_t`, :math:`n_t \sim N(0, N^r_t)`
    (``H = [H_t, 0, C_t]``, ``N = N^r_t``).

    Parameters
    ----------
    lin : Linearization
        A linearisation with its ``disturbance`` model.

    Returns
    -------
    tuple of numpy.ndarray
        ``(A (T, n, n), B (T, n, q), H (T, m, n), M (T, n, n), N (T, m, m))``, ``n = p + q``
        (``p + q + r`` with a measurement bias), with ``M = diag(M^r_t, 0)``: ``d`` does not
        change during an execution.
    """
    if lin.disturbance is None:
        raise InvalidInputError("lin: has no disturbance model; linearize it with disturbance=True")
    T, p, q = lin.B.shape
    m = lin.H.shape[1]
    dist = lin.disturbance
    r = dist.n_bias
    n = p + q + r
    A = np.zeros((T, n, n))
    A[:, :p, :p] = lin.A
    A[:, :p, p : p + q] = lin.B
    A[:, p:, p:] = np.eye(q + r)
    B = np.zeros((T, n, q))
    B[:, :p] = lin.B
    H = np.zeros((T, m, n))
    H[:, :, :p] = lin.H
    M = np.zeros((T, n, n))
    M[:, :p, :p] = dist.M
    if r:
        H[:, :, p + q :] = dist.C
        return A, B, H, M, np.asarray(dist.N)
    return A, B, H, M, np.asarray(lin.N)


@dataclass(frozen=True, eq=False)
class LQGController:
    """Gains of the LQG controller of one plan.

    ``L (T, q, n)`` feedback (``u_t = u*_t + L_t ξ̂_t``), ``K (T, n, m)`` Kalman gains,
    ``P (T, n, n)`` posterior estimate covariances (``P[t]`` of ``ξ̂_{t+1}``), ``P0 (n, n)``,
    and the :class:`Linearization` they were computed from. The estimated state ``ξ̂`` is
    ``x̂`` (``n = p``, the paper's) or, with ``disturbance=True``, ``(x̂, d̂)``
    (``n = p + q``, :func:`augmented_model`).
    """

    L: np.ndarray
    K: np.ndarray
    P: np.ndarray
    P0: np.ndarray
    lin: Linearization
    disturbance: bool = False

    @property
    def n_steps(self) -> int:
        return int(self.L.shape[0])

    def model(self):
        """``(A, B, H, M, N)`` of the model the filter and LQG-MP use: the linearisation's
        (paper) or :func:`augmented_model` (``disturbance=True``)."""
        if self.disturbance:
            return augmented_model(self.lin)
        lin = self.lin
        return lin.A, lin.B, lin.H, lin.M, lin.N


def bryson_weights(state_scale, control_scale) -> tuple[np.ndarray, np.ndarray]:
    """Bryson's rule (Bryson & Ho, *Applied Optimal Control*, 1975, section 5.4).

    ``Q = diag(1 / x_max²)`` and ``R = diag(1 / u_max²)``, so every term of the LQR cost is
    dimensionless and a deviation of one "acceptable" unit costs 1 in any component.

    Parameters
    ----------
    state_scale : array_like
        ``x_max (p,)``, the acceptable deviation of each state component (> 0).
    control_scale : array_like
        ``u_max (q,)``, the acceptable deviation of each control component (> 0).

    Returns
    -------
    Q : numpy.ndarray
        ``(p, p)`` diagonal state cost.
    R : numpy.ndarray
        ``(q, q)`` diagonal control cost.
    """
    xs = as_array(state_scale, "state_scale", shape=(None,))
    us = as_array(control_scale, "control_scale", shape=(None,))
    for name, v in (("state_scale", xs), ("control_scale", us)):
        if not np.all(v > 0):
            raise InvalidInputError(f"{name}: expected positive values, got {v}")
    return np.diag(1.0 / xs**2), np.diag(1.0 / us**2)


def lqg_controller(
    lin: Linearization, Q=None, R=None, Q_final=None, P0=None, *, disturbance: bool = False
) -> LQGController:
    r"""LQR + Kalman gains for ``lin`` (paper IV-C).

    Defaults (explicit ``Q``/``R`` override them): Bryson's rule (:func:`bryson_weights`),
    ``Q = diag(1 / lin.state_scale²)`` and ``R = diag(1 / lin.control_scale²)``, the
    scales the simulator declares (:func:`~riskplan.control.linearize` copies
    ``sim.state_scale`` and the control half-ranges); a component without a declared
    scale gets weight 1 (``Q = I``/``R = I``, the identity costs of van den Berg, Abbeel &
    Goldberg, IJRR 2011, section VII). ``Q_final = Q``, ``P0 = 0`` (the start state is known).

    ``disturbance=True`` (beyond the paper; needs ``linearize(..., disturbance=True)``):
    the state is ``(x̄, d)`` with the constant input disturbance ``d ~ N(0, Σ_d)``
    (:func:`augmented_model`). ``d`` cannot be steered, so the LQR cost is put on what the
    plant receives, ``v_t = ū_t + d``:

    .. math::

        J = \sum_{t<T} (\bar x_t^\top Q \bar x_t + v_t^\top R v_t) + \bar x_T^\top Q_{final}
        \bar x_T, \qquad \bar x_{t+1} = A_t \bar x_t + B_t v_t,

    which is the plain LQR in ``(x̄, v)``: ``v_t = L_t x̄_t``, so ``ū_t = L_t x̄_t − d`` and
    the augmented gain is ``[L_t, −I]`` (the plain gain plus a feed-forward cancelling
    ``B_t d``). The Kalman filter estimates ``(x̄, d)`` on the augmented model from
    ``P0 = diag(P0, Σ_d)`` with the residual process noise ``M^r_t``.

    Parameters
    ----------
    lin : Linearization
        ``A (T, p, p)``, ``B (T, p, q)``, ``M``, ``H``, ``N`` of the plan.
    Q, R, Q_final : array_like, optional
        LQR costs (:func:`~riskplan.control.lqr_gains`); defaults above.
    P0 : array_like, optional
        ``(p, p)`` covariance of the initial estimate (default 0).
    disturbance : bool
        Estimate and cancel a constant input disturbance (beyond the paper).

    Returns
    -------
    LQGController
        Gains ``L``, ``K``, covariances ``P`` and the linearisation.
    """
    if not isinstance(lin, Linearization):
        raise InvalidInputError(f"lin: expected a Linearization, got {type(lin).__name__}")
    if disturbance and lin.disturbance is None:
        raise InvalidInputError(
            "disturbance=True: lin has no disturbance model; linearize it with disturbance=True"
        )
    _T, p, q = lin.B.shape
    if Q is None:
        Q = np.eye(p) if lin.state_scale is None else bryson_weights(lin.state_scale, np.ones(1))[0]
    if R is None:
        R = (
            np.eye(q)
            if lin.control_scale is None
            else bryson_weights(np.ones(1), lin.control_scale)[1]
        )
    Q_final = Q if Q_final is None else Q_final
    P0 = np.zeros((p, p)) if P0 is None else as_array(P0, "P0", shape=(p, p))
    L = lqr_gains(lin.A, lin.B, Q, R, Q_final)
    if not disturbance:
        K, P = kalman_gains(lin.A, lin.H, lin.M, lin.N, P0)
        return LQGController(L=L, K=K, P=P, P0=P0, lin=lin)
    T = L.shape[0]
    r = lin.disturbance.n_bias
    # the bias e moves only the measurement: no feedback on it (its gain is 0)
    L = np.concatenate([L, np.broadcast_to(-np.eye(q), (T, q, q)), np.zeros((T, q, r))], axis=2)
    A, _B, H, M, N = augmented_model(lin)
    P0 = _block_diag(P0, lin.disturbance.cov, lin.disturbance.bias_cov)
    K, P = kalman_gains(A, H, M, N, P0)
    return LQGController(L=L, K=K, P=P, P0=P0, lin=lin, disturbance=True)


#: The outcomes of an execution (module docstring), in the order they are checked.
OUTCOMES = ("success", "solver_failure", "left_tissue", "collision", "missed_goal")


@dataclass(frozen=True, eq=False)
class Execution:
    """One execution. ``states``: simulator states ``y_0 ..`` up to the last one reached;
    ``x (k, p)`` their reduced states, ``estimates (k, p)`` the filter's ``x*_t + x̂_t``,
    ``controls (k − 1, q)`` applied (before actuation noise); ``collided``, ``reached_goal``,
    ``success``; ``failed_step`` the step that collided, left the body or whose solve
    failed (``None`` otherwise), ``error`` the solver's message if one failed, ``outcome``
    one of :data:`OUTCOMES` and ``reason`` a sentence saying why a run failed (``None``
    on success); ``disturbance (k, q)`` the filter's ``d̂_t`` with a disturbance-state
    controller (``None`` otherwise)."""

    states: tuple
    x: np.ndarray
    estimates: np.ndarray
    controls: np.ndarray
    collided: bool
    reached_goal: bool
    failed_step: int | None = None
    error: str | None = None
    outcome: str = "success"
    reason: str | None = None
    disturbance: np.ndarray | None = None

    @property
    def success(self) -> bool:
        return self.outcome == "success"

    @property
    def left_tissue(self) -> bool:
        return self.outcome == "left_tissue"


GOAL_AT = ("final", "any")


def _check_goal_at(goal_at: str) -> None:
    if goal_at not in GOAL_AT:
        raise InvalidInputError(f"goal_at: expected one of {GOAL_AT}, got {goal_at!r}")


def _reason(outcome: str, failed, error, goal_at: str):
    """The reason an execution's ``outcome`` names (``None`` for a success)."""
    return {
        "success": None,
        "solver_failure": error,
        "left_tissue": f"left the body at step {failed}",
        "collision": f"collision at step {failed}",
        "missed_goal": "not in the goal at the end" if goal_at == "final" else "never in the goal",
    }[outcome]


def execute(
    sim,
    plan: NominalPlan,
    controller: LQGController | None,
    params,
    *,
    seed=None,
    keep_states: bool = True,
    goal_at: str = "final",
    estimator: str = "kalman",
) -> Execution:
    """Run ``plan`` on ``sim`` under the true parameters ``params`` (module docstring).

    ``controller=None`` executes open loop (``u_t = u*_t``, no filter). A solve that fails
    (:class:`~riskplan.errors.ConvergenceError`,
    :class:`~riskplan.errors.ElementInversionError`,
    :class:`~riskplan.errors.SimulationError`) or returns a non-finite state ends the run
    with the outcome ``"solver_failure"`` and a reason naming the step.

    Parameters
    ----------
    sim : Simulator
        The true simulator.
    plan : NominalPlan
        The plan executed.
    controller : LQGController or None
        Closed loop with these gains, open loop with ``None``.
    params : SimParams
        The true parameters ``s`` of this execution.
    seed : int, numpy.random.Generator or None
        Seeds the sensing noise.
    keep_states : bool
        Keep every simulator state in the result (``False`` saves memory).
    goal_at : {"final", "any"}
        When the goal counts: at the plan's last step, or at any step.
    estimator : {"kalman", "ukf"}
        The filter: the precomputed Kalman gains, or :func:`~riskplan.control.ukf.execution_ukf`.

    Returns
    -------
    Execution
        States, estimates, applied controls and the outcome.
    """
    _check_goal_at(goal_at)
    if estimator not in ("kalman", "ukf"):
        raise InvalidInputError(f"estimator: expected 'kalman' or 'ukf', got {estimator!r}")
    gen = as_generator(seed)
    T = plan.n_steps
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    lo, hi = bounds[:, 0], bounds[:, 1]
    closed = controller is not None
    if closed and controller.n_steps != T:
        raise InvalidInputError(f"controller: has {controller.n_steps} steps, plan has {T}")
    p = plan.reduced.shape[1]
    y = sim.initial_state(params)
    states = [y]
    xs = [np.asarray(sim.reduced(y), dtype=np.float64)]
    est = [plan.reduced[0].copy()]
    dist = [np.zeros(sim.control_dim)]
    us = []
    xhat = np.zeros(p)
    augmented = closed and controller.disturbance
    if closed:
        L, K = controller.L, controller.K
        A, B, H = controller.model()[:3]
        xhat = np.zeros(A.shape[1])
        # a simulator whose measurement needs the full state (``measure(state, noise,
        # rng)``: the needle in its material frame) is sensed through it
        measure = getattr(sim, "measure", None)
        z_nominal = nominal_measurements(sim, plan, measure)
        ukf = execution_ukf(sim, plan, controller) if estimator == "ukf" else None
    collided, failed, error, outcome = False, None, None, None
    inside = getattr(sim, "inside", None)
    for t in range(T):
        if closed:
            u = np.minimum(np.maximum(plan.controls[t] + L[t] @ xhat, lo), hi)
        else:
            u = plan.controls[t]
        try:
            y = sim.step(y, u, params)
        except (ConvergenceError, ElementInversionError, SimulationError) as exc:
            failed, error, outcome = t, f"step {t}: {exc}", "solver_failure"
            break
        x = np.asarray(sim.reduced(y), dtype=np.float64)
        if not np.all(np.isfinite(x)):
            failed, error, outcome = t, f"step {t}: non-finite reduced state", "solver_failure"
            break
        us.append(u)
        if keep_states:
            states.append(y)
        xs.append(x)
        if closed:
            zbar, ubar = sense(sim, measure, y, x, gen) - z_nominal[t], u - plan.controls[t]
            if ukf is not None:
                xhat = ukf(t, xhat, ubar, zbar)
            else:
                xp = A[t] @ xhat + B[t] @ ubar
                xhat = xp + K[t] @ (zbar - H[t] @ xp)
        est.append(plan.reduced[t + 1] + xhat[:p])
        if augmented:
            dist.append(xhat[p : p + sim.control_dim].copy())
        if inside is not None and not inside(y):
            failed, outcome = t + 1, "left_tissue"
            break
        if sim.in_collision(y):
            collided, failed, outcome = True, t + 1, "collision"
            break
        if goal_at == "any" and sim.in_goal(y):
            break
    reached = outcome is None and (goal_at == "any" or len(xs) == T + 1) and bool(sim.in_goal(y))
    if outcome is None:
        outcome = "success" if reached else "missed_goal"
    reason = _reason(outcome, failed, error, goal_at)
    if not keep_states:
        states = [states[0], y]
    return Execution(
        states=tuple(states),
        x=np.stack(xs),
        estimates=np.stack(est),
        controls=np.array(us).reshape(len(us), sim.control_dim),
        collided=collided,
        reached_goal=reached,
        failed_step=failed,
        error=error,
        outcome=outcome,
        reason=reason,
        disturbance=np.stack(dist) if augmented else None,
    )


@dataclass(frozen=True, eq=False)
class SuccessEstimate:
    """Monte Carlo success rate: ``successes`` of ``n`` runs, ``probability``, the 95 %
    Wilson interval ``[low, high]``, per-run flags ``success``, ``collided``,
    ``reached_goal``, ``solver_failed``, ``left_tissue`` (``(n,)`` bool), ``outcomes`` the
    count of each of :data:`OUTCOMES`, and ``solver_errors`` the reasons of the solver
    failures (one per failed run, in run order)."""

    successes: int
    n: int
    probability: float
    low: float
    high: float
    success: np.ndarray
    collided: np.ndarray
    reached_goal: np.ndarray
    solver_failed: np.ndarray
    left_tissue: np.ndarray | None = None
    outcomes: dict | None = None
    solver_errors: tuple = ()


def _draw(distribution, sim, gen):
    if distribution is None:
        return sim.nominal_params
    return distribution.sample(gen)


def _run_batch(sim, plan, controller, distribution, goal_at, seeds):
    out = []
    for s in seeds:
        gen = np.random.default_rng(s)
        params = _draw(distribution, sim, gen)
        ex = execute(sim, plan, controller, params, seed=gen, keep_states=False, goal_at=goal_at)
        out.append((ex.outcome, ex.reached_goal, ex.error))
    return out


def monte_carlo_success(
    sim,
    plan: NominalPlan,
    controller: LQGController | None,
    distribution=None,
    *,
    n: int = 1000,
    seed=None,
    confidence: float = 0.95,
    backend: str = "serial",
    workers: int | None = None,
    goal_at: str = "final",
) -> SuccessEstimate:
    """Success rate of ``n`` executions of ``plan``, with a Wilson interval
    (:func:`riskplan.collision.binomial_interval`).

    Run ``i`` draws its parameters and noise from ``spawn_seeds(seed, n)[i]``, so the result
    does not depend on ``backend`` (:func:`riskplan.parallel.map_tasks`) or ``workers``.

    Parameters
    ----------
    sim, plan, controller
        As in :func:`execute`, for every run.
    distribution : object with ``sample(gen)``, ``"nominal"`` or None
        Each run's ``s ~ distribution``. ``None``: ``sim.distribution``, the rule of
        :func:`riskplan.control.linearize` and the plan selection (and every run on
        ``sim.nominal_params`` when the simulator has none). ``"nominal"``: every run on
        ``sim.nominal_params`` (only the sensing noise differs).
    n : int
        Number of executions.
    seed : int, numpy.random.Generator or None
        Root of the runs' seeds.
    confidence : float
        Level of the interval.
    backend, workers
        As in :func:`riskplan.parallel.map_tasks`.
    goal_at : {"final", "any"}
        When the goal counts (:func:`execute`).

    Returns
    -------
    SuccessEstimate
        Successes, probability, interval, per-run outcomes.
    """
    from riskplan.collision import binomial_interval
    from riskplan.parallel import chunk_count, map_tasks, spawn_seeds

    n = check_count(n, "n", 1, integral=True)
    _check_goal_at(goal_at)
    if isinstance(distribution, str):
        if distribution != "nominal":
            raise InvalidInputError(
                f"distribution: expected a distribution, 'nominal' or None, got {distribution!r}"
            )
        distribution = None
    elif distribution is None:
        distribution = getattr(sim, "distribution", None)
    if isinstance(seed, np.random.Generator):
        seed = int(seed.integers(2**63))
    seeds = spawn_seeds(seed, n)
    n_chunks = chunk_count(n, backend, workers)
    chunks = [seeds[k::n_chunks] for k in range(n_chunks)]
    results = map_tasks(
        partial(_run_batch, sim, plan, controller, distribution, goal_at),
        chunks,
        backend=backend,
        workers=workers,
        chunksize=1,
    )
    rows = [None] * n
    for k, res in enumerate(results):
        rows[k::n_chunks] = res
    outcome = np.array([r[0] for r in rows])
    hits = int((outcome == "success").sum())
    lo, hi = binomial_interval(hits, n, confidence=confidence)
    return SuccessEstimate(
        successes=hits,
        n=n,
        probability=hits / n,
        low=float(lo),
        high=float(hi),
        success=outcome == "success",
        collided=outcome == "collision",
        reached_goal=np.array([bool(r[1]) for r in rows]),
        solver_failed=outcome == "solver_failure",
        left_tissue=outcome == "left_tissue",
        outcomes={o: int((outcome == o).sum()) for o in OUTCOMES},
        solver_errors=tuple(r[2] for r in rows if r[0] == "solver_failure"),
    )
