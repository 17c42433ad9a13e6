"""Compiled geometry kernels for the collision estimators (numba, ``cache=True``).

Callers validate; these functions trust shapes and dtypes. Conventions:

* ``V (nv, d)`` float64 vertices, ``F (nf, d)`` int64 faces: triangles in 3-D, segments in 2-D
  (a face has ``d`` vertices, so one code path serves both dimensions).
* Whitened coordinates ``y = U (x - mu)`` (MDN paper eq. 8): the Gaussian becomes N(0, I).
* Planar queries (2-D winding numbers, segment tests, closest points on edges) and the
  boundary convention they follow live in :mod:`riskplan.geometry2d`; the whitened loop here
  calls its ``closest_point_on_segment``.

References: closest point on a triangle, Ericson, *Real-Time Collision Detection* (2005) §5.1.5;
segment/triangle intersection, Moller & Trumbore (1997); winding number by signed ray crossings.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from riskplan.geometry2d import closest_point_on_segment, closest_points_on_segments

# ---------------------------------------------------------------- closest points


@nb.njit(cache=True, inline="always")
def _two_dots(ux, uy, uz, vx, vy, vz, wx, wy, wz):
    """``(u . w, v . w)``: the two edge projections of one vertex region test of
    :func:`_closest_tri`."""
    return ux * wx + uy * wy + uz * wz, vx * wx + vy * wy + vz * wz


@nb.njit(cache=True, inline="always")
def _on_edge(ox, oy, oz, ux, uy, uz, num, den):
    """The point ``o + (num / den) u`` of an edge region of :func:`_closest_tri` (``o`` when
    ``den <= 0``: a degenerate edge, any point of which is closest)."""
    t = num / den if den > 0.0 else 0.0
    return ox + t * ux, oy + t * uy, oz + t * uz


@nb.njit(cache=True, inline="always")
def _closest_tri(ax, ay, az, bx, by, bz, cx, cy, cz, px, py, pz):
    """Closest point of triangle ``abc`` to ``p`` (Ericson §5.1.5); returns (x, y, z)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    d1, d2 = _two_dots(abx, aby, abz, acx, acy, acz, px - ax, py - ay, pz - az)
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    d3, d4 = _two_dots(abx, aby, abz, acx, acy, acz, px - bx, py - by, pz - bz)
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        # d1 - d3 = |ab|^2 > 0 unless a == b (a degenerate edge: any point of it is closest)
        return _on_edge(ax, ay, az, abx, aby, abz, d1, d1 - d3)
    d5, d6 = _two_dots(abx, aby, abz, acx, acy, acz, px - cx, py - cy, pz - cz)
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        return _on_edge(ax, ay, az, acx, acy, acz, d2, d2 - d6)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        return _on_edge(bx, by, bz, cx - bx, cy - by, cz - bz, d4 - d3, (d4 - d3) + (d5 - d6))
    tot = va + vb + vc
    if not tot > 0.0:
        # numerically degenerate (collinear) triangle: the closest point lies on an edge
        return _closest_tri_edges(ax, ay, az, bx, by, bz, cx, cy, cz, px, py, pz)
    # interior: project p onto the plane along the normal n = ab x ac. Unlike the barycentric
    # form, this keeps the distance accurate relative to itself, not to the triangle's size
    # (a thin Gaussian next to a large face: whitened distance 3 against a face 1e200 wide)
    nx = aby * acz - abz * acy
    ny = abz * acx - abx * acz
    nz = abx * acy - aby * acx
    nn = nx * nx + ny * ny + nz * nz
    if nn > 1e-300:
        s = ((ax - px) * nx + (ay - py) * ny + (az - pz) * nz) / nn
        return px + s * nx, py + s * ny, pz + s * nz
    denom = 1.0 / tot
    v = vb * denom
    w = vc * denom
    return ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w


@nb.njit(cache=True, inline="always")
def _closest_seg_3d(ax, ay, az, bx, by, bz, px, py, pz):
    """Closest point of segment ``ab`` to ``p`` in 3-D; returns (x, y, z)."""
    ex, ey, ez = bx - ax, by - ay, bz - az
    ee = ex * ex + ey * ey + ez * ez
    t = 0.0
    if ee > 0.0:
        t = ((px - ax) * ex + (py - ay) * ey + (pz - az) * ez) / ee
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
    return ax + t * ex, ay + t * ey, az + t * ez


