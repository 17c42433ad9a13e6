"""``riskplan plan robot``: the MDN paper's planner (roadmap, nominal trajectory, Bayesian
optimisation of P(collision)) for any robot in any anatomy, from a problem file or from a
robot, a mesh and a start and goal; builds and caches the robot's model when none is given."""

from __future__ import annotations

from pathlib import Path

import typer


def register(plan_app: typer.Typer) -> None:
    """Add the ``robot`` command to the ``riskplan plan`` group."""
    _add_robot_cmd(plan_app)


def _robot_problem(problem, robot, env, start, goal, goal_tip):
    """The planning problem of ``plan robot``: its ``--problem`` file, or one made of
    ``--robot``, ``--env``, ``--start`` and ``--goal`` (the combinations checked first)."""
    from riskplan.errors import InvalidInputError
    from riskplan.planning.problem_scene import problem_from_options

    # every input is checked before any work: the problem, the scene, start and goal
    if problem is not None:
        if robot is not None or env is not None or start is not None or goal is not None:
            raise InvalidInputError(
                "--problem holds the robot, environment, start and goal: do not combine it with --robot/--env/--start/--goal"
            )
        if goal_tip is not None:
            raise InvalidInputError("--goal-tip: the problem file gives the goal")
        from riskplan.planning.problem import load_problem

        prob = load_problem(problem)
    else:
        missing = [
            n for n, v in (("--robot", robot), ("--env", env), ("--start", start)) if v is None
        ]
        if goal is None and goal_tip is None:
            missing.append("--goal or --goal-tip")
        if missing:
            raise InvalidInputError(
                f"give --problem FILE, or --robot, --env, --start and --goal: missing {', '.join(missing)}"
            )
        if goal is not None and goal_tip is not None:
            raise InvalidInputError("give --goal or --goal-tip, not both")
        prob = problem_from_options(robot, env, start, goal)
    return prob


def _robot_model(bar, model, rob, preset, cache, seed, workers):
    """``(model, box, build)`` of ``plan robot``: the ``--model`` folder (checked against the
    robot), else the model built or found in the cache for the robot (with progress)."""
    from riskplan.errors import InvalidInputError
    from riskplan.kinematics.model_cache import ensure_model, robot_hash

    if model is not None:
        from riskplan.kinematics import load_model

        mdl = load_model(model)
        if mdl.robot is None or robot_hash(mdl.robot) != robot_hash(rob):
            raise InvalidInputError(
                f"--model {model!r} was trained for robot {mdl.robot_name!r}, not the problem's robot {rob.name!r} (their parameters differ)"
            )
        box, build = None, None
    else:
        tasks = {}

        def on_build(stage, done, total):
            if stage not in tasks:
                tasks[stage] = bar.add_task(f"model: {stage}", total=total, status="")
            bar.update(tasks[stage], completed=done, total=total)

        build = ensure_model(
            rob,
            preset=preset,
            cache=cache,
            seed=seed,
            workers=workers or None,
            backend="serial" if workers == 1 else "local",
            progress=on_build,
        )
        mdl, box = build.model, build.box
    return mdl, box, build


def _robot_validation(bar, executions, mdl, plan, environment, rob, mixture_samples, seed, workers):
    """The validation table of ``plan robot`` (None without ``--executions``)."""
    validation = None
    if executions:
        from riskplan.planning.validate import validation_table

        t_va = bar.add_task(
            f"validation ({executions} robot executions per trajectory)", total=None
        )
        validation = validation_table(
            mdl,
            {"nominal": plan.nominal, "optimised": plan.optimised.trajectory},
            environment,
            robot=rob,
            n_robot=executions,
            n_mixture=mixture_samples,
            seed=seed,
            backend="serial" if workers == 1 else "local",
            workers=workers or None,
        )
        bar.update(t_va, total=1, completed=1)
    return validation


