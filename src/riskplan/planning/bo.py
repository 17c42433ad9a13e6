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

from riskplan._validation import as_array, check_count, check_range
from riskplan.collision import trajectory_probability
from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.planning.bo_checks import (
    LIMIT_SLACK,
    check_optimiser_budget,
    check_trajectory_limits,
)
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
        """The result's figures as JSON types (arrays as lists).

        Returns
        -------
        dict
            ``method``, ``bound``, ``initial_bound``, ``reduction``, ``trace``, ``chosen``,
            ``accepted``, ``evaluations``, ``seconds`` and the ``extra`` entries.
        """
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


def _digest(state: dict) -> str:
    """SHA-256 of a checkpoint's content (canonical JSON, the result store's rule)."""
    from riskplan.io import canonical_json

    return hashlib.sha256(canonical_json(state).encode()).hexdigest()


def _bad(path, what: str):
    return DataFormatError(
        f"checkpoint {path}: {what}; delete it or rerun without --resume to start over"
    )


def read_checkpoint(path, fp: str, traj: np.ndarray, lim: np.ndarray, config) -> dict:
    """The state saved in ``path``, after checking everything read back.

    The content hash must match (an edited or damaged file is refused), the fingerprint must be
    this run's (trajectory, limits, settings, seed), and every number must be in range:
    probabilities in [0, 1], counts consistent with the iteration, configurations inside the
    limits with the start and goal unchanged, the trace non-increasing and ending at eq. 10 of
    the saved bounds. Any failure is a :class:`~riskplan.errors.DataFormatError`.
    """
    T, m = traj.shape
    try:
        state = json.loads(Path(path).read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise _bad(path, f"unreadable ({type(exc).__name__}: {exc})") from exc
    if not isinstance(state, dict):
        raise _bad(path, f"expected a JSON object, got {type(state).__name__}")
    if state.get("format") != CHECKPOINT_FORMAT:
        raise _bad(path, "not a trajectory optimisation checkpoint")
    digest = state.pop("sha256", None)
    try:
        ok = digest == _digest(state)
    except (TypeError, ValueError):  # non-finite numbers or unserialisable content
        ok = False
    if not ok:
        raise _bad(path, "content hash mismatch (edited, truncated or damaged)")
    if state.get("fingerprint") != fp:
        raise DataFormatError(
            f"checkpoint {path}: written for another trajectory, seed or settings; "
            "rerun without --resume (or with the original options)"
        )

    def integer(key, lo, hi=None):
        return check_count(
            state.get(key), repr(key), lo, maximum=hi, error=lambda msg: _bad(path, msg)
        )

    def number(key, lo, hi):
        v = state.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not lo <= v <= hi:
            raise _bad(path, f"{key!r} = {v!r} is not a number in [{lo}, {hi}]")
        return float(v)

    def array(key, shape, lo=None, hi=None, dtype=np.float64):
        v = state.get(key)
        try:
            a = np.asarray(v, dtype=dtype)
        except (TypeError, ValueError) as exc:
            raise _bad(path, f"{key!r} is not a numeric array") from exc
        if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape)):
            raise _bad(path, f"{key!r} has shape {a.shape}, expected {shape}")
        if isinstance(v, list) and dtype is not bool and _has_bools(v):
            raise _bad(path, f"{key!r} holds true/false where numbers belong")
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise _bad(path, f"{key!r} holds non-finite numbers")
        if lo is not None and a.size and not (np.all(a >= lo) and np.all(a <= hi)):
            raise _bad(path, f"{key!r} leaves its range [{lo}, {hi}]")
        return a

    it = integer("iteration", 0, int(config.iterations))
    slack = LIMIT_SLACK * (lim[:, 1] - lim[:, 0])
    lo, hi = lim[:, 0] - slack, lim[:, 1] + slack
    cur = array("trajectory", (T, m), lo, hi)
    if not (np.array_equal(cur[0], traj[0]) and np.array_equal(cur[-1], traj[-1])):
        raise _bad(path, "the start or goal configuration moved")
    p = array("bounds", (T,), 0.0, 1.0)
    initial = number("initial_bound", 0.0, 1.0)
    trace = array("trace", (it + 1,), 0.0, 1.0)
    if trace[0] != initial or np.any(np.diff(trace) > 0):
        raise _bad(path, "the trace does not start at the initial bound or increases")
    if trace[-1] != float(trajectory_probability(p)):
        raise _bad(path, "the trace does not end at eq. 10 of the saved bounds")
    chosen = array("chosen", (it,), -1, T - 2, dtype=np.int64)
    if np.any(chosen == 0) or (isinstance(state["chosen"], list) and _has_bools(state["chosen"])):
        raise _bad(path, "'chosen' names the start configuration or holds true/false")
    acc = state.get("accepted")
    if not isinstance(acc, list) or len(acc) != it or not all(isinstance(a, bool) for a in acc):
        raise _bad(path, f"'accepted' is not a list of {it} true/false values")
    if any(a and c < 0 for a, c in zip(acc, chosen.tolist())):
        raise _bad(path, "an iteration accepted a move it did not make")
    n_moves = int(np.sum(chosen >= 0))
    X = array("X", (T + n_moves, m), lo, hi)
    array("p", (T + n_moves,), 0.0, 1.0)
    if not np.array_equal(X[:T], traj):
        raise _bad(path, "'X' does not start with the input trajectory")
    integer("evaluations", n_moves, T + n_moves)
    number("radius", TR_MIN if config.method == "trust_region" else 0.0, max(TR_MAX, config.radius))
    integer("succ", 0, TR_SUCCESS)
    integer("fail", 0, TR_FAILURE)
    number("seconds", 0.0, math.inf)
    gp = state.get("gp")
    if gp is not None and not (
        isinstance(gp, dict)
        and all(isinstance(k, str) and _finite_numbers(v) for k, v in gp.items())
    ):
        raise _bad(path, "'gp' is not a table of finite hyperparameters")
    return state


