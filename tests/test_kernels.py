"""`riskplan warm` compiles every numba kernel into its cache, so no command compiles."""

from __future__ import annotations

import os
import subprocess
import sys

from typer.testing import CliRunner

from riskplan import kernels
from riskplan.cli import app


def test_every_kernel_module_is_listed():
    # a module that defines a kernel but is missing from KERNEL_MODULES would escape `warm`
    src = os.path.dirname(kernels.__file__)
    defining = set()
    for root, _, files in os.walk(src):
        for f in files:
            if f.endswith(".py"):
                path = os.path.join(root, f)
                with open(path, encoding="utf-8") as fh:
                    if "njit" in fh.read():
                        rel = os.path.relpath(path, os.path.dirname(src))[: -len(".py")]
                        defining.add(rel.replace(os.sep, "."))
    defining.discard("riskplan.kernels")
    assert defining == set(kernels.KERNEL_MODULES)


def test_warm_command_leaves_no_kernel_uncached():
    res = CliRunner().invoke(app, ["warm"])
    assert res.exit_code == 0, res.output
    assert "robot" in res.output and "collision" in res.output
    assert kernels.cold() == []


def test_warm_compiles_from_an_empty_cache(tmp_path):
    # in a fresh cache, the planar area alone compiles (and caches) all planar kernels
    code = (
        "from riskplan import kernels; kernels._geometry2d(); "
        "print(','.join(k for k in kernels.cold() if k.startswith('riskplan.geometry2d')))"
    )
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == ""
    assert any(p.suffix == ".nbi" for p in tmp_path.rglob("*"))


def test_warm_in_two_processes_fills_the_cache(tmp_path):
    # the worker processes compile; their cache entries are what a later process loads
    code = (
        "from riskplan import kernels; "
        "t = kernels.warm(workers=2, areas=('geometry2d', 'deformable')); "
        "print(sorted(t)); "
        "print(','.join(k for k in kernels.cold() "
        "if k.startswith(('riskplan.geometry2d', 'riskplan.deformable.nhkernels'))))"
    )
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    lines = out.stdout.strip().splitlines()
    assert lines[0] == "['deformable', 'geometry2d']"
    assert len(lines) == 1 or lines[1] == ""


def test_warm_rejects_unknown_areas_and_workers():
    import pytest

    from riskplan.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="areas"):
        kernels.warm(areas=("nope",))
    with pytest.raises(InvalidInputError, match="workers"):
        kernels.warm(workers=0)
