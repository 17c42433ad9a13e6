r"""The simulator runs of :func:`riskplan.control.linearize`, one plan step at a time
(deformable-planning paper IV-B; the method is in the docstring of
:mod:`riskplan.control.linearize`).

Per step ``t``, each run restarts the simulator from a stored plan state:

1. the A runs (``t >= 1``): ``K`` perturbed controls ``u*_{t-1} + w_k`` from ``y*_{t-1}``,
   then ``u*_t``; their deviations ``X_t``, ``X_{t+1}`` give the least-squares fit
   ``A_t = A_prior + (X_{t+1} − A_prior X_t) X_t⁺`` (``_a_runs``, ``_fit_a``);
2. the B runs: forward differences in each control component (:func:`control_jacobian`);
3. the parameter draws: one run per draw ``s_i ~ S`` from ``y*_t`` with ``u*_t``, whose
   deviations give ``M_t``, the drift and, for simulators that measure the full state, the
   measurement biases (``_draw_runs``); with ``disturbance=True`` also the draws'
   persistent deviations, without their actuation noise (``_persistent_runs``).

Steps are independent: ``_run_chunk`` runs a chunk of them in one task of
:func:`riskplan.parallel.map_tasks`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from riskplan._validation import as_generator
from riskplan.control.plan import NominalPlan
from riskplan.errors import InvalidInputError, SimulationError

__all__ = ["control_jacobian"]


class _Step(NamedTuple):
    """What the runs of one step ``t`` give (``_steps``)."""

    A: np.ndarray | None  # (p, p); None at t = 0 (no earlier control to perturb)
    B: np.ndarray  # (p, q)
    M: np.ndarray  # (p, p)
    drift: np.ndarray  # (p,)
    rank: int  # rank of X_t (-1 at t = 0)
    D: np.ndarray | None  # (n, p) the draws' deviations
    P: np.ndarray | None  # (n, p) those without actuation noise (disturbance only)
    H: np.ndarray | None  # (m, p) H_t at y*_{t+1} (measuring only)
    bias: np.ndarray | None  # (n, m) the draws' measurement biases (measuring only)
    bias_persistent: np.ndarray | None  # (n, m) those without actuation noise


def _checked(sim, state, t: int, what: str) -> np.ndarray:
    x = np.asarray(sim.reduced(state), dtype=np.float64)
    if not np.all(np.isfinite(x)):
        raise SimulationError(f"linearize: non-finite reduced state at step {t} ({what})")
    return x


def _finite(X: np.ndarray, t: int, what: str) -> None:
    if not np.isfinite(X).all():
        raise SimulationError(f"linearize: non-finite reduced state at step {t} ({what})")


def _mirror(u: np.ndarray, w: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    v = u + w
    out = (v < bounds[:, 0]) | (v > bounds[:, 1])
    v = np.where(out, u - w, v)
    return np.clip(v, bounds[:, 0], bounds[:, 1])


def _fixed_prior(a_prior: str, p: int) -> np.ndarray:
    return np.eye(p) if a_prior == "identity" else np.zeros((p, p))


def _callable_prior(a_prior, plan: NominalPlan, t: int, p: int) -> np.ndarray:
    """``a_prior(y*_{t+1}, params) (p, p)``: a simulator's own structure of ``A_t``."""
    prior = np.asarray(a_prior(plan.states[t + 1], plan.params), dtype=np.float64)
    if prior.shape != (p, p) or not np.all(np.isfinite(prior)):
        raise InvalidInputError(
            f"a_prior: expected a finite ({p}, {p}) matrix from the callable, got shape {prior.shape}"
        )
    return prior


def _stepper(sim):
    """``run(state, u, params, near)``: ``sim.step_near`` where the simulator has one (its
    solver starts from ``near``, a state expected close to the result), else ``sim.step``."""
    step_near = getattr(sim, "step_near", None)
    if step_near is None:
        return lambda state, u, params, near: sim.step(state, u, params)
    return step_near


