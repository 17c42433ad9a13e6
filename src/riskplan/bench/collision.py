"""``riskplan bench collision``: speed of the collision bounds on the procedural chest mesh.

Keys: ``gaussian_ms`` (one Gaussian), ``mixture5_ms`` (one 5-component mixture),
``trajectory50_ms`` (50 mixtures + eq. 10), ``mesh_triangles``. Extra keys: scaling with the
number of triangles and of components, closest-point queries by library (libigl AABB, coal,
trimesh), Monte Carlo containment throughput. Robot geometry: 5-component mixtures built
from constant-curvature backbones of the 0.2 m paper robot (``collision.robot_geometry``).
"""

from __future__ import annotations

import numpy as np

from riskplan.bench import median_time


def _mixtures(n, K, seed=0):
    from riskplan.kinematics.robot_mixture import arc_backbone, backbone_mixture

    rng = np.random.default_rng(seed)
    k = rng.uniform(0.0, 10.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    return backbone_mixture(arc_backbone(k, phi, n=max(41, 4 * K + 1)), K)


def _closest_point_libraries(env, n, quick):
    """Milliseconds for ``n`` closest-point queries with each library that is installed.

    libigl's AABB tree is what :class:`Environment` uses; coal (the ``bench`` extra) and
    trimesh are the alternatives it was chosen against. A library that is not installed is
    reported as ``None``.
    """
    import trimesh

    rng = np.random.default_rng(1)
    lo, hi = env.bounds
    P = rng.uniform(lo, hi, size=(n, 3))
    out = {}
    env.closest_points(P[:2])
    out["libigl_aabb"] = (
        median_time(lambda: env.closest_points(P), repeats=3 if quick else 10) * 1e3
    )
    try:
        import coal
    except ImportError:
        out["coal"] = None
    else:
        bvh = coal.BVHModelOBBRSS()
        bvh.beginModel(env.n_faces, len(env.vertices))
        bvh.addVertices(env.vertices)
        bvh.addTriangles(env.faces)
        bvh.endModel()
        sph = coal.Sphere(1e-9)
        req = coal.DistanceRequest()
        eye = coal.Transform3s()

        def coal_query():
            for p in P:
                res = coal.DistanceResult()
                tf = coal.Transform3s()
                tf.setTranslation(p)
                coal.distance(bvh, eye, sph, tf, req, res)

        out["coal"] = median_time(coal_query, repeats=3 if quick else 5, warmup=1) * 1e3
    mesh = trimesh.Trimesh(env.vertices, env.faces, process=False)
    m = max(10, n // 20)
    out["trimesh"] = (
        median_time(
            lambda: trimesh.proximity.closest_point(mesh, P[:m]),
            repeats=1 if quick else 3,
            warmup=1,
        )
        * 1e3
        * n
        / m
    )
    return out


def run(quick: bool = False) -> dict:
    from riskplan.collision import gaussian_bound, probability_of_collision, trajectory_bound
    from riskplan.planning.chest_scene import build_chest

    reps = 10 if quick else 60
    chest = build_chest(0)
    env = chest.base_environment
    gm50 = _mixtures(50, 5)
    gm1 = gm50[0]
    arrs = gm1.numpy()
    mu, U = arrs["means"][2], arrs["precision_cholesky"][2]
    probability_of_collision(gm50, env)  # compile / warm caches
    figures = {
        "gaussian_ms": median_time(lambda: gaussian_bound(mu, U, env), repeats=reps) * 1e3,
        "mixture5_ms": median_time(lambda: probability_of_collision(gm1, env), repeats=reps) * 1e3,
        "trajectory50_ms": median_time(
            lambda: trajectory_bound(gm50, env), repeats=max(3, reps // 6)
        )
        * 1e3,
        "mesh_triangles": int(env.n_faces),
    }
    # per-configuration cost when many configurations go in one batched call
    figures["mixture5_batched_ms_per_config"] = figures["trajectory50_ms"] / 50
    # growth with the number of triangles (finer organ/wall meshes, more rib segments)
    by_tri = {}
    for sub, seg in ((2, 24), (3, 40), (4, 64), (5, 96)) if not quick else ((2, 24), (3, 40)):
        ch = build_chest(0, subdivisions=sub, rib_segments=seg, rib_sides=8 if sub >= 4 else 6)
        e = ch.base_environment
        probability_of_collision(gm1, e)
        by_tri[str(e.n_faces)] = (
            median_time(lambda e=e: probability_of_collision(gm50, e), repeats=3) * 1e3 / 50
        )
    figures["mixture5_ms_per_config_by_triangles"] = by_tri
    by_k = {}
    for K in (1, 2, 5, 10, 20) if not quick else (1, 5):
        g = _mixtures(50, K)
        probability_of_collision(g[:2], env)
        by_k[str(K)] = (
            median_time(lambda g=g: probability_of_collision(g, env), repeats=3) * 1e3 / 50
        )
    figures["mixture_ms_per_config_by_components"] = by_k
    figures["closest_points_1000_ms"] = _closest_point_libraries(
        chest.environment, 200 if quick else 1000, quick
    )
    rng = np.random.default_rng(2)
    pts = chest.base_environment.bounds[0] + rng.random((100_000, 3)) * np.ptp(
        chest.base_environment.bounds, axis=0
    )
    figures["contains_100k_points_ms"] = (
        median_time(lambda: env.contains(pts), repeats=3 if quick else 10) * 1e3
    )
    return {
        k: (
            round(v, 4)
            if isinstance(v, float)
            else ({kk: round(vv, 4) for kk, vv in v.items()} if isinstance(v, dict) else v)
        )
        for k, v in figures.items()
    }
