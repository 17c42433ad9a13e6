import functools

import numpy as np
import pytest

from riskplan.errors import InvalidInputError
from riskplan.parallel import map_tasks, spawn_seeds


def _draw(seed: int, n: int = 5) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=n)


def test_spawn_seeds_deterministic_and_distinct():
    a, b = spawn_seeds(7, 50), spawn_seeds(7, 50)
    assert a == b and len(set(a)) == 50
    assert spawn_seeds(8, 50) != a


@pytest.mark.parametrize("backend", ["serial", "local"])
def test_backends_agree(backend):
    seeds = spawn_seeds(3, 23)
    ref = [_draw(s) for s in seeds]
    got = map_tasks(functools.partial(_draw, n=5), seeds, backend=backend, workers=2, chunksize=3)
    for r, g in zip(ref, got):
        np.testing.assert_array_equal(r, g)


@pytest.mark.ray
def test_ray_backend_agrees():
    pytest.importorskip("ray")
    # Ray workers import the task by module: use a library function, not one defined here.
    task = functools.partial(spawn_seeds, n=4)
    seeds = spawn_seeds(3, 9)
    assert map_tasks(task, seeds, backend="ray", workers=2) == [task(s) for s in seeds]


def test_on_result_sees_every_task():
    seen = []
    map_tasks(abs, [-1, -2, -3], backend="serial", on_result=lambda i, r: seen.append((i, r)))
    assert sorted(seen) == [(0, 1), (1, 2), (2, 3)]


def test_bad_backend():
    with pytest.raises(InvalidInputError, match="backend"):
        map_tasks(abs, [1], backend="mpi")


def test_task_exception_propagates():
    with pytest.raises(ZeroDivisionError):
        map_tasks(functools.partial(divmod, 1), [1, 0], backend="local", workers=2, chunksize=1)
