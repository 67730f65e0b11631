"""Numba kernels of Lenstool's dPIE (profile 81) and NFW (profile 12) potentials.

The dPIE kernels sum many components (a cluster model has hundreds); the NFW
kernels, at the end of the module, are documented there.

Everything here is unit-free: positions and radii are plain ``float64`` arrays
in arcsec, the normalisation ``b0`` is in arcsec too (the Einstein radius of
the singular isothermal limit, already multiplied by ``D_ls / D_s``). No input
validation happens here; :mod:`lensdual.parametric.lenstool` does it.

The profile (Kassiola & Kovner 1993; Eliasdottir et al. 2007; Lenstool's
``profile 81``) is, in the frame of the component (``X`` along the major axis)

.. math::

    \\kappa(X, Y) = \\frac{b_0}{2} \\frac{s}{s - a}
        \\left(\\frac{1}{\\sqrt{a^2 + R_\\epsilon^2}}
             - \\frac{1}{\\sqrt{s^2 + R_\\epsilon^2}}\\right),
    \\qquad
    R_\\epsilon^2 = \\frac{X^2}{(1 + \\epsilon)^2} + \\frac{Y^2}{(1 - \\epsilon)^2},

with core radius ``a``, cut radius ``s`` and ``epsilon`` Lenstool's
"potential" ellipticity ``(1 - sqrt(1 - e^2)) / e`` of the mass ellipticity
``e = (A^2 - B^2) / (A^2 + B^2)``: the iso-density axis ratio is
``q = (1 - epsilon) / (1 + epsilon)``.

Each of the two terms is a cored isothermal ellipse. Lenstool evaluates it with
the complex formula of Kassiola & Kovner (its ``ci05`` function); the kernels
use the equivalent real form of Keeton & Kochanek (1998),
``kappa = b / (2 psi)``, ``psi = sqrt(q^2 (w^2 + X^2) + Y^2)`` with
``b = b0 s / (s - a) (1 - epsilon)`` and ``w = (1 + epsilon) r`` for
``r = a, s``:

.. math::

    \\alpha_X = \\frac{b}{t} \\arctan\\frac{t X}{\\psi + w}, \\quad
    \\alpha_Y = \\frac{b}{t} \\operatorname{artanh}\\frac{t Y}{\\psi + q^2 w},
    \\quad t = \\sqrt{1 - q^2},

whose Hessian is rational in ``psi``. The difference of the core and cut terms
is taken inside one ``arctan`` and one ``log1p`` with every subtraction
rewritten so that nothing cancels (``psi_s - psi_a = q^2 (w_s^2 - w_a^2) /
(psi_s + psi_a)``, ...): no precision is lost far from the component, near the
circular limit or on the points where Kassiola & Kovner's ratio is 0/0 (the
tests compare the kernels with Lenstool's complex formula written in plain
numpy: 1e-12 relative).

Speed: the points are processed in blocks; for each block the components are
added by an inner loop over the points that LLVM vectorises (AVX2/AVX-512). For
that the loop holds no calls and no branches: ``arctan`` and ``log`` are
branch-free polynomial versions (:func:`_atan`, within 1 ulp;
:func:`_log_ge1`, within 2 ulp), and a circular component uses a tiny ``t``
instead of a separate formula.

Parameter array ``params``, shape (M, ``N_PARAMS``), one row per component:
``x_centre, y_centre, theta, epsilon, core, cut, b0`` with ``theta`` the
angle of the major axis in radians, counter-clockwise from the x axis,
``0 <= epsilon <= EPS_MAX`` and ``0 <= core < cut``. A core radius of 0 is
allowed (the centre of that component is then singular).
"""

import numpy as np
from numba import njit

__all__ = []

# IEEE division semantics: a singular point yields inf/NaN instead of raising.
from .._numba import JIT_OPTIONS_NUMPY_ERRORS as JIT_OPTIONS  # noqa: F401

