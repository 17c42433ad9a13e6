"""Studies of the needle scenario beyond Fig. 6 (deformable paper, Patil, van den Berg &
Alterovitz, RSS 2011, §V-A): how large the deformations are, open against closed loop in
the conditions of Figs. 4 and 5 as rates on common draws, and sensitivity tables.

* :func:`deformation_sizes` — for the nominal model and each uncertainty case: the
  displacement of the goal centre and of the obstacles (and the tissue's offset of the
  robot) at the end of plans, executed open loop under draws of the case, beside the goal
  radius. No target size: they follow from the paper's values (unit square fixed at the
  corners, E = 50, ν = 0.4, f = 1) and our modelling choices (plane stress, unit thickness,
  a point load spread by the P1 weights of its element; docs/scenarios.md).
* :func:`fig45_rates` — Fig. 4 (actuation noise) and Fig. 5 (a stiffer material, at values
  fixed in advance: E = 150, three times the planning value, "much stiffer"; and E = 67,
  about +2σ of the high-variance case, 50 + 2√75) as success rates of the same plan open
  and closed loop on the same draws (:func:`riskplan.app.reproduce.deformable.open_closed_rates`).
* :func:`needle_variant` — a ``make_sim`` for :func:`riskplan.app.reproduce.deformable.run_scenario`
  with the actuation noise scaled (its standard deviations × ``actuation_scale``), the
  interaction force scaled (nominal ``f_int`` and the force case's range × ``force_scale``),
  or actuation noise present in every case (``actuation_everywhere``: the other reading of
  the paper's list of cases); :func:`sensitivity` runs Fig. 6 for each variant.

The RRT's control margin stays at 2σ of the *nominal* actuation noise in every variant:
the planner is the same, only what the executions meet changes.
"""

from __future__ import annotations

import math
from functools import partial

import numpy as np

from riskplan.errors import InvalidInputError

__all__ = [
    "FIG5_YOUNGS",
    "deformation_sizes",
    "fig45_rates",
    "needle_variant",
    "sensitivity",
]

#: Fig. 5's stiffer materials, fixed before measuring: 3 × the planning value ("much
#: stiffer"), and the high-variance case's mean + 2σ (50 + 2√75 ≈ 67.3, rounded).
FIG5_YOUNGS = (150.0, 67.0)


def _make_variant(
    name: str,
    case: str,
    *,
    actuation_scale: float = 1.0,
    force_scale: float = 1.0,
    actuation_everywhere: bool = False,
):
    from riskplan.scenarios.needle import NeedleScenario
    from riskplan.scenarios.uncertainty import (
        InteractionForceUncertainty,
        WithActuation,
        get_case,
        needle_actuation_cov,
    )

    if name != "needle":
        raise InvalidInputError(f"scenario: the needle variants are for 'needle', got {name!r}")
    sim = NeedleScenario()
    base = sim.nominal_params.replace(force_scale=force_scale)
    cov = tuple(tuple(v * actuation_scale**2 for v in row) for row in needle_actuation_cov())
    if case == "force":
        dist = InteractionForceUncertainty(base=base, high=2.0 * force_scale)
    else:
        dist = get_case(case, base, actuation_cov=cov)
    if actuation_everywhere and case not in ("actuation", "nominal"):
        dist = WithActuation(inner=dist, cov=cov)
    sim.distribution = dist
    return sim


def needle_variant(
    actuation_scale: float = 1.0, force_scale: float = 1.0, actuation_everywhere: bool = False
):
    """A picklable ``make_sim(name, case)`` for :func:`riskplan.app.reproduce.deformable.run_scenario`
    (module docstring). ``actuation_scale``: factor on the actuation noise's standard
    deviations (case 3, or every case with ``actuation_everywhere``); ``force_scale``: factor
    on the interaction force (the planning value and the force case's ``U[0, 2]``)."""
    for n, v in (("actuation_scale", actuation_scale), ("force_scale", force_scale)):
        if not (math.isfinite(v) and v > 0):
            raise InvalidInputError(f"{n}: expected a finite value > 0, got {v!r}")
    return partial(
        _make_variant,
        actuation_scale=float(actuation_scale),
        force_scale=float(force_scale),
        actuation_everywhere=bool(actuation_everywhere),
    )