def control_jacobian(
    sim, state, control, params, epsilon, x_next=None, t: int = 0, near=None
) -> np.ndarray:
    """``B (p, q)``: forward differences of ``sim.reduced(sim.step(state, u, params))`` in ``u``
    (paper IV-B, ``B_t``): column ``j`` is ``(x(u + ε_j e_j) − x(u)) / ε_j``.

    Parameters
    ----------
    sim : Simulator
        The simulator (``step``, or ``step_near`` where it has one; ``reduced``).
    state : object
        The full state ``y`` the step starts from.
    control : numpy.ndarray
        ``(q,)`` the unperturbed control ``u``.
    params : SimParams
        The parameters of the runs.
    epsilon : numpy.ndarray
        ``(q,)`` the step per component (sign flipped where ``u + ε`` leaves the upper
        bound).
    x_next : numpy.ndarray, optional
        ``(p,)`` the unperturbed result (computed if not given).
    t : int
        The plan step, named in the error of a non-finite state.
    near : object, optional
        The unperturbed next state, the solver's start for simulators with ``step_near``.

    Returns
    -------
    numpy.ndarray
        ``(p, q)`` the control Jacobian. Raises :class:`~riskplan.errors.SimulationError`
        when a run returns a non-finite reduced state.
    """
    run = _stepper(sim)
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    u = np.asarray(control, dtype=np.float64)
    if x_next is None:
        x_next = _checked(sim, run(state, u, params, near), t + 1, "nominal control")
    eps = np.asarray(epsilon, dtype=np.float64)
    q = u.shape[0]
    B = np.empty((x_next.shape[0], q))
    for j in range(q):
        e = eps[j] if u[j] + eps[j] <= bounds[j, 1] else -eps[j]
        du = u.copy()
        du[j] += e
        B[:, j] = (
            _checked(sim, run(state, du, params, near), t + 1, f"control component {j} perturbed")
            - x_next
        ) / e
    return B


def _persistent(params, plan_params):
    """``params`` without its actuation noise, or ``None`` if that is the plan's own
    parameters (then the persistent deviation is zero without a run)."""
    quiet = params.replace(actuation_cov=None, actuation_seed=plan_params.actuation_seed)
    return None if quiet == plan_params else quiet


def _draw_state(sim, run, plan: NominalPlan, t: int, s_i):
    """Full state after ``u*_t`` from ``y*_t`` under the draw ``s_i``; a draw on another
    mesh (only with ``sim.transfer_state``) runs on its own mesh."""
    y_t = plan.states[t]
    if s_i.n_elements != plan.params.n_elements:
        y_i = sim.transfer_state(y_t, s_i)
        return run(y_i, plan.controls[t], s_i, None)
    return run(y_t, plan.controls[t], s_i, plan.states[t + 1])


def _measured(sim, state) -> np.ndarray:
    return np.asarray(sim.measure(state, noise=np.zeros(sim.obs_dim)), dtype=np.float64)


def _param_draws(sim, plan: NominalPlan, params_distribution, n_samples: int, seed) -> list:
    if params_distribution is None:
        params_distribution = getattr(sim, "distribution", None)
    if params_distribution is None or n_samples == 0:
        return []
    if isinstance(params_distribution, (list, tuple)):
        draws = list(params_distribution)
    elif hasattr(params_distribution, "sample_many"):
        draws = params_distribution.sample_many(n_samples, seed)
    elif hasattr(params_distribution, "sample"):
        gen = as_generator(seed)
        draws = [params_distribution.sample(gen) for _ in range(n_samples)]
    else:
        raise InvalidInputError(
            f"params_distribution: expected a distribution with sample_many/sample or a list of SimParams, "
            f"got {type(params_distribution).__name__}"
        )
    if callable(getattr(sim, "transfer_state", None)):
        return list(draws)  # mesh draws run on their own meshes (_steps)
    n_el = plan.params.n_elements
    return [d if d.n_elements == n_el else d.replace(n_elements=n_el) for d in draws]