P_X, P_Y, P_THETA, P_EPS, P_CORE, P_CUT, P_B0 = range(7)
N_PARAMS = 7

#: Largest ``epsilon`` (axis ratio 1:2000) the kernels take: it keeps the argument of
#: ``_log_ge1`` below 2**64, ``((1 + sqrt(eps)) / (1 - sqrt(eps)))**2`` at most.
EPS_MAX = 0.999

# what to compute: deflection only, Hessian only, both
MODE_ALPHA = 0
MODE_HESSIAN = 1
MODE_BOTH = 2

# columns of the per-component constants (see _prepare)
(_C_X, _C_Y, _C_COS, _C_SIN, _C_Q2, _C_T, _C_B, _C_BT, _C_WA, _C_WS, _C_WA2, _C_WS2,
 _C_DW, _C_DW2) = range(14)
_N_CONST = 14
_T_MIN = 1e-100


@njit(**JIT_OPTIONS)
def _prepare(params):
    """Per-component constants of the inner loop, shape (M, _N_CONST)."""
    m = params.shape[0]
    c = np.empty((m, _N_CONST))
    for j in range(m):
        eps = params[j, P_EPS]
        a = params[j, P_CORE]
        s = params[j, P_CUT]
        q = (1.0 - eps) / (1.0 + eps)
        wa = (1.0 + eps) * a
        ws = (1.0 + eps) * s
        c[j, _C_X] = params[j, P_X]
        c[j, _C_Y] = params[j, P_Y]
        c[j, _C_COS] = np.cos(params[j, P_THETA])
        c[j, _C_SIN] = np.sin(params[j, P_THETA])
        c[j, _C_Q2] = q * q
        # t = sqrt(1 - q^2); a circular component gets a tiny t instead of 0, for which
        # arctan(t g) / t and log1p(t g) / t are g to rounding (no branch in the loop)
        t = max(2.0 * np.sqrt(eps) / (1.0 + eps), _T_MIN)
        b = params[j, P_B0] * s / (s - a) * (1.0 - eps)
        c[j, _C_T] = t
        c[j, _C_B] = b
        c[j, _C_BT] = b / t
        c[j, _C_WA] = wa
        c[j, _C_WS] = ws
        c[j, _C_WA2] = wa * wa
        c[j, _C_WS2] = ws * ws
        c[j, _C_DW] = ws - wa
        c[j, _C_DW2] = (ws - wa) * (ws + wa)
    return c


# --------------------------------------------------------------------------- elementary functions
# Branch-free arctan and log, so that LLVM vectorises the loops over points
# (libm's scalar calls would not vectorise). arctan: Cephes' rational
# approximation (Moshier), within 1 ulp; log: exact binary range reduction by
# powers of two and the artanh series, within 2 ulp for 1 <= u < 2**64.

_T3P8 = 2.41421356237309504880  # tan(3 pi / 8)
_PIO2 = 1.57079632679489661923
_PIO4 = 0.78539816339744830962
_MOREBITS = 6.123233995736765886130e-17
_AP0, _AP1, _AP2, _AP3, _AP4 = (
    -8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
    -1.228866684490136173410e2, -6.485021904942025371773e1)
_AQ0, _AQ1, _AQ2, _AQ3, _AQ4 = (
    2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
    4.853903996359136964868e2, 1.945506571482613964425e2)
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_SQRT2 = 1.4142135623730951


@njit(inline="always", **JIT_OPTIONS)
def _atan(x):
    """arctan(x), branch-free (Cephes atan.c)."""
    z = abs(x)
    big = z > _T3P8
    mid = z > 0.66
    # reduced argument: -1/z, (z - 1)/(z + 1) or z, with one division
    num = -1.0 if big else (z - 1.0 if mid else z)
    den = z if big else (z + 1.0 if mid else 1.0)
    zr = num / den
    y0 = _PIO2 if big else (_PIO4 if mid else 0.0)
    extra = _MOREBITS if big else (0.5 * _MOREBITS if mid else 0.0)
    zz = zr * zr
    p = (((_AP0 * zz + _AP1) * zz + _AP2) * zz + _AP3) * zz + _AP4
    q = ((((zz + _AQ0) * zz + _AQ1) * zz + _AQ2) * zz + _AQ3) * zz + _AQ4
    return np.copysign(y0 + ((zr * (zz * p / q) + zr) + extra), x)