def _has_bools(v) -> bool:
    return any(_has_bools(x) if isinstance(x, list) else isinstance(x, bool) for x in v)


def _finite_numbers(v) -> bool:
    if isinstance(v, list):
        return all(_finite_numbers(x) for x in v)
    return not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v)


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
        # learned values only: priors and constraint bounds (one is +inf) are the model's own
        if k.startswith(("likelihood.", "mean_module.", "covar_module."))
        and "prior" not in k
        and "constraint" not in k
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
    r"""Lower the eq.-10 bound of a trajectory by moving its intermediate configurations.

    Each iteration moves at most one intermediate configuration ``x_i`` (see the module
    docstring for the choice of ``i``, the candidates and their ranking) and keeps the move
    when the trajectory's bound decreases; eq. 10 combines the per-configuration eq.-9
    bounds :math:`p_t` as

    .. math:: P = 1 - \prod_{t=1}^{T} (1 - p_t).

    Never returns a trajectory with a larger bound than the start's.

    Parameters
    ----------
    trajectory : array_like, shape (T, m)
        The start trajectory (tendon displacements, m); ``T >= 2``; its first and last
        configurations never move.
    bound : callable
        ``bound(configs (N, m)) -> (N,)``: eq. 9 per configuration, a probability.
    validity : callable
        ``validity(configs (N, m)) -> (N,)`` bool, and ``validity.motions(a (N, m), b (N, m),
        resolution) -> (N,)`` bool (a :class:`~riskplan.planning.prm.MeanValidity`).
    limits : array_like, shape (m, 2)
        Displacement limits (m), low and high per tendon.
    config : OptimiserConfig, optional
        Method, iterations, candidates, radius and motion resolution (default
        ``OptimiserConfig()``).
    seed : int
        Iteration ``k`` draws from ``numpy.random.default_rng([seed, k])``.
    bounds : array_like, shape (T,), optional
        The start trajectory's eq.-9 bounds if already known (saves T evaluations).
    checkpoint : str or path, optional
        A JSON file written atomically after every iteration.
    resume : bool
        Continue from ``checkpoint`` if it exists (the result equals an uninterrupted run's).
    progress : callable, optional
        ``progress(iteration, total, bound)`` after each iteration.

    Returns
    -------
    OptimisationResult
        The optimised trajectory ``(T, m)``, its bounds and the trace of eq. 10 per iteration.
    """
    from riskplan.io import write_json_atomic

    config, traj, lim, bounds = _check_optimiser_arguments(
        trajectory, limits, config, seed, bounds, checkpoint
    )
    fp = _fingerprint(traj, lim, config, seed)
    t0 = time.perf_counter()
    state = None
    if resume and checkpoint is not None and Path(checkpoint).is_file():
        state = read_checkpoint(checkpoint, fp, traj, lim, config)
    if state is None:
        p0 = np.asarray(bound(traj) if bounds is None else bounds, dtype=np.float64)
        state = _initial_state(traj, p0, fp, config, 0 if bounds is not None else len(traj))
    elapsed0 = float(state["seconds"])
    cur, p = np.asarray(state["trajectory"]), np.asarray(state["bounds"])
    X, pX = [np.asarray(x) for x in state["X"]], list(state["p"])

    for it in range(int(state["iteration"]), int(config.iterations)):
        rng = np.random.default_rng([int(seed), it])
        best = float(trajectory_probability(p))
        chosen, accepted = -1, False
        i = _pick_configuration(p, rng, config)
        x_new = None
        if i is not None:
            x_new = _propose(i, cur, p, X, pX, lim, best, rng, state, validity, config)
        if x_new is not None:
            chosen = i
            cur, p, accepted = _evaluate_move(i, x_new, bound, cur, p, X, pX, best, state)
        if config.method == "trust_region":
            _update_trust_region(state, accepted)
        seconds = elapsed0 + time.perf_counter() - t0
        _record_iteration(state, it, cur, p, X, pX, chosen, accepted, seconds)
        if checkpoint is not None:
            state.pop("sha256", None)
            state["sha256"] = _digest(state)
            write_json_atomic(checkpoint, state, indent=None)
        if progress is not None:
            progress(it + 1, int(config.iterations), state["trace"][-1])
    return _result(state, config, elapsed0 + time.perf_counter() - t0)


