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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan.errors import InvalidInputError

__all__ = ["CONDITIONS", "Condition", "condition_params", "feedback_batch", "paired_summary"]


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
