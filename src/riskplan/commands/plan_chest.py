"""``riskplan plan chest``: PRM nominal trajectory + Bayesian optimisation of its collision
bound in the chest cavity (MDN paper section V, Figs. 6-7)."""

from __future__ import annotations

from pathlib import Path

import typer

from riskplan.commands._shared import base_pose_option, echo_validation


def _check_finite(**values):
    import math

    from riskplan.errors import InvalidInputError

    for name, v in values.items():
        if not math.isfinite(v):
            raise InvalidInputError(
                f"--{name.replace('_', '-')}: expected a finite number, got {v}"
            )


def register(plan_app: typer.Typer) -> None:
    """Add the ``chest`` and ``chest-risk-study`` commands to the ``riskplan plan`` group."""
    register_study(plan_app)
    _add_chest(plan_app)


def _chest_endpoints(model, robot, goal, start, goal_tensions, start_tensions, goal_tip):
    """``(model, robot or None, goal, start, goal tip)`` of ``plan chest`` from its options: the
    model, the robot it must match, and the end configurations as displacements (tensions
    converted through the robot model)."""
    from riskplan.errors import DataFormatError, InvalidInputError
    from riskplan.kinematics import load_model
    from riskplan.parsing import parse_numbers

    mdl = load_model(model)
    rob = None
    if robot is not None:
        from riskplan.robots import load_robot

        rob = load_robot(robot)
        if rob.n_tendons != mdl.n_tendons:
            raise DataFormatError(
                f"--robot {robot!r} has {rob.n_tendons} tendons but the model {model!r} has {mdl.n_tendons}"
            )
    m = mdl.n_tendons
    goal_tip_xyz = None if goal_tip is None else parse_numbers(goal_tip, "--goal-tip", count=3)
    if goal_tensions is None and start_tensions is None:
        goal_d = None if goal is None else parse_numbers(goal, "--goal", count=m)
        start_d = None if start is None else parse_numbers(start, "--start", count=m)
    else:
        from riskplan.commands._shared import configuration_from_options

        conv = rob if rob is not None else mdl.robot
        if conv is None:
            raise InvalidInputError(
                "--start-tensions/--goal-tensions need a robot model: give --robot"
            )
        goal_d = configuration_from_options(conv, goal, goal_tensions, "goal")
        start_d = configuration_from_options(conv, start, start_tensions, "start")
    return mdl, rob, goal_d, start_d, goal_tip_xyz


def _chest_scene(env, base_pose, chest_seed, rob, mdl):
    """``(environment in the world, in the robot's base frame, base-to-world map, scene record)``
    of ``plan chest``: the procedural chest, or a mesh placed by its sidecar or ``--base-pose``."""
    from riskplan.collision import Environment
    from riskplan.errors import InvalidInputError

    if env is None:
        if base_pose is not None:
            raise InvalidInputError(
                "--base-pose applies to --env meshes; the procedural chest has its own base frame"
            )
        from riskplan.planning.chest_scene import build_chest

        ch = build_chest(chest_seed)
        env_world, env_base, to_world = ch.environment, ch.base_environment, ch.to_world
        scene = {"scene": "procedural chest", "chest_seed": chest_seed}
    else:
        from riskplan.collision.mesh_files import (
            BasePose,
            environment_in_base_frame,
            mesh_base_pose,
        )

        # frame from --base-pose, else the mesh's sidecar (riskplan env chest), else a named error
        pose = mesh_base_pose(env, BasePose.parse(base_pose) if base_pose is not None else None)
        env_world = Environment.load(env)
        # units judged against the robot planned for (--robot, else the model's own)
        judge = rob if rob is not None else mdl.robot
        if judge is not None:
            from riskplan.collision.geometry import check_metre_scale

            check_metre_scale(
                env_world.vertices, judge.params.backbone.length, source=f"--env {env}"
            )
        env_base = environment_in_base_frame(env_world, pose)
        to_world = pose.to_world
        scene = {"scene": str(env), **pose.to_json()}
    return env_world, env_base, to_world, scene


