"""The HTML report in a real browser: loads without console errors, every image loaded,
every plotly figure (2-D and WebGL 3-D) rendered, screenshot saved."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.app.report import Report
from tests.browser import browser_or_skip, check_report


@pytest.fixture(scope="module")
def driver():
    d = browser_or_skip()
    yield d
    d.quit()


def _small_report(out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import plotly.graph_objects as go

    rep = Report(out, title="browser check")
    sec = rep.section("figures")
    fig, ax = plt.subplots(figsize=(3, 2))
    ax.plot([0, 1], [0, 1])
    rep.figure(sec, fig, "line", "a line")
    Report.table(sec, ["a", "b"], [[1, 2.5]])
    pts = np.random.default_rng(0).normal(size=(50, 3))
    rep.plotly(
        sec,
        go.Figure(go.Scatter3d(x=pts[:, 0], y=pts[:, 1], z=pts[:, 2], mode="markers")),
        "cloud",
        "cloud",
    )
    rep.plotly(sec, go.Figure(go.Scatter(x=[0, 1], y=[1, 0])), "flat", "flat")
    return rep.write()


def test_report_renders_in_browser(tmp_path, driver):
    path = _small_report(tmp_path)
    shot = tmp_path / "report.png"
    pages = check_report(driver, path, shot)
    assert len(pages) == 3  # the report and its two interactive pages
    for page in pages:
        assert page.ok, page
    assert pages[0].n_images == 1
    assert all(len(p.plots_rendered) == 1 for p in pages[1:])
    assert shot.stat().st_size > 1000


def test_broken_image_and_script_error_are_caught(tmp_path, driver):
    """The checker itself can fail: a missing image and a throwing script are reported."""
    page = tmp_path / "bad.html"
    page.write_text(
        "<html><body><img src='missing.png'><script>undefined_function()</script></body></html>"
    )
    (check,) = check_report(driver, page)
    assert check.broken_images == ["missing.png"]
    assert any("undefined_function" in e for e in check.console_errors)
    assert not check.ok
