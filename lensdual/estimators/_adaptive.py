"""Numba kernels of the locality-adaptive estimator (``method="adaptive"``).

:func:`adaptive_pair` is its one-pair kernel (its docstring specifies the
algorithm) and ``tests/_reference.py`` its plain-numpy twin. Positions are
plain ``float64`` arrays in one angular unit, as in
:mod:`lensdual.estimators._kernels`; nothing is validated here.

One pair's estimate (:func:`adaptive_pair`) sets up its frame and design
with :func:`_pilot_frame` (the eigenframe of ``P P^T``, ``P`` the pilot
Jacobian, where the effective-variance noise ``s1^2 I + s2^2 P P^T`` of the
two output components is independent), :func:`_ranked_design` (the pair's
neighbours ranked by distance in L2, their monomials up to degree 3, rotated
outputs and weights) and :func:`_pilot_gradient` (the gradient of
``ln|det|`` at the pilot, which ranks the passing fits). It then adds the
points one by one (:func:`_add_point`), factors each neighbourhood's normal
matrices once (:func:`_factor_neighbourhood`) and tests, ranks and records
its fits with the helpers below; :func:`_residual_pass` is the reported
fit's chi-square and PRESS while no fit has passed.

Every tuning constant is a field of :class:`AdaptiveSettings`. The kernels
pass arrays, not namedtuples of arrays, to the helpers that run for every
neighbourhood: Numba takes and releases a reference to each array of a
namedtuple argument, which made a namedtuple version of this kernel 1.8
times slower.
"""

from typing import NamedTuple

import numpy as np
from numba import njit

from .._numba import JIT_OPTIONS
from ._kernels import (
    COND_MAX,
    STATUS_OK,
    _jacobian_quad,
    _pair_sums,
    _row,
    _solve_normal,
    all_rows,
)
from ._linalg import cholesky_factor, factored_solve, inverse_entry, slope_covariance

__all__ = []

METHOD_ADAPTIVE = 3

#: Coefficients of the largest fit: tested fits have degree 1 or 2, reported
#: ones up to 3, and a full cubic in two variables has 10 coefficients.
NCOEF_MAX = 10

ADAPTIVE_OK = 0  # a local fit consistent with the noise was found
ADAPTIVE_MISFIT = 1  # no tested fit passed, but a reported fit is consistent on its own
ADAPTIVE_FAILED = 2  # no usable fit (too few or degenerate baselines)
ADAPTIVE_UNTESTABLE = 3  # no fit, not even the reported one, is consistent with the noise

_INLINE = {**JIT_OPTIONS, "inline": "always"}

# Coefficient counts and offsets passed to the helpers below are numpy integers
# (see lensdual._numba), except in the loops over neighbourhoods of _store_linear,
# _two_scale and _cubic_alias, whose small loops are compiled for the fixed sizes.
#: Coefficients of a linear fit (1, x, y); the quadratic monomials start here.
N_LINEAR = np.int64(3)
#: Coefficients of a quadratic fit; the cubic monomials start here.
N_QUADRATIC = np.int64(6)
#: Coefficients of a cubic fit.
N_CUBIC = np.int64(10)
#: The cubic monomials (x^3, x^2 y, x y^2, y^3).
N_CUBIC_TERMS = np.int64(4)
#: The degree of the quadratic terms.
DEGREE_2 = np.int64(2)


class AdaptiveSettings(NamedTuple):
    """The tuning constants of the adaptive estimator, each with its default.

    The measurements behind each default are in the record of design
    decisions of the documentation. ``nest_crit6`` and
    ``two_nest_crit8`` are the chi-square quantiles of ``nest_alpha`` and
    ``two_nest_alpha`` (the tests check them against scipy).
    """

    #: Significance of the chi-square test that a local polynomial fits within the noise.
    alpha: float = 0.05
    #: Degrees of freedom a reported fit keeps beyond its coefficients.
    min_extra: int = 1
    #: Degrees the reported fit lies above the tested one (1: robust bias correction).
    report_extra: int = 1
    #: Self-consistent fits a "misfit" estimate needs (their spread is its model error).
    min_candidates: int = 2
    #: Larger neighbourhoods (same degree) whose change widens a "misfit" error.
    lookahead: int = 5
    #: Passes of the effective-variance iteration (pilot Jacobian -> estimate).
    n_pass: int = 2
    #: Where no L2-to-L1 fit is testable, fit the L1-to-L2 map and invert it.
    reverse: bool = True
    #: With a neighbour cap, neighbourhoods up to this size are all tried, larger
    #: ones on a geometric grid (steps of 1/8); without a cap every one is.
    k_dense: int = 10
    #: Truncation error of a "misfit" fit, ``curv_coef * c^2`` in ln|det J|
    #: (``c`` its curvature).
    curv_coef: float = 0.1
    #: Noise allowance (in standard errors) subtracted from the curvature ``c``.
    curv_nsig: float = 2.0
    #: Weight of the top-order change ``c_top`` in the rank of a passing fit.
    top_coef: float = 0.6
    #: Noise allowance subtracted from ``c_top``.
    top_nsig: float = 1.5
    #: Largest change of ln|det J| across a two-scale estimate's larger
    #: neighbourhood (plus ``two_gate_nsig`` times its noise).
    two_gate: float = 0.5
    #: Noise allowance added to that change before the gate.
    two_gate_nsig: float = 2.0
    #: Noise allowance subtracted from the cubic alias bias of a quadratic
    #: licensed by a linear test.
    cubic_nsig: float = 1.5
    #: Level of the nested test (linear against quadratic) of a passing linear fit.
    nest_alpha: float = 0.01
    #: Its critical value, ``chi2.isf(nest_alpha, 6)``.
    nest_crit6: float = 16.811893829770927
    #: Level of the nested test (quadratic against cubic) of a two-scale
    #: estimate's larger neighbourhood.
    two_nest_alpha: float = 0.05
    #: Its critical value, ``chi2.isf(two_nest_alpha, 8)``.
    two_nest_crit8: float = 15.507313055865453
    #: Largest condition number of the Quad pilot's least-squares design.
    pilot_cond_max: float = COND_MAX


#: The settings the public functions use.
SETTINGS = AdaptiveSettings()


