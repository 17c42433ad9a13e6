"""Does a collision risk computed from the learned model predict the robot's collision rate?
(beyond the MDN paper; ``riskplan reproduce --paper mdn --stage robot-risk``, or
``riskplan plan chest-risk-study``, the same study into a folder of its own.)

Eq. 9/10 measure the mixture's mass inside obstacles. This study puts that number and the
body-contact cloud risk (:mod:`riskplan.collision.body_risk`, for several coherences ``ρ``)
beside the collision rate measured on the simulated robot (:func:`~riskplan.planning.validate.execute_on_robot`,
body of backbone and disks) for configurations and trajectories in the procedural chest:

* configurations: seeded uniform draws within the displacement and tension limits whose MDN
  component means are free (the planner's validity), stratified by their nominal body clearance
  (:func:`~riskplan.planning.chest.body_clearance`): two thirds with ``|clearance| < band`` (near
  contact, where the rate is between 0 and 1), one third from the rest, in draw order;
* trajectories: straight ramps of ``steps`` configurations from zero displacement to end
  configurations stratified the same way (other draws than the configurations');
* each executed ``executions`` times on the robot (seeds ``spawn_seeds``), its rate with a
  95 % Wilson interval;
* metrics per risk: mean absolute error on the items whose measured rate is in [5 %, 95 %],
  on all items, and the Brier score over all executions,
  ``mean_i [r_i (1 - p_i)^2 + (1 - r_i) p_i^2]``; a binned calibration figure.

Every piece is a record of a :class:`~riskplan.app.store.ResultStore` (chunks of robot
executions, one record per risk), so an interrupted study continues where it stopped.

The ``robot-risk`` stage of ``riskplan reproduce`` (:mod:`riskplan.app.reproduce.robot_risk`)
runs this study and puts its summary into ``results.json`` and the report.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from riskplan._validation import check_count
from riskplan.errors import InvalidInputError

log = logging.getLogger(__name__)

__all__ = [
    "RISK_STUDY_SCALES",
    "RiskStudyScale",
    "calibration_metrics",
    "cross_fitted_logistic",
    "run_risk_study",
    "transmission_mechanism",
]

CHUNK = 10


@dataclass(frozen=True)
class RiskStudyScale:
    """Sizes of the study (module docstring)."""

    configurations: int = 200
    trajectories: int = 30
    executions: int = 200
    steps: int = 8
    coherences: tuple = (0.5,)
    n_clouds: int = 128
    draws: int = 256
    extents: tuple = (2.0,)
    n_points: int = 512
    pool: int = 4000
    band: float = 0.002

    def __post_init__(self):
        for name in (
            "configurations",
            "trajectories",
            "executions",
            "steps",
            "n_clouds",
            "pool",
            "draws",
        ):
            check_count(getattr(self, name), name, 1, integral=True)
        if not all(0.0 <= float(c) <= 1.0 for c in self.coherences) or not self.coherences:
            raise InvalidInputError(f"coherences: expected values in [0, 1], got {self.coherences}")
        object.__setattr__(self, "coherences", tuple(float(c) for c in self.coherences))
        if not self.extents or not all(float(c) > 0 for c in self.extents):
            raise InvalidInputError(f"extents: expected values > 0, got {self.extents}")
        object.__setattr__(self, "extents", tuple(float(c) for c in self.extents))


RISK_STUDY_SCALES = {
    "smoke": RiskStudyScale(
        configurations=9,
        trajectories=3,
        executions=40,
        steps=4,
        coherences=(0.5,),
        n_clouds=32,
        pool=600,
        draws=32,
    ),
    "reduced": RiskStudyScale(
        configurations=60, trajectories=12, coherences=(0.0, 0.15, 0.5, 0.9, 1.0)
    ),
    "full": RiskStudyScale(),
}


def _spearman(p, r):
    """Spearman's rank correlation (ties by average rank); ``None`` when undefined (fewer than
    three items or a constant side)."""
    import warnings

    from scipy.stats import spearmanr

    if len(p) < 3 or np.ptp(p) == 0 or np.ptp(r) == 0:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rho = float(spearmanr(p, r).statistic)
    return rho if np.isfinite(rho) else None


def calibration_metrics(predicted, measured, *, low: float = 0.05, high: float = 0.95) -> dict:
    """MAE on the items measured in ``[low, high]``, MAE on all, the execution-level Brier
    score and Spearman's rank correlation on the ``[low, high]`` items (``None``: undefined)."""
    p = np.asarray(predicted, dtype=np.float64)
    r = np.asarray(measured, dtype=np.float64)
    mid = (r >= low) & (r <= high)
    return {
        "mae_mid": float(np.abs(p - r)[mid].mean()) if mid.any() else None,
        "n_mid": int(mid.sum()),
        "mae_all": float(np.abs(p - r).mean()),
        "brier": float(np.mean(r * (1 - p) ** 2 + (1 - r) * p**2)),
        "n": len(r),
        "spearman_mid": _spearman(p[mid], r[mid]),
    }


