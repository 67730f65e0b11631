"""The small dense solvers of the estimators' Numba kernels (unit-free, no checks).

- :func:`lstsq_mgs`: least squares by modified Gram-Schmidt, for the Quad
  estimators' weighted designs; :func:`mgs_factor`, its factorisation, also
  for the flux field's fits (:mod:`lensdual._flux_field_kernels`).
- :func:`cholesky_factor`, :func:`factored_solve`,
  :func:`inverse_entry`, :func:`slope_covariance`: Cholesky factors of the
  adaptive estimator's equilibrated normal matrices and what it reads off them.

Every matrix is a leading block of a larger work array, so one allocation
serves fits of every size.
"""

import numpy as np
from numba import njit

from .._numba import JIT_OPTIONS

__all__ = []


# the slope columns as numpy integers (see lensdual._numba)
_SLOPE_X = np.int64(1)
_SLOPE_Y = np.int64(2)


@njit(**JIT_OPTIONS)
def _equilibrate(A, ncol, scale):
    """Scale the columns of ``A[:, :ncol]`` to unit norm (norms into ``scale``).

    Returns False when a column is zero (or not finite).
    """
    M = A.shape[0]
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
    return True


@njit(**JIT_OPTIONS)
def _orthonormalise(A, ncol, R):
    """Modified Gram-Schmidt, two passes per column: ``A`` becomes Q, ``R`` the factor.

    Returns False when a column is dependent on the earlier ones (zero norm).
    """
    M = A.shape[0]
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
    return True


@njit(**JIT_OPTIONS)
def _well_conditioned(R, ncol, cond_max):
    """Whether the smallest pivot of ``R`` exceeds ``1 / cond_max`` of the largest."""
    rmax = 0.0
    rmin = np.inf
    for j in range(ncol):
        d = abs(R[j, j])
        rmax = max(rmax, d)
        rmin = min(rmin, d)
    return rmin * cond_max > rmax


@njit(**JIT_OPTIONS)
def _qr_solve(Q, R, Y, ncol, scale, sol):
    """``sol = S^-1 R^-1 Q^T Y`` for both columns of ``Y`` (``S = diag(scale)``)."""
    M = Q.shape[0]
    for c in range(2):
        for j in range(ncol):
            q = 0.0
            for m in range(M):
                q += Q[m, j] * Y[m, c]
            sol[j, c] = q
        for j in range(ncol - 1, -1, -1):
            v = sol[j, c]
            for i in range(j + 1, ncol):
                v -= R[j, i] * sol[i, c]
            sol[j, c] = v / R[j, j]
        for j in range(ncol):
            sol[j, c] /= scale[j]


@njit(**JIT_OPTIONS)
def mgs_factor(A, ncol, scale, R, cond_max):
    """Factor ``A[:, :ncol] = Q R S`` in place by modified Gram-Schmidt.

    The columns are scaled to unit norm first (their norms into ``scale``,
    ``S = diag(scale)``), then orthonormalised with two passes per column
    (``A`` becomes Q, ``R`` (>=ncol, >=ncol), zero below the diagonal,
    receives R). Returns False when a column vanishes or the smallest pivot
    is below ``1 / cond_max`` of the largest (the design is numerically rank
    deficient).
    """
    if not _equilibrate(A, ncol, scale):
        return False
    if not _orthonormalise(A, ncol, R):
        return False
    return _well_conditioned(R, ncol, cond_max)


@njit(**JIT_OPTIONS)
def lstsq_mgs(A, Y, ncol, sol, cond_max):
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
    scale = np.empty(ncol)
    R = np.zeros((ncol, ncol))
    if not mgs_factor(A, ncol, scale, R, cond_max):
        return False
    _qr_solve(A, R, Y, ncol, scale, sol)
    return True


@njit(**JIT_OPTIONS)
def cholesky_factor(A, p, scale, L, tol):
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
def factored_solve(L, p, scale, rhs, sol):
    """Solve ``(S A S) z = S rhs`` with the factor ``L`` of ``S A S``; ``sol = S z``."""
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
def inverse_entry(L, p, scale, i, j, work):
    """Entry (i, j) of ``(S A S)^-1`` scaled back: ``S (S A S)^-1 S`` at (i, j).

    ``work[:p]`` is left holding column ``j`` of ``(S A S)^-1``.
    """
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
def slope_covariance(L, p, scale, work, out):
    """Entries (1, 1), (1, 2), (2, 2) of ``S (S A S)^-1 S`` into ``out[:3]``.

    The same arithmetic as three :func:`inverse_entry` calls, with the solve
    for ``e_2`` made once for both entries that need it.
    """
    out[0] = inverse_entry(L, p, scale, _SLOPE_X, _SLOPE_X, work)
    out[2] = inverse_entry(L, p, scale, _SLOPE_Y, _SLOPE_Y, work)
    out[1] = work[1] * scale[1] * scale[2]
