"""Sparse symmetric positive definite solves for the FEM models: reverse Cuthill-McKee
ordering and LAPACK banded Cholesky (``pbtrf``/``pbtrs``), which beat SuperLU on the
narrow-band 2-D stiffness matrices of a few thousand DOFs."""

from __future__ import annotations

import numpy as np


def band_layout(pattern, r: np.ndarray, c: np.ndarray, nf: int):
    """Reverse Cuthill-McKee order of a symmetric sparsity ``pattern`` ``(nf, nf)`` and where
    its entries ``(r, c)`` go in LAPACK's upper band layout.

    Returns
    -------
    perm : numpy.ndarray
        ``(nf,)`` the order.
    bandwidth : int
        Of ``pattern[perm][:, perm]``.
    upper : numpy.ndarray
        ``(len(r),)`` bool: the entries on or above the diagonal after the permutation.
    slot : numpy.ndarray
        Their index in the flat ``(bandwidth + 1) * nf`` band (row ``bandwidth + i - j`` of
        column ``j``).
    """
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    perm = reverse_cuthill_mckee(pattern.tocsr(), symmetric_mode=True)
    pos = np.empty(nf, dtype=np.int64)
    pos[perm] = np.arange(nf)
    pr, pc = pos[r], pos[c]
    upper = pr <= pc
    bw = int(np.max(pc[upper] - pr[upper])) if np.any(upper) else 0
    return perm, bw, upper, (bw + pr[upper] - pc[upper]) * nf + pc[upper]


def cached_layout(cache, build, cells: np.ndarray, free_dofs: np.ndarray, n_dofs: int, limit: int):
    """``build(cells, free_dofs, n_dofs)`` (a model's sparsity and band layout) looked up in
    the least-recently-used ``cache`` (an ``OrderedDict`` of at most ``limit`` layouts), keyed
    by the cells and free DOFs: models of one mesh with different materials share one."""
    key = (cells.shape, cells.tobytes(), free_dofs.tobytes(), int(n_dofs))
    layout = cache.get(key)
    if layout is None:
        layout = cache[key] = build(cells, free_dofs, n_dofs)
        if len(cache) > limit:
            cache.popitem(last=False)
    else:
        cache.move_to_end(key)
    return layout


class BandedCholeskySolver:
    """``r -> K⁻¹ r`` from the upper banded Cholesky factor ``cb`` of ``K[perm][:, perm]``
    (LAPACK ``pbtrs`` called directly: the wrapper's checks cost more than the solve at
    these sizes). Picklable (the LAPACK handle is looked up again after unpickling)."""

    def __init__(self, cb: np.ndarray, perm: np.ndarray):
        self.cb = cb
        self.perm = perm
        self._pbtrs = None

    def __getstate__(self):
        return {"cb": self.cb, "perm": self.perm}

    def __setstate__(self, state):
        self.__init__(state["cb"], state["perm"])

    def __call__(self, r: np.ndarray) -> np.ndarray:
        if self._pbtrs is None:
            from scipy.linalg import get_lapack_funcs

            (self._pbtrs,) = get_lapack_funcs(("pbtrs",), (self.cb,))
        x, info = self._pbtrs(self.cb, r[self.perm], lower=0)
        if info != 0:  # pragma: no cover - only for malformed arguments
            raise RuntimeError(f"pbtrs failed with info={info}")
        out = np.empty_like(x)
        out[self.perm] = x
        return out


def banded_cholesky(K):
    """Reverse Cuthill-McKee ordering + banded Cholesky of a sparse SPD matrix ``K``;
    returns a :class:`BandedCholeskySolver` ``solve(r)``. Raises
    ``numpy.linalg.LinAlgError`` if ``K`` is not positive definite."""
    import scipy.linalg
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    K = K.tocsr()
    perm = reverse_cuthill_mckee(K, symmetric_mode=True)
    Kp = K[perm][:, perm].tocoo()
    upper = Kp.row <= Kp.col
    bw = int(np.max(Kp.col[upper] - Kp.row[upper]))
    ab = np.zeros((bw + 1, K.shape[0]))
    ab[bw + Kp.row[upper] - Kp.col[upper], Kp.col[upper]] = Kp.data[upper]
    cb = scipy.linalg.cholesky_banded(ab, lower=False)
    return BandedCholeskySolver(cb, perm)