def deformation_sizes(plans, *, n_draws: int = 50, seed: int = 0, cases=None) -> dict:
    """Displacements at the end of ``plans`` (needle :class:`~riskplan.control.NominalPlan`
    list) executed open loop under draws of each case (the nominal model: one run per plan).

    Returns ``{case: {"goal_centre": (mean, max), "obstacles": (mean, max), "robot":
    (mean, max), "runs": n, "goal_radius": r}}``: ``goal_centre`` is ``|u|`` at the goal's
    centre, ``obstacles`` the largest ``|u|`` over the obstacles' vertices, ``robot`` the
    tissue's offset ``|x − X|`` of the robot, each at the last state of the run.
    """
    from riskplan.app.reproduce.deformable import EVAL_CASES
    from riskplan.parallel import spawn_seeds
    from riskplan.scenarios.base import rollout
    from riskplan.scenarios.registry import make_scenario

    cases = ("nominal", *EVAL_CASES) if cases is None else tuple(cases)
    out = {}
    for k, case in enumerate(cases):
        sim = make_scenario("needle", case)
        cfg = sim.config
        ref_obst = np.concatenate(cfg.obstacles)
        ref_goal = np.asarray(cfg.goal_center)
        g, o, r = [], [], []
        n = 1 if case == "nominal" else int(n_draws)
        # case k's draws from root seed + k, not a spawn_seeds child: the deformation sizes
        # in docs/scenarios.md were measured on exactly these streams (a child would redraw them)
        seeds = spawn_seeds(seed + k, n * len(plans))
        for i, plan in enumerate(plans):
            for j in range(n):
                params = sim.sample_params(seeds[i * n + j])
                last = rollout(sim, sim.initial_state(params), plan.controls, params)[-1]
                g.append(float(np.linalg.norm(sim.goal_center(last) - ref_goal)))
                o.append(
                    float(
                        np.linalg.norm(np.concatenate(sim.obstacles(last)) - ref_obst, axis=1).max()
                    )
                )
                r.append(float(np.linalg.norm(last.pose[:2] - last.material[:2])))
        out[case] = {
            "goal_centre": (float(np.mean(g)), float(np.max(g))),
            "obstacles": (float(np.mean(o)), float(np.max(o))),
            "robot": (float(np.mean(r)), float(np.max(r))),
            "runs": len(g),
            "goal_radius": float(cfg.goal_radius),
        }
    return out


def fig45_rates(plans_and_controllers: dict, *, n: int = 200, seed: int = 0) -> dict:
    """Figs. 4 and 5 as rates: ``plans_and_controllers[case] = (plan, controller)`` for the
    cases ``"actuation"`` (Fig. 4) and ``"material-high"`` (Fig. 5; the controller the
    high-variance case selected). Fig. 4: ``n`` draws of the actuation case; Fig. 5: the
    planning parameters with E fixed at each of :data:`FIG5_YOUNGS`, ``n`` sensing-noise
    seeds (open loop is deterministic there). Returns ``{label: open_closed_rates(...)}``.
    """
    from riskplan.app.reproduce.deformable import open_closed_rates
    from riskplan.parallel import spawn_seeds
    from riskplan.scenarios.registry import make_scenario

    out = {}
    if "actuation" in plans_and_controllers:
        sim = make_scenario("needle", "actuation")
        plan, ctrl = plans_and_controllers["actuation"]
        seeds = spawn_seeds(seed, n)
        params = [sim.distribution.sample(np.random.default_rng([s, 1])) for s in seeds]
        out["fig4 actuation"] = open_closed_rates(sim, plan, ctrl, params, seeds)
    if "material-high" in plans_and_controllers:
        sim = make_scenario("needle", "material-high")
        plan, ctrl = plans_and_controllers["material-high"]
        for e in FIG5_YOUNGS:
            params = [sim.nominal_params.replace(youngs_modulus=e)] * n
            # sensing noise from root seed + 1, not a spawn_seeds child: the Fig. 5 counts in
            # docs/reproduce.md were measured on exactly this stream (a child would redraw it)
            out[f"fig5 E={e:g}"] = open_closed_rates(
                sim, plan, ctrl, params, spawn_seeds(seed + 1, n)
            )
    return out