@njit(inline="always", **JIT_OPTIONS)
def _log_ge1(u):
    """log(u) for 1 <= u < 2**64, branch-free."""
    k = 0.0
    f = u >= 4294967296.0
    u = u * 2.3283064365386963e-10 if f else u
    k = k + 32.0 if f else k
    f = u >= 65536.0
    u = u * 1.52587890625e-05 if f else u
    k = k + 16.0 if f else k
    f = u >= 256.0
    u = u * 0.00390625 if f else u
    k = k + 8.0 if f else k
    f = u >= 16.0
    u = u * 0.0625 if f else u
    k = k + 4.0 if f else k
    f = u >= 4.0
    u = u * 0.25 if f else u
    k = k + 2.0 if f else k
    f = u >= 2.0
    u = u * 0.5 if f else u
    k = k + 1.0 if f else k
    f = u > _SQRT2
    u = u * 0.5 if f else u
    k = k + 1.0 if f else k
    # log(u) = 2 artanh(s), |s| <= 0.172
    s = (u - 1.0) / (u + 1.0)
    s2 = s * s
    p = 1.0 / 23.0
    p = p * s2 + 1.0 / 21.0
    p = p * s2 + 1.0 / 19.0
    p = p * s2 + 1.0 / 17.0
    p = p * s2 + 1.0 / 15.0
    p = p * s2 + 1.0 / 13.0
    p = p * s2 + 1.0 / 11.0
    p = p * s2 + 1.0 / 9.0
    p = p * s2 + 1.0 / 7.0
    p = p * s2 + 1.0 / 5.0
    p = p * s2 + 1.0 / 3.0
    return k * _LN2_HI + (k * _LN2_LO + (2.0 * s + 2.0 * s * (p * s2)))


@njit(**JIT_OPTIONS)
def atan_vec(x):
    """Element-wise ``_atan`` (for the tests)."""
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = _atan(x[i])
    return out


@njit(**JIT_OPTIONS)
def log_ge1_vec(u):
    """Element-wise ``_log_ge1`` (for the tests)."""
    out = np.empty_like(u)
    for i in range(u.size):
        out[i] = _log_ge1(u[i])
    return out


# --------------------------------------------------------------------------- the sums
# Points are processed in blocks of BLOCK; for each block the components are
# added one after the other by an inner loop over the points of the block,
# which LLVM vectorises (no calls, no branches).

BLOCK = 256


@njit(inline="always", **JIT_OPTIONS)
def _terms(X, Y, q2, wa, ws, wa2, ws2):
    X2 = X * X
    Y2 = Y * Y
    pa = np.sqrt(q2 * (wa2 + X2) + Y2)  # psi of the core term
    ps = np.sqrt(q2 * (ws2 + X2) + Y2)  # psi of the cut term
    return X2, Y2, X2 + Y2, pa, ps


