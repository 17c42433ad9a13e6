"""`riskplan robot ...` subcommands (heavy imports stay inside the commands).

* ``riskplan robot shape --robot paper --displacements 0.01,0,0,0 [--json] [--plot FILE.png]``
* ``riskplan robot shape --robot FILE.toml --tensions 1,0,0,0``
* ``riskplan robot info --robot paper``
* ``riskplan robot template [--out FILE.toml]``: a commented robot file to start from
* ``--robot`` also reads the Kuntz lab's robot and task files (docs/robots.md)

JSON output (``--json``) is strict JSON: non-finite numbers (an inextensible tendon's
``stiffness_n_per_m = inf``) are written as ``null``, never as ``Infinity`` / ``NaN``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import typer

from riskplan.commands._shared import add_group

_ROBOT = typer.Option(
    "paper", "--robot", help="Packaged robot name ('paper') or a robot TOML file."
)


def _finite_or_none(value):
    """``value`` with every non-finite float (``inf``, ``nan``) replaced by ``None``, recursively."""
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _dumps(value) -> str:
    """Strict JSON text of ``value``: non-finite numbers become ``null`` (see module docs)."""
    return json.dumps(_finite_or_none(value), allow_nan=False)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    sub = add_group(app, "robot", "Tendon-driven continuum robots: shapes and descriptions.")
    _add_shape(sub)
    _add_info(sub)
    _add_template(sub)


def _add_shape(sub: typer.Typer):
    """Add ``shape`` to ``sub``; returns the command function."""

    @sub.command("shape")
    def shape(
        robot: str = _ROBOT,
        displacements: str = typer.Option(
            None,
            "--displacements",
            "-d",
            help="Tendon displacements (m), comma-separated, one per tendon.",
        ),
        tensions: str = typer.Option(
            None, "--tensions", "-t", help="Tendon tensions (N), comma-separated, one per tendon."
        ),
        rotation: float = typer.Option(
            None, "--rotation", help="Base rotation (rad), robots whose file enables it."
        ),
        retraction: float = typer.Option(
            None, "--retraction", help="Base retraction (m), robots whose file enables it."
        ),
        gravity: bool = typer.Option(
            None, "--gravity/--no-gravity", help="Override the robot file's gravity setting."
        ),
        as_json: bool = typer.Option(
            False,
            "--json",
            help="Print {tip, backbone, tensions} as JSON (non-finite numbers as null).",
        ),
        plot: Path = typer.Option(None, "--plot", help="Write a PNG of the backbone and disks."),
    ) -> None:
        """Solve the robot's shape for tendon displacements or tensions."""
        from riskplan.errors import InvalidInputError
        from riskplan.parsing import parse_numbers
        from riskplan.robots import load_robot

        if (displacements is None) == (tensions is None):
            raise InvalidInputError("give exactly one of --displacements and --tensions")
        if plot is not None:
            from riskplan.io import check_output_file

            check_output_file(plot, "--plot")
        r = load_robot(robot)
        if gravity is not None:
            r = r.with_gravity(gravity)
        moved = {}
        if rotation is not None or retraction is not None:
            moved = {"rotation": rotation, "retraction": retraction}
        if displacements is not None:
            d = parse_numbers(displacements, "--displacements", count=r.n_tendons)
            s = r.solve_displacements(d, **moved)
        else:
            s = r.solve_tensions(parse_numbers(tensions, "--tensions", count=r.n_tendons), **moved)
        if as_json:
            typer.echo(_dumps(s.to_json()))
        else:
            x, y, z = s.tip
            typer.echo(f"robot {r.name}: tip = ({x:.6f}, {y:.6f}, {z:.6f}) m")
            typer.echo("tensions [N]: " + ", ".join(f"{v:.4f}" for v in s.tensions))
        if plot is not None:
            import matplotlib

            matplotlib.use("Agg")
            from riskplan.io import atomic_path
            from riskplan.robots.plotting import plot_shape

            fig = plot_shape(s, r, title=f"{r.name}")
            with atomic_path(plot) as tmp:
                fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
            if not as_json:
                typer.echo(f"plot: {plot}")

    return shape