#: folds of the cross-fitted logistic map (each item is predicted by the fit on the others)
FOLDS = 2


def _logistic_fit(gaps, k, n):
    """Maximum-likelihood ``(a, b)`` of ``p_i = mean_s σ(a - b g_is)`` (``g`` in mm, ``b > 0``)
    for ``k_i`` collisions in ``n`` executions; ``(a, b)``."""
    from scipy.optimize import minimize
    from scipy.special import expit

    g = np.where(np.isfinite(gaps), gaps, 1.0) * 1e3  # mm; a body-free sample is far away

    def nll(theta):
        p = expit(theta[0] - np.exp(theta[1]) * g).mean(axis=1)
        p = np.clip(p, 1e-12, 1 - 1e-12)
        return -float(np.sum(k * np.log(p) + (n - k) * np.log1p(-p)))

    res = minimize(
        nll,
        np.array([0.0, 0.0]),
        method="Nelder-Mead",
        options={"xatol": 1e-6, "fatol": 1e-9, "maxiter": 4000},
    )
    return float(res.x[0]), float(np.exp(res.x[1]))


def cross_fitted_logistic(gaps, measured, executions, groups, *, seed: int = 0, folds: int = FOLDS):
    r"""Held-out predictions of a logistic map of the sampled bodies' clearances.

    The risk of item ``i`` is :math:`p_i = \frac1S \sum_s \sigma(a - b\, g_{is})`, ``g_is``
    the clearance of sampled execution ``s`` (:meth:`~riskplan.planning.risk.SampledBodyRisk.gaps`,
    in mm; the smallest along a trajectory). ``a`` (an offset of the learned body's
    geometry, ``a / b`` mm) and ``b`` (how sharply a clearance decides, per mm) are fitted
    by maximum likelihood on the binomial counts of the training items; the items are split
    into ``folds`` folds by a seeded permutation within each group (``groups``: configurations
    and trajectories), and every item is predicted by the fit on the other folds, so no
    item's own execution counts enter its prediction.

    Parameters
    ----------
    gaps : array_like
        ``(N, S)`` clearances [m] (``inf``: no body component).
    measured : array_like
        ``(N,)`` collision rates on the robot.
    executions : int
        Executions behind each rate.
    groups : array_like
        ``(N,)`` labels split separately (e.g. True for trajectories).

    Returns
    -------
    held_out : numpy.ndarray
        ``(N,)`` predictions, each from the fit that did not see the item.
    fits : list of dict
        Per fold ``{"a", "b", "n_train"}``.
    """
    from scipy.special import expit

    G = np.asarray(gaps, dtype=np.float64)
    r = np.asarray(measured, dtype=np.float64)
    k = np.round(r * executions)
    groups = np.asarray(groups)
    rng = np.random.default_rng(seed)
    fold = np.empty(len(r), dtype=int)
    for lab in np.unique(groups):
        idx = np.nonzero(groups == lab)[0]
        fold[idx[rng.permutation(len(idx))]] = np.arange(len(idx)) % folds
    held_out = np.empty(len(r))
    fits = []
    g_mm = np.where(np.isfinite(G), G, 1.0) * 1e3
    for f in range(folds):
        train = fold != f
        a, b = _logistic_fit(G[train], k[train], executions)
        held_out[~train] = expit(a - b * g_mm[~train]).mean(axis=1)
        fits.append({"a": a, "b": b, "n_train": int(train.sum())})
    return held_out, fits