# ---------------------------------------------------------------------------
# the fits' building blocks
# ---------------------------------------------------------------------------


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
def _rotate_cov(c, s, cv, hmax, out):
    """The covariance of ``vec J = (J00, J01, J10, J11)`` in the original frame
    into ``out`` (4, 4), from the rotated slopes' covariance entries
    ``cv[comp] = (11, 12, 22)`` (independent components, ``J' = slopes /
    hmax``, ``J = R J'``): ``cov(J_ij, J_kl) = sum_m R_im R_km C_m[j, l]``."""
    r = ((c, -s), (s, c))
    h2 = hmax * hmax
    for i in range(2):
        for j in range(2):
            for k in range(2):
                for m in range(2):
                    v = 0.0
                    for comp in range(2):
                        e = j + m  # (0, 0) -> 0, (0, 1) and (1, 0) -> 1, (1, 1) -> 2
                        v += r[i][comp] * r[k][comp] * cv[comp, e]
                    out[2 * i + j, 2 * k + m] = v / h2


@njit(**JIT_OPTIONS)
def _copy_matrix(src, out):
    """``out[:, :] = src`` for the small matrices of a pair (Jacobians, slope
    covariances), element by element: a slice assignment compiles Numba's
    shape-mismatch error machinery."""
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            out[i, j] = src[i, j]


@njit(**JIT_OPTIONS)
def _order_change(L, pr, scale, work, beta, U, kk, g00, g01, g10, g11, hmax, n_sig, deg,
                  cov_o, grad):
    """The largest change of ln|det J| across a fit's ``kk`` points that its
    terms of degree ``deg`` (2 or 3) alone predict, ``tr(J^-1 dJ_deg(u))``,
    less ``n_sig`` times its standard error at each point (from the fit's
    covariance, J held fixed); 0 when the fit (``pr`` coefficients) has no
    such terms. Degree 2 is the curvature of a "misfit" fit, the fit's top
    degree its top-order change (see :func:`adaptive_pair`)."""
    return _order_changes(L, pr, scale, work, beta, U, kk, g00, g01, g10, g11, hmax, n_sig,
                          0.0, deg, cov_o, grad)[0]


@njit(**JIT_OPTIONS)
def _block_covariance(L, pr, scale, i0, m, work, out):
    """The covariance of the ``m`` coefficients from ``i0`` of both components'
    fits (``pr`` coefficients, factors ``L``) into ``out[comp, :m, :m]``."""
    for comp in range(2):
        for j in range(m):
            inverse_entry(L[comp], pr, scale, i0 + j, i0 + j, work)
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
    variance of ``ln|det J|`` (see :func:`adaptive_pair`).
    """
    if pr < 6:
        return 0.0  # no second-order terms
    h2 = hmax * hmax
    _block_covariance(L, pr, scale, N_LINEAR, N_LINEAR, work, cov_o)
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
            factored_solve(L[comp], 3, scale, rhs_al, sol_al)
            h_al[j, comp, 0, m] = sol_al[1]
            h_al[j, comp, 1, m] = sol_al[2]
        slope_covariance(L[comp], 3, scale, work, h_cv[j, comp])


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
               q, best_rank, s13, s33, cov_o, grad_o, jb, cb, st):
    """Two-scale estimates at the ``kk`` points whose quadratic fit (``beta``,
    factor ``L``) passed its test: each stored linear fit of ``h < kk``
    points, less the alias of this quadratic's second-order terms (robust
    bias correction whose bias estimate comes from the larger
    neighbourhood). Returns ``(rank, sd, g2)`` of the best-ranked one below
    ``best_rank`` (its Jacobian in ``jb``, its slopes' covariance in ``cb``;
    ``g2`` from
    :func:`_centre_gradient2` of the quadratic), or ``(best_rank, -1, 0)``.

    The covariance of ``slopes_h - A_h gamma_b`` is exact: with ``S`` the
    inverse normal matrix of the quadratic fit and the points of ``h`` the
    first of ``b``, ``cov(slopes_h, gamma_b) = [I | A_h] S[:, 2nd]`` and the
    slopes' covariance is ``M_h^-1 - S12 A^T - A S21 - A S22 A^T``.
    """
    for comp in range(2):
        for m in range(3):
            jcol = 3 + m
            inverse_entry(L[comp], 6, scale, 1, jcol, work)
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
                                   st.top_nsig, st.two_gate_nsig, 2, cov_o, grad_o)
        if cup > st.two_gate:
            continue
        rank += (st.top_coef * ctop) ** 2
        if rank < best_rank:
            best_rank = rank
            best_sd = np.sqrt(var_ln)
            best_g2 = _centre_gradient2(L, 6, scale, work, beta, g00, g01, g10, g11, hmax,
                                        cov_o)
            _rotate_back(c, s, jr00, jr01, jr10, jr11, jb)
            _copy_matrix(cv, cb)
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
            factored_solve(L[comp], 6, scale, rhs_al, sol_al)
            v3[comp, m] = (ga * sol_al[1] + gb * sol_al[2]) / hmax


@njit(**JIT_OPTIONS)
def _cubic_alias_bias2(A, L, scale, rhs, beta, work, cov_o, v3, n_sig):
    """The squared bias of ``ln|det J|`` that the cubic terms of the map put
    into a quadratic fit's slopes, beyond its noise:
    ``(|b| - n_sig sd(b))_+^2`` with ``b = sum v3 c3``, ``c3``
    the cubic coefficients of the cubic fit of the whole row (``A``, ``rhs``
    its normal sums once every point is in) and ``sd(b)`` from their
    covariance; 0 when that fit is singular. The noise is subtracted as in
    ``c_top`` (``AdaptiveSettings.top_nsig``): with ``b^2 - var b`` (an unbiased
    estimate of the squared bias, clipped at 0) a bias-free fit would gain
    half its ``var b`` on average, which made the errors of cluster arcs at
    10-20 mas conservative (Gaussian-equivalent widths down to 0.71).

    At the ends of a constellation the neighbourhoods are one-sided and
    their slopes alias the cubic terms most, so a quadratic whose linear
    test passed (at 20 mas the test cannot see them) regresses towards the
    constellation's mean; the whole row's cubic terms, with the longest lever
    arm, are the least noisy estimate of them there."""
    for i in range(NCOEF_MAX):
        scale[i] = 1.0  # the row's own radius: the monomials are of u / hmax
    for comp in range(2):
        if cholesky_factor(A[comp], N_CUBIC, scale, L[comp], 1e-13) < N_CUBIC:
            return 0.0
        factored_solve(L[comp], N_CUBIC, scale, rhs[comp], beta[comp])
    _block_covariance(L, N_CUBIC, scale, N_QUADRATIC, N_CUBIC_TERMS, work, cov_o)
    b = 0.0
    var = 0.0
    for comp in range(2):
        for i in range(4):
            b += v3[comp, i] * beta[comp, 6 + i]
            for j in range(4):
                var += v3[comp, i] * cov_o[comp, i, j] * v3[comp, j]
    return max(abs(b) - n_sig * np.sqrt(max(var, 0.0)), 0.0) ** 2


@njit(**JIT_OPTIONS)
def _nested_chi2(L, p, scale, rhs, ywy, sol):
    """Weighted chi-square of both components' fits with ``p`` coefficients
    (the leading block of the factors ``L``), from the normal sums alone: at
    the least-squares solution ``beta`` (into ``sol``), ``r^T W r = y^T W y -
    beta^T rhs``."""
    chi2 = 0.0
    for comp in range(2):
        factored_solve(L[comp], p, scale, rhs[comp], sol[comp])
        w_sum = ywy[comp]
        for i in range(p):
            w_sum -= sol[comp, i] * rhs[comp, i]
        chi2 += max(w_sum, 0.0)
    return chi2


@njit(**JIT_OPTIONS)
def _model_error(cand_ln, cand_var, cand_k, cand_dr, cand_ok, n_cand, ln_c, k_c, dr_c,
                 lookahead, curv, curv_coef):
    """Model error (variance of ``ln|det J|``) of the chosen fallback fit
    (``ln_c`` on ``k_c`` points at degree ``dr_c``, curvature ``curv``).

    The mean of the squared changes of ``ln|det J|`` beyond each fit's own
    noise over the other self-consistent fits and the next ``lookahead``
    larger neighbourhoods of the same degree (the model spread), with the
    square of the truncation error ``curv_coef * curv^2`` as one
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
    trunc = curv_coef * curv * curv
    return (spread + trunc * trunc) / (n_spread + 1.0)


