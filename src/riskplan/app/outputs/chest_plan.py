"""Chest-cavity planning outputs (MDN paper section V, Figs. 6-7): trajectory files, the
Fig. 7 trace, and an interactive 3-D view of the mixtures along the trajectories.

:func:`write_plan` writes, into one folder (every file atomically):

* ``nominal.json`` / ``nominal.csv`` and ``optimised.json`` / ``optimised.csv`` — tendon
  displacements per configuration with its eq.-9 bound, and the trajectory's eq.-10 bound;
* ``<name>_plan.csv`` / ``.json`` / ``.joint_trajectory.yaml`` for both — what a controller
  reads: time, displacements, tensions, per-step risk, and a ROS 2 JointTrajectory
  (:mod:`riskplan.planning.export`);
* ``trace.json`` / ``trace.png`` — the best eq.-10 bound per iteration (Fig. 7) with the
  paper's start and end values for comparison;
* ``chest.html`` — plotly: the obstacles and samples of the predicted mixtures along the
  nominal and optimised trajectories (world frame);
* ``plan.json`` — settings, timings, the roadmap size and (if computed) the shortest vs
  least-risk path bounds;
* ``validation.{json,md}`` (if given) — both trajectories executed on the simulated robot and
  a Monte Carlo of the mixtures next to the eq.-10 bound
  (:func:`riskplan.planning.validate.validation_table`).
"""

from __future__ import annotations

import io
import json

import numpy as np

# MDN paper, section V / Fig. 7: nominal ~15 %, under 7 % after 50 iterations
PAPER_FIG7 = {"nominal": 0.15, "optimised": 0.07, "iterations": 50}


def configuration_columns(n: int, robot=None) -> list[str]:
    """Column names of ``n`` model inputs: ``d1_m .. dm_m``, then ``rotation_rad`` and
    ``retraction_m`` where the robot has them."""
    m = n if robot is None else robot.n_tendons
    cols = [f"d{j + 1}_m" for j in range(m)]
    if robot is not None and robot.base_motion.rotation:
        cols.append("rotation_rad")
    if robot is not None and robot.base_motion.retraction:
        cols.append("retraction_m")
    return cols if len(cols) == n else [f"d{j + 1}_m" for j in range(n)]


def trajectory_record(name: str, trajectory, bounds, bound: float, robot=None) -> dict:
    traj = np.asarray(trajectory)
    cols = configuration_columns(traj.shape[1], robot)
    rec = {
        "name": name,
        "bound_eq10": float(bound),
        "configurations": traj.tolist(),
        "bounds_eq9": np.asarray(bounds).tolist(),
        "units": "m (tendon displacements)",
    }
    if len(cols) > sum(c.startswith("d") for c in cols):
        rec["columns"] = cols
        rec["units"] = "m (tendon displacements), rad (base rotation), m (base retraction)"
    return rec


def trajectory_csv(trajectory, bounds, bound: float, robot=None) -> str:
    traj = np.asarray(trajectory)
    buf = io.StringIO()
    buf.write(f"# eq. 10 trajectory bound: {bound:.8g}\n")
    buf.write(
        ",".join(["index"] + configuration_columns(traj.shape[1], robot) + ["bound_eq9"]) + "\n"
    )
    for i, (row, p) in enumerate(zip(traj, bounds)):
        buf.write(",".join([str(i)] + [f"{v:.9g}" for v in row] + [f"{p:.8g}"]) + "\n")
    return buf.getvalue()


def export_tendon_plans(out, trajectories: dict, robot) -> list[str]:
    """The controller's files of each trajectory ``{name: (T x m, eq. 9 bounds, eq. 10 bound)}``:
    ``<name>_plan.csv``, ``<name>_plan.json``, ``<name>_plan.joint_trajectory.yaml``
    (:mod:`riskplan.planning.export`)."""
    from riskplan.planning.export import tendon_plan, write_tendon_plan

    files = []
    for name, (traj, b, P) in trajectories.items():
        # base rotation/retraction columns become the plan's base joints (tendon_plan)
        plan = tendon_plan(
            robot, np.asarray(traj, dtype=np.float64), b, trajectory_risk=P, name=name
        )
        written = write_tendon_plan(plan, out, stem=f"{name}_plan")
        files += [p.name for p in written.values()]
    return files


