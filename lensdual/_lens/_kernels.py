"""Numba kernels of the point-source image finder.

Everything here is unit-free: positions are plain ``float64`` arrays in one
angular unit (the solver uses arcsec), indices are ``int64``. No input
validation happens here; :mod:`lensdual._lens._solver` does it.

The image plane is covered by triangles whose vertices were traced to the
source plane ("nodes": ``bx``, ``by``; ``tri`` is an ``(N, 3)`` array of node
indices). Each triangle carries a tolerance ``tol`` (source-plane distance): an
upper estimate of how far the true lens mapping of the image triangle deviates
from the piecewise-linear (barycentric) mapping. A source is a *candidate* of a
triangle when its distance to the mapped (source-plane) triangle is at most
``tol``; the candidate's first guess is the barycentric coordinates of the
source in the mapped triangle (or of the closest point of the mapped triangle
when the source lies outside it).

To avoid testing every source against every triangle, the triangles are
bucketed once on a regular source-plane grid (:func:`bucket_triangles`): each
triangle is registered in every bucket that its tolerance-expanded bounding
box overlaps; a triangle that would cover more than ``max_cover`` buckets (a
huge or very non-linear one) goes to a short "global" list tested against
every source instead. :func:`find_candidates` then tests each source against
the triangles of its bucket and the global list only.
"""

import numpy as np
from numba import njit

__all__ = []

from .._numba import JIT_OPTIONS  # noqa: F401  (the package-wide options)

# A mapped triangle whose |signed area| is below this fraction of its longest
# squared edge is treated as degenerate: only the distance-to-edges test is used.
DEGENERATE_AREA = 1e-14


@njit(**JIT_OPTIONS)
def point_in_triangle(px, py, ax, ay, bx, by, cx, cy, tol, out):
    """Tolerance test of point ``p`` against triangle ``abc`` (either orientation).

    Returns True when ``p`` is inside the triangle or within distance ``tol`` of
    its edges. On success ``out[0:3]`` receives barycentric weights of ``a, b, c``
    (all >= 0, summing to 1): those of ``p`` itself when it is inside a
    non-degenerate triangle, otherwise those of the closest point on the edges.
    """
    e1x = bx - ax
    e1y = by - ay
    e2x = cx - ax
    e2y = cy - ay
    d = e1x * e2y - e1y * e2x
    l1 = e1x * e1x + e1y * e1y
    l2 = e2x * e2x + e2y * e2y
    l3 = (cx - bx) * (cx - bx) + (cy - by) * (cy - by)
    lmax = max(l1, max(l2, l3))
    if abs(d) > DEGENERATE_AREA * lmax:
        w0 = ((bx - px) * (cy - py) - (by - py) * (cx - px)) / d
        w1 = ((cx - px) * (ay - py) - (cy - py) * (ax - px)) / d
        w2 = 1.0 - w0 - w1
        if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
            out[0] = w0
            out[1] = w1
            out[2] = w2
            return True
    if not tol >= 0.0:
        return False
    # closest point on the three edges (also covers degenerate triangles)
    best = np.inf
    bi = 0
    bt = 0.0
    for k in range(3):
        if k == 0:
            ux, uy, vx, vy = ax, ay, bx, by
        elif k == 1:
            ux, uy, vx, vy = bx, by, cx, cy
        else:
            ux, uy, vx, vy = cx, cy, ax, ay
        sx = vx - ux
        sy = vy - uy
        ss = sx * sx + sy * sy
        t = 0.0
        if ss > 0.0:
            t = ((px - ux) * sx + (py - uy) * sy) / ss
            if t < 0.0:
                t = 0.0
            elif t > 1.0:
                t = 1.0
        qx = ux + t * sx - px
        qy = uy + t * sy - py
        dd = qx * qx + qy * qy
        if dd < best:
            best = dd
            bi = k
            bt = t
    if not best <= tol * tol:
        return False
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    out[bi] = 1.0 - bt
    out[(bi + 1) % 3] = bt
    return True