def _select(robot, model, env, n, pool, band, rng):
    """``n`` configurations: two thirds near contact, one third from the rest (draw order)."""
    from riskplan.planning.chest import body_clearance
    from riskplan.planning.prm import MeanValidity

    lim = np.asarray(robot.displacement_limits, dtype=np.float64)
    q = lim[:, 0] + rng.random((int(pool), len(lim))) * (lim[:, 1] - lim[:, 0])
    q = q[(robot.tensions_for_displacements(q, validate=False) <= robot.tension_limits).all(-1)]
    q = q[MeanValidity(model, env)(q)]
    _, c = body_clearance(robot, q, env)
    near, far = np.nonzero(np.abs(c) < band)[0], np.nonzero(np.abs(c) >= band)[0]
    k = min(len(near), int(np.ceil(2 * n / 3)))
    idx = np.r_[near[:k], far[: n - k]]
    if len(idx) < n:
        raise InvalidInputError(f"pool: {pool} draws give only {len(idx)} configurations")
    return q[idx], c[idx]


def _robot_rates(
    store, key, robot, env, trajectories, executions, seed, progress, label, backend, workers
):
    from riskplan.parallel import spawn_seeds
    from riskplan.planning.validate import execute_on_robot

    seeds = spawn_seeds(seed, len(trajectories))
    out = []
    for k in range(0, len(trajectories), CHUNK):

        def compute(k=k):
            # the executions of one item run as chunks on the pool (``backend``); the rates do
            # not depend on it (execute_on_robot's seeding)
            return [
                execute_on_robot(
                    robot,
                    trajectories[i],
                    env,
                    executions,
                    int(seeds[i]),
                    body="disks",
                    backend=backend,
                    workers=workers,
                ).trajectory.probability.item()
                for i in range(k, min(k + CHUNK, len(trajectories)))
            ]

        out += store.get_or_compute(f"{key}.{k // CHUNK}", compute)
        progress(label, min(k + CHUNK, len(trajectories)), len(trajectories))
    return np.asarray(out)


def _logistic_risks(risks, store, model, env, Q, trajs, measured, scale, seed, report) -> dict:
    """Add the held-out logistic map of the sampled bodies' clearances (one per extent) to
    ``risks``; the clearances are a record per extent (``risk.gaps.<c>``). Returns the fits."""
    from riskplan.planning.risk import SampledBodyRisk

    fits = {}
    is_traj = np.r_[np.zeros(len(Q), bool), np.ones(len(trajs), bool)]
    for c in scale.extents:

        def compute(c=c):
            risk = SampledBodyRisk(model, env, n_draws=scale.draws, extent=c, seed=seed)
            return {
                "configurations": [risk.gaps(x[None])[:, 0].tolist() for x in Q],
                "trajectories": [risk.gaps(t).min(axis=1).tolist() for t in trajs],
            }

        g = store.get_or_compute(f"risk.gaps.{c:g}", compute)
        gaps = np.r_[np.asarray(g["configurations"]), np.asarray(g["trajectories"])]
        held_out, fits[f"logistic c={c:g}"] = cross_fitted_logistic(
            gaps, measured, scale.executions, is_traj, seed=seed
        )
        risks[f"logistic c={c:g}"] = (held_out[: len(Q)].tolist(), held_out[len(Q) :].tolist())
        report(
            "robot risk: clearance distributions", scale.extents.index(c) + 1, len(scale.extents)
        )
    return fits


