"""Plain-numpy references of the estimator kernels, written independently.

They follow the paper's definitions literally, one pair at a time, with
``numpy.linalg.lstsq`` and ``numpy.linalg.solve``; the tests compare the
Numba kernels of :mod:`lensdual.estimators._kernels` (the paper's estimators) and
:mod:`lensdual.estimators._adaptive` (the adaptive one) against them.
"""

import numpy as np
from scipy.stats import chi2 as _chi2_dist


def baselines(theta, a):
    """Baselines D_ab = theta_b - theta_a for all b != a, shape (N-1, 2)."""
    others = np.delete(np.arange(len(theta)), a)
    return theta[others] - theta[a]


def jacobian_quad(t1, t2, weight_power=2.0, order=1):
    """Weighted least squares D1 = J D2 (+ quadratic terms) at every pair."""
    n = len(t1)
    out = np.empty((n, 2, 2))
    for a in range(n):
        d2 = baselines(t2, a)
        d1 = baselines(t1, a)
        w = np.linalg.norm(d2, axis=1) ** (-weight_power)
        if order == 1:
            design = d2
        else:
            x, y = d2.T
            design = np.column_stack([x, y, x * x, x * y, y * y])
        sw = np.sqrt(w)[:, None]
        coef, *_ = np.linalg.lstsq(design * sw, d1 * sw, rcond=None)
        out[a] = coef[:2].T
    return out


MIN_SIN_5DEG = np.sin(np.deg2rad(5.0))


def jacobian_2v(t1, t2, min_sin=MIN_SIN_5DEG):
    """2v Jacobian: exact solution on the first well-conditioned triangle.

    Neighbours are ranked by distance in L2; triangles (a, i, j) are tried in
    the order j = 1, 2, ... (neighbour rank), i = 0 .. j-1, and the first one
    whose two baselines are at least ``arcsin(min_sin)`` apart is used.
    """
    n = len(t1)
    out = np.full((n, 2, 2), np.nan)
    for a in range(n):
        d = np.linalg.norm(t2 - t2[a], axis=1)
        d[a] = np.inf
        rank = np.argsort(d, kind="stable")[: n - 1]
        found = False
        for j in range(1, n - 1):
            for i in range(j):
                b, c = rank[i], rank[j]
                x2 = np.column_stack([t2[b] - t2[a], t2[c] - t2[a]])
                x1 = np.column_stack([t1[b] - t1[a], t1[c] - t1[a]])
                sin = abs(np.linalg.det(x2)) / (d[b] * d[c])
                if sin >= min_sin:
                    out[a] = np.linalg.solve(x2.T, x1.T).T
                    found = True
                    break
            if found:
                break
    return out


def bootstrap_determinants(t1, t2, noise1, noise2, method="quad", **kwargs):
    """det J of every pair for every bootstrap realisation, (B, N)."""
    func = {
        "quad": jacobian_quad,
        "quad2": lambda a, b, **k: jacobian_quad(a, b, order=2, **k),
        "2v": jacobian_2v,
    }[method]
    dets = np.empty(noise1.shape[:2])
    for k in range(len(noise1)):
        jac = func(t1 + noise1[k], t2 + noise2[k], **kwargs)
        dets[k] = np.linalg.det(jac)
    return dets


def size_magnification(t1, t2, sigma, n_bootstrap, rng, method="quad"):
    """Reference of ``size_magnification``: mu, half 16-84 width, percentiles."""
    jac = {"quad": jacobian_quad, "2v": jacobian_2v,
           "quad2": lambda a, b: jacobian_quad(a, b, order=2)}[method](t1, t2)
    noise1 = rng.standard_normal((n_bootstrap, len(t1), 2)) * sigma
    noise2 = rng.standard_normal((n_bootstrap, len(t1), 2)) * sigma
    boot = np.abs(bootstrap_determinants(t1, t2, noise1, noise2, method))
    p16, p50, p84 = np.percentile(boot, [16, 50, 84], axis=0)
    return np.abs(np.linalg.det(jac)), 0.5 * (p84 - p16), (p16, p50, p84)


# ---------------------------------------------------------------------------
# The adaptive estimator, one pair and one candidate fit at a time
# ---------------------------------------------------------------------------