@njit(inline="always", **JIT_OPTIONS)
def _alpha_local(X, Y, X2, r2, pa, ps, q2, t, bt, wa, ws, wa2, dw, dw2):
    """Deflection of one component in its own frame."""
    spa = ps + pa
    # arctan(t X / (pa + wa)) - arctan(t X / (ps + ws)) = arctan(t gx),
    # with psi_s - psi_a = q2 (ws^2 - wa^2) / (ps + pa)
    nx = X * (q2 * dw2 + dw * spa)
    dnx = spa * ((pa + wa) * (ps + ws) + t * t * X2)
    # artanh(t Y / (pa + q2 wa)) - artanh(t Y / (ps + q2 ws)) = sign(Y) log1p(t gy) / 2,
    # on |Y|, with 1 - t |Y| / (pa + q2 wa) written without cancellation
    ay = abs(Y)
    ty = t * ay
    pty = pa + ty
    ny = 2.0 * ay * (dw2 + dw * spa) * pty
    dny = spa * (wa * pty + wa2 + r2) * (ps + q2 * ws + ty)
    inv = 1.0 / (dnx * dny)
    fx = bt * _atan(t * (nx * dny * inv))
    z = t * (ny * dnx * inv)
    v = 1.0 + z
    # log1p(z) = log(v) - ((v - 1) - z) / v to within an ulp
    fy = 0.5 * bt * (_log_ge1(v) - ((v - 1.0) - z) / v)
    return fx, np.copysign(fy, Y)


@njit(inline="always", **JIT_OPTIONS)
def _hess_local(X, Y, X2, Y2, r2, pa, ps, q2, b, wa, ws, wa2, ws2):
    """Hessian of one component in its own frame.

    Per term: f_XX = b (w psi + q2 w^2 + Y^2) / (psi D), f_XY = -b X Y / (psi D),
    f_YY = b (w psi + w^2 + X^2) / (psi D), D = (1 + q2) w^2 + r^2 + 2 w psi.
    """
    da = pa * ((1.0 + q2) * wa2 + r2 + 2.0 * wa * pa)
    ds = ps * ((1.0 + q2) * ws2 + r2 + 2.0 * ws * ps)
    inv = b / (da * ds)
    ia = ds * inv
    i_s = da * inv
    fxx = (wa * pa + q2 * wa2 + Y2) * ia - (ws * ps + q2 * ws2 + Y2) * i_s
    fxy = -X * Y * (ia - i_s)
    fyy = (wa * pa + wa2 + X2) * ia - (ws * ps + ws2 + X2) * i_s
    return fxx, fxy, fyy


