"""Check an HTML report in a real browser (headless Chromium through Selenium).

A report passes when the page loads with no console error, every ``<img>`` has loaded
(``naturalWidth > 0``) and every plotly figure on it, or on the interactive pages it links
to, has rendered (plotly draws an SVG or a WebGL canvas into each ``.js-plotly-plot``).
Chromium and its driver come from Debian (``chromium``, ``chromium-driver``); ``make test``
installs them where it can. Where they are missing, :func:`browser_or_skip` skips the test
and says why.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

# WebGL (plotly's 3-D traces) has no GPU in CI: SwiftShader renders it in software.
CHROMIUM_ARGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-dev-shm-usage",
    "--allow-file-access-from-files",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--window-size=1280,1000",
)
RENDER_TIMEOUT_S = 60.0


@dataclass
class PageCheck:
    """What the browser saw on one page."""

    url: str
    console_errors: list[str] = field(default_factory=list)
    broken_images: list[str] = field(default_factory=list)
    n_images: int = 0
    plots_rendered: list[bool] = field(default_factory=list)
    links: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.console_errors and not self.broken_images and all(self.plots_rendered)


def browser_or_skip():
    """A headless Chromium WebDriver, or ``pytest.skip`` naming what is missing."""
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        pytest.skip("selenium is not installed (pip install 'riskplan[test]')")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_path = shutil.which("chromedriver")
    if chromium is None or driver_path is None:
        pytest.skip(
            "headless Chromium is not available (Debian packages chromium and chromium-driver; "
            "`make test` installs them when it runs as root with apt-get)"
        )
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in CHROMIUM_ARGS:
        opts.add_argument(arg)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    try:
        return webdriver.Chrome(options=opts, service=Service(executable_path=driver_path))
    except Exception as exc:  # the browser exists but cannot start here (no sandbox support, ...)
        pytest.skip(f"headless Chromium did not start: {type(exc).__name__}: {str(exc)[:200]}")


_PLOTS_JS = """
return Array.from(document.querySelectorAll('.js-plotly-plot')).map(
    d => d.querySelectorAll('svg.main-svg, canvas').length > 0 && !!d._fullLayout);
"""
_IMAGES_JS = """
return Array.from(document.images).map(i => [i.getAttribute('src'), i.complete && i.naturalWidth > 0]);
"""
_LINKS_JS = (
    "return Array.from(document.querySelectorAll('a[href]')).map(a => a.getAttribute('href'));"
)


def check_page(driver, path: Path, screenshot: Path | None = None) -> PageCheck:
    """Load ``path`` (a local HTML file), wait for images and plots, and record what failed."""
    url = Path(path).resolve().as_uri()
    driver.get(url)
    deadline = time.monotonic() + RENDER_TIMEOUT_S
    while time.monotonic() < deadline:
        ready = driver.execute_script("return document.readyState") == "complete"
        plots = driver.execute_script(_PLOTS_JS)
        if ready and all(plots):
            break
        time.sleep(0.2)
    check = PageCheck(url=url)
    check.plots_rendered = list(driver.execute_script(_PLOTS_JS))
    images = driver.execute_script(_IMAGES_JS)
    check.n_images = len(images)
    check.broken_images = [src for src, loaded in images if not loaded]
    check.links = list(driver.execute_script(_LINKS_JS))
    check.console_errors = [
        e["message"] for e in driver.get_log("browser") if e.get("level") == "SEVERE"
    ]
    if screenshot is not None:
        driver.save_screenshot(str(screenshot))
    return check


def check_report(driver, report: Path, screenshot: Path | None = None) -> list[PageCheck]:
    """Check ``report`` and every local HTML page it links to (the interactive plotly views)."""
    report = Path(report)
    first = check_page(driver, report, screenshot)
    pages = [first]
    for href in first.links:
        if href.startswith(("#", "http:", "https:")) or not href.endswith(".html"):
            continue
        pages.append(check_page(driver, report.parent / href))
    return pages
