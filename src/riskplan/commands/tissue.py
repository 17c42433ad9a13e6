"""`riskplan tissue ...`: simulate the deformable-tissue scenarios (heavy imports stay
inside the commands).

The controls file format (``--controls FILE``) is :mod:`riskplan.scenarios.controls`'s; the
step costs ``riskplan tissue step-cost`` prints are :func:`riskplan.bench.tissue.step_costs`.
"""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    from riskplan.commands._shared import add_group

    sub = add_group(
        app, "tissue", "Deformable-tissue scenarios (FEM): simulate, render frames and GIFs."
    )

    @sub.command("step-cost")
    def step_cost(quick: bool = typer.Option(False, "--quick", help="fewer repeats")) -> None:
        """Print the median cost of one needle / manipulation step as JSON."""
        import json

        from riskplan.bench.tissue import step_costs

        typer.echo(json.dumps(step_costs(quick)))

    @sub.command("simulate")
    def simulate(
        scenario: str = typer.Option(
            "needle",
            "--scenario",
            help="needle | manipulation | a scenario file (.toml, docs/scenarios.md)",
        ),
        controls: str = typer.Option(
            "random",
            "--controls",
            help="FILE (CSV, JSON or .npy, one (T, q) row per step; or the selected.npz of "
            "`riskplan plan tissue`) or 'random'",
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

        from riskplan._validation import check_count
        from riskplan.commands._shared import output_folder, progress_bar
        from riskplan.errors import InvalidInputError
        from riskplan.io import check_output_folder, write_json_atomic
        from riskplan.scenarios.base import rollout
        from riskplan.scenarios.controls import read_controls
        from riskplan.scenarios.plotting import save_frames, save_gif
        from riskplan.scenarios.registry import make_scenario

        # a scenario file is read and checked here, before any work
        sim = make_scenario(scenario, case)
        check_count(steps, "--steps", 1, none=True)
        check_count(max_frames, "--max-frames", 1)
        check_count(seed, "--seed", 0)
        check_output_folder(out, "--out")
        params = sim.sample_params(seed)
        if controls == "random":
            n = steps or (30 if sim.name == "needle" else 20)
            from riskplan.budget import check_budget

            # every state of the rollout is kept (for the frames): the mesh displacement,
            # 2 float64 per node, and the step's controls
            nodes = sim.mesh_data(params.n_elements).mesh.n_nodes
            check_budget(
                f"{n} simulator steps (states kept for the frames)",
                "--steps",
                nbytes=float(n) * 8.0 * (2 * nodes + sim.control_dim),
            )
            u = sim.random_controls(n, seed)
        else:
            u = read_controls(controls, sim.control_dim, sim.control_bounds)
            if steps is not None:
                if steps > len(u):
                    raise InvalidInputError(
                        f"--steps: {steps} exceeds the {len(u)} rows of {controls}"
                    )
                u = u[:steps]
        with output_folder(out), progress_bar() as bar:
            task = bar.add_task(f"simulate {sim.name}", total=len(u), status="")

            def on_step(state):
                bar.update(task, advance=1, status=f"goal dist {sim.goal_distance(state):.3f}")

            states = rollout(sim, sim.initial_state(params), u, params, on_step=on_step)
            frames = save_frames(sim, states, out / "frames", max_frames=max_frames)
            gif = save_gif(sim, states, out / f"{sim.name}.gif", max_frames=max_frames)
            collided = [s.t for s in states if sim.in_collision(s)]
            inside = getattr(sim, "inside", None)
            left = next((s.t for s in states if inside is not None and not inside(s)), None)
            # the first failure decides the outcome; states after it are still drawn
            events = [(t, "collision") for t in collided[:1]] + (
                [(left, "left_tissue")] if left is not None else []
            )
            if events:
                t_fail, outcome = min(events)
                reason = f"{'left the tissue' if outcome == 'left_tissue' else 'collision'} at step {t_fail}"
            else:
                outcome = "reached_goal" if sim.in_goal(states[-1]) else "missed_goal"
                reason = None
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
                "left_tissue_step": left,
                "outcome": outcome,
                "reason": reason,
                "gif": gif.name,
                "frames": [p.name for p in frames],
            }
            write_json_atomic(out / "summary.json", summary)
        typer.echo(
            f"{scenario} ({case}): {len(u)} steps, final goal distance {summary['final_goal_distance']:.4f}, "
            f"{'collision at steps ' + str(collided[:5]) if collided else 'no collision'}"
            f"{'; FAILED: ' + reason if reason else ''}; wrote {out / gif.name}"
        )