def run_risk_study(
    out,
    scale: RiskStudyScale,
    store,
    *,
    seed: int = 0,
    progress=None,
    backend: str = "serial",
    workers: int | None = None,
) -> dict:
    """Run (or continue) the study; writes ``out/risk_calibration.{png,json}``, returns the JSON.

    ``backend``, ``workers``: where the robot executions run (:mod:`riskplan.parallel`; inside
    a :class:`~riskplan.parallel.TaskPool` of that backend, on its workers); the results do not
    depend on them.
    """
    from riskplan.collision import mixture_bound, trajectory_bound
    from riskplan.collision.body_risk import cloud_risk
    from riskplan.gaussian_mixture import as_numpy_mixture
    from riskplan.io import write_json_atomic
    from riskplan.kinematics import load_model
    from riskplan.planning.chest_scene import build_chest
    from riskplan.planning.risk import SampledBodyRisk
    from riskplan.robots import load_robot

    report = progress or (lambda stage, done, total: None)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    robot, model = load_robot("paper"), load_model("paper")
    env = build_chest(0).base_environment
    sel = store.get("risk.selection")
    if sel is None:
        rng = np.random.default_rng(seed)
        q, c = _select(robot, model, env, scale.configurations, scale.pool, scale.band, rng)
        e, ce = _select(robot, model, env, scale.trajectories, scale.pool, scale.band, rng)
        sel = {"configurations": q.tolist(), "clearance": c.tolist(), "ends": e.tolist()}
        sel["end_clearance"] = ce.tolist()
        store.put("risk.selection", sel)
    from riskplan.parallel import spawn_seeds

    s_conf, s_traj = spawn_seeds(seed, 2)
    Q = np.asarray(sel["configurations"])
    ends = np.asarray(sel["ends"])
    trajs = [np.linspace(np.zeros(len(x)), x, scale.steps) for x in ends]
    r_conf = _robot_rates(
        store, "risk.robot.conf", robot, env, [x[None] for x in Q], scale.executions, s_conf,
        report, "robot risk: robot executions, configurations", backend, workers,
    )  # fmt: skip
    r_traj = _robot_rates(
        store, "risk.robot.traj", robot, env, trajs, scale.executions, s_traj,
        report, "robot risk: robot executions, trajectories", backend, workers,
    )  # fmt: skip
    risks = {}
    gm = as_numpy_mixture(model.predict(Q))
    risks["eq9 / eq10"] = (
        mixture_bound(gm, env).tolist(),
        [float(trajectory_bound(as_numpy_mixture(model.predict(t)), env)) for t in trajs],
    )
    for rho in scale.coherences:

        def compute(rho=rho):
            conf = [
                cloud_risk(
                    model.predict(x[None]), env, n_points=scale.n_points,
                    n_clouds=scale.n_clouds, coherence=rho, seed=seed,
                ).per_configuration[0].item()
                for x in Q
            ]  # fmt: skip
            traj = [
                cloud_risk(
                    model.predict(t), env, n_points=scale.n_points, n_clouds=scale.n_clouds,
                    coherence=rho, seed=seed,
                ).trajectory
                for t in trajs
            ]  # fmt: skip
            return [conf, traj]

        risks[f"cloud ρ={rho:g}"] = tuple(store.get_or_compute(f"risk.cloud.{rho:g}", compute))
        report("robot risk: cloud risks", scale.coherences.index(rho) + 1, len(scale.coherences))
    for c in scale.extents:

        def compute(c=c):
            risk = SampledBodyRisk(model, env, n_draws=scale.draws, extent=c, seed=seed)
            return [risk(Q).tolist(), [risk.trajectory(t) for t in trajs]]

        risks[f"bodies c={c:g}"] = tuple(store.get_or_compute(f"risk.bodies.{c:g}", compute))
        report("robot risk: sampled-body risks", scale.extents.index(c) + 1, len(scale.extents))
    fits = _logistic_risks(
        risks, store, model, env, Q, trajs, np.r_[r_conf, r_traj], scale, seed, report
    )
    measured = np.r_[r_conf, r_traj]
    metrics = {
        name: {
            "all": calibration_metrics(np.r_[c, t], measured),
            "configurations": calibration_metrics(c, r_conf),
            "trajectories": calibration_metrics(t, r_traj),
        }
        for name, (c, t) in risks.items()
    }
    result = {
        "scale": asdict(scale),
        "seed": int(seed),
        "measured": {"configurations": r_conf.tolist(), "trajectories": r_traj.tolist()},
        "predicted": {k: {"configurations": c, "trajectories": t} for k, (c, t) in risks.items()},
        "nominal_clearance": sel["clearance"],
        "metrics": metrics,
        "share_measured_5_95": float(np.mean((measured >= 0.05) & (measured <= 0.95))),
        "logistic_fits": fits,
        "seconds": time.perf_counter() - t0,
    }
    write_json_atomic(out / "risk_calibration.json", result)
    _figure(result, out / "risk_calibration.png")
    return result


