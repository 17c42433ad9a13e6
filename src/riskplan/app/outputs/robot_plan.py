"""Outputs of ``riskplan plan robot``: the plan of any robot in any anatomy, exported, and
checked on the robot model.

:func:`write_robot_plan` writes, into one folder (every file atomically), the files of
:func:`riskplan.app.outputs.chest_plan.write_plan` without the chest's framing: the trace
(``trace.{json,png}``) without the paper's Fig. 7 values, the 3-D view as ``scene.html``
(robot base frame), the trajectories with their base rotation/retraction columns, and
``plan.json`` with the model build (cache folder, per-stage seconds, test-split evaluation),
the problem file, and :func:`robot_model_check` of both trajectories.
"""

from __future__ import annotations

import numpy as np


def robot_model_check(robot, trajectory, environment) -> dict:
    """The trajectory ``(T, n_config)`` (displacement form) on the robot model: the backbone of
    the Cosserat shape at every configuration against ``environment`` (a backbone segment inside
    an obstacle or crossing a surface counts as a collision), and the tensions each needs.

    Returns ``{"configurations", "colliding", "colliding_steps", "above_max_tension",
    "max_tension_ratio"}``. A check of the plan on the nominal robot (no hysteresis, no
    transmission noise), beside the model's eq.-10 bound.
    """
    q = np.atleast_2d(np.asarray(trajectory, dtype=np.float64))
    d, rot, ret = robot.split_configuration(q)
    shape = robot.solve_displacements(d, rotation=rot, retraction=ret)
    P = np.asarray(shape.positions)  # (T, S, 3), base frame
    hit = environment.segments_collide(P[:, :-1], P[:, 1:]).any(-1)
    tau = robot.tensions_for_displacements(d, retraction=ret)
    ratio = tau / robot.tension_limits
    return {
        "configurations": len(q),
        "colliding": int(hit.sum()),
        "colliding_steps": np.flatnonzero(hit).tolist(),
        "above_max_tension": int((ratio > 1 + 1e-9).any(-1).sum()),
        "max_tension_ratio": float(ratio.max()),
    }


def write_robot_plan(
    out, plan, *, model, environment, problem=None, build=None, validation=None
) -> dict:
    """Write the plan's files (module docs); returns the ``plan.json`` summary.

    ``validation``: optional :func:`riskplan.planning.validate.validation_table` rows (the
    executions on the simulated robot), written as the chest plan writes them."""
    import json
    from pathlib import Path

    from riskplan.app.outputs.chest_plan import write_plan
    from riskplan.io import write_json_atomic

    out = Path(out)
    robot = model.robot
    check = {}
    if robot is not None and problem is not None:
        check = {
            "nominal": robot_model_check(problem.robot, plan.nominal, environment),
            "optimised": robot_model_check(problem.robot, plan.optimised.trajectory, environment),
        }
    extra = {
        "scene": "problem file" if problem is not None and problem.path else "mesh",
        "problem": None if problem is None or problem.path is None else str(problem.path),
        "meshes": [] if problem is None else [str(m) for m in problem.meshes],
        "robot": None if robot is None else robot.name,
        "model": None
        if build is None
        else {
            "path": str(build.path),
            "cached": build.cached,
            "build_timings_s": build.timings,
            "evaluation": build.evaluation,
            "protocol": build.record.get("protocol"),
        },
        "robot_model_check": check,
    }
    write_plan(
        out,
        plan,
        model=model,
        environment_world=environment,
        to_world=lambda x: x,
        extra=extra,
        scene="scene",
        paper=None,
        validation=validation,
    )
    summary = json.loads((out / "plan.json").read_text(encoding="utf-8"))
    write_json_atomic(out / "plan.json", summary)
    return summary
