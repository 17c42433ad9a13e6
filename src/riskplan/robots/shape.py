"""What a robot solve returns (:class:`RodShape`), and the two small geometric maps of base
motion: the routing polynomials of a retracted robot (:func:`shift_polynomial`) and rotations
about the base axis (``rotation_z``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from riskplan.errors import InvalidInputError

__all__ = ["RodShape", "rotation_z", "shift_polynomial"]


@dataclass(frozen=True, eq=False)
class RodShape:
    """Robot shape(s) in the world frame (= base frame for the default base pose).

    Attributes
    ----------
    s : (n,) arc length of the stations [m], from the exposed base; ``(..., n)`` for a batch
        solved with per-configuration ``retraction`` (each exposed length has its own stations)
    positions : (..., n, 3) backbone points [m]
    rotations : (..., n, 3, 3) body frames; columns are the body axes (z = backbone tangent
        direction of the unsheared rod)
    tensions : (..., m) tendon tensions [N]
    """

    s: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray
    tensions: np.ndarray

    @property
    def tip(self) -> np.ndarray:
        """``(..., 3)`` tip position."""
        return self.positions[..., -1, :]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.tensions.shape[:-1]

    def __getitem__(self, idx) -> RodShape:
        if not self.batch_shape:
            raise InvalidInputError("RodShape: a single shape cannot be indexed")
        s = self.s if self.s.ndim == 1 else self.s[idx]
        return RodShape(s, self.positions[idx], self.rotations[idx], self.tensions[idx])

    def to_json(self) -> dict:
        """A single shape as JSON types.

        Returns
        -------
        dict
            ``tip`` (3 numbers, m), ``backbone`` (``n`` points of 3, m) and ``tensions``
            (``m`` numbers, N), as plain lists.
        """
        if self.batch_shape:
            raise InvalidInputError("to_json: expected a single shape; index the batch first")
        return {
            "tip": self.tip.tolist(),
            "backbone": self.positions.tolist(),
            "tensions": self.tensions.tolist(),
        }


def shift_polynomial(coefficients, offset: float) -> tuple[float, ...]:
    """Coefficients of ``q(x) = p(x + offset)`` for ``p(x) = sum_k c_k x^k`` (ascending powers).

    A retracted robot's routing ``theta(s)``, ``r(s)`` at absolute arc length ``s = s' + rho``
    is the same-degree polynomial of the exposed arc length ``s'``.

    Parameters
    ----------
    coefficients : sequence of float
        ``c_0, c_1, ...`` of ``p`` (ascending powers).
    offset : float
        The shift of the argument.

    Returns
    -------
    tuple of float
        The coefficients of ``q``, same length.
    """
    P = np.polynomial.Polynomial(np.asarray(coefficients, dtype=np.float64))
    q = P(np.polynomial.Polynomial([float(offset), 1.0])).coef
    out = np.zeros(len(coefficients))
    out[: len(q)] = q
    return tuple(float(v) for v in out)


def rotation_z(angle) -> np.ndarray:
    """``(..., 3, 3)`` rotations about z by ``angle (...)`` [rad] (right-handed).

    Parameters
    ----------
    angle : array_like
        Angles [rad], any shape.

    Returns
    -------
    numpy.ndarray
        ``(..., 3, 3)`` rotation matrices.
    """
    a = np.asarray(angle, dtype=np.float64)
    c, s_ = np.cos(a), np.sin(a)
    out = np.zeros(a.shape + (3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s_, s_, c
    out[..., 2, 2] = 1.0
    return out
