"""The public face: ``import riskplan as rp`` then ``rp.load_robot``, ``rp.plan_tissue``, ...
loaded on first use (PEP 562), so the import stays fast and torch-free; every package's
``__all__`` names what it hands out."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys

import pytest

import riskplan

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


def _run(code: str) -> str:
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=os.environ
    )
    return out.stdout.strip()


def test_import_riskplan_loads_no_layer():
    # a fresh process: only the errors module and the standard library come with the face
    loaded = _run(
        "import sys, riskplan\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in "
        "{'torch', 'scipy', 'numba', 'numpy', 'trimesh'} or m.startswith('riskplan.')))"
    )
    assert loaded == "['riskplan.errors']", loaded


def test_a_face_name_loads_only_its_wing():
    # make_scenario needs the tissue wing, never torch (the kinematic wing's MDN)
    loaded = _run(
        "import sys, riskplan as rp\n"
        "rp.make_scenario\n"
        "print('torch' in sys.modules, 'riskplan.kinematics' in sys.modules)"
    )
    assert loaded == "False False", loaded


@pytest.mark.parametrize("name", sorted(riskplan.PUBLIC))
def test_every_face_name_is_its_home_object(name):
    home = importlib.import_module(riskplan.PUBLIC[name])
    assert getattr(riskplan, name) is getattr(home, name)
    assert name in riskplan.__all__ and name in dir(riskplan)
    if hasattr(home, "__path__"):  # a package hands the name out in its __all__
        assert name in home.__all__, f"{home.__name__}.__all__ lacks {name}"


def test_unknown_names_raise_attribute_error():
    with pytest.raises(AttributeError, match="no_such_name"):
        riskplan.no_such_name  # noqa: B018


@pytest.mark.parametrize("pkg", PACKAGES)
def test_package_all_is_complete(pkg):
    """A package's ``__all__`` names every name in its modules' ``__all__`` that is not
    private to the package (a module's ``__all__`` is what it hands on)."""
    import pkgutil

    mod = importlib.import_module(f"riskplan.{pkg}")
    names = set(getattr(mod, "__all__", ()))
    assert names, f"riskplan.{pkg} has no __all__"
    for n in names:
        assert getattr(mod, n) is not None
    if pkg in {"scenarios", "tissue_planning"}:
        missing = []
        for _, sub, _ in pkgutil.iter_modules(mod.__path__):
            if sub.startswith("_"):
                continue
            sm = importlib.import_module(f"riskplan.{pkg}.{sub}")
            missing += [f"{sub}.{n}" for n in getattr(sm, "__all__", ()) if n not in names]
        assert not missing, f"riskplan.{pkg}.__all__ lacks {missing}"
