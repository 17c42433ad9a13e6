"""The Ray backend against a real Ray head that this test starts on the loopback address
(``ray start --head``), then stops: the same seed gives the same results as serial, and an
address where nothing listens fails within seconds with a named error."""

from __future__ import annotations

import functools
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from riskplan.errors import BackendUnavailableError, InvalidInputError
from riskplan.parallel import RAY_CONNECT_TIMEOUT_S, map_tasks, parse_ray_address, spawn_seeds


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ray_head(tmp_path_factory):
    pytest.importorskip("ray")
    ray_bin = Path(sys.executable).with_name("ray")
    if not ray_bin.exists() and shutil.which("ray") is None:
        pytest.skip("the `ray` command is not installed")
    port = _free_port()
    env = {**os.environ, "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_AUTH_MODE": "disabled"}
    cmd = [
        str(ray_bin if ray_bin.exists() else shutil.which("ray")),
        "start",
        "--head",
        "--block",
        "--node-ip-address=127.0.0.1",
        f"--port={port}",
        "--num-cpus=2",
        "--include-dashboard=false",
        "--disable-usage-stats",
        f"--temp-dir={tmp_path_factory.mktemp('ray')}",
    ]
    proc = subprocess.Popen(
        cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, start_new_session=True
    )
    deadline = time.monotonic() + 120
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            break
        except OSError:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.kill()
                pytest.skip("could not start a local Ray head")
            time.sleep(0.5)
    yield f"127.0.0.1:{port}"
    proc.terminate()  # `ray start --block` stops the head's processes when terminated
    try:
        proc.wait(60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)


@pytest.mark.ray
def test_ray_cluster_same_results_as_serial(ray_head):
    import ray

    task = functools.partial(spawn_seeds, n=4)
    seeds = spawn_seeds(11, 7)
    try:
        got = map_tasks(task, seeds, backend="ray", ray_address=ray_head)
    finally:
        ray.shutdown()
    assert got == map_tasks(task, seeds, backend="serial")


@pytest.mark.ray
def test_unreachable_address_fails_fast():
    pytest.importorskip("ray")
    port = _free_port()  # nothing listens there
    t0 = time.monotonic()
    with pytest.raises(BackendUnavailableError, match=f"127.0.0.1:{port}"):
        map_tasks(abs, [1, 2], backend="ray", ray_address=f"127.0.0.1:{port}")
    assert time.monotonic() - t0 < 10 * RAY_CONNECT_TIMEOUT_S  # fails, does not hang for minutes


@pytest.mark.parametrize("address", ["", "nohost", "host:", "host:99999", "ray://:80", 5])
def test_bad_addresses_are_named(address):
    with pytest.raises(InvalidInputError, match="ray_address"):
        parse_ray_address(address)


def test_addresses_parse():
    assert parse_ray_address("auto") is None
    assert parse_ray_address("10.0.0.5:6379") == ("10.0.0.5", 6379)
    assert parse_ray_address("ray://head.example:10001") == ("head.example", 10001)
    assert parse_ray_address("[::1]:6379") == ("::1", 6379)
