"""Numba kernels of the flux field (:mod:`lensdual.flux_field`): unit-free, no checks.

:func:`predict_all` makes the leave-one-out prediction of every pair (steps 0
to 3 of the module docstring of :mod:`lensdual.flux_field`) and returns what
step 2 reads; step 2's estimate of the squared bias and the common model
variance (step 4) are made by the caller.
"""

import numpy as np
from numba import njit

from ._numba import JIT_OPTIONS
from .estimators._linalg import mgs_factor

__all__ = []

#: ``status`` codes of :func:`predict_all`, in the order of ``FIELD_STATUS``.
OK, TOO_FEW, UNRESOLVED, ILL_CONDITIONED = 0, 1, 2, 3


@njit(**JIT_OPTIONS)
def _n_terms(degree):
    return (degree + 1) * (degree + 2) // 2


@njit(inline="always", **JIT_OPTIONS)
def _monomials(x, y, degree, out):
    """``x**(k-j) y**j`` for k = 0..degree, j = 0..k, into ``out``."""
    c = 0
    for k in range(degree + 1):
        for j in range(k + 1):
            out[c] = x ** (k - j) * y**j
            c += 1


@njit(inline="always", **JIT_OPTIONS)
def _gradient(x, y, degree, coef):
    """The gradient of the polynomial ``coef`` at ``(x, y)``."""
    gx = 0.0
    gy = 0.0
    c = 0
    for k in range(degree + 1):
        for j in range(k + 1):
            if k - j > 0:
                gx += coef[c] * (k - j) * x ** (k - j - 1) * y**j
            if j > 0:
                gy += coef[c] * j * x ** (k - j) * y ** (j - 1)
            c += 1
    return gx, gy


@njit(**JIT_OPTIONS)
def _weighted_fit(dw, y, s, m, degree, cond_max, coef, a, lev):
    """Weighted least squares of ``y[:m]`` (errors ``s``) on the monomials of ``dw``.

    Fills ``coef``, ``a`` (``a @ y[:m]`` is the value at the origin,
    ``coef[0]``) and ``lev`` (the leverages, the diagonal of the weighted hat
    matrix); returns False where the design is numerically rank deficient.
    """
    p = _n_terms(degree)
    design = np.empty((m, p))
    row = np.empty(p)
    for i in range(m):
        _monomials(dw[i, 0], dw[i, 1], degree, row)
        for c in range(p):
            design[i, c] = row[c] / s[i]
    scale = np.empty(p)
    r = np.zeros((p, p))
    if not mgs_factor(design, p, scale, r, cond_max):
        return False
    # design is now Q: the hat matrix is Q Q^T
    for i in range(m):
        h = 0.0
        for c in range(p):
            h += design[i, c] ** 2
        lev[i] = h
    # rows = S^-1 R^-1 Q^T, then coef = rows @ (y / s) and a = rows[0] / s
    rinv = np.zeros((p, p))
    for j in range(p - 1, -1, -1):
        rinv[j, j] = 1.0 / r[j, j]
        for k in range(j + 1, p):
            v = 0.0
            for i in range(j + 1, k + 1):
                v += r[j, i] * rinv[i, k]
            rinv[j, k] = -v / r[j, j]
    for c in range(p):
        coef[c] = 0.0
    for i in range(m):
        yi = y[i] / s[i]
        for c in range(p):
            v = 0.0
            for k in range(c, p):
                v += rinv[c, k] * design[i, k]
            v /= scale[c]
            coef[c] += v * yi
            if c == 0:
                a[i] = v / s[i]
    return True