# ---------------------------------------------------------------------------
# one pair
# ---------------------------------------------------------------------------


@njit(**_INLINE)
def _pilot_frame(pilot):
    """``(c, s, ev0, ev1)``: the rotation ``R = [[c, -s], [s, c]]`` whose columns
    are the eigenvectors of ``P P^T`` (``P`` the pilot), and its eigenvalues."""
    m00 = pilot[0, 0] * pilot[0, 0] + pilot[0, 1] * pilot[0, 1]
    m01 = pilot[0, 0] * pilot[1, 0] + pilot[0, 1] * pilot[1, 1]
    m11 = pilot[1, 0] * pilot[1, 0] + pilot[1, 1] * pilot[1, 1]
    half_tr = 0.5 * (m00 + m11)
    disc = np.sqrt(0.25 * (m00 - m11) ** 2 + m01 * m01)
    ev0 = half_tr + disc
    ev1 = max(half_tr - disc, 0.0)
    ang = 0.5 * np.arctan2(2.0 * m01, m00 - m11)
    return np.cos(ang), np.sin(ang), ev0, ev1


@njit(**_INLINE)
def _ranked_design(t1, t2, s1, s2, a, row, c, s, ev0, ev1, order, dsort, U, Yr, W, A, rhs):
    """The design of pair ``a``: the points of ``row`` ranked by distance in L2
    (``order``, squared distances ``dsort``), the monomials of their offsets
    scaled by the largest distance (``U``), their L1 offsets in the pilot
    frame (``Yr``: ``y' = R^T y``) and the effective-variance weights of both
    components (``W``); the normal sums ``A``, ``rhs`` are zeroed. Returns
    that largest distance ``hmax`` (the rest is not filled when it is 0)."""
    n = row.shape[0]
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
        return hmax
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
        for i in range(NCOEF_MAX):
            rhs[comp, i] = 0.0
            for j in range(NCOEF_MAX):
                A[comp, i, j] = 0.0
    return hmax


@njit(**_INLINE)
def _pilot_gradient(pilot, c, s, qv):
    """``d ln|det| / dP'`` of the pilot in the rotated frame (``P' = R^T P``)
    into ``qv`` (zeroed first); returns False for a singular pilot, whose
    fits are then ranked by their own errors."""
    pr00 = c * pilot[0, 0] + s * pilot[1, 0]
    pr01 = c * pilot[0, 1] + s * pilot[1, 1]
    pr10 = -s * pilot[0, 0] + c * pilot[1, 0]
    pr11 = -s * pilot[0, 1] + c * pilot[1, 1]
    pdet = pr00 * pr11 - pr01 * pr10
    pilot_ranks = np.isfinite(pdet) and pdet != 0.0
    if pilot_ranks:
        qv[0] = pr11 / pdet
        qv[1] = -pr10 / pdet
        qv[2] = -pr01 / pdet
        qv[3] = pr00 / pdet
    return pilot_ranks


@njit(**_INLINE)
def _add_point(A, rhs, ywy, U, Yr, W, k):
    """Add point ``order[k]`` to both components' normal systems (full cubic design)."""
    for comp in range(2):
        w = W[k, comp]
        ywy[comp] += w * Yr[k, comp] * Yr[k, comp]
        for i in range(NCOEF_MAX):
            wi = w * U[k, i]
            rhs[comp, i] += wi * Yr[k, comp]
            for j in range(i + 1):
                A[comp, i, j] += wi * U[k, j]


@njit(**_INLINE)
def _largest_fit(kk, st):
    """Coefficients of the largest reported fit ``kk`` points allow (0: none)."""
    p_max = np.int64(0)
    for dt in range(1, 4 - st.report_extra):
        if kk >= _ncoef(dt + st.report_extra) + st.min_extra:
            p_max = _ncoef(dt + st.report_extra)
    return p_max


