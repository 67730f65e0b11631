"""Numba kernels of the profile-likelihood duality SNR (private module).

The estimated Jacobian ``J`` of a pair is Gaussian around the true one with
the covariance ``C`` of its fit, and the rest of the error of ``ln mu_size``
(the model error, the pair's own position noise) and the flux ratio's error
are Gaussian in ``ln|det J|`` with total variance ``v``. The duality
hypothesis ``|det J_true| = R`` (``R`` the flux ratio) is then tested by its
profile likelihood:

    T^2 = min_J  (J - J_hat)^T C^-1 (J - J_hat) + (ln R - ln|det J|)^2 / v,

the squared distance from the data to the hypothesis, which follows
``chi^2_1`` as long as the hypothesis surface is nearly flat over the
noise. Linearising ``ln|det J|`` at ``J_hat`` (``(ln R - ln|det J_hat|)^2 /
(g^T C g + v)``) is the same statistic where the error of ``ln|det J|`` is
small; where it is not, ``|det J|`` is not log-normal: an over-estimate of
``|det J|`` comes with an under-estimated error, and the linearised SNR
flags it. Both signs of ``det J`` are tried (the flux ratio does not give
the parity).

For a hypothesis ``det J = D`` the constrained minimum is the closest
point on a quadric: in the whitened coordinates ``y = V^T L^-1 vec J``
(``C = L L^T``, ``V`` the eigenvectors of ``Q = L^T M L / 2``, ``det J = vec
J^T M vec J / 2``) the constraint is ``sum_i q_i y_i^2 = D`` and the
minimum is at ``y_i = y_hat_i / (1 - 2 lambda q_i)``, the root of the
secular equation in the interval of ``lambda`` where every ``1 - 2 lambda
q_i`` is positive (where it is monotonic).
"""

import numpy as np
from numba import njit

from ._numba import JIT_OPTIONS_NUMPY_ERRORS as JIT_OPTIONS

__all__ = []

_N_BISECT = 100
#: Most Jacobi sweeps of a 4 x 4 eigenproblem (it converges in 5-10).
_JACOBI_SWEEPS = 50
_N_GRID = 24
_N_GOLDEN = 40
#: Newton's steps on the secular equation stop once a step moves lambda by less than
#: this fraction of it (the step's quadratic convergence takes it to float resolution).
_LAM_RTOL = 1e-10
#: The golden-section search stops at a bracket this many times the rest's noise.
_U_TOL = 1e-6


@njit(**JIT_OPTIONS)
def _rotate(a, v, p, r):
    """One Jacobi rotation zeroing ``a[p, r]`` (``a`` symmetric 4 x 4, ``v`` the
    eigenvectors so far)."""
    apr = a[p, r]
    theta = 0.5 * (a[r, r] - a[p, p]) / apr
    t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
    c = 1.0 / np.sqrt(t * t + 1.0)
    sn = t * c
    for k in range(4):
        akp = a[k, p]
        akr = a[k, r]
        a[k, p] = c * akp - sn * akr
        a[k, r] = sn * akp + c * akr
    for k in range(4):
        apk = a[p, k]
        ark = a[r, k]
        a[p, k] = c * apk - sn * ark
        a[r, k] = sn * apk + c * ark
    for k in range(4):
        vkp = v[k, p]
        vkr = v[k, r]
        v[k, p] = c * vkp - sn * vkr
        v[k, r] = sn * vkp + c * vkr


@njit(**JIT_OPTIONS)
def _eigh4(a, w, v):
    """Eigenvalues ``w`` (ascending) and eigenvectors (columns of ``v``) of the
    symmetric 4 x 4 ``a`` (overwritten), by cyclic Jacobi rotations to float
    resolution: written out, so that it compiles in a fraction of LAPACK's
    bindings' time."""
    for i in range(4):
        for j in range(4):
            v[i, j] = 1.0 if i == j else 0.0
    for _ in range(_JACOBI_SWEEPS):
        off = 0.0
        scale = 0.0
        for i in range(4):
            scale += a[i, i] * a[i, i]
            for j in range(i + 1, 4):
                off += a[i, j] * a[i, j]
        if off <= 1e-32 * scale:
            break
        for p in range(3):
            for r in range(p + 1, 4):
                if a[p, r] != 0.0:
                    _rotate(a, v, p, r)
    for i in range(4):
        w[i] = a[i, i]
    for i in range(1, 4):  # ascending, eigenvectors along
        j = i
        while j > 0 and w[j - 1] > w[j]:
            w[j - 1], w[j] = w[j], w[j - 1]
            for k in range(4):
                v[k, j - 1], v[k, j] = v[k, j], v[k, j - 1]
            j -= 1


