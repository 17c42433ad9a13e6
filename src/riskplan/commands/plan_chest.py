"""``riskplan plan chest``."""

from __future__ import annotations

import typer


def register(plan_app: typer.Typer) -> None:
    """Add the ``chest`` command to the ``riskplan plan`` group."""
