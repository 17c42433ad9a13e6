"""The kinematics demo stage and benchmark at small scale (figures and keys, not speed)."""

import math

from riskplan.app.demo import kinematics as demo_kinematics
from riskplan.app.report import Report
from tests.conftest import TOL


def test_demo_stage_on_synthetic_data(synth_paths, tmp_path, monkeypatch):
    monkeypatch.setattr(demo_kinematics, "MAIN_EPOCHS", 3)
    monkeypatch.setattr(demo_kinematics, "SWEEP_EPOCHS", 2)
    monkeypatch.setattr(demo_kinematics, "SWEEP_COMPONENTS", (1, 2))
    report = Report(tmp_path)
    ctx = {"out": tmp_path, "train_path": synth_paths[0], "test_path": synth_paths[1]}
    demo_kinematics.run(report, ctx, seed=0, workers=1)
    assert ctx["model"].n_components == demo_kinematics.DEMO_COMPONENTS
    assert (ctx["model_path"] / "model.json").is_file()
    for name in ("kinematics_fig4.png", "kinematics_fig5.png", "kinematics_fig5.html"):
        assert (tmp_path / name).is_file(), name
    assert "HDR coverage" in report.write().read_text()


def test_bench_keys():
    from riskplan.bench.kinematics import run

    out = run(quick=True)
    for key in (
        "mdn_single_ms",
        "mdn_batched_us_per_config",
        "cosserat_single_ms",
        "speedup_vs_cosserat",
    ):
        assert key in out
    assert out["mdn_single_ms"] > 0 and math.isfinite(out["mdn_batched_us_per_config"])
    if out["cosserat_single_ms"] is not None:
        assert math.isclose(
            out["speedup_vs_cosserat"],
            out["cosserat_single_ms"] / out["mdn_single_ms"],
            rel_tol=TOL["float64_exact_rel"]["rtol"],
        )