@njit(**JIT_OPTIONS)
def _square_root(cov, jac, lmat, zs):
    """``L = D S`` (``S`` the symmetric square root of ``cov`` scaled to unit
    diagonal by ``D``, so that ``cov = L L^T``) into ``lmat`` and ``L^-1 jac``
    into ``zs``; False when ``cov`` is not positive definite."""
    d = np.empty(4)
    for i in range(4):
        if not cov[i, i] > 0.0:
            return False
        d[i] = np.sqrt(cov[i, i])
    # scaled to unit diagonal before the factorisation (entries differ by orders)
    cs = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            cs[i, j] = cov[i, j] / (d[i] * d[j])
    w = np.empty(4)
    u = np.empty((4, 4))
    _eigh4(cs, w, u)
    if not w[0] > 1e-12 * w[3]:
        return False
    for i in range(4):
        zs[i] = 0.0
    for i in range(4):
        for j in range(4):
            sij = 0.0
            sinv = 0.0
            for k in range(4):
                sij += u[i, k] * np.sqrt(w[k]) * u[j, k]
                sinv += u[i, k] * u[j, k] / np.sqrt(w[k])
            lmat[i, j] = d[i] * sij
            zs[i] += sinv * jac[j] / d[j]
    return True


@njit(**JIT_OPTIONS)
def _whiten(jac, cov, q, yh):
    """The eigenvalues ``q`` of the whitened determinant form and the data's
    whitened coordinates ``yh``; False when ``cov`` is not positive definite."""
    lmat = np.empty((4, 4))
    zs = np.empty(4)
    if not _square_root(cov, jac, lmat, zs):
        return False
    # det J = (L z)^T M (L z), M with +-1/2 on its anti-diagonal; the form of z
    qm = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            qm[i, j] = 0.5 * (lmat[0, i] * lmat[3, j] + lmat[3, i] * lmat[0, j]
                              - lmat[1, i] * lmat[2, j] - lmat[2, i] * lmat[1, j])
    qv = np.empty(4)
    v = np.empty((4, 4))
    _eigh4(qm, qv, v)  # ascending: two negative, two positive
    for i in range(4):
        q[i] = qv[i]
        y = 0.0
        for k in range(4):
            y += v[k, i] * zs[k]
        yh[i] = y
    return True


@njit(**JIT_OPTIONS)
def _secular(q, yh, lam):
    f = 0.0
    for i in range(4):
        r = 1.0 - 2.0 * lam * q[i]
        f += q[i] * yh[i] * yh[i] / (r * r)
    return f


@njit(**JIT_OPTIONS)
def _secular_slope(q, yh, lam):
    d = 0.0
    for i in range(4):
        r = 1.0 - 2.0 * lam * q[i]
        d += 4.0 * q[i] * q[i] * yh[i] * yh[i] / (r * r * r)
    return d


@njit(**JIT_OPTIONS)
def _quadric_d2(q, yh, target, lam0=np.nan):
    """The squared whitened distance from ``yh`` to ``sum q y^2 = target``
    (``q`` sorted, two negative and two positive: the form of ``det``) and
    the multiplier ``lambda`` of the closest point: the root of the secular
    equation between 0 and the pole on the side of the target, where it is
    increasing, by Newton steps kept inside the bracket (a bisection step
    where Newton would leave it), until a Newton step moves ``lambda`` by less
    than :data:`_LAM_RTOL` of it (or the bracket reaches float resolution, or
    an exact root). The steps start at ``lam0`` where it lies inside the
    bracket (the root of a nearby target), else at the bracket's middle."""
    f0 = _secular(q, yh, 0.0)
    if f0 == target:
        return 0.0, 0.0
    if target > f0:
        a, b = 0.0, 0.5 / q[3]
    else:
        a, b = 0.5 / q[0], 0.0
    lam = lam0 if a < lam0 < b else 0.5 * (a + b)
    for _ in range(_N_BISECT):
        f = _secular(q, yh, lam) - target
        if f == 0.0:
            break
        if f > 0.0:
            b = lam
        else:
            a = lam
        mid = 0.5 * (a + b)
        if mid == a or mid == b:
            break
        slope = _secular_slope(q, yh, lam)
        step = lam - f / slope if slope > 0.0 else mid
        # Newton where it lands well inside the bracket, else bisection
        if a < step < b and abs(step - lam) < 0.5 * (b - a):
            if abs(step - lam) <= _LAM_RTOL * abs(lam):
                lam = step  # converged: the next step would move lam by less
                break
            lam = step
        else:
            lam = mid
    d2 = 0.0
    for i in range(4):
        r = 1.0 - 2.0 * lam * q[i]
        dy = yh[i] / r - yh[i]
        d2 += dy * dy
    return d2, lam


@njit(**JIT_OPTIONS)
def _objective(q, yh, sign, u, ln_r, v, lam0):
    """The profile objective at ``u = ln|D|`` and the multiplier of its
    closest point (``lam0`` a start for it, see :func:`_quadric_d2`)."""
    d2, lam = _quadric_d2(q, yh, sign * np.exp(u), lam0)
    if v > 0.0:
        d2 += (ln_r - u) ** 2 / v
    return d2, lam


