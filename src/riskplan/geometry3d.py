"""Convex bodies in 3-D for the 3-D needle: balls and boxes of material points, their images
under an affine map (ellipsoids and parallelepipeds), and the nearest point of such a body
to the origin after whitening (the construction of Patil, van den Berg & Alterovitz, ICRA
2012, in 3-D).

A body is ``{c + A s : s ∈ B}`` with ``B`` the unit ball of the 2-norm (``kind =
"ellipsoid"``) or of the ∞-norm (``kind = "box"``). For a Gaussian ``N(μ, Σ)`` with
``Σ = L Lᵀ`` the whitened body is ``{a + M s}`` with ``a = L⁻¹ (c − μ)``, ``M = L⁻¹ A``; its
nearest point ``y*`` to the origin gives the whitened distance ``d = |y*|`` and the
half-space ``nᵀ y ≤ d`` (``n = y*/d``) that holds the origin and no point of the body
(the body is convex and ``y*`` its nearest point).

Nearest points, exactly:

* ellipsoid: ``min |a + M s|²`` s.t. ``|s| ≤ 1`` (a trust-region subproblem). The
  unconstrained minimiser ``−M⁻¹ a`` inside the ball means the origin is inside; else
  ``s(λ) = −(MᵀM + λ I)⁻¹ Mᵀ a`` with ``|s(λ)| = 1``, ``λ > 0`` found by safeguarded Newton
  on ``1/|s(λ)| − 1`` (Moré & Sorensen 1983), in the eigenbasis of ``MᵀM``;
* box: ``min |a + M s|²`` s.t. ``|s_i| ≤ 1`` (a 3-variable bound-constrained least-squares
  problem): every one of the 27 active sets (each ``s_i`` free, −1 or +1) is solved and the
  best feasible candidate kept; the optimum's active set is among them.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from riskplan.errors import InvalidInputError

__all__ = ["KINDS", "ConvexBody", "nearest_to_origin"]

KINDS = ("ellipsoid", "box")


@dataclass(frozen=True, eq=False)
class ConvexBody:
    """``{centre + A s : s ∈ B}`` (module docstring); ``centre (3,)``, ``A (3, 3)`` invertible."""

    kind: str
    centre: np.ndarray
    A: np.ndarray

    def __post_init__(self):
        if self.kind not in KINDS:
            raise InvalidInputError(f"kind: expected one of {KINDS}, got {self.kind!r}")
        c = np.asarray(self.centre, dtype=np.float64).reshape(3)
        A = np.asarray(self.A, dtype=np.float64).reshape(3, 3)
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(A))):
            raise InvalidInputError("ConvexBody: centre and A must be finite")
        object.__setattr__(self, "centre", c)
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "_Ainv", np.linalg.inv(A))

    def local(self, points) -> np.ndarray:
        """``s = A⁻¹ (x − c)`` for points ``(..., 3)``.

        Parameters
        ----------
        points : array_like, shape (..., 3)
            Points in the body's frame of reference.

        Returns
        -------
        numpy.ndarray
            ``(..., 3)`` local coordinates ``s``.
        """
        return (np.asarray(points, dtype=np.float64) - self.centre) @ self._Ainv.T

    def norm(self, points) -> np.ndarray:
        """The body's gauge of each point ``(...)``: ``≤ 1`` inside (closed).

        Parameters
        ----------
        points : array_like, shape (..., 3)
            Points.

        Returns
        -------
        numpy.ndarray
            ``(...)``: ``|s|`` (ellipsoid) or ``max_i |s_i|`` (box).
        """
        s = self.local(points)
        if self.kind == "ellipsoid":
            return np.sqrt(np.einsum("...i,...i->...", s, s))
        return np.abs(s).max(axis=-1)

    def contains(self, points) -> np.ndarray:
        """Whether each point ``(..., 3)`` lies in the body (closed).

        Parameters
        ----------
        points : array_like, shape (..., 3)
            Points.

        Returns
        -------
        numpy.ndarray
            ``(...)`` bool.
        """
        return self.norm(points) <= 1.0

    def support_min(self, n, a=None, M=None) -> float:
        """``min_{s ∈ B} nᵀ (a + M s)`` (``a = centre``, ``M = A`` by default).

        Parameters
        ----------
        n : numpy.ndarray
            ``(3,)`` direction.
        a : numpy.ndarray, optional
            ``(3,)`` centre of the mapped body (default ``centre``).
        M : numpy.ndarray, optional
            ``(3, 3)`` map of the unit body (default ``A``).

        Returns
        -------
        float
            ``nᵀ a − |Mᵀ n|₂`` (ellipsoid) or ``nᵀ a − |Mᵀ n|₁`` (box).
        """
        a = self.centre if a is None else a
        M = self.A if M is None else M
        g = M.T @ n
        spread = float(np.linalg.norm(g)) if self.kind == "ellipsoid" else float(np.abs(g).sum())
        return float(n @ a) - spread

    def surface(self, n: int = 12) -> np.ndarray:
        """Points ``(k, 3)`` on the boundary (a latitude-longitude grid of the sphere or the
        cube mapped by ``A``), for figures.

        Parameters
        ----------
        n : int
            Latitude rows (``2 n`` longitudes).

        Returns
        -------
        numpy.ndarray
            ``(2 n², 3)`` boundary points.
        """
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 2 * n), np.linspace(0, np.pi, n))
        s = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1).reshape(-1, 3)
        if self.kind == "box":
            s = s / np.abs(s).max(axis=1, keepdims=True)
        return self.centre + s @ self.A.T


def _nearest_ellipsoid(a, M):
    Minv_a = np.linalg.solve(M, a)
    if float(Minv_a @ Minv_a) <= 1.0:
        return None
    w, V = np.linalg.eigh(M.T @ M)
    b = V.T @ (M.T @ a)

    def norm_s(lam):
        return math.sqrt(float(np.sum((b / (w + lam)) ** 2)))

    # Newton on φ(λ) = 1/|s(λ)| − 1 (concave, increasing), from λ = 0 (|s(0)| > 1)
    lam = 0.0
    for _ in range(200):
        ns = norm_s(lam)
        dns = -float(np.sum(b**2 / (w + lam) ** 3)) / ns  # d|s|/dλ
        phi = 1.0 / ns - 1.0
        dphi = -dns / (ns * ns)
        step = -phi / dphi
        lam = max(lam + step, 0.5 * lam)
        if abs(phi) < 1e-14:
            break
    s = -V @ (b / (w + lam))
    s /= np.linalg.norm(s)
    return a + M @ s


#: the box's faces, edges and vertices: (free coordinates, fixed ones, their sign patterns)
_BOX_PIECES = []
for _free in itertools.product((True, False), repeat=3):
    _F = np.array([i for i in range(3) if _free[i]], dtype=np.int64)
    _C = np.array([i for i in range(3) if not _free[i]], dtype=np.int64)
    _S = np.array(list(itertools.product((-1.0, 1.0), repeat=_C.size)), dtype=np.float64)
    _BOX_PIECES.append((_F, _C, _S.reshape(2**_C.size, _C.size)))


def _nearest_box(a, M):
    """The nearest point to the origin of ``{a + M s : |s|∞ ≤ 1}`` (``None`` inside): the
    least-squares point of every face, edge and vertex (the fixed coordinates at ±1, the
    free ones solved from the normal equations, kept where they stay in [−1, 1]), all sign
    patterns of one piece type at once; the nearest of them."""
    if np.all(np.abs(np.linalg.solve(M, -a)) <= 1.0):
        return None
    best, best_val = None, math.inf
    for F, C, signs in _BOX_PIECES:
        S = np.zeros((signs.shape[0], 3))
        S[:, C] = signs
        if F.size:
            MF = M[:, F]
            r = a + signs @ M[:, C].T
            sol = -np.linalg.solve(MF.T @ MF, MF.T @ r.T).T
            ok = np.all(np.abs(sol) <= 1.0 + 1e-12, axis=1)
            if not ok.any():
                continue
            S, sol = S[ok], sol[ok]
            S[:, F] = sol
        Y = a + S @ M.T
        v = np.einsum("ij,ij->i", Y, Y)
        k = int(np.argmin(v))
        if v[k] < best_val:
            best, best_val = Y[k], float(v[k])
    return best


def nearest_to_origin(body: ConvexBody, L: np.ndarray, mu: np.ndarray):
    """``(d, n)``: the whitened distance from ``N(mu, L Lᵀ)``'s mean to ``body`` and the unit
    normal ``n (3,)`` (whitened) of the separating half-space ``nᵀ y ≤ d``; ``(0.0, None)``
    when the mean lies in the body.

    Parameters
    ----------
    body : ConvexBody
        The body.
    L : numpy.ndarray
        ``(3, 3)`` Cholesky factor of the covariance.
    mu : numpy.ndarray
        ``(3,)`` mean.

    Returns
    -------
    d : float
        Whitened distance (0 inside the body).
    n : numpy.ndarray or None
        ``(3,)`` whitened unit normal, None inside.
    """
    a = np.linalg.solve(L, body.centre - mu)
    M = np.linalg.solve(L, body.A)
    y = _nearest_ellipsoid(a, M) if body.kind == "ellipsoid" else _nearest_box(a, M)
    if y is None:
        return 0.0, None
    d = float(np.linalg.norm(y))
    return d, y / d
