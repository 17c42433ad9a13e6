"""Planning under uncertainty in deformable tissue, end to end (Patil, van den Berg &
Alterovitz, RSS 2011, Fig. 2): simulator RRT candidates → linearisation, LQG and LQG-MP
selection → the LQG-MP estimate checked against closed-loop executions.

:func:`plan_tissue` is the tissue wing's twin of :func:`riskplan.planning.chest.plan_chest`;
what ``riskplan plan tissue`` writes is in :mod:`riskplan.app.outputs.tissue_plan`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from riskplan.errors import InvalidInputError
from riskplan.parallel import spawn_seeds

__all__ = ["STEP_S", "TissuePlanningResult", "check_tissue_budget", "plan_tissue"]


@dataclass
class TissuePlanningResult:
    """Everything one run produces: the scenario (``sim``, with the case's distribution),
    ``plans``, ``trees``, the :class:`~riskplan.tissue_planning.select.Selection`, the honesty rows
    and wall-clock ``timings`` (seconds: ``rrt``, ``selection``, ``check``)."""

    scenario: str
    case: str
    seed: int
    sim: object
    plans: list
    trees: list
    selection: object
    honesty: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)


def plan_tissue(
    scenario: str = "needle",
    *,
    n_plans: int = 100,
    case: str = "material-high",
    seed: int = 0,
    workers: int | None = None,
    backend: str = "local",
    rrt_options=None,
    method: str = "sigma",
    n_samples: int = 16,
    check_runs: int = 1000,
    check_others: int = 2,
    on_tree=None,
    on_plan=None,
    on_check=None,
) -> TissuePlanningResult:
    """Run the method on one scenario (``"needle"`` or ``"manipulation"``) and uncertainty
    ``case`` (:data:`riskplan.scenarios.uncertainty.CASE_NAMES`).

    ``n_plans`` candidates from :func:`~riskplan.tissue_planning.rrt.rrt_plans`, selection by
    :func:`~riskplan.tissue_planning.select.select_plan` (``method``, ``n_samples`` parameter draws
    per step for ``M_t``), then ``check_runs`` closed-loop executions for the selected plan
    and ``check_others`` more (``check_runs = 0`` skips the check). ``on_tree(i, tree)``,
    ``on_plan(i, score)``, ``on_check(row)`` report progress. The trees, the selection and
    the check draw from three streams ``spawn_seeds(seed, 3)``
    (:func:`riskplan.parallel.spawn_seeds`).
    """
    from riskplan._validation import check_count
    from riskplan.control.lqgmp import METHODS
    from riskplan.scenarios.registry import make_scenario
    from riskplan.tissue_planning.rrt import RRTOptions, rrt_plans
    from riskplan.tissue_planning.select import honesty_check, select_plan

    # every argument checked before the trees grow (a bad method used to fail after them)
    if method not in METHODS:
        raise InvalidInputError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
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
    selection = select_plan(
        sim,
        plans,
        sim.distribution,
        method=method,
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
        rows = honesty_check(
            sim,
            plans,
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
    return TissuePlanningResult(scenario, case, seed, sim, plans, trees, selection, rows, timings)


#: least time of one simulator step (s): a tenth of the measured 16.5 µs of a needle step on
#: the 175-element mesh (README, `riskplan tissue step-cost`, 2-core AMD EPYC, shared); the
#: manipulation step is 50 times slower
STEP_S = 1.65e-6


def check_tissue_budget(sim, *, n_plans: int, check_runs: int, check_others: int) -> None:
    """Refuse a run whose work exceeds the budget (:mod:`riskplan.budget`) before any work:
    the candidates (``--plans``: each keeps at least two simulator states, the mesh
    displacement at 2 float64 per node) and the Monte Carlo check (``--check-runs``
    executions of each checked plan, each at least one simulator step)."""
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
