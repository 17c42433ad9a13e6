"""``riskplan plan tissue``: simulator RRT candidates, LQG-MP selection and its check against
closed-loop executions for the deformable-tissue scenarios (Patil et al., RSS 2011, section IV)."""

from __future__ import annotations

from pathlib import Path

import typer

from riskplan.commands._shared import progress_bar, workers_option


def register(plan_app: typer.Typer) -> None:
    """Add the ``tissue`` command to the ``riskplan plan`` group."""
    _add_tissue(plan_app)


def _check_choices(case, plans, method, selection) -> None:
    """``--case``, ``--plans``, ``--method`` and ``--selection`` of ``plan tissue``, checked
    before any work."""
    from riskplan.control.lqgmp import METHODS
    from riskplan.errors import InvalidInputError
    from riskplan.scenarios.uncertainty import CASE_NAMES
    from riskplan.tissue_planning.plan import SELECTIONS

    if case not in CASE_NAMES:
        raise InvalidInputError(f"--case: expected one of {', '.join(CASE_NAMES)}, got {case!r}")
    if plans < 1:
        raise InvalidInputError(f"--plans: expected >= 1, got {plans}")
    if method is not None and method not in METHODS:
        raise InvalidInputError(f"--method: expected one of {', '.join(METHODS)}, got {method!r}")
    if selection not in SELECTIONS:
        raise InvalidInputError(
            f"--selection: expected one of {', '.join(SELECTIONS)}, got {selection!r}"
        )


# options of the command below
_TISSUE_SCENARIO = typer.Option(
    "needle",
    "--scenario",
    help="needle | manipulation | a scenario file (.toml, docs/scenarios.md)",
)
_TISSUE_PLANS = typer.Option(100, "--plans", help="number of candidate plans (the paper: 100)")
_TISSUE_CASE = typer.Option(
    "material-high",
    "--case",
    help="nominal | material-low | material-high | actuation | mesh | force",
)
_TISSUE_SEED = typer.Option(0, "--seed", min=0, help="master seed (trees, linearisation, checks)")
_TISSUE_METHOD = typer.Option(
    None,
    "--method",
    help="LQG-MP collision estimate: sigma (paper; conservative) | truncation | "
    "sampling (trajectories of the linear model); default: the --selection's",
)
_TISSUE_SELECTION = typer.Option(
    "calibrated",
    "--selection",
    help="calibrated (default: per scenario the estimator that matched measured success "
    "best, docs/control.md) | material (needle: material frame with the bias state) | "
    "paper (sigma on the world-frame LQG)",
)
_TISSUE_CHECK_RUNS = typer.Option(
    1000, "--check-runs", min=0, help="closed-loop executions per checked plan (0: skip)"
)
_TISSUE_CHECK_OTHERS = typer.Option(
    2, "--check-others", min=0, help="plans checked besides the selected one"
)
_TISSUE_GIF = typer.Option(
    True, "--gif/--no-gif", help="write an animation of one closed-loop execution"
)


def _add_tissue(plan_app: typer.Typer):
    """Add ``tissue`` to ``plan_app``; returns the command function."""

    @plan_app.command("tissue")
    def tissue(
        scenario: str = _TISSUE_SCENARIO,
        plans: int = _TISSUE_PLANS,
        case: str = _TISSUE_CASE,
        out: Path = typer.Option(..., "--out", help="output folder (npz, JSON, PNG, GIF)"),
        workers: int = workers_option("worker processes (0: one per core)"),
        seed: int = _TISSUE_SEED,
        method: str = _TISSUE_METHOD,
        selection: str = _TISSUE_SELECTION,
        check_runs: int = _TISSUE_CHECK_RUNS,
        check_others: int = _TISSUE_CHECK_OTHERS,
        gif: bool = _TISSUE_GIF,
    ) -> None:
        """Plan with the simulator RRT, select with LQG-MP, check the estimate, write OUT/."""
        from rich.console import Console
        from rich.table import Table

        from riskplan.app.outputs.tissue_plan import CALIBRATION_HEADER, summary_rows, write_outputs
        from riskplan.commands._shared import output_folder
        from riskplan.io import check_output_folder
        from riskplan.scenarios.registry import make_scenario
        from riskplan.tissue_planning.plan import check_tissue_budget, plan_tissue
        from riskplan.tissue_planning.rrt import RRTOptions

        _check_choices(case, plans, method, selection)
        # a scenario file is read and checked here, before any work
        sim = make_scenario(scenario, case)
        check_output_folder(out, "--out")
        check_tissue_budget(
            sim,
            n_plans=plans,
            check_runs=check_runs,
            check_others=check_others,
        )
        options = RRTOptions()
        n_trees = -(-plans // options.plans_per_tree)
        console = Console(stderr=True)
        with output_folder(out), progress_bar() as bar:
            t_rrt = bar.add_task("RRT trees", total=n_trees, status="")
            t_sel = bar.add_task("LQG-MP selection", total=plans, status="", start=False)
            found = [0]

            def on_tree(i, tree):
                found[0] += len(tree.plans)
                total = max(n_trees, i + 1)
                bar.update(
                    t_rrt,
                    total=total,
                    completed=min(total, bar.tasks[t_rrt].completed + 1),
                    status=f"{found[0]} plans",
                )

            def on_plan(i, score):
                if not bar.tasks[t_sel].started:
                    bar.start_task(t_sel)
                bar.advance(t_sel)
                bar.update(t_sel, status=f"#{i}: P={score.p_success:.3f}")

            t_chk = bar.add_task(
                "Monte Carlo check",
                total=1 + check_others if check_runs else 0,
                status="",
                visible=bool(check_runs),
            )

            def on_check(row):
                bar.advance(t_chk)

            result = plan_tissue(
                scenario,
                n_plans=plans,
                case=case,
                seed=seed,
                workers=workers or None,
                rrt_options=options,
                method=method,
                selection=selection,
                check_runs=check_runs,
                check_others=check_others,
                on_tree=on_tree,
                on_plan=on_plan,
                on_check=on_check,
            )
            bar.update(t_sel, total=len(result.plans))
            files = write_outputs(result, out, gif=gif, gif_seed=seed)
        sel = result.selection
        best = sel.score(sel.best)
        console.print(
            f"{scenario}, case {case}: {len(result.plans)} candidates in {result.timings['rrt']:.1f} s, "
            f"selection {result.timings['selection']:.1f} s; selected #{sel.best} ({sel.plan.n_steps} steps): "
            f"LQG-MP P(success) = {best.p_success:.3f} (no collision {best.p_collision_free:.3f}, goal {best.p_goal:.3f})"
        )
        if sel.tie_note:
            console.print(sel.tie_note)
        if result.calibration_rows:
            table = Table(title=f"LQG-MP estimate vs {check_runs} closed-loop executions ({case})")
            for h in CALIBRATION_HEADER:
                table.add_column(h, justify="right")
            for row in summary_rows(result):
                table.add_row(*[f"{v:.3f}" if isinstance(v, float) else str(v) for v in row])
            Console().print(table)
        for name, path in files.items():
            typer.echo(f"{name}: {path}")

    return tissue