@njit(**JIT_OPTIONS)
def _sum_components(x, y, params, mode, out):
    """Sum the deflection and/or Hessian of all components at all points.

    ``out`` has shape (N, 5) for ``MODE_BOTH`` (alpha_x, alpha_y, f_xx, f_xy,
    f_yy), (N, 2) for ``MODE_ALPHA`` and (N, 3) for ``MODE_HESSIAN``.
    """
    c = _prepare(params)
    m = c.shape[0]
    n = x.shape[0]
    h0 = 2 if mode == MODE_BOTH else 0
    acc = np.zeros((5, BLOCK))
    for start in range(0, n, BLOCK):
        nb = min(BLOCK, n - start)
        acc[:, :] = 0.0
        a0 = acc[0]
        a1 = acc[1]
        a2 = acc[2]
        a3 = acc[3]
        a4 = acc[4]
        xb = x[start:start + nb]
        yb = y[start:start + nb]
        for j in range(m):
            xc = c[j, _C_X]
            yc = c[j, _C_Y]
            cs = c[j, _C_COS]
            sn = c[j, _C_SIN]
            q2 = c[j, _C_Q2]
            t = c[j, _C_T]
            b = c[j, _C_B]
            bt = c[j, _C_BT]
            wa = c[j, _C_WA]
            ws = c[j, _C_WS]
            wa2 = c[j, _C_WA2]
            ws2 = c[j, _C_WS2]
            dw = c[j, _C_DW]
            dw2 = c[j, _C_DW2]
            c2 = cs * cs
            s2 = sn * sn
            cssn = cs * sn
            if mode == MODE_ALPHA:
                for k in range(nb):
                    dx = xb[k] - xc
                    dy = yb[k] - yc
                    X = dx * cs + dy * sn
                    Y = dy * cs - dx * sn
                    X2, Y2, r2, pa, ps = _terms(X, Y, q2, wa, ws, wa2, ws2)
                    fx, fy = _alpha_local(X, Y, X2, r2, pa, ps, q2, t, bt, wa, ws, wa2, dw,
                                          dw2)
                    a0[k] += fx * cs - fy * sn
                    a1[k] += fx * sn + fy * cs
            elif mode == MODE_HESSIAN:
                for k in range(nb):
                    dx = xb[k] - xc
                    dy = yb[k] - yc
                    X = dx * cs + dy * sn
                    Y = dy * cs - dx * sn
                    X2, Y2, r2, pa, ps = _terms(X, Y, q2, wa, ws, wa2, ws2)
                    fxx, fxy, fyy = _hess_local(X, Y, X2, Y2, r2, pa, ps, q2, b, wa, ws,
                                                wa2, ws2)
                    a2[k] += c2 * fxx - 2.0 * cssn * fxy + s2 * fyy
                    a3[k] += cssn * (fxx - fyy) + (c2 - s2) * fxy
                    a4[k] += s2 * fxx + 2.0 * cssn * fxy + c2 * fyy
            else:
                for k in range(nb):
                    dx = xb[k] - xc
                    dy = yb[k] - yc
                    X = dx * cs + dy * sn
                    Y = dy * cs - dx * sn
                    X2, Y2, r2, pa, ps = _terms(X, Y, q2, wa, ws, wa2, ws2)
                    fx, fy = _alpha_local(X, Y, X2, r2, pa, ps, q2, t, bt, wa, ws, wa2, dw,
                                          dw2)
                    fxx, fxy, fyy = _hess_local(X, Y, X2, Y2, r2, pa, ps, q2, b, wa, ws,
                                                wa2, ws2)
                    a0[k] += fx * cs - fy * sn
                    a1[k] += fx * sn + fy * cs
                    a2[k] += c2 * fxx - 2.0 * cssn * fxy + s2 * fyy
                    a3[k] += cssn * (fxx - fyy) + (c2 - s2) * fxy
                    a4[k] += s2 * fxx + 2.0 * cssn * fxy + c2 * fyy
        if mode != MODE_HESSIAN:
            for k in range(nb):
                out[start + k, 0] = a0[k]
                out[start + k, 1] = a1[k]
        if mode != MODE_ALPHA:
            for k in range(nb):
                out[start + k, h0] = a2[k]
                out[start + k, h0 + 1] = a3[k]
                out[start + k, h0 + 2] = a4[k]


@njit(**JIT_OPTIONS)
def dpie_deflection(x, y, params):
    """Deflection ``(alpha_x, alpha_y)`` of the sum of components, shape (N, 2)."""
    out = np.empty((x.shape[0], 2))
    _sum_components(x, y, params, MODE_ALPHA, out)
    return out


@njit(**JIT_OPTIONS)
def dpie_hessian(x, y, params):
    """Hessian ``(f_xx, f_xy, f_yy)`` of the lensing potential, shape (N, 3)."""
    out = np.empty((x.shape[0], 3))
    _sum_components(x, y, params, MODE_HESSIAN, out)
    return out


@njit(**JIT_OPTIONS)
def dpie_deflection_hessian(x, y, params):
    """Deflection and Hessian in one pass: ``(alpha_x, alpha_y, f_xx, f_xy, f_yy)``."""
    out = np.empty((x.shape[0], 5))
    _sum_components(x, y, params, MODE_BOTH, out)
    return out


@njit(**JIT_OPTIONS)
def dpie_convergence(x, y, params):
    """Convergence ``kappa`` of the sum of components, shape (N,)."""
    c = _prepare(params)
    m = c.shape[0]
    n = x.shape[0]
    out = np.empty(n)
    for i in range(n):
        kap = 0.0
        for j in range(m):
            dx = x[i] - c[j, _C_X]
            dy = y[i] - c[j, _C_Y]
            X = dx * c[j, _C_COS] + dy * c[j, _C_SIN]
            Y = dy * c[j, _C_COS] - dx * c[j, _C_SIN]
            q2 = c[j, _C_Q2]
            pa = np.sqrt(q2 * (c[j, _C_WA2] + X * X) + Y * Y)
            ps = np.sqrt(q2 * (c[j, _C_WS2] + X * X) + Y * Y)
            kap += 0.5 * c[j, _C_B] * (1.0 / pa - 1.0 / ps)
        out[i] = kap
    return out


