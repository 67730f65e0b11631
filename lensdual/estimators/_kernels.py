"""Numba kernels of the relative-Jacobian estimators.

Everything here is unit-free: positions are plain ``float64`` arrays in one
angular unit (the public wrappers use arcsec), the Jacobians are dimensionless.
No input validation happens here; :mod:`lensdual.estimators.core` does it.

Conventions (the "pairs table" page of the docs): at pair ``a`` the baselines are
``D_ab = theta_b - theta_a`` on each arc, and the relative Jacobian ``J_a``
satisfies ``D1_ab ~= J_a D2_ab`` (column vectors).

Status codes returned per pair:

* ``STATUS_OK`` (0): a finite Jacobian.
* ``STATUS_NO_TRIANGLE`` (1): 2v only, no neighbour pair closes a triangle
  whose baselines are separated by at least the minimum angle.
* ``STATUS_ILL_CONDITIONED`` (2): the weighted least-squares design matrix
  is (numerically) rank deficient, e.g. all baselines collinear.
* ``STATUS_FALLBACK`` (3): quad2 only, the second-order fit was not possible
  (fewer than 5 baselines, or rank deficient) and the first-order Quad
  Jacobian was used; the Jacobian is finite.

Neighbour rows (``nbr``, int64): the points each pair's estimate may use.
Either one shared row ``arange(N)`` of shape (1, N), every point for every
pair (no cap: the original, O(N^2) estimators, bit for bit), or one row per
pair, shape (N, K), holding the pair itself and its ``K - 1`` nearest
neighbours in L2 (a k-d tree query, :mod:`lensdual.estimators.core`). Within
a row the kernels rank the points by their distance in L2 themselves, so a
row may be in any order and stay fixed while the positions move (bootstrap).
The kernels named ``*_knn`` take such rows; the others are the uncapped
entry points.
"""

import numpy as np
from numba import njit

__all__ = []

from .._numba import JIT_OPTIONS
from ._linalg import lstsq_mgs

STATUS_OK = 0
STATUS_NO_TRIANGLE = 1
STATUS_ILL_CONDITIONED = 2
STATUS_FALLBACK = 3

METHOD_2V = 0
METHOD_QUAD = 1
METHOD_QUAD2 = 2

#: Largest condition estimate accepted for the (column-equilibrated)
#: least-squares design of the Quad estimators.
COND_MAX = 1e10


@njit(**JIT_OPTIONS)
def all_rows(n):
    """The shared neighbour row of the uncapped estimators: every point, shape (1, n)."""
    rows = np.empty((1, n), dtype=np.int64)
    for i in range(n):
        rows[0, i] = i
    return rows


@njit(**JIT_OPTIONS)
def _row(nbr, a):
    """The neighbour row of pair ``a`` (the shared row when ``nbr`` has one row)."""
    return nbr[0] if nbr.shape[0] == 1 else nbr[a]


@njit(**JIT_OPTIONS)
def _normal_sums_knn(t1, t2, nbr, weight_power, acc):
    """Weighted normal-equation sums of the first-order Quad fit, for every pair.

    ``acc[a]`` receives ``(Sxx, Sxy, Syy, Txx, Txy, Tyx, Tyy)`` with
    ``S = sum_b w D2 D2^T`` and ``T = sum_b w D1 D2^T`` over the baselines to
    the neighbours ``b`` in the row of pair ``a``, in row order.
    """
    for a in range(t1.shape[0]):
        _pair_sums(t1, t2, _row(nbr, a), a, weight_power, acc[a])


