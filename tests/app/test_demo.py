"""The demo end to end: every stage runs and contributes its figures and tables to one report,
and the report renders in a real browser (headless Chromium; skipped with a reason without it)."""

import importlib
import re

import pytest

from riskplan.app.demo.pipeline import STAGES, run_demo
from tests.browser import browser_or_skip, check_report

# one figure file each stage must write (the report embeds or links it)
STAGE_FILES = {
    "robot": "robot_shapes.png",
    "kinematics": "kinematics_fig4.png",
    "collision": "collision_chest.png",
    "tissue": "tissue_needle.gif",
    "planning": "planning_fig7.png",
    "planning_tissue": "planning_tissue_candidates.png",
}


def test_every_stage_exists_with_run():
    for name in STAGES:
        mod = importlib.import_module(f"riskplan.app.demo.{name}")
        assert callable(mod.run)
    assert set(STAGE_FILES) == set(STAGES)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    seen = []
    path = run_demo(
        out,
        seed=0,
        workers=1,
        progress=lambda done, total, stage, seconds: seen.append((stage, seconds)),
    )
    return path, seen


def test_demo_report_holds_every_stage(demo):
    path, seen = demo
    html = path.read_text(encoding="utf-8")
    assert [s for s, sec in seen if sec is not None] == list(STAGES)  # each stage reported as done
    sections = re.split(r"<h2 id='s\d+'>", html)[1:]
    titles = [s.split("</h2>", 1)[0] for s in sections]
    assert titles[-1] == "Run time"
    for title, body in zip(titles[:-1], sections[:-1]):
        assert "<img" in body or "<table>" in body, f"section {title!r} has no figure or table"
    for stage, name in STAGE_FILES.items():
        assert (path.parent / name).stat().st_size > 1000, f"stage {stage}: {name} missing"
        assert name in html, f"stage {stage}: {name} not shown in the report"
    run_time = sections[-1]
    for stage in STAGES:
        assert f"<td>{stage}</td>" in run_time


def test_demo_report_renders_in_browser(demo):
    path, _ = demo
    driver = browser_or_skip()
    try:
        pages = check_report(driver, path, path.parent / "report.png")
    finally:
        driver.quit()
    assert len(pages) >= 4  # the report and its interactive 3-D pages
    for page in pages:
        assert page.ok, page
    assert pages[0].n_images >= len(STAGES)
