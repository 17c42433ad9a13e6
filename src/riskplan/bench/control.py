"""Speed of the control stage (issue 11, parts 2-5): ``riskplan bench control --json``.

On one needle plan (the tissue demo's greedy arc steering on the nominal parameters,
40-step budget), uncertainty case ``actuation``:

* ``needle_linearize_ms``: :func:`riskplan.control.linearize` of the plan (its default
  K = 2 min(p, q) A-runs, q B-runs, 16 parameter draws per step), serial;
* ``needle_gains_ms``: LQR + Kalman gains; ``needle_lqgmp_sigma_ms`` /
  ``needle_lqgmp_truncation_ms``: :func:`riskplan.control.lqgmp` (2000 goal samples);
* ``needle_per_plan_ms``: linearize + gains + LQG-MP (sigma), the selection's unit of work,
  and ``needle_selection_100_est_s`` = 100 × that / 2 (two worker processes);
* ``needle_mc_1000_s``: 1000 closed-loop executions (:func:`monte_carlo_success`), serial.

Not quick: the same for one manipulation plan (resolved-rate steering, 14-step budget), and
``manipulation_linearize_k2p_ms`` with the paper's ``n_a_runs = 2p = 52`` instead of the
default ``2q = 12``.
"""

from __future__ import annotations

import time
import warnings


def _timed(fn, repeats: int) -> tuple[float, object]:
    out = fn()  # warm-up (numba kernels, FEM caches)
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        samples.append(time.perf_counter() - t0)
    samples.sort()
    return samples[len(samples) // 2], out


def _scenario_figures(
    name: str, plan_controls, repeats: int, mc_runs: int, k_2p: bool = False
) -> dict:
    from riskplan.control import NominalPlan, linearize, lqg_controller, lqgmp, monte_carlo_success
    from riskplan.control.linearize import RankDeficiencyWarning
    from riskplan.scenarios.registry import make_scenario

    sim = make_scenario(name, "actuation")
    u = plan_controls(sim, sim.nominal_params)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RankDeficiencyWarning)
        t_lin, lin = _timed(lambda: linearize(sim, plan, seed=0), repeats)
    t_gain, ctrl = _timed(lambda: lqg_controller(lin), repeats)
    t_sig, _ = _timed(lambda: lqgmp(sim, plan, ctrl, method="sigma", seed=0), repeats)
    t_tr, _ = _timed(lambda: lqgmp(sim, plan, ctrl, method="truncation", seed=0), repeats)
    per_plan = t_lin + t_gain + t_sig
    out = {
        f"{name}_plan_steps": plan.n_steps,
        f"{name}_linearize_ms": 1e3 * t_lin,
        f"{name}_gains_ms": 1e3 * t_gain,
        f"{name}_lqgmp_sigma_ms": 1e3 * t_sig,
        f"{name}_lqgmp_truncation_ms": 1e3 * t_tr,
        f"{name}_per_plan_ms": 1e3 * per_plan,
        f"{name}_selection_100_est_s": 100 * per_plan / 2,
    }
    if k_2p:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RankDeficiencyWarning)
            t_k, _ = _timed(
                lambda: linearize(sim, plan, n_a_runs=2 * sim.state_dim, seed=0), repeats
            )
        out[f"{name}_linearize_k2p_ms"] = 1e3 * t_k
    if mc_runs:
        t0 = time.perf_counter()
        monte_carlo_success(sim, plan, ctrl, sim.distribution, n=mc_runs, seed=0)
        out[f"{name}_mc_{mc_runs}_s"] = time.perf_counter() - t0
    return out


def run(quick: bool = False) -> dict:
    from riskplan.control.greedy import greedy_manipulation_controls, greedy_needle_controls

    figures = _scenario_figures(
        "needle",
        lambda sim, p: greedy_needle_controls(sim, p, 40),
        repeats=1 if quick else 5,
        mc_runs=50 if quick else 1000,
    )
    if not quick:
        figures.update(
            _scenario_figures(
                "manipulation",
                lambda sim, p: greedy_manipulation_controls(sim, p, 14),
                repeats=1,
                mc_runs=0,
                k_2p=True,
            )
        )
    return {k: (float(v) if not isinstance(v, int) else v) for k, v in figures.items()}
