"""Demo stage ``collision``: the chest cavity (Fig. 6), P(collision) bound vs Monte Carlo,
and the speed of the bound.

Uses ``ctx["model"]`` (trained MDN) if the kinematics stage ran, else the robot's backbone
(``ctx["robot"]``) or constant-curvature arcs of the 0.2 m robot. Sets ``ctx["chest"]`` and
``ctx["environment"]`` (chest in the robot base frame) for later stages. Budget: ~40 s.
"""

from __future__ import annotations

import time

import numpy as np

from riskplan.app.report import Report


def run(report: Report, ctx: dict, *, seed: int, workers: int | None) -> None:
    import matplotlib.pyplot as plt

    from riskplan.app.outputs.collision_table import _geometry_source, collision_table
    from riskplan.collision import (
        monte_carlo_probability,
        probability_of_collision,
        trajectory_bound,
    )
    from riskplan.planning.chest_scene import build_chest, chest_figure, chest_plotly

    sec = report.section("Collision probability in the chest cavity (MDN paper section V, Fig. 6)")
    chest = build_chest(seed)
    env = chest.base_environment
    ctx["chest"], ctx["environment"] = chest, env
    model, robot = ctx.get("model"), ctx.get("robot")
    if model is None and robot is None:
        from riskplan.app.outputs.collision_table import _default_robot

        robot = _default_robot()  # None until a robot model is installed: arcs then
    kind, make, configs, _labels = _geometry_source(
        model=model, robot=robot if model is None else None
    )
    Report.text(
        sec,
        f"Procedural thoracic cavity: {chest.n_triangles} triangles, {env.n_obstacles} obstacles "
        f"({', '.join(n for n in env.names if not n.startswith('rib'))}, {sum(n.startswith('rib') for n in env.names)} ribs). "
        f"Robot base at the insertion point (red), z axis medial. Robot geometry from: {kind}.",
    )
    home = make(configs[:1])
    pts = home.sample(2000, seed=seed).detach().cpu().numpy().reshape(-1, 3)
    report.figure(
        sec,
        chest_figure(chest, chest.to_world(pts)),
        "collision_chest",
        "Chest cavity, exterior and interior; blue: points sampled from the robot's geometry distribution at home.",
    )
    report.plotly(
        sec,
        chest_plotly(chest, chest.to_world(pts)),
        "collision_chest_3d",
        "Chest cavity with the robot at home",
    )

    rows, meta = collision_table(
        seed=seed,
        n_samples=20_000,
        model=model,
        robot=robot if model is None else None,
        use_robot=False,
    )
    Report.table(
        sec,
        ["configuration", "bound (eq. 9)", "Monte Carlo", "95% CI", "union bound", "MC union"],
        [
            [
                r["label"],
                r["bound"],
                r["mc"],
                f"[{r['mc_low']:.4f}, {r['mc_high']:.4f}]",
                "-" if np.isnan(r["union"]) else r["union"],
                "-" if np.isnan(r["mc_union"]) else r["mc_union"],
            ]
            for r in rows
        ],
        caption=f"Bound vs Monte Carlo ({meta['n_samples']} samples, Wilson 95% intervals). The bound never falls below the interval.",
    )

    # sweep: from home to the most colliding configuration
    target = configs[int(np.argmax([r["bound"] for r in rows[:-1]]))]
    alpha = np.linspace(0, 1, 15)
    sweep = configs[0] + alpha[:, None] * (target - configs[0])
    gm = make(sweep)
    b = probability_of_collision(gm, env)
    mc = monte_carlo_probability(gm, env, 10_000, seed=seed)
    fig, ax = plt.subplots(figsize=(6, 3.6))
    ax.plot(alpha, b, "o-", label="bound (eq. 9)")
    ax.errorbar(
        alpha,
        mc.probability,
        yerr=[mc.probability - mc.low, mc.high - mc.probability],
        fmt="s",
        ms=3,
        capsize=2,
        label="Monte Carlo, 95% CI",
    )
    ax.set_xlabel("fraction of the way from home to the target configuration")
    ax.set_ylabel("P(collision)")
    ax.legend()
    ax.grid(alpha=0.3)
    report.figure(
        sec,
        fig,
        "collision_sweep",
        "Bound and Monte Carlo along a straight path in configuration space.",
    )

    # speed on this mesh
    gm50 = make(np.resize(sweep, (50, sweep.shape[1])))
    probability_of_collision(gm50[:1], env)
    t0 = time.perf_counter()
    for _ in range(5):
        probability_of_collision(gm50[:1], env)
    one = (time.perf_counter() - t0) / 5
    t0 = time.perf_counter()
    trajectory_bound(gm50, env)
    traj = time.perf_counter() - t0
    Report.table(
        sec,
        ["figure", "value"],
        [
            ["mesh triangles", env.n_faces],
            [f"one {gm50.n_components}-component mixture (ms)", one * 1e3],
            ["50-configuration trajectory, eq. 10 (ms)", traj * 1e3],
        ],
        caption="Speed of the bound (riskplan bench collision --json gives the full set).",
    )
