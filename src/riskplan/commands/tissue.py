"""`riskplan tissue ...`: simulate the deformable-tissue scenarios (heavy imports stay
inside the commands).

Controls file format (``--controls FILE``): a ``(T, q)`` table of controls, one step per
row — ``q = 2`` for the needle (``v, phi``), ``q = 6`` for the manipulation scenario
(``F1x, F1y, F2x, F2y, F3x, F3y``):

* ``.csv`` / ``.txt``: comma-separated numbers; lines starting with ``#`` and a first
  line that does not parse as numbers (a header) are skipped;
* ``.json``: a list of rows ``[[v, phi], ...]`` or an object ``{"controls": [[...], ...]}``.
"""

from __future__ import annotations

from pathlib import Path

import typer

SCENARIOS = ("needle", "manipulation")


def read_controls(path, control_dim: int, bounds=None):
    """Read a ``(T, control_dim)`` controls table from CSV/TXT or JSON (see module docstring).

    ``bounds (control_dim, 2)``: when given, every row is checked against them here, before any
    simulation, and the first offending row is named (rows counted from 1).
    """
    import json

    import numpy as np

    from riskplan._validation import as_array
    from riskplan.errors import DataFormatError

    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"controls: no such file {str(path)!r}")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise DataFormatError(f"controls: {path.name} is not UTF-8 text ({exc})") from exc
    if path.suffix.lower() == ".json":
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataFormatError(f"controls: {path.name} is not valid JSON ({exc})") from exc
        if isinstance(obj, dict):
            if "controls" not in obj:
                raise DataFormatError(f"controls: {path.name} has no 'controls' key")
            obj = obj["controls"]
        rows = obj
    else:
        rows = []
        header_seen = False
        for i, line in enumerate(text.splitlines()):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            try:
                rows.append(
                    [float(v) for v in line.replace(";", ",").split(",") if v.strip() != ""]
                )
            except ValueError as exc:
                if not rows and not header_seen:
                    header_seen = True
                    continue  # one header line before the data
                raise DataFormatError(
                    f"controls: {path.name} line {i + 1} is not a row of numbers ({exc})"
                ) from exc
    try:
        arr = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataFormatError(
            f"controls: {path.name} rows have different lengths or non-numbers"
        ) from exc
    if arr.ndim != 2 or arr.shape[0] == 0:
        raise DataFormatError(
            f"controls: expected a non-empty (T, {control_dim}) table, got shape {arr.shape}"
        )
    if arr.shape[1] != control_dim:
        raise DataFormatError(
            f"controls: {path.name} has {arr.shape[1]} columns per row, expected {control_dim}"
        )
    bad_rows = np.flatnonzero(~np.isfinite(arr).all(axis=1))
    if bad_rows.size:
        raise DataFormatError(
            f"controls: {path.name} row {int(bad_rows[0]) + 1} contains NaN or inf"
        )
    if bounds is not None:
        b = np.asarray(bounds, dtype=np.float64)
        out = (arr < b[:, 0]) | (arr > b[:, 1])
        if out.any():
            r, c = (int(i) for i in np.argwhere(out)[0])
            raise DataFormatError(
                f"controls: {path.name} row {r + 1} column {c + 1} is {arr[r, c]:.6g}, outside the bounds "
                f"[{b[c, 0]:.6g}, {b[c, 1]:.6g}]"
            )
    return as_array(arr, "controls", shape=(None, control_dim))


def make_scenario(name: str, case: str):
    """See :func:`riskplan.scenarios.registry.make_scenario`."""
    from riskplan.scenarios.registry import make_scenario as _make

    return _make(name, case)