def sensitivity(
    scale,
    root,
    *,
    factors=(0.5, 1.0, 2.0),
    other_reading: bool = True,
    seed: int = 0,
    backend: str = "local",
    workers: int | None = None,
    progress=None,
) -> dict:
    """Fig. 6 of the needle for each actuation-noise scale and each interaction-force scale
    in ``factors`` (one at a time, the other at 1), at ``scale``
    (:class:`~riskplan.app.reproduce.deformable.ScenarioScale`), each variant in its own resumable
    store under ``root``.

    Under our reading of the cases actuation noise acts in case 3 only, so an actuation
    variant changes only that case (the plans are made without noise and are the same):
    it runs the ``actuation`` case alone on the ×1 run's candidates and takes the other
    four cases from the ×1 run. A
    force variant changes the plans and every case, and runs all five. ``other_reading``:
    also run the four other cases with actuation noise in every draw (the other reading).

    Returns ``{"actuation": {f: {method: mean rate}}, "force": {...}, "runs": {tag:
    run_scenario result}}`` (rates averaged over the five cases; ``None`` where a method
    does not apply) and, with ``other_reading``, ``"actuation_everywhere": {method: mean
    rate}`` over the five cases (case 3 from the ×1 run).
    """
    from pathlib import Path

    from riskplan.app.reproduce.deformable import EVAL_CASES, METHODS, run_scenario

    root = Path(root)
    runs: dict = {}

    from dataclasses import asdict

    from riskplan.app.reproduce.deformable import BlobStore
    from riskplan.app.store import ResultStore

    def store_of(tag):
        config = {
            "study": "needle-sensitivity",
            "variant": tag,
            "seed": seed,
            "scale": asdict(scale),
        }
        return ResultStore(root / tag, config)

    def run(tag, cases, plans_from=None, **variant):
        if tag not in runs:
            store = store_of(tag)
            if plans_from is not None:
                # the same planning parameters: the same candidates (no noise in planning)
                src, dst = BlobStore(store_of(plans_from)), BlobStore(store)
                for s in ("deforming", "plain", "static"):
                    key = f"fig6.needle.plans.{s}"
                    if dst.get(key) is None:
                        dst.put(key, src.get(key))
            runs[tag] = run_scenario(
                "needle",
                scale,
                store,
                seed=seed,
                backend=backend,
                workers=workers,
                progress=progress,
                cases=cases,
                make_sim=needle_variant(**variant),
            )
        return runs[tag]["cases"]

    def mean(cases: dict) -> dict:
        return {
            m: None
            if any(cases[c][m] is None for c in EVAL_CASES)
            else float(np.mean([cases[c][m]["rate"] for c in EVAL_CASES]))
            for m in METHODS
        }

    base = run("act1_force1", EVAL_CASES)
    out: dict = {"actuation": {}, "force": {}}
    for f in factors:
        if f == 1.0:
            out["actuation"][f] = out["force"][f] = mean(base)
            continue
        act = run(f"act{f:g}_force1", ("actuation",), "act1_force1", actuation_scale=f)
        out["actuation"][f] = mean({**base, **act})
        out["force"][f] = mean(run(f"act1_force{f:g}", EVAL_CASES, force_scale=f))
    if other_reading:
        others = tuple(c for c in EVAL_CASES if c != "actuation")
        every = run("actuation_everywhere", others, "act1_force1", actuation_everywhere=True)
        out["actuation_everywhere"] = mean({**base, **every})
    out["runs"] = runs
    return out