def _fit_a(X0, X1, prior, rcond, n_first_order, max_rank) -> tuple[np.ndarray, int]:
    """``A_t = A_prior + (X_{t+1} − A_prior X_t) X_t⁺`` and the rank of ``X_t``.

    ``X0``, ``X1 (p, K)`` the deviations of the A runs at ``t`` and ``t + 1``; singular
    values of ``X0`` below ``rcond · σ_max`` are dropped, and so are those beyond the
    ``n_first_order`` first-order directions (a declared prior; ``None`` otherwise) and
    beyond ``max_rank`` (the simulator's ``a_max_rank``; ``None``: no limit).
    """
    U, s, Vt = np.linalg.svd(X0, full_matrices=False)
    keep = s > rcond * (s[0] if s.size and s[0] > 0 else 1.0)
    if n_first_order is not None:
        # a declared (exact) prior: fit only the q first-order directions; beyond
        # them X_t holds second-order parts, whose pseudo-inverse would replace the
        # exact prior by a fit of curvature divided by tiny singular values
        keep[n_first_order:] = False
    if max_rank is not None:
        keep[max_rank:] = False  # singular values are sorted: keep the largest
    rank = int(keep.sum())
    if rank == 0:
        return prior.copy(), rank
    pinv = (Vt[keep].T / s[keep]) @ U[:, keep].T  # (K, p)
    return prior + (X1 - prior @ X0) @ pinv, rank


def _a_runs(sim, run, plan: NominalPlan, t: int, seed, W_factor, K: int, bounds):
    """The ``K`` A runs of step ``t >= 1``: ``u*_{t-1} + w_k`` (mirrored into the bounds)
    from ``y*_{t-1}``, then ``u*_t``. Returns the deviations ``X_t``, ``X_{t+1} (p, K)``."""
    params = plan.params
    p = plan.reduced.shape[1]
    y_t = plan.states[t]
    u_t = plan.controls[t]
    gen = np.random.default_rng(seed)
    y_prev, u_prev = plan.states[t - 1], plan.controls[t - 1]
    Z = gen.standard_normal((K, W_factor.shape[1])) @ W_factor.T
    X0 = np.empty((p, K))
    X1 = np.empty((p, K))
    for k in range(K):
        yk = run(y_prev, _mirror(u_prev, Z[k], bounds), params, y_t)
        X0[:, k] = sim.reduced(yk)
        X1[:, k] = sim.reduced(run(yk, u_t, params, plan.states[t + 1]))
    _finite(X0, t, "A runs")
    _finite(X1, t + 1, "A runs")
    X0 -= plan.reduced[t][:, None]
    X1 -= plan.reduced[t + 1][:, None]
    return X0, X1


def _draw_runs(sim, run, plan: NominalPlan, t: int, draws, Ht, z_next):
    """One run per parameter draw from ``y*_t`` with ``u*_t``.

    Returns ``M_t (p, p)`` (second moment of the deviations about zero), the drift
    ``(p,)`` (their mean), the deviations ``D (n, p)`` and, with ``Ht`` (a simulator that
    measures the full state), the measurement biases ``(n, m)``: the part of
    ``measure(y^i_{t+1}) − z_next`` that ``Ht`` does not explain (else ``None``).
    """
    measuring = Ht is not None
    D = np.empty((len(draws), plan.reduced.shape[1]))
    Y = []
    for i, s_i in enumerate(draws):
        y_i = _draw_state(sim, run, plan, t, s_i)
        D[i] = sim.reduced(y_i)
        if measuring:
            Y.append(_measured(sim, y_i))
    _finite(D, t + 1, "parameter draws")
    D -= plan.reduced[t + 1]
    M = D.T @ D / len(draws)
    drift = D.mean(axis=0)
    Bm = None
    if measuring:
        Bm = np.asarray(Y) - z_next - D @ Ht.T
        _finite(Bm, t + 1, "measurements of the parameter draws")
    return M, drift, D, Bm


