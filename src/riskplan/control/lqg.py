"""LQG execution of a plan on the true simulator (deformable-planning paper, Patil, van den
Berg & Alterovitz, RSS 2011, section IV-C) and its Monte Carlo success rate (the check the
paper does not report: how good is LQG-MP's estimate?).

Controller (:func:`lqg_controller`, designed in :mod:`riskplan.control.lqg_gains`): LQR
gains ``L_t`` (:func:`~riskplan.control.lqr_gains`) and Kalman gains ``K_t``
(:func:`~riskplan.control.kalman_gains`) of a :class:`~riskplan.control.Linearization`. Execution (:func:`execute`), ``t = 0 .. T-1``,
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

from riskplan._validation import as_generator, check_count
from riskplan.control.lqg_gains import (
    LQGController,
    augmented_model,
    bryson_weights,
    lqg_controller,
)
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
    augmented = closed and controller.disturbance
    loop = _ClosedLoop(sim, plan, controller, estimator) if closed else None
    xhat = loop.xhat if closed else np.zeros(p)
    collided, failed, error, outcome = False, None, None, None
    inside = getattr(sim, "inside", None)
    for t in range(T):
        u = loop.control(t, lo, hi) if closed else plan.controls[t]
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
            xhat = loop.update(t, y, x, u, gen)
        est.append(plan.reduced[t + 1] + xhat[:p])
        if augmented:
            dist.append(xhat[p : p + sim.control_dim].copy())
        stop = _stopped(sim, y, inside)
        if stop is not None:
            collided, failed, outcome = stop == "collision", t + 1, stop
            break
        if goal_at == "any" and sim.in_goal(y):
            break
    reached = outcome is None and (goal_at == "any" or len(xs) == T + 1) and bool(sim.in_goal(y))
    if outcome is None:
        outcome = "success" if reached else "missed_goal"
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
        reason=_reason(outcome, failed, error, goal_at),
        disturbance=np.stack(dist) if augmented else None,
    )


def _stopped(sim, y, inside) -> str | None:
    """The outcome that ends a run at the state ``y`` (``"left_tissue"``, then
    ``"collision"``), or ``None``."""
    if inside is not None and not inside(y):
        return "left_tissue"
    if sim.in_collision(y):
        return "collision"
    return None


class _ClosedLoop:
    """The feedback of one closed-loop execution (module docstring): the control
    ``u_t = clip(u*_t + L_t x̂_t)`` and the update of the estimate ``x̂`` from the
    measurement after each step, by the Kalman filter of the controller's model (or by
    :func:`~riskplan.control.ukf.execution_ukf`)."""

    def __init__(self, sim, plan: NominalPlan, controller: LQGController, estimator: str):
        self.sim, self.plan = sim, plan
        self.L, self.K = controller.L, controller.K
        self.A, self.B, self.H = controller.model()[:3]
        self.xhat = np.zeros(self.A.shape[1])
        # a simulator whose measurement needs the full state (``measure(state, noise,
        # rng)``: the needle in its material frame) is sensed through it
        self.measure = getattr(sim, "measure", None)
        self.z_nominal = nominal_measurements(sim, plan, self.measure)
        self.ukf = execution_ukf(sim, plan, controller) if estimator == "ukf" else None

    def control(self, t: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """``u_t (q,)``: the plan's control plus the feedback, clipped to the bounds."""
        return np.minimum(np.maximum(self.plan.controls[t] + self.L[t] @ self.xhat, lo), hi)

    def update(self, t: int, y, x: np.ndarray, u: np.ndarray, gen) -> np.ndarray:
        """``x̂_{t+1}`` from the measurement of the state ``y`` (reduced ``x``) reached by
        ``u``; the measurement noise is drawn from ``gen``."""
        zbar, ubar = (
            sense(self.sim, self.measure, y, x, gen) - self.z_nominal[t],
            u - self.plan.controls[t],
        )
        if self.ukf is not None:
            self.xhat = self.ukf(t, self.xhat, ubar, zbar)
        else:
            xp = self.A[t] @ self.xhat + self.B[t] @ ubar
            self.xhat = xp + self.K[t] @ (zbar - self.H[t] @ xp)
        return self.xhat


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
