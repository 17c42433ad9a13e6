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


# ----------------------------------------------------------------------------------------
# The same factor and solve unrolled, on one column of a structure-of-arrays work array
# ``W (rows, chunk)`` holding the packed lower triangle (21 entries, row by row), for the
# lockstep kernel of ``riskplan.robots.batch_kernel``: written out, LLVM keeps the 21 entries
# in registers and vectorises across the chunk. Compiled inline; the operations and their order
# are those of the loops above, so results agree with them bit for bit.


@njit(cache=True, error_model="numpy", inline="always")
def packed_load(W, row, c):
    """The 21 entries ``W[row : row + 21, c]`` of a packed lower triangle, as a tuple."""
    return (
        W[row + 0, c], W[row + 1, c], W[row + 2, c], W[row + 3, c], W[row + 4, c],
        W[row + 5, c], W[row + 6, c], W[row + 7, c], W[row + 8, c], W[row + 9, c],
        W[row + 10, c], W[row + 11, c], W[row + 12, c], W[row + 13, c], W[row + 14, c],
        W[row + 15, c], W[row + 16, c], W[row + 17, c], W[row + 18, c], W[row + 19, c],
        W[row + 20, c],
    )  # fmt: skip


@njit(cache=True, error_model="numpy", inline="always")
def packed_store(W, row, c, store, L):
    """``W[row : row + 21, c] = L`` (a 21-tuple) when ``store``; otherwise left as it is."""
    W[row + 0, c] = L[0] if store else W[row + 0, c]
    W[row + 1, c] = L[1] if store else W[row + 1, c]
    W[row + 2, c] = L[2] if store else W[row + 2, c]
    W[row + 3, c] = L[3] if store else W[row + 3, c]
    W[row + 4, c] = L[4] if store else W[row + 4, c]
    W[row + 5, c] = L[5] if store else W[row + 5, c]
    W[row + 6, c] = L[6] if store else W[row + 6, c]
    W[row + 7, c] = L[7] if store else W[row + 7, c]
    W[row + 8, c] = L[8] if store else W[row + 8, c]
    W[row + 9, c] = L[9] if store else W[row + 9, c]
    W[row + 10, c] = L[10] if store else W[row + 10, c]
    W[row + 11, c] = L[11] if store else W[row + 11, c]
    W[row + 12, c] = L[12] if store else W[row + 12, c]
    W[row + 13, c] = L[13] if store else W[row + 13, c]
    W[row + 14, c] = L[14] if store else W[row + 14, c]
    W[row + 15, c] = L[15] if store else W[row + 15, c]
    W[row + 16, c] = L[16] if store else W[row + 16, c]
    W[row + 17, c] = L[17] if store else W[row + 17, c]
    W[row + 18, c] = L[18] if store else W[row + 18, c]
    W[row + 19, c] = L[19] if store else W[row + 19, c]
    W[row + 20, c] = L[20] if store else W[row + 20, c]


