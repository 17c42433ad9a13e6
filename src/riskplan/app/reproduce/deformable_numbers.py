"""The numbers of the deformable paper's Fig. 6 (:mod:`riskplan.app.reproduce.deformable`):
each method's outcome counts with a 95 % Wilson interval per case, the mechanism (the
same plan open and closed loop on the same draws), every candidate's LQG-MP values, and
the paper's claims checked on the measured rates (:func:`claims`, :func:`highest_verdict`).
"""

from __future__ import annotations

import numpy as np

from riskplan.app.reproduce.deformable_setup import METHODS, OPEN_LOOP
from riskplan.app.reproduce.deformable_tasks import _outcome_counts
from riskplan.app.reproduce.feedback import paired_outcomes

__all__ = ["case_numbers", "claims", "highest_verdict", "mechanism", "selection_values"]


def _wilson(k: int, n: int) -> tuple[float, float]:
    from riskplan.collision import binomial_interval

    lo, hi = binomial_interval(k, n, confidence=0.95)
    return float(lo), float(hi)


def claims(cases: dict) -> dict:
    """The paper's Fig. 6 claims checked on measured rates (§V-A).

    * ``ours_highest[case]``: ours has a strictly higher rate than every other applicable
      method; ``ours_tied[case]``: ours shares the highest rate with at least one other
      method (a tie is reported as a tie, not as "highest"); ``ours_highest_all``: strictly
      highest in every case; ``ours_separated[case]`` whether its Wilson interval lies
      above every other method's.
    * "without LQG-MP: 34 % better than RRT with deformations and 17 % worse than the
      complete method, averaged over cases": the paper does not say whether percent points
      or relative change; both readings, on the rates averaged over the cases:
      ``points = 100 (r̄_a − r̄_b)`` and ``relative = 100 (r̄_a / r̄_b − 1)``.
    """
    highest, tied, separated = {}, {}, {}
    for c, ms in cases.items():
        ours = ms["ours"]
        others = [v for m, v in ms.items() if m != "ours" and v is not None]
        best_other = max((o["rate"] for o in others), default=-1.0)
        highest[c] = ours["rate"] > best_other
        tied[c] = ours["rate"] == best_other
        separated[c] = all(ours["low"] > o["high"] for o in others)

    def mean_rate(m):
        return float(np.mean([ms[m]["rate"] for ms in cases.values()]))

    r_rrt, r_ns, r_ours = mean_rate("rrt"), mean_rate("ours_no_select"), mean_rate("ours")

    def rel(a, b):
        return None if b == 0 else 100.0 * (a / b - 1.0)

    return {
        "ours_highest": highest,
        "ours_tied": tied,
        "ours_highest_all": all(highest.values()),
        "ours_separated": separated,
        "mean_rate": {"rrt": r_rrt, "ours_no_select": r_ns, "ours": r_ours},
        "no_select_vs_rrt": {
            "points": 100.0 * (r_ns - r_rrt),
            "relative": rel(r_ns, r_rrt),
            "paper": 34.0,
        },
        "no_select_vs_ours": {
            "points": 100.0 * (r_ns - r_ours),
            "relative": rel(r_ns, r_ours),
            "paper": -17.0,
        },
    }


def highest_verdict(cl: dict) -> str:
    """ "ours highest in every case": yes only when strictly highest in every case; ties
    are named as ties (``cl`` from :func:`claims`)."""
    strict = cl["ours_highest"]
    ties = cl.get("ours_tied", {})
    if cl["ours_highest_all"]:
        return "yes"
    parts = []
    tied = [c for c, t in ties.items() if t]
    lower = [c for c, ok in strict.items() if not ok and not ties.get(c)]
    if tied:
        parts.append("tied for highest in " + ", ".join(tied))
    if lower:
        parts.append("below another method in " + ", ".join(lower))
    return "no (" + "; ".join(parts) + ")"


def _rows(flags: dict, case: str, method: str, n_batches: int) -> list:
    """The execution rows of ``(case, method)``, batch after batch."""
    return [row for b in range(n_batches) for row in flags[case, method, b]]


def case_numbers(
    cases, na: dict, flags: dict, n_batches: int, chosen: dict, ties: dict, plans: dict
) -> dict:
    """``{case: {method: counts}}`` of the executed methods (``None`` where a method does
    not apply: ``na``), from the ``n_batches`` stored batches ``flags[case, method, batch]``,
    the choice
    ``chosen[case, method] = (set, candidate, selection)`` and ``ties[case, method]`` (the
    candidates sharing the best LQG-MP value); the keys as
    :func:`riskplan.app.reproduce.deformable.run_scenario` documents them."""
    from riskplan.tissue_planning.select import tie_note

    out_cases: dict = {}
    for c in cases:
        out_cases[c] = {}
        for m in METHODS:
            if m in na:
                out_cases[c][m] = None
                continue
            f, reasons = _outcome_counts(_rows(flags, c, m, n_batches))
            k = int(f[:, 0].sum())
            lo, hi = _wilson(k, len(f))
            s, j, sel = chosen[c, m]
            out_cases[c][m] = {
                "successes": k,
                "n": len(f),
                "rate": k / len(f),
                "low": lo,
                "high": hi,
                "collided": int(f[:, 1].sum()),
                "missed_goal": int(
                    ((f[:, 0] == 0) & (f[:, 1] == 0) & (f[:, 3] == 0) & (f[:, 4] == 0)).sum()
                ),
                "solver_failed": int(f[:, 3].sum()),
                "left_tissue": int(f[:, 4].sum()),
                "solver_failure_reasons": reasons,
                "predicted": None if m in OPEN_LOOP else sel["p_success"],
                "controller_error": None if m in OPEN_LOOP else sel.get("error"),
                "candidate_set": s,
                "candidate": j,
                "n_tied": ties.get((c, m)),
                "tie": None
                if (c, m) not in ties
                else tie_note(ties[c, m], len(plans[s]), sel["p_success"]),
            }
    return out_cases


def mechanism(cases, flags: dict, n_batches: int, chosen: dict) -> dict:
    """``{case: paired_outcomes}``: the plan of ``rrt_margins`` open loop against the same
    plan closed loop (``ours_no_select``) on the same draws, for the cases where both ran."""
    out = {}
    for c in cases:
        if (c, "rrt_margins") not in chosen or (c, "ours_no_select") not in chosen:
            continue
        rows = {
            m: _outcome_counts(_rows(flags, c, m, n_batches))[0]
            for m in ("rrt_margins", "ours_no_select")
        }
        out[c] = paired_outcomes(rows["rrt_margins"][:, 0], rows["ours_no_select"][:, 0])
    return out


def selection_values(cases, selected_sets, selection: dict, plans: dict) -> dict:
    """``{case: {set: [LQG-MP values of each candidate]}}``: the stored selection results
    without their controllers."""
    return {
        c: {
            s: [
                {k: v for k, v in selection[c, s, j].items() if k != "controller"}
                for j in range(len(plans[s]))
            ]
            for s in selected_sets
        }
        for c in cases
    }
