"""The tissue benchmark runs, reports exactly the issue's keys, and its steps do real work
(no timing assertions)."""

from __future__ import annotations

import numpy as np

from riskplan.bench import tissue, tissue3d


def test_bench_keys():
    figures = tissue.run(quick=True)
    keys = {
        "linear_step_ms_175",
        "linear_step_ms_1000",
        "nonlinear_step_ms_175",
        "nonlinear_step_ms_1000",
        "tet_linear_step_ms_5k",
        "tet_linear_resolve_ms_5k",
        "tet_neohookean_step_ms_5k",
    }
    if tissue3d.sfepy_available():
        keys.add("sfepy_linear_step_ms_5k")
    assert set(figures) == keys
    assert all(np.isfinite(v) and v > 0 for v in figures.values())


def test_bench_times_the_scenarios_public_step(tol):
    # needle: the planning mesh, a pose inside the tissue; the step pushes the tissue and the
    # collision check answers from the deformed obstacles
    sim, p, s, u = tissue.needle_setup(175)
    assert sim.mesh_data(p.n_elements).mesh.n_elements == 175 and sim.inside(s)
    s1 = sim.step(s, u, p)
    assert np.abs(s1.displacement).max() > 1e-4 and isinstance(sim.in_collision(s1), bool)
    # manipulation: the timed state is the equilibrium under forces 0.5; the timed step
    # (warm-started from it) reaches the equilibrium of the new forces that a cold solve from
    # the undeformed body under those forces reaches (transfer_state solves from it)
    sim, p, s, u = tissue.manipulation_setup(175)
    assert sim.mesh_data(p.n_elements).mesh.n_elements == 175 and s.t == 2
    np.testing.assert_array_equal(s.forces, 0.5)
    warm = sim.step(s, u, p)
    cold = sim.transfer_state(warm, p)
    np.testing.assert_allclose(warm.displacement, cold.displacement, **tol["newton_paths"])
    assert np.abs(warm.displacement - s.displacement).max() > 1e-4  # the force change moves it
    assert sim.reduced(warm).shape == (sim.state_dim,)


def test_tet_bench_times_one_problem_on_both_sides(tol):
    """The 3-D figures time the same mesh (5040 tetrahedra) and load; both sides solve it to
    the same displacement, and the neo-Hookean step moves the body by a finite amount."""
    from riskplan.deformable import TetTissue

    mesh, mat, fixed, f = tissue3d.setup()
    assert mesh.n_elements == 5040
    u = TetTissue(mesh, mat, fixed).solve(f)
    un = TetTissue(mesh, mat, fixed, law="neo-hookean").solve(f)
    # a finite deformation: the laws differ by more than 1 % of the displacement
    assert np.abs(u).max() > 0.01 and np.abs(un - u).max() > 0.01 * np.abs(u).max()
    if tissue3d.sfepy_available():
        u_ref = tissue3d.sfepy_linear_problem(mesh, mat, fixed, tissue3d.BODY_FORCE)()
        np.testing.assert_allclose(
            u, u_ref, rtol=0, atol=tol["float64_exact"]["atol"] * np.abs(u).max()
        )


def test_step_cost_keys():
    from riskplan.bench.tissue import step_costs

    out = step_costs(quick=True)
    for n in (175, 1000):
        for key in (
            f"needle_step_us_{n}",
            f"needle_step_and_collision_us_{n}",
            f"manipulation_step_ms_{n}",
            f"manipulation_reduced_us_{n}",
        ):
            assert out[key] > 0


def test_sfepy_prints_nothing_on_stdout():
    # `riskplan bench tissue --json` owns stdout: SfePy's import-time notes (e.g. on its
    # optional jax terms) must not land there. A fresh process, since SfePy prints once.
    import subprocess
    import sys

    import pytest

    pytest.importorskip("sfepy")
    code = (
        "from riskplan.bench import tissue3d\n"
        "from riskplan.deformable.tetmesh import tet_block\n"
        "from riskplan.deformable import Material\n"
        "import numpy as np\n"
        "assert tissue3d.sfepy_available()\n"
        "m = tet_block((1.0, 1.0, 1.0), n_elements=48)\n"
        "u = tissue3d.sfepy_linear_problem(m, Material(50.0, 0.4), m.face_nodes('z-'),"
        " np.array([0.0, 0.0, -1.0]))()\n"
        "assert u.shape == (m.n_nodes, 3)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout == ""
