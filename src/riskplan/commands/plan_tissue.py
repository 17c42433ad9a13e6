"""``riskplan plan tissue``."""

from __future__ import annotations

import typer


def register(plan_app: typer.Typer) -> None:
    """Add the ``tissue`` command to the ``riskplan plan`` group."""
