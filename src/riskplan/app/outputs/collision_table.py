"""Bound vs Monte Carlo in the procedural chest (docs/results.md, collision section).

For a set of robot configurations inside the chest (robot base frame at the insertion
point) this computes the eq. 9 bound, its Monte Carlo reference with a 95 % Wilson interval,
the union variant and its reference, and one trajectory (eq. 10) row.

Robot geometry, in order of preference: a trained MDN (``model``/``model_path``), the
robot's Cosserat model through :func:`~riskplan.kinematics.robot_mixture.robot_mixture`,
or constant-curvature arcs of the 0.2 m paper robot.

Reproduce: ``riskplan collision table --samples 100000 --seed 0`` or
``python -m riskplan.app.outputs.collision_table``.
"""

from __future__ import annotations

import logging
import time

import numpy as np

log = logging.getLogger(__name__)


def _geometry_source(model=None, model_path=None, robot=None):
    """Returns ``(kind, make_mixture(configs) -> GaussianMixture, configs, labels)``."""
    from riskplan.kinematics.robot_mixture import arc_backbone, backbone_mixture, robot_mixture

    if model is None and model_path is not None:
        from riskplan.kinematics import load_model

        model = load_model(model_path)
    if model is not None or robot is not None:
        rob = robot if robot is not None else getattr(model, "robot", None)
        m = rob.n_tendons if rob is not None else 4
        hi = np.asarray(rob.displacement_limits)[:, 1] if rob is not None else np.full(m, 0.04)
        configs, labels = [np.zeros(m)], ["home (all 0)"]
        for j in range(m):
            for frac in (0.5, 1.0):
                d = np.zeros(m)
                d[j] = frac * hi[j]
                configs.append(d)
                labels.append(f"tendon {j} at {d[j] * 1e3:.0f} mm")
        d = np.zeros(m)
        d[: min(2, m)] = 0.5 * hi[: min(2, m)]
        configs.append(d)
        labels.append("tendons 0+1 at half")
        configs = np.stack(configs)
        if model is not None:
            return "MDN model", lambda c: model.predict(np.asarray(c)), configs, labels
        return "robot backbone", lambda c: robot_mixture(rob, np.asarray(c)), configs, labels
    curv = [0.0, 3.0, 5.0, 5.0, 5.0, 5.0, 7.0, 7.0, 9.0, 9.0]
    phis = [0.0, 0.0, 0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi, 0.0, np.pi, 0.5 * np.pi, 1.5 * np.pi]
    configs = np.column_stack([curv, phis])
    labels = [f"arc kappa={k:g}/m phi={p / np.pi:.1f}pi" for k, p in configs]
    return (
        "constant-curvature arcs",
        lambda c: backbone_mixture(arc_backbone(np.asarray(c)[..., 0], np.asarray(c)[..., 1]), 5),
        configs,
        labels,
    )


def _default_robot():
    """The paper robot, or ``None`` (arcs are used then) when no robot model can be loaded."""
    from riskplan.errors import RiskplanError

    try:
        from riskplan.robots import load_robot

        return load_robot("paper")
    except (ImportError, RiskplanError) as exc:
        log.warning("robot model unavailable (%s); using constant-curvature arcs", exc)
        return None


