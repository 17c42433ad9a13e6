r"""The mixture density network (MDN paper, section III, Fig. 2) and the trained model.

Network: normalised tendon displacements ``(..., m)`` → shared fully connected trunk →
three separate fully connected heads producing, for each of ``K`` components,

* a weight logit (weights through a softmax, eq. 1 requires ``w >= 0, sum w = 1``),
* a mean ``mu_k`` (``d = 3``),
* the ``d(d+1)/2`` unconstrained entries of ``U_k``: strictly-upper entries are used
  as they are, diagonal entries through ``exp`` (eq. 2), so ``Sigma_k^{-1} = Ubar_k^T Ubar_k``
  (eq. 3) is positive definite for any network output.

The loss is the mean negative log-likelihood of a configuration's ground-truth points
(the loss after eq. 7), with ``log |Sigma^{-1}|^{1/2} = sum_j log diag(Ubar)_j`` (eqs. 4-6):

.. math::

    (\bar U_k)_{jl} = \begin{cases} (U_k)_{jl}, & j < l \\ \exp (U_k)_{jj}, & j = l
    \\ 0, & j > l \end{cases} \qquad \text{(eq. 2)}

    \mathrm{MDN}_\theta(y) = \{ w_{k|\theta}, \mu_{k|\theta}, U_{k|\theta} \}_{k=1}^K
    \qquad \text{(eq. 7)}

    \mathcal{L}(\theta) = \mathbb{E}_{x, y} \left[ -\log \sum_{k=1}^K w_{k|\theta}
    \exp\left( \sum_{j} \log (\bar U_{k|\theta})_{jj} - \frac{1}{2} \| \bar U_{k|\theta}
    (x - \mu_{k|\theta}) \|^2 \right) \right] + \frac{d}{2} \log 2\pi.

(The paper writes ``diag(U)`` in the loss's exponent; with eq. 2 that is
``log diag(Ubar)``.)

The network works in normalised coordinates: inputs ``(d - input_mean) / input_scale``
and points ``(x - output_centre) / output_scale`` (per axis). :class:`MDNModel` maps the
mixture back to metres: ``mu = c + s * mu_n`` and ``Ubar = Ubar_n diag(1/s)`` (still
upper triangular), so ``log p(x) = log p_n(x_n) - sum log s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.special import expit as _expit
from torch import nn

from riskplan._validation import as_array
from riskplan.errors import InvalidInputError
from riskplan.kinematics.normalisation import Normalisation
from riskplan.kinematics.torch_mixture import GaussianMixture

# exp of a raw diagonal entry is clamped to exp(+-LOG_DIAG_BOUND): eq. 2 holds exactly inside this
# range (standard deviations from 2e-9 to 5e8 in normalised units), and outside it the output and its
# gradient stay finite instead of overflowing for extreme inputs.
LOG_DIAG_BOUND = 20.0
ACTIVATIONS = ("silu", "tanh", "relu")
# Displacements may exceed the robot's limits by this much (rounding in files and conversions).
LIMIT_SLACK = 1e-9
# batches from this many rows use the vectorisation-friendly SiLU form in the NumPy path
_LARGE_BATCH = 256


def n_cholesky_entries(d: int) -> int:
    return d * (d + 1) // 2


def _act_module(name: str) -> nn.Module:
    return {"silu": nn.SiLU, "tanh": nn.Tanh, "relu": nn.ReLU}[name]()


def _mlp(n_in: int, widths, n_out: int, activation: str) -> nn.Sequential:
    layers: list[nn.Module] = []
    for w in widths:
        layers += [nn.Linear(n_in, w), _act_module(activation)]
        n_in = w
    layers.append(nn.Linear(n_in, n_out))
    return nn.Sequential(*layers)


class MDN(nn.Module):
    """Fig. 2: trunk + separate heads for weights, means and the unconstrained ``U``.

    ``forward(x (..., m))`` returns ``(log_weights (..., K), means (..., K, d),
    precision_cholesky (..., K, d, d))`` in normalised coordinates.
    """

    def __init__(
        self,
        n_inputs: int,
        n_components: int,
        dim: int = 3,
        hidden=(64, 64),
        head_hidden=(32,),
        activation: str = "silu",
        angle_inputs=(),
    ):
        super().__init__()
        angle_inputs = tuple(int(a) for a in angle_inputs)
        if any(not 0 <= a < n_inputs for a in angle_inputs) or len(set(angle_inputs)) != len(
            angle_inputs
        ):
            raise InvalidInputError(
                f"angle_inputs: expected distinct input indices in [0, {n_inputs}), got {angle_inputs}"
            )
        if n_inputs < 1 or n_components < 1 or dim < 1:
            raise InvalidInputError(
                f"MDN: need n_inputs, n_components, dim >= 1, got {n_inputs}, {n_components}, {dim}"
            )
        if activation not in ACTIVATIONS:
            raise InvalidInputError(
                f"activation: expected one of {ACTIVATIONS}, got {activation!r}"
            )
        hidden, head_hidden = tuple(int(h) for h in hidden), tuple(int(h) for h in head_hidden)
        if not hidden or any(h < 1 for h in hidden + head_hidden):
            raise InvalidInputError(
                f"hidden: expected at least one positive width, got {hidden} (heads {head_hidden})"
            )
        self.n_inputs, self.n_components, self.dim = n_inputs, n_components, dim
        self.hidden, self.head_hidden, self.activation = hidden, head_hidden, activation
        #: inputs that are angles (a base rotation over a full turn): the network reads
        #: (cos a, sin a) in their place, so a and a + 2 pi are one input (the normalisation
        #: leaves them as they are, Normalisation.fit(angle_columns=...))
        self.angle_inputs = angle_inputs
        trunk: list[nn.Module] = []
        n = n_inputs + len(angle_inputs)
        for w in hidden:
            trunk += [nn.Linear(n, w), _act_module(activation)]
            n = w
        self.trunk = nn.Sequential(*trunk)
        K, T = n_components, n_cholesky_entries(dim)
        self.weight_head = _mlp(n, head_hidden, K, activation)
        self.mean_head = _mlp(n, head_hidden, K * dim, activation)
        self.chol_head = _mlp(n, head_hidden, K * T, activation)
        rows, cols = torch.triu_indices(dim, dim)
        self.register_buffer("_flat_index", rows * dim + cols, persistent=False)
        self.register_buffer("_is_diag", rows == cols, persistent=False)
        self._init_output_layers()

    def _init_output_layers(self) -> None:
        # Start from a sensible mixture: equal weights, means spread like the normalised data (unit
        # scale), covariances of the data's scale (U = I), so the first NLL is moderate.
        with torch.no_grad():
            for head in (self.weight_head, self.chol_head):
                head[-1].weight.mul_(0.1)
                head[-1].bias.zero_()

    def architecture(self) -> dict:
        """The constructor's arguments, as stored in ``model.json``.

        Returns
        -------
        dict
            ``MDN(**architecture())`` rebuilds the network (``angle_inputs`` only when there are any).
        """
        arch = {
            "n_inputs": self.n_inputs,
            "n_components": self.n_components,
            "dim": self.dim,
            "hidden": list(self.hidden),
            "head_hidden": list(self.head_hidden),
            "activation": self.activation,
        }
        if self.angle_inputs:  # left out otherwise: earlier models' files stay as they were
            arch["angle_inputs"] = list(self.angle_inputs)
        return arch

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` with each angle input ``a`` replaced by ``cos a`` and ``sin a`` appended.

        Parameters
        ----------
        x : torch.Tensor, (..., n_inputs)

        Returns
        -------
        torch.Tensor, (..., n_inputs + len(angle_inputs))
        """
        if not self.angle_inputs:
            return x
        idx = list(self.angle_inputs)
        ang = x[..., idx]
        f = x.clone()
        f[..., idx] = torch.cos(ang)
        return torch.cat([f, torch.sin(ang)], dim=-1)

    def raw(self, x: torch.Tensor):
        """Head outputs ``(logits (..., K), means (..., K*d), u_raw (..., K*T))``, before eq. 2.

        Parameters
        ----------
        x : torch.Tensor, (..., n_inputs)

        Returns
        -------
        tuple of torch.Tensor
            ``logits (..., K)``, ``means (..., K*d)``, ``u_raw (..., K*T)``.
        """
        h = self.trunk(self.features(x))
        return self.weight_head(h), self.mean_head(h), self.chol_head(h)

    def forward(self, x: torch.Tensor):
        """The mixture at normalised inputs (Fig. 2; eq. 2 builds ``U``).

        Parameters
        ----------
        x : torch.Tensor, (..., n_inputs)

        Returns
        -------
        tuple of torch.Tensor
            ``log_weights (..., K)`` (log-softmax of the logits), ``means (..., K, d)`` and
            ``precision_cholesky (..., K, d, d)``, ``Sigma_k^{-1} = U_k^T U_k``.
        """
        logits, mu, u_raw = self.raw(x)
        batch = x.shape[:-1]
        K, d = self.n_components, self.dim
        log_w = torch.log_softmax(logits, dim=-1)
        means = mu.reshape(*batch, K, d)
        u = build_precision_cholesky(
            u_raw.reshape(*batch, K, -1), d, self._flat_index, self._is_diag
        )
        return log_w, means, u