@njit(**JIT_OPTIONS)
def _pair_sums(t1, t2, row, a, weight_power, acc):
    """The sums of :func:`_normal_sums_knn` for pair ``a`` alone, into ``acc[:7]``."""
    square = weight_power == 2.0
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = 0.0
    for jj in range(row.shape[0]):
        b = row[jj]
        if b == a:
            continue
        dx = t2[b, 0] - t2[a, 0]
        dy = t2[b, 1] - t2[a, 1]
        ex = t1[b, 0] - t1[a, 0]
        ey = t1[b, 1] - t1[a, 1]
        r2 = dx * dx + dy * dy
        w = 1.0 / r2 if square else r2 ** (-0.5 * weight_power)
        wx = w * dx
        wy = w * dy
        s0 += wx * dx
        s1 += wx * dy
        s2 += wy * dy
        s3 += ex * wx
        s4 += ex * wy
        s5 += ey * wx
        s6 += ey * wy
    acc[0] = s0
    acc[1] = s1
    acc[2] = s2
    acc[3] = s3
    acc[4] = s4
    acc[5] = s5
    acc[6] = s6


# Largest condition number of the 2x2 weighted normal matrix for which the
# closed-form solution is used (its relative error is about cond * eps, i.e.
# below 1e-10); worse-conditioned fits go through the QR path instead.
_NORMAL_COND_MAX = 1e6


@njit(**JIT_OPTIONS)
def _solve_normal(s, out):
    """``J = T S^-1`` from the sums of :func:`_normal_sums_knn` for one pair.

    Returns False, leaving ``out`` untouched, when ``S`` is too badly
    conditioned for the normal equations to be accurate.
    """
    sxx, sxy, syy, txx, txy, tyx, tyy = s[0], s[1], s[2], s[3], s[4], s[5], s[6]
    half_tr = 0.5 * (sxx + syy)
    disc = np.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    if not (half_tr - disc) * _NORMAL_COND_MAX > half_tr + disc:
        return False
    det = sxx * syy - sxy * sxy
    # S^-1 = [[syy, -sxy], [-sxy, sxx]] / det
    out[0, 0] = (txx * syy - txy * sxy) / det
    out[0, 1] = (txy * sxx - txx * sxy) / det
    out[1, 0] = (tyx * syy - tyy * sxy) / det
    out[1, 1] = (tyy * sxx - tyx * sxy) / det
    return True


@njit(**JIT_OPTIONS)
def _jacobian_quad(t1, t2, a, row, order, weight_power, cond_max, A, Y, sol, out):
    """Weighted least-squares (Quad/QW) Jacobian at pair ``a``.

    The baselines are those from ``a`` to the other points of its neighbour
    ``row`` (which holds ``a``; ``A`` and ``Y`` have one row per baseline).
    ``order`` 1 fits ``D1 = J D2``; ``order`` 2 adds the quadratic terms of
    the Taylor expansion (``D2x^2, D2x D2y, D2y^2`` per output component), of
    which only the linear part is returned. Weights ``|D2|^-weight_power``
    enter the squared residuals, so rows are scaled by their square root.
    """
    half_power = 0.5 * weight_power
    m = 0
    for jj in range(row.shape[0]):
        b = row[jj]
        if b == a:
            continue
        dx = t2[b, 0] - t2[a, 0]
        dy = t2[b, 1] - t2[a, 1]
        r2 = dx * dx + dy * dy
        sw = r2 ** (-0.5 * half_power)
        A[m, 0] = sw * dx
        A[m, 1] = sw * dy
        if order == 2:
            A[m, 2] = sw * dx * dx
            A[m, 3] = sw * dx * dy
            A[m, 4] = sw * dy * dy
        Y[m, 0] = sw * (t1[b, 0] - t1[a, 0])
        Y[m, 1] = sw * (t1[b, 1] - t1[a, 1])
        m += 1
    ncol = 2 if order == 1 else 5
    if not lstsq_mgs(A, Y, ncol, sol, cond_max):
        for i in range(2):
            for j in range(2):
                out[i, j] = np.nan
        return STATUS_ILL_CONDITIONED
    # rows of B are the coefficients of D2x, D2y: J = B[:2].T
    out[0, 0] = sol[0, 0]
    out[0, 1] = sol[1, 0]
    out[1, 0] = sol[0, 1]
    out[1, 1] = sol[1, 1]
    return STATUS_OK


