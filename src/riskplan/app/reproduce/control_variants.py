"""LQG against its variants on common random draws (issue item "beyond LQG"): the Kalman
filter against the UKF (:mod:`riskplan.control.ukf`), and the plan as given against the
plan re-optimised by iLQR (:mod:`riskplan.control.ilqr`) for a cost with the goal as
terminal term and an obstacle barrier (:func:`riskplan.control.ilqr_cost.scenario_terms`; 2-D
polygons, and the 3-D needle's convex bodies below).

Rules, fixed before any number was seen:

* **Plans**: per scenario, ``n_candidates`` simulator-RRT plans in the deforming tissue with
  the options of the Fig. 6 stage at the same named scale
  (:meth:`riskplan.app.reproduce.deformable.ScenarioScale.rrt_options`; the 3-D needle:
  those of :func:`riskplan.tissue_planning.plan_needle3d`); per case, the plan with
  the highest LQG-MP ``P(success)`` under that case's S is the one executed (the
  selected plan, as Fig. 6's "ours"; 3-D: the truncation estimate, as the needle3d stage).
* **Variants** on that plan: ``lqg`` (the paper's LQR + Kalman filter), ``ukf`` (the same
  gains, the UKF as estimator), ``ilqr`` (the plan re-optimised by iLQR, at most
  :data:`ILQR_ITERATIONS` iterations, then LQR + Kalman filter about it). Both plans are
  linearised with the same draws count and seed.
* **Executions**: ``n_executions`` per (case, variant); execution ``i`` draws its
  parameters from generator ``(seed_i, 0)`` and its sensing noise from ``(seed_i, 1)``,
  ``seed_i`` the ``i``-th of the case's seeds, the same for every variant (common random
  numbers), so two variants differ in an execution only through the controller or filter.
  Rates with 95 % Wilson intervals, and the paired counts won/lost against ``lqg``.
* **Computation**: CPU seconds (``time.process_time``) per plan for the controller's set-up
  (LQG: one linearisation and the gains; iLQR: its iterations and that linearisation) and
  per execution for each variant.

The 3-D needle's iLQR cost has the same terms against its deformed ellipsoids and
parallelepipeds (:mod:`riskplan.control.ilqr_cost3d`, read by
:func:`~riskplan.control.ilqr_cost.scenario_terms`). Its executions run grouped by mesh (a
draw's outcome is a function of its seeds alone, so the order changes no result): the mesh
case's draws fall on some ninety grids, and each grid's FEM model is built once.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import asdict, dataclass

import numpy as np

log = logging.getLogger(__name__)

__all__ = [
    "CONTROL_SCALES",
    "ILQR_ITERATIONS",
    "MATERIAL_CASES",
    "VARIANTS",
    "ControlScale",
    "compare_on_plan",
    "compare_variants",
    "run_control_variants",
]

#: The variants compared (module docstring).
VARIANTS = ("lqg", "ukf", "ilqr")
#: iLQR iterations at most (each one simulator linearisation of the plan).
ILQR_ITERATIONS = 3
#: Cases of the needle in its material frame (``needle-material``), where the measurement is
#: nonlinear in the reduced state (:func:`riskplan.control.ukf.material_measurement`): only
#: actuation noise makes the material pose uncertain; a material, mesh or force draw moves
#: only the measurement map, the estimate's covariance stays 0 and every filter is exact.
MATERIAL_CASES = ("actuation",)


@dataclass(frozen=True)
class ControlScale:
    """Sizes of the control-variants stage: ``n_candidates`` RRT plans per 2-D scenario,
    ``n_executions`` per (case, variant), ``cases`` (the 2-D scenarios'), ``lin_samples``
    parameter draws of each linearisation, ``goal_samples`` of LQG-MP; the 3-D needle:
    ``n3d_candidates`` (0: not run), ``n3d_executions``, ``n3d_cases``."""

    n_candidates: int
    n_executions: int
    cases: tuple
    lin_samples: int = 8
    goal_samples: int = 1000
    n3d_candidates: int = 0
    n3d_executions: int = 0
    n3d_cases: tuple = ("actuation",)


#: ``smoke``: seconds; ``paper``: the issue's 1000 executions per case and variant on the
#: 2-D scenarios (10 candidates each, the five cases, Fig. 6's linearisation sizes) and on
#: the 3-D needle (2 candidates of its RRT, the five cases).
CONTROL_SCALES = {
    "smoke": ControlScale(n_candidates=2, n_executions=4, cases=("material-high",)),
    "paper": ControlScale(
        n_candidates=10,
        n_executions=1000,
        cases=("material-low", "material-high", "actuation", "mesh", "force"),
        lin_samples=16,
        goal_samples=2000,
        n3d_candidates=2,
        n3d_executions=1000,
        n3d_cases=("material-low", "material-high", "actuation", "mesh", "force"),
    ),
}


def _draw(sim, gen):
    sample = getattr(sim, "sample_params", None)
    return sample(gen) if sample is not None else sim.distribution.sample(gen)


def _mesh_group(sim, params) -> int:
    """The element count a draw's FEM model is keyed by (the 3-D needle's grid, else the
    count itself): executions on one mesh run together."""
    data = getattr(sim, "mesh_data", None)
    if data is None or params.n_elements is None:
        return 0
    return int(getattr(data(params.n_elements), "model_count", params.n_elements))


def compare_on_plan(sim, plan, n: int, *, seed: int = 0, lin_samples: int = 8, terms=None):
    """Every variant of :data:`VARIANTS` executed ``n`` times on ``plan`` on common draws.

    Parameters
    ----------
    sim : Simulator
        The scenario with its case's distribution S.
    plan : NominalPlan
        The plan (RRT or greedy).
    n : int
        Executions per variant.
    seed : int
        Seed of the draws and of the linearisations.
    lin_samples : int
        Parameter draws per linearisation.
    terms : dict, optional
        iLQR's goal/obstacle terms (default :func:`~riskplan.control.ilqr_cost.scenario_terms`,
        2-D or 3-D).

    Returns
    -------
    dict
        Per variant: ``successes``, ``n``, ``rate``, ``low``, ``high`` (95 % Wilson),
        ``outcomes``, ``setup_cpu_s`` (per plan), ``cpu_s_per_execution``, ``won``/``lost``
        (paired against ``lqg``); and ``ilqr_costs``, ``ilqr_linearizations``.
    """
    from riskplan.collision import binomial_interval
    from riskplan.control import execute
    from riskplan.control.ilqr import tracking_controller
    from riskplan.control.ilqr_cost import scenario_terms
    from riskplan.parallel import spawn_seeds

    if terms is None:
        terms = scenario_terms(sim, plan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # rank-deficient fits, documented
        c0 = time.process_time()
        plan_l, ctrl_l, _ = tracking_controller(
            sim, plan, sim.distribution, controller="lqr", n_samples=lin_samples, seed=seed
        )
        c1 = time.process_time()
        plan_i, ctrl_i, info = tracking_controller(
            sim,
            plan,
            sim.distribution,
            controller="ilqr",
            terms=terms,
            max_iter=ILQR_ITERATIONS,
            n_samples=lin_samples,
            seed=seed,
        )
        c2 = time.process_time()
    variants = {
        "lqg": (plan_l, ctrl_l, "kalman", c1 - c0),
        "ukf": (plan_l, ctrl_l, "ukf", c1 - c0),
        "ilqr": (plan_i, ctrl_i, "kalman", c2 - c1),
    }
    ok = {k: [False] * n for k in variants}
    outcomes = {k: [None] * n for k in variants}
    cpu = dict.fromkeys(variants, 0.0)
    names = list(variants)
    warm = getattr(sim, "model", None)
    seeds = spawn_seeds(seed, n)
    draws = [_draw(sim, np.random.default_rng([s, 0])) for s in seeds]
    order = sorted(
        range(n), key=lambda i: _mesh_group(sim, draws[i])
    )  # stable: same mesh, seed order
    for i in order:
        s, params = seeds[i], draws[i]
        if callable(warm):
            warm(params)  # the draw's FEM model is built once and cached: outside the timing
        # each variant goes first equally often, so no variant pays for what another warmed
        for k in names[i % 3 :] + names[: i % 3]:
            pl, c, est, _ = variants[k]
            t0 = time.process_time()
            ex = execute(
                sim,
                pl,
                c,
                params,
                seed=np.random.default_rng([s, 1]),
                keep_states=False,
                estimator=est,
            )
            cpu[k] += time.process_time() - t0
            outcomes[k][i] = ex.outcome
            ok[k][i] = ex.outcome == "success"
    out = {
        "n": n,
        "T": plan.n_steps,
        "ilqr_costs": info.costs.tolist(),
        "ilqr_linearizations": info.n_linearizations,
    }
    base = np.array(ok["lqg"])
    for k, (_, _, _, setup) in variants.items():
        o = np.array(ok[k])
        succ = int(o.sum())
        lo, hi = binomial_interval(succ, n, confidence=0.95)
        out[k] = {
            "successes": succ,
            "n": n,
            "rate": succ / n,
            "low": float(lo),
            "high": float(hi),
            "outcomes": {x: outcomes[k].count(x) for x in sorted(set(outcomes[k]))},
            "setup_cpu_s": setup,
            "cpu_s_per_execution": cpu[k] / n,
            "won": int((o & ~base).sum()),
            "lost": int((~o & base).sum()),
        }
    return out


def _select(sim, plans, *, lin_samples, goal_samples, seed, three_d=False):
    """Index and LQG-MP ``P(success)`` of the best candidate under ``sim``'s case (first
    of the best on ties); candidates whose linearisation fails score 0."""
    from riskplan.app.reproduce.deformable import evaluate_candidate
    from riskplan.parallel import spawn_seeds
    from riskplan.tissue_planning.select import _FAILURES, evaluate_plan

    scores = []
    for plan, s in zip(plans, spawn_seeds(seed, len(plans))):
        if three_d:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    _, res = evaluate_plan(
                        sim,
                        plan,
                        method="truncation",
                        n_samples=lin_samples,
                        n_goal_samples=goal_samples,
                        seed=s,
                    )
                scores.append(float(res.p_success))
            except _FAILURES:
                scores.append(0.0)
        else:
            scores.append(
                evaluate_candidate((sim, plan, lin_samples, goal_samples, s))["p_success"]
            )
    j = int(np.argmax(scores))
    return j, scores


def _candidates(name: str, scale_name: str, n: int, seed: int):
    """RRT candidates of a 2-D scenario in the deforming tissue, Fig. 6's options at the
    named scale (:data:`riskplan.app.reproduce.deformable.SCALES`)."""
    from riskplan.app.reproduce.deformable import SCALES, _seed_for
    from riskplan.scenarios.registry import make_scenario
    from riskplan.tissue_planning.rrt import rrt_plans

    base = make_scenario(name, "nominal")
    plans, _ = rrt_plans(
        base,
        n,
        seed=_seed_for(seed, name, "control-variants", "rrt"),
        params=base.nominal_params,
        options=SCALES[scale_name][name].rrt_options(),
        backend="serial",
    )
    return plans


def _candidates_3d(n: int, seed: int):
    """RRT candidates of the 3-D needle, the options of
    :func:`~riskplan.tissue_planning.plan_needle3d`."""
    from riskplan.scenarios.registry import scenario_from_config
    from riskplan.tissue_planning.rrt import RRTOptions, rrt_plans

    sim = scenario_from_config("needle3d", None, "nominal")
    plans, _ = rrt_plans(
        sim,
        n,
        seed=seed,
        options=RRTOptions(plans_per_tree=5, max_iterations=400, goal_bias=0.5, goal_depth=0.3),
        backend="serial",
    )
    return plans


def run_control_variants(
    store, scale_name: str = "smoke", *, seed: int = 0, scenarios=None, progress=None
) -> dict:
    """The ``reproduce`` stage ``control-variants``: per scenario and case the selected RRT
    plan, and :func:`compare_on_plan` on it (module docstring).

    Parameters
    ----------
    store : ResultStore
        Finished (scenario, case) rows are read from and written to it (resumable).
    scale_name : str
        A key of :data:`CONTROL_SCALES`.
    seed : int
        Root seed.
    scenarios : sequence of str, optional
        Subset of ``("needle", "needle-material", "manipulation", "needle3d")`` (default
        all of the scale; ``needle-material``: the needle's candidates in its material frame,
        :data:`MATERIAL_CASES`).
    progress : callable, optional
        ``progress(stage, done, total)``.

    Returns
    -------
    dict
        ``scale`` (the sizes) and per scenario: ``candidates``, and per case the selected
        ``plan`` index, the candidates' ``p_success``, the selection's CPU seconds and the
        :func:`compare_on_plan` row.
    """
    from riskplan.app.reproduce.deformable import SCALES, _seed_for
    from riskplan.errors import InvalidInputError
    from riskplan.scenarios.registry import make_scenario, scenario_from_config

    if scale_name not in CONTROL_SCALES:
        raise InvalidInputError(
            f"scale: expected one of {', '.join(CONTROL_SCALES)}, got {scale_name!r}"
        )
    sc = CONTROL_SCALES[scale_name]
    rrt_scale = scale_name if scale_name in SCALES else "smoke"
    names = ["needle", "needle-material", "manipulation"]
    names += ["needle3d"] if sc.n3d_candidates else []
    if scenarios is not None:
        names = [x for x in names if x in scenarios]
    report = progress or (lambda stage, done, total: None)
    out: dict = {"scale": {**asdict(sc), "name": scale_name}}
    for name in names:
        three_d = name == "needle3d"
        material = name == "needle-material"
        cases = sc.n3d_cases if three_d else MATERIAL_CASES if material else sc.cases
        n = sc.n3d_executions if three_d else sc.n_executions
        todo = [c for c in cases if store.get(f"control.{scale_name}.{name}.{c}") is None]
        plans = None
        c0 = time.process_time()
        if todo:
            if three_d:
                plans = _candidates_3d(sc.n3d_candidates, _seed_for(seed, name, "rrt"))
            else:  # the needle-material rows run on the needle's candidates
                plans = _candidates(name.split("-")[0], rrt_scale, sc.n_candidates, seed)
        rrt_cpu = time.process_time() - c0
        rows = {}
        for k, case in enumerate(cases):
            report(f"control-variants {name}", k, len(cases))
            key = f"control.{scale_name}.{name}.{case}"
            row = store.get(key)
            if row is None:
                if three_d:
                    sim = scenario_from_config("needle3d", None, case)
                elif material:
                    sim = make_scenario("needle", case).with_frame("material")
                else:
                    sim = make_scenario(name, case)
                cands = [pl.reframed(sim) for pl in plans] if material else plans
                c0 = time.process_time()
                j, scores = _select(
                    sim,
                    cands,
                    lin_samples=sc.lin_samples,
                    goal_samples=sc.goal_samples,
                    seed=_seed_for(seed, name, "select", case),
                    three_d=three_d,
                )
                sel_cpu = time.process_time() - c0
                row = {
                    "plan": j,
                    "p_success": scores,
                    "rrt_cpu_s": rrt_cpu,
                    "selection_cpu_s": sel_cpu,
                    **compare_on_plan(
                        sim,
                        cands[j],
                        n,
                        seed=_seed_for(seed, name, "execute", case),
                        lin_samples=sc.lin_samples,
                    ),
                }
                store.put(key, row)
            rows[case] = row
        report(f"control-variants {name}", len(cases), len(cases))
        out[name] = rows
    return out


def compare_variants(scenario: str, case: str, n: int, seed: int = 0) -> dict:
    """:func:`compare_on_plan` on the demo's greedy plan (:mod:`riskplan.control.greedy`) of
    a 2-D scenario (``riskplan study control-variants``; the stage runs on RRT plans).

    Parameters
    ----------
    scenario : str
        ``"needle"`` or ``"manipulation"``.
    case : str
        The uncertainty case.
    n : int
        Executions per variant.
    seed : int
        Root seed.

    Returns
    -------
    dict
        :func:`compare_on_plan`'s row.
    """
    from riskplan.control import NominalPlan
    from riskplan.control.greedy import greedy_manipulation_controls, greedy_needle_controls
    from riskplan.scenarios.registry import make_scenario

    sim = make_scenario(scenario, case)
    if scenario == "needle":
        u = greedy_needle_controls(sim, sim.nominal_params, 60, speed=0.8)
    else:
        u = greedy_manipulation_controls(sim, sim.nominal_params, 40)
    plan = NominalPlan.from_rollout(sim, sim.initial_state(), u)
    return compare_on_plan(sim, plan, n, seed=seed)
