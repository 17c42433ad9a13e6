"""``riskplan plan ...``: the planners (chest cavity: PRM + Bayesian optimisation; deformable
tissue: simulator RRT + LQG-MP selection). Each planner registers its subcommand from its own
module (``plan_chest``, ``plan_tissue``) so they stay independent."""

from __future__ import annotations

import importlib

import typer

PLANNERS = ("plan_chest", "plan_robot", "plan_tissue", "plan_needle3d")


def register(app: typer.Typer) -> None:
    from riskplan.commands._shared import add_group

    plan_app = add_group(
        app,
        "plan",
        "Plan motions under uncertainty (chest cavity, any robot in any anatomy, deformable tissue).",
    )
    for name in PLANNERS:
        importlib.import_module(f"riskplan.commands.{name}").register(plan_app)
