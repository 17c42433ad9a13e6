r"""The exact goal test of the 3-D LQG-MP: the probability that a Gaussian point lies in an
ellipsoid, by quadrature instead of draws.

For ``x ~ N(m, S)`` and the ellipsoid ``E = {c + A s : |s| ≤ 1}``
(:class:`~riskplan.geometry3d.ConvexBody` of kind ``"ellipsoid"``), ``y = A⁻¹ (x − c)`` is
``N(a, C)`` with ``a = A⁻¹ (m − c)``, ``C = A⁻¹ S A⁻ᵀ``, and ``x ∈ E`` iff ``|y|² ≤ 1``. In the
eigenbasis of ``C = V diag(λ) Vᵀ`` (``λ₁ ≥ λ₂ ≥ λ₃ ≥ 0``, ``b = Vᵀ a``) the coordinates are
independent, ``y_i = b_i + σ_i z_i`` with ``σ_i = √λ_i``: ``|y|²`` is a generalised
(non-central) χ², ``Σ λ_i (z_i + b_i/σ_i)²``, and

.. math::

    P(x \in E) = \int\!\!\int \varphi(z_3)\, \varphi(z_2)
        \left[\Phi\!\left(\frac{r - b_1}{\sigma_1}\right)
            - \Phi\!\left(\frac{-r - b_1}{\sigma_1}\right)\right] dz_2\, dz_3,
    \qquad r = \sqrt{1 - y_2^2 - y_3^2},

the largest-variance coordinate integrated in closed form (the chord of the unit ball at
``(y₂, y₃)``), the two others by adaptive Gauss–Kronrod quadrature
(:func:`scipy.integrate.quad`) over ``|z| ≤ 8.5`` cut to the ball's extent (the chord's
square-root onset lands on an end of each interval, where the quadrature's extrapolation
handles it). A coordinate whose ``σ`` is zero is a point, not an integral, so a degenerate
``S`` (rank 1 or 2: the force case's tip spread) needs nothing special, and a near-singular
one only narrows a window in ``y``, not in ``z``.

Why not the characteristic-function inversion (Imhof 1961, the integral
``½ − π⁻¹ ∫₀^∞ sin θ(u) / (u ρ(u)) du``) or Davies' algorithm (1980; ``chi2comb`` on PyPI
wraps its C code, one release, 2020): both oscillate, and their integrands decay like
``u^{−1−k/2}`` for ``k`` non-degenerate terms, so a rank-1 or near-singular covariance, or
a spread much smaller than the body, needs truncation points of ``10¹⁰`` and more (Davies'
non-centralities ``b_i²/λ_i`` grow without bound as ``λ_i → 0``). In three dimensions the
conditional form above costs a few thousand scalar evaluations (about 10 ms) and has no
such case; a dependency for it is not worth its build.

Error: the quadratures' own estimates (outer ``abserr`` plus the worst inner one, each
requested below ``tol``) plus the Gaussian mass beyond ``|z| = 8.5`` in the two integrated
coordinates (``4 Φ(−8.5) ≈ 4·10⁻¹⁷``). Where a χ² bound already settles it — ``|a| < 1`` and ``P(|y − a| ≥ 1 − |a|) ≤ P(λ₁ χ²₃ ≥ (1 − |a|)²) ≤ tol``
(or ``|a| > 1`` and the same with ``|a| − 1``) — the answer is ``1`` (or ``0``) with that
bound as its error, without quadrature.

Parallelepipeds (kind ``"box"``) have no exact test here (no goal of the 3-D needle is one);
:func:`riskplan.control.lqgmp3d.lqgmp_3d` keeps the draws for them.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.integrate import quad
from scipy.special import ndtr
from scipy.stats import chi2

from riskplan.errors import InvalidInputError

__all__ = ["DEFAULT_TOL", "gaussian_in_ellipsoid"]

#: absolute error requested of the quadrature (the stage's draws had a standard error of
#: 3·10⁻⁴; this is far below anything a Wilson interval of 10⁴ executions resolves)
DEFAULT_TOL = 1e-9

#: the integrated coordinates' window, ``|z| ≤ 8.5`` (mass outside: 2 Φ(−8.5) ≈ 1.9·10⁻¹⁷)
_Z = 8.5
_OUT = 2.0 * float(ndtr(-_Z))
_INV_SQRT2PI = 1.0 / math.sqrt(2.0 * math.pi)
_R2 = 1.0 / math.sqrt(2.0)
#: Gauss–Legendre points per angle of the product rule (and twice as many for its check)
_N = 48


def _phi(z: float) -> float:
    return _INV_SQRT2PI * math.exp(-0.5 * z * z)


def _chord(b1: float, s1: float, rr: float) -> float:
    """``P(|b₁ + s₁ z| ≤ √rr)`` for ``z ~ N(0, 1)`` (0 for ``rr ≤ 0``)."""
    if rr <= 0.0:
        return 0.0
    r = math.sqrt(rr)
    hi, lo = (r - b1) / s1, (-r - b1) / s1
    # the difference of the two tails on the side where they are small (no cancellation);
    # Φ(x) = erfc(−x/√2)/2 through math (a scalar ufunc call costs ten times as much)
    if lo > 0.0:
        return 0.5 * (math.erfc(lo * _R2) - math.erfc(hi * _R2))
    if hi < 0.0:
        return 0.5 * (math.erfc(-hi * _R2) - math.erfc(-lo * _R2))
    return 1.0 - 0.5 * (math.erfc(-lo * _R2) + math.erfc(hi * _R2))


def _window(b: float, s: float, half: float) -> tuple[float, float] | None:
    """The ``z`` interval of ``|b + s z| ≤ half`` within ``|z| ≤ _Z`` (``s > 0``), or
    ``None`` if empty."""
    lo, hi = max(-_Z, (-half - b) / s), min(_Z, (half - b) / s)
    return (lo, hi) if hi > lo else None


def _check(body, mean, cov):
    from riskplan.geometry3d import ConvexBody

    if not isinstance(body, ConvexBody) or body.kind != "ellipsoid":
        raise InvalidInputError("body: expected a ConvexBody of kind 'ellipsoid'")
    m = np.asarray(mean, dtype=np.float64)
    S = np.asarray(cov, dtype=np.float64)
    if m.shape != (3,) or S.shape != (3, 3):
        raise InvalidInputError(
            f"mean, cov: expected shapes (3,), (3, 3), got {m.shape}, {S.shape}"
        )
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(S))):
        raise InvalidInputError("mean, cov: expected finite values")
    scale = max(float(np.abs(S).max()), 1e-300)
    if not np.allclose(S, S.T, rtol=0.0, atol=1e-10 * scale):
        raise InvalidInputError("cov: expected a symmetric matrix")
    return m, 0.5 * (S + S.T)


def _coordinates(body, m: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(b, σ)``: the mean and standard deviations of ``y = A⁻¹ (x − c)`` in the
    eigenbasis of its covariance, ``σ₁ ≥ σ₂ ≥ σ₃``; variances below ``1e-14`` of the largest
    (round-off of a singular ``S``) are set to zero."""
    Ainv = np.linalg.inv(body.A)
    C = Ainv @ S @ Ainv.T
    lam, V = np.linalg.eigh(0.5 * (C + C.T))
    lam, V = lam[::-1], V[:, ::-1]
    top = max(float(lam[0]), 0.0)
    if lam[-1] < -1e-10 * top:
        raise InvalidInputError("cov: expected a positive semi-definite matrix")
    lam = np.where(lam > 1e-14 * top, lam, 0.0)
    return V.T @ (Ainv @ (m - body.centre)), np.sqrt(lam)