def trace_figure(trace, *, label: str = "riskplan (this run)", paper: dict | None = PAPER_FIG7):
    """Fig. 7: best eq.-10 bound vs iteration, next to the paper's start/end values
    (``paper=None``: without them, for a scene that is not the paper's)."""
    import matplotlib.pyplot as plt

    tr = np.asarray(trace)
    fig, ax = plt.subplots(figsize=(6, 3.6))
    ax.plot(np.arange(len(tr)), 100 * tr, "o-", ms=3, label=label)
    if paper:
        ax.plot(
            [0, paper["iterations"]],
            [100 * paper["nominal"], 100 * paper["optimised"]],
            "s--",
            color="gray",
            label="paper Fig. 7 (start 15 %, < 7 % after 50)",
        )
    ax.set_xlabel("iteration")
    ax.set_ylabel("P(collision) bound, eq. 10 [%]")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return fig


def trajectories_plotly(
    environment_world,
    model,
    trajectories: dict,
    to_world,
    *,
    samples: int = 60,
    seed: int = 0,
    title: str = "chest cavity: mixtures along the trajectories",
):
    """Plotly figure: obstacles of ``environment_world`` and ``samples`` points of each predicted
    mixture along each trajectory (``{name: (T, m)}``), mapped by ``to_world (N, 3) -> (N, 3)``."""
    import plotly.graph_objects as go

    from riskplan.planning.chest_scene import mesh_traces

    env = environment_world
    meshes = {name: env.obstacle(k) for k, name in enumerate(env.names)}
    data = mesh_traces(meshes, wall_opacity=0.12, opacity=0.5)
    colours = {"nominal": "royalblue", "optimised": "darkorange", "least_risk": "seagreen"}
    for name, traj in trajectories.items():
        gm = model.predict(np.asarray(traj))
        pts = gm.sample(samples, seed=seed).detach().cpu().numpy().reshape(-1, 3)
        w = to_world(pts)
        data.append(
            go.Scatter3d(
                x=w[:, 0],
                y=w[:, 1],
                z=w[:, 2],
                mode="markers",
                name=f"{name} (mixture samples)",
                marker=dict(size=1.5, color=colours.get(name, "black"), opacity=0.5),
            )
        )
        tips = to_world(gm.means.detach().cpu().numpy().reshape(-1, 3))
        data.append(
            go.Scatter3d(
                x=tips[:, 0],
                y=tips[:, 1],
                z=tips[:, 2],
                mode="markers",
                name=f"{name} (component means)",
                marker=dict(size=3, color=colours.get(name, "black"), symbol="diamond"),
            )
        )
    fig = go.Figure(data=data)
    fig.update_layout(scene=dict(aspectmode="data"), title=title)
    return fig