def _print_robot_summary(plan, summary, build, model, validation, out) -> None:
    """What ``plan robot`` prints when it is done: model, roadmap, bounds, checks."""
    from riskplan.commands._shared import echo_validation

    res = plan.optimised
    typer.echo(
        f"model: {'cached ' if build is not None and build.cached else ''}"
        + (str(build.path) if build is not None else model)
    )
    typer.echo(
        f"roadmap: {plan.roadmap.describe()}; trajectory of {len(plan.nominal)} configurations"
    )
    typer.echo(
        f"eq. 10 bound: nominal {plan.nominal_bound:.4f} -> optimised {res.bound:.4f} "
        f"({100 * res.reduction:.1f} % lower, {len(res.trace) - 1} iterations)"
    )
    chk = summary["robot_model_check"]
    for name, c in chk.items():
        typer.echo(
            f"check on the robot model, {name}: {c['colliding']} of {c['configurations']} configurations collide, "
            f"{c['above_max_tension']} need more than max_tension"
        )
    echo_validation(validation)
    typer.echo(f"wrote {out}")


# options of the command below
_ROBOT_CMD_PROBLEM = typer.Option(
    None,
    "--problem",
    help="Problem file (the Kuntz lab's task TOML or riskplan's): the robot, its problem table (start, goal) and its environment (meshes, spheres, points, voxels).",
)
_ROBOT_CMD_ROBOT = typer.Option(
    None, "--robot", help="Robot (name or TOML), with --env and --start/--goal."
)
_ROBOT_CMD_ENV = typer.Option(
    None, "--env", help="Anatomy mesh (STL/OBJ/PLY) in the robot base frame (m)."
)
_ROBOT_CMD_START = typer.Option(
    None,
    "--start",
    help="Start: tendon tensions T1,...,Tm (N), then rotation (rad) and retraction (m) where the robot has them.",
)
_ROBOT_CMD_GOAL_TIP = typer.Option(
    None, "--goal-tip", help="Goal as a tip target X,Y,Z (m, base frame) instead of --goal."
)
_ROBOT_CMD_MODEL = typer.Option(
    None,
    "--model",
    help="A model folder from `riskplan model train` (default: the robot's cached model, built if absent).",
)
_ROBOT_CMD_PRESET = typer.Option(
    "small", "--preset", help="Data-set preset of a model built here (tiny, small, paper)."
)
_ROBOT_CMD_CACHE = typer.Option(
    None,
    "--cache",
    help="Model cache folder (default $RISKPLAN_CACHE/models or ~/.cache/riskplan/models).",
)
_ROBOT_CMD_ITERATIONS = typer.Option(
    50, "--iterations", min=0, help="Optimisation iterations (one bound evaluation each)."
)
_ROBOT_CMD_CANDIDATES = typer.Option(
    256, "--candidates", min=1, help="Candidates drawn per iteration."
)
_ROBOT_CMD_STEP = typer.Option(
    0.0025, "--step", help="Largest step between trajectory configurations (m)."
)
_ROBOT_CMD_RESOLUTION = typer.Option(0.001, "--resolution", help="Motion check resolution (m).")
_ROBOT_CMD_TIP_TOLERANCE = typer.Option(0.005, "--tip-tolerance", help="Goal tip tolerance (m).")
_ROBOT_CMD_WORKERS = typer.Option(
    1, "--workers", min=0, help="Data-set generation workers (0: one per core)."
)
_ROBOT_CMD_RESUME = typer.Option(
    False, "--resume", help="Continue an interrupted optimisation from OUT/checkpoint.json."
)
_ROBOT_CMD_EXECUTIONS = typer.Option(
    0,
    "--executions",
    min=0,
    help="Validation: executions of each trajectory on the simulated robot (0: skip; the chest plan's check uses 1000).",
)
_ROBOT_CMD_MIXTURE_SAMPLES = typer.Option(
    100_000,
    "--mixture-samples",
    min=1,
    help="Validation: Monte Carlo trials of the MDN mixtures.",
)
_ROBOT_CMD_VOXELS = typer.Option(
    "auto",
    "--voxels",
    help="Plan against the problem's [voxel_environment]: auto (when it gives no mesh), on, off.",
)


