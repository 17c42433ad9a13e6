"""Small dense solves inside the Cosserat kernels: Gaussian elimination for the m x m
systems of the displacement solve, and Cholesky factor/solve of the 6 x 6 SPD Jacobian of the
local strain equations (fixed small sizes, no allocation)."""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, error_model="numpy", inline="always")
def gauss_solve(A, b, n, nrhs):
    """Solve ``A X = b`` in place (partial pivoting); ``A (n, n)``, ``b (n, nrhs)``. Returns False if singular."""
    for k in range(n):
        piv = k
        big = abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > big:
                big = abs(A[i, k])
                piv = i
        if big == 0.0:
            return False
        if piv != k:
            for j in range(n):
                tmp = A[k, j]
                A[k, j] = A[piv, j]
                A[piv, j] = tmp
            for j in range(nrhs):
                tmp = b[k, j]
                b[k, j] = b[piv, j]
                b[piv, j] = tmp
        inv = 1.0 / A[k, k]
        for i in range(k + 1, n):
            f = A[i, k] * inv
            if f != 0.0:
                for j in range(k + 1, n):
                    A[i, j] -= f * A[k, j]
                for j in range(nrhs):
                    b[i, j] -= f * b[k, j]
    for k in range(n - 1, -1, -1):
        for j in range(nrhs):
            acc = b[k, j]
            for i in range(k + 1, n):
                acc -= A[k, i] * b[i, j]
            b[k, j] = acc / A[k, k]
    return True


@njit(cache=True, error_model="numpy")
def chol_factor6(J):
    """Cholesky factor (lower, in place) of a symmetric positive definite ``J (6, 6)``.

    The local Jacobian is SPD: ``K + sum_i T_i^T A_i T_i`` with ``T_i = [I, -[r_i]x]`` and
    ``A_i`` positive semidefinite. Returns False if a pivot is not positive."""
    for j in range(6):
        d = J[j, j]
        for k in range(j):
            d -= J[j, k] * J[j, k]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        J[j, j] = d
        inv = 1.0 / d
        for i in range(j + 1, 6):
            acc = J[i, j]
            for k in range(j):
                acc -= J[i, k] * J[j, k]
            J[i, j] = acc * inv
    return True


@njit(cache=True, error_model="numpy")
def chol_solve6(L, b):
    """Solve ``L L^T x = b`` in place with the factor from :func:`chol_factor6`."""
    for i in range(6):
        acc = b[i]
        for k in range(i):
            acc -= L[i, k] * b[k]
        b[i] = acc / L[i, i]
    for i in range(5, -1, -1):
        acc = b[i]
        for k in range(i + 1, 6):
            acc -= L[k, i] * b[k]
        b[i] = acc / L[i, i]
