"""Shared test helpers: one seeded generator and the numeric tolerances in one place."""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")
# Ray binds every node of a test cluster to the loopback address (127.0.0.1) instead of the
# machine's network address: tests never send traffic off the machine.
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")

import numpy as np
import pytest
import torch

torch.set_num_threads(1)

# Tolerances (rtol, atol) by kind of comparison. Every numeric assertion names one.
TOL = {
    "float64_exact": dict(rtol=1e-12, atol=1e-12),  # same arithmetic, different order
    "float64_ref": dict(rtol=1e-8, atol=1e-8),  # against an independent float64 reference
    "float32_ref": dict(rtol=1e-4, atol=1e-5),
    "solver": dict(rtol=1e-6, atol=1e-9),  # iterative solver at its default tolerance
}


@pytest.fixture
def rng() -> np.random.Generator:
    """The one seeded generator tests draw from."""
    return np.random.default_rng(20111)


@pytest.fixture
def tol():
    return TOL