def _monomials(u, degree):
    x, y = u[:, 0], u[:, 1]
    cols = [np.ones_like(x)]
    for deg in range(1, degree + 1):
        for i in range(deg + 1):
            cols.append(x ** (deg - i) * y**i)
    return np.column_stack(cols)


def _gls_beta(t1, t2, a, idx, degree, s1, s2, pilot):
    """Generalised least squares of theta1 on a polynomial of theta2 - theta2[a].

    Each point's 2x2 covariance is s1^2 I + s2^2 P P^T (no rotation trick:
    the full 2p x 2p normal system). Returns the offsets u, the design, the
    data, the weights, the coefficients (2, p) and their covariance.
    """
    u = t2[idx] - t2[a]
    x = _monomials(u, degree)
    y = t1[idx] - t1[a]
    cov = s1[idx, None, None] ** 2 * np.eye(2) + s2[idx, None, None] ** 2 * (pilot @ pilot.T)
    w = np.linalg.inv(cov)
    p = x.shape[1]
    normal = np.einsum("bi,bj,bkl->kilj", x, x, w).reshape(2 * p, 2 * p)
    rhs = np.einsum("bi,bkl,bl->ki", x, w, y).reshape(2 * p)
    cinv = np.linalg.inv(normal)
    return u, x, y, w, (cinv @ rhs).reshape(2, p), cinv


def _gls_fit(t1, t2, a, idx, degree, s1, s2, pilot):
    """The GLS fit (:func:`_gls_beta`): J, its 4x4 covariance, chi2, dof."""
    _, x, y, w, beta, cinv = _gls_beta(t1, t2, a, idx, degree, s1, s2, pilot)
    p = x.shape[1]
    r = y - x @ beta.T
    chi2 = np.einsum("bk,bkl,bl->", r, w, r)
    sel = [1, 2, p + 1, p + 2]
    jac = np.array([[beta[0, 1], beta[0, 2]], [beta[1, 1], beta[1, 2]]])
    return jac, cinv[np.ix_(sel, sel)], chi2, 2 * (len(idx) - p)


def _press_ratio(t1, t2, a, idx, degree, s1, s2, pilot):
    """Leave-one-out (PRESS) misfit of a fit over its null expectation.

    Per output component of the eigenframe of ``pilot pilot^T`` (where the
    effective noise is diagonal): sum w r^2 / (1 - h)^2 over sum 1 / (1 - h),
    with h the leverages of the weighted fit.
    """
    evals, evecs = np.linalg.eigh(pilot @ pilot.T)
    u = t2[idx] - t2[a]
    x = _monomials(u, degree)
    y = (t1[idx] - t1[a]) @ evecs  # components along the eigenvectors
    num = den = 0.0
    for c in range(2):
        w = 1.0 / (s1[idx] ** 2 + s2[idx] ** 2 * max(evals[c], 0.0))
        xtwx = x.T @ (w[:, None] * x)
        beta = np.linalg.solve(xtwx, x.T @ (w * y[:, c]))
        r = y[:, c] - x @ beta
        lev = np.minimum(w * np.einsum("bi,ij,bj->b", x, np.linalg.inv(xtwx), x), 1 - 1e-9)
        num += np.sum(w * r**2 / (1 - lev) ** 2)
        den += np.sum(1.0 / (1 - lev))
    return num / den