@njit(**JIT_OPTIONS)
def _min_over_u(q, yh, sign, lo, hi, ln_r, v):
    """The smallest objective over ``u = ln|D|`` in ``[lo, hi]``: a grid, then
    golden-section steps around its best point; each root starts from the previous evaluation's."""
    best = np.inf
    ib = 0
    us = np.linspace(lo, hi, _N_GRID)
    lam = np.nan
    lams = np.empty(_N_GRID)
    for i in range(_N_GRID):
        val, lam = _objective(q, yh, sign, us[i], ln_r, v, lam)
        lams[i] = lam
        if val < best:
            best = val
            ib = i
    a = us[max(ib - 1, 0)]
    b = us[min(ib + 1, _N_GRID - 1)]
    g = 0.5 * (np.sqrt(5.0) - 1.0)
    x1 = b - g * (b - a)
    x2 = a + g * (b - a)
    f1, lam = _objective(q, yh, sign, x1, ln_r, v, lams[ib])
    f2, lam = _objective(q, yh, sign, x2, ln_r, v, lam)
    # to a bracket of _U_TOL of the rest's noise: the objective, quadratic about
    # its minimum with a curvature of order 1 / v, is then within ~1e-12 of it
    tol = _U_TOL * np.sqrt(v)
    for _ in range(_N_GOLDEN):
        if b - a <= tol:
            break
        if f1 < f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - g * (b - a)
            f1, lam = _objective(q, yh, sign, x1, ln_r, v, lam)
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + g * (b - a)
            f2, lam = _objective(q, yh, sign, x2, ln_r, v, lam)
    return min(best, f1, f2)


@njit(**JIT_OPTIONS)
def whiten_all(jac, cov, q, yh, ok):
    """:func:`_whiten` of each pair: ``q`` and ``yh`` (N, 4) filled, ``ok`` (N,)
    False where ``cov`` is not positive definite or the Jacobian's determinant
    is not finite and non-zero."""
    for a in range(jac.shape[0]):
        ok[a] = False
        if not (np.isfinite(jac[a]).all() and np.isfinite(cov[a]).all()):
            continue
        if not _whiten(jac[a], cov[a], q[a], yh[a]):
            continue
        det = jac[a, 0] * jac[a, 3] - jac[a, 1] * jac[a, 2]
        ok[a] = np.isfinite(det) and det != 0.0


@njit(**JIT_OPTIONS)
def profile_snr_whitened(q, yh, ok, det, var_rest, ln_r, out):
    """:func:`profile_snr` from the pairs' whitened forms (:func:`whiten_all`:
    ``q``, ``yh``, ``ok``) and determinants ``det`` (N,)."""
    for a in range(q.shape[0]):
        out[a] = np.nan
        v = var_rest[a]
        lr = ln_r[a]
        if not (ok[a] and np.isfinite(lr) and v >= 0.0 and np.isfinite(v)):
            continue
        qa = q[a]
        ya = yh[a]
        best = np.inf
        same = 1.0 if det[a] > 0.0 else -1.0
        for sign in (same, -same):  # the estimate's parity first
            if v == 0.0:
                best = min(best, _quadric_d2(qa, ya, sign * np.exp(lr))[0])
                continue
            if sign == same:
                # between the estimate and the hypothesis, with a margin of the rest's noise
                u0 = np.log(abs(det[a]))
                lo = min(u0, lr) - 2.0 * np.sqrt(v)
                hi = max(u0, lr) + 2.0 * np.sqrt(v)
            else:
                # the other parity: |D| below R (the distance grows with |D|), reached
                # only through D = 0; a |D| more than sqrt(best) noise below R costs
                # more than the best already found
                if _quadric_d2(qa, ya, 0.0)[0] >= best:
                    continue
                lo = lr - max(8.0, np.sqrt(best)) * np.sqrt(v)
                hi = lr
            best = min(best, _min_over_u(qa, ya, sign, lo, hi, lr, v))
        out[a] = np.sqrt(best)


@njit(**JIT_OPTIONS)
def profile_snr(jac, cov, var_rest, ln_r, out):
    """The profile-likelihood SNR ``T`` (module docstring) of each pair into
    ``out`` (N,): ``jac`` (N, 4) the estimated Jacobians ``(J00, J01, J10,
    J11)``, ``cov`` (N, 4, 4) their covariances, ``var_rest`` (N,) the rest
    of the variance of ``ln|det J|`` and the flux ratio's, ``ln_r`` (N,) the
    log flux ratios. NaN where an input is not finite or ``cov`` is not
    positive definite."""
    n = jac.shape[0]
    q = np.empty((n, 4))
    yh = np.empty((n, 4))
    ok = np.empty(n, dtype=np.bool_)
    whiten_all(jac, cov, q, yh, ok)
    det = np.empty(n)
    for a in range(n):
        det[a] = jac[a, 0] * jac[a, 3] - jac[a, 1] * jac[a, 2]
    profile_snr_whitened(q, yh, ok, det, var_rest, ln_r, out)