@njit(**JIT_OPTIONS)
def _local_fit(d, y, s, sig_target, sig, m, degree, cond_max, coef, a, s_eff, dw, lev):
    """One neighbourhood's fit in its whitened frame, refitted with the neighbours'
    errors widened by their position errors times the fitted gradient.

    Returns ``(ok, value, var_stat, var_position)``: the value at the origin, the
    variance the neighbours' errors give it, and the variance the origin's own
    position error adds. ``a`` receives the prediction's weights, ``s_eff`` the
    widened errors, ``dw`` the neighbours' whitened offsets and ``lev`` their
    leverages.
    """
    sxx = 0.0
    sxy = 0.0
    syy = 0.0
    for i in range(m):
        sxx += d[i, 0] * d[i, 0]
        sxy += d[i, 0] * d[i, 1]
        syy += d[i, 1] * d[i, 1]
    sxx /= m
    sxy /= m
    syy /= m
    det = sxx * syy - sxy * sxy
    if not det > 0.0:
        return False, np.nan, np.nan, np.nan
    # lower Cholesky factor of the inverse covariance [[syy, -sxy], [-sxy, sxx]] / det
    l00 = np.sqrt(syy / det)
    l10 = -sxy / det / l00
    l11 = np.sqrt(sxx / det - l10 * l10)
    for i in range(m):
        dw[i, 0] = d[i, 0] * l00 + d[i, 1] * l10
        dw[i, 1] = d[i, 1] * l11
    if not _weighted_fit(dw, y, s, m, degree, cond_max, coef, a, lev):
        return False, np.nan, np.nan, np.nan
    for i in range(m):
        gx, gy = _gradient(dw[i, 0], dw[i, 1], degree, coef)
        # gradient in the original frame: L @ g (row form g @ L^T)
        hx = l00 * gx
        hy = l10 * gx + l11 * gy
        s_eff[i] = np.sqrt(s[i] ** 2 + sig[i] ** 2 * (hx * hx + hy * hy))
    if not _weighted_fit(dw, y, s_eff, m, degree, cond_max, coef, a, lev):
        return False, np.nan, np.nan, np.nan
    var_stat = 0.0
    for i in range(m):
        var_stat += a[i] ** 2 * s_eff[i] ** 2
    hx = l00 * coef[1]
    hy = l10 * coef[1] + l11 * coef[2]
    return True, coef[0], var_stat, sig_target**2 * (hx * hx + hy * hy)


@njit(**JIT_OPTIONS)
def _cubic_sensitivity(dw, a, m):
    """``sum_c (sum_k a_k m_c(dw_k))^2`` over the four cubic monomials ``m_c``: how much
    cubic terms of unit coefficients (in the whitened frame) move the prediction."""
    g = 0.0
    for c in range(4):
        v = 0.0
        for k in range(m):
            v += a[k] * dw[k, 0] ** (3 - c) * dw[k, 1] ** c
        g += v * v
    return g


@njit(**JIT_OPTIONS)
def _worst_neighbour(dw, y, s_eff, lev, coef, m, degree):
    """The neighbour whose externally studentised deletion residual is the largest in
    absolute value, and that residual.

    The residual of neighbour ``k`` from the fit without it, over its standard
    deviation, is ``z_k = (y_k - f(x_k)) / (s_k sqrt(1 - h_k))`` with ``f``
    the fit ``coef`` of all ``m`` and ``h_k`` its leverage. It is divided by
    the scale the other neighbours' residuals show, ``sqrt(chi2_(k) / (m - p -
    1))`` with ``chi2_(k) = chi2 - z_k^2``, but never by less than 1 (the
    errors quoted). Neighbours of leverage 1 (the fit passes through them
    whatever their value) are not tested; ``(-1, 0)`` where none is.
    """
    p = _n_terms(degree)
    row = np.empty(p)
    z = np.zeros(m)
    chi2 = 0.0
    for k in range(m):
        _monomials(dw[k, 0], dw[k, 1], degree, row)
        fit = 0.0
        for c in range(p):
            fit += coef[c] * row[c]
        e = (y[k] - fit) / s_eff[k]
        chi2 += e * e
        q = 1.0 - lev[k]
        z[k] = abs(e) / np.sqrt(q) if q > 1e-9 else np.nan
    dof = m - p - 1
    worst = -1
    t_max = 0.0
    for k in range(m):
        if not np.isfinite(z[k]):
            continue
        scale = 1.0
        if dof > 0:
            scale = max(1.0, (chi2 - z[k] * z[k]) / dof)
        t = z[k] / np.sqrt(scale)
        if t > t_max:
            t_max = t
            worst = k
    return worst, t_max


@njit(**JIT_OPTIONS)
def _dev_variance(a, a2, s_eff, s_eff2, m_local, m_check):
    """The variance the neighbours' errors give the quadratic's (weights ``a2`` on the
    first ``m_local``) minus the cubic's (``a``) prediction."""
    vd = 0.0
    for k in range(m_check):
        if k < m_local:
            sk = max(s_eff[k], s_eff2[k])
            vd += (a2[k] - a[k]) ** 2 * sk * sk
        else:
            vd += a[k] ** 2 * s_eff[k] ** 2
    return vd