def build_precision_cholesky(
    u_raw: torch.Tensor, d: int, flat_index=None, is_diag=None
) -> torch.Tensor:
    """Eq. 2: ``Ubar_jk = U_jk`` for ``j < k``, ``exp(U_jj)`` on the diagonal, zero below.

    ``u_raw (..., K, d(d+1)/2)`` lists the upper triangle row by row
    (``torch.triu_indices`` order); returns ``(..., K, d, d)``. The diagonal's raw
    values are clamped to ``[-LOG_DIAG_BOUND, LOG_DIAG_BOUND]`` before ``exp``.
    """
    if flat_index is None:
        rows, cols = torch.triu_indices(d, d, device=u_raw.device)
        flat_index, is_diag = rows * d + cols, rows == cols
    vals = torch.where(
        is_diag, torch.exp(torch.clamp(u_raw, -LOG_DIAG_BOUND, LOG_DIAG_BOUND)), u_raw
    )
    out = u_raw.new_zeros(*u_raw.shape[:-1], d * d)
    out = out.index_copy(out.ndim - 1, flat_index, vals)
    return out.reshape(*u_raw.shape[:-1], d, d)


def mixture_log_prob(
    log_weights: torch.Tensor, means: torch.Tensor, u: torch.Tensor, points: torch.Tensor
) -> torch.Tensor:
    """Eq. 1 with eqs. 4-6, from log-weights (stable for weights that underflow to zero).

    ``log_weights (..., K)``, ``means (..., K, d)``, ``u (..., K, d, d)``, ``points (..., N, d)``
    → ``(..., N)``: ``logsumexp_k [log w_k + sum_j log U_k,jj - ||U_k (x - mu_k)||^2 / 2] - d/2 log 2 pi``.
    """
    d = means.shape[-1]
    diff = points.unsqueeze(-3) - means.unsqueeze(-2)  # (..., K, N, d)
    y = torch.einsum("...kij,...knj->...kni", u, diff)
    sq = (y * y).sum(-1)
    logdet = torch.log(torch.diagonal(u, dim1=-2, dim2=-1)).sum(-1)
    comp = logdet.unsqueeze(-1) - 0.5 * sq
    return torch.logsumexp(log_weights.unsqueeze(-1) + comp, dim=-2) - 0.5 * d * math.log(
        2.0 * math.pi
    )