def collision_table(
    *,
    seed: int = 0,
    n_samples: int = 100_000,
    model=None,
    model_path=None,
    robot=None,
    use_robot: bool = True,
    trajectory_steps: int = 10,
):
    """Rows of bound vs Monte Carlo for configurations in the chest; returns ``(rows, meta)``.

    Each row: ``label, bound, mc, mc_low, mc_high, union, mc_union, mc_union_low, mc_union_high``.
    The last row is a trajectory from home to the last configuration (eq. 10 vs Monte Carlo with
    independent draws per state).
    """
    from riskplan.collision import (
        monte_carlo_probability,
        monte_carlo_trajectory,
        probability_of_collision,
        trajectory_bound,
    )
    from riskplan.parallel import spawn_seeds
    from riskplan.planning.chest_scene import build_chest

    if model is None and model_path is None and robot is None and use_robot:
        robot = _default_robot()
    kind, make, configs, labels = _geometry_source(model, model_path, robot)
    chest = build_chest(seed)
    env = chest.base_environment
    gm = make(configs)
    probability_of_collision(gm[:1], env)  # load the compiled kernels before timing
    t0 = time.perf_counter()
    bound = probability_of_collision(gm, env)
    union = probability_of_collision(gm, env, "union")
    t_bound = time.perf_counter() - t0
    t0 = time.perf_counter()
    # the chest is built from seed; the three Monte Carlo estimates draw from streams spawned from it
    s_mc, s_union, s_traj = spawn_seeds(seed, 3)
    mc = monte_carlo_probability(gm, env, n_samples, seed=s_mc)
    mcu = monte_carlo_probability(gm, env, n_samples, combine="union", seed=s_union)
    t_mc = time.perf_counter() - t0
    rows = []
    for i, lab in enumerate(labels):
        rows.append(
            dict(
                label=lab,
                bound=float(bound[i]),
                mc=float(mc.probability[i]),
                mc_low=float(mc.low[i]),
                mc_high=float(mc.high[i]),
                union=float(union[i]),
                mc_union=float(mcu.probability[i]),
                mc_union_low=float(mcu.low[i]),
                mc_union_high=float(mcu.high[i]),
            )
        )
    # trajectory: straight-line interpolation from home to the most colliding configuration
    target = configs[int(np.argmax(bound))]
    path = configs[0] + np.linspace(0, 1, trajectory_steps)[:, None] * (target - configs[0])
    gmt = make(path)
    tb = trajectory_bound(gmt, env)
    tmc = monte_carlo_trajectory(gmt, env, max(1000, n_samples // 10), seed=s_traj)
    rows.append(
        dict(
            label=f"trajectory, {trajectory_steps} states home -> {labels[int(np.argmax(bound))]} (eq. 10)",
            bound=float(tb),
            mc=float(tmc.probability),
            mc_low=float(tmc.low),
            mc_high=float(tmc.high),
            union=float("nan"),
            mc_union=float("nan"),
            mc_union_low=float("nan"),
            mc_union_high=float("nan"),
        )
    )
    meta = dict(
        geometry=kind,
        seed=seed,
        n_samples=n_samples,
        triangles=env.n_faces,
        bound_seconds=t_bound,
        monte_carlo_seconds=t_mc,
        configurations=len(labels),
        trajectory_samples=int(tmc.n),
    )
    return rows, meta


def to_markdown(rows, meta) -> str:
    """Markdown table of :func:`collision_table` output."""
    head = (
        f"Chest mesh: {meta['triangles']} triangles (seed {meta['seed']}); geometry: {meta['geometry']}; "
        f"Monte Carlo: {meta['n_samples']} samples per configuration, 95 % Wilson intervals.\n\n"
        "| configuration | bound (eq. 9) | Monte Carlo [95 % CI] | bound / MC | union bound | MC union [95 % CI] |\n"
        "|---|---|---|---|---|---|\n"
    )
    lines = []
    for r in rows:
        ratio = r["bound"] / r["mc"] if r["mc"] > 0 else float("inf")
        union = "—" if np.isnan(r["union"]) else f"{r['union']:.4f}"
        mcu = (
            "—"
            if np.isnan(r["mc_union"])
            else f"{r['mc_union']:.4f} [{r['mc_union_low']:.4f}, {r['mc_union_high']:.4f}]"
        )
        lines.append(
            f"| {r['label']} | {r['bound']:.4f} | {r['mc']:.4f} [{r['mc_low']:.4f}, {r['mc_high']:.4f}] | {ratio:.2f} | {union} | {mcu} |"
        )
    tail = (
        f"\n\nBound computation: {meta['bound_seconds'] * 1e3:.1f} ms for all {meta['configurations']} configurations "
        f"(both variants); Monte Carlo: {meta['monte_carlo_seconds']:.1f} s.\n"
    )
    return head + "\n".join(lines) + tail