@njit(**JIT_OPTIONS)
def _triangle_2v(t1, t2, a, b, c, min_sin, db, dc, out):
    """Exact Jacobian on triangle (a, b, c) if its L2 baselines are well separated.

    ``db``, ``dc`` are the squared L2 distances of ``b`` and ``c`` from ``a``.
    Returns False (``out`` untouched) when the sine of the angle between the
    baselines is below ``min_sin``.
    """
    bx = t2[b, 0] - t2[a, 0]
    by = t2[b, 1] - t2[a, 1]
    cx = t2[c, 0] - t2[a, 0]
    cy = t2[c, 1] - t2[a, 1]
    det = bx * cy - by * cx
    if not abs(det) >= min_sin * np.sqrt(db * dc) or det == 0.0:
        return False
    # J [b c] = [b1 c1]  =>  J = [b1 c1] [b c]^-1
    b1x = t1[b, 0] - t1[a, 0]
    b1y = t1[b, 1] - t1[a, 1]
    c1x = t1[c, 0] - t1[a, 0]
    c1y = t1[c, 1] - t1[a, 1]
    out[0, 0] = (b1x * cy - c1x * by) / det
    out[0, 1] = (c1x * bx - b1x * cx) / det
    out[1, 0] = (b1y * cy - c1y * by) / det
    out[1, 1] = (c1y * bx - b1y * cx) / det
    return True


@njit(**JIT_OPTIONS)
def _jacobian_2v(t1, t2, a, row, min_sin, dist, out):
    """2v Jacobian at pair ``a``: the exact inverse on one triangle.

    The triangle is ``a`` with its two nearest neighbours in L2 (among its
    neighbour ``row``). When their baselines are closer to collinear than
    ``min_sin`` (the sine of the minimum angle between them), the
    neighbourhood grows one neighbour at a time (ranked by distance in L2)
    and the first pair ``(i, j)``, ``i < j``, that closes a well-conditioned
    triangle is used. ``dist`` (at least the length of ``row``) is scratch.
    """
    n = row.shape[0]
    # the two nearest neighbours by a linear scan (the common case) ...
    n1 = -1
    n2 = -1
    d1 = np.inf
    d2 = np.inf
    self_pos = -1
    for jj in range(n):
        b = row[jj]
        dx = t2[b, 0] - t2[a, 0]
        dy = t2[b, 1] - t2[a, 1]
        d = dx * dx + dy * dy
        dist[jj] = d
        if b == a:
            self_pos = jj
            continue
        if d < d1:
            n2 = n1
            d2 = d1
            n1 = jj
            d1 = d
        elif d < d2:
            n2 = jj
            d2 = d
    if self_pos >= 0:
        dist[self_pos] = np.inf
    if n2 >= 0 and _triangle_2v(t1, t2, a, row[n1], row[n2], min_sin, dist[n1], dist[n2],
                                out):
        return STATUS_OK
    # ... and a growing neighbourhood only when they are nearly collinear
    order = np.argsort(dist[:n])  # a itself is last
    for jj in range(1, n - 1):
        c = order[jj]
        for ii in range(jj):
            b = order[ii]
            if _triangle_2v(t1, t2, a, row[b], row[c], min_sin, dist[b], dist[c], out):
                return STATUS_OK
    for i in range(2):
        for j in range(2):
            out[i, j] = np.nan
    return STATUS_NO_TRIANGLE


