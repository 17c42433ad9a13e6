"""Open vs closed loop as rates on common random draws: the deformable-planning paper's
Fig. 7(c, d) and 7(e, f) (Patil, van den Berg & Alterovitz, RSS 2011, §V-B) measured over
many executions instead of one picture.

The paper shows one execution of the selected manipulation plan without feedback (the
object collides) and one with LQG feedback (it does not), under "variation in material
parameters" (c, d) and with "mesh elements increased" (e, f). Here each condition is a
distribution of simulation parameters; execution ``i`` draws its parameters and its
sensing noise from seed ``i`` (:func:`riskplan.parallel.spawn_seeds`), and runs the plan
open loop and closed loop on *those same* parameters and noise, so the difference between
the two rates is the feedback's and the pairs show it run by run.

Conditions (:data:`CONDITIONS`; the paper gives no numbers):

* ``fig7cd`` — a softer material: ``E ~ N(35, 75)``, ``ν ~ N(0.4, 4e-4)``: the spread of
  the paper's high-variance material case around E = 35 (two of its standard deviations
  below the planning value 50, an object that deforms more than planned). The controller
  is the ``material-high`` case's.
* ``fig7ef`` — a 1000-element mesh (the top of the mesh case's range; plans use 175), the
  nominal material; executions differ in their sensing noise only, so the open-loop runs
  are all alike. The controller is the ``mesh`` case's.
* ``fig4`` (needle, §V-A) — actuation noise: draws of the ``actuation`` case, whose
  controller runs.
* ``fig5``, ``fig5-67`` (needle) — a stiffer material at values fixed in advance
  (:data:`riskplan.app.reproduce.needle_study.FIG5_YOUNGS`): E = 150 (three times the
  planning value, "much stiffer") and E = 67 (about +2σ of the high-variance case), the
  planning parameters otherwise; the ``material-high`` case's controller. Open loop is
  deterministic there; the runs differ in their sensing noise.

Success as in Fig. 6 (:func:`riskplan.control.lqg.execute`): no collision at any state
and the final target in the goal; a solver failure counts as a failure and is counted
separately with its first message.

In Fig. 6's run (:func:`riskplan.app.reproduce.deformable.run_scenario`) the conditions of a
scenario execute the ``ours`` plan of their case in stored batches (:func:`_feedback_rates`);
:func:`single_executions` gives the single executions the paper draws (:data:`SINGLE_RUNS`,
states kept for the report's plots), and :func:`open_closed_rates` with
:func:`paired_outcomes` the same comparison for any plan and list of draws (the needle
study).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan.app.reproduce.work_units import _seed_for
from riskplan.errors import InvalidInputError

__all__ = [
    "CONDITIONS",
    "SINGLE_RUNS",
    "Condition",
    "condition_params",
    "feedback_batch",
    "open_closed_rates",
    "paired_outcomes",
    "paired_summary",
    "single_executions",
]


@dataclass(frozen=True)
class Condition:
    """One open-vs-closed condition: the figure, the scenario, the uncertainty case whose
    controller runs, the parameter changes and a caption."""

    figure: str
    scenario: str
    case: str
    caption: str


CONDITIONS = {
    "fig7cd": Condition(
        "fig7cd",
        "manipulation",
        "material-high",
        "Fig. 7(c, d): softer material, E ~ N(35, 75), ν ~ N(0.4, 4e-4)",
    ),
    "fig7ef": Condition(
        "fig7ef",
        "manipulation",
        "mesh",
        "Fig. 7(e, f): a 1000-element mesh (plans use 175)",
    ),
    "fig4": Condition("fig4", "needle", "actuation", "Fig. 4: actuation noise (case 3's draws)"),
    "fig5": Condition(
        "fig5", "needle", "material-high", "Fig. 5: a much stiffer material, E = 150"
    ),
    "fig5-67": Condition(
        "fig5-67", "needle", "material-high", "Fig. 5 at E = 67 (about +2σ of case 2)"
    ),
}

#: Young's moduli of the needle's stiffer-material conditions (values fixed in advance,
#: riskplan.app.reproduce.needle_study.FIG5_YOUNGS)
_STIFF_E = {"fig5": 150.0, "fig5-67": 67.0}

#: the softer material of Fig. 7(c, d): the planning value minus two standard deviations
#: of the high-variance material case (sd √75 ≈ 8.66)
SOFT_E_SHIFT = -15.0


def condition_params(figure: str, sim, gen: np.random.Generator):
    """The simulation parameters of one execution of ``figure`` (module docstring)."""
    from riskplan.scenarios.uncertainty import MaterialUncertainty

    base = sim.nominal_params
    if figure == "fig7cd":
        case = MaterialUncertainty.high(base)
        case = MaterialUncertainty(
            base=base,
            name="material-soft",
            youngs_mean=base.youngs_modulus + SOFT_E_SHIFT,
            youngs_var=case.youngs_var,
            poisson_mean=case.poisson_mean,
            poisson_var=case.poisson_var,
        )
        return case.sample(gen)
    if figure == "fig7ef":
        return base.replace(n_elements=1000)
    if figure == "fig4":
        return sim.distribution.sample(gen)
    if figure in _STIFF_E:
        return base.replace(youngs_modulus=_STIFF_E[figure])
    raise InvalidInputError(f"figure: expected one of {tuple(CONDITIONS)}, got {figure!r}")


def feedback_batch(args) -> list[list]:
    """``args = (sim, plan, controller, figure, seeds)``: for each seed, the plan executed
    open loop and closed loop under the same parameters and sensing noise; rows
    ``[open success, open collided, open solver failed, closed success, closed collided,
    closed solver failed, error message or ""]``."""
    from riskplan.control.lqg import execute

    sim, plan, controller, figure, seeds = args
    out = []
    for s in seeds:
        gen = np.random.default_rng(s)
        params = condition_params(figure, sim, gen)
        noise_seed = int(gen.integers(2**63))
        row, msg = [], ""
        for ctrl in (None, controller):
            ex = execute(sim, plan, ctrl, params, seed=noise_seed, keep_states=False)
            row += [int(ex.success), int(ex.collided), int(ex.error is not None)]
            msg = msg or (ex.error or "")
        out.append(row + [msg])
    return out


def paired_summary(rows) -> dict:
    """Rates, 95 % Wilson intervals and the pairs of :func:`feedback_batch` rows.

    ``open``/``closed``: ``successes``, ``n``, ``rate``, ``low``, ``high``, ``collided``,
    ``solver_failed``; ``pairs``: executions where both succeed, only closed loop, only
    open loop, neither; ``difference``: closed minus open rate; ``first_error``."""
    from riskplan.collision import binomial_interval

    arr = np.array([r[:6] for r in rows], dtype=np.int64).reshape(-1, 6)
    n = len(arr)
    out = {}
    for k, mode in ((0, "open"), (3, "closed")):
        hits = int(arr[:, k].sum())
        lo, hi = binomial_interval(hits, n, confidence=0.95) if n else (0.0, 1.0)
        out[mode] = {
            "successes": hits,
            "n": n,
            "rate": hits / n if n else None,
            "low": float(lo),
            "high": float(hi),
            "collided": int(arr[:, k + 1].sum()),
            "solver_failed": int(arr[:, k + 2].sum()),
        }
    o, c = arr[:, 0].astype(bool), arr[:, 3].astype(bool)
    out["pairs"] = {
        "both": int((o & c).sum()),
        "closed_only": int((~o & c).sum()),
        "open_only": int((o & ~c).sum()),
        "neither": int((~o & ~c).sum()),
    }
    out["difference"] = None if not n else out["closed"]["rate"] - out["open"]["rate"]
    out["first_error"] = next((r[6] for r in rows if r[6]), None)
    return out


def paired_outcomes(open_ok, closed_ok) -> dict:
    """Open against closed loop on the same draws (``(n,)`` success flags each): how many
    runs ``both`` succeed, ``neither``, ``only_open``, ``only_closed`` (feedback rescued
    them), and the rates. Feedback that changes nothing leaves ``only_*`` at 0."""
    a = np.asarray(open_ok, dtype=bool)
    b = np.asarray(closed_ok, dtype=bool)
    n = int(a.size)
    return {
        "n": n,
        "open": int(a.sum()),
        "closed": int(b.sum()),
        "both": int((a & b).sum()),
        "neither": int((~a & ~b).sum()),
        "only_open": int((a & ~b).sum()),
        "only_closed": int((~a & b).sum()),
        "open_rate": float(a.mean()) if n else float("nan"),
        "closed_rate": float(b.mean()) if n else float("nan"),
    }


def open_closed_rates(sim, plan, controller, params_list, seeds) -> dict:
    """Executions of ``plan`` without and with ``controller`` on the same draws: run ``i``
    uses ``params_list[i]`` and sensing seed ``seeds[i]`` in both. Returns
    :func:`paired_outcomes` plus the outcome counts of each loop (``open_outcomes``,
    ``closed_outcomes``; :data:`riskplan.control.lqg.OUTCOMES`)."""
    from riskplan.control.lqg import OUTCOMES, execute

    res = {"open": [], "closed": []}
    for params, sd in zip(params_list, seeds):
        for kind, ctrl in (("open", None), ("closed", controller)):
            ex = execute(sim, plan, ctrl, params, seed=np.random.default_rng(sd), keep_states=False)
            res[kind].append(ex.outcome)
    out = paired_outcomes(
        [o == "success" for o in res["open"]], [o == "success" for o in res["closed"]]
    )
    for kind in ("open", "closed"):
        out[f"{kind}_outcomes"] = {o: res[kind].count(o) for o in OUTCOMES}
    return out


# ---- Figs. 4, 5 and 7(c-f): single executions with and without feedback -----------------

#: The single executions of the paper's Figs. 4, 5, 7(c-f): ``(figure, scenario, case used
#: for the controller, parameter change, caption)``. "Much stiffer" (Fig. 5) is E = 150
#: (three times the planning value; the paper gives no number). Fig. 7(c, d) "variation
#: in material parameters": E = 35 (two standard deviations of case 2 below the mean,
#: a softer object that deforms more); Fig. 7(e, f) "mesh elements increased": 1000
#: elements (the top of case 4's range) instead of the planning mesh's 175.
SINGLE_RUNS = (
    ("fig4", "needle", "actuation", {"actuation": True}, "Fig. 4: actuation noise"),
    (
        "fig5",
        "needle",
        "material-high",
        {"youngs_modulus": 150.0},
        "Fig. 5: a much stiffer material (E = 150)",
    ),
    (
        "fig7cd",
        "manipulation",
        "material-high",
        {"youngs_modulus": 35.0},
        "Fig. 7(c, d): softer material (E = 35)",
    ),
    ("fig7ef", "manipulation", "mesh", {"n_elements": 1000}, "Fig. 7(e, f): a 1000-element mesh"),
)


def single_executions(name: str, plans_and_controllers: dict, *, seed: int = 0) -> dict:
    """Executions of the ``ours`` plan of ``name`` without and with feedback for the
    :data:`SINGLE_RUNS` of that scenario.

    ``plans_and_controllers[case] = (plan, controller)``. Returns ``{fig: {"open": Execution,
    "closed": Execution, "params": SimParams, "caption": str}}`` (states kept for plots).
    """
    from riskplan.control.lqg import execute
    from riskplan.scenarios.registry import make_scenario

    out = {}
    for fig, scen, case, change, caption in SINGLE_RUNS:
        if scen != name or case not in plans_and_controllers:
            continue
        sim = make_scenario(name, case)
        plan, ctrl = plans_and_controllers[case]
        change = dict(change)
        params = sim.nominal_params
        if change.pop("actuation", False):
            params = sim.distribution.sample(_seed_for(seed, fig, "actuation"))
        params = params.replace(**change)
        gen_seed = _seed_for(seed, fig, "sensing")
        out[fig] = {
            "open": execute(sim, plan, None, params, seed=gen_seed),
            "closed": execute(sim, plan, ctrl, params, seed=gen_seed),
            "params": params,
            "caption": caption,
            "sim": sim,
        }
    return out


def _feedback_rates(name, scale, store, chosen, plans, sims, seed, pmap, report, pre=None) -> dict:
    """``{figure: paired summary}`` (:func:`paired_summary`) for the conditions
    of scenario ``name`` whose case ran: the ``ours`` plan of that case executed open and
    closed loop on ``scale.n_feedback`` common draws, in stored batches (resumable)."""
    from riskplan.parallel import spawn_seeds

    n, bs = int(scale.n_feedback), scale.batch_size
    figs = [f for f, c in CONDITIONS.items() if c.scenario == name and (c.case, "ours") in chosen]
    if n == 0 or not figs:
        return {}
    n_batches = -(-n // bs)
    items = [(f, b) for f in figs for b in range(n_batches)]
    pre = pre or f"fig6.{name}"
    key = {it: f"{pre}.feedback.{it[0]}.b{it[1]:05d}" for it in items}
    rows = {it: store.get(key[it]) for it in items}
    todo = [it for it in items if rows[it] is None]
    seeds = {f: spawn_seeds(_seed_for(seed, name, "feedback", f), n) for f in figs}
    done = len(items) - len(todo)
    report(f"{name}: open vs closed loop", done * bs, len(items) * bs)

    def task(it):
        f, b = it
        case = CONDITIONS[f].case
        s, j, sel = chosen[case, "ours"]
        return (sims[case], plans[s][j], sel["controller"], f, seeds[f][b * bs : (b + 1) * bs])

    for i, res in pmap(feedback_batch, [task(it) for it in todo]):
        rows[todo[i]] = res
        store.put(key[todo[i]], res)
        done += 1
        report(f"{name}: open vs closed loop", done * bs, len(items) * bs)
    out = {}
    for f in figs:
        summary = paired_summary([r for b in range(n_batches) for r in rows[f, b]])
        case = CONDITIONS[f].case
        _set, j, sel = chosen[case, "ours"]
        summary.update(
            caption=CONDITIONS[f].caption,
            case=case,
            candidate=j,
            controller_error=sel.get("error"),
        )
        out[f] = summary
    return out
