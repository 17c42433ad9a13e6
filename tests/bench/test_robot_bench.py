"""The robot benchmark reports the issue's keys and the kernel-only figure (no timing assertions)."""

from __future__ import annotations

import numpy as np
import pytest

from riskplan.bench import robot
from riskplan.errors import InvalidInputError


def test_bench_keys():
    figures = robot.run(quick=True, include_dataset=False, include_first_call=False)
    issue_keys = {
        "tension_single_ms",
        "tension_batched_us_per_config",
        "displacement_single_ms",
        "dataset_small_s",
        "first_call_cold_s",
        "first_call_installed_s",
    }
    cpu_keys = {"first_call_cold_cpu_s", "first_call_installed_cpu_s"}
    extra = {"tension_kernel_single_us", "kernel_cache_complete"} | cpu_keys
    assert set(figures) == issue_keys | extra
    skipped = {"dataset_small_s", "first_call_cold_s", "first_call_installed_s"} | cpu_keys
    skipped.add("kernel_cache_complete")
    assert all(np.isfinite(figures[k]) and figures[k] > 0 for k in figures if k not in skipped)


FIRST_CALL_KEYS = {
    "first_call_cold_s",
    "first_call_cold_cpu_s",
    "first_call_installed_s",
    "first_call_installed_cpu_s",
    "kernel_cache_complete",
}


@pytest.mark.slow
def test_first_call_figures_run_cold_in_the_folder_given(tmp_path):
    """The measurement path itself (two fresh processes; the cold one compiles the robot
    kernels, about 9 s of CPU): its keys and types, and the cold run compiled into the empty
    folder it was given (numba's index files appear there), so it did not read the package's
    cache. No timing is asserted."""
    cache = tmp_path / "numba-cache"
    cache.mkdir()
    figures = robot.first_call_figures(cold_cache_dir=cache)
    assert set(figures) == FIRST_CALL_KEYS
    assert isinstance(figures["kernel_cache_complete"], bool)
    for key in FIRST_CALL_KEYS - {"kernel_cache_complete"}:
        assert isinstance(figures[key], float) and np.isfinite(figures[key]) and figures[key] > 0
    index = [p.name for p in cache.rglob("*.nbi")]
    # one index file per compiled kernel, named after its module: the displacement solve's
    assert any(name.startswith("displacement.") for name in index), index


def test_a_cold_cache_folder_must_be_empty(tmp_path):
    (tmp_path / "stale.nbi").write_bytes(b"")
    with pytest.raises(InvalidInputError, match="cold_cache_dir: expected an empty folder"):
        robot.first_call_figures(cold_cache_dir=tmp_path)
