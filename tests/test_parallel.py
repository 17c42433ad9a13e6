import functools
import os

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


_HELPER = """
import os, time
def sleepy(folder):
    open(os.path.join(folder, f"worker-{os.getpid()}"), "w").close()
    time.sleep(120)
    return os.getpid()
"""

_SCRIPT = """
import os, sys
sys.path.insert(0, sys.argv[1])
from helper import sleepy
from riskplan.parallel import map_tasks
map_tasks(sleepy, [sys.argv[1]] * 4, backend="local", workers=2, chunksize=1)
"""


def _descendants(pid: int) -> set[int]:
    import os

    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat", "rb") as fh:
                    ppid = int(fh.read().rsplit(b")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            children.setdefault(ppid, []).append(int(entry))
    out, todo = set(), [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.add(c)
            todo.append(c)
    return out


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[0] not in (b"Z", b"X")
    except OSError:
        return False


@pytest.mark.skipif(not __import__("os").path.isdir("/proc"), reason="needs /proc (Linux)")
@pytest.mark.parametrize("sig", ["SIGKILL"])  # SIGTERM takes the same path: the parent is gone
def test_killed_parent_leaves_no_process_behind(tmp_path, sig):
    # workers, the forkserver and the resource tracker used to outlive a killed parent for minutes
    import os
    import signal
    import subprocess
    import sys
    import time

    (tmp_path / "helper.py").write_text(_HELPER)
    proc = subprocess.Popen(
        [sys.executable, "-c", _SCRIPT, str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    family: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while len(list(tmp_path.glob("worker-*"))) < 2:
            assert time.monotonic() < deadline and proc.poll() is None, "workers did not start"
            time.sleep(0.1)
        family = _descendants(proc.pid)
        workers = {int(p.name.split("-")[1]) for p in tmp_path.glob("worker-*")}
        assert workers <= family and len(family) >= 3  # forkserver + 2 workers (+ resource tracker)
        os.kill(proc.pid, getattr(signal, sig))
        proc.wait(timeout=30)
        deadline = time.monotonic() + 15
        while any(_alive(p) for p in family) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [p for p in family if _alive(p)]
        assert proc.stdout.read() == b""  # EOF: no process holds the command's pipe any more
    finally:  # whatever happened, leave nothing of ours running
        if proc.poll() is None:
            proc.kill()
        for p in family | _descendants(proc.pid):
            if _alive(p):
                os.kill(p, signal.SIGKILL)


def _pid(_item) -> int:
    import os

    return os.getpid()


def test_task_pool_reuses_its_workers_across_calls():
    """Explicit and implicit calls inside one ``with TaskPool`` block run on the same two
    worker processes (one pool started); results equal the serial ones."""
    from riskplan.parallel import TaskPool, active_pool

    seeds = spawn_seeds(5, 12)
    ref = [_draw(s) for s in seeds]
    with TaskPool("local", workers=2) as pool:
        assert active_pool() is pool
        pids = set(pool.map(_pid, range(8), chunksize=1))
        got = map_tasks(_draw, seeds, backend="local", chunksize=2)  # implicit: no workers given
        pids |= set(map_tasks(_pid, range(8), backend="local", workers=2, chunksize=1))
        assert pool.pools_started == 1
        # a call the pool cannot serve (other worker count) starts its own pool
        other = set(map_tasks(_pid, range(4), backend="local", workers=3, chunksize=1))
        assert pool.pools_started == 1 and not (other & pids)
    assert active_pool() is None
    assert len(pids) <= 2 and os.getpid() not in pids
    for r, g in zip(ref, got):
        np.testing.assert_array_equal(r, g)


def test_task_pool_restarts_after_a_failed_call():
    from riskplan.parallel import TaskPool

    with TaskPool("local", workers=2) as pool:
        before = set(pool.map(_pid, range(4), chunksize=1))
        with pytest.raises(ZeroDivisionError):
            pool.map(functools.partial(divmod, 1), [1, 0, 2], chunksize=1)
        after = set(pool.map(_pid, range(4), chunksize=1))
        assert pool.pools_started == 2 and not (before & after)  # the old workers were ended
    for pid in before | after:  # every worker is gone after the block
        assert not os.path.exists(f"/proc/{pid}") or _is_zombie(pid)
    with pytest.raises(InvalidInputError, match="close"):
        pool.map(abs, [1])


def _burn(seconds: float) -> float:
    """Spin for ``seconds`` of this process's CPU time; the CPU seconds it used."""
    import time

    t0 = time.process_time()
    while time.process_time() - t0 < seconds:
        pass
    return time.process_time() - t0


@pytest.mark.skipif(not os.path.exists("/proc/self/stat"), reason="worker CPU is read from /proc")
def test_task_pool_counts_its_workers_cpu():
    """``workers_cpu_s`` is at least the CPU the tasks measured in the workers (the workers
    also start up) and at most the workers' wall time; the parent's ``RUSAGE_CHILDREN`` (what
    the Fig. 6 timings reported before, 0.0) does not see the forkserver's children."""
    import resource
    import time

    from riskplan.parallel import TaskPool

    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with TaskPool("local", workers=2) as pool:
        task_cpu = sum(pool.map(_burn, [0.2] * 4, chunksize=1))
        assert pool.workers_cpu_s == 0.0  # read when the workers stop
    wall = time.perf_counter() - t0
    assert task_cpu <= pool.workers_cpu_s <= 2 * wall
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    assert (after.ru_utime + after.ru_stime) - (kids.ru_utime + kids.ru_stime) < task_cpu
    assert TaskPool("serial").workers_cpu_s == 0.0  # no workers


def _is_zombie(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[1].split()[0] in (b"Z", b"X")
    except OSError:
        return True


def test_task_pool_bad_input():
    from riskplan.parallel import TaskPool

    with pytest.raises(InvalidInputError, match="backend"):
        TaskPool("mpi")
    with pytest.raises(InvalidInputError, match="workers"):
        TaskPool("local", workers=0)


@pytest.mark.ray
def test_task_pool_on_ray_initialises_once():
    """Ray is started on entering the block (unless already running), serves explicit and
    implicit calls, and is stopped on leaving it only if the pool started it."""
    ray = pytest.importorskip("ray")
    from riskplan.parallel import TaskPool

    task = functools.partial(spawn_seeds, n=4)  # a library function: Ray imports it by module
    seeds = spawn_seeds(3, 6)
    was_running = ray.is_initialized()
    with TaskPool("ray", workers=2) as pool:
        assert ray.is_initialized()
        a = pool.map(task, seeds)
        b = map_tasks(task, seeds, backend="ray")
        assert ray.is_initialized()
    assert ray.is_initialized() == was_running
    assert a == b == [task(s) for s in seeds]


def test_workers_capped_at_the_cores_unless_a_cluster(caplog):
    """``workers=100000`` on a few cores starts at most one process per core (and says so);
    a Ray cluster address is not bounded by this machine."""
    import logging

    from riskplan.parallel import TaskPool, default_workers, effective_workers

    cores = default_workers()
    with caplog.at_level(logging.WARNING, logger="riskplan.parallel"):
        assert effective_workers("local", 100_000) == cores
    assert "100000 requested" in caplog.text
    assert effective_workers("local", 1) == 1
    assert effective_workers("ray", 100_000) == cores  # a local Ray instance on this machine
    assert effective_workers("ray", 100_000, "10.0.0.1:6379") == 100_000
    with TaskPool("local", workers=100_000) as pool:
        assert pool.workers == cores
        assert pool.accepts("local", 100_000, None)  # calls asking for the same run on it
        assert pool.map(abs, [-1, -2, 3]) == [1, 2, 3]


def test_chunk_sizing_is_one_rule():
    """``workers=None`` means one per core in the chunk sizing as in the pools."""
    from riskplan.parallel import chunk_count, chunk_size, default_workers, effective_workers

    cores = default_workers()
    assert chunk_count(100, "serial", 8) == 1
    assert chunk_count(1, "local", 2) == 1
    assert chunk_count(100, "local", None) == 4 * effective_workers("local", None) == 4 * cores
    assert chunk_count(3, "local", None) == min(3, 4 * cores)
    assert chunk_count(100, "local", 1) == 4
    assert chunk_size(100, "local", 1) == min(8, 100 // 4)
    assert chunk_size(0, "local", None) == 1
    assert 1 <= chunk_size(5, "local", None) <= 8