# --------------------------------------------------------------------------- NFW (profile 12)
# Lenstool's profile 12: a circular NFW lensing potential made elliptical in the
# potential (Golse & Kneib 2002), psi(X, Y) = psi_NFW(u) with
# u^2 = (1 - eps) X^2 + (1 + eps) Y^2 in the frame of the component (X along the
# major axis). With x = u / r_s, the circular profile has
#
#     alpha(u) = b g(x) / x,     kappa(u) = b / (2 r_s) f(x),
#     g(x) = ln(x / 2) + h(x),   f(x) = (1 - h(x)) / (x^2 - 1),
#     h(x) = arccosh(1/x) / sqrt(1 - x^2)  (x < 1),  arccos(1/x) / sqrt(x^2 - 1)  (x > 1),
#
# with b = 4 kappa_s r_s = 6 pi (v_disp / c)^2 D_ls / D_s (Lenstool's b0, arcsec).
# h is an analytic function of s = 1 - x^2, h = sum_k s^k / (2k + 1), and
# f = (h - 1) / s = sum_{k>=1} s^(k-1) / (2k + 1): near x = 1 (|s| < _NFW_SERIES) both
# come from that series, elsewhere from the closed forms written without
# cancellation (for x < 1, g = [x^2 ln(2/x) / (1 + v) + log1p(-x^2 / (2 (1 + v)))] / v
# with v = sqrt(s)). In the frame of the component, with m = alpha(u) / u and
# gamma = m - kappa(u),
#
#     alpha_X = m a1 X,  alpha_Y = m a2 Y,       (a1 = 1 - eps, a2 = 1 + eps)
#     f_XX = a1 m - 2 gamma a1^2 X^2 / u^2,  f_YY = a2 m - 2 gamma a2^2 Y^2 / u^2,
#     f_XY = -2 gamma a1 a2 X Y / u^2.
#
# Parameter array ``nfw``, shape (K, NFW_N_PARAMS): ``x_centre, y_centre, theta, eps,
# r_s, b`` (arcsec; theta in radians, counter-clockwise from the x axis to the major
# axis; 0 <= eps < 1, r_s > 0). At the exact centre of a component the deflection is
# 0 and the Hessian is not finite (the NFW convergence diverges logarithmically).

NFW_X, NFW_Y, NFW_THETA, NFW_EPS, NFW_RS, NFW_B = range(6)
NFW_N_PARAMS = 6
_NFW_SERIES = 0.1
_NFW_SERIES_TERMS = 20


@njit(**JIT_OPTIONS)
def nfw_radial(x):
    """``(g(x), f(x))`` of the circular NFW for ``x > 0`` (see above)."""
    s = (1.0 - x) * (1.0 + x)
    if abs(s) < _NFW_SERIES:
        f = 0.0
        for k in range(_NFW_SERIES_TERMS, 0, -1):
            f = f * s + 1.0 / (2.0 * k + 1.0)
        return np.log(0.5 * x) + 1.0 + s * f, f
    if s > 0.0:  # x < 1
        v = np.sqrt(s)
        x2 = x * x
        g = (x2 * np.log(2.0 / x) / (1.0 + v) + np.log1p(-x2 / (2.0 * (1.0 + v)))) / v
        h = np.log((1.0 + v) / x) / v
        return g, (h - 1.0) / s
    w = np.sqrt(-s)  # x > 1
    h = np.arctan(w) / w
    return np.log(0.5 * x) + h, (h - 1.0) / s