@njit(**JIT_OPTIONS)
def _expanded_bbox(bx, by, tri, tol, i):
    a = tri[i, 0]
    b = tri[i, 1]
    c = tri[i, 2]
    x_lo = min(bx[a], min(bx[b], bx[c])) - tol[i]
    x_hi = max(bx[a], max(bx[b], bx[c])) + tol[i]
    y_lo = min(by[a], min(by[b], by[c])) - tol[i]
    y_hi = max(by[a], max(by[b], by[c])) + tol[i]
    return x_lo, x_hi, y_lo, y_hi


@njit(**JIT_OPTIONS)
def _bucket_range(lo, hi, origin, cell, n):
    """Inclusive bucket index range covered by [lo, hi], clipped to [0, n - 1]."""
    i0 = np.floor((lo - origin) / cell)
    i1 = np.floor((hi - origin) / cell)
    if i0 < 0.0:
        i0 = 0.0
    if i1 > n - 1.0:
        i1 = n - 1.0
    return np.int64(i0), np.int64(i1)


@njit(**JIT_OPTIONS)
def _triangle_buckets(bx, by, tri, tol, i, x0, y0, cell, nbx, nby):
    """The bucket ranges ``(i0, i1, j0, j1)`` that triangle ``i``'s bounding
    box expanded by ``tol`` overlaps, clipped to the grid; ``i0 = -1`` where
    the box lies entirely outside the grid."""
    x_lo, x_hi, y_lo, y_hi = _expanded_bbox(bx, by, tri, tol, i)
    if not (x_hi >= x0 and x_lo <= x0 + nbx * cell and y_hi >= y0
            and y_lo <= y0 + nby * cell):
        return np.int64(-1), np.int64(-1), np.int64(-1), np.int64(-1)
    i0, i1 = _bucket_range(x_lo, x_hi, x0, cell, nbx)
    j0, j1 = _bucket_range(y_lo, y_hi, y0, cell, nby)
    return i0, i1, j0, j1


@njit(**JIT_OPTIONS)
def bucket_triangles(bx, by, tri, tol, x0, y0, cell, nbx, nby, max_cover):
    """Register the triangles in the buckets of a regular source-plane grid.

    Bucket ``(i, j)`` covers ``[x0 + i cell, x0 + (i + 1) cell) x [y0 + j cell, ...)``
    and has flat index ``i * nby + j``. A triangle is registered in every bucket
    that its bounding box expanded by ``tol`` overlaps (clipped to the grid);
    triangles entirely outside the grid are skipped; those covering more than
    ``max_cover`` buckets go to the global list.

    Returns ``(start, items, global_tris)``: the triangles of bucket ``b`` are
    ``items[start[b]:start[b + 1]]`` (increasing triangle index).
    """
    nt = tri.shape[0]
    nb = nbx * nby
    counts = np.zeros(nb + 1, dtype=np.int64)
    n_global = 0
    for i in range(nt):
        i0, i1, j0, j1 = _triangle_buckets(bx, by, tri, tol, i, x0, y0, cell, nbx, nby)
        if i0 < 0:
            continue
        if (i1 - i0 + 1) * (j1 - j0 + 1) > max_cover:
            n_global += 1
            continue
        for ii in range(i0, i1 + 1):
            for jj in range(j0, j1 + 1):
                counts[ii * nby + jj + 1] += 1
    start = np.cumsum(counts)
    items = np.empty(start[nb], dtype=np.int64)
    global_tris = np.empty(n_global, dtype=np.int64)
    fill = start[:nb].copy()
    g = 0
    for i in range(nt):
        i0, i1, j0, j1 = _triangle_buckets(bx, by, tri, tol, i, x0, y0, cell, nbx, nby)
        if i0 < 0:
            continue
        if (i1 - i0 + 1) * (j1 - j0 + 1) > max_cover:
            global_tris[g] = i
            g += 1
            continue
        for ii in range(i0, i1 + 1):
            for jj in range(j0, j1 + 1):
                b = ii * nby + jj
                items[fill[b]] = i
                fill[b] += 1
    return start, items, global_tris