def _print_chest_summary(plan, risk, validation, out) -> None:
    """What ``plan chest`` prints when it is done: roadmap, bounds, validation table."""
    res = plan.optimised
    typer.echo(
        f"roadmap: {plan.roadmap.describe()}; trajectory of {len(plan.nominal)} configurations"
    )
    if plan.paths is not None:
        typer.echo(
            f"shortest path bound {plan.paths['shortest']['bound']:.4f}, least-risk path bound {plan.paths['least_risk']['bound']:.4f}"
        )
    typer.echo(
        f"{'eq. 10 bound' if risk == 'eq9' else f'{risk} risk (eq. 10 product)'}: "
        f"nominal {plan.nominal_bound:.4f} -> optimised {res.bound:.4f} "
        f"({100 * res.reduction:.1f} % lower, {len(res.trace) - 1} iterations, {res.evaluations} bound evaluations)"
    )
    echo_validation(validation)
    typer.echo(f"wrote {out}")


def _chest_optimiser(
    mdl, iterations, candidates, radius, method, resolution, step, milestones, executions
):
    """The optimiser settings of ``plan chest``, checked with the whole request's budget before
    any work."""
    from riskplan.errors import InvalidInputError
    from riskplan.planning.bo import OptimiserConfig
    from riskplan.planning.robot_plan import check_plan_budget

    cfg = OptimiserConfig(
        iterations=iterations,
        n_candidates=candidates,
        radius=radius,
        method=method,
        resolution=resolution,
    )
    cfg.validate()
    for name, v in (("step", step), ("resolution", resolution)):
        if v <= 0:
            raise InvalidInputError(f"--{name}: expected a number > 0, got {v}")
    check_plan_budget(
        mdl.limits,
        n_milestones=milestones,
        step=step,
        resolution=resolution,
        optimiser=cfg,
        executions=executions,
    )
    return cfg


# options of the command below
_CHEST_OUT = typer.Option(
    ..., "--out", "-o", help="Output folder (trajectories, trace, chest.html, plan.json)."
)
_CHEST_MODEL = typer.Option(
    "paper",
    "--model",
    help="'paper' (shipped model) or a model folder from `riskplan model train`.",
)
_CHEST_ENV = typer.Option(
    None,
    "--env",
    help="Patient mesh (STL/OBJ/PLY); its frame comes from the sidecar FILE.json that `riskplan env chest` writes, or from --base-pose. Default: the procedural chest.",
)
_CHEST_CHEST_SEED = typer.Option(
    0, "--chest-seed", min=0, help="Seed of the procedural chest's organ shapes."
)
_CHEST_GOAL_TIP = typer.Option(
    None,
    "--goal-tip",
    help="Tip target X,Y,Z in the robot base frame (m). Default: the recess goal DEFAULT_GOAL (docs/validation.md).",
)
_CHEST_START = typer.Option(None, "--start", help="Start tendon displacements (default: zeros).")
_CHEST_GOAL_TENSIONS = typer.Option(
    None,
    "--goal-tensions",
    help="Goal as tendon tensions T1,...,Tm (N), converted to displacements through the robot model.",
)
_CHEST_START_TENSIONS = typer.Option(
    None, "--start-tensions", help="Start as tendon tensions (N), like --goal-tensions."
)
_CHEST_TIP_TOLERANCE = typer.Option(0.005, "--tip-tolerance", help="Goal tip tolerance (m).")
_CHEST_ITERATIONS = typer.Option(
    50, "--iterations", min=0, help="Optimisation iterations (one bound evaluation each)."
)
_CHEST_CANDIDATES = typer.Option(256, "--candidates", min=1, help="Candidates drawn per iteration.")
_CHEST_RADIUS = typer.Option(
    0.1, "--radius", help="Neighbourhood half-width, fraction of each tendon's range."
)
_CHEST_METHOD = typer.Option(
    "bo", "--method", help="bo (the paper's), random (local search), trust_region."
)
_CHEST_STEP = typer.Option(
    0.0025, "--step", help="Largest step between trajectory configurations (m)."
)
_CHEST_RESOLUTION = typer.Option(0.001, "--resolution", help="Motion check resolution (m).")
_CHEST_LEAST_RISK = typer.Option(
    False,
    "--least-risk",
    help="Also search the roadmap for the least-risk path (prices every edge).",
)
_CHEST_RISK = typer.Option(
    "eq9",
    "--risk",
    help="Risk optimised per configuration: eq9 (the paper's bound), cloud (body contact "
    "from sampled body clouds) or bodies (body contact over sampled executions: the "
    "transmission's draws through the learned model; docs/validation.md); eq. 10 "
    "combines it along the path.",
)
_CHEST_ROBOT = typer.Option(
    None,
    "--robot",
    help="Robot (name or TOML) the model must match (default: the model's own).",
)
_CHEST_EXECUTIONS = typer.Option(
    1000,
    "--executions",
    min=0,
    help="Validation: executions of each trajectory on the simulated robot (0: skip).",
)
_CHEST_MIXTURE_SAMPLES = typer.Option(
    100_000,
    "--mixture-samples",
    min=1,
    help="Validation: Monte Carlo trials of the MDN mixtures.",
)
_CHEST_WORKERS = typer.Option(
    1,
    "--workers",
    min=1,
    help="Worker processes for the validation (1: in this process, the fastest on 2 shared cores).",
)
_CHEST_SEED = typer.Option(
    0, "--seed", min=0, help="Seed of the roadmap, goal search, optimiser and validation."
)
_CHEST_RESUME = typer.Option(
    False, "--resume", help="Continue an interrupted optimisation from OUT/checkpoint.json."
)


