"""``riskplan plan chest``: PRM nominal trajectory + Bayesian optimisation of its collision
bound in the chest cavity (MDN paper section V, Figs. 6-7)."""

from __future__ import annotations

from pathlib import Path

import typer

from riskplan.commands._shared import base_pose_option


def _check_finite(**values):
    import math

    from riskplan.errors import InvalidInputError

    for name, v in values.items():
        if not math.isfinite(v):
            raise InvalidInputError(
                f"--{name.replace('_', '-')}: expected a finite number, got {v}"
            )


def register(plan_app: typer.Typer) -> None:
    """Add the ``chest`` command to the ``riskplan plan`` group."""

    @plan_app.command("chest")
    def chest(
        out: Path = typer.Option(
            ..., "--out", "-o", help="Output folder (trajectories, trace, chest.html, plan.json)."
        ),
        model: str = typer.Option(
            "paper",
            "--model",
            help="'paper' (shipped model) or a model folder from `riskplan train`.",
        ),
        env: Path = typer.Option(
            None,
            "--env",
            help="Patient mesh (STL/OBJ/PLY); its frame comes from the sidecar FILE.json that `riskplan env chest` writes, or from --base-pose. Default: the procedural chest.",
        ),
        base_pose: str = base_pose_option(),
        chest_seed: int = typer.Option(
            0, "--chest-seed", min=0, help="Seed of the procedural chest's organ shapes."
        ),
        goal_tip: str = typer.Option(
            None,
            "--goal-tip",
            help="Tip target X,Y,Z in the robot base frame (m). Default: the effusion-pocket target.",
        ),
        goal: str = typer.Option(None, "--goal", help="Goal tendon displacements D1,...,Dm (m)."),
        start: str = typer.Option(
            None, "--start", help="Start tendon displacements (default: zeros)."
        ),
        tip_tolerance: float = typer.Option(
            0.005, "--tip-tolerance", help="Goal tip tolerance (m)."
        ),
        iterations: int = typer.Option(
            50, "--iterations", min=0, help="Optimisation iterations (one bound evaluation each)."
        ),
        candidates: int = typer.Option(
            256, "--candidates", min=1, help="Candidates drawn per iteration."
        ),
        radius: float = typer.Option(
            0.1, "--radius", help="Neighbourhood half-width, fraction of each tendon's range."
        ),
        method: str = typer.Option(
            "bo", "--method", help="bo (the paper's), random (local search), trust_region."
        ),
        milestones: int = typer.Option(300, "--milestones", min=2, help="PRM milestones."),
        step: float = typer.Option(
            0.0025, "--step", help="Largest step between trajectory configurations (m)."
        ),
        resolution: float = typer.Option(
            0.001, "--resolution", help="Motion check resolution (m)."
        ),
        least_risk: bool = typer.Option(
            False,
            "--least-risk",
            help="Also search the roadmap for the least-risk path (prices every edge).",
        ),
        robot: str = typer.Option(
            None,
            "--robot",
            help="Robot (name or TOML) the model must match (default: the model's own).",
        ),
        executions: int = typer.Option(
            1000,
            "--executions",
            min=0,
            help="Validation: executions of each trajectory on the simulated robot (0: skip).",
        ),
        mixture_samples: int = typer.Option(
            100_000,
            "--mixture-samples",
            min=1,
            help="Validation: Monte Carlo trials of the MDN mixtures.",
        ),
        workers: int = typer.Option(
            1,
            "--workers",
            min=1,
            help="Worker processes for the validation (1: in this process, the fastest on 2 shared cores).",
        ),
        seed: int = typer.Option(
            0, "--seed", min=0, help="Seed of the roadmap, goal search, optimiser and validation."
        ),
        resume: bool = typer.Option(
            False, "--resume", help="Continue an interrupted optimisation from OUT/checkpoint.json."
        ),
    ) -> None:
        """Plan a nominal trajectory with a PRM and lower its P(collision) bound by Bayesian optimisation."""
        import torch

        from riskplan.collision import Environment
        from riskplan.commands._shared import output_folder, progress_bar
        from riskplan.errors import DataFormatError, InvalidInputError
        from riskplan.io import check_output_folder
        from riskplan.kinematics import load_model
        from riskplan.parsing import parse_numbers
        from riskplan.planning.bo import OptimiserConfig
        from riskplan.planning.chest import check_chest_budget, plan_chest

        torch.set_num_threads(1)
        _check_finite(tip_tolerance=tip_tolerance, radius=radius, step=step, resolution=resolution)
        check_output_folder(out, "--out")
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
        goal_d = None if goal is None else parse_numbers(goal, "--goal", count=m)
        start_d = None if start is None else parse_numbers(start, "--start", count=m)
        if env is None:
            if base_pose is not None:
                raise InvalidInputError(
                    "--base-pose applies to --env meshes; the procedural chest has its own base frame"
                )
            from riskplan.scenarios.chest import build_chest

            ch = build_chest(chest_seed)
            env_world, env_base, to_world = ch.environment, ch.base_environment, ch.to_world
            scene = {"scene": "procedural chest", "chest_seed": chest_seed}
        else:
            from riskplan.collision.frames import (
                BasePose,
                environment_in_base_frame,
                mesh_base_pose,
            )

            # frame from --base-pose, else the mesh's sidecar (riskplan env chest), else a named error
            pose = mesh_base_pose(env, BasePose.parse(base_pose) if base_pose is not None else None)
            env_world = Environment.load(env)
            env_base = environment_in_base_frame(env_world, pose)
            to_world = pose.to_world
            scene = {"scene": str(env), **pose.to_json()}
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
        check_chest_budget(
            mdl.limits,
            n_milestones=milestones,
            step=step,
            resolution=resolution,
            optimiser=cfg,
            executions=executions,
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
            from riskplan.experiments.chest_planning import write_plan

            write_plan(
                out,
                plan,
                model=mdl,
                environment_world=env_world,
                to_world=to_world,
                validation=validation,
                extra={"model": model, **scene},
            )
        res = plan.optimised
        typer.echo(
            f"roadmap: {plan.roadmap.describe()}; trajectory of {len(plan.nominal)} configurations"
        )
        if plan.paths is not None:
            typer.echo(
                f"shortest path bound {plan.paths['shortest']['bound']:.4f}, least-risk path bound {plan.paths['least_risk']['bound']:.4f}"
            )
        typer.echo(
            f"eq. 10 bound: nominal {plan.nominal_bound:.4f} -> optimised {res.bound:.4f} "
            f"({100 * res.reduction:.1f} % lower, {len(res.trace) - 1} iterations, {res.evaluations} bound evaluations)"
        )
        if validation is not None:
            from riskplan.planning.validate import endpoint_warnings, validation_markdown

            typer.echo(validation_markdown(validation))
            for line in endpoint_warnings(validation):
                typer.echo(f"warning: {line}", err=True)
        typer.echo(f"wrote {out}")