def gaussian_in_ellipsoid(body, mean, cov, *, tol: float = DEFAULT_TOL) -> tuple[float, float]:
    """``P(x ∈ body)`` for ``x ~ N(mean, cov)`` and an ellipsoid ``body`` (module docstring).

    Parameters
    ----------
    body : ConvexBody
        An ellipsoid ``{c + A s : |s| ≤ 1}`` (kind ``"ellipsoid"``).
    mean : array_like, shape (3,)
        ``m``.
    cov : array_like, shape (3, 3)
        ``S``, symmetric positive semi-definite (eigenvalues below ``1e-14`` of the largest,
        round-off of a singular matrix, count as zero; negative ones beyond that are an
        error).
    tol : float
        Absolute error requested of each quadrature (> 0).

    Returns
    -------
    tuple of float
        ``(p, err)``: the probability and a bound on its error (the quadratures' error
        estimates plus the Gaussian mass outside the integration windows, or the χ² bound
        where that settles it; 0 for a point mass).
    """
    if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
        raise InvalidInputError(f"tol: expected a finite number > 0, got {tol!r}")
    b, s = _coordinates(body, *_check(body, mean, cov))
    d, top = float(np.linalg.norm(b)), float(s[0]) ** 2
    if top == 0.0:
        return float(d * d <= 1.0), 0.0
    # the χ² bound: |y − a|² = Σ λ_i z_i² ≤ λ₁ χ²₃
    bound = float(chi2.sf((1.0 - d) ** 2 / top, 3))
    if bound <= tol:
        return (1.0 if d < 1.0 else 0.0), bound
    coarse, fine = _tensor(b, s, _N), _tensor(b, s, 2 * _N)
    if abs(fine - coarse) <= tol:
        return min(max(fine, 0.0), 1.0), abs(fine - coarse) + 2.0 * _OUT
    return _adaptive(b, s, tol)


@functools.lru_cache(maxsize=8)
def _leggauss(n: int):
    return np.polynomial.legendre.leggauss(n)


