"""Fixtures of the data-set tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def robot():
    from riskplan.robots import load_robot

    return load_robot("paper")
