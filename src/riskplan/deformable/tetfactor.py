"""Factorisation of the tetrahedral stiffness and the band of its inverse, for
:class:`riskplan.deformable.TetTissue`.

**Factorisation.** The reduced stiffness ``K_ff`` (free DOFs), permuted by reverse
Cuthill-McKee, is factorised as a banded Cholesky matrix ``K = Uᵀ U`` (LAPACK ``pbtrf``;
sparse LU for a neo-Hookean tangent that is not positive definite).

**Selected inversion** (Takahashi, Fagan & Chen 1973; Erisman & Tinney 1975). A point load
on one tetrahedron answers at that tetrahedron's own nodes through the 12 × 12 block of
``Z = K⁻¹`` over its DOFs. Every such block lies inside the band of ``K`` (the element's DOFs
are coupled in ``K``), and the band of ``Z`` follows from the factor alone: from ``U Z = U⁻ᵀ``
and ``U⁻ᵀ`` lower triangular with diagonal ``1 / u_ii``, for ``i ≤ j``::

    Z_ij = (δ_ij / u_ii − Σ_{k = i+1}^{i+b} u_ik Z_kj) / u_ii

taken for ``i = n−1, …, 0``, and for each ``i`` the off-diagonal ``j > i`` before ``j = i``.
Each row needs only ``Z`` inside the band, so the whole band costs ``O(n b²)`` flops, what the
factorisation costs, instead of ``n`` solves for the columns (``O(n² b)``).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from riskplan.deformable.banded import BandedCholeskySolver
from riskplan.errors import ConvergenceError, InvalidInputError

__all__ = [
    "SINGULAR_PIVOT_RATIO",
    "band_inverse",
    "element_band_index",
    "factor_reduced",
]

#: Least ratio of the smallest to the largest Cholesky pivot of a linear stiffness: below it
#: the matrix is singular up to round-off (1e-16 relative) and the supports are refused.
SINGULAR_PIVOT_RATIO = 1e-12


def factor_reduced(pattern, Ke_flat: np.ndarray, linear: bool = False):
    """Solver ``r -> K_ff⁻¹ r`` of the reduced matrix: banded Cholesky in RCM order.

    The linear stiffness is symmetric positive definite exactly when the supports hold
    every rigid motion: a failed Cholesky factorisation, or a pivot ratio
    ``min d / max d`` below :data:`SINGULAR_PIVOT_RATIO` (round-off of a singular
    matrix; a held body measures 0.06-0.08 at 750-5000 elements), is an
    :class:`~riskplan.errors.InvalidInputError` about the supports, never a fall-back to LU
    (which would answer a singular system with round-off). A neo-Hookean tangent may be
    indefinite away from rest: sparse LU then,
    :class:`~riskplan.errors.ConvergenceError` if that fails too.

    Parameters
    ----------
    pattern : TetPattern
        The sparsity and band layout of the mesh and supports.
    Ke_flat : numpy.ndarray, shape (T·144,)
        The element matrices, flat.
    linear : bool
        A linear stiffness (refuse singular matrices) rather than a Newton tangent.

    Returns
    -------
    callable
        A ``banded.BandedCholeskySolver`` (or an LU solve).
    """
    import scipy.linalg

    singular = InvalidInputError(
        "fixed_nodes, fixed_dofs: the stiffness is singular (the supports leave a rigid "
        "motion free, or some part of the mesh is not held)"
    )
    try:
        cb = scipy.linalg.cholesky_banded(pattern.banded(Ke_flat), lower=False, check_finite=False)
    except np.linalg.LinAlgError as exc:
        if linear:
            raise singular from exc
        from scipy.sparse.linalg import splu

        try:
            return splu(pattern.csc(Ke_flat)).solve
        except RuntimeError as exc2:
            raise ConvergenceError(f"Newton: singular tangent ({exc2})") from exc2
    d = cb[-1] ** 2
    if linear and not d.min() > SINGULAR_PIVOT_RATIO * d.max():
        raise singular
    return BandedCholeskySolver(cb, pattern.band_perm)


@nb.njit(cache=True)
def band_inverse(cb):
    """The band of ``Z = K⁻¹`` from the upper banded Cholesky factor of ``K`` (module
    docstring's recurrence).

    Parameters
    ----------
    cb : numpy.ndarray, shape (b + 1, n)
        LAPACK's upper band of ``U`` (``K = Uᵀ U``): ``U[i, j] = cb[b + i − j, j]``, ``i ≤ j``.

    Returns
    -------
    numpy.ndarray, shape (b + 1, n)
        ``Z`` in the same layout: ``Z[i, j] = out[b + i − j, j]`` for ``0 ≤ j − i ≤ b``.
    """
    b = cb.shape[0] - 1
    n = cb.shape[1]
    B = b + 1
    zb = np.zeros_like(cb)
    # the dense window Z[r, c], r, c in [i, i + b], at (r mod B, c mod B): row i needs Z
    # on rows and columns i+1 .. i+b only, which the window holds when row i is computed
    W = np.zeros((B, B))
    s = np.zeros(B)
    for i in range(n - 1, -1, -1):
        uii = cb[b, i]
        m = min(b, n - 1 - i)
        for t in range(m):
            s[t] = 0.0
        c0 = (i + 1) % B
        n1 = min(m, B - c0)
        for kk in range(1, m + 1):
            uik = cb[b - kk, i + kk]
            if uik == 0.0:
                continue
            row = (i + kk) % B
            for t in range(n1):  # s[t] += u_ik Z[k, i+1+t], in two contiguous runs
                s[t] += uik * W[row, c0 + t]
            for t in range(n1, m):
                s[t] += uik * W[row, t - n1]
        ri = i % B
        d = 0.0
        for t in range(m):
            j = i + 1 + t
            z = -s[t] / uii
            zb[b - 1 - t, j] = z
            W[ri, j % B] = z
            W[j % B, ri] = z
            d += cb[b - 1 - t, j] * z
        zii = (1.0 / uii - d) / uii
        zb[b, i] = zii
        W[ri, ri] = zii
    return zb


def element_band_index(
    element_dofs: np.ndarray, free_dofs: np.ndarray, n_dofs: int, perm: np.ndarray, bandwidth: int
) -> np.ndarray:
    """Where each element's 12 × 12 block of ``Z`` sits in the flat band of
    :func:`band_inverse` (``(b + 1) · n_free`` entries, then one zero for a fixed DOF).

    Parameters
    ----------
    element_dofs : numpy.ndarray, shape (T, 12)
        Each element's DOFs (interleaved, all DOFs).
    free_dofs : numpy.ndarray, shape (n_free,)
        The free DOFs (the reduced system's order before the permutation).
    n_dofs : int
        All DOFs, ``3 N``.
    perm : numpy.ndarray, shape (n_free,)
        The band order: reduced index ``perm[p]`` sits at position ``p``.
    bandwidth : int
        ``b``.

    Returns
    -------
    numpy.ndarray, shape (T, 12, 12)
        Flat indices; ``(b + 1) · n_free`` (the appended zero) where a DOF is fixed.

    Raises
    ------
    InvalidInputError
        An element's DOFs lie farther apart than the band (not the band of this mesh).
    """
    nf = len(free_dofs)
    pos_of_reduced = np.empty(nf, dtype=np.int64)
    pos_of_reduced[perm] = np.arange(nf)
    pos = np.full(n_dofs, -1, dtype=np.int64)
    pos[free_dofs] = pos_of_reduced
    p = pos[element_dofs]  # (T, 12)
    r, c = p[:, :, None], p[:, None, :]
    lo, hi = np.minimum(r, c), np.maximum(r, c)
    free = lo >= 0
    if np.any(hi[free] - lo[free] > bandwidth):
        raise InvalidInputError("element_dofs: an element's DOFs lie outside the band")
    return np.where(free, (bandwidth + lo - hi) * nf + hi, (bandwidth + 1) * nf)
