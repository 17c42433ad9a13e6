"""Progress a person can follow: plain lines when stdout is not a terminal, and every bar
ends at its total."""

from __future__ import annotations

from riskplan.commands import _shared
from riskplan.commands._shared import progress_bar


def test_plain_lines_when_not_a_terminal(capsys, monkeypatch):
    monkeypatch.setattr(_shared, "PLAIN_EVERY_S", 3600.0)  # only start and end lines
    with progress_bar(plain=True) as bar:
        t = bar.add_task("roadmap", total=4, status="")
        for _ in range(4):
            bar.advance(t)
        hidden = bar.add_task("hidden", total=2, status="", visible=False)
        bar.advance(hidden)
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split(" ", 1)[1] for ln in lines] == ["roadmap: 0/4", "roadmap: 4/4"]


def test_lines_while_running(capsys, monkeypatch):
    monkeypatch.setattr(_shared, "PLAIN_EVERY_S", 0.0)  # every change
    with progress_bar(plain=True) as bar:
        t = bar.add_task("training", total=3, status="")
        bar.update(t, completed=1, status="val 1.2")
        bar.update(t, completed=1, status="val 1.2")  # nothing new: no line
    out = capsys.readouterr().out
    assert "training: 1/3 val 1.2" in out
    assert out.count("training: 1/3") == 1


def test_bars_end_at_their_total(capsys):
    """A search that stops once it settles the goal (269 of 302 milestones) and a task whose
    total was unknown end full, not frozen part-way."""
    with progress_bar(plain=True) as bar:
        a = bar.add_task("risk roadmap", total=302, status="")
        bar.update(a, completed=269)
        b = bar.add_task("validation", total=None, status="")
        bar.update(b, completed=1)
    for task in bar.tasks:
        assert task.total == task.completed
    assert "risk roadmap: 269/269" in capsys.readouterr().out


def test_interrupted_bars_are_left_as_they_were():
    try:
        with progress_bar(plain=True) as bar:
            a = bar.add_task("x", total=5, status="")
            bar.update(a, completed=2)
            raise KeyboardInterrupt
    except KeyboardInterrupt:
        pass
    assert bar.tasks[0].total == 5 and bar.tasks[0].completed == 2
