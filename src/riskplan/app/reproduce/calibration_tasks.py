"""The calibration stage's tasks (:mod:`riskplan.app.reproduce.calibration`): a candidate's
controllers and LQG-MP estimates, and a batch of closed-loop executions. Module level, so
that a process pool can pickle them; each times itself in CPU seconds. Beside them what the
study makes of their results: a measured rate (``_rate``) and where the time went
(``_cost``)."""

from __future__ import annotations

import time
import warnings

import numpy as np

from riskplan.errors import (
    ConvergenceError,
    ElementInversionError,
    NumericalError,
    SimulationError,
)

__all__ = ["estimate_candidate", "execute_rates"]

#: a candidate whose linearisation fails with one of these is counted and left out
_FAILURES = (
    ConvergenceError,
    ElementInversionError,
    NumericalError,
    SimulationError,
    np.linalg.LinAlgError,
)


def _framed(sim, plan, controller: str):
    """``(sim, plan)`` as the executions of ``controller`` see them: the material frame's
    (:meth:`~riskplan.scenarios.needle.NeedleScenario.with_frame`,
    :meth:`~riskplan.control.NominalPlan.reframed`) for ``"mat"``/``"matdist"``."""
    if controller in ("mat", "matdist"):
        m = sim.with_frame("material")
        return m, plan.reframed(m)
    return sim, plan


def estimate_candidate(args):
    """``args = (sim, plan, lin_samples, goal_samples, seed, methods[, earlier])``: the
    paper's LQG controller and, per method of ``methods`` (a subset of
    :data:`~riskplan.app.reproduce.calibration.ESTIMATORS`), its LQG-MP ``P(success)``; ``"disturbance"`` builds the disturbance-state controller too.
    ``earlier``: a result of this function for the same plan, case and seed (the σ
    ranking's): its paper's controller and estimates are taken, not recomputed (the same
    seed gives the same linearisation, so the values are those a recomputation gives).
    Returns ``{"p": {method: float}, "lqg": controller, "dist": controller, "mat": ...,
    "matdist": ..., "error": str | None, "cpu_s": float}`` (``cpu_s``: this call's CPU
    seconds, ``time.process_time``); a failed linearisation gives ``error`` and no
    controllers."""
    from riskplan.control import linearize
    from riskplan.control.lqg import lqg_controller
    from riskplan.control.lqgmp import lqgmp
    from riskplan.parallel import spawn_seeds

    t0 = time.process_time()
    sim, plan, lin_samples, goal_samples, seed, methods = args[:6]
    earlier = args[6] if len(args) > 6 else None
    s_lin, s_mp, s_dlin, s_dmp, s_mlin, s_mmp = spawn_seeds(seed, 6)
    out = {"p": {}, "lqg": None, "dist": None, "mat": None, "matdist": None, "error": None}
    with warnings.catch_warnings():
        # rank-deficient X_t along straight stretches is expected and documented by linearize
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            if earlier is not None and earlier.get("lqg") is not None:
                ctrl = earlier["lqg"]
                out["p"].update(earlier["p"])
            else:
                lin = linearize(sim, plan, sim.distribution, n_samples=lin_samples, seed=s_lin)
                ctrl = lqg_controller(lin)
            out["lqg"] = ctrl
            for m in methods:
                if m in ("sigma", "truncation", "sampling") and m not in out["p"]:
                    r = lqgmp(sim, plan, ctrl, method=m, n_goal_samples=goal_samples, seed=s_mp)
                    out["p"][m] = float(r.p_success)
            if "disturbance" in methods:
                dlin = linearize(
                    sim,
                    plan,
                    sim.distribution,
                    n_samples=lin_samples,
                    seed=s_dlin,
                    disturbance=True,
                )
                dctrl = lqg_controller(dlin, disturbance=True)
                out["dist"] = dctrl
                r = lqgmp(
                    sim, plan, dctrl, method="sampling", n_goal_samples=goal_samples, seed=s_dmp
                )
                out["p"]["disturbance"] = float(r.p_success)
            for m, key, dist in (
                ("material", "mat", False),
                ("material-disturbance", "matdist", True),
            ):
                if m not in methods:
                    continue
                msim, mplan = _framed(sim, plan, key)
                mlin = linearize(
                    msim,
                    mplan,
                    sim.distribution,
                    n_samples=lin_samples,
                    seed=s_mlin,
                    disturbance=dist,
                )
                mctrl = lqg_controller(mlin, disturbance=dist)
                out[key] = mctrl
                r = lqgmp(
                    msim, mplan, mctrl, method="sampling", n_goal_samples=goal_samples, seed=s_mmp
                )
                out["p"][m] = float(r.p_success)
        except _FAILURES as exc:
            out["error"] = f"{type(exc).__name__}: {exc}"
    out["cpu_s"] = time.process_time() - t0
    return out


def execute_rates(args) -> dict:
    """``args = (sim, plan, controller, seeds)``: ``{"runs": [[success (0/1), outcome], ...],
    "cpu_s": float}``, one run per seed (``outcome``: the execution's, one of
    :data:`riskplan.control.lqg.OUTCOMES`; ``cpu_s``: the batch's CPU seconds)."""
    from riskplan.control.lqg import execute

    t0 = time.process_time()
    sim, plan, controller, seeds = args
    out = []
    for s in seeds:
        gen = np.random.default_rng(s)
        params = sim.distribution.sample(gen)
        ex = execute(sim, plan, controller, params, seed=gen, keep_states=False)
        out.append([int(ex.success), ex.outcome])
    return {"runs": out, "cpu_s": time.process_time() - t0}


def _runs(record) -> list:
    """The ``[[success, outcome], ...]`` of a stored batch (a list in stores written before
    batches carried their CPU seconds)."""
    return record["runs"] if isinstance(record, dict) else record


def _cpu(record) -> float:
    """A stored record's CPU seconds (0 where it predates the field)."""
    return float(record.get("cpu_s", 0.0)) if isinstance(record, dict) else 0.0


def _rate(runs) -> dict:
    """A (case, plan, controller)'s measured rate from its ``[[success, outcome], ...]``:
    ``successes``, ``n``, ``rate``, its 95 % Wilson interval ``low``/``high`` and the count
    of each ``outcome``."""
    from riskplan.collision import binomial_interval

    hits = int(sum(row[0] for row in runs))
    lo, hi = binomial_interval(hits, len(runs), confidence=0.95)
    outcomes: dict = {}
    for row in runs:
        outcomes[row[1]] = outcomes.get(row[1], 0) + 1
    return {
        "successes": hits,
        "n": len(runs),
        "rate": hits / len(runs),
        "low": float(lo),
        "high": float(hi),
        "outcomes": outcomes,
    }


def _cost(store, pre, sig, full, flags, n_executions) -> dict:
    """Where the stage's time went: CPU seconds summed over the stored records (each task
    times itself) of the σ ranking, the estimators and the executions, and the RRT's wall
    seconds when first computed (timings, not results: they differ from run to run)."""
    return {
        "rrt_wall_s": float(store.get(f"{pre}.plans_wall_s") or 0.0),
        "sigma_ranking_cpu_s": sum(_cpu(v) for v in sig.values()),
        "estimators_cpu_s": sum(_cpu(v) for v in full.values()),
        "executions_cpu_s": sum(_cpu(v) for v in flags.values()),
        "n_linearised": {"sigma_ranking": len(sig), "estimators": len(full)},
        "n_executions": n_executions,
    }
