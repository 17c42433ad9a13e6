"""The numbers the two papers publish, with where they stand, so every reproduced figure can
be shown beside its published value.

Sources (section / figure of each paper as cited):

* ``DEFORMABLE``: S. Patil, J. van den Berg, R. Alterovitz, "Motion Planning Under
  Uncertainty in Highly Deformable Environments", RSS 2011, section V.
* ``MDN``: B. Thompson, A. Cho, D. Brown, A. Kuntz, "Modeling Kinematic Uncertainty of
  Tendon-Driven Continuum Robots via Mixture Density Networks" (the MDN paper), sections V-VI.

Only what the text states is recorded. The bar heights of the deformable paper's Fig. 6 are
not given as numbers in the text, so they are absent here (the report says so); its claims
are.
"""

from __future__ import annotations

__all__ = ["DEFORMABLE", "MDN"]

DEFORMABLE = {
    "executions_per_case": {
        "value": 1000,
        "where": "§V-A: 'we simulate 1000 executions of the planner solution'",
    },
    "candidates": {"value": 100, "where": "§V-A and §V-B: 'a set of 100 candidate motion plans'"},
    "needle_rrt_s": {"value": 81.0, "where": "§V-A: 100 candidate plans 'took 81 seconds'"},
    "needle_select_s": {
        "value": 57.0,
        "where": "§V-A: linearisation, LQG and LQG-MP selection 'took 57 seconds'",
    },
    "manipulation_rrt_s": {"value": 438.0, "where": "§V-B: 100 candidate plans 'took 438 seconds'"},
    "manipulation_select_s": {"value": 386.0, "where": "§V-B: selection 'took 386 seconds'"},
    "ours_highest": {
        "value": True,
        "where": "§V-A, Fig. 6: 'our method consistently yields a significantly higher probability of success'",
    },
    "no_select_vs_rrt": {
        "value": 34.0,
        "where": "§V-A: 'our method without the LQG-MP step performed 34% better than RRT with deformations' "
        "(averaged across the scenarios; percent points or relative: not said)",
    },
    "no_select_vs_ours": {
        "value": -17.0,
        "where": "§V-A: '... and 17% worse than our complete method' (averaged across the scenarios)",
    },
    "fig6_bars": {"value": None, "where": "Fig. 6: bar heights are drawn, not printed"},
}

MDN = {
    "fig4_best_k": {
        "value": 5,
        "where": "MDN paper §V, Fig. 4: 'five mixture components minimize the negative log-likelihood the most "
        "while avoiding mode collapse' (K = 1..10; the NLL values are drawn, not printed)",
    },
    "mdn_ms": {
        "value": 0.33,
        "where": "MDN paper §V: mean MDN time over 10,000 random configurations, 0.33 ms",
    },
    "cosserat_ms": {
        "value": 0.39,
        "where": "MDN paper §V, quoting its ref. [8]: Cosserat rod model 0.39 ms",
    },
    "speedup_percent": {
        "value": 15.0,
        "where": "MDN paper §V: 'a 15% reduction in computation time'",
    },
    "train_configs": {
        "value": 2277,
        "where": "MDN paper §IV: 2,277 training and 253 test configurations",
    },
    "bo_iterations": {
        "value": 50,
        "where": "MDN paper §VI, Fig. 7: 50 iterations of Bayesian optimisation",
    },
    "collision_before": {
        "value": 0.15,
        "where": "MDN paper §VI (Fig. 7): probability of collision of the PRM path, about 15 %",
    },
    "collision_after": {
        "value": 0.07,
        "where": "MDN paper §VI (Fig. 7): after Bayesian optimisation, below 7 %",
    },
}
