"""Checks of the 3-D needle stage (:mod:`riskplan.app.reproduce.needle3d`) beside its
estimates: the prediction with the goal test drawn instead of exact, warm repeats of the
prediction's timing, and the structured linearisation's controller against executions."""

from __future__ import annotations

import time

import numpy as np

__all__ = ["actuation_cov", "drawn_estimate", "measure_structured", "repeat_cpu"]


def actuation_cov(sim):
    """``Σ_w`` when the case's only uncertainty is the actuation noise (the second-order
    model's scope), else ``None`` (material, mesh and force draws: the linear model)."""
    from riskplan.scenarios.uncertainty import ActuationNoise

    dist = sim.distribution
    return np.asarray(dist.cov, dtype=np.float64) if isinstance(dist, ActuationNoise) else None


def repeat_cpu(sim, plan, ctrl, seed, W, kw_se: dict, n: int = 2) -> list:
    """CPU seconds of ``n`` more runs of the prediction (the second-order model and the
    truncation on it), after the first: the first run of a plan also fills the tissue's
    per-node caches for the points the statistical linearisation visits."""
    from riskplan.control.lqgmp3d import lqgmp_3d
    from riskplan.control.lqgmp3d_moments import second_order_model

    out = []
    for _ in range(n):
        c0 = time.process_time()
        mo = None if W is None else second_order_model(sim, plan, ctrl, W)
        lqgmp_3d(sim, plan, ctrl, method="truncation", seed=seed, moments=mo, **kw_se)
        out.append(time.process_time() - c0)
    return out


def drawn_estimate(sim, plan, ctrl, seed, moments, c_model: float, kw_se: dict) -> dict:
    """The truncation estimate (on ``moments`` and on the linear model) with the goal test
    drawn to :data:`~riskplan.app.reproduce.needle3d.GOAL_SE` instead of exact, for comparison: ``{"truncation": p, "n": n,
    "se": s.e., "cpu_s": the prediction's CPU seconds with the draws, "linear": p}``."""
    from riskplan.control.lqgmp3d import lqgmp_3d

    c0 = time.process_time()
    tr = lqgmp_3d(
        sim, plan, ctrl, method="truncation", seed=seed, moments=moments, goal="draws", **kw_se
    )
    cpu = c_model + time.process_time() - c0
    lin = lqgmp_3d(sim, plan, ctrl, method="truncation", seed=seed, goal="draws", **kw_se)
    return {
        "truncation": tr.p_success,
        "n": tr.n_goal_samples,
        "se": tr.p_success_se,
        "cpu_s": cpu,
        "linear": lin.p_success,
    }


def measure_structured(sim, plan, row, *, n: int, seed=0):
    """The structured linearisation's check (the actuation case; nothing otherwise): the
    controller from :func:`~riskplan.control.lqgmp3d_moments.structured_linearization`
    (the material step's closed form times the tissue's Jacobian, no simulator runs), its
    prediction (second-order model, truncation, exact goal test) and ``n`` closed-loop
    executions on the draws of
    :func:`~riskplan.app.reproduce.needle3d.measure_plan`, in ``row.structured``: ``prediction``,
    ``closed``, ``closed_ci``, ``lin_cpu_s`` (linearisation and gains), ``cpu_s`` (the
    prediction), ``closed_cpu_s``. Returns ``row`` (a
    :class:`~riskplan.app.reproduce.needle3d.PlanRow`)."""
    from riskplan.collision import binomial_interval
    from riskplan.control.lqg import execute, lqg_controller
    from riskplan.control.lqgmp3d import lqgmp_3d
    from riskplan.control.lqgmp3d_moments import second_order_model, structured_linearization
    from riskplan.parallel import spawn_seeds

    W = actuation_cov(sim)
    if W is None:
        return row
    c0 = time.process_time()
    ctrl = lqg_controller(structured_linearization(sim, plan, W))
    c1 = time.process_time()
    pred = lqgmp_3d(
        sim, plan, ctrl, method="truncation", moments=second_order_model(sim, plan, ctrl, W)
    )
    c2 = time.process_time()
    k = 0
    for s in spawn_seeds(seed, n):
        gen = np.random.default_rng(s)
        ex = execute(sim, plan, ctrl, sim.sample_params(gen), seed=gen, keep_states=False)
        k += ex.outcome == "success"
    lo, hi = binomial_interval(k, n)
    row.structured = dict(
        prediction=pred.p_success,
        closed=k,
        closed_ci=(float(lo), float(hi)),
        lin_cpu_s=c1 - c0,
        cpu_s=c2 - c1,
        closed_cpu_s=time.process_time() - c2,
    )
    return row