def _persistent_runs(sim, run, plan: NominalPlan, t: int, draws, D, Bm, Ht, z_next):
    """The draws' one-step deviations without their actuation noise ``(n, p)``, and their
    measurement biases ``(n, m)`` (``None`` without ``Bm``): a draw without actuation noise
    keeps its deviation, one that differs from the plan's parameters only by it gets 0,
    any other is run once more with the noise switched off."""
    x_next = plan.reduced[t + 1]
    Pd = D.copy()
    Pb = None if Bm is None else Bm.copy()
    for i, s_i in enumerate(draws):
        if s_i.actuation_cov is None:
            continue  # no per-step part: the persistent deviation is D[i]
        quiet = _persistent(s_i, plan.params)
        if quiet is None:
            Pd[i] = 0.0
            if Pb is not None:
                Pb[i] = 0.0
            continue
        y_q = _draw_state(sim, run, plan, t, quiet)
        Pd[i] = sim.reduced(y_q) - x_next
        if Pb is not None:
            Pb[i] = _measured(sim, y_q) - z_next - Ht @ Pd[i]
    _finite(Pd, t + 1, "parameter draws without actuation noise")
    return Pd, Pb


def _steps(
    sim,
    plan: NominalPlan,
    draws,
    W_factor,
    eps,
    a_prior,
    rcond,
    K,
    seeds,
    ts,
    disturbance=False,
    measuring=False,
) -> list[_Step]:
    """The runs of each step ``t`` in ``ts`` (:class:`_Step`): ``A_t`` (``None`` at
    ``t = 0``), ``B_t``, ``M_t``, the drift, the rank of ``X_t``, the draws' deviations
    ``D_t (n, p)`` and, with ``disturbance``, those without actuation noise ``P_t (n, p)``.
    With ``measuring`` (a simulator with ``observation_jacobian`` and ``measure``):
    ``H_t (m, p)`` at ``y*_{t+1}``, the draws' measurement biases ``(n, m)`` and, with
    ``disturbance``, those without actuation noise; else ``None``."""
    bounds = np.asarray(sim.control_bounds, dtype=np.float64)
    params = plan.params
    p = plan.reduced.shape[1]
    fixed = None if callable(a_prior) else _fixed_prior(a_prior, p)
    max_rank = getattr(sim, "a_max_rank", None)
    n_first_order = None if fixed is not None else W_factor.shape[0]
    run = _stepper(sim)
    out = []
    for t, seed in zip(ts, seeds):
        prior = fixed if fixed is not None else _callable_prior(a_prior, plan, t, p)
        A = None
        rank = -1
        if t >= 1:
            X0, X1 = _a_runs(sim, run, plan, t, seed, W_factor, K, bounds)
            A, rank = _fit_a(X0, X1, prior, rcond, n_first_order, max_rank)
        B = control_jacobian(
            sim,
            plan.states[t],
            plan.controls[t],
            params,
            eps,
            x_next=plan.reduced[t + 1],
            t=t,
            near=plan.states[t + 1],
        )
        M = np.zeros((p, p))
        drift = np.zeros(p)
        D = Pd = Ht = Bm = Pb = z_next = None
        if measuring:
            Ht = np.asarray(sim.observation_jacobian(plan.states[t + 1], params), dtype=np.float64)
            z_next = _measured(sim, plan.states[t + 1])
        if draws:
            M, drift, D, Bm = _draw_runs(sim, run, plan, t, draws, Ht, z_next)
            if disturbance:
                Pd, Pb = _persistent_runs(sim, run, plan, t, draws, D, Bm, Ht, z_next)
        out.append(_Step(A, B, M, drift, rank, D, Pd, Ht, Bm, Pb))
    return out


def _run_chunk(
    sim, plan, draws, W_factor, eps, a_prior, rcond, K, step_seeds, disturbance, measuring, ts
):
    return _steps(
        sim,
        plan,
        draws,
        W_factor,
        eps,
        a_prior,
        rcond,
        K,
        [step_seeds[t] for t in ts],
        ts,
        disturbance,
        measuring,
    )
