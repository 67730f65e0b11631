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

from .._numba import JIT_OPTIONS  # noqa: F401  (the package-wide options)

STATUS_OK = 0
STATUS_NO_TRIANGLE = 1
STATUS_ILL_CONDITIONED = 2
STATUS_FALLBACK = 3

METHOD_2V = 0
METHOD_QUAD = 1
METHOD_QUAD2 = 2


# Kept whole (noqa): a numba kernel whose McCabe count comes from its explicit scalar
# loops (equilibrate, Gram-Schmidt twice, condition test, back-substitution); helpers
# would add calls in the innermost loop of every local fit.
@njit(**JIT_OPTIONS)
def _lstsq_mgs(A, Y, ncol, sol, cond_max):  # noqa: C901
    """Least squares ``min ||A[:, :ncol] B - Y||`` by modified Gram-Schmidt.

    ``A`` (M, >=ncol) is overwritten (it becomes Q, column-equilibrated), ``Y``
    is (M, 2), ``sol`` (>=ncol, 2) receives ``B``. Two Gram-Schmidt passes are
    made per column ("twice is enough"), which keeps Q orthonormal to rounding
    even for badly conditioned columns. The columns are scaled to unit norm
    first, so that the conditioning test is independent of the units of the
    columns (baselines and squared baselines in the second-order fit).

    Returns True on success, False when the smallest pivot is below
    ``1 / cond_max`` of the largest (the design is numerically rank deficient).
    """
    M = A.shape[0]
    scale = np.empty(ncol)
    R = np.zeros((ncol, ncol))
    for j in range(ncol):
        s = 0.0
        for m in range(M):
            s += A[m, j] * A[m, j]
        s = np.sqrt(s)
        if not s > 0.0:
            return False
        scale[j] = s
        for m in range(M):
            A[m, j] /= s
    for j in range(ncol):
        for _ in range(2):
            for i in range(j):
                r = 0.0
                for m in range(M):
                    r += A[m, i] * A[m, j]
                R[i, j] += r
                for m in range(M):
                    A[m, j] -= r * A[m, i]
        nrm = 0.0
        for m in range(M):
            nrm += A[m, j] * A[m, j]
        nrm = np.sqrt(nrm)
        R[j, j] = nrm
        if not nrm > 0.0:
            return False
        for m in range(M):
            A[m, j] /= nrm
    rmax = 0.0
    rmin = np.inf
    for j in range(ncol):
        d = abs(R[j, j])
        rmax = max(rmax, d)
        rmin = min(rmin, d)
    if not rmin * cond_max > rmax:
        return False
    # B = R^-1 Q^T Y, then undo the column scaling.
    for c in range(2):
        for j in range(ncol):
            q = 0.0
            for m in range(M):
                q += A[m, j] * Y[m, c]
            sol[j, c] = q
        for j in range(ncol - 1, -1, -1):
            v = sol[j, c]
            for i in range(j + 1, ncol):
                v -= R[j, i] * sol[i, c]
            sol[j, c] = v / R[j, j]
        for j in range(ncol):
            sol[j, c] /= scale[j]
    return True


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
    if not _lstsq_mgs(A, Y, ncol, sol, cond_max):
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


# ---------------------------------------------------------------------------
# The locality-adaptive estimator ("adaptive")
# ---------------------------------------------------------------------------

METHOD_ADAPTIVE = 3

# Tested fits have degree 1 or 2, reported ones up to 3: a full cubic in two
# variables has 10 coefficients.
_ADAPTIVE_NCOEF_MAX = 10

ADAPTIVE_OK = 0  # a local fit consistent with the noise was found
ADAPTIVE_MISFIT = 1  # no tested fit passed, but a reported fit is consistent on its own
ADAPTIVE_FAILED = 2  # no usable fit (too few or degenerate baselines)
ADAPTIVE_UNTESTABLE = 3  # no fit, not even the reported one, is consistent with the noise

# Truncation error of a "misfit" estimate: ``_ADAPTIVE_CURV_COEF * c ** 2`` in
# ln|det J|, ``c`` the largest change of ln|det J| across the chosen fit's
# neighbourhood that the fit's own second-order terms predict, less
# ``_ADAPTIVE_CURV_NSIG`` times its noise at each point (see _adaptive_pair).
_ADAPTIVE_CURV_COEF = 0.1
_ADAPTIVE_CURV_NSIG = 2.0
# Weight of the top-order change ``c_top`` in the ranking of the passing fits
# (see _adaptive_pair): rank = variance along the pilot's gradient
# + (_ADAPTIVE_TOP_COEF * c_top) ** 2, ``c_top`` less ``_ADAPTIVE_TOP_NSIG``
# times its noise at each point (1.5, not the curvature's 2: at 10-20 mas
# the noise allowance of 2 zeroed ``c_top`` for most fits, and large
# neighbourhoods won whose truncation the test cannot see).
_ADAPTIVE_TOP_COEF = 0.6
_ADAPTIVE_TOP_NSIG = 1.5
# Two-scale estimates (see _two_scale) only where the larger neighbourhood's
# quadratic is known to be gentle: its change of ln|det J| across that
# neighbourhood plus _ADAPTIVE_TWO_GATE_NSIG times its noise at each point at
# most _ADAPTIVE_TWO_GATE (0.3-0.6 measured; without the gate, or with a limit
# on the ratio of the two neighbourhoods' radii instead, galaxy-scale folds at
# 10-20 mas were flagged 0.8-1.6 %: their truncation bias, hidden before in
# the larger error of the one-scale estimate).
_ADAPTIVE_TWO_GATE = 0.5
_ADAPTIVE_TWO_GATE_NSIG = 2.0
# An "ok" quadratic report licensed by a linear test holds the bias its cubic
# terms alias into its slopes, estimated from the cubic fit of the whole row,
# less _ADAPTIVE_CUBIC_NSIG times that estimate's noise: see _cubic_alias_bias2
_ADAPTIVE_CUBIC_BIAS = True
_ADAPTIVE_CUBIC_NSIG = 1.5
# A linear test also needs the quadratic terms of its neighbourhood to be
# insignificant: the likelihood-ratio (nested) test of the linear against the
# quadratic fit on the same points, 2 x 3 degrees of freedom, at
# _ADAPTIVE_NEST_ALPHA (0.01; the critical value below is
# scipy.stats.chi2.isf(0.01, 6), checked by the tests). See _adaptive_pair.
_ADAPTIVE_NEST = True
_ADAPTIVE_NEST_ALPHA = 0.01
_ADAPTIVE_NEST_CRIT6 = 16.811893829770927
# The larger neighbourhood of a two-scale estimate (see _two_scale) also needs
# its cubic terms to be insignificant: the likelihood-ratio test of its
# quadratic against the cubic on the same points, 2 x 4 degrees of freedom, at
# _ADAPTIVE_TWO_NEST_ALPHA (0.05; scipy.stats.chi2.isf(0.05, 8) below, checked
# by the tests). The quadratic terms it lends the smaller fit are otherwise
# those of a region where the map bends more than a quadratic (a cluster
# member next to the pair), and the estimate, the most precise of all, is
# biased by several times its error.
_ADAPTIVE_TWO_NEST = True
_ADAPTIVE_TWO_NEST_ALPHA = 0.05
_ADAPTIVE_TWO_NEST_CRIT8 = 15.507313055865453


@njit(**JIT_OPTIONS)
def _ncoef(degree):
    return (degree + 1) * (degree + 2) // 2


