"""The methods, uncertainty cases and sizes of the deformable paper's Fig. 6
(:mod:`riskplan.app.reproduce.deformable`, whose docstring describes the methods):
:data:`METHODS` with their labels, which run open loop and which candidate sets LQG-MP
ranks, the five cases :data:`EVAL_CASES`, the methods a scenario has no plan for
(:data:`NOT_APPLICABLE`), and the sizes of a run (:class:`ScenarioScale`, the named
:data:`SCALES`).
"""

from __future__ import annotations

from dataclasses import dataclass

from riskplan._validation import check_count

__all__ = [
    "EVAL_CASES",
    "METHODS",
    "METHOD_LABELS",
    "NOT_APPLICABLE",
    "OPEN_LOOP",
    "SCALES",
    "SELECTED_SETS",
    "ScenarioScale",
]

METHODS = ("rrt", "rrt_margins", "lqgmp_only", "ours_no_select", "ours")
METHOD_LABELS = {
    "rrt": "RRT with deformations (plain RRT, open loop)",
    "rrt_margins": "RRT with deformations, our RRT's margins (open loop)",
    "lqgmp_only": "LQG-MP only (static plans)",
    "ours_no_select": "ours without LQG-MP selection",
    "ours": "ours",
}
#: Methods executed without feedback.
OPEN_LOOP = ("rrt", "rrt_margins")
#: Candidate sets that are linearised and ranked by LQG-MP.
SELECTED_SETS = ("deforming", "static")

#: The paper's five uncertainty cases (riskplan.scenarios.uncertainty.CASE_NAMES minus nominal).
EVAL_CASES = ("material-low", "material-high", "actuation", "mesh", "force")

NOT_APPLICABLE = {
    "manipulation": {
        "lqgmp_only": "no static plan exists: without force the target never moves (paper §V-A defines this baseline for the needle)"
    }
}


@dataclass(frozen=True)
class ScenarioScale:
    """Sizes of one scenario's evaluation.

    ``n_candidates``: RRT candidates per set (paper: 100); ``n_executions`` per method and
    case (paper: 1000); ``batch_size``: executions per stored work unit; ``lin_samples``:
    parameter draws for ``M_t``; ``goal_samples``: LQG-MP draws for ``P(goal)``;
    ``plans_per_tree`` / ``max_iterations`` / ``n_controls``: the RRT budget
    (:class:`riskplan.tissue_planning.rrt.RRTOptions`); ``n_feedback``: executions of each
    open-vs-closed condition of :mod:`riskplan.app.reproduce.feedback` (Figs. 4, 5 and
    7(c-f) as rates; 0: not run).
    """

    n_candidates: int
    n_executions: int
    batch_size: int
    lin_samples: int = 16
    goal_samples: int = 2000
    plans_per_tree: int = 5
    max_iterations: int = 4000
    n_controls: int = 6
    n_feedback: int = 0

    def __post_init__(self):
        for name in (
            "n_candidates",
            "n_executions",
            "batch_size",
            "plans_per_tree",
            "max_iterations",
            "n_controls",
            "goal_samples",
        ):
            check_count(getattr(self, name), name, 1)
        check_count(self.n_feedback, "n_feedback", 0)
        check_count(self.lin_samples, "lin_samples", 2)

    def rrt_options(self):
        from riskplan.tissue_planning.rrt import RRTOptions

        return RRTOptions(
            n_controls=self.n_controls,
            max_iterations=self.max_iterations,
            plans_per_tree=self.plans_per_tree,
        )


#: Named scales. ``smoke`` fits ``riskplan reproduce --paper all`` in about 5 minutes on two
#: cores; ``paper`` is the paper's (100 candidates, 1000 executions per method and case).
SCALES: dict[str, dict[str, ScenarioScale]] = {
    "smoke": {
        "needle": ScenarioScale(
            n_candidates=2,
            n_executions=20,
            batch_size=10,
            lin_samples=6,
            goal_samples=300,
            plans_per_tree=2,
            n_feedback=10,
        ),
        "manipulation": ScenarioScale(
            n_candidates=2,
            n_executions=6,
            batch_size=3,
            lin_samples=4,
            goal_samples=300,
            plans_per_tree=2,
            n_feedback=10,
        ),
    },
    "paper": {
        "needle": ScenarioScale(
            n_candidates=100, n_executions=1000, batch_size=50, plans_per_tree=10, n_feedback=200
        ),
        "manipulation": ScenarioScale(
            n_candidates=100,
            n_executions=1000,
            batch_size=20,
            plans_per_tree=10,
            n_feedback=200,
        ),
    },
}
