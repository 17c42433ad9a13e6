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
    "float32_ref": dict(rtol=1e-4, atol=1e-5),  # float32 computation vs a float64 reference
    "solver": dict(rtol=1e-6, atol=1e-9),  # iterative solver at its default tolerance
    # float64, same formula or exact cases
    "round_off": dict(rtol=0.0, atol=1e-15),  # exact up to a rounding (straight rod)
    "float64_bits": dict(rtol=1e-15, atol=0.0),  # one formula evaluated twice
    "float64_exact_rel": dict(rtol=1e-12, atol=0.0),  # same arithmetic, relative only
    "float64_abs": dict(rtol=0.0, atol=1e-12),  # exact result, absolute round-off
    "batch_vs_scalar": dict(rtol=1e-10, atol=1e-12),  # lockstep vs scalar robot kernel (m, 1)
    "quoted_5_digits": dict(rtol=0.0, atol=5e-5),  # against a value quoted to 5 digits
    "quoted_10um": dict(rtol=0.0, atol=5e-6),  # against a length (m) quoted to 0.01 mm
    "float64_exact_small": dict(rtol=1e-12, atol=1e-15),  # round-off, values far below 1
    "float64_accumulated": dict(rtol=1e-9, atol=1e-12),  # long float64 paths in another order
    # discretisation and iteration errors of the robot model
    "rk4_closed_form": dict(rtol=0.0, atol=1e-6),  # RK4 pass vs closed-form arc / orthonormality
    "bvp_positions": dict(rtol=0.0, atol=2e-6),  # vs scipy solve_bvp of R&W's ODE (m)
    "bvp_rotations": dict(rtol=0.0, atol=2e-5),  # ... and its rotation matrices
    "small_deflection": dict(rtol=2e-3, atol=0.0),  # gravity vs linear beam theory (deflection)
    "small_deflection_length": dict(rtol=1e-3, atol=0.0),  # ... and the tip's axial position
    "surface_sampling": dict(rtol=0.0, atol=2e-6),  # sampled surface distance (m)
    "tension_solve": dict(rtol=1e-8, atol=1e-9),  # displacement -> tension solve vs tensions (N)
    "displacement_solve": dict(rtol=0.0, atol=1e-11),  # complementarity residual (m)
    "displacement_roundtrip": dict(rtol=0.0, atol=1e-10),  # tension -> displacement -> tension (m)
    "strain_residual": dict(rtol=0.0, atol=1e-11),  # local strain solve residual at every node
    "hermite_midpoints": dict(rtol=0.0, atol=5e-6),  # Hermite vs solved midpoints, n = 40 (m)
    "hermite_midpoints_length": dict(rtol=0.0, atol=1e-6),  # ... tendon lengths (m)
    # solve_displacements' shape (solved midpoint strains) vs shape_free (Hermite midpoints) at
    # the same tensions, n = 40: measured <= 2.8e-7 m and 3.6e-6 over 441 configurations
    # spanning the paper robot's displacement box (shape_free's own n=40 vs n=80 change: 2.2e-7 m)
    "node_strain_shape": dict(rtol=0.0, atol=1e-6),  # positions (m)
    "node_strain_rotations": dict(rtol=0.0, atol=1e-5),  # ... frames
    "free_tip_force": dict(rtol=0.0, atol=1e-12),  # N(L) of a shot solution with gravity (N)
    "free_tip_moment": dict(rtol=0.0, atol=1e-10),  # M(L) of a shot solution with gravity (N m)
    # finite differences (central, float64)
    "fd_strain_slope": dict(rtol=1e-5, atol=1e-6),  # h = 1e-6 on nested Newton solves
    "fd_jacobian": dict(rtol=1e-6, atol=1e-8),  # h = 1e-7 .. 1e-6 of a residual
    "fd_tangent": dict(rtol=1e-6, atol=1e-6),  # FEM tangent (atol times max |K|)
    "fd_law": dict(rtol=1e-7, atol=1e-7),  # material law derivatives, h = 1e-6
    "fd_force_jacobian": dict(rtol=0.0, atol=1e-6),  # central differences h = 1e-4 of Newton solves
    "fd_forward_force": dict(rtol=0.0, atol=1e-3),  # forward differences h = 1e-4 of a step
    "fd_hessian_scaled": dict(rtol=1e-6, atol=1e-6),  # h = 1e-6 of a gradient (atol x max |H|)
    "fd_kink_margin": dict(rtol=0.0, atol=1e-4),  # points this far from a kink, h = 1e-6
    "linearize_second_order": dict(rtol=0.0, atol=1e-2),  # A_t fit, perturbations 1 % of range
    "feedback_null": dict(rtol=0.0, atol=1e-4),  # feedback through A_t's second-order fit residue
    # FEM
    "linear_fem": dict(rtol=0.0, atol=1e-10),  # patch tests, residuals, reactions
    "nonlinear_patch": dict(rtol=0.0, atol=1e-9),  # nonlinear patch test under tractions
    "newton_paths": dict(rtol=0.0, atol=1e-8),  # different load paths, same equilibrium
    "solver_start_M": dict(rtol=1e-6, atol=1e-12),  # M fitted from solves with other starts
    "residual_norm": dict(rtol=1e-6, atol=1e-12),  # reported vs recomputed residual norm
    "convergence_ratio": dict(rtol=0.1, atol=0.0),  # error ratio per refinement
    "interpolation": dict(rtol=0.0, atol=1e-9),  # P1 interpolation, either element on an edge
    "superposition": dict(rtol=1e-10, atol=1e-16),  # K⁻¹ f by cached columns vs one solve
    "fd_quadratic": dict(rtol=1e-5, atol=0.0),  # central differences, step 1e-7, quadratic
    "patch_centroid": dict(rtol=0.0, atol=2e-3),  # centroid of discretised bump weights
    "small_load_linear": dict(rtol=1e-3, atol=0.0),  # neo-Hookean vs linear FEM at 1e-3 of a load
    # tissue scenarios (quasi-static FEM steps)
    "barycentric": dict(rtol=0.0, atol=1e-10),  # located point's barycentric coordinates >= -atol
    "fem_reactions": dict(rtol=1e-9, atol=1e-10),  # support reactions vs the applied load (N)
    "newton_residual": dict(rtol=1e-8, atol=1e-12),  # |r| vs |f|; Newton stops at 1e-9 |f_ref|
    "small_controls_linear": dict(rtol=1e-2, atol=0.0),  # neo-Hookean step vs linear, 0.4 mm pushes
    # geometry and collision bounds
    "on_surface": dict(rtol=0.0, atol=1e-9),  # distance of a point on a mesh edge/face, margins
    "closest_point": dict(rtol=1e-7, atol=1e-7),  # accelerated vs brute-force closest points
    "orthonormality": dict(rtol=1e-7, atol=1e-6),  # R^T R = I from arbitrary parsed quaternions
    "chord_length": dict(rtol=1e-3, atol=0.0),  # 40 chords of an arc vs its length
    "rounded_constants": dict(rtol=0.0, atol=1e-4),  # a file's 5-digit angles (2.0944 for 2 pi/3)
    "cutoff_tail": dict(rtol=1e-8, atol=1e-15),  # bound with the chi cut-off vs without
    "extruded_2d": dict(rtol=1e-9, atol=1e-14),  # 2-D bound vs the extruded 3-D scene's
    "scipy_reference": dict(rtol=1e-8, atol=1e-12),  # same formula as scipy's implementation
    # stored data
    "float32_rounding": dict(rtol=0.0, atol=1e-6),  # float32 coordinates (m) that may round apart
    "float32_vertices": dict(rtol=1e-6, atol=1e-7),  # mesh read back from float32 vertices (m)
    "float32_mesh_bound": dict(rtol=1e-4, atol=1e-9),  # bound on a float32 mesh file vs float64
    "float32_mesh_probability": dict(rtol=1e-5, atol=0.0),  # CLI bound from an STL, p >= 1e-3
    "segmentation_volume": dict(rtol=0.03, atol=0.0),  # label-map mesh vs analytic solid (issue)
    "ros_duration": dict(rtol=0.0, atol=1e-9),  # time_from_start rounded to whole ns (s)
    # mixture density network (float64 unless named)
    "numpy_vs_torch": dict(rtol=1e-11, atol=1e-12),  # NumPy fast path vs torch (atol x max |v|)
    "float32_means": dict(rtol=1e-4, atol=1e-6),  # float32 network's component means (m)
    "float32_scaled": dict(rtol=1e-4, atol=1e-4),  # float32 network (atol times max |value|)
    "float32_log_density": dict(rtol=1e-4, atol=1e-3),  # float32 vs float64 log density (nats)
    "float32_training": dict(rtol=0.0, atol=1e-2),  # same seeded training in float32 / float64
    # a trained MDN against the known mixture its data were drawn from
    "recovered_weights": dict(rtol=0.0, atol=0.03),  # mixture weights
    "recovered_means": dict(rtol=0.0, atol=1e-3),  # (m); component stds are 1.5-12 mm
    "recovered_sd": dict(rtol=0.08, atol=0.0),  # per-axis standard deviations
    "recovered_correlation": dict(rtol=0.0, atol=0.05),  # correlation of one component
    # linearisation, LQG and LQG-MP
    "needle_car_A": dict(rtol=0.0, atol=1e-3),  # regressed needle Jacobian vs the car model's
    "needle_car_B": dict(rtol=0.0, atol=2e-3),  # ... its control Jacobian
    "noise_free_tracking": dict(rtol=0.0, atol=1e-3),  # closed loop, sensing sd 1e-5, vs plan
    "covariance_support": dict(rtol=1e-10, atol=1e-6),  # eigenvalue > rtol max; |x| off it < atol
    "half_plane_truncation": dict(rtol=0.0, atol=1e-9),  # truncated Gaussian vs closed form
    "half_plane_sigma": dict(rtol=1e-9, atol=0.0),  # chi-square ball vs closed form
    "sigma_jitter": dict(rtol=1e-8, atol=0.0),  # ... with a 1e-9 variance jitter (rank-1 spread)
    "gaussian_in_ellipsoid": dict(rtol=0.0, atol=1e-8),  # quadrature (asks 1e-9) vs closed form
    "steady_state": dict(rtol=1e-6, atol=0.0),  # loop state after 40 steps vs its fixed point
    # Monte Carlo
    "monte_carlo_mean": dict(rtol=0.0, atol=0.05),  # 4000 draws, sd 0.009 (atol x max |c|)
    "monte_carlo_std": dict(rtol=0.05, atol=0.0),  # sample std of 48,000 draws (~15 std errors)
    "monte_carlo_cov": dict(rtol=0.02, atol=0.02),  # covariance of 400,000 draws
    "hdr_threshold": dict(rtol=0.0, atol=0.02),  # HDR level from 2e5 draws (nats; sd ~ 1e-3)
    "hdr_coverage": dict(rtol=0.0, atol=0.025),  # two coverage estimates, 2e4 draws (sd 7.1e-3)
}


@pytest.fixture
def rng() -> np.random.Generator:
    """The one seeded generator tests draw from."""
    return np.random.default_rng(20111)


@pytest.fixture
def tol():
    return TOL


def approx_tol(name: str) -> dict:
    """``TOL[name]`` as ``pytest.approx`` keywords (``rel``, ``abs``)."""
    return dict(rel=TOL[name]["rtol"], abs=TOL[name]["atol"])