@njit(**_INLINE)
def _factor_neighbourhood(A, L, scale, spow, hr, p_max):
    """Factor both normal matrices up to ``p_max`` coefficients, each monomial
    of degree ``d`` scaled by ``hr^d`` (``hr = hmax / h_k``: the offsets in
    units of the neighbourhood's radius). Returns the coefficients both
    factors hold (their leading blocks serve every smaller fit)."""
    for d in range(4):
        spow[d] = hr ** float(d)
    for i in range(NCOEF_MAX):
        scale[i] = spow[int(_MONOMIAL_DEGREE[i])]
    n_fac0 = cholesky_factor(A[0], p_max, scale, L[0], 1e-13)
    n_fac1 = cholesky_factor(A[1], p_max, scale, L[1], 1e-13)
    return min(n_fac0, n_fac1)


@njit(**_INLINE)
def _residual_pass(U, W, Yr, L, scale, beta, work, kk, pr):
    """The reported fit's (``pr`` coefficients) weighted chi-square on the ``kk``
    points, its PRESS (leave-one-out residuals from the leverages
    ``w |L^-1 S u|^2``) and PRESS's null expectation."""
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
    return chi2_r, press, press_null


@njit(**_INLINE)
def _pair_state(n):
    """The per-pair arrays of :func:`adaptive_pair` for a row of ``n`` points.

    In order: the fallback candidates (``cand_f``: ln|det J| and its
    variance; ``cand_i``: points and degree; ``cand_ok``: consistent on its
    own), the two fallback slots (``fb_f``: PRESS-scaled error, ln|det J|,
    degrees of freedom, curvature, centre gradient; ``fb_i``: points and
    degree; ``jfb``: Jacobians; slot 0 the best self-consistent fit, slot 1
    the least-bad other one), the stored linear fits of the two-scale
    estimates (``h_k``, ``h_sl``, ``h_al``, ``h_cv``), the best estimate's
    Jacobian and cubic alias (``jb``, ``v3``), scratch, and the slopes'
    covariances of the best estimate (``cb``) and of the fallback slots
    (``cfb``, scaled as their errors).
    """
    fb_f = np.zeros((5, 2))
    fb_f[0, :] = np.inf
    return (np.empty((2, 4 * n)), np.empty((2, 4 * n), dtype=np.int64),
            np.empty(4 * n, dtype=np.bool_), fb_f, np.zeros((2, 2), dtype=np.int64),
            np.empty((2, 2, 2)), np.empty(n, dtype=np.int64), np.empty((n, 2, 2)),
            np.empty((n, 2, 2, 3)), np.empty((n, 2, 3)), np.empty((2, 2)), np.empty((2, 4)),
            np.empty((2, 3)), np.empty(4), np.zeros(2), np.empty((2, 4, 4)), np.empty(4),
            np.empty((2, NCOEF_MAX)), np.empty(3), np.empty(3), np.empty((2, 2, 3)),
            np.empty((2, 3, 3)), np.empty(6), np.empty(6), np.zeros(4), np.empty((2, 3)),
            np.empty((2, 2, 3)))


@njit(**_INLINE)
def _test_fit(L, scale, rhs, ywy, beta, beta_n, chi2_crit, kk, dt, pt, pr, n_fac, bias_fit, st):
    """The chi-square test of degree ``dt`` (``pt`` coefficients) on the ``kk``
    points and its nested tests; ``(passed, two_passed)``.

    A linear fit also needs its quadratic terms to be insignificant (the
    likelihood-ratio test at ``st.nest_alpha``). A quadratic test serving
    the two-scale estimates (``bias_fit``) also needs its cubic terms to be
    insignificant (``st.two_nest_alpha``) for ``two_passed``. ``beta`` is
    left holding the tested fit.
    """
    chi2 = _nested_chi2(L, pt, scale, rhs, ywy, beta)
    passed = chi2 <= chi2_crit[2 * (kk - pt)]
    if passed and dt == 1 and pr - pt == 3 and n_fac >= pr:
        # the nested test: the chi-square the quadratic terms remove
        passed = chi2 - _nested_chi2(L, pr, scale, rhs, ywy, beta_n) <= st.nest_crit6
    two_passed = passed
    if passed and bias_fit and n_fac >= N_CUBIC:
        two_passed = (chi2 - _nested_chi2(L, N_CUBIC, scale, rhs, ywy, beta_n)
                      <= st.two_nest_crit8)
    return passed, two_passed


@njit(**_INLINE)
def _reported_fit(L, scale, rhs, beta, work, cov, pr, hmax):
    """Solve the reported fit (``pr`` coefficients) with its slopes' covariance
    ``cov``; its rotated Jacobian, ``det J'``, ``d ln|det| / dJ'`` and the
    variance of ``ln|det J|`` (:func:`_slopes_jacobian`)."""
    for comp in range(2):
        factored_solve(L[comp], pr, scale, rhs[comp], beta[comp])
        slope_covariance(L[comp], pr, scale, work, cov[comp])
    return _slopes_jacobian(beta[0, 1], beta[0, 2], beta[1, 1], beta[1, 2], cov, hmax)


@njit(**_INLINE)
def _passing_rank(L, scale, work, beta, U, cov, cov_o, grad_o, qv, pilot_ranks, kk, deg, pr,
                  hmax, g, var_ln, best_rank, st):
    """The rank of a passing reported fit of degree ``deg``: its variance of
    ``ln|det J|`` along the pilot's gradient ``qv`` (its own variance for a
    singular pilot), plus ``(st.top_coef c_top)^2`` where that can still
    beat ``best_rank`` (``c_top``: the truncation the fit cannot test, its
    top-order change)."""
    rank = var_ln
    if pilot_ranks:
        rank = _ln_det_form(cov, qv[0], qv[1], qv[2], qv[3], hmax)
        if not rank > 0.0:
            rank = var_ln
    if rank < best_rank and st.top_coef > 0.0:
        ctop = _order_change(L, pr, scale, work, beta, U, kk, g[0], g[1], g[2], g[3], hmax,
                             st.top_nsig, deg, cov_o, grad_o)
        rank += (st.top_coef * ctop) ** 2
    return rank


@njit(**_INLINE)
def _accept(L, scale, work, beta, A, cov_o, rhs_al6, sol_al6, v3, jb, c, s, jr, g, hmax, dt, pr):
    """Make a passing reported fit the estimate: its Jacobian into ``jb``;
    returns its centre gradient (:func:`_centre_gradient2`) and whether it
    is a quadratic licensed by a linear test, whose cubic alias then goes
    into ``v3`` (:func:`_cubic_alias`)."""
    g2 = _centre_gradient2(L, pr, scale, work, beta, g[0], g[1], g[2], g[3], hmax, cov_o)
    _rotate_back(c, s, jr[0], jr[1], jr[2], jr[3], jb)
    lin = dt == 1 and pr == 6
    if lin:
        _cubic_alias(L, scale, A, g[0], g[1], g[2], g[3], hmax, rhs_al6, sol_al6, v3)
    return g2, lin