@njit(**JIT_OPTIONS)
def _monomials(ux, uy, out):
    """Degree-ordered monomials 1, x, y, x^2, xy, y^2, x^3, x^2 y, x y^2, y^3."""
    out[0] = 1.0
    out[1] = ux
    out[2] = uy
    out[3] = ux * ux
    out[4] = ux * uy
    out[5] = uy * uy
    out[6] = ux * ux * ux
    out[7] = ux * ux * uy
    out[8] = ux * uy * uy
    out[9] = uy * uy * uy


_MONOMIAL_DEGREE = np.array([0, 1, 1, 2, 2, 2, 3, 3, 3, 3], dtype=np.float64)


@njit(**JIT_OPTIONS)
def _rotate_back(c, s, jr00, jr01, jr10, jr11, out):
    """``out = R J'`` with ``R = [[c, -s], [s, c]]``: a rotated-frame Jacobian back."""
    out[0, 0] = c * jr00 - s * jr10
    out[0, 1] = c * jr01 - s * jr11
    out[1, 0] = s * jr00 + c * jr10
    out[1, 1] = s * jr01 + c * jr11


@njit(**JIT_OPTIONS)
def _copy_jacobian(src, out):
    for i in range(2):
        for j in range(2):
            out[i, j] = src[i, j]


