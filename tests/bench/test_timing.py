"""Where a benchmark ran: ``machine_info`` and the ``bench`` command that adds it to every
area's JSON (no timing assertions)."""

from __future__ import annotations

import json
import os
import sys
import types

import pytest
from typer.testing import CliRunner

from riskplan import cli
from riskplan.bench import machine_info
from riskplan.bench._timing import THREAD_ENV_VARS, cpu_model


def test_machine_info_names_cpu_cores_and_threads(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    info = machine_info()
    assert set(info) == {"cpu_model", "cpu_count", "cpus_usable", "threads"}
    assert info["cpu_model"] == cpu_model() and info["cpu_model"]
    assert info["cpu_count"] == os.cpu_count()
    assert 1 <= info["cpus_usable"] <= info["cpu_count"]
    threads = info["threads"]
    assert set(THREAD_ENV_VARS) <= set(threads)
    assert threads["OMP_NUM_THREADS"] == "3" and threads["MKL_NUM_THREADS"] is None
    # numpy's BLAS is loaded in every test process, so at least one pool is reported
    assert threads["pools"] and all(p["num_threads"] >= 1 for p in threads["pools"])
    assert threads["torch"] == sys.modules["torch"].get_num_threads()
    assert json.loads(json.dumps(info)) == info


def test_cpu_model_matches_proc_cpuinfo():
    try:
        text = open("/proc/cpuinfo", encoding="utf-8").read()
    except OSError:
        pytest.skip("no /proc/cpuinfo: cpu_model falls back to platform")
    names = {
        line.split(":", 1)[1].strip() for line in text.splitlines() if line.startswith("model name")
    }
    if not names:
        pytest.skip("/proc/cpuinfo names no model")
    assert cpu_model() in names


def _fake_area(monkeypatch, figures):
    mod = types.ModuleType("riskplan.bench.fake_area")
    mod.run = lambda quick=False: dict(figures)
    monkeypatch.setitem(sys.modules, "riskplan.bench.fake_area", mod)
    monkeypatch.setattr(cli, "BENCH_AREAS", cli.BENCH_AREAS + ("fake-area",))


def test_bench_command_adds_machine_to_every_area(monkeypatch):
    _fake_area(monkeypatch, {"step_ms": 1.5})
    res = CliRunner().invoke(cli.app, ["bench", "fake-area", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["step_ms"] == 1.5
    assert set(out["machine"]) == {"cpu_model", "cpu_count", "cpus_usable", "threads"}
    assert out["machine"]["cpu_count"] == os.cpu_count()


def test_bench_table_lists_machine_rows(monkeypatch):
    _fake_area(monkeypatch, {"step_ms": 1.5})
    res = CliRunner().invoke(cli.app, ["bench", "fake-area"])
    assert res.exit_code == 0, res.output
    assert "machine.cpu_model" in res.output and "machine.threads.OMP_NUM_THREADS" in res.output
