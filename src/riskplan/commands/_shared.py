"""Pieces the commands share: the rich progress bar of long jobs, the Ctrl-C exit, command
groups (``riskplan robot ...``) and the options several commands declare alike
(``--workers``, ``--base-pose``).

Numbers on command lines are read by :mod:`riskplan.parsing` (one convention for every
option); what a command computes comes from the library, the commands only parse, call and
print.

Alike on purpose (``duplicates`` lists them): the typer option declarations of each
command's signature (typer has no option groups; options that several commands declare
with the same default and help are shared objects: here, ``_BATCH_SIZE`` ... in
``kinematics.py``, ``_ROBOT`` in ``robot.py``), and the keyword calls that hand a command's
options to its library function (different functions that take like-named arguments).
"""

from __future__ import annotations

import contextlib

import typer

#: seconds between two plain progress lines of one task (when stdout is not a terminal)
PLAIN_EVERY_S = 10.0


def progress_bar(transient: bool = False, *, plain: bool | None = None):
    """A rich ``Progress`` bar with count, elapsed and remaining time; use as a context manager.

    When stdout is not a terminal (``riskplan reproduce ... > log``), or with ``plain=True``,
    nothing is drawn; plain lines ``HH:MM:SS task: done/total status`` are printed instead,
    when a task starts, at most every :data:`PLAIN_EVERY_S` seconds while it runs, and when it
    reaches its total. At a normal end every bar ends at its total: a task that finished
    before the count it announced (a search that stopped once it found the goal) gets its
    count as total.
    """
    import sys

    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    if plain is None:
        plain = not sys.stdout.isatty()

    class _Progress(Progress):
        def __init__(self, *columns, **kwargs):
            super().__init__(*columns, disable=plain, **kwargs)
            self._printed: dict = {}

        def add_task(self, *args, **kwargs):
            task_id = super().add_task(*args, **kwargs)
            self._line(task_id)
            return task_id

        def update(self, task_id, **kwargs):
            super().update(task_id, **kwargs)
            self._line(task_id)

        def advance(self, task_id, advance: float = 1) -> None:
            super().advance(task_id, advance)
            self._line(task_id)

        def _line(self, task_id) -> None:
            if not plain:
                return
            import time

            task = self._tasks[task_id]
            if not task.visible:
                return
            now = time.monotonic()
            done = task.total is not None and task.completed >= task.total
            key = (task.completed, task.total, done)
            last = self._printed.get(task_id)
            if last is not None and (
                last[1] == key or (not done and now - last[0] < PLAIN_EVERY_S)
            ):
                return
            self._printed[task_id] = (now, key)
            total = "?" if task.total is None else f"{task.total:g}"
            status = task.fields.get("status", "")
            print(
                f"{time.strftime('%H:%M:%S')} {task.description}: {task.completed:g}/{total}"
                + (f" {status}" if status else ""),
                flush=True,
            )

        def __exit__(self, exc_type, exc, tb):
            if exc_type is None:
                for task in list(self._tasks.values()):
                    if task.visible and (task.total is None or task.completed < task.total):
                        self.update(task.id, total=task.completed)
            return super().__exit__(exc_type, exc, tb)

    return _Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[status]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        transient=transient,
    )


@contextlib.contextmanager
def output_folder(out, name: str = "--out"):
    """Write into the folder ``out``, alone: it must not be a file (checked first), and its
    lock (``OUT.lock`` beside it, :func:`riskplan.io.output_lock`) is held while the block
    runs, so a second command writing the same folder stops at once with
    :class:`~riskplan.errors.OutputLockedError` instead of overwriting the first one's files.
    Yields ``out`` (created)."""
    from riskplan.io import check_output_folder, output_lock

    out = check_output_folder(out, name)
    with output_lock(out, "output folder"):
        out.mkdir(parents=True, exist_ok=True)
        yield out


def stop_interrupted(bar, how_to_resume: str):
    """After Ctrl-C: stop ``bar``, say what was kept and how to resume, exit with status 130."""
    bar.stop()
    typer.secho(f"interrupted: {how_to_resume}", fg="yellow", err=True)
    return typer.Exit(130)


def echo_validation(validation) -> None:
    """Print a plan's robot validation (``None``: none was run) as Markdown, and each endpoint
    warning on stderr."""
    if validation is None:
        return
    from riskplan.planning.validate import endpoint_warnings, validation_markdown

    typer.echo(validation_markdown(validation))
    for line in endpoint_warnings(validation):
        typer.echo(f"warning: {line}", err=True)


def add_group(app: typer.Typer, name: str, help: str) -> typer.Typer:
    """A command group ``riskplan NAME ...`` added to ``app`` (``--help`` when called bare)."""
    group = typer.Typer(help=help, no_args_is_help=True)
    app.add_typer(group, name=name)
    return group


def base_pose_option():
    """``--base-pose`` of the commands that read a mesh file (``collision``, ``plan chest``);
    parsed by :meth:`riskplan.robots.BasePose.parse`."""
    return typer.Option(
        None,
        "--base-pose",
        help="Robot base in the mesh's frame: x,y,z,qw,qx,qy,qz (m, quaternion scalar first; "
        "or xyzw:x,y,z,qx,qy,qz,qw in ROS order), a JSON file "
        "with base_position/base_rotation, or 'identity' (mesh already in the base frame). "
        "Overrides the sidecar.",
    )


def workers_option(help: str = "Worker processes (0: one per core).", default: int = 0):
    """The ``--workers`` option of the commands that run a process pool (the library takes
    ``workers or None``: ``None`` is one per core)."""
    return typer.Option(default, "--workers", min=0, help=help)


def configuration_from_options(robot, displacements, tensions, name: str):
    """Tendon displacements ``(m,)`` from a command's ``--NAME`` (displacements, m) or
    ``--NAME-tensions`` (N) option: tensions are converted through the robot model
    (:meth:`~riskplan.robots.TendonRobot.displacements_for_tensions`, checked against
    ``max_tension``). ``None`` when neither is given; both is an error."""
    from riskplan.errors import InvalidInputError
    from riskplan.parsing import parse_numbers

    if displacements is not None and tensions is not None:
        raise InvalidInputError(f"give one of --{name} and --{name}-tensions, not both")
    if displacements is not None:
        return parse_numbers(displacements, f"--{name}", count=robot.n_tendons)
    if tensions is None:
        return None
    tau = parse_numbers(tensions, f"--{name}-tensions", count=robot.n_tendons)
    try:
        robot.check_tensions(tau)
    except InvalidInputError as exc:
        raise InvalidInputError(
            f"--{name}-tensions: {exc} (tension limits [0, max_tension] of robot {robot.name!r}: "
            f"{robot.tension_limits.tolist()} N)"
        ) from None
    return robot.displacements_for_tensions(tau)


def rows_from_tensions(robot, spec: str, name: str = "--tensions"):
    """Configurations ``(N, n_config)`` in displacement form from ``spec``: rows of tensions
    [N] (then rotation [rad] and retraction [m] where the robot has them), ``;`` between rows,
    converted through the robot model (:meth:`TendonRobot.configuration_to_displacements`)."""
    from riskplan.errors import InvalidInputError
    from riskplan.parsing import parse_rows

    if robot is None:
        raise InvalidInputError(f"{name}: converting tensions needs a robot model; give --robot")
    rows = parse_rows(spec, name)
    try:
        return robot.configuration_to_displacements(rows)
    except InvalidInputError as exc:
        raise InvalidInputError(
            f"{name}: {exc} (robot {robot.name!r}: max_tension {robot.tension_limits.tolist()} N)"
        ) from None