@njit(**_INLINE)
def _fallback_fit(U, W, Yr, L, scale, beta, work, chi2_crit, kk, pr, var_ln):
    """A reported fit as a fallback: its error scaled by its PRESS misfit,
    whether it is consistent with the noise on its own, and its residual
    degrees of freedom."""
    chi2_r, press, press_null = _residual_pass(U, W, Yr, L, scale, beta, work, kk, pr)
    dof_r = 2 * (kk - pr)
    sdf = np.sqrt(var_ln) * np.sqrt(max(1.0, press / press_null))
    return sdf, chi2_r <= chi2_crit[dof_r], dof_r


@njit(**_INLINE)
def _add_candidate(cand_f, cand_i, cand_ok, n_cand, ln, var_ln, kk, dr, consistent):
    """Record a fallback candidate (room permitting); the new count."""
    if n_cand >= cand_ok.shape[0]:
        return n_cand
    cand_f[0, n_cand] = ln
    cand_f[1, n_cand] = var_ln
    cand_i[0, n_cand] = kk
    cand_i[1, n_cand] = dr
    cand_ok[n_cand] = consistent
    return n_cand + 1


@njit(**_INLINE)
def _keep_fallback(fb_f, fb_i, jfb, cfb, slot, sdf, ln, kk, dr, dof_r, L, scale, work, beta, U,
                   cov, var_ln, cov_o, grad_o, c, s, jr, g, hmax, pr, st):
    """Keep a fit in its fallback ``slot`` when its PRESS-scaled error ``sdf``
    is the smallest there, with its centre gradient and its curvature: the
    largest change of ``ln|det J|`` over the neighbourhood that its
    second-order terms predict, less ``st.curv_nsig`` times its noise (a
    noisy fit's second-order terms would otherwise pass for curvature). Its slopes'
    covariance ``cov`` goes into ``cfb[slot]``, scaled as its error (by
    ``sdf^2 / var_ln``)."""
    if not sdf < fb_f[0, slot]:
        return
    f = sdf * sdf / var_ln
    for comp in range(2):
        for e in range(3):
            cfb[slot, comp, e] = cov[comp, e] * f
    fb_f[0, slot] = sdf
    fb_f[1, slot] = ln
    fb_i[0, slot] = kk
    fb_i[1, slot] = dr
    fb_f[2, slot] = float(dof_r)
    fb_f[4, slot] = _centre_gradient2(L, pr, scale, work, beta, g[0], g[1], g[2], g[3], hmax,
                                      cov_o)
    fb_f[3, slot] = _order_change(L, pr, scale, work, beta, U, kk, g[0], g[1], g[2], g[3], hmax,
                                  st.curv_nsig, DEGREE_2, cov_o, grad_o)
    _rotate_back(c, s, jr[0], jr[1], jr[2], jr[3], jfb[slot])


@njit(**_INLINE)
def _fallback_error(fb_f, fb_i, jfb, cfb, cand_f, cand_i, cand_ok, n_cand, n_consistent,
                    v_centre, st, c, s, hmax, jac_out, jcov_out):
    """``(ln_sd, status, dof)`` without a passing fit: the self-consistent
    fallback fit, or else the least-bad one, widened by its model error
    (:func:`_model_error`) and the pair's own L2 noise; "misfit" with at
    least ``st.min_candidates`` self-consistent fits, "untestable"
    otherwise, "failed" without any. The fit's Jacobian goes into ``jac_out``
    and its covariance, scaled as its error, into ``jcov_out``."""
    for slot in range(2):
        if fb_f[0, slot] < np.inf:
            _copy_matrix(jfb[slot], jac_out)
            _rotate_cov(c, s, cfb[slot], hmax, jcov_out)
            model = _model_error(cand_f[0], cand_f[1], cand_i[0], cand_i[1], cand_ok, n_cand,
                                 fb_f[1, slot], fb_i[0, slot], fb_i[1, slot], st.lookahead,
                                 fb_f[3, slot], st.curv_coef)
            sd = np.sqrt(fb_f[0, slot] * fb_f[0, slot] + model + v_centre * fb_f[4, slot])
            tested = slot == 0 and n_consistent >= st.min_candidates
            return sd, ADAPTIVE_MISFIT if tested else ADAPTIVE_UNTESTABLE, fb_f[2, slot]
    jac_out[:, :] = np.nan
    jcov_out[:, :] = np.nan
    return np.nan, ADAPTIVE_FAILED, 0.0


@njit(**_INLINE)
def _winner_error(jb, cb, best_sd, best_g2, best_lin, v3, A, L, scale, rhs, beta, work, cov_o,
                  n, v_centre, st, c, s, hmax, jac_out, jcov_out):
    """The error of the winning estimate: its own, the pair's own L2 noise
    (``v_centre`` times its squared centre gradient) and, for a quadratic
    licensed by a linear test, the cubic alias bias of the whole row
    (:func:`_cubic_alias_bias2`). Its Jacobian goes into ``jac_out`` and the
    covariance of the Jacobian's own estimate into ``jcov_out``."""
    _copy_matrix(jb, jac_out)
    _rotate_cov(c, s, cb, hmax, jcov_out)
    bias2 = 0.0
    if best_lin and n >= N_CUBIC + st.min_extra:
        bias2 = _cubic_alias_bias2(A, L, scale, rhs, beta, work, cov_o, v3, st.cubic_nsig)
    return np.sqrt(best_sd * best_sd + v_centre * best_g2 + bias2)