def _add_info(sub: typer.Typer):
    """Add ``info`` to ``sub``; returns the command function."""

    @sub.command("info")
    def info(
        robot: str = _ROBOT,
        as_json: bool = typer.Option(
            False,
            "--json",
            help="Print as JSON; non-finite numbers (e.g. inf stiffness of an inextensible tendon) as null.",
        ),
    ) -> None:
        """Describe a robot: backbone, stiffness, tendons, limits, hysteresis.

        With --json, non-finite numbers are written as null (strict JSON): an inextensible
        tendon's stiffness_n_per_m is null.
        """
        from riskplan.robots import load_robot

        r = load_robot(robot)
        p = r.params
        b = p.backbone
        d = {
            "name": r.name,
            "length_m": b.length,
            "outer_radius_m": b.outer_radius,
            "youngs_modulus_pa": b.youngs_modulus,
            "shear_modulus_pa": b.shear_modulus,
            "bending_stiffness_nm2": float(b.kbt[0]),
            "steps": b.n_steps,
            "disks": p.disks.count,
            "gravity": p.gravity.enabled,
            "collision_radius_m": p.collision_radius,
            "base_rotation": p.base_motion.rotation,
            "base_retraction": p.base_motion.retraction,
            "configuration_limits": r.configuration_limits.tolist(),
            "tendons": [
                {
                    "name": t.name,
                    "theta": list(t.theta),
                    "radius": list(t.radius),
                    "stiffness_n_per_m": t.stiffness,
                    "displacement_limits_m": list(t.displacement_limits),
                    "max_tension_n": t.max_tension,
                }
                for t in p.tendons
            ],
            "hysteresis": {
                "play_m": p.hysteresis.play,
                "play_variation": p.hysteresis.play_variation,
                "offset_std_m": p.hysteresis.offset_std,
            },
        }
        if as_json:
            typer.echo(_dumps(d))
            return
        typer.echo(
            f"robot {d['name']}: length {b.length} m, {d['disks']} disks, EI = {d['bending_stiffness_nm2']:.4g} N m^2, {b.n_steps} steps"
        )
        for t in d["tendons"]:
            typer.echo(
                f"  {t['name']}: theta {t['theta']}, r {t['radius']}, k {t['stiffness_n_per_m']} N/m, "
                f"d in {t['displacement_limits_m']} m, tension <= {t['max_tension_n']} N"
            )
        typer.echo(
            f"  hysteresis: {d['hysteresis']}; gravity {'on' if p.gravity.enabled else 'off'}"
        )
        bm = p.base_motion
        if bm.n_extra:
            typer.echo(
                "  base motion: "
                + ", ".join(
                    f"{k} in [{lo:.4g}, {hi:.4g}] {u}"
                    for k, on, (lo, hi), u in (
                        ("rotation", bm.rotation, bm.rotation_limits, "rad"),
                        ("retraction", bm.retraction, bm.retraction_limits, "m"),
                    )
                    if on
                )
                + f"; configuration = {r.n_tendons} tensions or displacements"
                + (", rotation" if bm.rotation else "")
                + (", retraction" if bm.retraction else "")
            )

    return info


def _add_template(sub: typer.Typer):
    """Add ``template`` to ``sub``; returns the command function."""

    @sub.command("template")
    def template(
        out: Path = typer.Option(
            None, "--out", "-o", help="Write the file here (default: print it)."
        ),
        overwrite: bool = typer.Option(False, help="Replace an existing --out file."),
    ) -> None:
        """Write a commented robot file (riskplan's format, every key with its unit) to start from."""
        from importlib import resources

        text = (
            resources.files("riskplan")
            .joinpath("data", "robot_template.toml")
            .read_text(encoding="utf-8")
        )
        if out is None:
            typer.echo(text, nl=False)
            return
        from riskplan.errors import InvalidInputError
        from riskplan.io import atomic_path, check_output_file

        check_output_file(out, "--out")
        if out.exists() and not overwrite:
            raise InvalidInputError(f"--out: {str(out)!r} exists; pass --overwrite to replace it")
        with atomic_path(out) as tmp:
            Path(tmp).write_text(text, encoding="utf-8")
        typer.echo(f"robot template: {out}")

    return template