def _figure(result: dict, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from riskplan.io import atomic_path

    measured = np.r_[result["measured"]["configurations"], result["measured"]["trajectories"]]
    edges = np.array([0.0, 0.02, 0.05, 0.1, 0.2, 0.35, 0.5, 0.7, 0.9, 1.0])
    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot([0, 1], [0, 1], "k--", lw=1, label="perfect calibration")
    for name, pr in result["predicted"].items():
        p = np.r_[pr["configurations"], pr["trajectories"]]
        b = np.clip(np.digitize(p, edges) - 1, 0, len(edges) - 2)
        xs, ys, ns = [], [], []
        for j in range(len(edges) - 1):
            if (b == j).any():
                xs.append(p[b == j].mean())
                ys.append(measured[b == j].mean())
                ns.append(int((b == j).sum()))
        m = result["metrics"][name]["all"]
        mae = "n/a" if m["mae_mid"] is None else f"{100 * m['mae_mid']:.1f}"
        shown = f"{name}, held out" if name.startswith("logistic") else name
        ax.plot(
            xs, ys, "o-", ms=4, label=f"{shown} (MAE 5-95 %: {mae} pts, Brier {m['brier']:.3f})"
        )
    ax.set_xlabel("predicted risk (bin mean)")
    ax.set_ylabel("collision rate on the robot (bin mean)")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title("Calibration against the simulated robot (backbone + disks)", fontsize=10)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def transmission_mechanism(
    configurations, measured, *, executions: int = 200, seed: int = 777, offset_seed: int = 5
):
    """Which part of the transmission decides the robot's collisions (docs/validation.md).

    For each configuration ``(N, 4)`` of the ``paper`` robot in ``build_chest(0)``, with
    ``executions`` fresh runs (seed ``seed``; the offsets-only runs draw their offsets from
    ``offset_seed``): the collision rate from the runs' own
    displacements (all sources), from the start history alone (nominal play, no play variation,
    no offset) and from the zero offsets alone (no play), each the body clearance
    (:func:`~riskplan.planning.chest.body_clearance`) at the displacements a run receives; and
    the share of the clearance variance between the 16 approach patterns (each tendon's start
    below or above its target). Returns the mean absolute errors against ``measured (N,)`` on
    the items measured in [5 %, 95 %] and the median share there.
    """
    from riskplan.datasets.protocol import random_starts
    from riskplan.parallel import spawn_seeds
    from riskplan.planning.chest import body_clearance
    from riskplan.planning.chest_scene import build_chest
    from riskplan.planning.executions import execution_displacements
    from riskplan.robots import load_robot

    Q = np.asarray(configurations, dtype=np.float64)
    r = np.asarray(measured, dtype=np.float64)
    robot, env = load_robot("paper"), build_chest(0).base_environment
    lim = np.asarray(robot.displacement_limits, dtype=np.float64)
    hp = robot.params.hysteresis
    seeds = spawn_seeds(seed, executions)
    starts = np.stack(
        [
            random_starts(
                lim, 1, np.random.default_rng(np.random.SeedSequence(int(s)).spawn(2)[0])
            )[0]
            for s in seeds
        ]
    )
    offsets = hp.offset_std * np.random.default_rng(offset_seed).standard_normal(starts.shape)
    rates = {"all sources": [], "start history": [], "offsets": []}
    share = []
    for x in Q:
        runs = {
            "all sources": execution_displacements(robot, x[None], seeds)[:, 0],
            "start history": np.clip(np.clip(starts, x - hp.play, x + hp.play), *lim.T),
            "offsets": np.clip(x + offsets, *lim.T),
        }
        for name, eff in runs.items():
            c = body_clearance(robot, eff, env)[1]
            rates[name].append(float((c < 0).mean()))
            if name == "all sources":
                pattern = ((starts < x) * (2 ** np.arange(len(x)))).sum(-1)
                means = np.array([c[pattern == p].mean() for p in pattern])
                share.append(float(means.var() / c.var()) if c.var() > 0 else np.nan)
    mid = (r >= 0.05) & (r <= 0.95)
    return {
        "mae_mid": {k: float(np.abs(np.asarray(v) - r)[mid].mean()) for k, v in rates.items()},
        "pattern_share_median": float(np.nanmedian(np.asarray(share)[mid])),
        "n_mid": int(mid.sum()),
        "rates": rates,
    }