@njit(**JIT_OPTIONS)
def adaptive_pair(t1, t2, s1, s2, a, row, pilot, chi2_crit, k_dense, st, order, dsort, U, Yr,
                  W, A, rhs, L, scale, beta, work, jac_out, jcov_out):
    """Adaptive local-polynomial Jacobian at pair ``a``; returns (ln_sd, status, dof).

    The points are those of the neighbour ``row`` of ``a`` (``a`` included),
    ``pilot`` is the pilot Jacobian, ``chi2_crit[dof]`` the critical values of
    the chi-square test and ``st`` the :class:`AdaptiveSettings`; the other
    arrays are scratch of :func:`adaptive_knn`.
    The noise of each baseline is the effective variance
    ``s1^2 I + s2^2 P P^T`` (P the pilot Jacobian at ``a``); in the frame of
    the eigenvectors of ``P P^T`` the two output components are independent,
    so each is a weighted polynomial fit of its own. Candidate fits use the
    ``k`` nearest neighbours of ``a`` in L2 (``a`` included): a fit of degree
    ``d`` (1 or 2) tests whether the map is that smooth there (chi-square of
    both components against ``chi2_crit[dof]``; a linear one also needs the
    quadratic terms of the same points to be insignificant, the nested
    likelihood-ratio test at ``st.nest_alpha``: the chi-square test
    spreads its power over ``2 (k - 3)`` degrees of freedom and passes large
    neighbourhoods whose curvature the nested test sees plainly, and with it
    the truncation of the quadratic reported for them), and the estimate
    reported for that neighbourhood is the fit of degree ``d + st.report_extra`` on the
    same points, whose truncation bias is one order smaller (robust bias
    correction). A linear fit that passed its test on ``h`` points also
    gives *two-scale* estimates (:func:`_two_scale`): its slopes less the
    alias of the quadratic terms of each larger neighbourhood ``b > h``
    whose quadratic fit passes its own test and whose cubic terms are
    insignificant (the nested test of the quadratic against the cubic on the
    ``b`` points, at ``st.two_nest_alpha``, where ``b`` is enough for a
    cubic), provided that quadratic is known to be gentle (its change of
    ``ln|det J|`` across the ``b`` points plus ``st.two_gate_nsig``
    times its noise at most ``st.two_gate``); its ``c_top`` is that
    quadratic's change.
    Among the passing estimates, the one whose
    reported fit has the smallest variance of ``ln|det J|`` *along the
    pilot's gradient* plus ``(st.top_coef c_top)^2`` wins
    (``ADAPTIVE_OK``), and its own error is returned. The ranking uses the
    fits' covariances (their designs) and the common pilot, not each fit's
    own noisy ``det J``: ranked by their own errors, which scale as
    ``1 / |det J|``, fits whose noise raised ``|det J|`` would win (a
    selection bias towards over-estimates). ``c_top`` (:func:`_order_change`)
    is the largest change of ``ln|det J|`` across the neighbourhood that the
    reported fit's highest-degree terms alone predict, less
    ``st.top_nsig`` times its noise: where it is large, the terms
    the fit truncates next are likely to matter, so a smaller neighbourhood
    is preferred to a larger one that passed its test only because that
    test cannot see them.

    If none passes, the reported fits that pass the chi-square test on their
    own are used: the one with the smallest error scaled by its
    leave-one-out (PRESS) misfit, widened by its model error: the mean,
    over the other self-consistent fits and the next ``st.lookahead`` larger
    neighbourhoods of its degree, of the squared change of ``ln|det J|``
    beyond each fit's noise, with the square of a truncation error
    ``st.curv_coef * c^2`` as one more term of that mean. Both
    estimate the chosen fit's bias: with few comparisons (8 sources) the
    truncation term carries the mean, with many the comparisons do
    (``ADAPTIVE_MISFIT``, when at least ``st.min_candidates`` fits are
    self-consistent). ``c``, the chosen fit's curvature, is the largest
    ``|tr(J^-1 dJ(u))| - st.curv_nsig sd``
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
    the next ``st.lookahead`` neighbourhoods of its degree). Measured on the
    calibration suite's untestable pairs, their pulls' Gaussian-equivalent
    width falls from 1.41 (PRESS-scaled error alone) to 0.87.

    An ``ADAPTIVE_OK`` quadratic reported for a passing *linear* test also
    holds the bias that the map's cubic terms alias into its slopes, beyond
    ``st.cubic_nsig`` times its noise (:func:`_cubic_alias_bias2`,
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
    c, s, ev0, ev1 = _pilot_frame(pilot)
    hmax = _ranked_design(t1, t2, s1, s2, a, row, c, s, ev0, ev1, order, dsort, U, Yr, W, A, rhs)
    if not hmax > 0.0:
        jac_out[:, :] = np.nan
        jcov_out[:, :] = np.nan
        return np.nan, ADAPTIVE_FAILED, 0.0
    (cand_f, cand_i, cand_ok, fb_f, fb_i, jfb, h_k, h_sl, h_al, h_cv, jb, v3, cov, spow, ywy,
     cov_o, grad_o, beta_n, rhs_al, sol_al, s13, s33, rhs_al6, sol_al6, qv, cb,
     cfb) = _pair_state(n)
    pilot_ranks = _pilot_gradient(pilot, c, s, qv)
    best_rank = best_sd = np.inf
    best_g2 = 0.0
    found = best_lin = False
    # int64 counters from the start (a literal 0 would compile their callees once more)
    n_cand = n_consistent = n_h = k_last = np.int64(0)
    # stored linear fits serve the two-scale estimates (report_extra == 1 only)
    two_scale = st.report_extra == 1
    for k in range(n):
        _add_point(A, rhs, ywy, U, Yr, W, k)
        kk = k + 1
        hk = np.sqrt(dsort[k])
        # beyond k_dense points, fits are tried on a geometric grid of
        # neighbourhood sizes only (steps of about 1/8), and at the full row
        if not hk > 0.0 or (kk > k_dense and kk < n and 8 * (kk - k_last) < k_last):
            continue
        k_last = kk
        p_max = _largest_fit(kk, st)
        if p_max == 0:
            continue
        n_fac = _factor_neighbourhood(A, L, scale, spow, hmax / hk, p_max)
        for dt in range(1, 4 - st.report_extra):
            pt = _ncoef(dt)
            pr = _ncoef(dt + st.report_extra)
            # a quadratic test also serves the two-scale estimates of the stored
            # linear fits, from fewer points than its own reported (cubic) fit needs
            # (stored fits come in increasing size: the first is the smallest)
            bias_fit = two_scale and dt == 2 and n_h > 0 and h_k[0] < kk and kk >= pt + st.min_extra
            if (kk < pr + st.min_extra and not bias_fit) or n_fac < pt:
                continue
            passed, two_passed = _test_fit(L, scale, rhs, ywy, beta, beta_n, chi2_crit, kk, dt,
                                           pt, pr, n_fac, bias_fit, st)
            if passed and two_scale and dt == 1:
                _store_linear(L, scale, A, beta, work, rhs_al, sol_al, h_sl, h_al, h_cv, n_h)
                h_k[n_h] = kk
                n_h += 1
            if two_passed and bias_fit:
                rank2, sd2, g2 = _two_scale(L, scale, work, beta, U, kk, hmax, h_k, h_sl, h_al,
                                            h_cv, n_h, c, s, pilot_ranks, qv, best_rank, s13, s33,
                                            cov_o, grad_o, jb, cb, st)
                # (the rank comes back unchanged unless a two-scale estimate won)
                won = sd2 > 0.0
                best_rank = rank2
                best_sd = sd2 if won else best_sd
                best_g2 = g2 if won else best_g2
                found = found or won
                best_lin = best_lin and not won
            # only a better-ranked passing fit can change a result once found
            if kk < pr + st.min_extra or (found and not passed) or n_fac < pr:
                continue
            jr00, jr01, jr10, jr11, det, g00, g01, g10, g11, var_ln = _reported_fit(
                L, scale, rhs, beta, work, cov, pr, hmax)
            if not var_ln > 0.0:
                continue
            jr = (jr00, jr01, jr10, jr11)
            g = (g00, g01, g10, g11)
            if passed:
                rank = _passing_rank(L, scale, work, beta, U, cov, cov_o, grad_o, qv, pilot_ranks,
                                     kk, dt + st.report_extra, pr, hmax, g, var_ln, best_rank, st)
                if rank < best_rank:
                    best_rank, best_sd, found = rank, np.sqrt(var_ln), True
                    best_g2, best_lin = _accept(L, scale, work, beta, A, cov_o, rhs_al6, sol_al6,
                                                v3, jb, c, s, jr, g, hmax, dt, pr)
                    _copy_matrix(cov, cb)
            if not found:
                dr = dt + st.report_extra
                sdf, consistent, dof_r = _fallback_fit(U, W, Yr, L, scale, beta, work,
                                                       chi2_crit, kk, pr, var_ln)
                ln_det = np.log(abs(det))
                n_cand = _add_candidate(cand_f, cand_i, cand_ok, n_cand, ln_det, var_ln, kk, dr,
                                        consistent)
                n_consistent += consistent
                _keep_fallback(fb_f, fb_i, jfb, cfb, 0 if consistent else 1, sdf, ln_det, kk,
                               dr, dof_r, L, scale, work, beta, U, cov, var_ln, cov_o, grad_o, c,
                               s, jr, g, hmax, pr, st)
    # the pair's own L2 noise moves the point where the fits take the Jacobian
    # (every offset is measured from it): s2^2 |grad ln|det J||^2
    v_centre = s2[a] * s2[a]
    if found:
        return _winner_error(jb, cb, best_sd, best_g2, best_lin, v3, A, L, scale, rhs, beta,
                             work, cov_o, n, v_centre, st, c, s, hmax, jac_out,
                             jcov_out), ADAPTIVE_OK, np.inf
    return _fallback_error(fb_f, fb_i, jfb, cfb, cand_f, cand_i, cand_ok, n_cand, n_consistent,
                           v_centre, st, c, s, hmax, jac_out, jcov_out)


# ---------------------------------------------------------------------------
# entry points
# ---------------------------------------------------------------------------


@njit(**_INLINE)
def _copy_positions(t, noise, c, out):
    """The positions of copy ``c``: ``out = t + noise[c]``, or ``t`` itself when
    there are no copies (``noise`` empty)."""
    if noise.shape[0] == 0:
        return t
    for i in range(t.shape[0]):
        for d in range(2):
            out[i, d] = t[i, d] + noise[c, i, d]
    return out


@njit(**JIT_OPTIONS)
def normal_pilots(t1, t2, nbr, noise1, noise2, need, weight_power, pilot, ok):
    """The first-order Quad Jacobians from the normal equations
    (:func:`~lensdual.estimators._kernels._solve_normal`) of the pairs where
    ``need`` (C, N) is true, on the copies of :func:`adaptive_knn`, into
    ``pilot`` (C, N, 2, 2); ``ok`` (C, N) is set False where the normal
    equations are too badly conditioned (those pilots are then
    :func:`lstsq_pilots`). Other entries are left as they are."""
    n = t1.shape[0]
    acc = np.empty(7)
    p1 = np.empty((n, 2))
    p2 = np.empty((n, 2))
    for c in range(need.shape[0]):
        q1 = _copy_positions(t1, noise1, c, p1)
        q2 = _copy_positions(t2, noise2, c, p2)
        for a in range(n):
            if need[c, a]:
                _pair_sums(q1, q2, _row(nbr, a), a, weight_power, acc)
                ok[c, a] = _solve_normal(acc, pilot[c, a])


@njit(**JIT_OPTIONS)
def lstsq_pilots(t1, t2, nbr, rows, weight_power, cond_max, pilot):
    """The first-order Quad Jacobians by least squares of the pairs ``rows``
    (whose normal equations failed, :func:`normal_pilots`) into ``pilot``
    (N, 2, 2), the identity where that fails too. A separate kernel: it is
    rarely needed, and compiled only then."""
    k = nbr.shape[1]
    Aq = np.empty((k - 1, 2))
    Yq = np.empty((k - 1, 2))
    sol = np.empty((2, 2))
    for r in range(rows.shape[0]):
        a = rows[r]
        pa = pilot[a]
        if _jacobian_quad(t1, t2, a, _row(nbr, a), 1, weight_power, cond_max, Aq, Yq, sol,
                          pa) != STATUS_OK:
            pa[0, 0] = 1.0
            pa[0, 1] = 0.0
            pa[1, 0] = 0.0
            pa[1, 1] = 1.0


@njit(**_INLINE)
def _rows_passes(t1, t2, nbr, s1, s2, chi2_crit, k_dense, st, rows, pilot0, scratch, jac, jcov,
                 ln_sd, status, dof):
    """The adaptive Jacobian (:func:`adaptive_pair`) of the pairs ``rows`` of one
    copy, from their neighbour rows ``nbr`` and first pilots ``pilot0`` (N, 2, 2)
    (see :func:`adaptive_knn`); ``scratch`` holds the work arrays of
    :func:`adaptive_pair`."""
    order, dsort, U, Yr, W, A, rhs, L, scale, beta, work = scratch
    k = nbr.shape[1]
    m = rows.shape[0]
    pilot = np.empty((m, 2, 2))
    for r in range(m):
        for i in range(2):
            for j in range(2):
                pilot[r, i, j] = pilot0[rows[r], i, j]
    n_pass = st.n_pass
    for p in range(n_pass):
        # with a cap (k_dense < K), the passes that only make the next pass's
        # pilot use the 2 k_dense nearest points
        k_row = k if (p + 1 == n_pass or k_dense >= k) else min(k, 2 * k_dense)
        for r in range(m):
            a = rows[r]
            ln_sd[a], status[a], dof[a] = adaptive_pair(
                t1, t2, s1, s2, a, _row(nbr, a)[:k_row], pilot[r], chi2_crit, k_dense, st, order,
                dsort, U, Yr, W, A, rhs, L, scale, beta, work, jac[a], jcov[a])
        if p + 1 < n_pass:
            for r in range(m):
                a = rows[r]
                if status[a] != ADAPTIVE_FAILED:
                    for i in range(2):
                        for j in range(2):
                            pilot[r, i, j] = jac[a, i, j]


@njit(**JIT_OPTIONS)
def adaptive_knn(t1, t2, nbr, noise1, noise2, s1, s2, chi2_crit, k_dense, st, need, pilot, jac,
                 jcov, ln_sd, status, dof):
    """The adaptive Jacobian (:func:`adaptive_pair`) of the pairs where ``need``
    (C, N) is true, on ``C`` copies of the constellation, from their neighbour
    rows ``nbr``; the other entries of the outputs are left as they are.

    Copy ``c`` has the positions ``t1 + noise1[c]``, ``t2 + noise2[c]``
    (``noise1``, ``noise2`` of shape (C, N, 2)); with noise arrays of shape
    (0, N, 2) there is one copy, ``t1``, ``t2`` themselves. ``jac`` (C, N, 2, 2)
    receives the Jacobians, ``jcov`` (C, N, 4, 4) the covariances of their
    entries ``(J00, J01, J10, J11)`` (of the chosen fit, scaled as its error:
    the part of the error of ``ln|det J|`` that the Jacobian carries, the
    model and centre terms aside), ``ln_sd`` (C, N) the standard errors of
    ``ln|det J|``, ``status`` (C, N) the status codes and ``dof`` (C, N) the
    degrees of freedom the errors were estimated with. ``chi2_crit`` must
    cover ``2 K`` degrees of freedom.

    The pilot Jacobian of the first pass is ``pilot`` (C, N, 2, 2): the
    first-order Quad one on the same neighbour rows (:func:`normal_pilots`,
    :func:`lstsq_pilots`); each further pass (``st.n_pass`` in all) uses the
    previous pass's result (its own pilot where that failed). Each pair's
    estimate depends on its own row and pilot only, so disjoint sets of
    pairs can run in separate threads (the kernels release the GIL), and a
    subset gives the same estimates as the whole, bit for bit. With a cap
    (``k_dense`` below the row length ``K``) the pilot passes use the
    ``2 k_dense`` nearest points of each row only. The neighbour rows are
    the same for every copy.
    """
    n = t1.shape[0]
    k = nbr.shape[1]
    scratch = (np.empty(k, dtype=np.int64), np.empty(k), np.empty((k, NCOEF_MAX)),
               np.empty((k, 2)), np.empty((k, 2)), np.empty((2, NCOEF_MAX, NCOEF_MAX)),
               np.empty((2, NCOEF_MAX)), np.empty((2, NCOEF_MAX, NCOEF_MAX)),
               np.empty(NCOEF_MAX), np.empty((2, NCOEF_MAX)), np.empty(NCOEF_MAX))
    p1 = np.empty((n, 2))
    p2 = np.empty((n, 2))
    for c in range(need.shape[0]):
        _rows_passes(_copy_positions(t1, noise1, c, p1), _copy_positions(t2, noise2, c, p2),
                     nbr, s1, s2, chi2_crit, k_dense, st, np.flatnonzero(need[c]), pilot[c],
                     scratch, jac[c], jcov[c], ln_sd[c], status[c], dof[c])


def run_adaptive(t1, t2, nbr, noise1, noise2, s1, s2, chi2_crit, k_dense, weight_power, st, need,
                 jac, jcov, ln_sd, status, dof):
    """:func:`adaptive_knn` with its first pilots: :func:`normal_pilots`, and
    :func:`lstsq_pilots` for the copies where some normal equations failed
    (arguments as :func:`adaptive_knn`'s, with ``weight_power`` for the pilots)."""
    pilot = np.empty(need.shape + (2, 2))
    ok = np.ones(need.shape, dtype=np.bool_)
    normal_pilots(t1, t2, nbr, noise1, noise2, need, weight_power, pilot, ok)
    failed = need & ~ok
    for c in np.flatnonzero(failed.any(axis=1)):
        p1, p2 = (t1 + noise1[c], t2 + noise2[c]) if noise1.shape[0] else (t1, t2)
        lstsq_pilots(p1, p2, nbr, np.flatnonzero(failed[c]), weight_power, st.pilot_cond_max,
                     pilot[c])
    adaptive_knn(t1, t2, nbr, noise1, noise2, s1, s2, chi2_crit, k_dense, st, need, pilot, jac,
                 jcov, ln_sd, status, dof)


def adaptive_jacobians(t1, t2, s1, s2, chi2_crit, k_dense, weight_power, st, jac, jcov, ln_sd,
                       status, dof):
    """:func:`run_adaptive` of every pair with every point in its row (no cap),
    outputs of one copy (``jac`` (N, 2, 2); ``jcov`` (N, 4, 4); ``ln_sd``,
    ``status``, ``dof`` (N,))."""
    n = t1.shape[0]
    no_noise = np.empty((0, n, 2))
    run_adaptive(t1, t2, all_rows(n), no_noise, no_noise, s1, s2, chi2_crit, k_dense,
                 weight_power, st, np.ones((1, n), dtype=np.bool_), jac[None], jcov[None],
                 ln_sd[None], status[None], dof[None])