def step_costs(quick: bool = False) -> dict:
    """Median cost of one scenario step (the planner's unit of work), warm caches.

    Needle: ``step`` at a pose inside the square, and ``step`` + ``in_collision``;
    manipulation: ``step`` from an equilibrium under forces 0.5 to a small force change
    (warm-started Newton), and ``reduced``. Keys name the unit and the element count.
    """
    import numpy as np

    from riskplan.bench._timing import median_time
    from riskplan.scenarios.base import SimParams
    from riskplan.scenarios.manipulation import ManipulationScenario
    from riskplan.scenarios.needle import NeedleScenario

    reps = 200 if quick else 2000
    out = {}
    nd = NeedleScenario()
    for n in (175, 1000):
        p = SimParams(n_elements=n)
        s = nd.initial_state(p, pose=(0.3, 0.45, 0.2))
        u = np.array([0.5, 0.3])
        out[f"needle_step_us_{n}"] = round(
            1e6 * median_time(lambda s=s, u=u, p=p: nd.step(s, u, p), repeats=reps, warmup=20), 1
        )
        out[f"needle_step_and_collision_us_{n}"] = round(
            1e6
            * median_time(
                lambda s=s, u=u, p=p: nd.in_collision(nd.step(s, u, p)), repeats=reps, warmup=20
            ),
            1,
        )
    ms = ManipulationScenario()
    for n in (175, 1000):
        p = SimParams(n_elements=n)
        s = ms.step(ms.initial_state(p), np.full(6, 0.5), p)
        u = np.full(6, 0.5) + 0.05 * np.array([1.0, -1.0, 0.5, 0.2, -0.3, 0.1])
        out[f"manipulation_step_ms_{n}"] = round(
            1e3
            * median_time(
                lambda s=s, u=u, p=p: ms.step(s, u, p), repeats=10 if quick else 40, warmup=2
            ),
            2,
        )
        out[f"manipulation_reduced_us_{n}"] = round(
            1e6 * median_time(lambda s=s: ms.reduced(s), repeats=reps, warmup=10), 1
        )
    return out


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    sub = typer.Typer(
        help="Deformable-tissue scenarios (FEM): simulate, render frames and GIFs.",
        no_args_is_help=True,
    )
    app.add_typer(sub, name="tissue")

    @sub.command("step-cost")
    def step_cost(quick: bool = typer.Option(False, "--quick", help="fewer repeats")) -> None:
        """Print the median cost of one needle / manipulation step as JSON."""
        import json

        typer.echo(json.dumps(step_costs(quick)))

    @sub.command("simulate")
    def simulate(
        scenario: str = typer.Option("needle", "--scenario", help="needle | manipulation"),
        controls: str = typer.Option(
            "random", "--controls", help="FILE (CSV or JSON, one (T, q) row per step) or 'random'"
        ),
        out: Path = typer.Option(
            ..., "--out", help="output folder for frames, GIF and summary.json"
        ),
        case: str = typer.Option(
            "nominal",
            "--case",
            help="nominal | material-low | material-high | actuation | mesh | force",
        ),
        steps: int = typer.Option(
            None,
            "--steps",
            help="steps to run (default: all rows of FILE, or 30 needle / 20 manipulation)",
        ),
        seed: int = typer.Option(
            0, "--seed", help="seed of the parameter draw and of random controls"
        ),
        max_frames: int = typer.Option(
            40, "--max-frames", help="at most this many PNG frames / GIF frames"
        ),
    ) -> None:
        """Run one simulation and write PNG frames, an animated GIF and summary.json."""
        import numpy as np

        from riskplan.commands._progress import progress_bar
        from riskplan.errors import InvalidInputError
        from riskplan.io import write_json_atomic
        from riskplan.scenarios.plotting import save_frames, save_gif

        sim = make_scenario(scenario, case)
        if steps is not None and steps < 1:
            raise InvalidInputError(f"steps: expected >= 1, got {steps}")
        if max_frames < 1:
            raise InvalidInputError(f"--max-frames: expected >= 1, got {max_frames}")
        if seed < 0:
            raise InvalidInputError(f"--seed: expected a non-negative integer, got {seed}")
        if out.exists() and not out.is_dir():
            raise InvalidInputError(f"--out: {out} is an existing file; expected a folder")
        params = sim.sample_params(seed)
        if controls == "random":
            n = steps or (30 if scenario == "needle" else 20)
            u = sim.random_controls(n, seed)
        else:
            u = read_controls(controls, sim.control_dim, sim.control_bounds)
            if steps is not None:
                if steps > len(u):
                    raise InvalidInputError(
                        f"steps: {steps} exceeds the {len(u)} rows of {controls}"
                    )
                u = u[:steps]
        out.mkdir(parents=True, exist_ok=True)
        states = [sim.initial_state(params)]
        with progress_bar() as bar:
            task = bar.add_task(f"simulate {scenario}", total=len(u), status="")
            for k in range(len(u)):
                states.append(sim.step(states[-1], u[k], params))
                bar.update(task, advance=1, status=f"goal dist {sim.goal_distance(states[-1]):.3f}")
            frames = save_frames(sim, states, out / "frames", max_frames=max_frames)
            gif = save_gif(sim, states, out / f"{scenario}.gif", max_frames=max_frames)
        collided = [s.t for s in states if sim.in_collision(s)]
        summary = {
            "scenario": scenario,
            "case": case,
            "seed": seed,
            "steps": len(u),
            "params": {
                "youngs_modulus": params.youngs_modulus,
                "poissons_ratio": params.poissons_ratio,
                "n_elements": params.n_elements,
                "force_scale": params.force_scale,
                "actuation_cov": params.actuation_cov,
            },
            "mesh_elements": int(sim.mesh_data(params.n_elements).mesh.n_elements),
            "final_reduced_state": np.asarray(sim.reduced(states[-1])).tolist(),
            "final_goal_distance": sim.goal_distance(states[-1]),
            "reached_goal": bool(sim.in_goal(states[-1])),
            "collision_steps": collided,
            "gif": gif.name,
            "frames": [p.name for p in frames],
        }
        write_json_atomic(out / "summary.json", summary)
        typer.echo(
            f"{scenario} ({case}): {len(u)} steps, final goal distance {summary['final_goal_distance']:.4f}, "
            f"{'collision at steps ' + str(collided[:5]) if collided else 'no collision'}; wrote {out / gif.name}"
        )
