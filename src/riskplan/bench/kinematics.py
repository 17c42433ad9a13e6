"""``riskplan bench kinematics``: MDN inference time vs the Cosserat-rod model (MDN paper, section IV).

Figures:

* ``mdn_single_ms`` — one ``MDNModel.predict`` call for one configuration (input
  validation, forward pass, mixture construction), median.
* ``mdn_batched_us_per_config`` — one ``predict`` call for 10,000 configurations, per configuration.
* ``cosserat_single_ms`` — ``robot.solve_displacements`` for one configuration, timed in the same run.
* ``speedup_vs_cosserat`` — ``cosserat_single_ms / mdn_single_ms``.

The network has the default training architecture (K = 5, trunk 64-64, heads 32) with
the robot's tendon count; inference time does not depend on the weight values, so a
freshly initialised network is timed (no training needed for the benchmark).
"""

from __future__ import annotations

import numpy as np

from riskplan.threads import one_torch_thread

N_BATCH = 10_000


def make_bench_model(n_tendons: int, limits: np.ndarray, n_components: int = 5, seed: int = 0):
    import torch

    from riskplan.kinematics.mdn import MDN, MDNModel, Normalisation
    from riskplan.kinematics.training import TrainConfig

    cfg = TrainConfig(n_components=n_components)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = MDN(n_tendons, n_components, 3, cfg.hidden, cfg.head_hidden, cfg.activation)
    mid, half = limits.mean(1), (limits[:, 1] - limits[:, 0]) / 2
    norm = Normalisation(mid, half, np.array([0.0, 0.0, 0.1]), np.array([0.01, 0.01, 0.06]))
    return MDNModel(net, norm, limits, "", "bench")


@one_torch_thread
def run(quick: bool = False) -> dict:
    from riskplan.bench import median_time
    from riskplan.robots import load_robot

    robot = load_robot("paper")
    limits = np.asarray(robot.displacement_limits, dtype=np.float64)
    m = limits.shape[0]
    model = make_bench_model(m, limits)
    rng = np.random.default_rng(0)
    singles = rng.uniform(limits[:, 0], limits[:, 1], size=(64, m))
    # time configurations the robot can realise (tensions within their limits), as a user would
    cand = rng.uniform(limits[:, 0], limits[:, 1], size=(512, m))
    ok = (robot.tensions_for_displacements(cand) <= robot.tension_limits).all(-1)
    if ok.sum() >= 8:
        singles = cand[ok][:64]
    batch = rng.uniform(limits[:, 0], limits[:, 1], size=(N_BATCH, m))
    n_single = len(singles)
    it = iter(range(1 << 62))

    def one():
        model.predict(singles[next(it) % n_single])

    reps = 30 if quick else 300
    single = median_time(one, repeats=reps, warmup=20, inner=10)
    batched = median_time(lambda: model.predict(batch), repeats=3 if quick else 15, warmup=1)
    out = {
        "mdn_single_ms": single * 1e3,
        "mdn_batched_us_per_config": batched / N_BATCH * 1e6,
        "n_components": model.n_components,
        "n_tendons": m,
        "batch_size": N_BATCH,
    }

    def cosserat():
        robot.solve_displacements(singles[next(it) % n_single])

    cs = median_time(cosserat, repeats=10 if quick else 100, warmup=3)
    out["cosserat_single_ms"] = cs * 1e3
    out["speedup_vs_cosserat"] = cs / single
    return out