def _add_chest(plan_app: typer.Typer):
    """Add ``chest`` to ``plan_app``; returns the command function."""

    @plan_app.command("chest")
    def chest(
        out: Path = _CHEST_OUT,
        model: str = _CHEST_MODEL,
        env: Path = _CHEST_ENV,
        base_pose: str = base_pose_option(),
        chest_seed: int = _CHEST_CHEST_SEED,
        goal_tip: str = _CHEST_GOAL_TIP,
        goal: str = typer.Option(None, "--goal", help="Goal tendon displacements D1,...,Dm (m)."),
        start: str = _CHEST_START,
        goal_tensions: str = _CHEST_GOAL_TENSIONS,
        start_tensions: str = _CHEST_START_TENSIONS,
        tip_tolerance: float = _CHEST_TIP_TOLERANCE,
        iterations: int = _CHEST_ITERATIONS,
        candidates: int = _CHEST_CANDIDATES,
        radius: float = _CHEST_RADIUS,
        method: str = _CHEST_METHOD,
        milestones: int = typer.Option(300, "--milestones", min=2, help="PRM milestones."),
        step: float = _CHEST_STEP,
        resolution: float = _CHEST_RESOLUTION,
        least_risk: bool = _CHEST_LEAST_RISK,
        risk: str = _CHEST_RISK,
        robot: str = _CHEST_ROBOT,
        executions: int = _CHEST_EXECUTIONS,
        mixture_samples: int = _CHEST_MIXTURE_SAMPLES,
        workers: int = _CHEST_WORKERS,
        seed: int = _CHEST_SEED,
        resume: bool = _CHEST_RESUME,
    ) -> None:
        """Plan a nominal trajectory with a PRM and lower its P(collision) bound by Bayesian optimisation."""

        from riskplan.commands._shared import output_folder, progress_bar
        from riskplan.io import check_output_folder
        from riskplan.planning.chest import plan_chest

        _check_finite(tip_tolerance=tip_tolerance, radius=radius, step=step, resolution=resolution)
        check_output_folder(out, "--out")
        mdl, rob, goal_d, start_d, goal_tip_xyz = _chest_endpoints(
            model, robot, goal, start, goal_tensions, start_tensions, goal_tip
        )
        env_world, env_base, to_world, scene = _chest_scene(env, base_pose, chest_seed, rob, mdl)
        cfg = _chest_optimiser(
            mdl, iterations, candidates, radius, method, resolution, step, milestones, executions
        )
        with output_folder(out), progress_bar() as bar:
            t_rm = bar.add_task("roadmap", total=milestones, status="")
            t_rk = bar.add_task("risk roadmap", total=1, status="", visible=least_risk)
            t_bo = bar.add_task(f"optimisation ({method})", total=iterations, status="")
            plan = plan_chest(
                mdl,
                env_base,
                start=start_d,
                goal=goal_d,
                goal_tip=goal_tip_xyz,
                tip_tolerance=tip_tolerance,
                n_milestones=milestones,
                step=step,
                resolution=resolution,
                optimiser=cfg,
                seed=seed,
                least_risk=least_risk,
                risk=risk,
                checkpoint=out / "checkpoint.json",
                resume=resume,
                roadmap_progress=lambda d, n: bar.update(t_rm, completed=d, total=n),
                risk_progress=lambda d, n: bar.update(
                    t_rk, completed=d, total=n, status="milestones settled"
                ),
                optimise_progress=lambda i, n, b: bar.update(
                    t_bo, completed=i, total=n, status=f"bound {b:.4f}"
                ),
            )
            validation = None
            if executions > 0:
                from riskplan.planning.validate import validation_table

                t_va = bar.add_task(
                    "validation on the robot", total=None, status=f"{executions} executions x 2"
                )
                validation = validation_table(
                    mdl,
                    {"nominal": plan.nominal, "optimised": plan.optimised.trajectory},
                    env_base,
                    robot=rob,
                    n_robot=executions,
                    n_mixture=mixture_samples,
                    seed=seed,
                    backend="serial" if workers <= 1 else "local",
                    workers=workers,
                )
                bar.update(t_va, total=1, completed=1)
            from riskplan.app.outputs.chest_plan import write_plan

            write_plan(
                out,
                plan,
                model=mdl,
                environment_world=env_world,
                to_world=to_world,
                validation=validation,
                extra={"model": model, **scene},
            )
        _print_chest_summary(plan, risk, validation, out)

    return chest


