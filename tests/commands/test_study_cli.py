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