def _check_optimiser_arguments(trajectory, limits, config, seed, bounds, checkpoint):
    """``optimise_trajectory``'s arguments checked before any work: (config, trajectory
    ``(T, m)``, limits ``(m, 2)``, bounds ``(T,)`` or None)."""
    if config is not None and not isinstance(config, OptimiserConfig):
        raise InvalidInputError(f"config: expected an OptimiserConfig, got {type(config).__name__}")
    config = config or OptimiserConfig()
    config.validate()
    traj, lim = check_trajectory_limits(trajectory, limits)
    check_count(seed, "seed", 0)
    if bounds is not None:
        bounds = as_array(bounds, "bounds", shape=(len(traj),))
        check_range(bounds, "bounds", 0.0, 1.0)
    if checkpoint is not None:
        from riskplan.io import check_output_file

        check_output_file(checkpoint, "checkpoint")  # before any work: not a folder
    check_optimiser_budget(config, len(traj), lim)
    return config, traj, lim, bounds


def _initial_state(traj, p0, fp: str, config, evaluations: int) -> dict:
    """The state before the first iteration (the checkpoint's content)."""
    start = float(trajectory_probability(p0))
    return {
        "format": CHECKPOINT_FORMAT,
        "fingerprint": fp,
        "iteration": 0,
        "trajectory": traj.tolist(),
        "bounds": p0.tolist(),
        "initial_bound": start,
        "X": traj.tolist(),
        "p": p0.tolist(),
        "trace": [start],
        "chosen": [],
        "accepted": [],
        "radius": float(config.radius),
        "succ": 0,
        "fail": 0,
        "evaluations": evaluations,
        "seconds": 0.0,
    }


def _pick_configuration(p: np.ndarray, rng, config) -> int | None:
    """The intermediate configuration to move, from the bounds ``p (T,)``: drawn in proportion
    to its bound, or the largest for the trust region; None when no intermediate one carries
    risk."""
    inner = np.arange(1, len(p) - 1)
    w = p[inner] if len(inner) else np.zeros(0)
    if not (len(inner) and w.sum() > 0):
        return None
    if config.method == "trust_region":
        return int(inner[np.argmax(w)])
    return int(rng.choice(inner, p=w / w.sum()))