@njit(inline="always", **JIT_OPTIONS)
def _nfw_local(X, Y, a1, a2, rs, b, mode):
    """Deflection and Hessian of one NFW component in its own frame."""
    u2 = a1 * X * X + a2 * Y * Y
    if u2 == 0.0:
        inf = np.inf
        return 0.0, 0.0, inf, 0.0, inf
    u = np.sqrt(u2)
    x = u / rs
    g, f = nfw_radial(x)
    m = b * g / (x * x * rs)
    fx = m * a1 * X
    fy = m * a2 * Y
    if mode == MODE_ALPHA:
        return fx, fy, 0.0, 0.0, 0.0
    gam2 = 2.0 * (m - 0.5 * b / rs * f) / u2
    fxx = a1 * m - gam2 * a1 * a1 * X * X
    fyy = a2 * m - gam2 * a2 * a2 * Y * Y
    fxy = -gam2 * a1 * a2 * X * Y
    return fx, fy, fxx, fxy, fyy


@njit(**JIT_OPTIONS)
def _nfw_sum(x, y, nfw, mode, out):
    """Sum the NFW components; ``out`` as in :func:`_sum_components`."""
    n = x.shape[0]
    h0 = 2 if mode == MODE_BOTH else 0
    for i in range(n):
        ax = 0.0
        ay = 0.0
        hxx = 0.0
        hxy = 0.0
        hyy = 0.0
        for j in range(nfw.shape[0]):
            cs = np.cos(nfw[j, NFW_THETA])
            sn = np.sin(nfw[j, NFW_THETA])
            dx = x[i] - nfw[j, NFW_X]
            dy = y[i] - nfw[j, NFW_Y]
            X = dx * cs + dy * sn
            Y = dy * cs - dx * sn
            eps = nfw[j, NFW_EPS]
            fx, fy, fxx, fxy, fyy = _nfw_local(X, Y, 1.0 - eps, 1.0 + eps, nfw[j, NFW_RS],
                                               nfw[j, NFW_B], mode)
            ax += fx * cs - fy * sn
            ay += fx * sn + fy * cs
            if mode != MODE_ALPHA:
                c2 = cs * cs
                s2 = sn * sn
                cssn = cs * sn
                hxx += c2 * fxx - 2.0 * cssn * fxy + s2 * fyy
                hxy += cssn * (fxx - fyy) + (c2 - s2) * fxy
                hyy += s2 * fxx + 2.0 * cssn * fxy + c2 * fyy
        if mode != MODE_HESSIAN:
            out[i, 0] = ax
            out[i, 1] = ay
        if mode != MODE_ALPHA:
            out[i, h0] = hxx
            out[i, h0 + 1] = hxy
            out[i, h0 + 2] = hyy


@njit(**JIT_OPTIONS)
def nfw_deflection(x, y, nfw):
    """Deflection ``(alpha_x, alpha_y)`` of the NFW components, shape (N, 2)."""
    out = np.empty((x.shape[0], 2))
    _nfw_sum(x, y, nfw, MODE_ALPHA, out)
    return out


@njit(**JIT_OPTIONS)
def nfw_hessian(x, y, nfw):
    """Hessian ``(f_xx, f_xy, f_yy)`` of the NFW components, shape (N, 3)."""
    out = np.empty((x.shape[0], 3))
    _nfw_sum(x, y, nfw, MODE_HESSIAN, out)
    return out


@njit(**JIT_OPTIONS)
def nfw_deflection_hessian(x, y, nfw):
    """Deflection and Hessian of the NFW components, shape (N, 5)."""
    out = np.empty((x.shape[0], 5))
    _nfw_sum(x, y, nfw, MODE_BOTH, out)
    return out


@njit(**JIT_OPTIONS)
def nfw_convergence(x, y, nfw):
    """Convergence ``(f_xx + f_yy) / 2`` of the NFW components, shape (N,)."""
    out = nfw_hessian(x, y, nfw)
    return 0.5 * (out[:, 0] + out[:, 2])
