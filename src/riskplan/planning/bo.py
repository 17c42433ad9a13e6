"""Local optimisation of a nominal trajectory's collision bound (MDN paper section V, Fig. 7).

The paper's Bayesian optimisation (``method="bo"``), one intermediate configuration per
iteration:

1. choose an intermediate configuration ``x_i`` of the trajectory (start and goal never move);
2. draw ``n_candidates`` configurations uniformly in the box ``x_i +- radius * (limits range)``,
   clipped to the limits, and keep those that are valid (every component mean free, within
   limits) with valid motions from ``x_{i-1}`` and to ``x_{i+1}`` (the PRM's resolution);
3. score them with probability of improvement (BoTorch ``LogProbabilityOfImprovement``) under a
   GP surrogate (``SingleTaskGP``, float64, inputs scaled to the unit cube by the displacement
   limits, outcome standardised) of the trajectory bound as a function of the configuration
   placed at ``i``;
4. evaluate the best candidate with eq. 9 and combine with eq. 10; keep it if the trajectory
   bound decreased.

Choices the paper leaves open (documented in docs/planning.md):

* The configuration to move is drawn with probability proportional to its eq.-9 bound
  (configurations with zero risk cannot lower eq. 10).
* The surrogate's training set: eq. 10 factorises, ``P = 1 - (1 - P_rest,i)(1 - p(x))``, so
  every configuration whose eq.-9 bound is known (the nominal trajectory's and every candidate
  evaluated so far) gives the *exact* trajectory bound it would yield at ``i``. The GP is fit to
  those values at every iteration; no extra bound evaluations are spent on an initial design.
* ``radius = 0.1`` of each tendon's range (5 mm for the paper robot), 256 candidates.

Comparison methods with the same budget (one eq.-9 evaluation per iteration):

* ``"random"`` — random local search: the same candidates, one picked at random (no GP).
* ``"trust_region"`` — the same GP and acquisition with a TuRBO-style trust region (Eriksson
  et al. 2019): the radius doubles after 3 consecutive improvements and halves after 4
  consecutive failures (within [1/32, 0.4] of the range), and the configuration with the
  largest eq.-9 bound is moved.

Each iteration draws from a generator seeded by ``(seed, iteration)``, and the state after
each completed iteration is written atomically to ``checkpoint``; ``resume=True`` continues
from it and gives the same result as an uninterrupted run.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from riskplan.collision import trajectory_probability
from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.planning.prm import DEFAULT_RESOLUTION

log = logging.getLogger(__name__)

METHODS = ("bo", "random", "trust_region")
CHECKPOINT_FORMAT = "riskplan-trajectory-optimisation"
TR_SUCCESS, TR_FAILURE, TR_MIN, TR_MAX = 3, 4, 1 / 32, 0.4


@dataclass(frozen=True)
class OptimiserConfig:
    """Settings of :func:`optimise_trajectory` (see the module docstring)."""

    iterations: int = 50
    n_candidates: int = 256
    radius: float = 0.1
    method: str = "bo"
    resolution: float = DEFAULT_RESOLUTION

    def validate(self) -> None:
        if self.method not in METHODS:
            raise InvalidInputError(f"method: expected one of {METHODS}, got {self.method!r}")
        if int(self.iterations) < 0:
            raise InvalidInputError(f"iterations: expected >= 0, got {self.iterations}")
        if int(self.n_candidates) < 1:
            raise InvalidInputError(f"n_candidates: expected >= 1, got {self.n_candidates}")
        for name in ("radius", "resolution"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidInputError(f"{name}: expected a finite number > 0, got {v!r}")


@dataclass
class OptimisationResult:
    """Outcome of :func:`optimise_trajectory`.

    ``trajectory (T, m)``, ``bounds (T,)`` eq. 9 per configuration, ``bound`` eq. 10;
    ``trace (iterations + 1,)`` the best eq.-10 bound after each iteration (``trace[0]`` the
    start's); ``chosen``/``accepted (iterations,)``: moved index (-1 if none) and whether kept.
    """

    trajectory: np.ndarray
    bounds: np.ndarray
    bound: float
    initial_bound: float
    trace: np.ndarray
    chosen: np.ndarray
    accepted: np.ndarray
    evaluations: int
    seconds: float
    method: str
    extra: dict = field(default_factory=dict)

    @property
    def reduction(self) -> float:
        """Relative reduction ``1 - bound / initial_bound`` (0 if the start bound is 0)."""
        return 0.0 if self.initial_bound <= 0 else 1.0 - self.bound / self.initial_bound

    def to_json(self) -> dict:
        return {
            "method": self.method,
            "bound": self.bound,
            "initial_bound": self.initial_bound,
            "reduction": self.reduction,
            "trace": self.trace.tolist(),
            "chosen": self.chosen.tolist(),
            "accepted": self.accepted.tolist(),
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            **self.extra,
        }


def _fingerprint(
    trajectory: np.ndarray, limits: np.ndarray, config: OptimiserConfig, seed: int
) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(trajectory, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(limits, dtype=np.float64).tobytes())
    h.update(json.dumps({**asdict(config), "seed": int(seed)}, sort_keys=True).encode())
    return h.hexdigest()


def _acquisition(
    X: np.ndarray,
    y: np.ndarray,
    cand: np.ndarray,
    best: float,
    seed_int: int,
    warm: dict | None = None,
) -> tuple[np.ndarray, dict]:
    """Log probability that ``cand (N, m)`` (unit cube) improves on ``best`` under a GP fit to
    ``X (n, m)``, ``y (n,)`` (to be minimised); ``(N,)``, and the fitted hyperparameters.

    ``warm``: hyperparameters of the previous iteration's GP, the start of this fit (the data
    change by one point per iteration, so the optimum moves little).
    """
    import torch
    from botorch.acquisition.analytic import LogProbabilityOfImprovement
    from botorch.fit import fit_gpytorch_mll
    from botorch.models import SingleTaskGP
    from botorch.models.transforms.outcome import Standardize
    from gpytorch.mlls import ExactMarginalLogLikelihood

    torch.manual_seed(seed_int)
    tx = torch.as_tensor(X, dtype=torch.float64)
    ty = -torch.as_tensor(y, dtype=torch.float64)[:, None]  # BoTorch maximises
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gp = SingleTaskGP(tx, ty, outcome_transform=Standardize(m=1))
        if warm:
            gp.load_state_dict(
                {k: torch.as_tensor(v, dtype=torch.float64) for k, v in warm.items()}, strict=False
            )
        try:
            fit_gpytorch_mll(ExactMarginalLogLikelihood(gp.likelihood, gp))
        except Exception as exc:
            log.warning("GP fit failed (%s); using the prior hyperparameters this iteration", exc)
        gp.eval()
        acq = LogProbabilityOfImprovement(gp, best_f=-float(best))
        with torch.no_grad():
            values = acq(torch.as_tensor(cand, dtype=torch.float64)[:, None, :]).numpy()
    hyper = {
        k: v.tolist()
        for k, v in gp.state_dict().items()
        if k.startswith(("likelihood.", "mean_module.", "covar_module.")) and "prior" not in k
    }
    return values, hyper


def optimise_trajectory(
    trajectory,
    bound,
    validity,
    limits,
    *,
    config: OptimiserConfig | None = None,
    seed: int = 0,
    bounds=None,
    checkpoint=None,
    resume: bool = False,
    progress=None,
) -> OptimisationResult:
    """Lower the eq.-10 bound of ``trajectory (T, m)`` by moving intermediate configurations.

    ``bound(configs (N, m)) -> (N,)`` eq. 9 per configuration; ``validity(configs) -> (N,)``
    bool and ``validity.motions(a, b, resolution) -> (N,)`` bool (a
    :class:`~riskplan.planning.prm.MeanValidity`); ``limits (m, 2)``. ``bounds (T,)``: the
    start trajectory's eq.-9 bounds if already known (saves T evaluations). ``checkpoint``: a
    JSON path written atomically after every iteration; ``resume=True`` continues from it.
    ``progress(iteration, total, bound)`` after each iteration. Never returns a trajectory
    with a larger bound than the start's.
    """
    from riskplan.io import write_json_atomic

    config = config or OptimiserConfig()
    config.validate()
    lim = np.asarray(limits, dtype=np.float64)
    traj = np.array(trajectory, dtype=np.float64)
    if traj.ndim != 2 or traj.shape[1] != lim.shape[0] or len(traj) < 2:
        raise InvalidInputError(
            f"trajectory: expected shape (T >= 2, {lim.shape[0]}), got {traj.shape}"
        )
    if not np.all(np.isfinite(traj)):
        raise InvalidInputError("trajectory: contains NaN or inf")
    T, m = traj.shape
    span = lim[:, 1] - lim[:, 0]
    fp = _fingerprint(traj, lim, config, seed)
    t0 = time.perf_counter()

    state = None
    if resume and checkpoint is not None and Path(checkpoint).is_file():
        try:
            state = json.loads(Path(checkpoint).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise DataFormatError(f"checkpoint {checkpoint}: unreadable ({exc})") from exc
        if state.get("format") != CHECKPOINT_FORMAT or state.get("fingerprint") != fp:
            raise DataFormatError(
                f"checkpoint {checkpoint}: written for another trajectory, seed or settings; "
                "rerun without --resume (or with the original options)"
            )
    if state is None:
        p0 = np.asarray(bound(traj) if bounds is None else bounds, dtype=np.float64)
        state = {
            "format": CHECKPOINT_FORMAT,
            "fingerprint": fp,
            "iteration": 0,
            "trajectory": traj.tolist(),
            "bounds": p0.tolist(),
            "initial_bound": float(trajectory_probability(p0)),
            "X": traj.tolist(),
            "p": p0.tolist(),
            "trace": [float(trajectory_probability(p0))],
            "chosen": [],
            "accepted": [],
            "radius": float(config.radius),
            "succ": 0,
            "fail": 0,
            "evaluations": 0 if bounds is not None else T,
            "seconds": 0.0,
        }
    elapsed0 = float(state["seconds"])
    cur = np.asarray(state["trajectory"])
    p = np.asarray(state["bounds"])
    X = [np.asarray(x) for x in state["X"]]
    pX = list(state["p"])
    inner = np.arange(1, T - 1)

    for it in range(int(state["iteration"]), int(config.iterations)):
        rng = np.random.default_rng([int(seed), it])
        best = float(trajectory_probability(p))
        chosen, accepted = -1, False
        w = p[inner] if len(inner) else np.zeros(0)
        if len(inner) and w.sum() > 0:
            i = (
                int(inner[np.argmax(w)])
                if config.method == "trust_region"
                else int(rng.choice(inner, p=w / w.sum()))
            )
            radius = state["radius"] if config.method == "trust_region" else config.radius
            cand = cur[i] + (rng.random((config.n_candidates, m)) * 2 - 1) * radius * span
            cand = np.clip(cand, lim[:, 0], lim[:, 1])
            cand = cand[validity(cand)]
            if len(cand):
                if config.method == "random":
                    order = rng.permutation(len(cand))
                else:
                    rest = 1.0 - np.exp(np.log1p(-np.delete(p, i)).sum())  # eq. 10 without i
                    y = 1.0 - (1.0 - rest) * (1.0 - np.asarray(pX))
                    Xu = (np.asarray(X) - lim[:, 0]) / span
                    acq, state["gp"] = _acquisition(
                        Xu,
                        y,
                        (cand - lim[:, 0]) / span,
                        best,
                        int(rng.integers(2**31)),
                        state.get("gp"),
                    )
                    order = np.argsort(-acq, kind="stable")
                x_new = None
                for j in range(0, len(order), 16):
                    blk = cand[order[j : j + 16]]
                    ok = validity.motions(
                        np.broadcast_to(cur[i - 1], blk.shape), blk, config.resolution
                    ) & validity.motions(
                        blk, np.broadcast_to(cur[i + 1], blk.shape), config.resolution
                    )
                    if ok.any():
                        x_new = blk[int(np.argmax(ok))]
                        break
                if x_new is not None:
                    chosen = i
                    p_new = float(bound(x_new[None])[0])
                    state["evaluations"] += 1
                    X.append(x_new)
                    pX.append(p_new)
                    trial = p.copy()
                    trial[i] = p_new
                    if float(trajectory_probability(trial)) < best:
                        cur = cur.copy()
                        cur[i] = x_new
                        p = trial
                        accepted = True
        if config.method == "trust_region":
            if accepted:
                state["succ"], state["fail"] = state["succ"] + 1, 0
            else:
                state["succ"], state["fail"] = 0, state["fail"] + 1
            if state["succ"] >= TR_SUCCESS:
                state["radius"], state["succ"] = min(TR_MAX, 2 * state["radius"]), 0
            elif state["fail"] >= TR_FAILURE:
                state["radius"], state["fail"] = max(TR_MIN, state["radius"] / 2), 0
        state.update(
            iteration=it + 1,
            trajectory=cur.tolist(),
            bounds=p.tolist(),
            X=[x.tolist() for x in X],
            p=pX,
            seconds=elapsed0 + time.perf_counter() - t0,
        )
        state["trace"].append(float(trajectory_probability(p)))
        state["chosen"].append(chosen)
        state["accepted"].append(accepted)
        if checkpoint is not None:
            write_json_atomic(checkpoint, state, indent=None)
        if progress is not None:
            progress(it + 1, int(config.iterations), state["trace"][-1])

    return OptimisationResult(
        trajectory=np.asarray(state["trajectory"]),
        bounds=np.asarray(state["bounds"]),
        bound=float(state["trace"][-1]),
        initial_bound=float(state["initial_bound"]),
        trace=np.asarray(state["trace"]),
        chosen=np.asarray(state["chosen"], dtype=int),
        accepted=np.asarray(state["accepted"], dtype=bool),
        evaluations=int(state["evaluations"]),
        seconds=elapsed0 + time.perf_counter() - t0,
        method=config.method,
    )
