"""The API reference (docs/api, Sphinx + numpydoc) builds without a warning, every
cross-reference in it resolves (nitpicky), and it names every
public name and every public module (the checks of BoTorch's ``validate_sphinx.py`` and
python-control's ``test_sphinxdocs.py``)."""

from __future__ import annotations

import importlib
import pkgutil
import re
from pathlib import Path

import pytest

import riskplan
from tests.public_api import documented_at, public_modules, public_names

API = Path(__file__).resolve().parents[1] / "docs" / "api"
PACKAGES = (
    "robots",
    "datasets",
    "kinematics",
    "collision",
    "planning",
    "deformable",
    "scenarios",
    "control",
    "tissue_planning",
)

pytest.importorskip("sphinx")
pytest.importorskip("numpydoc")


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    from sphinx.cmd.build import build_main

    out = tmp_path_factory.mktemp("api")
    # -W: any warning (a docutils error in a docstring, a duplicate object) fails the build;
    # -n (nitpicky, also set in docs/api/conf.py): so does a cross-reference that resolves nowhere
    rc = build_main(["-q", "-n", "-W", "--keep-going", "-E", "-b", "html", str(API), str(out)])
    assert rc == 0, "sphinx-build reported warnings or errors (run `make docs` to see them)"
    return out


def _ids(html_dir: Path) -> set[str]:
    ids = set()
    for page in html_dir.glob("*.html"):
        ids |= set(re.findall(r'<dt class="sig sig-object py" id="([^"]+)"', page.read_text()))
    return ids


def test_every_public_name_is_in_the_reference(built):
    """Every public name (tests/public_api.py: a name in the ``__all__`` of a public module) is
    documented at one of its public paths (its package where the package exports it, else its
    module) or where it is defined."""
    ids = _ids(built)
    missing = [paths[-1] for paths in public_names().values() if not ids & documented_at(paths)]
    assert not missing, f"public names missing from docs/api: {sorted(missing)}"


def test_top_level_modules_name_their_public_names():
    """A top-level module of the shared core says what it hands out (its ``__all__``), so the
    reference and the numpydoc test see it; a module inside a package without ``__all__`` hands
    out only what its package exports."""
    top = [m for m in public_modules() if m.count(".") == 1]
    lacking = [m for m in top if not hasattr(importlib.import_module(m), "__all__")]
    assert not lacking, f"top-level public modules without __all__: {lacking}"


def test_every_package_and_public_module_has_its_page():
    missing = []
    for pkg in PACKAGES:
        page = API / f"{pkg}.rst"
        text = page.read_text(encoding="utf-8") if page.exists() else ""
        mod = importlib.import_module(f"riskplan.{pkg}")
        names = [pkg] + [
            f"{pkg}.{n}" for _, n, _ in pkgutil.iter_modules(mod.__path__) if not n.startswith("_")
        ]
        missing += [n for n in names if f".. automodule:: riskplan.{n}\n" not in text]
    assert not missing, f"docs/api has no automodule for: {missing}"
    top = {p.name for p in Path(riskplan.__file__).parent.iterdir() if p.is_dir()}
    top = {p for p in top if (Path(riskplan.__file__).parent / p / "__init__.py").exists()}
    application = {"app", "bench", "commands"}
    assert top - application == set(PACKAGES), "a new package needs its page in docs/api"