@njit(**JIT_OPTIONS)
def _cholesky_factor(A, p, scale, L, tol):
    """Cholesky factor ``L`` of the leading ``p`` x ``p`` block of ``S A S``.

    ``S = diag(scale)``; the matrix is equilibrated, so ``tol`` bounds its
    pivots relative to 1. Row ``i`` of ``L`` depends on rows ``< i`` only:
    the leading block of the factor of a larger block is the factor of the
    smaller one, bit for bit. Returns the number of leading rows factored
    before a pivot fell below ``tol`` (``p`` on success): a fit with up to
    that many coefficients can use ``L``.
    """
    for i in range(p):
        for j in range(i + 1):
            s = A[i, j] * scale[i] * scale[j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > tol:
                    return i
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    return p


@njit(**JIT_OPTIONS)
def _cholesky_solve(A, p, scale, rhs, L, sol, tol):
    """Solve ``(S A S) z = S rhs`` (S = diag(scale)) by Cholesky; ``sol = S z``.

    Only the leading ``p`` x ``p`` block of ``A`` is used. ``L`` receives the
    factor of the equilibrated matrix. Returns False when a pivot falls below
    ``tol`` times the largest diagonal element (numerically singular).
    """
    if _cholesky_factor(A, p, scale, L, tol) < p:
        return False
    _factored_solve(L, p, scale, rhs, sol)
    return True


@njit(**JIT_OPTIONS)
def _factored_solve(L, p, scale, rhs, sol):
    """The solve of :func:`_cholesky_solve` with the factor ``L`` already made."""
    for i in range(p):
        s = rhs[i] * scale[i]
        for k in range(i):
            s -= L[i, k] * sol[k]
        sol[i] = s / L[i, i]
    for i in range(p - 1, -1, -1):
        s = sol[i]
        for k in range(i + 1, p):
            s -= L[k, i] * sol[k]
        sol[i] = s / L[i, i]
    for i in range(p):
        sol[i] *= scale[i]


@njit(**JIT_OPTIONS)
def _inverse_entry(L, p, scale, i, j, work):
    """Entry (i, j) of ``(S A S)^-1`` scaled back: ``S (S A S)^-1 S`` at (i, j)."""
    # solve L L^T x = e_j, then take x_i
    for r in range(p):
        s = 1.0 if r == j else 0.0
        for k in range(r):
            s -= L[r, k] * work[k]
        work[r] = s / L[r, r]
    for r in range(p - 1, -1, -1):
        s = work[r]
        for k in range(r + 1, p):
            s -= L[k, r] * work[k]
        work[r] = s / L[r, r]
    return work[i] * scale[i] * scale[j]


@njit(**JIT_OPTIONS)
def _slope_covariance(L, p, scale, work, out):
    """Entries (1, 1), (1, 2), (2, 2) of ``S (S A S)^-1 S`` into ``out[:3]``.

    The same arithmetic as three :func:`_inverse_entry` calls, with the solve
    for ``e_2`` made once for both entries that need it.
    """
    out[0] = _inverse_entry(L, p, scale, 1, 1, work)
    out[2] = _inverse_entry(L, p, scale, 2, 2, work)
    out[1] = work[1] * scale[1] * scale[2]


@njit(**JIT_OPTIONS)
def _order_change(L, pr, scale, work, beta, U, kk, g00, g01, g10, g11, hmax, n_sig, deg,
                  cov_o, grad):
    """The largest change of ln|det J| across a fit's ``kk`` points that its
    terms of degree ``deg`` (2 or 3) alone predict, ``tr(J^-1 dJ_deg(u))``,
    less ``n_sig`` times its standard error at each point (from the fit's
    covariance, J held fixed); 0 when the fit (``pr`` coefficients) has no
    such terms. Degree 2 is the curvature of a "misfit" fit, the fit's top
    degree its top-order change (see :func:`_adaptive_pair`)."""
    return _order_changes(L, pr, scale, work, beta, U, kk, g00, g01, g10, g11, hmax, n_sig,
                          0.0, deg, cov_o, grad)[0]


@njit(**JIT_OPTIONS)
def _block_covariance(L, pr, scale, i0, m, work, out):
    """The covariance of the ``m`` coefficients from ``i0`` of both components'
    fits (``pr`` coefficients, factors ``L``) into ``out[comp, :m, :m]``."""
    for comp in range(2):
        for j in range(m):
            _inverse_entry(L[comp], pr, scale, i0 + j, i0 + j, work)
            for i in range(m):
                out[comp, i, j] = work[i0 + i] * scale[i0 + i] * scale[i0 + j]


@njit(**JIT_OPTIONS)
def _order_changes(L, pr, scale, work, beta, U, kk, g00, g01, g10, g11, hmax, n_sig, n_up,
                   deg, cov_o, grad):
    """:func:`_order_change` and, in the same pass, its upper bound: the largest
    change *plus* ``n_up`` times its standard error (both 0 without such
    terms)."""
    if deg < 2 or pr < _ncoef(deg):
        return 0.0, 0.0
    i0 = _ncoef(deg - 1)
    m = deg + 1
    _block_covariance(L, pr, scale, i0, m, work, cov_o)
    out = 0.0
    up = 0.0
    for q in range(kk):
        x = U[q, 1]
        y = U[q, 2]
        t = 0.0
        v = 0.0
        for comp in range(2):
            ga = g00 if comp == 0 else g10
            gb = g01 if comp == 0 else g11
            # d/dx and d/dy of the monomials x^(deg - i) y^i, weighted by dln|det|/dJ
            if m == 3:
                grad[0] = ga * 2.0 * x
                grad[1] = ga * y + gb * x
                grad[2] = gb * 2.0 * y
            else:
                grad[0] = ga * 3.0 * x * x
                grad[1] = ga * 2.0 * x * y + gb * x * x
                grad[2] = ga * y * y + gb * 2.0 * x * y
                grad[3] = gb * 3.0 * y * y
            for i in range(m):
                t += grad[i] * beta[comp, i0 + i]
                for j in range(m):
                    v += grad[i] * cov_o[comp, i, j] * grad[j]
        sq = np.sqrt(max(v, 0.0))
        out = max(out, abs(t) / hmax - n_sig * sq / hmax)
        up = max(up, abs(t) / hmax + n_up * sq / hmax)
    return out, up


@njit(**JIT_OPTIONS)
def _centre_gradient2(L, pr, scale, work, beta, g00, g01, g10, g11, hmax, cov_o):
    """``|grad ln|det J||^2`` at the pair from a fit's second-order terms, less
    its noise (the trace of its covariance from the fit's, J held fixed; 0 at
    least). ``beta`` holds the fit's coefficients (``pr >= 6``), ``g`` the
    gradient ``d ln|det| / dJ'`` of the rotated Jacobian, ``cov_o`` the
    (2, 4, 4) scratch of :func:`_order_changes`.

    The offsets of a pair's neighbours are taken from its own noisy L2
    position, so the fits estimate the Jacobian at that position, not at
    the true one: the pair's L2 noise ``s2`` adds ``s2^2`` times this to the
    variance of ``ln|det J|`` (see :func:`_adaptive_pair`).
    """
    if pr < 6:
        return 0.0  # no second-order terms
    h2 = hmax * hmax
    _block_covariance(L, pr, scale, 3, 3, work, cov_o)
    gx = 0.0
    gy = 0.0
    var = 0.0
    for comp in range(2):
        ga = g00 if comp == 0 else g10
        gb = g01 if comp == 0 else g11
        # d ln|det| / dx = sum g_ij dJ_ij/dx; dJ/dx of row comp = (2 b3, b4) / h^2,
        # dJ/dy = (b4, 2 b5) / h^2 (monomials x^2, xy, y^2 at 3, 4, 5)
        ax0, ax1, ax2 = 2.0 * ga / h2, gb / h2, 0.0
        ay0, ay1, ay2 = 0.0, ga / h2, 2.0 * gb / h2
        gx += ax0 * beta[comp, 3] + ax1 * beta[comp, 4]
        gy += ay1 * beta[comp, 4] + ay2 * beta[comp, 5]
        cv = cov_o[comp]
        var += _quad_form3(cv, ax0, ax1, ax2) + _quad_form3(cv, ay0, ay1, ay2)
    return max(gx * gx + gy * gy - var, 0.0)


@njit(**JIT_OPTIONS)
def _quad_form3(cv, v0, v1, v2):
    """``v^T cv v`` for a 3-vector ``v`` and the leading (3, 3) block of ``cv``."""
    return (v0 * (cv[0, 0] * v0 + cv[0, 1] * v1 + cv[0, 2] * v2)
            + v1 * (cv[1, 0] * v0 + cv[1, 1] * v1 + cv[1, 2] * v2)
            + v2 * (cv[2, 0] * v0 + cv[2, 1] * v1 + cv[2, 2] * v2))


@njit(**JIT_OPTIONS)
def _store_linear(L, scale, A, beta, work, rhs_al, sol_al, h_sl, h_al, h_cv, j):
    """Keep what a two-scale estimate needs of a linear fit that passed its test
    (:func:`_two_scale`): its slopes, the alias of the three quadratic
    monomials onto them and the slopes' covariance, per component (``L`` the
    factor of the neighbourhood's normal matrices, ``beta`` the linear
    solution)."""
    for comp in range(2):
        h_sl[j, comp, 0] = beta[comp, 1]
        h_sl[j, comp, 1] = beta[comp, 2]
        for m in range(3):
            for i in range(3):
                rhs_al[i] = A[comp, 3 + m, i]
            _factored_solve(L[comp], 3, scale, rhs_al, sol_al)
            h_al[j, comp, 0, m] = sol_al[1]
            h_al[j, comp, 1, m] = sol_al[2]
        _slope_covariance(L[comp], 3, scale, work, h_cv[j, comp])


@njit(**JIT_OPTIONS)
def _slopes_jacobian(s00, s01, s10, s11, cv, hmax):
    """``J' = slopes / hmax`` (rotated frame, derivatives with respect to the
    unscaled offsets), ``d ln|det| / dJ' = J'^-T`` and the variance of
    ``ln|det J|`` from the slopes' covariance ``cv`` (:func:`_ln_det_form`),
    with ``det J'`` after ``J'``; the gradient and the variance are 0 where
    ``det J'`` is 0 or not finite (the caller skips fits whose variance is
    not positive)."""
    jr00 = s00 / hmax
    jr01 = s01 / hmax
    jr10 = s10 / hmax
    jr11 = s11 / hmax
    det = jr00 * jr11 - jr01 * jr10
    if not (np.isfinite(det) and det != 0.0):
        return jr00, jr01, jr10, jr11, det, 0.0, 0.0, 0.0, 0.0, 0.0
    g00 = jr11 / det
    g01 = -jr10 / det
    g10 = -jr01 / det
    g11 = jr00 / det
    return (jr00, jr01, jr10, jr11, det, g00, g01, g10, g11,
            _ln_det_form(cv, g00, g01, g10, g11, hmax))


@njit(**JIT_OPTIONS)
def _ln_det_form(cv, g00, g01, g10, g11, hmax):
    """``g^T C g / hmax^2`` summed over the two components: the variance of
    ``ln|det J|`` (``g = J'^-T``) or of its projection on another gradient,
    from the slopes' covariance entries ``cv[comp] = (11, 12, 22)``."""
    return ((g00 * g00 * cv[0, 0] + 2.0 * g00 * g01 * cv[0, 1] + g01 * g01 * cv[0, 2])
            + (g10 * g10 * cv[1, 0] + 2.0 * g10 * g11 * cv[1, 1]
               + g11 * g11 * cv[1, 2])) / (hmax * hmax)


@njit(**JIT_OPTIONS)
def _two_scale_slopes(sl_h, al_h, cv_h, beta, s13, s33, sl, cv):
    """One component of a two-scale estimate (:func:`_two_scale`): the slopes
    ``sl_h - al_h gamma`` (``gamma = beta[3:6]``) into ``sl`` and their
    covariance entries (0, 0), (0, 1), (1, 1) into ``cv``."""
    for r in range(2):
        v = sl_h[r]
        for m in range(3):
            v -= al_h[r, m] * beta[3 + m]
        sl[r] = v
    for e in range(3):
        r1 = 0 if e < 2 else 1
        r2 = 0 if e == 0 else 1
        v = cv_h[e]
        for m in range(3):
            v -= s13[r1, m] * al_h[r2, m] + al_h[r1, m] * s13[r2, m]
            for m2 in range(3):
                v -= al_h[r1, m] * s33[m, m2] * al_h[r2, m2]
        cv[e] = v


@njit(**JIT_OPTIONS)
def _two_scale(L, scale, work, beta, U, kk, hmax, h_k, h_sl, h_al, h_cv, n_h, c, s, pilot_ranks,
               q, best_rank, s13, s33, cov_o, grad_o, jb):
    """Two-scale estimates at the ``kk`` points whose quadratic fit (``beta``,
    factor ``L``) passed its test: each stored linear fit of ``h < kk``
    points, less the alias of this quadratic's second-order terms (robust
    bias correction whose bias estimate comes from the larger
    neighbourhood). Returns ``(rank, sd, g2)`` of the best-ranked one below
    ``best_rank`` (its Jacobian in ``jb``; ``g2`` from
    :func:`_centre_gradient2` of the quadratic), or ``(best_rank, -1, 0)``.

    The covariance of ``slopes_h - A_h gamma_b`` is exact: with ``S`` the
    inverse normal matrix of the quadratic fit and the points of ``h`` the
    first of ``b``, ``cov(slopes_h, gamma_b) = [I | A_h] S[:, 2nd]`` and the
    slopes' covariance is ``M_h^-1 - S12 A^T - A S21 - A S22 A^T``.
    """
    for comp in range(2):
        for m in range(3):
            jcol = 3 + m
            _inverse_entry(L[comp], 6, scale, 1, jcol, work)
            for i in range(1, 6):
                v = work[i] * scale[i] * scale[jcol]
                if i < 3:
                    s13[comp, i - 1, m] = v
                else:
                    s33[comp, i - 3, m] = v
    best_sd = -1.0
    best_g2 = 0.0
    sl = np.empty((2, 2))
    cv = np.empty((2, 3))
    for j in range(n_h):
        if h_k[j] >= kk:
            continue
        for comp in range(2):
            _two_scale_slopes(h_sl[j, comp], h_al[j, comp], h_cv[j, comp], beta[comp], s13[comp],
                              s33[comp], sl[comp], cv[comp])
        jr00, jr01, jr10, jr11, _, g00, g01, g10, g11, var_ln = _slopes_jacobian(
            sl[0, 0], sl[0, 1], sl[1, 0], sl[1, 1], cv, hmax)
        if not var_ln > 0.0:
            continue
        rank = var_ln
        if pilot_ranks:
            rank = _ln_det_form(cv, q[0], q[1], q[2], q[3], hmax)
            if not rank > 0.0:
                rank = var_ln
        if not rank < best_rank:
            continue  # the gate only rejects and the penalty only adds
        # the quadratic's change across the b points: less 1.5 times its noise, the
        # truncation the bias estimate cannot test (penalty); plus twice, the gate
        ctop, cup = _order_changes(L, 6, scale, work, beta, U, kk, g00, g01, g10, g11, hmax,
                                   _ADAPTIVE_TOP_NSIG, _ADAPTIVE_TWO_GATE_NSIG, 2, cov_o, grad_o)
        if cup > _ADAPTIVE_TWO_GATE:
            continue
        rank += (_ADAPTIVE_TOP_COEF * ctop) ** 2
        if rank < best_rank:
            best_rank = rank
            best_sd = np.sqrt(var_ln)
            best_g2 = _centre_gradient2(L, 6, scale, work, beta, g00, g01, g10, g11, hmax,
                                        cov_o)
            _rotate_back(c, s, jr00, jr01, jr10, jr11, jb)
    return best_rank, best_sd, best_g2


@njit(**JIT_OPTIONS)
def _cubic_alias(L, scale, A, g00, g01, g10, g11, hmax, rhs_al, sol_al, v3):
    """How the slopes of a quadratic fit (factors ``L`` of its normal
    matrices ``A``, 6 coefficients) take up the four cubic monomials,
    weighted by ``d ln|det| / dJ'`` (``g``): ``v3[comp, m]`` is the change of
    ``ln|det J|`` per unit of cubic coefficient ``m`` of component ``comp``.
    The alias of monomial ``m`` is ``(X^T W X)^-1 X^T W u_m``, from the
    normal matrix's cross block (the design holds every cubic monomial)."""
    for comp in range(2):
        ga = g00 if comp == 0 else g10
        gb = g01 if comp == 0 else g11
        for m in range(4):
            for i in range(6):
                rhs_al[i] = A[comp, 6 + m, i]
            _factored_solve(L[comp], 6, scale, rhs_al, sol_al)
            v3[comp, m] = (ga * sol_al[1] + gb * sol_al[2]) / hmax


@njit(**JIT_OPTIONS)
def _cubic_alias_bias2(A, L, scale, rhs, beta, work, cov_o, v3):
    """The squared bias of ``ln|det J|`` that the cubic terms of the map put
    into a quadratic fit's slopes, beyond its noise:
    ``(|b| - _ADAPTIVE_CUBIC_NSIG sd(b))_+^2`` with ``b = sum v3 c3``, ``c3``
    the cubic coefficients of the cubic fit of the whole row (``A``, ``rhs``
    its normal sums once every point is in) and ``sd(b)`` from their
    covariance; 0 when that fit is singular. The noise is subtracted as in
    ``c_top`` (``_ADAPTIVE_TOP_NSIG``): with ``b^2 - var b`` (an unbiased
    estimate of the squared bias, clipped at 0) a bias-free fit would gain
    half its ``var b`` on average, which made the errors of cluster arcs at
    10-20 mas conservative (Gaussian-equivalent widths down to 0.71).

    At the ends of a constellation the neighbourhoods are one-sided and
    their slopes alias the cubic terms most, so a quadratic whose linear
    test passed (at 20 mas the test cannot see them) regresses towards the
    constellation's mean; the whole row's cubic terms, with the longest lever
    arm, are the least noisy estimate of them there."""
    for i in range(_ADAPTIVE_NCOEF_MAX):
        scale[i] = 1.0  # the row's own radius: the monomials are of u / hmax
    for comp in range(2):
        if _cholesky_factor(A[comp], 10, scale, L[comp], 1e-13) < 10:
            return 0.0
        _factored_solve(L[comp], 10, scale, rhs[comp], beta[comp])
    _block_covariance(L, 10, scale, 6, 4, work, cov_o)
    b = 0.0
    var = 0.0
    for comp in range(2):
        for i in range(4):
            b += v3[comp, i] * beta[comp, 6 + i]
            for j in range(4):
                var += v3[comp, i] * cov_o[comp, i, j] * v3[comp, j]
    return max(abs(b) - _ADAPTIVE_CUBIC_NSIG * np.sqrt(max(var, 0.0)), 0.0) ** 2


@njit(**JIT_OPTIONS)
def _nested_chi2(L, p, scale, rhs, ywy, sol):
    """Weighted chi-square of both components' fits with ``p`` coefficients
    (the leading block of the factors ``L``), from the normal sums alone: at
    the least-squares solution ``beta`` (into ``sol``), ``r^T W r = y^T W y -
    beta^T rhs``."""
    chi2 = 0.0
    for comp in range(2):
        _factored_solve(L[comp], p, scale, rhs[comp], sol[comp])
        w_sum = ywy[comp]
        for i in range(p):
            w_sum -= sol[comp, i] * rhs[comp, i]
        chi2 += max(w_sum, 0.0)
    return chi2


@njit(**JIT_OPTIONS)
def _model_error(cand_ln, cand_var, cand_k, cand_dr, cand_ok, n_cand, ln_c, k_c, dr_c,
                 lookahead, curv):
    """Model error (variance of ``ln|det J|``) of the chosen fallback fit
    (``ln_c`` on ``k_c`` points at degree ``dr_c``, curvature ``curv``).

    The mean of the squared changes of ``ln|det J|`` beyond each fit's own
    noise over the other self-consistent fits and the next ``lookahead``
    larger neighbourhoods of the same degree (the model spread), with the
    square of the truncation error ``_ADAPTIVE_CURV_COEF * curv^2`` as one
    more entry of that mean: with few comparisons (8 sources) the truncation
    term carries it, with dozens the comparisons do.
    """
    spread = 0.0
    n_spread = 0
    for i in range(n_cand):
        near = cand_dr[i] == dr_c and cand_k[i] > k_c and cand_k[i] <= k_c + lookahead
        itself = cand_k[i] == k_c and cand_dr[i] == dr_c
        if (cand_ok[i] or near) and not itself:
            # a difference beyond that fit's own noise is evidence of bias
            spread += max((cand_ln[i] - ln_c) ** 2 - cand_var[i], 0.0)
            n_spread += 1
    trunc = _ADAPTIVE_CURV_COEF * curv * curv
    return (spread + trunc * trunc) / (n_spread + 1.0)


# Kept whole (noqa): one jitted function keeps the incremental Cholesky state (L, scale,
# work) in local arrays while candidates are added one by one; split into helpers, the
# innermost loop would pay call and argument overhead for every candidate.
@njit(**JIT_OPTIONS)
def _adaptive_pair(t1, t2, s1, s2, a, row, pilot, chi2_crit, min_extra, report_extra,  # noqa: C901, PLR0915
                   min_candidates, lookahead, k_dense, order, dsort, U, Yr, W, A, rhs, L, scale,
                   beta, work, jac_out):
    """Adaptive local-polynomial Jacobian at pair ``a``; returns (ln_sd, status, dof).

    The points are those of the neighbour ``row`` of ``a`` (``a`` included).
    The noise of each baseline is the effective variance
    ``s1^2 I + s2^2 P P^T`` (P the pilot Jacobian at ``a``); in the frame of
    the eigenvectors of ``P P^T`` the two output components are independent,
    so each is a weighted polynomial fit of its own. Candidate fits use the
    ``k`` nearest neighbours of ``a`` in L2 (``a`` included): a fit of degree
    ``d`` (1 or 2) tests whether the map is that smooth there (chi-square of
    both components against ``chi2_crit[dof]``; a linear one also needs the
    quadratic terms of the same points to be insignificant, the nested
    likelihood-ratio test at ``_ADAPTIVE_NEST_ALPHA``: the chi-square test
    spreads its power over ``2 (k - 3)`` degrees of freedom and passes large
    neighbourhoods whose curvature the nested test sees plainly, and with it
    the truncation of the quadratic reported for them), and the estimate
    reported for that neighbourhood is the fit of degree ``d + report_extra`` on the
    same points, whose truncation bias is one order smaller (robust bias
    correction). A linear fit that passed its test on ``h`` points also
    gives *two-scale* estimates (:func:`_two_scale`): its slopes less the
    alias of the quadratic terms of each larger neighbourhood ``b > h``
    whose quadratic fit passes its own test and whose cubic terms are
    insignificant (the nested test of the quadratic against the cubic on the
    ``b`` points, at ``_ADAPTIVE_TWO_NEST_ALPHA``, where ``b`` is enough for a
    cubic), provided that quadratic is known to be gentle (its change of
    ``ln|det J|`` across the ``b`` points plus ``_ADAPTIVE_TWO_GATE_NSIG``
    times its noise at most ``_ADAPTIVE_TWO_GATE``); its ``c_top`` is that
    quadratic's change.
    Among the passing estimates, the one whose
    reported fit has the smallest variance of ``ln|det J|`` *along the
    pilot's gradient* plus ``(_ADAPTIVE_TOP_COEF c_top)^2`` wins
    (``ADAPTIVE_OK``), and its own error is returned. The ranking uses the
    fits' covariances (their designs) and the common pilot, not each fit's
    own noisy ``det J``: ranked by their own errors, which scale as
    ``1 / |det J|``, fits whose noise raised ``|det J|`` would win (a
    selection bias towards over-estimates). ``c_top`` (:func:`_order_change`)
    is the largest change of ``ln|det J|`` across the neighbourhood that the
    reported fit's highest-degree terms alone predict, less
    ``_ADAPTIVE_TOP_NSIG`` times its noise: where it is large, the terms
    the fit truncates next are likely to matter, so a smaller neighbourhood
    is preferred to a larger one that passed its test only because that
    test cannot see them.

    If none passes, the reported fits that pass the chi-square test on their
    own are used: the one with the smallest error scaled by its
    leave-one-out (PRESS) misfit, widened by its model error: the mean,
    over the other self-consistent fits and the next ``lookahead`` larger
    neighbourhoods of its degree, of the squared change of ``ln|det J|``
    beyond each fit's noise (the maximum over them, used before, doubled
    the errors of galaxy-scale arcs), with the square of a truncation error
    ``_ADAPTIVE_CURV_COEF * c^2`` as one more term of that mean. Both
    estimate the chosen fit's bias: with few comparisons (8 sources) the
    truncation term carries the mean, with many the comparisons do (the
    larger of the two, used before, let the truncation term double the
    errors of fits with dozens of comparisons; their sum counted the bias
    twice) (``ADAPTIVE_MISFIT``, when at least ``min_candidates`` fits are
    self-consistent). ``c``, the chosen fit's
    curvature, is the largest ``|tr(J^-1 dJ(u))| - _ADAPTIVE_CURV_NSIG sd``
    over the neighbourhood's offsets ``u``: ``dJ(u)`` the change of the
    Jacobian that the fit's second-order terms predict there, ``sd`` the
    standard error of that trace from the fit's covariance. It measures how
    much ``ln|det J|`` varies across the neighbourhood beyond what noise in
    the second-order terms would show. With few residual degrees of
    freedom, a fit of a map that bends that much passes its chi-square
    while its derivative at the centre is biased beyond its noise
    (galaxy-scale folds with 8 sources, ``c`` of 1-2); gently curved
    cluster maps (``c`` ~ 0.2) are barely widened, and noisy fits of
    nearly linear maps (20 mas) are not widened for their noise.

    Otherwise (one self-consistent fit only, or none) the pair is
    ``ADAPTIVE_UNTESTABLE``: its bias cannot be judged well enough to test
    it, but the error reported with it is built the same way, so that it
    holds as far as it can: the self-consistent fit, or else the least-bad
    one (smallest PRESS-scaled error), widened by the same model error
    (:func:`_model_error`; with no self-consistent fit the comparisons are
    the next ``lookahead`` neighbourhoods of its degree). Measured on the
    calibration suite's untestable pairs, their pulls' Gaussian-equivalent
    width falls from 1.41 (PRESS-scaled error alone) to 0.87.

    An ``ADAPTIVE_OK`` quadratic reported for a passing *linear* test also
    holds the bias that the map's cubic terms alias into its slopes, beyond
    ``_ADAPTIVE_CUBIC_NSIG`` times its noise (:func:`_cubic_alias_bias2`,
    the cubic terms from the cubic fit of the whole row): where the
    neighbourhood is one-sided (the ends of a constellation) that alias is
    largest and the linear test at 10-20 mas cannot see it.

    Every error returned also holds the pair's own L2 noise ``s2[a]``: the
    offsets of the neighbours are measured from the pair's noisy position, so
    the fits take the Jacobian there, not at the true position, which adds
    ``s2[a]^2 |grad ln|det J||^2`` to the variance (the gradient from the
    reported fit's second-order terms, less its noise:
    :func:`_centre_gradient2`). The L1 noise of the pair is common to all
    the outputs' offsets and goes into the fits' constant terms.

    Neighbourhoods of up to ``k_dense`` points are all tried; larger ones on
    a geometric grid (each at least 1/8 larger than the last tried) and the
    full row (``k_dense >= K`` tries every one).

    ``dof`` is the number of degrees of freedom the error was estimated
    with: infinite for ``ADAPTIVE_OK`` (the exact propagation of the known
    position errors), the residual degrees of freedom ``2 (k - p)`` of the
    chosen fit otherwise (its PRESS misfit and the spread are estimates
    from that many residuals, so its significance follows Student's t).

    The reported fit's chi-square and PRESS (a pass over the points with
    the leverages, the costly part) are computed only while no neighbourhood
    has passed: once one has, only a better-ranked passing fit can change
    the result.
    """
    n = row.shape[0]
    # pilot effective-variance frame
    m00 = pilot[0, 0] * pilot[0, 0] + pilot[0, 1] * pilot[0, 1]
    m01 = pilot[0, 0] * pilot[1, 0] + pilot[0, 1] * pilot[1, 1]
    m11 = pilot[1, 0] * pilot[1, 0] + pilot[1, 1] * pilot[1, 1]
    half_tr = 0.5 * (m00 + m11)
    disc = np.sqrt(0.25 * (m00 - m11) ** 2 + m01 * m01)
    ev0 = half_tr + disc
    ev1 = max(half_tr - disc, 0.0)
    ang = 0.5 * np.arctan2(2.0 * m01, m00 - m11)
    c = np.cos(ang)
    s = np.sin(ang)
    # R = [[c, -s], [s, c]]: columns are the eigenvectors; y' = R^T y
    for jj in range(n):
        b = row[jj]
        dx = t2[b, 0] - t2[a, 0]
        dy = t2[b, 1] - t2[a, 1]
        dsort[jj] = dx * dx + dy * dy
    idx = np.argsort(dsort[:n])
    for k in range(n):
        order[k] = row[idx[k]]
    # distances in rank order (idx is a fresh array: dsort may be overwritten)
    for k in range(n):
        b = order[k]
        dx = t2[b, 0] - t2[a, 0]
        dy = t2[b, 1] - t2[a, 1]
        dsort[k] = dx * dx + dy * dy
    hmax = np.sqrt(dsort[n - 1])
    if not hmax > 0.0:
        jac_out[:, :] = np.nan
        return np.nan, ADAPTIVE_FAILED, 0.0
    for k in range(n):
        b = order[k]
        _monomials((t2[b, 0] - t2[a, 0]) / hmax, (t2[b, 1] - t2[a, 1]) / hmax, U[k])
        y0 = t1[b, 0] - t1[a, 0]
        y1 = t1[b, 1] - t1[a, 1]
        Yr[k, 0] = c * y0 + s * y1
        Yr[k, 1] = -s * y0 + c * y1
        v1 = s1[b] * s1[b]
        v2 = s2[b] * s2[b]
        W[k, 0] = 1.0 / (v1 + v2 * ev0)
        W[k, 1] = 1.0 / (v1 + v2 * ev1)
    for comp in range(2):
        for i in range(_ADAPTIVE_NCOEF_MAX):
            rhs[comp, i] = 0.0
            for j in range(_ADAPTIVE_NCOEF_MAX):
                A[comp, i, j] = 0.0

    # gradient of ln|det| at the pilot, in the rotated frame (P' = R^T P): it ranks
    # the passing fits (see above); a singular pilot ranks by the fits' own errors
    pr00 = c * pilot[0, 0] + s * pilot[1, 0]
    pr01 = c * pilot[0, 1] + s * pilot[1, 1]
    pr10 = -s * pilot[0, 0] + c * pilot[1, 0]
    pr11 = -s * pilot[0, 1] + c * pilot[1, 1]
    pdet = pr00 * pr11 - pr01 * pr10
    pilot_ranks = np.isfinite(pdet) and pdet != 0.0
    q00 = q01 = q10 = q11 = 0.0
    if pilot_ranks:
        q00 = pr11 / pdet
        q01 = -pr10 / pdet
        q10 = -pr01 / pdet
        q11 = pr00 / pdet
    best_sd = np.inf
    best_g2 = 0.0
    best_rank = np.inf
    found = False
    cand_ln = np.empty(4 * n)
    cand_var = np.empty(4 * n)
    cand_k = np.empty(4 * n, dtype=np.int64)
    cand_dr = np.empty(4 * n, dtype=np.int64)
    cand_ok = np.empty(4 * n, dtype=np.bool_)
    n_cand = 0
    n_consistent = 0
    k_last = 0
    # the fallback fits while none passes, by slot: 0 the best self-consistent
    # one, 1 the least-bad of the others (smallest PRESS-scaled error each)
    fb_sd = np.full(2, np.inf)
    fb_ln = np.zeros(2)
    fb_k = np.zeros(2, dtype=np.int64)
    fb_dr = np.zeros(2, dtype=np.int64)
    fb_dof = np.zeros(2)
    fb_curv = np.zeros(2)
    fb_g2 = np.zeros(2)
    jfb = np.empty((2, 2, 2))
    cov = np.empty((2, 3))
    spow = np.empty(4)
    jb = np.empty((2, 2))
    ywy = np.zeros(2)
    cov_o = np.empty((2, 4, 4))
    grad_o = np.empty(4)
    # linear fits that passed their test, for the two-scale estimates
    two_scale = report_extra == 1
    n_h = 0
    h_k = np.empty(n, dtype=np.int64)
    h_sl = np.empty((n, 2, 2))
    h_al = np.empty((n, 2, 2, 3))
    h_cv = np.empty((n, 2, 3))
    rhs_al = np.empty(3)
    sol_al = np.empty(3)
    s13 = np.empty((2, 2, 3))
    s33 = np.empty((2, 3, 3))
    qv = np.array([q00, q01, q10, q11])  # the pilot's gradient, for _two_scale
    best_lin = False
    beta_n = np.empty((2, _ADAPTIVE_NCOEF_MAX))
    best_v3 = np.empty((2, 4))
    rhs_al6 = np.empty(6)
    sol_al6 = np.empty(6)
    for k in range(n):
        # add point order[k] to both normal systems (full cubic design)
        for comp in range(2):
            w = W[k, comp]
            ywy[comp] += w * Yr[k, comp] * Yr[k, comp]
            for i in range(_ADAPTIVE_NCOEF_MAX):
                wi = w * U[k, i]
                rhs[comp, i] += wi * Yr[k, comp]
                for j in range(i + 1):
                    A[comp, i, j] += wi * U[k, j]
        kk = k + 1
        hk = np.sqrt(dsort[k])
        if not hk > 0.0:
            continue
        # beyond k_dense points, fits are tried on a geometric grid of
        # neighbourhood sizes only (steps of about 1/8), and at the full row
        if kk > k_dense and kk < n:
            if 8 * (kk - k_last) < k_last:
                continue
        k_last = kk
        # the largest fit of this neighbourhood; one factorisation per component
        # serves all fits (the leading blocks of the factor)
        p_max = 0
        for dt in range(1, 4 - report_extra):
            if kk >= _ncoef(dt + report_extra) + min_extra:
                p_max = _ncoef(dt + report_extra)
        if p_max == 0:
            continue
        hr = hmax / hk
        for d in range(4):
            spow[d] = hr ** float(d)
        for i in range(_ADAPTIVE_NCOEF_MAX):
            scale[i] = spow[int(_MONOMIAL_DEGREE[i])]
        n_fac0 = _cholesky_factor(A[0], p_max, scale, L[0], 1e-13)
        n_fac1 = _cholesky_factor(A[1], p_max, scale, L[1], 1e-13)
        n_fac = min(n_fac0, n_fac1)
        for dt in range(1, 4 - report_extra):
            pt = _ncoef(dt)
            pr = _ncoef(dt + report_extra)
            # a quadratic test also serves the two-scale estimates of the stored
            # linear fits, from fewer points than its own reported (cubic) fit needs
            # (stored fits come in increasing size: the first is the smallest)
            bias_fit = two_scale and dt == 2 and n_h > 0 and h_k[0] < kk and kk >= pt + min_extra
            if kk < pr + min_extra and not bias_fit:
                continue
            # test fit: chi-square of both components at degree dt
            if n_fac < pt:
                continue
            chi2 = _nested_chi2(L, pt, scale, rhs, ywy, beta)
            dof = 2 * (kk - pt)
            passed = chi2 <= chi2_crit[dof]
            if passed and dt == 1 and pr - pt == 3 and n_fac >= pr and _ADAPTIVE_NEST:
                # the nested test: the chi-square the quadratic terms remove
                passed = chi2 - _nested_chi2(L, pr, scale, rhs, ywy, beta_n) <= _ADAPTIVE_NEST_CRIT6
            if passed and two_scale and dt == 1:
                # keep the linear fit: a quadratic fit of a larger neighbourhood
                # that passes its own test may correct its bias (_two_scale)
                _store_linear(L, scale, A, beta, work, rhs_al, sol_al, h_sl, h_al, h_cv, n_h)
                h_k[n_h] = kk
                n_h += 1
            # the two-scale estimates also need the quadratic's cubic terms to be
            # insignificant (the nested test of the larger neighbourhood)
            two_passed = passed
            if passed and bias_fit and _ADAPTIVE_TWO_NEST and n_fac >= _ncoef(3):
                two_passed = (chi2 - _nested_chi2(L, _ncoef(3), scale, rhs, ywy, beta_n)
                              <= _ADAPTIVE_TWO_NEST_CRIT8)
            if two_passed and bias_fit:
                rank2, sd2, g2 = _two_scale(L, scale, work, beta, U, kk, hmax, h_k, h_sl, h_al,
                                            h_cv, n_h, c, s, pilot_ranks, qv, best_rank, s13, s33,
                                            cov_o, grad_o, jb)
                if sd2 > 0.0:
                    best_rank = rank2
                    best_sd = sd2
                    best_g2 = g2
                    found = True
                    best_lin = False
            if kk < pr + min_extra:
                continue
            if found and not passed:
                continue  # only a better-ranked passing fit can change the result
            # reported fit: degree dt + report_extra on the same points, with
            # its covariance
            if n_fac < pr:
                continue
            for comp in range(2):
                _factored_solve(L[comp], pr, scale, rhs[comp], beta[comp])
                _slope_covariance(L[comp], pr, scale, work, cov[comp])
            # J' rows (rotated frame) and d ln|det| / dJ' = J'^-T
            jr00, jr01, jr10, jr11, det, g00, g01, g10, g11, var_ln = _slopes_jacobian(
                beta[0, 1], beta[0, 2], beta[1, 1], beta[1, 2], cov, hmax)
            if not var_ln > 0.0:
                continue
            sd = np.sqrt(var_ln)
            if passed:
                rank = var_ln
                if pilot_ranks:
                    rank = _ln_det_form(cov, q00, q01, q10, q11, hmax)
                    if not rank > 0.0:
                        rank = var_ln
                if rank < best_rank and _ADAPTIVE_TOP_COEF > 0.0:
                    # the truncation the fit cannot test: its top-order change
                    ctop = _order_change(L, pr, scale, work, beta, U, kk, g00, g01, g10, g11,
                                         hmax, _ADAPTIVE_TOP_NSIG, dt + report_extra, cov_o,
                                         grad_o)
                    rank += (_ADAPTIVE_TOP_COEF * ctop) ** 2
                if rank < best_rank:
                    best_rank = rank
                    best_sd = sd
                    best_g2 = _centre_gradient2(L, pr, scale, work, beta, g00, g01, g10, g11,
                                                hmax, cov_o)
                    found = True
                    _rotate_back(c, s, jr00, jr01, jr10, jr11, jb)
                    # a quadratic licensed by a linear test: keep how its slopes
                    # alias the cubic terms, weighted by d ln|det| / dJ'
                    best_lin = dt == 1 and pr == 6 and _ADAPTIVE_CUBIC_BIAS
                    if best_lin:
                        _cubic_alias(L, scale, A, g00, g01, g10, g11, hmax, rhs_al6, sol_al6,
                                     best_v3)
            if not found:
                # the reported fit's chi-square and leave-one-out (PRESS) misfit
                chi2_r = 0.0
                press = 0.0
                press_null = 0.0
                for comp in range(2):
                    Lc = L[comp]
                    for q in range(kk):
                        r = Yr[q, comp]
                        for i in range(pr):
                            r -= U[q, i] * beta[comp, i]
                        chi2_r += W[q, comp] * r * r
                        # leverage: w |L^-1 S u|^2
                        lev = 0.0
                        for i in range(pr):
                            v = U[q, i] * scale[i]
                            for m in range(i):
                                v -= Lc[i, m] * work[m]
                            work[i] = v / Lc[i, i]
                            lev += work[i] * work[i]
                        lev *= W[q, comp]
                        if not lev < 1.0 - 1e-9:
                            lev = 1.0 - 1e-9
                        press += W[q, comp] * r * r / ((1.0 - lev) * (1.0 - lev))
                        press_null += 1.0 / (1.0 - lev)
                dof_r = 2 * (kk - pr)
                sdf = sd * np.sqrt(max(1.0, press / press_null))
                consistent = chi2_r <= chi2_crit[dof_r]
                if n_cand < cand_ln.shape[0]:
                    cand_ln[n_cand] = np.log(abs(det))
                    cand_var[n_cand] = var_ln
                    cand_k[n_cand] = kk
                    cand_dr[n_cand] = dt + report_extra
                    cand_ok[n_cand] = consistent
                    n_cand += 1
                if consistent:
                    n_consistent += 1
                slot = 0 if consistent else 1
                if sdf < fb_sd[slot]:
                    fb_sd[slot] = sdf
                    fb_ln[slot] = np.log(abs(det))
                    fb_k[slot] = kk
                    fb_dr[slot] = dt + report_extra
                    fb_dof[slot] = float(dof_r)
                    fb_g2[slot] = _centre_gradient2(L, pr, scale, work, beta, g00, g01, g10,
                                                    g11, hmax, cov_o)
                    # curvature: the largest change of ln|det J| over the
                    # neighbourhood that the fit's second-order terms predict,
                    # less twice its noise (a noisy fit's second-order terms
                    # would otherwise pass for curvature)
                    fb_curv[slot] = _order_change(L, pr, scale, work, beta, U, kk, g00, g01,
                                                  g10, g11, hmax, _ADAPTIVE_CURV_NSIG, 2, cov_o,
                                                  grad_o)
                    _rotate_back(c, s, jr00, jr01, jr10, jr11, jfb[slot])
    # the pair's own L2 noise moves the point where the fits take the Jacobian
    # (every offset is measured from it): s2^2 |grad ln|det J||^2
    v_centre = s2[a] * s2[a]
    if found:
        _copy_jacobian(jb, jac_out)
        bias2 = 0.0
        if best_lin and n >= _ncoef(3) + min_extra:
            bias2 = _cubic_alias_bias2(A, L, scale, rhs, beta, work, cov_o, best_v3)
        return np.sqrt(best_sd * best_sd + v_centre * best_g2 + bias2), ADAPTIVE_OK, np.inf
    # else the self-consistent fallback fit, or the least-bad one, widened by its
    # model error; tested ("misfit") only with enough self-consistent fits to
    # judge that error, otherwise reported with it but "untestable"
    for slot in range(2):
        if fb_sd[slot] < np.inf:
            _copy_jacobian(jfb[slot], jac_out)
            model = _model_error(cand_ln, cand_var, cand_k, cand_dr, cand_ok, n_cand,
                                 fb_ln[slot], fb_k[slot], fb_dr[slot], lookahead, fb_curv[slot])
            sd = np.sqrt(fb_sd[slot] * fb_sd[slot] + model + v_centre * fb_g2[slot])
            tested = slot == 0 and n_consistent >= min_candidates
            return sd, ADAPTIVE_MISFIT if tested else ADAPTIVE_UNTESTABLE, fb_dof[slot]
    jac_out[:, :] = np.nan
    return np.nan, ADAPTIVE_FAILED, 0.0


@njit(**JIT_OPTIONS)
def adaptive_jacobians_knn(t1, t2, nbr, s1, s2, chi2_crit, min_extra, report_extra,
                           min_candidates, lookahead, k_dense, n_pass, weight_power, cond_max, jac,
                           ln_sd, status, dof):
    """The adaptive Jacobian at every pair (see :func:`_adaptive_pair`), from its row.

    The pilot Jacobian of the first pass is the first-order Quad one (on the
    same neighbour rows); each further pass uses the previous pass's result
    (its own pilot where that failed). ``ln_sd`` receives the standard error
    of ``ln|det J|`` and ``dof`` the degrees of freedom it was estimated
    with (see :func:`_adaptive_pair`). ``chi2_crit`` must cover ``2 K``
    degrees of freedom.
    """
    adaptive_rows_knn(t1, t2, nbr, s1, s2, chi2_crit, min_extra, report_extra, min_candidates,
                      lookahead, k_dense, n_pass, weight_power, cond_max, np.arange(t1.shape[0]),
                      jac, ln_sd, status, dof)


@njit(**JIT_OPTIONS)
def adaptive_rows_knn(t1, t2, nbr, s1, s2, chi2_crit, min_extra, report_extra,
                      min_candidates, lookahead, k_dense, n_pass, weight_power, cond_max,
                      rows, jac, ln_sd, status, dof):
    """:func:`adaptive_jacobians_knn` for the pairs ``rows`` only (the other
    entries of the outputs are left as they are).

    Each pair's estimate depends on its own row and pilot only, so disjoint
    sets of pairs can run in separate threads (the kernels release the GIL),
    and a subset gives the same estimates as the whole, bit for bit. With a
    cap (``k_dense`` below the row length ``K``) the pilot passes use the
    ``2 k_dense`` nearest points of each row only.
    """
    k = nbr.shape[1]
    m = rows.shape[0]
    pilot = np.empty((m, 2, 2))
    acc = np.empty(7)
    Aq = np.empty((k - 1, 2))
    Yq = np.empty((k - 1, 2))
    sol = np.empty((2, 2))
    for r in range(m):
        a = rows[r]
        # the first-order Quad pilot, on the pair's row
        _pair_sums(t1, t2, _row(nbr, a), a, weight_power, acc)
        pa = pilot[r]
        ok = _solve_normal(acc, pa)
        if not ok:
            ok = _jacobian_quad(t1, t2, a, _row(nbr, a), 1, weight_power, cond_max, Aq, Yq,
                                sol, pa) == STATUS_OK
        if not ok:
            pa[0, 0] = 1.0
            pa[0, 1] = 0.0
            pa[1, 0] = 0.0
            pa[1, 1] = 1.0
    order = np.empty(k, dtype=np.int64)
    dsort = np.empty(k)
    U = np.empty((k, _ADAPTIVE_NCOEF_MAX))
    Yr = np.empty((k, 2))
    W = np.empty((k, 2))
    A = np.empty((2, _ADAPTIVE_NCOEF_MAX, _ADAPTIVE_NCOEF_MAX))
    rhs = np.empty((2, _ADAPTIVE_NCOEF_MAX))
    L = np.empty((2, _ADAPTIVE_NCOEF_MAX, _ADAPTIVE_NCOEF_MAX))
    scale = np.empty(_ADAPTIVE_NCOEF_MAX)
    beta = np.empty((2, _ADAPTIVE_NCOEF_MAX))
    work = np.empty(_ADAPTIVE_NCOEF_MAX)
    for p in range(n_pass):
        # with a cap (k_dense < K), the passes that only make the next pass's
        # pilot use the 2 k_dense nearest points
        k_row = k if (p + 1 == n_pass or k_dense >= k) else min(k, 2 * k_dense)
        for r in range(m):
            a = rows[r]
            ln_sd[a], status[a], dof[a] = _adaptive_pair(
                t1, t2, s1, s2, a, _row(nbr, a)[:k_row], pilot[r], chi2_crit, min_extra,
                report_extra, min_candidates, lookahead, k_dense, order, dsort, U, Yr, W, A, rhs, L,
                scale, beta, work, jac[a])
        if p + 1 < n_pass:
            for r in range(m):
                a = rows[r]
                if status[a] != ADAPTIVE_FAILED:
                    for i in range(2):
                        for j in range(2):
                            pilot[r, i, j] = jac[a, i, j]


@njit(**JIT_OPTIONS)
def adaptive_jacobians(t1, t2, s1, s2, chi2_crit, min_extra, report_extra,
                       min_candidates, lookahead, k_dense, n_pass, weight_power, cond_max, jac,
                       ln_sd, status, dof):
    """:func:`adaptive_jacobians_knn` with every point for every pair (no cap)."""
    adaptive_jacobians_knn(t1, t2, all_rows(t1.shape[0]), s1, s2, chi2_crit, min_extra,
                           report_extra, min_candidates, lookahead, k_dense, n_pass, weight_power,
                           cond_max, jac, ln_sd, status, dof)


@njit(**JIT_OPTIONS)
def adaptive_batch_knn(t1, t2, nbr, noise1, noise2, s1, s2, chi2_crit, min_extra,
                       report_extra, min_candidates, lookahead, k_dense, n_pass, weight_power,
                       cond_max, need, det_out, ln_sd_out, status_out, dof_out):
    """The adaptive estimator on ``B`` noisy copies of a constellation.

    ``noise1``, ``noise2`` are (B, N, 2) offsets; ``det_out``, ``ln_sd_out``,
    ``status_out`` and ``dof_out`` (B, N) receive the signed determinant, the
    error of its logarithm, the status code and the error's degrees of
    freedom, for the pairs of each copy where ``need`` (B, N) is true
    (:func:`adaptive_rows_knn`); the others get a NaN determinant and error
    and ``ADAPTIVE_FAILED``. The neighbour rows stay fixed.
    """
    nb = noise1.shape[0]
    n = t1.shape[0]
    p1 = np.empty((n, 2))
    p2 = np.empty((n, 2))
    jac = np.empty((n, 2, 2))
    st = np.empty(n, dtype=np.int64)
    sd = np.empty(n)
    df = np.empty(n)
    for k in range(nb):
        for i in range(n):
            for d in range(2):
                p1[i, d] = t1[i, d] + noise1[k, i, d]
                p2[i, d] = t2[i, d] + noise2[k, i, d]
        for i in range(n):
            jac[i, :, :] = np.nan
            sd[i] = np.nan
            st[i] = ADAPTIVE_FAILED
            df[i] = 0.0
        adaptive_rows_knn(p1, p2, nbr, s1, s2, chi2_crit, min_extra, report_extra,
                          min_candidates, lookahead, k_dense, n_pass, weight_power, cond_max,
                          np.flatnonzero(need[k]), jac, sd, st, df)
        for i in range(n):
            det_out[k, i] = jac[i, 0, 0] * jac[i, 1, 1] - jac[i, 0, 1] * jac[i, 1, 0]
            ln_sd_out[k, i] = sd[i]
            status_out[k, i] = st[i]
            dof_out[k, i] = df[i]