def _gl_window(lo: np.ndarray, hi: np.ndarray, n: int):
    """Gauss–Legendre nodes and weights of ``n`` points on each interval ``[lo, hi]``
    (arrays of one shape ``(...)``): ``(x (..., n), w (..., n))``."""
    t, w = _leggauss(n)
    half = 0.5 * (hi - lo)[..., None]
    return 0.5 * (hi + lo)[..., None] + half * t, half * w


def _chords(b1: float, s1: float, r: np.ndarray) -> np.ndarray:
    """:func:`_chord` on an array of half-chords ``r ≥ 0`` (``s1 > 0``)."""
    hi, lo = (r - b1) / s1, (-r - b1) / s1
    out = 1.0 - ndtr(lo) - ndtr(-hi)
    left, right = lo > 0.0, hi < 0.0
    out[left] = ndtr(-lo[left]) - ndtr(-hi[left])
    out[right] = ndtr(hi[right]) - ndtr(lo[right])
    return out


def _angles(b: float, s: float, radius):
    """The angle window ``[asin(max(−1, (b − 8.5 s)/ρ)), asin(min(1, (b + 8.5 s)/ρ))]`` of
    ``y = ρ sin θ`` for ``y`` within ``8.5 s`` of ``b`` and in ``[−ρ, ρ]``."""
    lo = np.clip((b - _Z * s) / radius, -1.0, 1.0)
    hi = np.clip((b + _Z * s) / radius, -1.0, 1.0)
    return np.arcsin(lo), np.arcsin(hi)


def _tensor(b: np.ndarray, s: np.ndarray, n: int) -> float:
    """The integral of the module docstring by an ``n × n`` Gauss–Legendre product rule in
    the angles ``y₃ = sin ψ``, ``y₂ = cos ψ sin θ`` (the half-chord is ``cos ψ cos θ``: the
    ball's edge, a square-root onset in ``y``, is smooth in the angles), each over the
    window of its coordinate's ``8.5 σ``; a coordinate with ``σ = 0`` is a point."""
    b1, b2, b3 = (float(v) for v in b)
    s1, s2, s3 = (float(v) for v in s)
    if s3 == 0.0:
        if abs(b3) >= 1.0:
            return 0.0
        psi, wpsi = np.array([[math.asin(b3)]]), np.ones((1, 1))
    else:
        lo, hi = _angles(b3, s3, 1.0)
        if hi <= lo:
            return 0.0
        psi, wpsi = _gl_window(np.asarray(lo), np.asarray(hi), n)
        z3 = (np.sin(psi) - b3) / s3
        wpsi = wpsi * _INV_SQRT2PI * np.exp(-0.5 * z3 * z3) * np.cos(psi) / s3
    psi, wpsi = psi.reshape(-1), wpsi.reshape(-1)
    rho = np.cos(psi)  # the disc's radius at y₃
    if s2 == 0.0:
        inside = np.abs(b2) < rho
        r = np.sqrt(np.maximum(rho * rho - b2 * b2, 0.0))
        return float(np.sum(wpsi * np.where(inside, _chords(b1, s1, r), 0.0)))
    lo, hi = _angles(b2, s2, np.maximum(rho, 1e-300))
    th, wth = _gl_window(lo, hi, n)  # (n_psi, n)
    y2 = rho[:, None] * np.sin(th)
    wth = wth * np.exp(-0.5 * ((y2 - b2) / s2) ** 2) * rho[:, None] * np.cos(th) / s2
    inner = np.sum(wth * _chords(b1, s1, rho[:, None] * np.cos(th)), axis=1) * _INV_SQRT2PI
    return float(np.sum(wpsi * inner))


def _adaptive(b: np.ndarray, s: np.ndarray, tol: float) -> tuple[float, float]:
    """The same integral by nested adaptive quadrature (:func:`scipy.integrate.quad`) in
    ``z``, where the product rule's two sizes disagree by more than ``tol``."""
    b1, b2, b3 = (float(v) for v in b)
    s1, s2, s3 = (float(v) for v in s)
    worst = [0.0]

    def middle(y3: float) -> float:
        w2 = 1.0 - y3 * y3
        if s2 == 0.0:
            return _chord(b1, s1, w2 - b2 * b2)
        win = _window(b2, s2, math.sqrt(max(w2, 0.0)))
        if win is None:
            return 0.0
        val, err = quad(
            lambda z: _phi(z) * _chord(b1, s1, w2 - (b2 + s2 * z) ** 2),
            *win,
            epsabs=0.25 * tol,
            epsrel=0.0,
            limit=200,
        )
        worst[0] = max(worst[0], err)
        return val

    if s3 == 0.0:
        return middle(b3), worst[0] + (_OUT if s2 > 0.0 else 0.0)
    win = _window(b3, s3, 1.0)
    if win is None:
        return 0.0, _OUT
    p, err = quad(
        lambda z: _phi(z) * middle(b3 + s3 * z), *win, epsabs=0.5 * tol, epsrel=0.0, limit=200
    )
    return min(max(p, 0.0), 1.0), err + worst[0] + 2.0 * _OUT
