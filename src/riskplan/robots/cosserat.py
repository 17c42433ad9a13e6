"""Cosserat-rod statics of tendon-driven continuum robots with general tendon routing.

Implements Rucker & Webster, "Statics and dynamics of continuum robots with general tendon
routing and external loading", IEEE T-RO 27(6), 2011 (R&W below), in an equivalent
"resultant" form that needs no shooting when there are no external loads.

Model (body-frame strains ``v`` (shear/extension) and ``u`` (curvature/torsion), R&W eq. 2-4)::

    p' = R v,        R' = R [u]x,
    tendon i at body offset r_i(s) = rho_i(s) (cos theta_i(s), sin theta_i(s), 0),
    tendon tangent  w_i = v + u x r_i + r_i',  t_i = w_i / |w_i|       (R&W eq. 10)

Cut the robot *and its tendons* at ``s`` and take the distal part as one free body: the
tendon-disk contact forces are internal to it, the tendon tension enters only where the
tendons are cut. With ``N(s)``, ``M(s)`` the resultant force and moment (about ``p(s)``, world
frame) carried through the cross-section by rod and tendons together::

    N' = -f,   M' = -p' x N - l,   N(L) = F_tip, M(L) = L_tip                      (1)
    K_se (v - v*) + sum_i tau_i t_i         = R^T N                               (2)
    K_bt (u - u*) + sum_i tau_i r_i x t_i   = R^T M                               (3)

(2)-(3) are R&W's constitutive law ``n = R K_se (v - v*)``, ``m = R K_bt (u - u*)`` with the
tendon terms of their tip boundary condition (R&W eq. 17) carried to every ``s``; differentiating
them along ``s`` gives R&W's ODE (their eq. 19, the ``A, B, G, H`` matrices). The Jacobian of
(2)-(3) is exactly R&W's matrix ``[[K_se + A, G], [B, K_bt + H]]``. Without external loads
``N = M = 0`` everywhere, so the strains at each ``s`` follow from a local 6x6 Newton solve of
(2)-(3) and one RK4 pass integrates ``p, R`` (no shooting). With gravity or tip loads the base
values ``N(0), M(0)`` are shot (Newton, finite-difference Jacobian) so that (1) holds at the tip.

Tendon path length ``l_i = int_0^L |w_i| ds`` is integrated alongside (Simpson = RK4 for a
state-independent integrand). Reference state: straight, unstretched (``v* = e3``, ``u* = 0``).

The kernels are pure array functions (numba, ``cache=True``), one module per job; this module
is their namespace and the model's documentation. ``robot.TendonRobot`` is the validating facade.

* :mod:`.rod_tables` -- :class:`RodTables` (the per-robot arrays every kernel takes), tendon
  offsets ``r_i(s)`` from the routing polynomials, status codes;
* :mod:`.linalg6` -- 6x6 Cholesky and small Gaussian elimination;
* :mod:`.strains` -- residual, Jacobian and solves of (2)-(3) at one node, strain slopes;
* :mod:`.integration` -- the RK4 pass without loads (:func:`shape_free`), the pose from
  strains solved at every node (:func:`pose_from_node_strains`, the displacement solve's
  shape) and the pass with loads (:func:`shape_loaded`);
* :mod:`.tendon_lengths` -- path lengths and their tension sensitivity;
* :mod:`.displacement` -- tensions for tendon displacements (complementarity solve);
* :mod:`.batch_kernel` -- :func:`shape_free` in lockstep over chunks of configurations.

The per-node helpers that take array views are compiled with ``inline="always"``: passing
views to separate functions cost more than their arithmetic. numba's cache tracks a compiled
function's own file only, so after editing a helper module clear ``__pycache__`` (or touch the
callers) before timing.
"""

from riskplan.robots.displacement import solve_displacement_batch, solve_displacement_tensions
from riskplan.robots.integration import (
    pose_from_node_strains,
    shape_free,
    shape_free_batch,
    shape_loaded,
)
from riskplan.robots.rod_tables import (
    LOCAL_FAIL,
    OK,
    OUTER_FAIL,
    RodTables,
    rod_tables,
    tendon_offset_table,
    tendon_offsets,
)
from riskplan.robots.strains import (
    local_jacobian,
    local_residual,
    local_strains,
    local_strains_chord,
)
from riskplan.robots.tendon_lengths import lengths_and_jacobian

__all__ = [
    "LOCAL_FAIL",
    "OK",
    "OUTER_FAIL",
    "RodTables",
    "lengths_and_jacobian",
    "local_jacobian",
    "local_residual",
    "local_strains",
    "local_strains_chord",
    "pose_from_node_strains",
    "rod_tables",
    "shape_free",
    "shape_free_batch",
    "shape_loaded",
    "solve_displacement_batch",
    "solve_displacement_tensions",
    "tendon_offset_table",
    "tendon_offsets",
]
