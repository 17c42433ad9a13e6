"""Scenarios: procedural environments and task set-ups used by the experiments.

Modules are imported on demand (``from riskplan.scenarios.chest import build_chest``);
this package imports nothing heavy at import time.
"""
