"""Tissue scenarios of the deformable-planning paper: the :class:`~riskplan.scenarios.base.Simulator`
protocol, the needle and manipulation scenarios, their uncertainty cases and scenario files.

Modules are imported on demand (``from riskplan.scenarios.registry import make_scenario``);
this package imports nothing heavy at import time.
"""
