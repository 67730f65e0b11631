"""Numba kernels of the automatic pairing: inliers of map hypotheses.

Unit-free: positions are plain ``float64`` arrays in one angular unit (the
caller, :mod:`lensdual.pairing`, uses arcsec). No validation happens here.

The inliers of a map ``x1 = f(x2)`` are the mutual nearest neighbours closer
than ``sqrt(tau2)`` in a noise metric ``r^T M r`` (``r = x1 - f(x2)``; ``M``
per mapped point, see :func:`lensdual.pairing._metric`). The points of
catalogue 1 are binned once on a grid of square cells (:func:`grid`); a
mapped point only examines the cells that overlap the bounding box of its
metric ellipse ``r^T M r < tau2``, so a hypothesis costs O(N1 + N2) instead
of the O(N1 N2) of all distances.
"""

import numpy as np
from numba import njit

from ._numba import JIT_OPTIONS

__all__ = []

#: At most this many grid cells (the cell grows beyond the tolerance if needed).
MAX_CELLS = 2**20


def quantile_box(p):
    """(lower, upper) corners of the 1-99 % quantile box of the points ``p`` (N, 2),
    widened by 10 % on each side: their extent, without stray points far away."""
    q_lo, q_hi = np.quantile(p, [0.01, 0.99], axis=0)
    pad = 0.1 * (q_hi - q_lo)
    return q_lo - pad, q_hi + pad


def grid(p, tau):
    """Cells of the points ``p`` (N, 2): (rows sorted by cell, cell starts, x0, y0, cell, nx, ny).

    Cells are squares of side ``cell >= tau``; ``starts`` has ``nx * ny + 1``
    entries (rows ``order[starts[c]:starts[c + 1]]`` lie in cell ``c = iy *
    nx + ix``). The grid covers the 1-99 % quantiles of the points (widened
    by 10 %), so that a stray point far away does not make the cells huge;
    points outside lie in the edge cells, which every scan beyond the edge
    visits (:func:`_scan` clamps its cell range).
    """
    lo, hi = quantile_box(p)
    span = np.maximum(hi - lo, 0.0)
    cell = max(float(tau), float(np.sqrt(span[0] * span[1] / MAX_CELLS)),
               float(span.max()) / MAX_CELLS, 1e-300)
    nx, ny = (np.floor(span / cell).astype(np.int64) + 1).tolist()
    while nx * ny > MAX_CELLS:
        cell *= 2.0
        nx, ny = (np.floor(span / cell).astype(np.int64) + 1).tolist()
    ix = np.clip(np.floor((p[:, 0] - lo[0]) / cell), 0, nx - 1).astype(np.int64)
    iy = np.clip(np.floor((p[:, 1] - lo[1]) / cell), 0, ny - 1).astype(np.int64)
    key = iy * nx + ix
    order = np.argsort(key, kind="stable")
    starts = np.searchsorted(key[order], np.arange(nx * ny + 1))
    return order, starts, float(lo[0]), float(lo[1]), cell, nx, ny


@njit(inline="always", **JIT_OPTIONS)
def _clamp(x, n):
    """The cell index ``x`` (a float, possibly huge or NaN) clamped into 0 .. n - 1."""
    if not x > 0.0:
        return 0
    if x >= n - 1:
        return n - 1
    return int(x)


@njit(inline="always", **JIT_OPTIONS)
def _scan(j, qx, qy, m00, m01, m11, tau2, p, order, starts, x0, y0, cell, nx, ny,
          colour_ok, use_colour, best_i, best_d, rev_j, rev_d):
    """Update the nearest neighbours of mapped point ``j`` and of the points near it."""
    # bounding box of the ellipse r^T M r < tau2: half-widths sqrt(tau2 (M^-1)_kk)
    det = m00 * m11 - m01 * m01
    hx = np.sqrt(tau2 * m11 / det)
    hy = np.sqrt(tau2 * m00 / det)
    # clamped into the grid: the edge cells hold the points beyond it
    ix0 = _clamp(np.floor((qx - hx - x0) / cell), nx)
    ix1 = _clamp(np.floor((qx + hx - x0) / cell), nx)
    iy0 = _clamp(np.floor((qy - hy - y0) / cell), ny)
    iy1 = _clamp(np.floor((qy + hy - y0) / cell), ny)
    best_i[j] = -1
    best_d[j] = tau2
    for iy in range(iy0, iy1 + 1):
        for ix in range(ix0, ix1 + 1):
            c = iy * nx + ix
            for k in range(starts[c], starts[c + 1]):
                i = order[k]
                if use_colour and not colour_ok[i, j]:
                    continue
                rx = p[i, 0] - qx
                ry = p[i, 1] - qy
                d2 = m00 * rx * rx + 2.0 * m01 * rx * ry + m11 * ry * ry
                if d2 < best_d[j]:
                    best_d[j] = d2
                    best_i[j] = i
                if d2 < rev_d[i]:
                    rev_d[i] = d2
                    rev_j[i] = j


