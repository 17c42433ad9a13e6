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
    # float64, same formula or exact cases
    "round_off": dict(rtol=0.0, atol=1e-15),  # exact up to a rounding (straight rod)
    "float64_bits": dict(rtol=1e-15, atol=0.0),  # one formula evaluated twice
    "float64_exact_rel": dict(rtol=1e-12, atol=0.0),  # same arithmetic, relative only
    "float64_abs": dict(rtol=0.0, atol=1e-12),  # exact result, absolute round-off
    "batch_vs_scalar": dict(rtol=1e-10, atol=1e-12),  # lockstep vs scalar robot kernel (m, 1)
    "quoted_5_digits": dict(rtol=0.0, atol=5e-5),  # against a value quoted to 5 digits
    # discretisation and iteration errors of the robot model
    "rk4_closed_form": dict(rtol=0.0, atol=1e-6),  # RK4 pass vs closed-form arc / orthonormality
    "bvp_positions": dict(rtol=0.0, atol=2e-6),  # vs scipy solve_bvp of R&W's ODE (m)
    "bvp_rotations": dict(rtol=0.0, atol=2e-5),
    "small_deflection": dict(rtol=2e-3, atol=0.0),  # gravity vs linear beam theory (deflection)
    "small_deflection_length": dict(rtol=1e-3, atol=0.0),  # ... and the tip's axial position
    "surface_sampling": dict(rtol=0.0, atol=2e-6),  # sampled surface distance (m)
    "tension_solve": dict(rtol=1e-8, atol=1e-9),  # displacement -> tension solve vs tensions (N)
    "displacement_solve": dict(rtol=0.0, atol=1e-11),  # complementarity residual (m)
    "displacement_roundtrip": dict(rtol=0.0, atol=1e-10),  # tension -> displacement -> tension (m)
    # finite differences (central, float64)
    "fd_strain_slope": dict(rtol=1e-5, atol=1e-6),  # h = 1e-6 on nested Newton solves
    "fd_jacobian": dict(rtol=1e-6, atol=1e-8),  # h = 1e-7 .. 1e-6 of a residual
    "fd_tangent": dict(rtol=1e-6, atol=1e-6),  # FEM tangent (atol times max |K|)
    "fd_law": dict(rtol=1e-7, atol=1e-7),  # material law derivatives, h = 1e-6
    # FEM
    "linear_fem": dict(rtol=0.0, atol=1e-10),  # patch tests, residuals, reactions
    "nonlinear_patch": dict(rtol=0.0, atol=1e-9),  # nonlinear patch test under tractions
    "newton_paths": dict(rtol=0.0, atol=1e-8),  # different load paths, same equilibrium
    "residual_norm": dict(rtol=1e-6, atol=1e-12),  # reported vs recomputed residual norm
    "convergence_ratio": dict(rtol=0.1, atol=0.0),  # error ratio per refinement
    "interpolation": dict(rtol=0.0, atol=1e-9),  # P1 interpolation, either element on an edge
    "patch_centroid": dict(rtol=0.0, atol=2e-3),  # centroid of discretised bump weights
    # tissue scenarios (quasi-static FEM steps)
    "barycentric": dict(rtol=0.0, atol=1e-10),  # located point's barycentric coordinates >= -atol
    "fem_response": dict(rtol=1e-9, atol=1e-12),  # stored flexibility/factorisation vs a solve (m)
    "fem_reactions": dict(rtol=1e-9, atol=1e-10),  # support reactions vs the applied load (N)
    "newton_residual": dict(rtol=1e-8, atol=1e-12),  # |r| vs |f|; Newton stops at 1e-9 |f_ref|
    "small_controls_linear": dict(rtol=1e-2, atol=0.0),  # neo-Hookean step vs linear, 0.4 mm pushes
    # Monte Carlo
    "monte_carlo_std": dict(rtol=0.05, atol=0.0),  # sample std of 48,000 draws (~15 std errors)
}


@pytest.fixture
def rng() -> np.random.Generator:
    """The one seeded generator tests draw from."""
    return np.random.default_rng(20111)


@pytest.fixture
def tol():
    return TOL
