"""Planning in deformable tissue (Patil, van den Berg & Alterovitz, RSS 2011): the simulator
RRT (:mod:`~riskplan.tissue_planning.rrt`), LQG-MP plan selection
(:mod:`~riskplan.tissue_planning.select`) and the method end to end
(:func:`~riskplan.tissue_planning.plan.plan_tissue`).

The tissue wing's top: it imports ``scenarios`` and ``control`` and never the kinematic wing.
"""