@njit(**JIT_OPTIONS)
def score_hypotheses(a, b, q, tau2, p, order, starts, x0, y0, cell, nx, ny,
                     colour_ok, use_colour):
    """Inlier counts and MSAC scores of affine hypotheses ``(a (H, 2, 2), b (H, 2))``.

    The metric of a hypothesis is the normalised one of the search,
    ``M = (C / sqrt(det C))^-1`` with ``C = (I + A A^T) / 2``. ``colour_ok``
    (N1, N2) bool: combinations allowed by their colours (read only when
    ``use_colour``). The score is the sum over the inliers of ``1 - d^2 /
    tau2``.
    """
    n_hyp = a.shape[0]
    n1 = p.shape[0]
    n2 = q.shape[0]
    counts = np.zeros(n_hyp, dtype=np.int64)
    score = np.zeros(n_hyp)
    best_i = np.empty(n2, dtype=np.int64)
    best_d = np.empty(n2)
    rev_j = np.empty(n1, dtype=np.int64)
    rev_d = np.empty(n1)
    for h in range(n_hyp):
        a00, a01, a10, a11 = a[h, 0, 0], a[h, 0, 1], a[h, 1, 0], a[h, 1, 1]
        c00 = 0.5 * (1.0 + a00 * a00 + a01 * a01)
        c01 = 0.5 * (a00 * a10 + a01 * a11)
        c11 = 0.5 * (1.0 + a10 * a10 + a11 * a11)
        scale = 1.0 / np.sqrt(c00 * c11 - c01 * c01)
        m00, m01, m11 = c11 * scale, -c01 * scale, c00 * scale
        rev_j[:] = -1
        rev_d[:] = tau2
        for j in range(n2):
            qx = a00 * q[j, 0] + a01 * q[j, 1] + b[h, 0]
            qy = a10 * q[j, 0] + a11 * q[j, 1] + b[h, 1]
            _scan(j, qx, qy, m00, m01, m11, tau2, p, order, starts, x0, y0, cell, nx, ny,
                  colour_ok, use_colour, best_i, best_d, rev_j, rev_d)
        n_in = 0
        s = 0.0
        for j in range(n2):
            i = best_i[j]
            if i >= 0 and rev_j[i] == j:
                n_in += 1
                s += 1.0 - best_d[j] / tau2
        counts[h] = n_in
        score[h] = s
    return counts, score


@njit(**JIT_OPTIONS)
def mutual_inliers(qm, minv, tau2, p, order, starts, x0, y0, cell, nx, ny,
                   colour_ok, use_colour):
    """Inliers (i, j, d2) of one map: mapped points ``qm`` (N2, 2), metrics ``minv`` (N2, 2, 2).

    Sorted by ``j``; ``d2`` are the squared metric distances.
    """
    n1 = p.shape[0]
    n2 = qm.shape[0]
    best_i = np.empty(n2, dtype=np.int64)
    best_d = np.empty(n2)
    rev_j = np.full(n1, -1, dtype=np.int64)
    rev_d = np.full(n1, tau2)
    for j in range(n2):
        _scan(j, qm[j, 0], qm[j, 1], minv[j, 0, 0], minv[j, 0, 1], minv[j, 1, 1], tau2,
              p, order, starts, x0, y0, cell, nx, ny, colour_ok, use_colour,
              best_i, best_d, rev_j, rev_d)
    keep = np.zeros(n2, dtype=np.bool_)
    for j in range(n2):
        i = best_i[j]
        keep[j] = i >= 0 and rev_j[i] == j
    jj = np.flatnonzero(keep)
    return best_i[jj], jj, best_d[jj]
