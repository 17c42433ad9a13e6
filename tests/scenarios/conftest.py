"""Fixtures of the tissue-scenario tests: one scenario object per module (FEM models cached)."""

from __future__ import annotations

import pytest

from riskplan.scenarios.manipulation import ManipulationScenario
from riskplan.scenarios.needle import NeedleScenario


@pytest.fixture(scope="module")
def needle():
    return NeedleScenario()


@pytest.fixture(scope="module")
def manip():
    return ManipulationScenario()
