"""`riskplan` subcommands for the collision area (heavy imports stay inside the commands).

* ``riskplan env chest --out chest.stl [--seed N] [--view chest.png] [--html chest.html]``
* ``riskplan collision probability --env chest|FILE [--model M | --arc K,PHI] --displacements d1,d2,...``
* ``riskplan collision table --out docs-table.md`` (bound vs Monte Carlo in the chest)
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

from riskplan.commands._shared import add_group, base_pose_option


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    env_app = add_group(app, "env", "Build obstacle environments (meshes) for planning.")
    _add_env_chest(env_app)
    _add_env_from_segmentation(env_app)
    collision_app = add_group(
        app, "collision", "P(collision) of the robot's predicted geometry: bound and table."
    )
    _add_collision(collision_app)
    collision_table = _add_collision_table(collision_app)
    app.command("collision-table", hidden=True)(collision_table)


def _add_env_chest(env_app: typer.Typer):
    """Add ``chest`` to ``env_app``; returns the command function."""

    @env_app.command("chest")
    def env_chest(
        out: Path = typer.Option(
            Path("chest.stl"), "--out", "-o", help="Mesh file to write (.stl, .obj, .ply)."
        ),
        seed: int = typer.Option(0, min=0, help="Seed of the organ shape variation."),
        subdivisions: int = typer.Option(
            3, help="Icosphere subdivisions of the organ/wall meshes (3: ~12k triangles)."
        ),
        view: Path = typer.Option(None, "--view", help="Write a PNG view (exterior and interior)."),
        html: Path = typer.Option(None, "--html", help="Write an interactive plotly HTML view."),
    ) -> None:
        """Build the procedural chest cavity (MDN paper Fig. 6) and write it as one mesh file.

        The mesh is in the world frame; a JSON sidecar OUT.json records the frame, the robot base
        pose, the seed, the parameters and the insertion point, so `riskplan collision probability --env OUT`
        gives the same answer as the built-in chest.
        """
        from riskplan.collision.mesh_files import sidecar_path
        from riskplan.errors import InvalidInputError
        from riskplan.io import check_output_file, output_lock
        from riskplan.planning.chest_scene import build_chest, chest_figure, chest_plotly

        if out.suffix.lower() not in (".stl", ".obj", ".ply", ".off"):
            raise InvalidInputError(
                f"--out: {out.name}: expected a mesh file ending in .stl, .obj, .ply or .off"
            )
        for name, p in (("--out", out), ("--view", view), ("--html", html)):
            if p is not None:
                check_output_file(p, name)

        with output_lock(out, "mesh file"):  # one writer: the mesh and its sidecar agree
            chest = build_chest(seed, subdivisions=subdivisions)
            chest.save(out)
        meta = sidecar_path(out)
        typer.echo(
            f"chest: {chest.n_triangles} triangles, {chest.environment.n_obstacles} obstacles -> {out} (+ {meta.name})"
        )
        if view is not None:
            import matplotlib

            matplotlib.use("Agg")
            fig = chest_figure(chest)
            fig.savefig(view, dpi=110, bbox_inches="tight")
            typer.echo(f"view: {view}")
        if html is not None:
            chest_plotly(chest).write_html(html, include_plotlyjs="cdn")
            typer.echo(f"html: {html}")

    return env_chest


def _add_env_from_segmentation(env_app: typer.Typer):
    """Add ``from-segmentation`` to ``env_app``; returns the command function."""

    @env_app.command("from-segmentation")
    def env_from_segmentation(
        volume: Path = typer.Argument(
            ..., help="Label map: .nrrd, .nhdr, .nii, .nii.gz, .mha or .mhd."
        ),
        label: int = typer.Option(..., "--label", help="The label to mesh."),
        out: Path = typer.Option(
            None, "--out", "-o", help="Mesh file to write (default VOLUME-labelN.stl)."
        ),
        faces: int = typer.Option(
            5000, "--faces", min=0, help="Triangles after decimation (0: no decimation)."
        ),
        scale: float = typer.Option(
            1.0,
            "--scale",
            help="Physical units of the volume to metres (0.001 for millimetres).",
        ),
        robot: str = typer.Option(
            "paper", help="Robot name or file whose length judges the mesh's units."
        ),
        base_pose: str = typer.Option(
            None,
            "--base-pose",
            help="Robot base in the volume's physical frame (as for `collision --base-pose`), or "
            "'identity'; without it the sidecar leaves the pose to the planner's --base-pose.",
        ),
    ) -> None:
        """Surface mesh of one label of a segmentation volume, in the volume's physical frame.

        Marching cubes (scikit-image) on the label's mask, vertices mapped by the volume's
        spacing, origin and direction (SimpleITK, LPS), decimated (MeshLab quadric collapse, topology kept) to
        FACES triangles; a JSON sidecar OUT.json records the source, label, frame and base pose.
        """
        from riskplan.collision.mesh_files import BasePose, sidecar_path
        from riskplan.collision.segmentation import (
            save_segmentation_environment,
            segmentation_mesh,
        )
        from riskplan.errors import InvalidInputError
        from riskplan.io import check_output_file
        from riskplan.robots import load_robot

        if out is None:
            stem = volume.name.split(".")[0]
            out = volume.with_name(f"{stem}-label{label}.stl")
        if out.suffix.lower() not in (".stl", ".obj", ".ply", ".off"):
            raise InvalidInputError(
                f"--out: {out.name}: expected a mesh file ending in .stl, .obj, .ply or .off"
            )
        check_output_file(out, "--out")
        pose = None
        if base_pose is not None:
            pose = (
                "identity" if base_pose.strip().lower() == "identity" else BasePose.parse(base_pose)
            )
        length = load_robot(robot).params.backbone.length
        V, F, info = segmentation_mesh(
            volume, label, faces=faces or None, scale=scale, robot_length=length
        )
        save_segmentation_environment(V, F, out, info=info, base_pose=pose)
        typer.echo(
            f"label {label}: {info['marching_cubes_triangles']} -> {info['triangles']} triangles, "
            f"volume {info['marching_cubes_volume_m3']:.4g} -> {info['volume_m3']:.4g} m^3 "
            f"-> {out} (+ {sidecar_path(out).name})"
        )

    return env_from_segmentation


def _probability_environment(env, base_pose, seed, model, robot):
    """The obstacles of ``collision probability`` in the robot's base frame: the procedural
    chest (``env == "chest"``) or a mesh file, its units judged against the robot checked."""
    from riskplan.errors import InvalidInputError

    if env == "chest":
        if base_pose is not None:
            raise InvalidInputError(
                "--base-pose applies to mesh files; the procedural chest has its own base frame"
            )
        from riskplan.planning.chest_scene import build_chest

        return build_chest(seed).base_environment
    from riskplan.collision.mesh_files import BasePose, load_environment

    # the mesh's units are judged against the robot whose geometry is checked: the
    # model's robot, else --robot (also for --arc, whose scale the robot sets)
    judge = None
    if model is not None:
        from riskplan.kinematics import load_model as _load_model

        judge = _load_model(model).robot
    if judge is None:
        from riskplan.robots import load_robot as _load_robot

        judge = _load_robot(robot)
    return load_environment(
        env,
        base_pose=None if base_pose is None else BasePose.parse(base_pose),
        robot_length=judge.params.backbone.length,
        source=f"--env {env}",
    )


# options of the command below
_COLLISION_ENV = typer.Option(
    "chest",
    "--env",
    help="'chest' (procedural) or a mesh file; its frame comes from the sidecar FILE.json that `riskplan env chest` writes, or from --base-pose.",
)
_COLLISION_DISPLACEMENTS = typer.Option(
    None,
    "--displacements",
    "-d",
    help="Tendon displacements (m), comma-separated; ';' separates configurations.",
)
_COLLISION_TENSIONS = typer.Option(
    None,
    "--tensions",
    help="Or tendon tensions (N), like --displacements; converted through the model's "
    "robot (with --model) or --robot.",
)
_COLLISION_MODEL = typer.Option(
    None,
    "--model",
    help="Trained MDN model folder (riskplan model train) or a shipped name ('paper'). Default: robot backbone mixture.",
)
_COLLISION_ARC = typer.Option(
    None,
    "--arc",
    help="Constant-curvature geometry instead of a robot: 'kappa,phi' (1/m, rad).",
)
_COLLISION_ROBOT = typer.Option(
    "paper", "--robot", help="Robot name or TOML file for the backbone fallback."
)
_COLLISION_METHOD = typer.Option(
    "bound",
    help="bound (eq. 9) | union | monte_carlo | monte_carlo_union; the Monte Carlo "
    "reference column estimates the same event (any of K points, one per component, "
    "for the union methods).",
)
_COLLISION_SAMPLES = typer.Option(
    20000, min=1, help="Monte Carlo samples (also used for the reference interval)."
)


def _add_collision(collision_app: typer.Typer):
    """Add ``probability`` to ``collision_app``; returns the command function."""

    @collision_app.command("probability")
    def collision(
        env: str = _COLLISION_ENV,
        base_pose: str = base_pose_option(),
        displacements: str = _COLLISION_DISPLACEMENTS,
        tensions: str = _COLLISION_TENSIONS,
        model: Path = _COLLISION_MODEL,
        arc: str = _COLLISION_ARC,
        robot: str = _COLLISION_ROBOT,
        method: str = _COLLISION_METHOD,
        samples: int = _COLLISION_SAMPLES,
        seed: int = typer.Option(0, min=0, help="Seed (chest shape and Monte Carlo)."),
        json_out: bool = typer.Option(False, "--json", help="Print JSON."),
    ) -> None:
        """P(collision) of the robot's geometry distribution at given configurations."""
        from riskplan.collision import monte_carlo_probability, probability_of_collision
        from riskplan.errors import InvalidInputError
        from riskplan.parsing import parse_numbers, parse_rows

        if displacements is not None and tensions is not None:
            raise InvalidInputError("give one of --displacements and --tensions, not both")
        if arc is not None and (
            displacements is not None or tensions is not None or model is not None
        ):
            raise InvalidInputError(
                "--arc describes the geometry itself; give either --arc or --displacements (with --model), not both"
            )
        if arc is not None:
            from riskplan.kinematics.robot_mixture import arc_backbone, backbone_mixture

            ka = parse_numbers(arc, "--arc", count=2)
            gm = backbone_mixture(arc_backbone(ka[0], ka[1])[None], 5)
            configs = [ka]
        else:
            if displacements is None and tensions is None:
                raise InvalidInputError("--displacements (or --tensions, or --arc) is required")
            if tensions is not None:
                from riskplan.commands._shared import rows_from_tensions
                from riskplan.robots import load_robot as _load_robot

                if model is not None:
                    from riskplan.kinematics import load_model as _load_model

                    conv = _load_model(model).robot
                else:
                    conv = _load_robot(robot)
                d = rows_from_tensions(conv, tensions)
            else:
                d = parse_rows(displacements, "--displacements")
            configs = d.tolist()
            if model is not None:
                from riskplan.kinematics import load_model

                gm = load_model(model).predict(d)
            else:
                from riskplan.kinematics.robot_mixture import robot_mixture
                from riskplan.robots import load_robot

                gm = robot_mixture(load_robot(robot), d)
        environment = _probability_environment(env, base_pose, seed, model, robot)
        p = probability_of_collision(gm, environment, method, n_samples=samples, seed=seed)
        # the reference estimates the event the chosen method bounds: any point of the
        # mixture (eq. 9) or any of K points, one per component (the union variant)
        combine = "union" if method.endswith("union") else "weighted"
        mc = monte_carlo_probability(gm, environment, samples, combine=combine, seed=seed)
        rows = [
            {
                "config": c,
                "probability": float(p[i]),
                "method": method,
                "monte_carlo": float(mc.probability[i]),
                "mc_low": float(mc.low[i]),
                "mc_high": float(mc.high[i]),
            }
            for i, c in enumerate(configs)
        ]
        if json_out:
            typer.echo(json.dumps(rows))
            return
        from rich.console import Console
        from rich.table import Table

        table = Table(title=f"P(collision), {environment}")
        for col in ("config", method, "Monte Carlo", "95% interval"):
            table.add_column(col)
        for r in rows:
            table.add_row(
                str(r["config"]),
                f"{r['probability']:.4g}",
                f"{r['monte_carlo']:.4g}",
                f"[{r['mc_low']:.4g}, {r['mc_high']:.4g}]",
            )
        Console().print(table)

    return collision


def _add_collision_table(collision_app: typer.Typer):
    """Add ``table`` to ``collision_app``; returns the command function."""

    @collision_app.command("table")
    def collision_table(
        out: Path = typer.Option(
            None, "--out", "-o", help="Write the markdown table here (default: print)."
        ),
        samples: int = typer.Option(100_000, min=1, help="Monte Carlo samples per configuration."),
        seed: int = typer.Option(0, min=0, help="Seed of the chest and of the sampling."),
        model: Path = typer.Option(
            None,
            "--model",
            help="Trained MDN model folder or shipped name ('paper'); default: robot backbone (or arc) mixtures.",
        ),
    ) -> None:
        """Bound vs Monte Carlo (95 % intervals) for a set of robot configurations in the chest."""
        from riskplan.app.outputs.collision_table import collision_table as make_table
        from riskplan.app.outputs.collision_table import to_markdown

        rows, meta = make_table(seed=seed, n_samples=samples, model_path=model)
        text = to_markdown(rows, meta)
        if out is None:
            typer.echo(text)
        else:
            from riskplan.io import write_text_atomic

            write_text_atomic(out, text)
            typer.echo(f"table: {out}")

    return collision_table
