"""Planning under uncertainty in deformable tissue, end to end (Patil, van den Berg &
Alterovitz, RSS 2011, Fig. 2): simulator RRT candidates → linearisation, LQG and LQG-MP
selection → the LQG-MP estimate checked against closed-loop executions.

:func:`plan_tissue` is the tissue wing's twin of :func:`riskplan.planning.chest.plan_chest`;
what ``riskplan plan tissue`` writes is in ``riskplan.app.outputs.tissue_plan`` (the application layer).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from riskplan.errors import InvalidInputError
from riskplan.parallel import spawn_seeds

__all__ = [
    "SELECTIONS",
    "STEP_S",
    "TissuePlanningResult",
    "check_tissue_budget",
    "plan_tissue",
    "selection_setup",
]

#: How ``plan tissue`` selects (``selection=``): ``"paper"`` is the paper's σ-distance on
#: the world-frame LQG; ``"calibrated"`` (the default outside the paper reproduction) is,
#: per scenario, the estimator with the lowest mean absolute error against measured
#: closed-loop success in the calibration study at the full scale's plans (docs/control.md,
#: "Calibration": needle Patil truncation on the paper's LQG, mae 0.023, ρ 0.92;
#: manipulation sampling with the persistent-disturbance state, mae 0.049, ρ 0.91);
#: ``"material"``: the needle in its material frame with the bias state (mae 0.023, ρ 0.96,
#: and the controller that does not lose runs at force ×2; ``frame``: the needle's
#: reduced-state frame, ``NeedleScenario.with_frame``).
SELECTIONS = {
    "paper": {
        "needle": {"frame": None, "method": "sigma", "disturbance": False},
        "manipulation": {"frame": None, "method": "sigma", "disturbance": False},
    },
    "calibrated": {
        "needle": {"frame": None, "method": "truncation", "disturbance": False},
        "manipulation": {"frame": None, "method": "sampling", "disturbance": True},
    },
    "material": {
        "needle": {"frame": "material", "method": "sampling", "disturbance": True},
        "manipulation": {"frame": None, "method": "sampling", "disturbance": True},
    },
}


def selection_setup(sim, plans, selection: str):
    """The simulator, plans, LQG-MP method and controller of a :data:`SELECTIONS` entry.

    Parameters
    ----------
    sim : the scenario (its ``name``, a scenario file's kind, picks the entry).
    plans : the candidate :class:`~riskplan.control.NominalPlan` list.
    selection : ``"calibrated"``, ``"material"`` or ``"paper"``.

    Returns
    -------
    ``(sim, plans, method, disturbance)``: the simulator and plans in the entry's frame
    (:meth:`~riskplan.control.NominalPlan.reframed`), its method and whether the
    controller carries the persistent-disturbance state.
    """
    if selection not in SELECTIONS:
        raise InvalidInputError(
            f"selection: expected one of {', '.join(SELECTIONS)}, got {selection!r}"
        )
    entry = SELECTIONS[selection].get(getattr(sim, "name", ""), SELECTIONS["paper"]["needle"])
    if entry["frame"] is not None and callable(getattr(sim, "with_frame", None)):
        sim = sim.with_frame(entry["frame"])
        plans = [p.reframed(sim) for p in plans]
    return sim, plans, entry["method"], entry["disturbance"]


@dataclass
class TissuePlanningResult:
    """Everything one run produces: the scenario (``sim``, with the case's distribution),
    ``plans``, ``trees``, the :class:`~riskplan.tissue_planning.select.Selection`, the
    calibration check's rows ``calibration_rows``
    (:class:`~riskplan.tissue_planning.calibration.CalibrationRow`) and wall-clock ``timings`` (seconds: ``rrt``, ``selection``, ``check``);
    ``selection_mode`` (:data:`SELECTIONS`) and ``frame`` (the needle's reduced-state frame
    of the selection; ``selection.plan`` and its controller are in it)."""

    scenario: str
    case: str
    seed: int
    sim: object
    plans: list
    trees: list
    selection: object
    calibration_rows: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    selection_mode: str = "paper"
    frame: str | None = None


def plan_tissue(
    scenario: str = "needle",
    *,
    n_plans: int = 100,
    case: str = "material-high",
    seed: int = 0,
    workers: int | None = None,
    backend: str = "local",
    rrt_options=None,
    method: str | None = None,
    n_samples: int = 16,
    check_runs: int = 1000,
    check_others: int = 2,
    on_tree=None,
    on_plan=None,
    on_check=None,
    selection: str = "calibrated",
) -> TissuePlanningResult:
    """Run the method on one scenario and uncertainty case (deformable paper, Fig. 2).

    ``n_plans`` candidates from :func:`~riskplan.tissue_planning.rrt.rrt_plans`, selection by
    :func:`~riskplan.tissue_planning.select.select_plan`, then ``check_runs`` closed-loop
    executions for the selected plan and ``check_others`` more (``check_runs = 0`` skips the
    check). Trees, selection and check draw from ``spawn_seeds(seed, 3)``.

    Parameters
    ----------
    scenario : str
        ``"needle"`` or ``"manipulation"``.
    n_plans, check_runs, check_others : int
    case : str
        Uncertainty case (:data:`riskplan.scenarios.uncertainty.CASE_NAMES`).
    seed, workers, backend
    rrt_options : RRTOptions, optional
    method : str, optional
        Overrides the selection's LQG-MP method.
    n_samples : int
        Parameter draws per step for ``M_t``.
    on_tree, on_plan, on_check : callable, optional
        ``on_tree(i, tree)``, ``on_plan(i, score)``, ``on_check(row)`` report progress.
    selection : str
        ``"calibrated"`` (default), ``"material"`` or ``"paper"`` (:data:`SELECTIONS`).

    Returns
    -------
    TissuePlanningResult
    """
    from riskplan._validation import check_count
    from riskplan.control.lqgmp import METHODS
    from riskplan.scenarios.registry import make_scenario
    from riskplan.tissue_planning.calibration import calibration_check
    from riskplan.tissue_planning.rrt import RRTOptions, rrt_plans
    from riskplan.tissue_planning.select import select_plan

    # every argument checked before the trees grow (a bad method used to fail after them)
    if method is not None and method not in METHODS:
        raise InvalidInputError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    if selection not in SELECTIONS:
        raise InvalidInputError(
            f"selection: expected one of {', '.join(SELECTIONS)}, got {selection!r}"
        )
    n_plans = check_count(n_plans, "n_plans", 1)
    check_runs = check_count(check_runs, "check_runs", 0)
    check_others = check_count(check_others, "check_others", 0)
    sim = make_scenario(scenario, case)
    check_tissue_budget(sim, n_plans=n_plans, check_runs=check_runs, check_others=check_others)
    options = rrt_options or RRTOptions()
    timings = {}
    t0 = time.perf_counter()
    # trees, selection and check draw from independent streams spawned from seed
    s_rrt, s_select, s_check = spawn_seeds(seed, 3)
    plans, trees = rrt_plans(
        sim, n_plans, seed=s_rrt, options=options, backend=backend, workers=workers, on_tree=on_tree
    )
    timings["rrt"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    ssim, splans, smethod, dist = selection_setup(sim, plans, selection)
    mode = selection
    selection = select_plan(
        ssim,
        splans,
        sim.distribution,
        method=smethod if method is None else method,
        disturbance=dist,
        n_samples=n_samples,
        seed=s_select,
        backend=backend,
        workers=workers,
        on_result=on_plan,
    )
    timings["selection"] = time.perf_counter() - t0
    rows = []
    if check_runs:
        t0 = time.perf_counter()
        rows = calibration_check(
            ssim,
            splans,
            selection,
            sim.distribution,
            others=check_others,
            n=check_runs,
            seed=s_check,
            backend=backend,
            workers=workers,
            on_row=on_check,
        )
        timings["check"] = time.perf_counter() - t0
    return TissuePlanningResult(
        scenario,
        case,
        seed,
        sim,
        plans,
        trees,
        selection,
        rows,
        timings,
        selection_mode=mode,
        frame=getattr(ssim, "frame", None) if ssim is not sim else None,
    )


#: least time of one simulator step (s): a tenth of the measured 16.5 µs of a needle step on
#: the 175-element mesh (README, `riskplan tissue step-cost`, 2-core AMD EPYC, shared); the
#: manipulation step is 50 times slower
STEP_S = 1.65e-6


def check_tissue_budget(sim, *, n_plans: int, check_runs: int, check_others: int) -> None:
    """Refuse a run whose work exceeds the budget (:mod:`riskplan.budget`) before any work.

    The candidates (``--plans``: each keeps at least two simulator states, the mesh
    displacement at 2 float64 per node) and the Monte Carlo check (``--check-runs``
    executions of each checked plan, each at least one simulator step).

    Parameters
    ----------
    sim : Simulator
    n_plans : int
        Candidate plans.
    check_runs : int
        Executions per checked plan.
    check_others : int
        Checked plans besides the selected one.
    """
    from riskplan.budget import check_budget

    nodes = sim.mesh_data(sim.nominal_params.n_elements).mesh.n_nodes
    check_budget(
        f"{n_plans} candidate plans", "--plans", nbytes=float(n_plans) * 2 * 2 * 8.0 * nodes
    )
    n_checked = min(n_plans, 1 + check_others)
    check_budget(
        f"{check_runs} closed-loop executions of {n_checked} plans",
        "--check-runs",
        seconds=float(check_runs) * n_checked * STEP_S,
    )