@njit(**JIT_OPTIONS)
def relative_jacobians_knn(t1, t2, nbr, method, weight_power, min_sin, cond_max, jac, status):
    """Relative Jacobian at every pair, from its neighbour row.

    Parameters
    ----------
    t1, t2 : (N, 2) float64
        Positions on arcs L1 and L2.
    nbr : (1, N) or (N, K) int64
        Neighbour rows (see the module docstring); each row holds its pair.
    method : int
        ``METHOD_2V``, ``METHOD_QUAD`` or ``METHOD_QUAD2``.
    weight_power : float
        Baseline weights ``|D2|^-weight_power`` (Quad methods).
    min_sin : float
        Sine of the minimum angle between the two baselines of a 2v triangle.
    cond_max : float
        Largest acceptable condition estimate of the least-squares design.
    jac : (N, 2, 2) float64
        Output Jacobians (NaN where the status is not ``STATUS_OK``).
    status : (N,) int64
        Output status codes.
    """
    n = t1.shape[0]
    k = nbr.shape[1]
    ncol = 5 if method == METHOD_QUAD2 else 2
    A = np.empty((k - 1, ncol))
    Y = np.empty((k - 1, 2))
    sol = np.empty((ncol, 2))
    if method == METHOD_2V:
        dist = np.empty(k)
        for a in range(n):
            status[a] = _jacobian_2v(t1, t2, a, _row(nbr, a), min_sin, dist, jac[a])
    elif method == METHOD_QUAD:
        # closed-form normal equations, QR where they are badly conditioned
        acc = np.empty((n, 7))
        _normal_sums_knn(t1, t2, nbr, weight_power, acc)
        for a in range(n):
            if _solve_normal(acc[a], jac[a]):
                status[a] = STATUS_OK
            else:
                status[a] = _jacobian_quad(
                    t1, t2, a, _row(nbr, a), 1, weight_power, cond_max, A, Y, sol, jac[a]
                )
    else:
        for a in range(n):
            row = _row(nbr, a)
            st = STATUS_ILL_CONDITIONED
            if k - 1 >= 5:
                st = _jacobian_quad(t1, t2, a, row, 2, weight_power, cond_max, A, Y, sol,
                                    jac[a])
            if st != STATUS_OK:
                # not enough (or degenerate) baselines for the curvature terms
                st = _jacobian_quad(t1, t2, a, row, 1, weight_power, cond_max, A, Y, sol,
                                    jac[a])
                st = STATUS_FALLBACK if st == STATUS_OK else st
            status[a] = st


@njit(**JIT_OPTIONS)
def relative_jacobians(t1, t2, method, weight_power, min_sin, cond_max, jac, status):
    """:func:`relative_jacobians_knn` with every point for every pair (no cap)."""
    relative_jacobians_knn(t1, t2, all_rows(t1.shape[0]), method, weight_power, min_sin,
                           cond_max, jac, status)


@njit(**JIT_OPTIONS)
def bootstrap_determinants_knn(t1, t2, nbr, noise1, noise2, method, weight_power, min_sin,
                               cond_max, det_out):
    """Signed ``det J`` at every pair for every bootstrap realisation.

    ``noise1``, ``noise2`` are (B, N, 2) offsets added to ``t1``, ``t2``;
    ``det_out`` (B, N) receives the determinants (NaN where a realisation has
    no finite Jacobian). The neighbour rows ``nbr`` stay those of the
    measured positions; each realisation re-ranks the points within them.
    """
    nboot = noise1.shape[0]
    n = t1.shape[0]
    p1 = np.empty((n, 2))
    p2 = np.empty((n, 2))
    jac = np.empty((n, 2, 2))
    status = np.empty(n, dtype=np.int64)
    for k in range(nboot):
        for i in range(n):
            for d in range(2):
                p1[i, d] = t1[i, d] + noise1[k, i, d]
                p2[i, d] = t2[i, d] + noise2[k, i, d]
        relative_jacobians_knn(p1, p2, nbr, method, weight_power, min_sin, cond_max, jac,
                               status)
        for i in range(n):
            det_out[k, i] = jac[i, 0, 0] * jac[i, 1, 1] - jac[i, 0, 1] * jac[i, 1, 0]


@njit(**JIT_OPTIONS)
def bootstrap_determinants(t1, t2, noise1, noise2, method, weight_power, min_sin,
                           cond_max, det_out):
    """:func:`bootstrap_determinants_knn` with every point for every pair (no cap)."""
    bootstrap_determinants_knn(t1, t2, all_rows(t1.shape[0]), noise1, noise2, method,
                               weight_power, min_sin, cond_max, det_out)