def _propose(i, cur, p, X, pX, lim, best, rng, state, validity, config) -> np.ndarray | None:
    """The move for configuration ``i``: uniform candidates in the box around ``cur[i]``,
    the valid ones ranked (at random, or by the acquisition), the first whose motions from
    ``cur[i - 1]`` and to ``cur[i + 1]`` are valid; ``(m,)`` or None."""
    span = lim[:, 1] - lim[:, 0]
    radius = state["radius"] if config.method == "trust_region" else config.radius
    step = (rng.random((config.n_candidates, cur.shape[1])) * 2 - 1) * radius * span
    cand = np.clip(cur[i] + step, lim[:, 0], lim[:, 1])
    cand = cand[validity(cand)]
    if not len(cand):
        return None
    if config.method == "random":
        order = rng.permutation(len(cand))
    else:
        # eq. 10 factorises: every known eq.-9 value gives the exact trajectory bound at i
        rest = 1.0 - np.exp(np.log1p(-np.delete(p, i)).sum())  # eq. 10 without i
        y = 1.0 - (1.0 - rest) * (1.0 - np.asarray(pX))
        Xu = (np.asarray(X) - lim[:, 0]) / span
        acq, state["gp"] = _acquisition(
            Xu, y, (cand - lim[:, 0]) / span, best, int(rng.integers(2**31)), state.get("gp")
        )
        order = np.argsort(-acq, kind="stable")
    for j in range(0, len(order), 16):
        blk = cand[order[j : j + 16]]
        res = config.resolution
        ok = validity.motions(np.broadcast_to(cur[i - 1], blk.shape), blk, res) & (
            validity.motions(blk, np.broadcast_to(cur[i + 1], blk.shape), res)
        )
        if ok.any():
            return blk[int(np.argmax(ok))]
    return None


def _evaluate_move(i, x_new, bound, cur, p, X, pX, best, state):
    """Evaluate eq. 9 at ``x_new`` (one evaluation, kept for the surrogate) and keep the move
    of configuration ``i`` when eq. 10 decreases; (trajectory, bounds, accepted)."""
    p_new = float(bound(x_new[None])[0])
    state["evaluations"] += 1
    X.append(x_new)
    pX.append(p_new)
    trial = p.copy()
    trial[i] = p_new
    if float(trajectory_probability(trial)) < best:
        cur = cur.copy()
        cur[i] = x_new
        return cur, trial, True
    return cur, p, False


def _record_iteration(state, it, cur, p, X, pX, chosen, accepted, seconds) -> None:
    """The state after iteration ``it`` (what the checkpoint holds)."""
    state.update(
        iteration=it + 1,
        trajectory=cur.tolist(),
        bounds=p.tolist(),
        X=[x.tolist() for x in X],
        p=pX,
        seconds=seconds,
    )
    state["trace"].append(float(trajectory_probability(p)))
    state["chosen"].append(chosen)
    state["accepted"].append(accepted)


def _update_trust_region(state: dict, accepted: bool) -> None:
    """TuRBO's rule: the radius doubles after ``TR_SUCCESS`` consecutive improvements and
    halves after ``TR_FAILURE`` consecutive failures, within ``[TR_MIN, TR_MAX]``."""
    if accepted:
        state["succ"], state["fail"] = state["succ"] + 1, 0
    else:
        state["succ"], state["fail"] = 0, state["fail"] + 1
    if state["succ"] >= TR_SUCCESS:
        state["radius"], state["succ"] = min(TR_MAX, 2 * state["radius"]), 0
    elif state["fail"] >= TR_FAILURE:
        state["radius"], state["fail"] = max(TR_MIN, state["radius"] / 2), 0


def _result(state: dict, config, seconds: float) -> OptimisationResult:
    return OptimisationResult(
        trajectory=np.asarray(state["trajectory"]),
        bounds=np.asarray(state["bounds"]),
        bound=float(state["trace"][-1]),
        initial_bound=float(state["initial_bound"]),
        trace=np.asarray(state["trace"]),
        chosen=np.asarray(state["chosen"], dtype=int),
        accepted=np.asarray(state["accepted"], dtype=bool),
        evaluations=int(state["evaluations"]),
        seconds=seconds,
        method=config.method,
    )
