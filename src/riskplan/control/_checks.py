"""Boundary checks shared by the control modules (matrices per step, definiteness)."""

from __future__ import annotations

import numpy as np

from riskplan._validation import as_array
from riskplan.errors import InvalidInputError, NumericalError


def per_step(value, name: str, T: int, shape: tuple[int, int]) -> np.ndarray:
    """``value`` as a ``(T, *shape)`` array: a constant ``shape`` matrix is repeated for every step."""
    arr = as_array(value, name, min_ndim=2)
    if arr.shape == shape:
        return np.broadcast_to(arr, (T, *shape))
    if arr.shape != (T, *shape):
        raise InvalidInputError(f"{name}: expected shape {shape} or {(T, *shape)}, got {arr.shape}")
    return arr


def check_psd(mats: np.ndarray, name: str, *, definite: bool) -> None:
    """Raise unless every ``(..., n, n)`` matrix is symmetric positive (semi-)definite."""
    scale = max(1.0, float(np.abs(mats).max()) if mats.size else 1.0)
    if not np.allclose(mats, np.swapaxes(mats, -1, -2), rtol=1e-10, atol=1e-12 * scale):
        raise InvalidInputError(f"{name}: expected symmetric matrices")
    w = np.linalg.eigvalsh(0.5 * (mats + np.swapaxes(mats, -1, -2)))
    lo = float(w.min()) if w.size else 0.0
    if definite and lo <= 1e-12 * scale:
        raise InvalidInputError(
            f"{name}: expected positive definite matrices (smallest eigenvalue {lo:.3g})"
        )
    if not definite and lo < -1e-12 * scale:
        raise InvalidInputError(
            f"{name}: expected positive semi-definite matrices (smallest eigenvalue {lo:.3g})"
        )


def dynamics(A, B=None) -> tuple[np.ndarray, np.ndarray | None]:
    """``A (T, p, p)`` and ``B (T, p, q)`` checked against each other."""
    A = as_array(A, "A", min_ndim=3)
    if A.ndim != 3 or A.shape[1] != A.shape[2]:
        raise InvalidInputError(f"A: expected shape (T, p, p), got {A.shape}")
    if B is None:
        return A, None
    B = as_array(B, "B", min_ndim=3)
    if B.ndim != 3 or B.shape[:2] != A.shape[:2]:
        raise InvalidInputError(f"B: expected shape ({A.shape[0]}, {A.shape[1]}, q), got {B.shape}")
    return A, B


def raise_overflow(what: str, step: int, cause: Exception | None = None):
    """Raise :class:`NumericalError` for a recursion that left float64's range at ``step``."""
    raise NumericalError(
        f"{what} overflowed float64 at step {step} (non-finite gain or covariance); the "
        "matrices are finite but too large or too unstable over this horizon",
        step=step,
    ) from cause
