"""Hyperelastic material laws for the nonlinear FEM (paper V-B): stored energy ``W``,
first Piola-Kirchhoff stress ``P`` and tangent ``A = ∂P/∂F`` per element.

* compressible neo-Hookean (2-D):  W = μ/2 (I₁ − 2 − 2 ln J) + λ/2 (ln J)²,
  P = μ (F − F⁻ᵀ) + λ ln J F⁻ᵀ;
* St Venant-Kirchhoff:  E = ½(FᵀF − I),  W = μ E:E + λ/2 (tr E)²,  P = F (2 μ E + λ tr E I).

Both linearise at ``F = I`` to ``σ = λ tr(ε) I + 2 μ ε`` (the ``(λ, μ)`` of
``Material.lame``; see :mod:`riskplan.deformable.hyperelastic` for the plane-stress
choice). Pure array functions: ``F (T, 2, 2)`` in, ``W (T,)``, ``P (T, 2, 2)``,
``A (T, 2, 2, 2, 2)`` out.
"""

from __future__ import annotations

import numpy as np

from riskplan.deformable.elements import determinants_and_inverses


def neohookean_energy_and_stress(
    F: np.ndarray, Finv: np.ndarray, lnJ: np.ndarray, lam: float, mu: float
):
    """Neo-Hookean ``W (T,)`` and ``P (T, 2, 2)`` given ``F``, ``F⁻¹`` and ``ln J`` (the
    Newton solver has them already)."""
    FinvT = np.swapaxes(Finv, 1, 2)
    I1 = np.einsum("tij,tij->t", F, F)
    W = 0.5 * mu * (I1 - 2.0 - 2.0 * lnJ) + 0.5 * lam * lnJ**2
    P = mu * (F - FinvT) + (lam * lnJ)[:, None, None] * FinvT
    return W, P


def neohookean_energy_stress(F: np.ndarray, lam: float, mu: float, tangent: bool = True):
    """Energy density ``W (T,)``, stress ``P (T, 2, 2)`` and (optionally) the tangent
    ``A_iJkL = ∂P_iJ/∂F_kL`` ``(T, 2, 2, 2, 2)`` of the compressible neo-Hookean model.

    ``A = μ δ_ik δ_JL + λ F⁻¹_Ji F⁻¹_Lk + (μ − λ ln J) F⁻¹_Li F⁻¹_Jk``. Requires ``J > 0``.
    """
    J, Finv = determinants_and_inverses(F)
    lnJ = np.log(J)
    W, P = neohookean_energy_and_stress(F, Finv, lnJ, lam, mu)
    if not tangent:
        return W, P, None
    eye = np.eye(2)
    A = mu * np.einsum("ik,JL->iJkL", eye, eye)[None]
    A = A + lam * np.einsum("tJi,tLk->tiJkL", Finv, Finv)
    A = A + (mu - lam * lnJ)[:, None, None, None, None] * np.einsum("tLi,tJk->tiJkL", Finv, Finv)
    return W, P, A


def svk_energy_stress(F: np.ndarray, lam: float, mu: float, tangent: bool = True):
    """St Venant-Kirchhoff ``W``, ``P = F S`` with ``S = 2 μ E + λ tr(E) I`` and tangent
    ``A_iJkL = δ_ik S_JL + F_iI C_IJKL F_kK`` (``C = λ δ_IJ δ_KL + μ(δ_IK δ_JL + δ_IL δ_JK)``)."""
    eye = np.eye(2)
    E = 0.5 * (np.einsum("tki,tkj->tij", F, F) - eye)
    trE = E[:, 0, 0] + E[:, 1, 1]
    W = mu * np.einsum("tij,tij->t", E, E) + 0.5 * lam * trE**2
    S = 2.0 * mu * E + lam * trE[:, None, None] * eye
    P = F @ S
    if not tangent:
        return W, P, None
    A = np.einsum("ik,tJL->tiJkL", eye, S)
    A = A + lam * np.einsum("tiJ,tkL->tiJkL", F, F)
    A = A + mu * (np.einsum("tiL,tkJ->tiJkL", F, F) + np.einsum("tiI,tkI,JL->tiJkL", F, F, eye))
    return W, P, A


#: The laws by name (``HyperelasticModel(law=...)``).
LAWS = {"neohookean": neohookean_energy_stress, "svk": svk_energy_stress}