def _curvature_terms(t1, t2, a, idx, degree, s1, s2, pilot, jinv=None, order=2):
    """At each point of ``idx``: t(u) = tr(J^-1 dJ(u)), the change of ln|det J|
    from the centre to offset u that a fit's terms of degree ``order`` alone
    predict (dJ(u) their derivative at u; order 2: the curvature, dJ = H u),
    and its standard error from the fit's covariance (J held fixed, at
    ``jinv`` when given, else the fit's own inverse). Returns the two
    arrays."""
    u, x, _, _, beta, cinv = _gls_beta(t1, t2, a, idx, degree, s1, s2, pilot)
    p = x.shape[1]
    if jinv is None:
        jinv = np.linalg.inv(beta[:, 1:3])
    terms = np.arange(order * (order + 1) // 2, (order + 1) * (order + 2) // 2)
    ts, sds = [], []
    for ux, uy in u:
        # d/dx and d/dy of each monomial x^(order - i) y^i at u
        ddx = np.array([(order - i) * ux ** max(order - i - 1, 0) * uy**i
                        for i in range(order + 1)])
        ddy = np.array([i * ux ** (order - i) * uy ** max(i - 1, 0) for i in range(order + 1)])
        # t = sum_kl jinv[l, k] dJ[k, l] is linear in beta[k, terms]
        grad = np.zeros((2, p))
        for k in range(2):
            grad[k, terms] = jinv[0, k] * ddx + jinv[1, k] * ddy
        g = grad.ravel()
        ts.append(g @ beta.ravel())
        sds.append(np.sqrt(max(g @ cinv @ g, 0.0)))
    return np.array(ts), np.array(sds)


def _centre_gradient2(t1, t2, a, idx, degree, s1, s2, pilot, jinv=None):
    """|grad ln|det J||^2 at the pair (offset 0) from a fit's second-order
    terms, less the trace of its covariance (J held fixed, at ``jinv`` when
    given), at least 0: the pair's own L2 noise moves the point where the fit
    takes J by ``s2[a]``, so this times ``s2[a]^2`` is a variance of ln|det J|."""
    _, x, _, _, beta, cinv = _gls_beta(t1, t2, a, idx, degree, s1, s2, pilot)
    p = x.shape[1]
    if jinv is None:
        jinv = np.linalg.inv(beta[:, 1:3])
    total = 0.0
    # d/dx_m of dF_k/dx_l at 0 from the monomials x^2 (3), xy (4), y^2 (5)
    second = {(0, 0): (3, 2.0), (0, 1): (4, 1.0), (1, 0): (4, 1.0), (1, 1): (5, 2.0)}
    for m in range(2):
        grad = np.zeros((2, p))
        for k in range(2):
            for l in range(2):
                col, f = second[(l, m)]
                grad[k, col] += jinv[l, k] * f
        g = grad.ravel()
        total += (g @ beta.ravel()) ** 2 - g @ cinv @ g
    return max(total, 0.0)


def _order_change(t1, t2, a, idx, degree, s1, s2, pilot, order, n_sig=2.0):
    """max (|t(u)| - n_sig sd(t(u))) over the points ``idx`` for the terms of
    degree ``order`` of a fit of ``degree`` (:func:`_curvature_terms`); 0 when
    the fit has no such terms."""
    if order < 2 or degree < order:
        return 0.0
    t, sd = _curvature_terms(t1, t2, a, idx, degree, s1, s2, pilot, order=order)
    return max(float(np.max(np.abs(t) - n_sig * sd)), 0.0)


def _curvature(t1, t2, a, idx, degree, s1, s2, pilot, n_sig=2.0):
    """Largest change of ln|det J| over the points ``idx`` that a fit's
    second-order terms predict, less ``n_sig`` times its noise at each point."""
    return _order_change(t1, t2, a, idx, degree, s1, s2, pilot, 2, n_sig)


def _top_change(t1, t2, a, idx, degree, s1, s2, pilot, n_sig=1.5):
    """The same for the fit's highest-degree terms (0 for a linear fit): how
    much the terms it truncates next may matter there."""
    return _order_change(t1, t2, a, idx, degree, s1, s2, pilot, degree, n_sig)


def _ln_det_gradient(j):
    """d ln|det J| / dJ, as the entries J00, J01, J10, J11."""
    return np.array([j[1, 1], -j[1, 0], -j[0, 1], j[0, 0]]) / np.linalg.det(j)


def _error_and_rank(j, cj, g_pilot):
    """The error of ln|det J| of a fit (J, covariance ``cj``) and its base rank: the
    variance along the pilot's gradient ``g_pilot``, its own where that is None."""
    g = _ln_det_gradient(j)
    s = np.sqrt(g @ cj @ g)
    return s, (s**2 if g_pilot is None else g_pilot @ cj @ g_pilot)


def _gls_operator(t2, a, idx, degree, s1, s2, pilot):
    """The GLS fit of :func:`_gls_beta` as a linear operator: ``beta.ravel() =
    H @ y.ravel()`` (``y`` the (k, 2) offsets on L1), with the design ``x`` and
    the data covariance ``V`` (2k x 2k, block diagonal)."""
    u = t2[idx] - t2[a]
    x = _monomials(u, degree)
    cov = s1[idx, None, None] ** 2 * np.eye(2) + s2[idx, None, None] ** 2 * (pilot @ pilot.T)
    w = np.linalg.inv(cov)
    p, k = x.shape[1], len(idx)
    normal = np.einsum("bi,bj,bkl->kilj", x, x, w).reshape(2 * p, 2 * p)
    r = np.einsum("bi,bkl->kibl", x, w).reshape(2 * p, 2 * k)
    v = np.zeros((2 * k, 2 * k))
    for b in range(k):
        v[2 * b:2 * b + 2, 2 * b:2 * b + 2] = cov[b]
    return x, np.linalg.solve(normal, r), v


def _two_scale(t1, t2, a, order, h, b, s1, s2, pilot):
    """Two-scale estimate: the linear GLS fit of the ``h`` nearest points less
    the alias of the quadratic terms that the quadratic GLS fit of the ``b``
    nearest points estimates. Built as one explicit linear operator on the
    ``b`` points' L1 offsets; returns J and the 4x4 covariance of its entries."""
    idx_h, idx_b = order[:h], order[:b]
    _, op_h, _ = _gls_operator(t2, a, idx_h, 1, s1, s2, pilot)
    _, op_b, v_b = _gls_operator(t2, a, idx_b, 2, s1, s2, pilot)
    quad = _monomials(t2[idx_h] - t2[a], 2)[:, 3:6]
    # stacked L1 offsets that quadratic coefficients gamma (2, 3) predict on the h points
    z = np.zeros((2 * h, 6))
    for comp in range(2):
        z[comp::2, 3 * comp:3 * comp + 3] = quad
    gamma_rows = [3, 4, 5, 9, 10, 11]
    op_lin = np.zeros((6, 2 * b))
    op_lin[:, :2 * h] = op_h
    g = op_lin - op_h @ z @ op_b[gamma_rows]
    y = (t1[idx_b] - t1[a]).ravel()
    beta = (g @ y).reshape(2, 3)
    sel = [1, 2, 4, 5]
    jac = np.array([[beta[0, 1], beta[0, 2]], [beta[1, 1], beta[1, 2]]])
    return jac, (g @ v_b @ g.T)[np.ix_(sel, sel)]


def _linear_passes(t1, t2, a, idx, s1, s2, pilot, chi2_crit, nest_crit):
    """The linear test of a neighbourhood: its chi-square at the suite's level
    and, with ``nest_crit``, the likelihood-ratio test against the quadratic
    on the same points (the chi-square the quadratic terms remove)."""
    chi2 = _gls_fit(t1, t2, a, idx, 1, s1, s2, pilot)[2]
    if chi2 > chi2_crit[2 * (len(idx) - 3)]:
        return False
    return nest_crit is None or chi2 - _gls_fit(t1, t2, a, idx, 2, s1, s2, pilot)[2] <= nest_crit


def _two_scale_best(t1, t2, a, order, s1, s2, pilot, chi2_crit, min_extra, g_pilot, best,
                    top_coef, top_nsig, two_gate, two_gate_nsig, nest_crit, two_nest_crit):
    """The best-ranked of ``best`` (J, sd, rank, g2; or None) and the two-scale
    estimates of pair ``a``: a linear fit that passed its test, corrected by
    the quadratic terms of a larger neighbourhood whose quadratic fit passed
    its own (and, with ``two_nest_crit``, the nested test against the cubic),
    where that quadratic is known to be gentle."""
    n = len(t1)
    lin = [k for k in range(6 + min_extra, n + 1)
           if _linear_passes(t1, t2, a, order[:k], s1, s2, pilot, chi2_crit, nest_crit)]
    for b in range(6 + min_extra, n + 1):
        if not lin or lin[0] >= b:
            continue
        _, _, chi2, dof = _gls_fit(t1, t2, a, order[:b], 2, s1, s2, pilot)
        if chi2 > chi2_crit[dof]:
            continue
        # its cubic terms insignificant too, where b points allow a cubic
        if (two_nest_crit is not None and b >= 10 + min_extra
                and chi2 - _gls_fit(t1, t2, a, order[:b], 3, s1, s2, pilot)[2] > two_nest_crit):
            continue
        for h in (k for k in lin if k < b):
            j, cj = _two_scale(t1, t2, a, order, h, b, s1, s2, pilot)
            t, tsd = _curvature_terms(t1, t2, a, order[:b], 2, s1, s2, pilot,
                                      jinv=np.linalg.inv(j), order=2)
            if np.max(np.abs(t) + two_gate_nsig * tsd) > two_gate:
                continue
            s, rank = _error_and_rank(j, cj, g_pilot)
            rank += (top_coef * max(float(np.max(np.abs(t) - top_nsig * tsd)), 0.0)) ** 2
            if best is None or rank < best[2]:
                g2 = _centre_gradient2(t1, t2, a, order[:b], 2, s1, s2, pilot,
                                       jinv=np.linalg.inv(j))
                best = (j, s, rank, g2)
    return best


def _cubic_alias_bias2(t1, t2, a, idx, s1, s2, pilot, j, n_sig):
    """Squared bias of ln|det J| of the quadratic fit on ``idx`` (Jacobian
    ``j``) from the cubic terms of the map, beyond ``n_sig`` times its noise:
    ``(|b| - n_sig sd(b))_+^2``. ``b = g . dJ``, ``dJ`` the slopes that the
    GLS quadratic takes up from the cubic terms fitted by a GLS cubic on
    every point, ``sd(b)`` from that cubic fit's covariance."""
    n = len(t1)
    _, H, _ = _gls_operator(t2, a, idx, 2, s1, s2, pilot)  # beta (2 x 6) = H y
    _, _, _, _, beta3, cinv3 = _gls_beta(t1, t2, a, np.arange(n), 3, s1, s2, pilot)
    u3 = _monomials(t2[idx] - t2[a], 3)[:, 6:10]
    g = _ln_det_gradient(j)
    # b is linear in the cubic coefficients c (2 x 4): b = sum_km v[k, m] c[k, m]
    v = np.zeros((2, 4))
    for k in range(2):
        for m in range(4):
            y = np.zeros((len(idx), 2))
            y[:, k] = u3[:, m]
            beta = (H @ y.ravel()).reshape(2, 6)
            v[k, m] = g @ np.array([beta[0, 1], beta[0, 2], beta[1, 1], beta[1, 2]])
    rows = [k * 10 + 6 + m for k in range(2) for m in range(4)]
    b = v.ravel() @ beta3.ravel()[rows]
    sd_b = np.sqrt(v.ravel() @ cinv3[np.ix_(rows, rows)] @ v.ravel())
    return max(abs(b) - n_sig * sd_b, 0.0) ** 2


def adaptive(t1, t2, s1, s2, pilot, chi2_crit, min_extra=1, report_extra=1, min_candidates=2,
             lookahead=5, curv_coef=0.1, top_coef=0.6, top_nsig=1.5, two_gate=0.5,
             two_gate_nsig=2.0, cubic_nsig=1.5, nest_alpha=0.01, two_nest_alpha=0.05):
    """One pass of the adaptive estimator given pilot Jacobians (N, 2, 2).

    ``nest_alpha`` is the level of the nested test that a passing linear fit
    also needs (its quadratic terms insignificant; None: no such test);
    ``two_nest_alpha`` that of the nested test (cubic terms insignificant)
    that the larger neighbourhood of a two-scale estimate needs.

    Returns J (N, 2, 2), the error of ln|det J|, the status (0 ok,
    1 misfit, 2 failed, 3 untestable) and the degrees of freedom of the
    error (infinite when ok, the chosen fit's residual ones otherwise),
    following the rules documented in
    :func:`lensdual.estimators.size_magnification`.
    """
    n = len(t1)
    jac = np.full((n, 2, 2), np.nan)
    sd = np.full(n, np.nan)
    status = np.full(n, 2)
    dofs = np.zeros(n)
    nest_crit = None if nest_alpha is None else _chi2_dist.isf(nest_alpha, 6)
    two_nest_crit = None if two_nest_alpha is None else _chi2_dist.isf(two_nest_alpha, 8)
    for a in range(n):
        order = np.argsort(((t2 - t2[a]) ** 2).sum(axis=1), kind="stable")
        # passing fits are ranked by the variance of ln|det J| along the pilot's
        # gradient (their own errors where the pilot is singular)
        p_det = np.linalg.det(pilot[a])
        g_pilot = (_ln_det_gradient(pilot[a]) if np.isfinite(p_det) and p_det != 0.0
                   else None)
        best = fallback = worst = None
        consistent = []
        reported = {}  # (degree, k) -> ln|det J| of every reported fit
        for dt in range(1, 4 - report_extra):
            dr = dt + report_extra
            for k in range((dr + 1) * (dr + 2) // 2 + min_extra, n + 1):
                idx = order[:k]
                _, _, chi2, dof = _gls_fit(t1, t2, a, idx, dt, s1, s2, pilot[a])
                j, cj, chi2_r, dof_r = _gls_fit(t1, t2, a, idx, dr, s1, s2, pilot[a])
                det = np.linalg.det(j)
                s, rank = _error_and_rank(j, cj, g_pilot)
                reported[(dr, k)] = (np.log(abs(det)), s**2)
                # a linear test also needs its quadratic terms insignificant
                nested_ok = dt != 1 or nest_crit is None or chi2 - chi2_r <= nest_crit
                if chi2 <= chi2_crit[dof] and nested_ok:
                    # the truncation the fit cannot test: its top-order change
                    rank += (top_coef * _top_change(t1, t2, a, idx, dr, s1, s2, pilot[a],
                                                    n_sig=top_nsig)) ** 2
                    if best is None or rank < best[2]:
                        # a quadratic licensed by a linear test also holds the
                        # bias the row's cubic terms alias into its slopes
                        bias2 = (_cubic_alias_bias2(t1, t2, a, idx, s1, s2, pilot[a], j,
                                                    cubic_nsig)
                                 if dt == 1 and dr == 2 and n >= 10 + min_extra else 0.0)
                        best = (j, s, rank, _centre_gradient2(t1, t2, a, idx, dr, s1, s2,
                                                              pilot[a]), bias2)
                    continue
                sf = s * np.sqrt(max(1.0, _press_ratio(t1, t2, a, idx, dr, s1, s2, pilot[a])))
                if chi2_r <= chi2_crit[dof_r]:
                    consistent.append((dr, k))
                    if fallback is None or sf < fallback[1]:
                        curv = _curvature(t1, t2, a, idx, dr, s1, s2, pilot[a])
                        fallback = (j, sf, np.log(abs(det)), dr, k, dof_r, curv,
                                    _centre_gradient2(t1, t2, a, idx, dr, s1, s2, pilot[a]))
                elif worst is None or sf < worst[1]:
                    curv = _curvature(t1, t2, a, idx, dr, s1, s2, pilot[a])
                    worst = (j, sf, np.log(abs(det)), dr, k, dof_r, curv,
                             _centre_gradient2(t1, t2, a, idx, dr, s1, s2, pilot[a]))
        if report_extra == 1:
            best = _two_scale_best(t1, t2, a, order, s1, s2, pilot[a], chi2_crit, min_extra,
                                   g_pilot, best, top_coef, top_nsig, two_gate, two_gate_nsig,
                                   nest_crit, two_nest_crit)
        # the pair's own L2 noise moves the point where the fits take J
        v_centre = s2[a] ** 2
        if best is not None:
            bias2 = best[4] if len(best) > 4 else 0.0  # two-scale estimates have none
            jac[a], sd[a], status[a], dofs[a] = (
                best[0], np.sqrt(best[1] ** 2 + v_centre * best[3] + bias2), 0, np.inf)
        else:
            # a fallback fit: the self-consistent one, else the least-bad one
            chosen = fallback if fallback is not None else worst
            if chosen is None:
                continue
            j, sf, l_best, d_best, k_best, dofs[a], curv, g2 = chosen
            # the mean excess over the other self-consistent fits and the next
            # larger neighbourhoods of the chosen degree (each fit once)
            near = {(d, k) for (d, k) in reported
                    if d == d_best and k_best < k <= k_best + lookahead}
            keys = (set(consistent) | near) - {(d_best, k_best)}
            # the truncation term is one more entry of the mean
            excess = [max((reported[key][0] - l_best) ** 2 - reported[key][1], 0.0)
                      for key in keys]
            trunc = curv_coef * curv**2
            var = sf**2 + np.mean(excess + [trunc**2]) + v_centre * g2
            # tested ("misfit") with enough self-consistent fits to judge the
            # model error; otherwise reported with it but "untestable"
            tested = fallback is not None and len(consistent) >= min_candidates
            jac[a], sd[a], status[a] = j, np.sqrt(var), 1 if tested else 3
    return jac, sd, status, dofs