def register_study(plan_app: typer.Typer) -> None:
    """Add ``chest-risk-study`` (does a risk from the learned model predict the robot?)."""

    @plan_app.command("chest-risk-study")
    def chest_risk_study(
        out: Path = typer.Option(
            ..., "--out", "-o", help="Output folder (continued if it exists)."
        ),
        scale: str = typer.Option("reduced", help="smoke | reduced | full (docs/validation.md)."),
        seed: int = typer.Option(0, "--seed", min=0, help="Seed of the selection and executions."),
    ) -> None:
        """Calibration of eq. 9/10, the cloud risk and the sampled-body risk against collision rates on the robot.

        The same study as ``riskplan reproduce --paper mdn --stage robot-risk`` (which also
        writes its summary to results.json and the report), into OUT of its own.
        """
        from dataclasses import asdict

        from riskplan.app.reproduce.risk_calibration import RISK_STUDY_SCALES, run_risk_study
        from riskplan.app.store import ResultStore
        from riskplan.commands._shared import progress_bar
        from riskplan.errors import InvalidInputError

        if scale not in RISK_STUDY_SCALES:
            raise InvalidInputError(
                f"--scale: expected one of {sorted(RISK_STUDY_SCALES)}, got {scale!r}"
            )
        sc = RISK_STUDY_SCALES[scale]
        store = ResultStore(
            out / "store", {"study": "chest-risk", "scale": asdict(sc), "seed": seed}
        )
        with progress_bar() as bar:
            tasks: dict = {}

            def progress(stage, done, total):
                if stage not in tasks:
                    tasks[stage] = bar.add_task(stage, total=total, status="")
                bar.update(tasks[stage], completed=done, total=total)

            r = run_risk_study(out, sc, store, seed=seed, progress=progress)
        typer.echo(
            f"measured rates in [5 %, 95 %]: {100 * r['share_measured_5_95']:.0f} % of items"
        )
        for name, m in r["metrics"].items():
            a = m["all"]
            mae = "n/a" if a["mae_mid"] is None else f"{100 * a['mae_mid']:.1f}"
            typer.echo(
                f"{name}: MAE on 5-95 % items {mae} points (n = {a['n_mid']}), "
                f"MAE on all {100 * a['mae_all']:.1f}, Brier {a['brier']:.4f}"
            )
        typer.echo(f"wrote {out / 'risk_calibration.json'} and {out / 'risk_calibration.png'}")
