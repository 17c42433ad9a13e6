"""Speed of the 3-D tissue (P1 tetrahedra) against SfePy on the same mesh and load:
part of ``riskplan bench tissue --json``.

Problem (the same on both sides): the unit cube meshed by :func:`~riskplan.deformable.tet_block`
with 5000 requested elements (5040 tetrahedra, 1144 nodes, 3432 DOFs), E = 50, ν = 0.4
(the paper's nominal material), the face ``z = 0`` held, a uniform body force
``b = (1, 0, −5)`` per unit volume (consistent nodal loads ``V_e b / 4`` per element node).

* ``tet_linear_step_ms_5k``: :class:`~riskplan.deformable.TetTissue` (linear) built on
  the mesh (the sparsity layout is cached per mesh, as SfePy's problem keeps its matrix
  graph) — element matrices assembled, the reduced stiffness factorised — and one solve;
* ``tet_linear_resolve_ms_5k``: a further solve with the cached factorisation (another load);
* ``tet_neohookean_step_ms_5k``: the neo-Hookean solve from rest under the same load
  (Newton from the undeformed state: each iteration assembles the tangent, factorises and
  solves; 4 iterations at this load);
* ``sfepy_linear_step_ms_5k`` (only where SfePy is installed): SfePy's ``Problem.solve`` of
  the same problem (``dw_lin_elastic`` + ``dw_volume_lvf``, one Newton iteration with
  ``ScipyDirect``: residual and matrix assembled, factorised, solved), on a problem built
  once before timing.

Medians of repeated calls (:func:`riskplan.bench.median_time`); one BLAS thread.
"""

from __future__ import annotations

import numpy as np

from riskplan.bench import median_time

#: Requested element count of the timed mesh.
N_ELEMENTS = 5000
#: Body force per unit volume of the timed load.
BODY_FORCE = (1.0, 0.0, -5.0)


def setup(n_elements: int = N_ELEMENTS):
    """``(mesh, material, fixed_nodes, nodal_forces (N, 3))`` of the timed problem."""
    from riskplan.deformable import Material, tet_block

    mesh = tet_block((1.0, 1.0, 1.0), n_elements=n_elements)
    b = np.asarray(BODY_FORCE)
    f = np.zeros((mesh.n_nodes, 3))
    np.add.at(f, mesh.tets.ravel(), np.repeat(mesh.volumes / 4.0, 4)[:, None] * b)
    return mesh, Material(50.0, 0.4), mesh.face_nodes("z-"), f


def sfepy_linear_problem(mesh, material, fixed_nodes, body_force):
    """A callable ``solve() -> u (N, 3)``: SfePy's linear elasticity on ``mesh`` (same node
    order) with ``fixed_nodes`` held and a uniform body force ``(3,)``; the problem (domain,
    field, terms, boundary conditions, solvers) is built once here."""
    import contextlib
    import logging
    import sys

    # SfePy prints notes on stdout while it imports (e.g. that its optional jax terms are
    # missing); `bench --json` owns stdout, so they go to stderr
    with contextlib.redirect_stdout(sys.stderr):
        from sfepy.base.base import output

        output.set_output(quiet=True)
        logging.getLogger("sfepy").setLevel(logging.ERROR)
        from sfepy.discrete import Equation, Equations, FieldVariable, Integral, Problem
        from sfepy.discrete import Material as SMaterial
        from sfepy.discrete.conditions import Conditions, EssentialBC
        from sfepy.discrete.fem import FEDomain, Field, Mesh
        from sfepy.mechanics.matcoefs import stiffness_from_lame
        from sfepy.solvers.ls import ScipyDirect
        from sfepy.solvers.nls import Newton
        from sfepy.terms import Term

    smesh = Mesh.from_data(
        "tissue",
        np.asarray(mesh.nodes),
        None,
        [np.asarray(mesh.tets, dtype=np.int32)],
        [np.zeros(mesh.n_elements, dtype=np.int32)],
        ["3_4"],
    )
    domain = FEDomain("domain", smesh)
    omega = domain.create_region("Omega", "all")
    fixed = domain.create_region(
        "Fixed", "vertex " + ", ".join(str(int(i)) for i in fixed_nodes), "vertex"
    )
    field = Field.from_args("fu", np.float64, "vector", omega, approx_order=1)
    u = FieldVariable("u", "unknown", field)
    v = FieldVariable("v", "test", field, primary_var_name="u")
    m = SMaterial("m", D=stiffness_from_lame(3, material.lam3d, material.mu))
    f = SMaterial("f", val=np.asarray(body_force, dtype=np.float64).reshape(3, 1))
    integral = Integral("i", order=1)
    t1 = Term.new("dw_lin_elastic(m.D, v, u)", integral, omega, m=m, v=v, u=u)
    t2 = Term.new("dw_volume_lvf(f.val, v)", integral, omega, f=f, v=v)
    pb = Problem("elasticity", equations=Equations([Equation("balance", t1 - t2)]))
    pb.set_bcs(ebcs=Conditions([EssentialBC("fix", fixed, {"u.all": 0.0})]))
    pb.set_solver(Newton({"i_max": 1, "eps_a": 1e-10, "eps_r": 1.0}, lin_solver=ScipyDirect({})))
    if np.abs(field.get_coor() - mesh.nodes).max() != 0.0:  # pragma: no cover - SfePy internals
        raise RuntimeError("SfePy renumbered the mesh nodes; the comparison needs the same order")

    def solve() -> np.ndarray:
        state = pb.solve(save_results=False)
        return np.asarray(state.get_state_parts()["u"]).reshape(-1, 3)

    return solve


def sfepy_available() -> bool:
    import contextlib
    import sys

    try:
        with contextlib.redirect_stdout(sys.stderr):
            import sfepy  # noqa: F401
    except ImportError:
        return False
    return True


def run(quick: bool = False) -> dict:
    """``{"tet_linear_step_ms_5k", "tet_linear_resolve_ms_5k", "tet_neohookean_step_ms_5k"}``
    and, with SfePy installed, ``"sfepy_linear_step_ms_5k"`` (module docstring). ``quick``:
    fewer repeats (same problem)."""
    from riskplan.deformable import TetTissue

    mesh, mat, fixed, f = setup()
    reps = 3 if quick else 15
    TetTissue(mesh, mat, fixed).solve(f)  # sparsity layout cached for the mesh

    def linear_step():
        return TetTissue(mesh, mat, fixed).solve(f)

    tissue = TetTissue(mesh, mat, fixed)
    tissue.solve(f)
    f2 = 0.5 * f[:, ::-1].copy()

    def neo_step():
        t = TetTissue(mesh, mat, fixed, law="neo-hookean")
        return t.solve(f)

    out = {
        "tet_linear_step_ms_5k": round(1e3 * median_time(linear_step, reps, warmup=1), 2),
        "tet_linear_resolve_ms_5k": round(1e3 * median_time(lambda: tissue.solve(f2), reps), 3),
        "tet_neohookean_step_ms_5k": round(
            1e3 * median_time(neo_step, max(3, reps // 3), warmup=1), 1
        ),
    }
    if sfepy_available():
        solve = sfepy_linear_problem(mesh, mat, fixed, BODY_FORCE)
        out["sfepy_linear_step_ms_5k"] = round(1e3 * median_time(solve, reps, warmup=1), 2)
    return out
