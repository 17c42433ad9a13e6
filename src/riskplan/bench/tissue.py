"""Speed of one tissue-simulator step: ``riskplan bench tissue --json``.

One *step* is what a planner's simulator does per control: a quasi-static solve under a
small load change, warm-started from the previous state, then the material points read
off the new state.

* linear (needle scenario, V-A): unit square fixed at its corners, E = 50, ν = 0.4; the
  needle tip moves a little each step: locate the tip in the mesh, build the nodal force
  vector of a unit point force along the motion (P1 weights), solve with the cached
  factorisation, interpolate 12 material points (obstacle corners and goal);
* nonlinear (manipulation scenario, V-B): unit square, bottom-right boundary fixed,
  three manipulators push on boundary patches (precomputed patch weights); the
  manipulator forces change by a small control increment each step; neo-Hookean Newton
  solve warm-started from the previous equilibrium; interpolate the target and 8
  boundary points.
"""

from __future__ import annotations

import numpy as np

from riskplan.bench import median_time


def _linear_setup(n_elements: int):
    from riskplan.deformable import LinearElasticModel, Material, locate, mesh_polygon, rectangle

    mesh = mesh_polygon(rectangle(), n_elements)
    model = LinearElasticModel(mesh, Material(50.0, 0.4), mesh.vertex_nodes)
    pts = np.array(
        [
            [0.3, 0.3],
            [0.4, 0.3],
            [0.4, 0.45],
            [0.3, 0.45],
            [0.6, 0.6],
            [0.7, 0.6],
            [0.7, 0.7],
            [0.6, 0.7],
            [0.8, 0.85],
            [0.85, 0.85],
            [0.85, 0.9],
            [0.8, 0.9],
        ]
    )
    return mesh, model, locate(mesh, pts)


def linear_step_ms(n_elements: int, repeats: int = 200) -> float:
    from riskplan.deformable.locate import locate_points

    mesh, model, material_points = _linear_setup(n_elements)
    maps = mesh.barycentric_maps
    tri = mesh.triangles
    n = 2 * mesh.n_nodes
    state = {"x": np.array([0.1, 0.2]), "k": 0}
    heading = np.array([np.cos(0.7), np.sin(0.7)])

    def step():
        k = state["k"] = (state["k"] + 1) % 100
        tip = state["x"] + 0.005 * k * heading
        elem, lam = locate_points(maps, tip[None])
        nodes = tri[elem[0]]
        f = np.zeros(n)
        f[2 * nodes] = lam[0] * heading[0]
        f[2 * nodes + 1] = lam[0] * heading[1]
        u = model.solve_flat(f)
        return material_points.positions(u.reshape(-1, 2))

    return 1e3 * median_time(step, repeats=repeats, warmup=5)


def _nonlinear_setup(n_elements: int):
    from riskplan.deformable import (
        Material,
        NeoHookeanModel,
        locate,
        mesh_polygon,
        patch_weights,
        rectangle,
    )

    mesh = mesh_polygon(rectangle(), n_elements)
    x, y = mesh.nodes[:, 0], mesh.nodes[:, 1]
    fixed = np.flatnonzero(((y == 0.0) & (x >= 0.6)) | ((x == 1.0) & (y <= 0.4)))
    model = NeoHookeanModel(mesh, Material(50.0, 0.4), fixed)
    W = np.stack(
        [patch_weights(mesh, c, 0.1) for c in ([0.0, 0.5], [0.5, 1.0], [1.0, 0.8])], axis=1
    )  # (N, 3)
    b = mesh.boundary_nodes
    pts = np.vstack([[0.45, 0.55], mesh.nodes[b[:: max(1, len(b) // 8)][:8]]])
    return mesh, model, W, locate(mesh, pts)


def nonlinear_step_ms(n_elements: int, repeats: int = 30) -> float:
    _mesh, model, W, material_points = _nonlinear_setup(n_elements)
    base = np.array([[1.0, 0.2], [0.1, -1.0], [-0.8, -0.3]])  # manipulator forces (3, 2)
    state = {"u": model.solve(W @ base), "k": 0}

    def step():
        k = state["k"] = state["k"] + 1
        control = base * (1.0 + 0.05 * np.sin(0.3 * k))  # small load change per step
        u = model.solve(W @ control, u0=state["u"])
        state["u"] = u
        return material_points.positions(u)

    return 1e3 * median_time(step, repeats=repeats, warmup=3)


def run(quick: bool = False) -> dict:
    """``{"linear_step_ms_175", "linear_step_ms_1000", "nonlinear_step_ms_175",
    "nonlinear_step_ms_1000"}``: median milliseconds per simulator step."""
    r_lin = 50 if quick else 300
    r_nl = 10 if quick else 40
    return {
        "linear_step_ms_175": round(linear_step_ms(175, r_lin), 4),
        "linear_step_ms_1000": round(linear_step_ms(1000, r_lin), 4),
        "nonlinear_step_ms_175": round(nonlinear_step_ms(175, r_nl), 3),
        "nonlinear_step_ms_1000": round(nonlinear_step_ms(1000, r_nl), 3),
    }
