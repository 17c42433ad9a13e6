import matplotlib

matplotlib.use("Agg")

from riskplan.kinematics.data import read_point_clouds
from riskplan.kinematics.plotting import (
    fig_nll_vs_components,
    fig_samples_vs_truth,
    plotly_samples_vs_truth,
)
from riskplan.kinematics.sweep import SweepEntry, SweepResult


def test_figures(trained, synth_paths, tmp_path):
    import matplotlib.pyplot as plt

    res, _ = trained
    test = read_point_clouds(synth_paths[1])
    fig = fig_samples_vs_truth(res.model, test, n_configs=2, n_samples=300, seed=1)
    assert len(fig.axes) == 2
    fig.savefig(tmp_path / "f5.png")
    plt.close(fig)
    pf = plotly_samples_vs_truth(res.model, test, n_configs=2, n_samples=300, seed=1)
    assert len(pf.data) == 4
    entries = [
        SweepEntry(
            k, -k * 1.0, -k * 1.0, [1 / k] * k, [1 / k] * k, [] if k < 3 else [0], 1, 0.1, ""
        )
        for k in (1, 2, 3)
    ]
    fig = fig_nll_vs_components(SweepResult(entries, 2, 0.01, 0.05))
    fig.savefig(tmp_path / "f4.png")
    plt.close(fig)
    assert (tmp_path / "f4.png").stat().st_size > 1000
