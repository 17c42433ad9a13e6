"""LQG-MP's estimate against closed-loop executions (beyond the deformable-planning paper,
Patil, van den Berg & Alterovitz, RSS 2011, which never says how good the estimate is).

:func:`calibration_check` puts the LQG-MP ``P(success)`` of the selected plan
(:func:`~riskplan.tissue_planning.select.select_plan`) and of others at even quantiles of
the ranking next to the success rate of ``n ≥ 1000`` closed-loop executions on the true
simulator (each with its own ``s ~ S``, actuation and sensing noise;
:func:`riskplan.control.lqg.monte_carlo_success`) with a 95 % Wilson interval.
:func:`calibration_metrics` scores predicted probabilities against measured rates over many
(plan, case) pairs: mean absolute error and Spearman's rank correlation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan._validation import check_count
from riskplan.errors import InvalidInputError

__all__ = [
    "SATURATED",
    "Calibration",
    "CalibrationRow",
    "calibration_check",
    "calibration_metrics",
    "evenly_spaced_ranks",
]


@dataclass(frozen=True)
class CalibrationRow:
    """One candidate in the check: its LQG-MP ``p_lqgmp`` and the Monte Carlo success rate
    ``p_mc`` of ``n`` closed-loop executions with its 95 % interval ``[low, high]``, and
    whether the estimate lies inside that interval.

    ``index`` is the candidate's 0-based position in the candidate list (as in
    ``candidates.npz``); ``rank`` its 1-based place in the LQG-MP ranking (1 = the selected
    plan), the same count in tables and files."""

    index: int
    rank: int
    p_lqgmp: float
    p_mc: float
    low: float
    high: float
    n: int

    @property
    def inside(self) -> bool:
        """Whether the estimate lies in the Monte Carlo interval: ``low ≤ p_lqgmp ≤ high``.

        Returns
        -------
        bool
            ``True`` when the LQG-MP estimate is inside the 95 % interval.
        """
        return self.low <= self.p_lqgmp <= self.high


def calibration_check(
    sim,
    plans,
    selection,
    distribution=None,
    *,
    others: int = 2,
    n: int = 1000,
    seed=0,
    backend: str = "local",
    workers: int | None = None,
    on_row=None,
) -> list[CalibrationRow]:
    """LQG-MP ``P(success)`` against the success rate of ``n`` closed-loop LQG executions
    for the selected plan and ``others`` more (at even quantiles of the ranking, down to the
    worst usable candidate).

    Parameters
    ----------
    sim : Simulator
        The true simulator.
    plans : list of NominalPlan
        The candidates, as given to :func:`~riskplan.tissue_planning.select_plan`.
    selection : Selection
        Its result (the ranking and every candidate's controller).
    distribution : ParamDistribution or None
        Each execution draws ``s ~ distribution`` (``None``: ``sim.distribution``) and its
        sensing noise (:func:`riskplan.control.lqg.monte_carlo_success`).
    others : int
        Candidates checked beside the selected one.
    n : int
        Executions per candidate.
    seed : int or None
        Root of the candidates' seeds.
    backend, workers
        As in :func:`riskplan.parallel.map_tasks`.
    on_row : callable, optional
        ``on_row(row)``, called as each candidate's check finishes.

    Returns
    -------
    list of CalibrationRow
        One row per candidate checked, the selected plan first.
    """
    from riskplan.control.lqg import monte_carlo_success
    from riskplan.parallel import spawn_seeds

    n = check_count(n, "n", 1, integral=True)
    others = check_count(others, "others", 0, integral=True)
    distribution = getattr(sim, "distribution", None) if distribution is None else distribution
    usable = [s for s in selection.ranking if s.error is None]
    # the selected plan, then ``others`` ranks at even quantiles of the rest (the last one the worst)
    k = min(int(others), len(usable) - 1)
    picks = [0] + sorted(
        set(np.linspace(0, len(usable) - 1, k + 1)[1:].round().astype(int).tolist())
    )
    seeds = spawn_seeds(seed, len(picks))
    rows = []
    for rank, s in zip(picks, seeds):
        score = usable[rank]
        est = monte_carlo_success(
            sim,
            plans[score.index],
            selection.controllers[score.index],
            distribution,
            n=int(n),
            seed=s,
            backend=backend,
            workers=workers,
        )
        rows.append(
            CalibrationRow(
                index=score.index,
                rank=rank + 1,
                p_lqgmp=score.p_success,
                p_mc=est.probability,
                low=est.low,
                high=est.high,
                n=est.n,
            )
        )
        if on_row is not None:
            on_row(rows[-1])
    return rows


# ---- calibration of a predicted P(success) against measured rates (beyond the paper) -----

#: A set of measured rates all at or above this says nothing about calibration: every
#: estimator that predicts "near 1" scores well on it (issue: a saturated set).
SATURATED = 0.98


@dataclass(frozen=True)
class Calibration:
    """How well predicted probabilities match measured rates over ``n_plans`` (plan, case)
    pairs (:func:`calibration_metrics`).

    ``mae``: mean absolute error ``(1/n) Σ |p̂_i − r_i|``; ``spearman``: Spearman's rank
    correlation of ``p̂`` and ``r`` (``None`` where undefined: fewer than 3 pairs or a
    constant side); ``measured_spread``: ``max r − min r``; ``measured_min``,
    ``measured_max``; ``informative``: the set can judge calibration — the rank correlation
    is defined and not every measured rate is ``≥`` :data:`SATURATED`; ``meets_goal``:
    informative, ``mae ≤ mae_goal`` and ``spearman ≥ spearman_goal``.
    """

    mae: float
    spearman: float | None
    n_plans: int
    measured_spread: float
    measured_min: float
    measured_max: float
    informative: bool
    meets_goal: bool

    def as_dict(self) -> dict:
        """The fields as a JSON-serialisable dict.

        Returns
        -------
        dict
            The fields by name.
        """
        from dataclasses import asdict

        return asdict(self)


def calibration_metrics(
    predicted, measured, *, mae_goal: float = 0.05, spearman_goal: float = 0.8
) -> Calibration:
    """Calibration of predicted probabilities against measured success rates: mean absolute
    error, Spearman's rank correlation (:func:`scipy.stats.spearmanr`, ties by average rank)
    and the spread of the measured rates.

    Parameters
    ----------
    predicted : array_like
        ``(n,)`` predicted probabilities ``p̂_i`` in [0, 1].
    measured : array_like
        ``(n,)`` measured success rates ``r_i`` in [0, 1].
    mae_goal : float
        The goal for the mean absolute error (``meets_goal``).
    spearman_goal : float
        The goal for the rank correlation (``meets_goal``).

    Returns
    -------
    Calibration
        The metrics. Raises :class:`~riskplan.errors.InvalidInputError` for mismatched
        shapes, an empty set, or values outside [0, 1].
    """
    import warnings

    from scipy.stats import spearmanr

    p = np.asarray(predicted, dtype=np.float64)
    r = np.asarray(measured, dtype=np.float64)
    if p.ndim != 1 or r.shape != p.shape or p.size == 0:
        raise InvalidInputError(
            f"predicted, measured: expected two equal non-empty 1-D arrays, got shapes {p.shape} and {r.shape}"
        )
    for name, v in (("predicted", p), ("measured", r)):
        if not np.all(np.isfinite(v)) or v.min() < 0.0 or v.max() > 1.0:
            raise InvalidInputError(f"{name}: expected probabilities in [0, 1]")
    mae = float(np.abs(p - r).mean())
    rho = None
    if p.size >= 3 and np.ptp(p) > 0 and np.ptp(r) > 0:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # ConstantInputWarning is excluded above
            rho = float(spearmanr(p, r).statistic)
        if not np.isfinite(rho):
            rho = None
    informative = rho is not None and bool(r.min() < SATURATED)
    return Calibration(
        mae=mae,
        spearman=rho,
        n_plans=int(p.size),
        measured_spread=float(r.max() - r.min()),
        measured_min=float(r.min()),
        measured_max=float(r.max()),
        informative=informative,
        meets_goal=bool(informative and mae <= mae_goal and rho >= spearman_goal),
    )


def evenly_spaced_ranks(n: int, k: int) -> list[int]:
    """``min(k, n)`` distinct ranks ``0 … n − 1`` evenly spaced over the ranking (the first
    and the last included): ``round(linspace(0, n − 1, k))``; all ranks when ``k ≥ n``.

    Parameters
    ----------
    n : int
        Number of ranks (positive).
    k : int
        Number of ranks wanted (positive).

    Returns
    -------
    list of int
        The ranks, ascending.
    """
    n, k = check_count(n, "n", 1, integral=True), check_count(k, "k", 1, integral=True)
    if k >= n:
        return list(range(int(n)))
    return sorted(set(np.linspace(0, n - 1, int(k)).round().astype(int).tolist()))
