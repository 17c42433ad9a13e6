"""``riskplan demo``: :mod:`~riskplan.app.demo.pipeline` runs the stages (one module per
area: robot, kinematics, collision, tissue, planning, planning_tissue) into one report."""