def mdn_nll(net: MDN, x: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """The paper's loss (after eq. 7): mean over configurations and points of ``-log p(x | y)``.

    ``x (B, m)`` normalised inputs, ``points (B, N, d)`` normalised points; scalar.
    """
    log_w, means, u = net(x)
    return -mixture_log_prob(log_w, means, u, points).mean()


@dataclass(eq=False, repr=False)
class MDNModel:
    """A trained MDN with its normalisation and the robot it was trained for.

    ``predict(displacements (..., m)) -> GaussianMixture`` in the robot's base frame, metres.
    """

    net: MDN
    normalisation: Normalisation
    limits: np.ndarray  # (m, 2)
    robot_toml: str = ""
    robot_name: str = ""
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        self.net.eval()
        self._fast = None
        self._robot = None
        self._bounds = None

    @property
    def n_components(self) -> int:
        return self.net.n_components

    @property
    def n_tendons(self) -> int:
        return self.net.n_inputs

    def __repr__(self) -> str:
        a = self.net.architecture()
        return (
            f"MDNModel(robot={self.robot_name!r}, tendons={self.n_tendons}, K={self.n_components}, "
            f"hidden={a['hidden']}, heads={a['head_hidden']}, activation={a['activation']!r})"
        )

    @property
    def robot(self):
        """The robot rebuilt from the TOML stored with the model (a ``TendonRobot``).

        ``None`` if the model stores no robot description or ``riskplan.robots`` is not
        installed; :class:`DataFormatError` if the stored description cannot be rebuilt.
        """
        if self._robot is None and self.robot_toml:
            from riskplan.errors import DataFormatError, RiskplanError
            from riskplan.robots import robot_from_toml

            try:
                self._robot = robot_from_toml(self.robot_toml)
            except RiskplanError as exc:
                raise DataFormatError(
                    f"the model's robot {self.robot_name!r} cannot be rebuilt from its stored description: {exc}"
                ) from exc
        return self._robot

    # ----------------------------------------------------------- validation
    def check_displacements(self, displacements, name: str = "displacements") -> np.ndarray:
        """Validate ``(..., m)`` displacements: tendon count, finite, within the robot's limits.

        Parameters
        ----------
        displacements : array_like, (..., m)
        name : str
            The argument's name in the error message.

        Returns
        -------
        numpy.ndarray, (..., m)
            float64; :class:`InvalidInputError` when they are not valid.
        """
        try:
            d = np.asarray(displacements, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f"{name}: cannot convert to a float64 array ({exc})") from exc
        if d.ndim == 0 or d.shape[-1] != self.n_tendons:
            raise InvalidInputError(
                f"{name}: expected last dimension {self.n_tendons} (tendons of robot {self.robot_name!r}), got shape {d.shape}"
            )
        if self._bounds is None:
            slack = LIMIT_SLACK * max(1.0, float(np.abs(self.limits).max()))
            self._bounds = (self.limits[:, 0] - slack, self.limits[:, 1] + slack)
        # one pass catches NaN (every comparison with NaN is False) and out-of-limit values
        if not ((d >= self._bounds[0]) & (d <= self._bounds[1])).all():
            as_array(d, name)  # raises for NaN / inf, naming the first
            lo, hi = self.limits[:, 0], self.limits[:, 1]
            bad = (d < self._bounds[0]) | (d > self._bounds[1])
            idx = tuple(int(i) for i in np.argwhere(bad)[0])
            j = idx[-1]
            raise InvalidInputError(
                f"{name}: value {d[idx]:.6g} at index {idx} is outside tendon {j}'s displacement limits [{lo[j]:.6g}, {hi[j]:.6g}]"
            )
        return d

    # ------------------------------------------------------------- predict
    def mixture(self, displacements: torch.Tensor) -> GaussianMixture:
        """Differentiable torch path (no input validation) from displacements to the mixture in
        metres.

        Parameters
        ----------
        displacements : torch.Tensor
            ``(..., m)`` tendon displacements [m].

        Returns
        -------
        GaussianMixture
            Batch shape ``(...)``, in the base frame, metres.
        """
        p = next(self.net.parameters())
        n = self.normalisation
        x = (
            displacements.to(p.dtype) - torch.as_tensor(n.input_mean, dtype=p.dtype)
        ) / torch.as_tensor(n.input_scale, dtype=p.dtype)
        log_w, mu, u = self.net(x)
        c = torch.as_tensor(n.output_centre, dtype=p.dtype)
        s = torch.as_tensor(n.output_scale, dtype=p.dtype)
        return GaussianMixture(torch.exp(log_w), c + s * mu, u / s, validate=False)

    def predict(self, displacements, dtype: torch.dtype = torch.float64) -> GaussianMixture:
        """Gaussian mixture of the robot's geometry for tendon displacements (MDN paper eq. 7).

        Evaluated with fused NumPy matrix products (in the network's precision, the softmax and
        eq. 2 in float64) rather than the torch module: for one configuration this avoids
        torch's per-operation overhead.

        Parameters
        ----------
        displacements : array_like
            ``(..., m)`` [m], within the robot's limits.
        dtype : torch.dtype
            Of the returned mixture.

        Returns
        -------
        GaussianMixture
            Batch shape ``(...)``, ``K`` components, ``d = 3``, base frame, metres.

        Raises
        ------
        InvalidInputError
            A wrong number of tendons, NaN/inf, or displacements outside the robot's limits.
        DataFormatError
            The weights predict NaN or inf (corrupted or unstable).
        """
        d = self.check_displacements(displacements)
        arrays = self._forward_numpy(d)
        if not all(np.isfinite(a).all() for a in arrays):
            from riskplan.errors import DataFormatError

            raise DataFormatError(
                f"model of robot {self.robot_name!r} predicts NaN or inf for these displacements (corrupted or unstable weights)"
            )
        w, mu, u = (torch.from_numpy(a) for a in arrays)
        if dtype != torch.float64:
            w, mu, u = w.to(dtype), mu.to(dtype), u.to(dtype)
        return GaussianMixture(w, mu, u, validate=False)

    def _forward_numpy(self, d: np.ndarray):
        if self._fast is None:
            self._fast = _FusedNumpyMDN(self.net, self.normalisation)
        return self._fast(d)


class _FusedNumpyMDN:
    """The MDN forward pass as a few NumPy products.

    Products and activations run in the network's own precision (a float32 network in
    float32, as its torch forward does); the softmax, eq. 2 and the scaling to metres in
    float64.

    The three heads read the same trunk output, so their first layers are stacked into
    one matrix and their later layers into block-diagonal matrices: one product per
    layer for all heads. Input normalisation is folded into the first layer and the
    output de-normalisation into the last, so a call is ``len(layers)`` products plus
    a softmax and the eq. 2 scatter.
    """

    def __init__(self, net: MDN, norm: Normalisation):
        import scipy.linalg

        def lin(layer):
            return (
                layer.weight.detach().double().numpy().T.copy(),
                layer.bias.detach().double().numpy().copy(),
            )

        trunk = [lin(m) for m in net.trunk if isinstance(m, nn.Linear)]
        # fold (x - mean) / scale into the first layer: W' = W / scale, b' = b - (mean/scale) W;
        # angle inputs (identity normalisation) enter as cos in place and sin appended
        self.angle_inputs = list(net.angle_inputs)
        n_a = len(self.angle_inputs)
        W0, b0 = trunk[0]
        scale = np.concatenate([norm.input_scale, np.ones(n_a)])
        mean = np.concatenate([norm.input_mean, np.zeros(n_a)])
        W0s = W0 / scale[:, None]
        trunk[0] = (W0s, b0 - (mean[:, None] * W0s).sum(0))
        heads = [
            [lin(m) for m in h if isinstance(m, nn.Linear)]
            for h in (net.weight_head, net.mean_head, net.chol_head)
        ]
        K, d = net.n_components, net.dim
        T = n_cholesky_entries(d)
        # de-normalise means in the last layer: mu = c + s * mu_n
        Wm, bm = heads[1][-1]
        s_rep = np.tile(norm.output_scale, K)
        heads[1][-1] = (Wm * s_rep[None, :], bm * s_rep + np.tile(norm.output_centre, K))
        # order the U head's outputs as [all diagonals | all off-diagonals] so eq. 2's exp acts on
        # one contiguous slice; `targets` scatters them into row-major (K, d, d) storage
        rows, cols = np.triu_indices(d)
        entries = [(k, n) for k in range(K) for n in range(T)]
        order = [i for i, (k, n) in enumerate(entries) if rows[n] == cols[n]] + [
            i for i, (k, n) in enumerate(entries) if rows[n] != cols[n]
        ]
        Wu, bu = heads[2][-1]
        heads[2][-1] = (Wu[:, order], bu[order])
        fused = []
        for i in range(len(heads[0])):
            Ws = [h[i][0] for h in heads]
            bs = [h[i][1] for h in heads]
            W = np.concatenate(Ws, axis=1) if i == 0 else scipy.linalg.block_diag(*Ws)
            fused.append((np.ascontiguousarray(W), np.concatenate(bs)))
        self.dtype = np.float32 if next(net.parameters()).dtype == torch.float32 else np.float64
        self.layers = [(W.astype(self.dtype), b.astype(self.dtype)) for W, b in trunk + fused]
        self.activation = net.activation
        self.K, self.d, self.T = K, d, T
        self.targets = np.array(
            [entries[i][0] * d * d + rows[entries[i][1]] * d + cols[entries[i][1]] for i in order]
        )
        # Ubar = Ubar_n diag(1/s): entry (i, j) scaled by 1/s_j
        self.col_scale = np.array([1.0 / norm.output_scale[cols[entries[i][1]]] for i in order])
        self.n_diag = K * d

    def _act(self, h):
        # in place: h is a fresh product owned by this call
        if self.activation == "silu":
            if h.shape[0] < _LARGE_BATCH:
                h *= _expit(h)  # fewest ufunc calls: cheapest for a few rows
                return h
            # sigmoid(x) = (1 + tanh(x/2)) / 2: several times faster than expit on large batches
            # (the two agree to rounding); neither overflows for any x
            t = np.multiply(h, 0.5)
            np.tanh(t, out=t)
            t *= 0.5
            t += 0.5
            h *= t
            return h
        if self.activation == "tanh":
            return np.tanh(h, out=h)
        return np.maximum(h, 0.0, out=h)

    def __call__(self, x: np.ndarray):
        batch = x.shape[:-1]
        if self.angle_inputs:
            ang = x[..., self.angle_inputs]
            x = np.concatenate([x, np.sin(ang)], axis=-1)
            x[..., self.angle_inputs] = np.cos(ang)
        h = x.reshape(-1, x.shape[-1]).astype(self.dtype)
        n_layers = len(self.layers)
        for i, (W, b) in enumerate(self.layers):
            h = h @ W
            h += b
            if i < n_layers - 1:
                h = self._act(h)
        h = h.astype(np.float64)  # a fresh float64 array owned here: edited in place below
        K, d = self.K, self.d
        B = h.shape[0]
        logits = h[:, :K]
        logits -= logits.max(-1, keepdims=True)
        w = np.exp(logits)
        w /= w.sum(-1, keepdims=True)
        mu = h[:, K : K + K * d]
        ur = h[:, K + K * d :]
        diag = ur[:, : self.n_diag]
        np.clip(diag, -LOG_DIAG_BOUND, LOG_DIAG_BOUND, out=diag)
        np.exp(diag, out=diag)  # eq. 2
        ur *= self.col_scale
        u = np.zeros((B, K * d * d))
        u[:, self.targets] = ur
        return w.reshape(*batch, K), mu.reshape(*batch, K, d), u.reshape(*batch, K, d, d)