@njit(**JIT_OPTIONS)
def _gather(i, order, count, dropped, m_check, pos, y, s, sig2, chosen, d, yy, ss, sg):
    """The ``m_check`` nearest neighbours of ``i`` in ``order`` not ``dropped``: their
    indices into ``chosen``, offsets into ``d``, values, errors and position errors."""
    c = 0
    for k in range(count):
        j = order[k]
        if dropped[j]:
            continue
        chosen[c] = j
        d[c, 0] = pos[j, 0] - pos[i, 0]
        d[c, 1] = pos[j, 1] - pos[i, 1]
        yy[c] = y[j]
        ss[c] = s[j]
        sg[c] = sig2[j]
        c += 1
        if c == m_check:
            break


@njit(**JIT_OPTIONS)
def predict_all(pos, y, s, sig2, usable, resolved, n_local, n_gate, n_check, min_check,
                cond_max, max_unresolved, t_drop, max_drop, value, var, dev, var_dev, sens,
                status, n_used, n_dropped):
    """The leave-one-out prediction of every pair (steps 0, 1 and 3, and what step 2
    reads): fills ``value`` (the quadratic's prediction), ``var`` (its variance from
    the neighbours' errors and the pair's position error), ``dev`` (the quadratic's
    minus the cubic's prediction), ``var_dev`` (the variance the neighbours' errors
    give ``dev``), ``sens`` (:func:`_cubic_sensitivity` of the quadratic), ``status``,
    ``n_used`` and ``n_dropped``.

    A pair is predicted where it is ``resolved`` and at most ``max_unresolved`` of
    its ``n_gate`` nearest neighbours are not; its quadratic has ``n_local``. Up to
    ``max_drop`` neighbours are dropped, one at a time, while the largest
    studentised deletion residual of the quadratic's neighbours
    (:func:`_worst_neighbour`) exceeds ``t_drop``; the next nearest take their
    places in both fits.
    """
    n = y.size
    dist = np.empty(n)
    coef = np.empty(_n_terms(3))
    a = np.empty(n_check)
    a2 = np.empty(n_check)
    s_eff = np.empty(n_check)
    s_eff2 = np.empty(n_check)
    lev = np.empty(n_check)
    dw = np.empty((n_check, 2))
    dw2 = np.empty((n_check, 2))
    d = np.empty((n_check, 2))
    yy = np.empty(n_check)
    ss = np.empty(n_check)
    sg = np.empty(n_check)
    others = np.empty(n, dtype=np.int64)
    chosen = np.empty(n_check, dtype=np.int64)
    dropped = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        value[i] = np.nan
        var[i] = np.nan
        dev[i] = np.nan
        var_dev[i] = np.nan
        sens[i] = np.nan
        n_dropped[i] = 0
        count = 0
        for j in range(n):
            if usable[j] and j != i:
                dist[count] = np.hypot(pos[j, 0] - pos[i, 0], pos[j, 1] - pos[i, 1])
                others[count] = j
                count += 1
        n_used[i] = min(n_check, count)
        if count < min_check:
            status[i] = TOO_FEW
            continue
        order = others[:count][np.argsort(dist[:count], kind="mergesort")]
        n_unresolved = 0
        for k in range(min(n_gate, count)):
            if not resolved[order[k]]:
                n_unresolved += 1
        if not resolved[i] or n_unresolved > max_unresolved:
            status[i] = UNRESOLVED
            continue
        dropped[order] = False
        # step 1: the quadratic, refitted without its worst neighbour while that
        # neighbour is off the others' fit
        while True:
            left = count - n_dropped[i]
            m_local = min(n_local, left)
            m_check = min(n_check, left)
            n_used[i] = m_check
            if left < min_check:
                break
            _gather(i, order, count, dropped, m_check, pos, y, s, sig2, chosen, d, yy, ss, sg)
            ok2, v2, var_stat, var_pos = _local_fit(d, yy, ss, sig2[i], sg, m_local, 2,
                                                    cond_max, coef, a2, s_eff2, dw2, lev)
            if not ok2 or n_dropped[i] >= max_drop:
                break
            worst, t_max = _worst_neighbour(dw2, yy, s_eff2, lev, coef, m_local, 2)
            if worst < 0 or not t_max > t_drop:
                break
            dropped[chosen[worst]] = True
            n_dropped[i] += 1
        if left < min_check:
            status[i] = TOO_FEW
            continue
        ok3, v3, _, _ = _local_fit(d, yy, ss, sig2[i], sg, m_check, 3, cond_max, coef, a,
                                   s_eff, dw, lev)
        if not (ok2 and ok3):
            status[i] = ILL_CONDITIONED
            continue
        status[i] = OK
        value[i] = v2
        var[i] = var_stat + var_pos
        dev[i] = v2 - v3
        var_dev[i] = _dev_variance(a, a2, s_eff, s_eff2, m_local, m_check)
        sens[i] = _cubic_sensitivity(dw2, a2, m_local)


