"""The collision benchmark runs and reports the issue's keys (no timing assertions)."""

from __future__ import annotations

from riskplan.bench.collision import run


def test_bench_keys():
    figures = run(quick=True)
    assert {"gaussian_ms", "mixture5_ms", "trajectory50_ms", "mesh_triangles"} <= set(figures)
    assert figures["mesh_triangles"] > 3000
    assert all(figures[k] > 0 for k in ("gaussian_ms", "mixture5_ms", "trajectory50_ms"))
    assert set(figures["closest_points_1000_ms"]) == {"libigl_aabb", "coal", "trimesh"}
