"""``riskplan reproduce`` at a smoke-of-smoke size: the deformable Fig. 6 evaluation is
resumable (an interrupted run continues to the same numbers), independent of the backend,
refuses corrupted or foreign stores with the file named, its claims are computed as stated,
and its report renders in a real browser. Bad input fails fast with typed errors."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from riskplan.app.reproduce.deformable import ScenarioScale, claims, run_scenario
from riskplan.app.store import ResultStore
from riskplan.errors import BackendUnavailableError, DataFormatError, InvalidInputError
from tests.conftest import approx_tol
from tests.test_parallel_ray_cluster import ray_head  # noqa: F401  (fixture: a Ray head on 127.0.0.1)

#: One candidate per set, two executions per method, one case: every stage runs once.
TINY = ScenarioScale(
    n_candidates=1, n_executions=4, batch_size=2, lin_samples=2, goal_samples=50, plans_per_tree=1
)
CASES = ("material-high",)
CONFIG = {"test": "tiny", "seed": 3}


class Interrupt(Exception):
    pass


def _run(root, backend="serial", progress=None, workers=None):
    store = ResultStore(root, CONFIG)
    return run_scenario(
        "needle",
        TINY,
        store,
        seed=3,
        backend=backend,
        workers=workers,
        progress=progress,
        cases=CASES,
    )


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    root = tmp_path_factory.mktemp("ref")
    return root, _run(root)


def test_reference_run_is_consistent(reference):
    _, r = reference
    case = r["cases"]["material-high"]
    for m, v in case.items():
        assert v["n"] == TINY.n_executions
        assert 0 <= v["successes"] <= v["n"]
        assert v["low"] <= v["rate"] <= v["high"]
        # every failure is classified exactly once
        failures = v["collided"] + v["missed_goal"] + v["solver_failed"] + v["left_tissue"]
        assert failures == v["n"] - v["successes"]
        assert (v["predicted"] is None) == (m in ("rrt", "rrt_margins"))
    # RRT with deformations runs the plain RRT's first plan; its margins reading and ours
    # without selection execute the same plan (candidate 0 of the deforming set)
    assert case["rrt"]["candidate_set"] == "plain" and case["rrt"]["candidate"] == 0
    assert case["rrt_margins"]["candidate"] == case["ours_no_select"]["candidate"] == 0
    assert case["rrt_margins"]["candidate_set"] == case["ours_no_select"]["candidate_set"]
    assert case["ours_no_select"]["candidate_set"] == "deforming"
    assert case["lqgmp_only"]["candidate_set"] == "static"
    assert set(r["selection"]["material-high"]) == {"deforming", "static"}
    # the mechanism pairs the same plan open and closed loop, run by run
    mech = r["mechanism"]["material-high"]
    assert mech["open"] == case["rrt_margins"]["successes"]
    assert mech["closed"] == case["ours_no_select"]["successes"]
    assert mech["both"] + mech["neither"] + mech["only_open"] + mech["only_closed"] == mech["n"]
    # "ours" is the LQG-MP argmax over the deforming candidates
    ps = [s["p_success"] for s in r["selection"]["material-high"]["deforming"]]
    assert case["ours"]["candidate"] == int(np.argmax(ps))
    assert case["ours"]["predicted"] == max(ps)


def test_interrupted_run_resumes_to_identical_results(reference, tmp_path):
    _, ref = reference
    seen = []

    def stop_after_first_batch(stage, done, total):
        if stage.endswith("executions") and done > 0:
            seen.append(done)
            raise Interrupt

    with pytest.raises(Interrupt):
        _run(tmp_path, progress=stop_after_first_batch)
    store = ResultStore(tmp_path, CONFIG)
    n_exec = sum(k.startswith("fig6.needle.exec.") for k in store.keys())
    assert n_exec == 1  # one batch finished and was stored before the interruption
    calls = []
    resumed = _run(tmp_path, progress=lambda s, d, n: calls.append((s, d, n)))
    assert json.dumps(resumed, sort_keys=True) == json.dumps(ref, sort_keys=True)
    # the rerun started its executions from the stored batch, not from zero
    first_exec = next(c for c in calls if c[0].endswith("executions"))
    assert first_exec[1] == TINY.batch_size


def test_local_pool_gives_bit_identical_results(reference, tmp_path):
    """Executions (closed loop with the stored controllers, open loop) on a process pool equal the
    serial run bit for bit. Plans and controllers are reused from the serial store (the RRT and
    linearisation tests cover their own backend independence): one pool start."""
    import shutil

    src, ref = reference
    root = tmp_path / "local"
    shutil.copytree(src, root)
    for rec in (root / "records").glob("*.json"):
        if ".exec." in rec.name:
            rec.unlink()
    local = _run(root, backend="local", workers=2)
    assert json.dumps(local, sort_keys=True) == json.dumps(ref, sort_keys=True)


def test_corrupted_record_is_named(reference, tmp_path):
    import shutil

    src, _ref = reference
    root = tmp_path / "copy"
    shutil.copytree(src, root)
    rec = sorted((root / "records").glob("fig6.needle.exec.*.json"))[0]
    obj = json.loads(rec.read_text())
    obj["payload"][0][0] = 1 - obj["payload"][0][0]  # flip one execution's outcome
    rec.write_text(json.dumps(obj))
    with pytest.raises(DataFormatError, match=rec.name):
        _run(root)
    # a truncated pickled plan is refused too, naming the file
    root2 = tmp_path / "copy2"
    shutil.copytree(src, root2)
    blob = root2 / "blobs" / "fig6.needle.plans.deforming.pkl"
    blob.write_bytes(blob.read_bytes()[:-10])
    with pytest.raises(DataFormatError, match=r"fig6.needle.plans.deforming.pkl"):
        _run(root2)


def test_store_of_another_configuration_is_refused(reference):
    src, _ = reference
    with pytest.raises(DataFormatError, match="another run configuration"):
        ResultStore(src, {**CONFIG, "seed": 4})


def test_claims_both_readings():
    def v(rate):
        return {"rate": rate, "low": rate - 0.05, "high": rate + 0.05}

    cases = {
        "a": {"rrt": v(0.4), "lqgmp_only": v(0.3), "ours_no_select": v(0.6), "ours": v(0.8)},
        "b": {"rrt": v(0.2), "lqgmp_only": None, "ours_no_select": v(0.4), "ours": v(0.3)},
    }
    c = claims(cases)
    assert c["ours_highest"] == {"a": True, "b": False}
    assert c["ours_tied"] == {"a": False, "b": False}
    assert c["ours_separated"] == {"a": True, "b": False}
    # averages: rrt 0.3, without selection 0.5, ours 0.55
    assert c["no_select_vs_rrt"]["points"] == pytest.approx(20.0, **approx_tol("float64_exact"))
    assert c["no_select_vs_rrt"]["relative"] == pytest.approx(
        100 * (0.5 / 0.3 - 1), **approx_tol("float64_exact")
    )
    assert c["no_select_vs_ours"]["points"] == pytest.approx(-5.0, **approx_tol("float64_exact"))
    assert c["no_select_vs_ours"]["relative"] == pytest.approx(
        100 * (0.5 / 0.55 - 1), **approx_tol("float64_exact")
    )


def test_ties_are_not_highest():
    """All three methods at the same rate: a tie, not "ours highest" (the smoke report once
    said "yes" for three manipulation methods tied at 36.7 %)."""
    from riskplan.app.reproduce.deformable import highest_verdict

    def v(rate):
        return {"rate": rate, "low": rate - 0.1, "high": rate + 0.1}

    tie = {"rrt": v(11 / 30), "lqgmp_only": None, "ours_no_select": v(11 / 30), "ours": v(11 / 30)}
    up = {"rrt": v(0.2), "lqgmp_only": None, "ours_no_select": v(0.3), "ours": v(0.4)}
    down = {"rrt": v(0.5), "lqgmp_only": None, "ours_no_select": v(0.3), "ours": v(0.4)}
    c = claims({"mesh": tie, "force": up})
    assert c["ours_highest"] == {"mesh": False, "force": True}
    assert c["ours_tied"] == {"mesh": True, "force": False}
    assert not c["ours_highest_all"]
    assert highest_verdict(c) == "no (tied for highest in mesh)"
    c = claims({"mesh": tie, "force": down})
    assert highest_verdict(c) == "no (tied for highest in mesh; below another method in force)"
    assert highest_verdict(claims({"force": up})) == "yes"


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(paper="both"), InvalidInputError, "paper"),
        (dict(scale="huge"), InvalidInputError, "scale"),
        (dict(backend="dask"), InvalidInputError, "backend"),
        (dict(backend="local", ray_address="127.0.0.1:1"), InvalidInputError, "address"),
        (dict(workers=0), InvalidInputError, "workers"),
    ],
)
def test_bad_arguments(tmp_path, kwargs, error, match):
    from riskplan.app.reproduce.pipeline import reproduce

    with pytest.raises(error, match=match):
        reproduce(tmp_path / "out", **kwargs)
    assert not (tmp_path / "out").exists()  # nothing written before the arguments are checked


def test_unreachable_ray_address_fails_within_seconds(tmp_path):
    import socket

    from riskplan.app.reproduce.pipeline import reproduce

    with socket.socket() as s:  # a loopback port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.monotonic()
    with pytest.raises(BackendUnavailableError, match=f"127.0.0.1:{port}"):
        reproduce(tmp_path / "out", backend="ray", ray_address=f"127.0.0.1:{port}")
    assert time.monotonic() - t0 < 30  # a hang would take minutes; this bounds it, not measures it


def test_cli_rejects_unknown_paper(tmp_path):
    from typer.testing import CliRunner

    from riskplan.cli import app

    res = CliRunner().invoke(app, ["reproduce", "--paper", "nope", "--out", str(tmp_path / "o")])
    assert res.exit_code != 0
    assert isinstance(res.exception, InvalidInputError) and "paper" in str(res.exception)


def test_report_renders_in_browser(reference, tmp_path):
    from riskplan.app.reproduce.report import write_report
    from tests.browser import browser_or_skip, check_report

    src, r = reference
    store = ResultStore(src, CONFIG)
    results = {
        "config": {"paper": "deformable", "scale": "tiny", "seed": 3},
        "deformable": {"needle": r},
    }
    path = write_report(
        tmp_path, results, store, {"backend": "serial", "deformable_needle_s": 1.0}, seed=3
    )
    text = path.read_text()
    assert "Fig. 6" in text and "LQG-MP predicted" in text and "+34" in text
    driver = browser_or_skip()
    try:
        pages = check_report(driver, path, tmp_path / "shot.png")
    finally:
        driver.quit()
    assert len(pages) == 2  # the report and the interactive Fig. 6 page
    for page in pages:
        assert page.ok, page
    assert pages[0].n_images >= 2  # Fig. 6 and the single executions (Fig. 5 for material-high)
    assert len(pages[1].plots_rendered) == 1


@pytest.mark.ray
def test_ray_cluster_gives_bit_identical_results(reference, ray_head, tmp_path):  # noqa: F811 (fixture)
    """The execution batches on a Ray head started on the loopback address (the fixture of
    tests/test_parallel_ray_cluster.py) equal the serial run bit for bit."""
    import shutil

    import ray

    src, ref = reference
    root = tmp_path / "ray"
    shutil.copytree(src, root)
    for rec in (root / "records").glob("*.json"):
        if ".exec." in rec.name:
            rec.unlink()
    try:
        got = run_scenario(
            "needle",
            TINY,
            ResultStore(root, CONFIG),
            seed=3,
            backend="ray",
            ray_address=ray_head,
            cases=CASES,
        )
    finally:
        ray.shutdown()
    assert json.dumps(got, sort_keys=True) == json.dumps(ref, sort_keys=True)


def test_execute_methods_equals_execute_batch(reference):
    """Several methods on the same draws in one task equal one batch per method bit for
    bit (execute_methods builds a draw's model once for all of them)."""
    from riskplan.app.reproduce.deformable import BlobStore, execute_batch, execute_methods
    from riskplan.parallel import spawn_seeds
    from riskplan.scenarios.registry import make_scenario

    src, _ = reference
    blobs = BlobStore(ResultStore(src, CONFIG))
    plans = blobs.get("fig6.needle.plans.deforming")
    ctrl = blobs.get("fig6.needle.select.material-high.deforming.000")["controller"]
    sim = make_scenario("needle", "material-high")
    seeds = spawn_seeds(11, 6)
    runs = [(plans[0], None), (plans[0], ctrl)]
    joint = execute_methods((make_scenario("needle", "material-high"), runs, seeds))
    for (plan, c), rows in zip(runs, joint):
        assert rows == execute_batch((sim, plan, c, seeds))


def test_disturbance_variant_is_stored_apart(reference, tmp_path):
    """``disturbance=True`` reuses the candidates, stores its selection and executions under
    ``fig6d.`` and executes the disturbance-state controller."""
    import shutil

    from riskplan.app.reproduce.deformable import BlobStore

    src, ref = reference
    root = tmp_path / "d"
    shutil.copytree(src, root)
    store = ResultStore(root, CONFIG)
    got = run_scenario("needle", TINY, store, seed=3, cases=CASES, disturbance=True)
    assert got["disturbance"] is True and ref["disturbance"] is False
    assert got["plan_steps"] == ref["plan_steps"]
    keys = set(store.keys())
    assert any(k.startswith("fig6d.needle.exec.") for k in keys)
    sel = BlobStore(store).get("fig6d.needle.select.material-high.deforming.000")
    assert sel["controller"] is None or sel["controller"].disturbance
    assert sel["controller"] is not None or sel["error"]


def test_a_material_that_inverts_the_tissue_is_a_solver_failure_with_its_reason():
    """Bad input during an execution (issue 18, "Everywhere"): parameters that make the
    tissue invert or the solver diverge count as solver failures with the solver's reason,
    never as collisions or successes, in the rows Fig. 6 stores and in its counts. Here a
    huge force on a tiny patch (tests/scenarios/test_manipulation.py) from the first step."""
    from riskplan.app.reproduce.deformable import _outcome_counts, execute_methods
    from riskplan.control import NominalPlan
    from riskplan.scenarios.base import SimParams
    from riskplan.scenarios.manipulation import ManipulationConfig, ManipulationScenario

    base = SimParams(n_elements=60)

    class Nominal:  # draws the planning parameters (the failure comes from the forces)
        planning_params = base

        def sample(self, gen):
            gen.random()
            return base

    sim = ManipulationScenario(
        ManipulationConfig(f_max=1e4, df_max=1e4, patch_radius=0.03), distribution=Nominal()
    )
    u = np.array([[-1e4, 0.0, 0.0, 0.0, 0.0, -1e4]])
    plan = NominalPlan(
        controls=u,
        reduced=np.zeros((2, sim.state_dim)),
        states=(sim.initial_state(base), sim.initial_state(base)),
        params=base,
    )
    (rows,) = execute_methods((sim, [(plan, None)], [1, 2, 3]))
    flags, reasons = _outcome_counts(rows)
    assert flags[:, 3].tolist() == [1, 1, 1]  # solver failed
    assert flags[:, 0].sum() == flags[:, 1].sum() == 0  # neither success nor collision
    assert sum(reasons.values()) == 3
    assert all("manipulation step t=0" in k for k in reasons), reasons
