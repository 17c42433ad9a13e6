"""Tissue scenarios of the deformable-planning paper: the :class:`~riskplan.scenarios.base.Simulator`
protocol, the planning space a scenario hands the planner
(:mod:`~riskplan.scenarios.space`), the needle and manipulation scenarios, their uncertainty
cases and scenario files.

The names below load their module on first use (PEP 562), so ``import riskplan.scenarios``
imports nothing heavy: ``from riskplan.scenarios import make_scenario``.
"""

from __future__ import annotations

import importlib

#: public name -> the module of this package that defines it
_HOME = {
    "FEMScenario": "base",
    "SimParams": "values",
    "SimState": "values",
    "Simulator": "base",
    "actuation_noise": "values",
    "apply_actuation_noise": "base",
    "check_control": "base",
    "frozen_array": "values",
    "gaussian_noise": "base",
    "rollout": "base",
    "BoxSpace": "space",
    "PlanningScenario": "space",
    "PlanningSpace": "space",
    "SCENARIO_NAMES": "registry",
    "load_scenario_file": "registry",
    "make_scenario": "registry",
    "scenario_from_config": "registry",
    "SHIPPED_SCENARIOS": "files",
    "read_scenario_config": "files",
    "shipped_path": "files",
    "bevel_twist": "bevel",
    "hat": "bevel",
    "needle_step": "bevel",
    "pose_from_vector": "bevel",
    "pose_step_jacobian": "bevel",
    "pose_vector": "bevel",
    "rk4_needle": "bevel",
    "se3_exp": "bevel",
    "se3_exp_batch": "bevel",
    "read_controls": "controls",
    "ManipulationConfig": "manipulation_config",
    "ManipulationScenario": "manipulation",
    "ManipulationState": "manipulation_config",
    "FRAMES": "base",
    "NeedleConfig": "needle_config",
    "NeedleScenario": "needle",
    "NeedleState": "needle_config",
    "car_steer": "needle_space",
    "car_step": "needle_space",
    "world_pose": "needle_mesh",
    "TetBlock": "tissue3d",
    "TetBlockModel": "tissue3d",
    "grid_for": "tissue3d",
    "PLANNING_ELEMENTS": "needle3d",
    "Needle3DConfig": "needle3d_config",
    "Needle3DScenario": "needle3d",
    "Needle3DState": "needle3d_config",
    "needle3d_steer": "needle3d_space",
    "JACOBIAN_STEP": "needle3d_frames",
    "CONTROL_STEP": "needle3d_moments",
    "TIP_KINDS": "needle3d_moments",
    "draw_frame": "plotting",
    "figure_for": "plotting",
    "frame_indices": "plotting",
    "save_frames": "plotting",
    "save_gif": "plotting",
    "ActuationNoise": "uncertainty",
    "CASE_NAMES": "uncertainty",
    "InteractionForceUncertainty": "uncertainty",
    "MaterialUncertainty": "uncertainty",
    "MeshUncertainty": "uncertainty",
    "Nominal": "uncertainty",
    "ParamDistribution": "uncertainty",
    "WithActuation": "uncertainty",
    "get_case": "uncertainty",
    "needle_actuation_cov": "uncertainty",
}

__all__ = sorted(_HOME)


def __getattr__(name: str):
    module = _HOME.get(name)
    if module is None:
        raise AttributeError(f"module 'riskplan.scenarios' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"riskplan.scenarios.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOME))
