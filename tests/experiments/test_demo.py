import importlib

from riskplan.experiments.demo import STAGES


def test_every_stage_exists_with_run():
    for name in STAGES:
        mod = importlib.import_module(f"riskplan.experiments.demo_{name}")
        assert callable(mod.run)