@nb.njit(cache=True)
def _closest_tri_edges(ax, ay, az, bx, by, bz, cx, cy, cz, px, py, pz):
    """Closest point to ``p`` on the three edges of triangle ``abc`` (for degenerate triangles)."""
    bestx, besty, bestz = _closest_seg_3d(ax, ay, az, bx, by, bz, px, py, pz)
    best = (bestx - px) ** 2 + (besty - py) ** 2 + (bestz - pz) ** 2
    qx, qy, qz = _closest_seg_3d(bx, by, bz, cx, cy, cz, px, py, pz)
    s = (qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2
    if s < best:
        bestx, besty, bestz, best = qx, qy, qz, s
    qx, qy, qz = _closest_seg_3d(cx, cy, cz, ax, ay, az, px, py, pz)
    s = (qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2
    if s < best:
        bestx, besty, bestz = qx, qy, qz
    return bestx, besty, bestz


@nb.njit(cache=True, inline="always")
def _norm3(x, y, z):
    """``sqrt(x^2 + y^2 + z^2)`` without underflow or overflow of the squares."""
    m = max(abs(x), abs(y), abs(z))
    if m == 0.0 or not math.isfinite(m):
        return m
    x, y, z = x / m, y / m, z / m
    return m * math.sqrt(x * x + y * y + z * z)


@nb.njit(cache=True)
def closest_points_brute(V, F, P):
    """Exact closest points of ``P (n, d)`` on faces ``F`` (brute force over faces).

    Returns ``(dist (n,), closest (n, d), face (n,))``. In 2-D this is
    :func:`riskplan.geometry2d.closest_points_on_segments`; in 3-D a test oracle.
    """
    if V.shape[1] == 2:
        S = np.empty((F.shape[0], 4))
        for f in range(F.shape[0]):
            a, b = F[f, 0], F[f, 1]
            S[f, 0], S[f, 1], S[f, 2], S[f, 3] = V[a, 0], V[a, 1], V[b, 0], V[b, 1]
        return closest_points_on_segments(S, P)
    n = P.shape[0]
    dist = np.full(n, np.inf)
    closest = np.zeros((n, 3))
    face = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        best = np.inf
        for f in range(F.shape[0]):
            a, b, c = F[f, 0], F[f, 1], F[f, 2]
            qx, qy, qz = _closest_tri(
                V[a, 0],
                V[a, 1],
                V[a, 2],
                V[b, 0],
                V[b, 1],
                V[b, 2],
                V[c, 0],
                V[c, 1],
                V[c, 2],
                P[i, 0],
                P[i, 1],
                P[i, 2],
            )
            s = (qx - P[i, 0]) ** 2 + (qy - P[i, 1]) ** 2 + (qz - P[i, 2]) ** 2
            if s < best:
                best = s
                closest[i, 0], closest[i, 1], closest[i, 2] = qx, qy, qz
                face[i] = f
        dist[i] = math.sqrt(best)
    return dist, closest, face


# ------------------------------------------------------- Patil-2012 half-space loop


@nb.njit(cache=True)
def _whitened_closest(V, F, muh, Uh, t, scale, centers, radii, cutoff, W, cp, dhat, dist, idx):
    """Whiten the faces that can come within ``cutoff`` of the origin and find their closest points.

    Works in *scaled* whitened coordinates so that no intermediate overflows or underflows
    for any finite ``U`` and ``mu``: with ``s = max|U_ij|`` and ``t = max(1, max|mu_j|)``,
    ``y = U (x - mu) = scale * Uh (x / t - muh)`` where ``Uh = U / s`` (entries in [-1, 1]),
    ``muh = mu / t`` and ``scale = s t`` (which may be ``inf``; a face at an infinite whitened
    distance contributes nothing). ``W``, ``cp`` and ``dhat`` hold scaled quantities (``y / scale``);
    ``dist`` holds true whitened distances ``dhat * scale``.

    A face is skipped without exact work when its bounding sphere (centre ``centers[f]``,
    radius ``radii[f]``) maps to a ball that stays beyond ``cutoff``: the whitened centre is
    ``U (c - mu)`` and the whitened radius is at most ``||U||_2 r``. Returns the number of faces
    kept (those with exact whitened distance < cutoff); their data fill ``W, cp, dhat, dist, idx``.
    """
    d = V.shape[1]
    # spectral norm of Uh bounded by its Frobenius norm (cheap and conservative)
    unorm = 0.0
    for i in range(d):
        for j in range(d):
            unorm += Uh[i, j] * Uh[i, j]
    unorm = math.sqrt(unorm)
    n = 0
    wc = np.empty(d)
    for f in range(F.shape[0]):
        # whitened centre (scaled)
        sq = 0.0
        for i in range(d):
            acc = 0.0
            for j in range(i, d):
                acc += Uh[i, j] * (centers[f, j] / t - muh[j])
            wc[i] = acc
            sq += acc * acc
        lb = math.sqrt(sq) - unorm * (radii[f] / t)
        if lb > 0.0 and lb * scale >= cutoff:
            continue
        for k in range(d):
            vk = F[f, k]
            for i in range(d):
                acc = 0.0
                for j in range(i, d):
                    acc += Uh[i, j] * (V[vk, j] / t - muh[j])
                W[n, k, i] = acc
        if d == 3:
            qx, qy, qz = _closest_tri(
                W[n, 0, 0],
                W[n, 0, 1],
                W[n, 0, 2],
                W[n, 1, 0],
                W[n, 1, 1],
                W[n, 1, 2],
                W[n, 2, 0],
                W[n, 2, 1],
                W[n, 2, 2],
                0.0,
                0.0,
                0.0,
            )
            cp[n, 0], cp[n, 1], cp[n, 2] = qx, qy, qz
            rh = _norm3(qx, qy, qz)
        else:
            qx, qy = closest_point_on_segment(
                W[n, 0, 0], W[n, 0, 1], W[n, 1, 0], W[n, 1, 1], 0.0, 0.0
            )
            cp[n, 0], cp[n, 1] = qx, qy
            rh = _norm3(qx, qy, 0.0)
        # rh * scale is inf (face infinitely far) or 0 (touching), never NaN: rh is finite
        r = rh * scale if rh > 0.0 else 0.0
        if r >= cutoff:
            continue
        dhat[n] = rh
        dist[n] = r
        idx[n] = f
        n += 1
    return n


@nb.njit(cache=True)
def _halfspace_loop(W, cp, dhat, dist, scale, n, eps, a_out, b_out):
    """Patil et al. (ICRA 2012) in whitened space, on the ``n`` faces kept.

    Repeatedly take the closest remaining face point ``p`` (distance ``b = |p|``), add the
    half-space ``a . y <= b`` with ``a = p / b`` (tangent to the whitened obstacle there) and
    discard every face lying entirely in ``a . y >= b`` (behind it). Faces are convex, so the
    face that gave ``p`` is always discarded. Returns ``(n_constraints, touching)``;
    ``touching`` is True when the origin lies on a face (distance ~ 0).

    ``W``, ``cp``, ``dhat`` are scaled by ``1 / scale`` (see :func:`_whitened_closest`); the
    test "behind" ``a . y >= b - eps (1 + b)`` is done in those units, and ``b_out`` receives
    true whitened distances.
    """
    d = W.shape[2]
    order = np.argsort(dhat[:n])
    active = np.ones(n, dtype=np.bool_)
    inv_scale = (
        1.0 / scale
    )  # 0 for scale = inf, inf for a subnormal scale: both give finite thresholds
    m = 0
    for oi in range(n):
        f = order[oi]
        if not active[f]:
            continue
        b = dist[f]
        if b <= 1e-12:
            return m, True
        bh = dhat[f]
        for i in range(d):
            a_out[m, i] = cp[f, i] / bh
        b_out[m] = b
        thr = bh - eps * (inv_scale + bh)
        active[f] = False
        for oj in range(oi + 1, n):
            g = order[oj]
            if not active[g]:
                continue
            behind = True
            for k in range(d):
                s = 0.0
                for i in range(d):
                    s += a_out[m, i] * W[g, k, i]
                if s < thr:
                    behind = False
                    break
            if behind:
                active[g] = False
        m += 1
    return m, False


@nb.njit(cache=True)
def gaussian_bounds(V, F, centers, radii, mus, Us, cutoff, eps, record):
    """Patil bound terms for ``M`` Gaussians ``N(mus[i], (Us[i]^T Us[i])^{-1})``.

    Returns ``(tail_sum (M,), n_constraints (M,), touching (M,), truncated (M,), A, B, owner)``:
    ``tail_sum[i] = sum_j (1 - Phi(b_ij))`` over the constraints of Gaussian ``i``;
    ``truncated[i]`` is True when faces were left beyond ``cutoff`` (the caller adds the
    chi-square tail ``P(|y| >= cutoff)``). When ``record`` the whitened constraints
    ``A (total, d)``, ``B (total,)`` and their Gaussian index ``owner`` are returned too.

    Every finite input gives finite output: the whitening is done in scaled coordinates (see
    :func:`_whitened_closest`), distances that overflow are ``inf`` (``1 - Phi(inf) = 0``).
    """
    M = mus.shape[0]
    nf = F.shape[0]
    d = V.shape[1]
    W = np.empty((nf, d, d))
    cp = np.empty((nf, d))
    dhat = np.empty(nf)
    dist = np.empty(nf)
    idx = np.empty(nf, dtype=np.int64)
    a_buf = np.empty((nf, d))
    b_buf = np.empty(nf)
    tail = np.zeros(M)
    ncons = np.zeros(M, dtype=np.int64)
    touching = np.zeros(M, dtype=np.bool_)
    truncated = np.zeros(M, dtype=np.bool_)
    cap = 16 if record else 0
    A = np.empty((cap, d))
    B = np.empty(cap)
    owner = np.empty(cap, dtype=np.int64)
    total = 0
    inv_sqrt2 = 1.0 / math.sqrt(2.0)
    Uh = np.empty((d, d))
    muh = np.empty(d)
    for it in range(M):
        smax = 0.0
        for i in range(d):
            for j in range(d):
                smax = max(smax, abs(Us[it, i, j]))
        t = 1.0
        for j in range(d):
            t = max(t, abs(mus[it, j]))
        if smax == 0.0:  # U = 0 is rejected by the callers; treat as an infinitely wide Gaussian
            smax = 5e-324
        for i in range(d):
            muh[i] = mus[it, i] / t
            for j in range(d):
                Uh[i, j] = Us[it, i, j] / smax
        scale = smax * t
        n = _whitened_closest(
            V, F, muh, Uh, t, scale, centers, radii, cutoff, W, cp, dhat, dist, idx
        )
        truncated[it] = n < nf
        m, touch = _halfspace_loop(W, cp, dhat, dist, scale, n, eps, a_buf, b_buf)
        touching[it] = touch
        ncons[it] = m
        s = 0.0
        for j in range(m):
            s += 0.5 * math.erfc(b_buf[j] * inv_sqrt2)
        tail[it] = s
        if record:
            while total + m > A.shape[0]:
                A2 = np.empty((2 * A.shape[0] + m, d))
                B2 = np.empty(2 * A.shape[0] + m)
                o2 = np.empty(2 * A.shape[0] + m, dtype=np.int64)
                A2[:total] = A[:total]
                B2[:total] = B[:total]
                o2[:total] = owner[:total]
                A, B, owner = A2, B2, o2
            for j in range(m):
                A[total + j] = a_buf[j]
                B[total + j] = b_buf[j]
                owner[total + j] = it
            total += m
    return tail, ncons, touching, truncated, A[:total], B[:total], owner[:total]


# ------------------------------------------------------------ uniform grids (CSR)


@nb.njit(cache=True)
def build_grid(lo, hi, origin, cell, shape):
    """Bucket boxes ``[lo, hi] (n, k)`` into a uniform ``k``-D grid; returns CSR ``(start, items)``."""
    n, k = lo.shape
    ncell = 1
    for i in range(k):
        ncell *= shape[i]
    counts = np.zeros(ncell + 1, dtype=np.int64)
    i0 = np.empty(k, dtype=np.int64)
    i1 = np.empty(k, dtype=np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            for c in range(ncell):
                counts[c + 1] += counts[c]
            items = np.empty(counts[ncell], dtype=np.int64)
            fill = counts[:-1].copy()
        else:
            items = np.empty(0, dtype=np.int64)
            fill = np.empty(0, dtype=np.int64)
        for f in range(n):
            for i in range(k):
                a = math.floor((lo[f, i] - origin[i]) / cell[i])
                b = math.floor((hi[f, i] - origin[i]) / cell[i])
                i0[i] = min(max(a, 0), shape[i] - 1)
                i1[i] = min(max(b, 0), shape[i] - 1)
            if k == 2:
                for x in range(i0[0], i1[0] + 1):
                    for y in range(i0[1], i1[1] + 1):
                        c = x * shape[1] + y
                        if pass_ == 0:
                            counts[c + 1] += 1
                        else:
                            items[fill[c]] = f
                            fill[c] += 1
            else:
                for x in range(i0[0], i1[0] + 1):
                    for y in range(i0[1], i1[1] + 1):
                        for z in range(i0[2], i1[2] + 1):
                            c = (x * shape[1] + y) * shape[2] + z
                            if pass_ == 0:
                                counts[c + 1] += 1
                            else:
                                items[fill[c]] = f
                                fill[c] += 1
    return counts, items


@nb.njit(cache=True)
def winding_numbers_3d(Vr, F, P, origin, cell, shape, start, items):
    """Winding number of each point of ``P (n, 3)`` w.r.t. closed oriented triangles.

    ``Vr`` and ``P`` are given in a (randomly) rotated frame; the ray goes along +x, and
    the grid buckets triangles by their (y, z) extent. Each crossing counts +1 or -1 by the
    orientation of the triangle seen from the ray, so overlapping closed obstacles add up and
    inverted inner shells (cavities) subtract.
    """
    n = P.shape[0]
    out = np.zeros(n, dtype=np.int64)
    for i in range(n):
        py, pz = P[i, 1], P[i, 2]
        fy = math.floor((py - origin[0]) / cell[0])
        fz = math.floor((pz - origin[1]) / cell[1])
        # compare as floats: int() of a huge or infinite float is undefined
        if not (0.0 <= fy < shape[0] and 0.0 <= fz < shape[1]):
            continue
        cy, cz = int(fy), int(fz)
        c = cy * shape[1] + cz
        w = 0
        for q in range(start[c], start[c + 1]):
            f = items[q]
            a, b, cc = F[f, 0], F[f, 1], F[f, 2]
            ay, az = Vr[a, 1] - py, Vr[a, 2] - pz
            by, bz = Vr[b, 1] - py, Vr[b, 2] - pz
            cy2, cz2 = Vr[cc, 1] - py, Vr[cc, 2] - pz
            # signed areas of the projected sub-triangles (point at the origin of the y-z plane)
            e0 = by * cz2 - bz * cy2
            e1 = cy2 * az - cz2 * ay
            e2 = ay * bz - az * by
            if (e0 > 0.0 and e1 > 0.0 and e2 > 0.0) or (e0 < 0.0 and e1 < 0.0 and e2 < 0.0):
                tot = e0 + e1 + e2
                x = (e0 * Vr[a, 0] + e1 * Vr[b, 0] + e2 * Vr[cc, 0]) / tot
                if x > P[i, 0]:
                    w += 1 if tot > 0.0 else -1
        out[i] = w
    return out


@nb.njit(cache=True)
def segments_hit_3d(V, F, P0, P1, origin, cell, shape, start, items):
    """True where segment ``P0[i] -> P1[i]`` crosses a triangle (Moller-Trumbore, t in [0, 1])."""
    n = P0.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    lo = np.empty(3, dtype=np.int64)
    hi = np.empty(3, dtype=np.int64)
    nf = F.shape[0]
    seen = np.full(nf, -1, dtype=np.int64)
    for i in range(n):
        for k in range(3):
            a = min(P0[i, k], P1[i, k])
            b = max(P0[i, k], P1[i, k])
            # clamp as floats first: int() of a huge or infinite float is undefined
            lo[k] = int(min(max(math.floor((a - origin[k]) / cell[k]), 0.0), shape[k] - 1.0))
            hi[k] = int(min(max(math.floor((b - origin[k]) / cell[k]), 0.0), shape[k] - 1.0))
        dx, dy, dz = P1[i, 0] - P0[i, 0], P1[i, 1] - P0[i, 1], P1[i, 2] - P0[i, 2]
        hit = False
        for x in range(lo[0], hi[0] + 1):
            if hit:
                break
            for y in range(lo[1], hi[1] + 1):
                if hit:
                    break
                for z in range(lo[2], hi[2] + 1):
                    if hit:
                        break
                    c = (x * shape[1] + y) * shape[2] + z
                    for q in range(start[c], start[c + 1]):
                        f = items[q]
                        if seen[f] == i:
                            continue
                        seen[f] = i
                        a, b, cc = F[f, 0], F[f, 1], F[f, 2]
                        e1x, e1y, e1z = V[b, 0] - V[a, 0], V[b, 1] - V[a, 1], V[b, 2] - V[a, 2]
                        e2x, e2y, e2z = V[cc, 0] - V[a, 0], V[cc, 1] - V[a, 1], V[cc, 2] - V[a, 2]
                        hx, hy, hz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
                        det = e1x * hx + e1y * hy + e1z * hz
                        if det == 0.0:
                            continue
                        inv = 1.0 / det
                        sx, sy, sz = P0[i, 0] - V[a, 0], P0[i, 1] - V[a, 1], P0[i, 2] - V[a, 2]
                        u = (sx * hx + sy * hy + sz * hz) * inv
                        if u < 0.0 or u > 1.0:
                            continue
                        qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
                        v = (dx * qx + dy * qy + dz * qz) * inv
                        if v < 0.0 or u + v > 1.0:
                            continue
                        t = (e2x * qx + e2y * qy + e2z * qz) * inv
                        if 0.0 <= t <= 1.0:
                            hit = True
                            break
        out[i] = hit
    return out
