"""`riskplan study fig6`: the deformable paper's Fig. 6 for one scenario from the CLI."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from riskplan.app.reproduce.deformable import run_one_scenario
from riskplan.cli import app
from riskplan.errors import InvalidInputError

runner = CliRunner()


def test_study_fig6_is_a_cli_command():
    res = runner.invoke(app, ["study", "fig6", "--help"], terminal_width=200)
    assert res.exit_code == 0, res.output
    for option in ("--scale", "--disturbance", "--candidates", "--executions", "--out"):
        assert option in res.output


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"scenario": "chest"}, "scenario"), ({"scenario": "needle", "scale_name": "huge"}, "scale")],
)
def test_run_one_scenario_refuses_bad_names_before_writing(tmp_path, kwargs, field):
    out = tmp_path / "out"
    with pytest.raises(InvalidInputError, match=field):
        run_one_scenario(out=out, **kwargs)
    assert not out.exists()


def test_timings_count_the_workers_cpu(tmp_path):
    """A tiny Fig. 6 run on two local workers: ``cpu_s_workers`` is their CPU time (it read
    0.0 when taken from ``RUSAGE_CHILDREN``, which never sees the forkserver's children),
    positive and at most two workers' wall time."""
    import json
    import os

    if not os.path.exists("/proc/self/stat"):
        pytest.skip("worker CPU is read from /proc")
    out = tmp_path / "fig6"
    run_one_scenario("needle", out, candidates=1, executions=2, workers=2, seed=1)
    t = json.loads((out / "timings_needle.json").read_text())
    assert 0.0 < t["cpu_s_workers"] <= 2 * t["wall_s"]
    assert t["cpu_s_self"] > 0.0