@njit(**JIT_OPTIONS)
def _grow(src, tid, bary, n):
    """Copies of the first ``n`` entries of the candidate arrays in arrays twice as long."""
    cap = 2 * n
    src2 = np.empty(cap, dtype=np.int64)
    tid2 = np.empty(cap, dtype=np.int64)
    bary2 = np.empty((cap, 3), dtype=np.float64)
    # element loops: a slice assignment would compile NumPy's broadcasting checks
    for i in range(n):
        src2[i] = src[i]
        tid2[i] = tid[i]
        for k in range(3):
            bary2[i, k] = bary[i, k]
    return src2, tid2, bary2


@njit(**JIT_OPTIONS)
def _test_and_append(s, t, sx, sy, bx, by, tri, tol, w, src, tid, bary, n):
    a = tri[t, 0]
    b = tri[t, 1]
    c = tri[t, 2]
    if not point_in_triangle(sx[s], sy[s], bx[a], by[a], bx[b], by[b], bx[c], by[c], tol[t], w):
        return src, tid, bary, n
    if n == src.shape[0]:
        src, tid, bary = _grow(src, tid, bary, n)
    src[n] = s
    tid[n] = t
    bary[n, 0] = w[0]
    bary[n, 1] = w[1]
    bary[n, 2] = w[2]
    return src, tid, bary, n + 1


@njit(**JIT_OPTIONS)
def find_candidates(sx, sy, bx, by, tri, tol, x0, y0, cell, nbx, nby, start, items, global_tris):
    """All (source, triangle) pairs passing :func:`point_in_triangle` with ``tol``.

    Uses the buckets of :func:`bucket_triangles` (same grid parameters). Sources
    outside the bucket grid are only tested against the global triangles.

    Returns ``(source_index, triangle_index, bary)`` with shapes ``(K,)``,
    ``(K,)``, ``(K, 3)``, ordered by source then by triangle index.
    """
    m = sx.shape[0]
    cap = max(1024, 8 * m)
    src = np.empty(cap, dtype=np.int64)
    tid = np.empty(cap, dtype=np.int64)
    bary = np.empty((cap, 3), dtype=np.float64)
    w = np.empty(3, dtype=np.float64)
    # an int64 from the start: a literal 0 would compile _test_and_append once more
    n = np.int64(0)
    ng = global_tris.shape[0]
    for s in range(m):
        fi = np.floor((sx[s] - x0) / cell)
        fj = np.floor((sy[s] - y0) / cell)
        lo = 0
        hi = 0
        if 0.0 <= fi < nbx and 0.0 <= fj < nby:
            b = np.int64(fi) * nby + np.int64(fj)
            lo = start[b]
            hi = start[b + 1]
        # merge the bucket list and the global list (both increasing)
        p = lo
        q = 0
        while p < hi or q < ng:
            if q >= ng or (p < hi and items[p] < global_tris[q]):
                t = items[p]
                p += 1
            else:
                t = global_tris[q]
                q += 1
            src, tid, bary, n = _test_and_append(s, t, sx, sy, bx, by, tri, tol, w,
                                                 src, tid, bary, n)
    return src[:n].copy(), tid[:n].copy(), bary[:n].copy()


@njit(**JIT_OPTIONS)
def dedup_sorted(src, x, y, tol):
    """Flag duplicate points of the same source.

    ``src``, ``x``, ``y`` must be sorted by ``src`` then by ``x``. Point ``j`` is a
    duplicate when an earlier kept point ``i`` of the same source lies within
    Euclidean distance ``tol``. Returns a boolean "keep" mask.
    """
    n = src.shape[0]
    keep = np.ones(n, dtype=np.bool_)
    for j in range(n):
        i = j - 1
        while i >= 0 and src[i] == src[j] and x[j] - x[i] <= tol:
            if keep[i]:
                dx = x[j] - x[i]
                dy = y[j] - y[i]
                if dx * dx + dy * dy <= tol * tol:
                    keep[j] = False
                    break
            i -= 1
    return keep
