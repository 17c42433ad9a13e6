"""Compiled neo-Hookean kernels for P1 triangles: one pass over the elements for the
energy and internal forces, and one for the tangent written straight into the banded
layout that :class:`~riskplan.deformable.hyperelastic.HyperelasticModel` factorises.

They compute what the array path computes (``elements.deformation_gradients``,
``laws.neohookean_energy_and_stress``, ``assembly.element_forces``,
``assembly.neohookean_element_tangents`` and ``TangentPattern.banded``)
without its temporaries: per element ``F = I + Σ_a u_a ⊗ ∇N_a``, ``J = det F``,

    W = μ/2 (I₁ − 2 − 2 ln J) + λ/2 (ln J)²,   P = μ (F − F⁻ᵀ) + λ ln J F⁻ᵀ,
    f_{a,i} = A_e Σ_J P_iJ ∇N_aJ,
    K_{ai,bk} = A_e [μ δ_ik ∇N_a·∇N_b + λ h_ai h_bk + (μ − λ ln J) h_bi h_ak],  h_a = F⁻ᵀ ∇N_a.

The sums run in another order than NumPy's (``einsum``, ``matmul`` and the BLAS dot), so
results agree with the array path to rounding (a few ulp per element; tests/deformable
compare both), not bit for bit.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, inline="always")
def _gradient(u, tri, G, e):
    """``F = I + Σ_a u_a ⊗ ∇N_a`` of element ``e`` as ``(F00, F01, F10, F11)`` (both passes of
    :func:`neohookean_evaluate` use it)."""
    n0, n1, n2 = tri[e, 0], tri[e, 1], tri[e, 2]
    f00 = u[2 * n0] * G[e, 0, 0] + u[2 * n1] * G[e, 1, 0] + u[2 * n2] * G[e, 2, 0] + 1.0
    f01 = u[2 * n0] * G[e, 0, 1] + u[2 * n1] * G[e, 1, 1] + u[2 * n2] * G[e, 2, 1]
    f10 = u[2 * n0 + 1] * G[e, 0, 0] + u[2 * n1 + 1] * G[e, 1, 0] + u[2 * n2 + 1] * G[e, 2, 0]
    f11 = (
        u[2 * n0 + 1] * G[e, 0, 1] + u[2 * n1 + 1] * G[e, 1, 1] + u[2 * n2 + 1] * G[e, 2, 1]
    ) + 1.0
    return f00, f01, f10, f11


@nb.njit(cache=True)
def neohookean_evaluate(u, tri, G, areas, lam, mu, fint, Finv, lnJ, J):
    """Energy ``Σ_e A_e W(F_e)`` and internal forces of the neo-Hookean model.

    Parameters
    ----------
    u : (2N,) displacements, interleaved.
    tri : (T, 3) int64 triangles; ``G`` (T, 3, 2) shape gradients; ``areas`` (T,).
    lam, mu : Lamé parameters.
    fint : (2N,) output, internal forces (overwritten).
    Finv : (T, 2, 2) output, ``F⁻¹``; ``lnJ`` (T,) output, ``ln det F``; ``J`` (T,) output,
        ``det F``.

    Returns
    -------
    (float, bool)
        The energy and whether some ``det F ≤ 0`` (then ``J`` is filled for every element
        and the energy, ``fint``, ``Finv`` and ``lnJ`` are not meaningful).
    """
    T = tri.shape[0]
    inverted = False
    for e in range(T):
        f00, f01, f10, f11 = _gradient(u, tri, G, e)
        j = f00 * f11 - f01 * f10
        J[e] = j
        if j <= 0.0:
            inverted = True
            continue
        Finv[e, 0, 0] = f11 / j
        Finv[e, 1, 1] = f00 / j
        Finv[e, 0, 1] = -f01 / j
        Finv[e, 1, 0] = -f10 / j
    if inverted:
        return math.nan, True
    fint[:] = 0.0
    energy = 0.0
    for e in range(T):
        f00, f01, f10, f11 = _gradient(u, tri, G, e)
        l = math.log(J[e])
        lnJ[e] = l
        i1 = f00 * f00 + f01 * f01 + f10 * f10 + f11 * f11
        energy += areas[e] * (0.5 * mu * (i1 - 2.0 - 2.0 * l) + 0.5 * lam * l * l)
        # F⁻ᵀ entries: (F⁻ᵀ)_iJ = (F⁻¹)_Ji
        t00, t01, t10, t11 = Finv[e, 0, 0], Finv[e, 1, 0], Finv[e, 0, 1], Finv[e, 1, 1]
        c = lam * l
        p00 = mu * (f00 - t00) + c * t00
        p01 = mu * (f01 - t01) + c * t01
        p10 = mu * (f10 - t10) + c * t10
        p11 = mu * (f11 - t11) + c * t11
        a = areas[e]
        for k in range(3):
            n = tri[e, k]
            fint[2 * n] += a * (p00 * G[e, k, 0] + p01 * G[e, k, 1])
            fint[2 * n + 1] += a * (p10 * G[e, k, 0] + p11 * G[e, k, 1])
    return energy, False


@nb.njit(cache=True)
def neohookean_band(Finv, lnJ, G, areas, lam, mu, slot, out):
    """Neo-Hookean tangent accumulated into a banded (or any flat) layout.

    Parameters
    ----------
    Finv : (T, 2, 2) ``F⁻¹``; ``lnJ`` (T,); ``G`` (T, 3, 2); ``areas`` (T,); ``lam``, ``mu``.
    slot : (T, 36) int64, where element entry ``(e, (a,i)·6 + (b,k))`` goes in ``out``, ``-1``
        to drop it (a fixed DOF, or the lower triangle of the band).
    out : flat output (overwritten), e.g. the ``(bandwidth + 1) · n_free`` entries of the
        upper band in LAPACK's layout.
    """
    out[:] = 0.0
    T = G.shape[0]
    h = np.empty(6)
    for e in range(T):
        for a in range(3):
            g0, g1 = G[e, a, 0], G[e, a, 1]
            h[2 * a] = g0 * Finv[e, 0, 0] + g1 * Finv[e, 1, 0]
            h[2 * a + 1] = g0 * Finv[e, 0, 1] + g1 * Finv[e, 1, 1]
        c = mu - lam * lnJ[e]
        A = areas[e]
        for a in range(3):
            for i in range(2):
                r = 2 * a + i
                for b in range(3):
                    gg = G[e, a, 0] * G[e, b, 0] + G[e, a, 1] * G[e, b, 1]
                    for k in range(2):
                        s = slot[e, 6 * r + 2 * b + k]
                        if s < 0:
                            continue
                        v = lam * h[r] * h[2 * b + k] + c * h[2 * b + i] * h[2 * a + k]
                        if i == k:
                            v += mu * gg
                        out[s] += v * A


#: bandwidths above which LAPACK's blocked ``pbtrf`` factorises faster than
#: ``band_cholesky`` (measured on the manipulation's meshes, one core: 175 elements,
#: bandwidth 27: 0.08 ms against LAPACK's 0.12 ms with its wrapper; 500 elements, 51: 0.59 ms
#: against 0.32 ms; 1000 elements, 67: 1.74 ms against 0.95 ms)
LAPACK_BANDWIDTH = 40


def band_slots(pattern, n_elements: int, lapack: bool = False) -> np.ndarray:
    """``(T, 36)`` int64 map of ``TangentPattern``'s
    upper band (in its RCM order): the flat index of each element-matrix entry ``(i, j)``,
    ``i ≤ j``, in the row storage of ``band_cholesky`` (``i (kd + 1) + (j − i)``) or,
    with ``lapack``, in LAPACK's ``(kd + 1, n)`` upper storage (``(kd + i − j) n + j``);
    ``-1`` where the pattern drops the entry."""
    nf, kd = len(pattern.band_perm), pattern.bandwidth
    slot = np.full(n_elements * 36, -1, dtype=np.int64)
    if lapack:
        slot[pattern._band_sel] = pattern._band_slot
    else:
        flat = pattern._band_slot  # (kd + i − j) nf + j
        j = flat % nf
        i = flat // nf - kd + j
        slot[pattern._band_sel] = i * (kd + 1) + (j - i)
    return slot.reshape(n_elements, 36)


@nb.njit(cache=True)
def band_cholesky(R):
    """In-place banded Cholesky ``K = UᵀU`` in row storage: ``R[j, m] = K_{j, j+m}``
    (``0 ≤ m ≤ kd``, ``kd = R.shape[1] − 1``) becomes ``U_{j, j+m}``. The right-looking
    column sweep of LAPACK's unblocked ``pbtf2``, with each row of ``U`` contiguous (LAPACK's
    column storage strides the inner loop across the band).

    Returns
    -------
    int
        0, or ``j + 1`` when the leading minor of order ``j + 1`` is not positive definite
        (LAPACK's ``info``).
    """
    n, w = R.shape
    kd = w - 1
    for j in range(n):
        ajj = R[j, 0]
        if not ajj > 0.0:  # also nan
            return j + 1
        ajj = math.sqrt(ajj)
        R[j, 0] = ajj
        kn = min(kd, n - 1 - j)
        for m in range(1, kn + 1):
            R[j, m] /= ajj
        for m1 in range(1, kn + 1):
            v = R[j, m1]
            if v == 0.0:  # the band of an RCM-ordered FEM matrix is three quarters zeros
                continue
            for m2 in range(m1, kn + 1):
                R[j + m1, m2 - m1] -= v * R[j, m2]
    return 0


@nb.njit(cache=True)
def band_cholesky_solve(R, perm, r):
    """``x = K⁻¹ r`` from ``band_cholesky``'s factor ``R`` of ``K[perm][:, perm]``:
    ``Uᵀ y = r[perm]``, ``U z = y``, ``x[perm] = z``."""
    n, w = R.shape
    kd = w - 1
    y = np.empty(n)
    for j in range(n):
        s = r[perm[j]]
        for m in range(1, min(kd, j) + 1):
            s -= R[j - m, m] * y[j - m]
        y[j] = s / R[j, 0]
    for j in range(n - 1, -1, -1):
        s = y[j]
        for m in range(1, min(kd, n - 1 - j) + 1):
            s -= R[j, m] * y[j + m]
        y[j] = s / R[j, 0]
    x = np.empty(n)
    for j in range(n):
        x[perm[j]] = y[j]
    return x


@nb.njit(cache=True)
def scaled_norm(x):
    """Euclidean norm of ``x`` scaled by its largest magnitude first (no overflow for
    finite entries up to ``1e308``); ``nan`` or ``inf`` when an entry is."""
    m = 0.0
    for v in x:
        a = abs(v)
        if not a <= m:  # also nan
            m = a
    if m == 0.0 or not math.isfinite(m):
        return m
    s = 0.0
    for v in x:
        t = v / m
        s += t * t
    return m * math.sqrt(s)


class CompiledBandSolver:
    """``r -> K⁻¹ r`` from ``band_cholesky``'s factor ``R (n, kd + 1)`` of
    ``K[perm][:, perm]`` (picklable; the compiled twin of
    ``banded.BandedCholeskySolver``)."""

    def __init__(self, R: np.ndarray, perm: np.ndarray):
        self.cb = R
        self.perm = np.ascontiguousarray(perm, dtype=np.int64)

    def __call__(self, r: np.ndarray) -> np.ndarray:
        return band_cholesky_solve(self.cb, self.perm, np.ascontiguousarray(r, dtype=np.float64))
