"""``riskplan.threads``: BLAS pools are lowered inside the block and restored after."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from riskplan.threads import blas_pools, blas_threads, one_blas_thread


def _counts():
    return [p.get_num_threads() for p in blas_pools()]


def test_blas_pools_cover_numpy_and_scipy():
    assert len(blas_pools()) >= 1
    assert all(p.user_api == "blas" for p in blas_pools())


@pytest.mark.parametrize("outer", [1, 2])
def test_blas_threads_limits_and_restores(outer):
    with threadpool_limits(outer, user_api="blas"):
        before = _counts()
        assert all(n == outer for n in before)
        with blas_threads(1):
            assert all(n == 1 for n in _counts())
        assert _counts() == before


def test_blas_threads_restores_after_an_error():
    with threadpool_limits(2, user_api="blas"):
        with pytest.raises(RuntimeError), blas_threads(1):
            raise RuntimeError("inside")
        assert all(n == 2 for n in _counts())


def test_one_blas_thread_decorator_runs_limited_and_returns():
    seen = []

    @one_blas_thread
    def work(x):
        seen.append(_counts())
        return np.linalg.cholesky(x)

    with threadpool_limits(2, user_api="blas"):
        L = work(np.eye(3) * 4.0)
        assert all(n == 2 for n in _counts())
    assert all(n == 1 for n in seen[0])
    np.testing.assert_array_equal(L, np.eye(3) * 2.0)


def _record_counts(monkeypatch, name):
    import scipy.linalg

    seen = []
    real = getattr(scipy.linalg, name)

    def spy(*args, **kwargs):
        seen.append(_counts())
        return real(*args, **kwargs)

    monkeypatch.setattr(scipy.linalg, name, spy)
    return seen


def test_fem_factorisations_run_on_one_blas_thread(monkeypatch):
    from riskplan.deformable import (
        LinearElasticModel,
        Material,
        NeoHookeanModel,
        mesh_polygon,
        rectangle,
    )

    mesh = mesh_polygon(rectangle(), 60)
    dense = _record_counts(monkeypatch, "cho_factor")
    banded = _record_counts(monkeypatch, "cholesky_banded")
    with threadpool_limits(2, user_api="blas"):
        LinearElasticModel(mesh, Material(50.0, 0.4), mesh.vertex_nodes)
        model = NeoHookeanModel(mesh, Material(50.0, 0.4), mesh.vertex_nodes)
        # the array path (the compiled one factorises narrow bands in numba, without BLAS)
        model.compiled = False
        f = np.zeros((mesh.n_nodes, 2))
        f[:, 1] = 0.05
        model.solve(f)
        assert all(n == 2 for n in _counts())
    assert dense and banded
    assert all(n == 1 for counts in dense + banded for n in counts)


def test_torch_threads_limits_and_restores_after_an_error():
    torch = pytest.importorskip("torch")
    from riskplan.threads import one_torch_thread, torch_threads

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with pytest.raises(RuntimeError), torch_threads(1):
            assert torch.get_num_threads() == 1
            raise RuntimeError("inside")
        assert torch.get_num_threads() == 2
        assert one_torch_thread(torch.get_num_threads)() == 1
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_library_code_never_sets_process_threads():
    """Thread policy has one home: only ``threads.py`` calls ``set_num_threads``; entry
    points (cli, worker start-up) go through ``threads.limit_process_threads``."""
    import ast
    from pathlib import Path

    import riskplan

    root = Path(riskplan.__file__).parent
    offenders = []
    for path in root.rglob("*.py"):
        if path.name == "threads.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr in (
                "set_num_threads",
                "set_num_interop_threads",
            ):
                offenders.append(f"{path.relative_to(root)}:{node.lineno}")
    assert offenders == []