def write_plan(
    out,
    plan,
    *,
    model,
    environment_world,
    to_world,
    validation: dict | None = None,
    extra: dict | None = None,
    scene: str = "chest",
    paper: dict | None = PAPER_FIG7,
):
    """Write the files listed in the module docstring for a :class:`~riskplan.planning.chest.ChestPlan`
    (a :class:`~riskplan.planning.robot_plan.RobotPlan`).

    ``scene`` names the 3-D view (``<scene>.html``); ``paper``: the paper's Fig. 7 values drawn
    beside the trace and stored in ``trace.json`` (``None`` for a scene that is not the paper's).
    """
    from pathlib import Path

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from riskplan.io import atomic_path, write_json_atomic, write_text_atomic

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    res = plan.optimised
    trajs = {
        "nominal": (plan.nominal, plan.nominal_bounds, plan.nominal_bound),
        "optimised": (res.trajectory, res.bounds, res.bound),
    }
    files = []
    for name, (traj, b, P) in trajs.items():
        write_json_atomic(out / f"{name}.json", trajectory_record(name, traj, b, P, model.robot))
        write_text_atomic(out / f"{name}.csv", trajectory_csv(traj, b, P, model.robot))
        files += [f"{name}.json", f"{name}.csv"]
    files += export_tendon_plans(out, trajs, model.robot)
    trace = {"trace": res.trace.tolist(), **({"paper": paper} if paper else {}), **res.to_json()}
    write_json_atomic(out / "trace.json", trace)
    fig = trace_figure(res.trace, paper=paper)
    with atomic_path(out / "trace.png", suffix=".png") as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)
    show = {"nominal": plan.nominal, "optimised": res.trajectory}
    if plan.paths is not None:
        show["least_risk"] = plan.paths["least_risk"]["trajectory"]
    title = (
        "chest cavity: mixtures along the trajectories"
        if scene == "chest"
        else f"{scene}: mixtures along the trajectories"
    )
    html = trajectories_plotly(environment_world, model, show, to_world, title=title)
    with atomic_path(out / f"{scene}.html", suffix=".html") as tmp:
        html.write_html(str(tmp), include_plotlyjs="cdn")
    files += ["trace.json", "trace.png", f"{scene}.html"]
    summary = {
        "nominal_bound": plan.nominal_bound,
        "optimised_bound": res.bound,
        "reduction": res.reduction,
        "iterations": len(res.trace) - 1,
        "bound_evaluations": res.evaluations,
        "start": plan.start.tolist(),
        "goal": plan.goal.tolist(),
        "goal_tip_base_frame": None if plan.goal_tip is None else plan.goal_tip.tolist(),
        "roadmap": {
            "milestones": plan.roadmap.n_vertices,
            "edges": plan.roadmap.n_edges,
            "build_s": plan.roadmap.build_seconds,
            "ompl_seeded": plan.roadmap.ompl_seeded,
        },
        "trajectory_length": len(plan.nominal),
        "timings_s": plan.timings,
        "settings": plan.settings,
        "frames": f"trajectories in tendon-displacement space (with base rotation/retraction where the robot has them); mixtures and goal tip in the robot base frame; {scene}.html in the world frame",
    }
    if plan.paths is not None:
        summary["paths"] = {
            k: {
                "bound_eq10": v["bound"],
                "length_m": v["length"],
                "configurations": len(v["trajectory"]),
            }
            for k, v in plan.paths.items()
        }
    if validation is not None:
        from riskplan.planning.validate import validation_markdown

        write_json_atomic(out / "validation.json", {"rows": validation})
        write_text_atomic(out / "validation.md", validation_markdown(validation))
        files += ["validation.json", "validation.md"]
        summary["validation"] = [
            {k: v for k, v in r.items() if k != "robot_per_config"} for r in validation
        ]
    if extra:
        summary.update(extra)
    write_json_atomic(out / "plan.json", json.loads(json.dumps(summary, default=float)))
    files.append("plan.json")
    return files


def scan_goal_tips(
    model, environment, tips, *, n_milestones: int = 300, seed: int = 0, tolerance: float = 0.005
) -> list[dict]:
    """Nominal eq.-10 bound for each candidate goal tip ``(N, 3)`` (base frame) on one roadmap.

    Which tip targets the model reaches (its predicted tip within ``tolerance``) and the bound
    of the PRM's shortest path to each; unreachable targets get ``bound = None``. The default
    goal is chosen on the robot instead (:func:`riskplan.planning.chest.recess_goal`).
    """
    from riskplan.errors import PlanningError
    from riskplan.planning.prm import (
        MeanValidity,
        build_roadmap,
        goal_from_tip,
        interpolate_path,
    )
    from riskplan.planning.risk import ConfigurationBound, trajectory_risk

    validity = MeanValidity(model, environment)
    rm = build_roadmap(validity, n_milestones=n_milestones, seed=seed)
    bound = ConfigurationBound(model, environment)
    start = np.clip(np.zeros(model.n_tendons), model.limits[:, 0], model.limits[:, 1])
    rows = []
    for tip in np.atleast_2d(np.asarray(tips, dtype=np.float64)):
        try:
            goal = goal_from_tip(rm, model, tip, tolerance=tolerance, seed=seed)
            traj = interpolate_path(rm.shortest_path(start, goal))
            P, _ = trajectory_risk(bound, traj)
            rows.append({"tip": tip.tolist(), "goal": goal.tolist(), "T": len(traj), "bound": P})
        except PlanningError as exc:
            rows.append(
                {"tip": tip.tolist(), "goal": None, "T": 0, "bound": None, "reason": str(exc)}
            )
    return rows