@njit(cache=True, error_model="numpy", inline="always")
def packed_chol_factor6(W, c, src, dst, store):
    """Cholesky factor (``chol_factor6``'s operations, unrolled) of the packed 6x6 matrix
    ``W[src : src + 21, c]``, written to ``W[dst : dst + 21, c]`` when ``store``. Returns True
    if a pivot was not positive."""
    j00, j10, j11, j20, j21, j22, j30, j31, j32, j33, j40, \
        j41, j42, j43, j44, j50, j51, j52, j53, j54, j55 = packed_load(W, src, c)  # fmt: skip
    bad = False
    d = j00
    bad = bad | (not d > 0.0)
    d = math.sqrt(d)
    j00 = d
    inv = 1.0 / d
    acc = j10
    j10 = acc * inv
    acc = j20
    j20 = acc * inv
    acc = j30
    j30 = acc * inv
    acc = j40
    j40 = acc * inv
    acc = j50
    j50 = acc * inv
    d = j11
    d -= j10 * j10
    bad = bad | (not d > 0.0)
    d = math.sqrt(d)
    j11 = d
    inv = 1.0 / d
    acc = j21
    acc -= j20 * j10
    j21 = acc * inv
    acc = j31
    acc -= j30 * j10
    j31 = acc * inv
    acc = j41
    acc -= j40 * j10
    j41 = acc * inv
    acc = j51
    acc -= j50 * j10
    j51 = acc * inv
    d = j22
    d -= j20 * j20
    d -= j21 * j21
    bad = bad | (not d > 0.0)
    d = math.sqrt(d)
    j22 = d
    inv = 1.0 / d
    acc = j32
    acc -= j30 * j20
    acc -= j31 * j21
    j32 = acc * inv
    acc = j42
    acc -= j40 * j20
    acc -= j41 * j21
    j42 = acc * inv
    acc = j52
    acc -= j50 * j20
    acc -= j51 * j21
    j52 = acc * inv
    d = j33
    d -= j30 * j30
    d -= j31 * j31
    d -= j32 * j32
    bad = bad | (not d > 0.0)
    d = math.sqrt(d)
    j33 = d
    inv = 1.0 / d
    acc = j43
    acc -= j40 * j30
    acc -= j41 * j31
    acc -= j42 * j32
    j43 = acc * inv
    acc = j53
    acc -= j50 * j30
    acc -= j51 * j31
    acc -= j52 * j32
    j53 = acc * inv
    d = j44
    d -= j40 * j40
    d -= j41 * j41
    d -= j42 * j42
    d -= j43 * j43
    bad = bad | (not d > 0.0)
    d = math.sqrt(d)
    j44 = d
    inv = 1.0 / d
    acc = j54
    acc -= j50 * j40
    acc -= j51 * j41
    acc -= j52 * j42
    acc -= j53 * j43
    j54 = acc * inv
    d = j55
    d -= j50 * j50
    d -= j51 * j51
    d -= j52 * j52
    d -= j53 * j53
    d -= j54 * j54
    bad = bad | (not d > 0.0)
    d = math.sqrt(d)
    j55 = d
    inv = 1.0 / d
    packed_store(
        W, dst, c, store,
        (j00, j10, j11, j20, j21, j22, j30, j31, j32, j33, j40,
         j41, j42, j43, j44, j50, j51, j52, j53, j54, j55),
    )  # fmt: skip
    return bad


@njit(cache=True, error_model="numpy", inline="always")
def packed_chol_solve6(W, c, row, b0, b1, b2, b3, b4, b5):
    """``L L^T x = b`` (``chol_solve6``'s operations, unrolled) with the packed factor
    ``W[row : row + 21, c]``; returns ``x`` as a 6-tuple."""
    l00, l10, l11, l20, l21, l22, l30, l31, l32, l33, l40, \
        l41, l42, l43, l44, l50, l51, l52, l53, l54, l55 = packed_load(W, row, c)  # fmt: skip
    acc = b0
    b0 = acc / l00
    acc = b1
    acc -= l10 * b0
    b1 = acc / l11
    acc = b2
    acc -= l20 * b0
    acc -= l21 * b1
    b2 = acc / l22
    acc = b3
    acc -= l30 * b0
    acc -= l31 * b1
    acc -= l32 * b2
    b3 = acc / l33
    acc = b4
    acc -= l40 * b0
    acc -= l41 * b1
    acc -= l42 * b2
    acc -= l43 * b3
    b4 = acc / l44
    acc = b5
    acc -= l50 * b0
    acc -= l51 * b1
    acc -= l52 * b2
    acc -= l53 * b3
    acc -= l54 * b4
    b5 = acc / l55
    acc = b5
    b5 = acc / l55
    acc = b4
    acc -= l54 * b5
    b4 = acc / l44
    acc = b3
    acc -= l43 * b4
    acc -= l53 * b5
    b3 = acc / l33
    acc = b2
    acc -= l32 * b3
    acc -= l42 * b4
    acc -= l52 * b5
    b2 = acc / l22
    acc = b1
    acc -= l21 * b2
    acc -= l31 * b3
    acc -= l41 * b4
    acc -= l51 * b5
    b1 = acc / l11
    acc = b0
    acc -= l10 * b1
    acc -= l20 * b2
    acc -= l30 * b3
    acc -= l40 * b4
    acc -= l50 * b5
    b0 = acc / l00
    return b0, b1, b2, b3, b4, b5