def _add_robot_cmd(plan_app: typer.Typer):
    """Add ``robot`` to ``plan_app``; returns the command function."""

    @plan_app.command("robot")
    def robot_cmd(
        out: Path = typer.Option(..., "--out", "-o", help="Output folder."),
        problem: Path = _ROBOT_CMD_PROBLEM,
        robot: str = _ROBOT_CMD_ROBOT,
        env: Path = _ROBOT_CMD_ENV,
        start: str = _ROBOT_CMD_START,
        goal: str = typer.Option(None, "--goal", help="Goal, like --start."),
        goal_tip: str = _ROBOT_CMD_GOAL_TIP,
        model: str = _ROBOT_CMD_MODEL,
        preset: str = _ROBOT_CMD_PRESET,
        cache: Path = _ROBOT_CMD_CACHE,
        milestones: int = typer.Option(300, "--milestones", min=2, help="PRM milestones."),
        iterations: int = _ROBOT_CMD_ITERATIONS,
        candidates: int = _ROBOT_CMD_CANDIDATES,
        step: float = _ROBOT_CMD_STEP,
        resolution: float = _ROBOT_CMD_RESOLUTION,
        tip_tolerance: float = _ROBOT_CMD_TIP_TOLERANCE,
        workers: int = _ROBOT_CMD_WORKERS,
        seed: int = typer.Option(0, "--seed", min=0, help="Seed of the model build and the plan."),
        resume: bool = _ROBOT_CMD_RESUME,
        executions: int = _ROBOT_CMD_EXECUTIONS,
        mixture_samples: int = _ROBOT_CMD_MIXTURE_SAMPLES,
        voxels: str = _ROBOT_CMD_VOXELS,
    ) -> None:
        """Plan for any robot in any anatomy (MDN paper section V): the model, the roadmap, the
        nominal trajectory, its P(collision) bound lowered by Bayesian optimisation; the plan
        exported (CSV, JSON, ROS 2 JointTrajectory) and checked on the robot model."""
        import math

        import numpy as np

        from riskplan.commands._shared import progress_bar
        from riskplan.errors import InvalidInputError
        from riskplan.parsing import parse_numbers
        from riskplan.planning.bo import OptimiserConfig
        from riskplan.planning.problem_scene import problem_configurations, problem_environment

        for name, v in (
            ("step", step),
            ("resolution", resolution),
            ("tip-tolerance", tip_tolerance),
        ):
            if not (math.isfinite(v) and v > 0):
                raise InvalidInputError(f"--{name}: expected a finite number > 0, got {v}")
        # every input is checked before any work: the problem, the scene, start and goal
        prob = _robot_problem(problem, robot, env, start, goal, goal_tip)
        environment = problem_environment(prob, voxels=voxels)
        s_cfg, g_cfg = problem_configurations(prob)
        tip = None if goal_tip is None else parse_numbers(goal_tip, "--goal-tip", count=3)
        if tip is not None:
            g_cfg = None
        cfg = OptimiserConfig(iterations=iterations, n_candidates=candidates, resolution=resolution)
        cfg.validate()
        rob = prob.robot

        with progress_bar() as bar:
            mdl, box, build = _robot_model(bar, model, rob, preset, cache, seed, workers)
            from riskplan.planning.robot_plan import (
                check_plan_budget,
                configuration_weights,
                plan_robot,
            )

            if executions:
                n_in = len(s_cfg)
                lim = np.asarray(box if box is not None else mdl.limits, dtype=np.float64)
                check_plan_budget(
                    lim * configuration_weights(rob, n_in)[:, None],
                    n_milestones=milestones,
                    step=step,
                    resolution=resolution,
                    optimiser=cfg,
                    executions=executions,
                )
            out.mkdir(parents=True, exist_ok=True)
            t_rm = bar.add_task("roadmap", total=milestones, status="")
            t_bo = bar.add_task("optimisation (bo)", total=iterations, status="")
            plan = plan_robot(
                mdl,
                environment,
                start=s_cfg,
                goal=g_cfg,
                goal_tip=tip,
                box=box,
                tip_tolerance=tip_tolerance,
                n_milestones=milestones,
                step=step,
                resolution=resolution,
                optimiser=cfg,
                seed=seed,
                checkpoint=out / "checkpoint.json",
                resume=resume,
                roadmap_progress=lambda d, n: bar.update(t_rm, completed=d, total=n),
                optimise_progress=lambda i, n, b: bar.update(
                    t_bo, completed=i, total=n, status=f"bound {b:.4f}"
                ),
            )
            validation = _robot_validation(
                bar, executions, mdl, plan, environment, rob, mixture_samples, seed, workers
            )
        from riskplan.app.outputs.robot_plan import write_robot_plan

        summary = write_robot_plan(
            out,
            plan,
            model=mdl,
            environment=environment,
            problem=prob,
            build=build,
            validation=validation,
        )
        _print_robot_summary(plan, summary, build, model, validation, out)

    return robot_cmd