@njit(**JIT_OPTIONS)
def _bias_nll(ln_tau2, d2, sens, var_dev):
    """Minus the log likelihood (up to a constant) of ``d ~ N(0, tau^2 sens + var_dev)``."""
    t = np.exp(ln_tau2)
    total = 0.0
    for k in range(d2.size):
        v = t * sens[k] + var_dev[k]
        total += np.log(v) + d2[k] / v
    return 0.5 * total


@njit(**JIT_OPTIONS)
def max_likelihood_ln_tau2(d2, sens, var_dev, lo, hi, n_grid, xatol):
    """The ``ln tau^2`` in ``[lo, hi]`` that minimises :func:`_bias_nll`: the best of
    ``n_grid`` equally spaced values, refined by golden-section search between its
    two grid neighbours until the bracket is narrower than ``xatol``."""
    step = (hi - lo) / (n_grid - 1)
    best = 0
    f_best = np.inf
    for g in range(n_grid):
        f = _bias_nll(lo + g * step, d2, sens, var_dev)
        if f < f_best:
            f_best = f
            best = g
    a = lo + max(best - 1, 0) * step
    b = lo + min(best + 1, n_grid - 1) * step
    inv_phi = 0.5 * (np.sqrt(5.0) - 1.0)
    c = b - inv_phi * (b - a)
    d = a + inv_phi * (b - a)
    fc = _bias_nll(c, d2, sens, var_dev)
    fd = _bias_nll(d, d2, sens, var_dev)
    while b - a > xatol:
        if fc < fd:
            b = d
            d = c
            fd = fc
            c = b - inv_phi * (b - a)
            fc = _bias_nll(c, d2, sens, var_dev)
        else:
            a = c
            c = d
            fc = fd
            d = a + inv_phi * (b - a)
            fd = _bias_nll(d, d2, sens, var_dev)
    x = 0.5 * (a + b)
    if _bias_nll(x, d2, sens, var_dev) <= f_best:
        return x
    return lo + best * step


@njit(**JIT_OPTIONS)
def _median_ratio_excess(r, v, t, target):
    """``median(r / sqrt(v + t)) - target``."""
    return np.median(r / np.sqrt(v + t)) - target


@njit(**JIT_OPTIONS)
def common_variance(r, v, target):
    """The ``t >= 0`` at which ``median(r / sqrt(v + t))`` falls to ``target``
    (``r >= 0``, ``v > 0``; 0 where it is already at most ``target``).

    Each ratio falls below ``target`` at ``t_i = (r_i / target)^2 - v_i``. With
    an odd count the median is the middle ratio, which reaches ``target``
    exactly at the median of the ``t_i``. With an even count it is the mean of
    the two middle ratios, and the root lies between the two middle ``t_i``
    (below it more than half the ratios exceed ``target``, above it fewer):
    bisection there, to float resolution."""
    n = r.size
    if _median_ratio_excess(r, v, 0.0, target) <= 0.0:
        return 0.0
    ti = np.sort((r / target) ** 2 - v)
    if n % 2 == 1:
        return max(ti[n // 2], 0.0)
    a = max(ti[n // 2 - 1], 0.0)
    b = max(ti[n // 2], a)
    for _ in range(200):
        mid = 0.5 * (a + b)
        if mid == a or mid == b:
            break
        if _median_ratio_excess(r, v, mid, target) > 0.0:
            a = mid
        else:
            b = mid
    return 0.5 * (a + b)
