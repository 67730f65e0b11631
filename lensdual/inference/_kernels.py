"""Numba kernels of :mod:`lensdual.inference` (private): images of a point source
perturbed by many truncated-NFW sub-haloes in a locally linear macro lens.

Frame: the observed image at the origin, arcsec. With ``A`` the smooth
``d beta / d theta`` at the image, ``kbar`` the mean convergence of the
population (removed as a uniform sheet, so that only its fluctuation acts)
and haloes at ``h_k``, the local lens map is

    G(x) = (A + kbar I) x - sum_k alpha_k(x - h_k),

and the source sits at ``t = G(0)``, so that the origin is an image, as an
observed image is wherever it is observed. Its magnification is exact:
``1 / det(A + kbar I - sum_k H_k(-h_k))``. Other images appear only near a
halo whose Hessian can cancel the macro field; they are found by inverse
ray shooting on a triangulated grid around such a halo (the other haloes'
field linearised at the origin), each root polished by damped Newton. The
flux excess is ``sum_i |mu_i| * |det A|``.

A halo of another redshift plane acts, in the smooth lens's linearisation,
through ``P alpha(Q (x - h))`` (see :mod:`lensdual.inference._forward`):
every halo carries the ten numbers ``pq = (P, Q, |P| |Q|, 1 / s_min(Q))``
(row-major 2x2 blocks; the identity for the main plane), and its Hessian
``P H Q`` is no longer symmetric.
"""

import math

import numpy as np
from numba import njit

from .._numba import JIT_OPTIONS
from ..sensitivity._kernels import PROFILE_TNFW, deflection_hessian, in_triangle
from ..sensitivity._kernels import add_image as _add

__all__ = []

_FLOOR = 0.0011  # just outside lenstronomy's R >= 0.001 Rs floor, in Rs
_REFINE_CELL = 0.25  # a box's cell may be at most this fraction of the halo's Einstein radius
_MAX_REFINE = 3  # ... else up to this many boxes, each a quarter as wide, follow


@njit(**JIT_OPTIONS)
def _one(hx, hy, rs, rho0, rt, pq, k, x, y):
    """Deflection and Hessian ``(ax, ay, f00, f01, f10, f11)`` of halo ``k`` at (x, y)."""
    dx = x - hx[k]
    dy = y - hy[k]
    ux = pq[k, 4] * dx + pq[k, 5] * dy
    uy = pq[k, 6] * dx + pq[k, 7] * dy
    bx, by, gxx, gxy, gyy = deflection_hessian(PROFILE_TNFW, rs[k], rho0[k], rt[k], ux, uy)
    h00 = gxx * pq[k, 4] + gxy * pq[k, 6]
    h01 = gxx * pq[k, 5] + gxy * pq[k, 7]
    h10 = gxy * pq[k, 4] + gyy * pq[k, 6]
    h11 = gxy * pq[k, 5] + gyy * pq[k, 7]
    return (pq[k, 0] * bx + pq[k, 1] * by, pq[k, 2] * bx + pq[k, 3] * by,
            pq[k, 0] * h00 + pq[k, 1] * h10, pq[k, 0] * h01 + pq[k, 1] * h11,
            pq[k, 2] * h00 + pq[k, 3] * h10, pq[k, 2] * h01 + pq[k, 3] * h11)


@njit(**JIT_OPTIONS)
def _field(hx, hy, rs, rho0, rt, pq, lo, hi, x, y):
    """Sum of deflections and Hessians of haloes ``lo..hi-1`` at (x, y)."""
    ax = 0.0
    ay = 0.0
    f00 = 0.0
    f01 = 0.0
    f10 = 0.0
    f11 = 0.0
    for k in range(lo, hi):
        bx, by, g00, g01, g10, g11 = _one(hx, hy, rs, rho0, rt, pq, k, x, y)
        ax += bx
        ay += by
        f00 += g00
        f01 += g01
        f10 += g10
        f11 += g11
    return ax, ay, f00, f01, f10, f11


@njit(**JIT_OPTIONS)
def _residual(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq, lo, hi, x, y):
    ax, ay, f00, f01, f10, f11 = _field(hx, hy, rs, rho0, rt, pq, lo, hi, x, y)
    return (b00 * x + b01 * y - ax - tx, b10 * x + b11 * y - ay - ty,
            b00 - f00, b01 - f01, b10 - f10, b11 - f11)


@njit(**JIT_OPTIONS)
def _newton(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq, lo, hi, x, y, scale):
    """Damped Newton on ``G(x) = t``; returns (x, y, |G - t|, det of the Jacobian)."""
    rx, ry, j00, j01, j10, j11 = _residual(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt,
                                           pq, lo, hi, x, y)
    res = math.hypot(rx, ry)
    for _ in range(60):
        det = j00 * j11 - j01 * j10
        if det == 0.0 or not math.isfinite(det):
            break
        dx = (j11 * rx - j01 * ry) / det
        dy = (-j10 * rx + j00 * ry) / det
        lam = 1.0
        improved = False
        for _k in range(30):
            xn = x - lam * dx
            yn = y - lam * dy
            sx, sy, k00, k01, k10, k11 = _residual(b00, b01, b10, b11, tx, ty, hx, hy, rs,
                                                   rho0, rt, pq, lo, hi, xn, yn)
            rn = math.hypot(sx, sy)
            if rn < res or rn == 0.0:
                improved = True
                break
            lam *= 0.5
        if not improved:
            break
        step = lam * math.hypot(dx, dy)
        x, y, rx, ry, res = xn, yn, sx, sy, rn
        j00, j01, j10, j11 = k00, k01, k10, k11
        if res <= 1e-14 * scale or step <= 1e-15 * scale:
            break
    return x, y, res, j00 * j11 - j01 * j10


@njit(**JIT_OPTIONS)
def _is_identity(pq, k):
    return pq[k, 4] == 1.0 and pq[k, 5] == 0.0 and pq[k, 6] == 0.0 and pq[k, 7] == 1.0


@njit(**JIT_OPTIONS)
def _q_inverse(pq, k):
    det = pq[k, 4] * pq[k, 7] - pq[k, 5] * pq[k, 6]
    return pq[k, 7] / det, -pq[k, 5] / det, -pq[k, 6] / det, pq[k, 4] / det


@njit(**JIT_OPTIONS)
def _box_grid(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq, n_h, k, half, n, gx, gy):
    """``G - t`` on the (n+1)^2 nodes of the box of half-width ``half`` around halo ``k``,
    in the halo's own coordinates ``u = Q (x - h)`` (the image plane's for ``Q = I``)."""
    cx = hx[k]
    cy = hy[k]
    ident = _is_identity(pq, k)
    i00, i01, i10, i11 = _q_inverse(pq, k)
    # haloes near the box are summed exactly on the grid, the rest linearised at its centre
    near = 2.0 * half * pq[k, 9]
    lx, ly, l00, l01, l10, l11 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    for j in range(n_h):
        if math.hypot(hx[j] - cx, hy[j] - cy) > near:
            bx, by, g00, g01, g10, g11 = _one(hx, hy, rs, rho0, rt, pq, j, cx, cy)
            lx += bx
            ly += by
            l00 += g00
            l01 += g01
            l10 += g10
            l11 += g11
    step = 2.0 * half / n
    for i in range(n + 1):
        for jj in range(n + 1):
            if ident:
                xi = cx - half + i * step
                yj = cy - half + jj * step
            else:
                u = -half + i * step
                v = -half + jj * step
                xi = cx + i00 * u + i01 * v
                yj = cy + i10 * u + i11 * v
            ax = lx + l00 * (xi - cx) + l01 * (yj - cy)
            ay = ly + l10 * (xi - cx) + l11 * (yj - cy)
            for j in range(n_h):
                if math.hypot(hx[j] - cx, hy[j] - cy) <= near:
                    bx, by, _, _, _, _ = _one(hx, hy, rs, rho0, rt, pq, j, xi, yj)
                    ax += bx
                    ay += by
            gx[i, jj] = b00 * xi + b01 * yj - ax - tx
            gy[i, jj] = b10 * xi + b11 * yj - ay - ty


@njit(**JIT_OPTIONS)
def _box_images(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq, n_h, k, half, n, gx, gy,
                pos, mu, n_found, scale, dedup, accept):
    """Roots of ``G = t`` in the box of half-width ``half`` (halo coordinates) around
    halo ``k``."""
    _box_grid(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq, n_h, k, half, n, gx, gy)
    cx = hx[k]
    cy = hy[k]
    ident = _is_identity(pq, k)
    i00, i01, i10, i11 = _q_inverse(pq, k)
    step = 2.0 * half / n
    # the central image of the halo, close to its centre
    if ident:
        x_start = cx + 0.01 * step
        y_start = cy + 0.01 * step
    else:
        x_start = cx + 0.01 * step * (i00 + i01)
        y_start = cy + 0.01 * step * (i10 + i11)
    xs, ys, res, det = _newton(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq, 0, n_h,
                               x_start, y_start, scale)
    if res <= accept and det != 0.0:
        n_found = _add(xs, ys, det, pos, mu, n_found, dedup)
    for i in range(n):
        for jj in range(n):
            c0x = gx[i, jj]
            c1x = gx[i + 1, jj]
            c2x = gx[i + 1, jj + 1]
            c3x = gx[i, jj + 1]
            if min(min(c0x, c1x), min(c2x, c3x)) > 0.0 or max(max(c0x, c1x), max(c2x, c3x)) < 0.0:
                continue
            c0y = gy[i, jj]
            c1y = gy[i + 1, jj]
            c2y = gy[i + 1, jj + 1]
            c3y = gy[i, jj + 1]
            if min(min(c0y, c1y), min(c2y, c3y)) > 0.0 or max(max(c0y, c1y), max(c2y, c3y)) < 0.0:
                continue
            if ident:
                x0 = cx - half + i * step
                y0 = cy - half + jj * step
            else:
                x0 = -half + i * step
                y0 = -half + jj * step
            for tri in range(2):
                if tri == 0:
                    w1, w2 = in_triangle(c0x, c0y, c1x, c1y, c2x, c2y, 0.0, 0.0)
                    sx = x0 + w1 * step + w2 * step
                    sy = y0 + w2 * step
                else:
                    w1, w2 = in_triangle(c0x, c0y, c2x, c2y, c3x, c3y, 0.0, 0.0)
                    sx = x0 + w1 * step
                    sy = y0 + w1 * step + w2 * step
                if w1 < 0.0:
                    continue
                if not ident:
                    sx, sy = cx + i00 * sx + i01 * sy, cy + i10 * sx + i11 * sy
                xs, ys, res, det = _newton(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq,
                                           0, n_h, sx, sy, scale)
                if res <= accept and det != 0.0:
                    n_found = _add(xs, ys, det, pos, mu, n_found, dedup)
    return n_found


@njit(**JIT_OPTIONS)
def _s_min(b00, b01, b10, b11):
    """Smallest singular value of a 2x2 matrix."""
    p = b00 * b00 + b01 * b01 + b10 * b10 + b11 * b11
    q = abs(b00 * b11 - b01 * b10)
    return math.sqrt(max(0.5 * p - math.sqrt(max(0.25 * p * p - q * q, 0.0)), 0.0))


@njit(**JIT_OPTIONS)
def _norm_at(rs, rho0, rt, r):
    _, _, fxx, _, fyy = deflection_hessian(PROFILE_TNFW, rs, rho0, rt, r, 0.0)
    return max(abs(fxx), abs(fyy))


@njit(**JIT_OPTIONS)
def critical_radius(rs, rho0, rt, level):
    """Largest radius at which a halo's Hessian norm reaches ``level`` (0 if nowhere).

    The norm, ``max(mean convergence, |2 kappa - mean convergence|)``,
    falls with radius; bisection in log radius from lenstronomy's floor.
    """
    lo = _FLOOR * rs
    if _norm_at(rs, rho0, rt, lo) < level:
        return 0.0
    hi = 100.0 * max(rt, rs)
    if _norm_at(rs, rho0, rt, hi) >= level:
        return hi
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        if _norm_at(rs, rho0, rt, mid) >= level:
            lo = mid
        else:
            hi = mid
    return hi


@njit(**JIT_OPTIONS)
def _fold_partner(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq, n_h, j00, j01, j10,
                  j11, pos, mu, n_found, scale, dedup, accept):
    """Images near the origin along the Jacobian's nearly singular direction.

    An image next to a critical curve has its fold partner at a distance that
    can be below a grid cell; Newton is started on both sides of the origin
    along the right singular vector of the smallest singular value, at
    distances from ``0.3 scale`` down by factors of 3.
    """
    m00 = j00 * j00 + j10 * j10
    m01 = j00 * j01 + j10 * j11
    m11 = j01 * j01 + j11 * j11
    sv = _s_min(j00, j01, j10, j11)
    lam = sv * sv
    vx = m01
    vy = lam - m00
    if math.hypot(vx, vy) < 1e-300:
        vx = lam - m11
        vy = m01
    norm = math.hypot(vx, vy)
    if norm < 1e-300:
        vx, vy, norm = 1.0, 0.0, 1.0
    vx /= norm
    vy /= norm
    d = 0.3 * scale
    for _ in range(9):
        for sgn in (1.0, -1.0):
            xs, ys, res, det = _newton(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq,
                                       0, n_h, sgn * d * vx, sgn * d * vy, scale)
            if res <= accept and det != 0.0:
                n_found = _add(xs, ys, det, pos, mu, n_found, dedup)
        d /= 3.0
    return n_found


@njit(**JIT_OPTIONS)
def image_excess(b00, b01, b10, b11, det0, hx, hy, rs, rho0, rt, pq, te, hsup, n_h, n, gx, gy,
                 pos, mu):
    """Flux excess and image count of the image at the origin.

    ``b`` is the local ``d beta / d theta`` with the sheet and the Hessians
    (at the origin) of the haloes that cannot make images in it; haloes
    ``0..n_h-1`` are the others, summed in full; ``det0`` is the smooth
    ``|det A|``. Where their Hessian norms ``hsup`` sum to less than the
    smallest singular value of ``b``, the map is invertible everywhere and
    the origin is the only image. Otherwise a halo whose norm reaches half
    that value within ``r_c`` of its centre (:func:`critical_radius`) can
    have images near its critical curve, at about ``r_c``; it gets a grid
    box of half-width ``3 r_c`` when the origin lies inside it. For a halo
    of another plane ``hsup`` and ``te`` are its effective values, the
    level is divided by ``|P| |Q|``, and the box is in the halo's own
    coordinates ``u = Q (x - h)``.
    """
    ax, ay, f00, f01, f10, f11 = _field(hx, hy, rs, rho0, rt, pq, 0, n_h, 0.0, 0.0)
    tx = -ax
    ty = -ay
    det = (b00 - f00) * (b11 - f11) - (b01 - f01) * (b10 - f10)
    pos[0, 0] = 0.0
    pos[0, 1] = 0.0
    mu[0] = 1.0 / det
    n_found = 1
    s_min = _s_min(b00, b01, b10, b11)
    total = 0.0
    scale = 1e-3
    for k in range(n_h):
        total += hsup[k]
        scale = max(scale, te[k])
    if total >= s_min:
        dedup = 1e-7 * scale
        accept = 1e-10 * scale
        for k in range(n_h):
            if te[k] <= 0.0 or hsup[k] < 0.5 * s_min:
                continue
            half = 3.0 * critical_radius(rs[k], rho0[k], rt[k], 0.5 * s_min / pq[k, 8])
            # the origin in the halo's coordinates, u = Q (0 - h)
            ux = pq[k, 4] * hx[k] + pq[k, 5] * hy[k]
            uy = pq[k, 6] * hx[k] + pq[k, 7] * hy[k]
            if half <= 0.0 or abs(ux) > half or abs(uy) > half:
                continue
            n_found = _box_images(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq, n_h, k,
                                  half, n, gx, gy, pos, mu, n_found, scale, dedup, accept)
            # a box much wider than the halo's Einstein radius (a nearly singular macro
            # field) has cells that can hold several images: finer boxes, a quarter as wide
            te_own = te[k] / (math.sqrt(pq[k, 8]) * pq[k, 9])
            for _ in range(_MAX_REFINE):
                if 2.0 * half / n <= _REFINE_CELL * te_own:
                    break
                half *= 0.25
                n_found = _box_images(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq,
                                      n_h, k, half, n, gx, gy, pos, mu, n_found, scale, dedup,
                                      accept)
        j00 = b00 - f00
        j01 = b01 - f01
        j10 = b10 - f10
        j11 = b11 - f11
        if _s_min(j00, j01, j10, j11) < 0.5 * s_min:
            n_found = _fold_partner(b00, b01, b10, b11, tx, ty, hx, hy, rs, rho0, rt, pq, n_h,
                                    j00, j01, j10, j11, pos, mu, n_found, scale, dedup, accept)
    s = 0.0
    for i in range(n_found):
        s += abs(mu[i])
    return s * det0, n_found


@njit(**JIT_OPTIONS)
def excess_grid(a00, a01, a10, a11, kbar_max, hx, hy, rs, rho0, rt, te, hsup, tag, starts,
                frac, lam_min, strong, box_factor, box_cap, n, max_images, los, los_starts,
                los_lin, excess, counts):
    """Flux excesses of one image on an abundance grid, for many realisations.

    Realisation ``r`` holds haloes ``starts[r]..starts[r+1]-1``, sorted by
    their ``tag`` (uniform in [0, 1)); at abundance ``frac[j]`` (a fraction
    of the largest) it keeps the haloes with ``tag < frac[j]`` and the sheet
    ``-kbar_max * frac[j]``. A halo whose Hessian norm is below ``strong``
    times the smallest singular value of ``A``, or whose box cannot reach
    the origin, acts through its Hessian at the origin (summed in tag
    order); the others are solved in full. Line-of-sight haloes do not
    depend on the abundance: realisation ``r`` adds the strong ones
    ``los[los_starts[r]:los_starts[r+1]]`` (columns x, y, rs, rho0, rt, te,
    hsup, then the ten of ``pq``) at every abundance, and the row-major
    matrix ``los_lin[r]`` (their weak haloes' Hessians at the origin less
    their sheets) is subtracted from ``A``. ``excess`` and ``counts`` are
    (R, S).
    """
    gx = np.empty((n + 1, n + 1))
    gy = np.empty((n + 1, n + 1))
    pos = np.empty((max_images, 2))
    mu = np.empty(max_images)
    det0 = abs(a00 * a11 - a01 * a10)
    s_min = _s_min(a00, a01, a10, a11)
    n_los = 0
    for r in range(los_starts.shape[0] - 1):
        n_los = max(n_los, los_starts[r + 1] - los_starts[r])
    n_tot = hx.shape[0] + n_los
    sx = np.empty(n_tot)
    sy = np.empty(n_tot)
    srs = np.empty(n_tot)
    srho = np.empty(n_tot)
    srt = np.empty(n_tot)
    ste = np.empty(n_tot)
    ssup = np.empty(n_tot)
    spq = np.zeros((n_tot, 10))
    for r in range(starts.shape[0] - 1):
        lo = starts[r]
        hi = starts[r + 1]
        ns = 0
        for i in range(los_starts[r], los_starts[r + 1]):
            sx[ns] = los[i, 0]
            sy[ns] = los[i, 1]
            srs[ns] = los[i, 2]
            srho[ns] = los[i, 3]
            srt[ns] = los[i, 4]
            ste[ns] = los[i, 5]
            ssup[ns] = los[i, 6]
            for c in range(10):
                spq[ns, c] = los[i, 7 + c]
            ns += 1
        c00 = los_lin[r, 0]
        c01 = los_lin[r, 1]
        c10 = los_lin[r, 2]
        c11 = los_lin[r, 3]
        k = lo
        for j in range(frac.shape[0]):
            # haloes enter in tag order: strong ones are compacted, weak ones summed into c
            while k < hi and tag[k] < frac[j]:
                reach = min(box_factor * te[k] / math.sqrt(lam_min), box_cap * te[k])
                if hsup[k] >= strong * s_min and max(abs(hx[k]), abs(hy[k])) <= 3.0 * reach:
                    sx[ns] = hx[k]
                    sy[ns] = hy[k]
                    srs[ns] = rs[k]
                    srho[ns] = rho0[k]
                    srt[ns] = rt[k]
                    ste[ns] = te[k]
                    ssup[ns] = hsup[k]
                    for c in range(10):
                        spq[ns, c] = 0.0
                    spq[ns, 0] = 1.0
                    spq[ns, 3] = 1.0
                    spq[ns, 4] = 1.0
                    spq[ns, 7] = 1.0
                    spq[ns, 8] = 1.0
                    spq[ns, 9] = 1.0
                    ns += 1
                else:
                    _, _, fxx, fxy, fyy = deflection_hessian(PROFILE_TNFW, rs[k], rho0[k],
                                                             rt[k], -hx[k], -hy[k])
                    c00 += fxx
                    c01 += fxy
                    c10 += fxy
                    c11 += fyy
                k += 1
            kb = kbar_max * frac[j]
            e, c = image_excess(a00 + kb - c00, a01 - c01, a10 - c10, a11 + kb - c11, det0,
                                sx, sy, srs, srho, srt, spq, ste, ssup, ns, n, gx, gy, pos, mu)
            excess[r, j] = e
            counts[r, j] = c


@njit(**JIT_OPTIONS)
def los_split(hx, hy, rs, rho0, rt, te, hsup, pq, real, n_real, s_min, lam_min, strong,
              box_factor, box_cap, keep, lin):
    """Sort line-of-sight haloes into strong ones (``keep``) and the weak rest.

    Halo ``i`` belongs to realisation ``real[i]``; ``te`` and ``hsup`` are
    its effective Einstein radius and Hessian norm. The criterion is
    :func:`excess_grid`'s. Each weak halo's Hessian ``P H Q`` at the origin
    is added to ``lin[real[i]]`` (row-major, ``n_real`` rows).
    """
    for i in range(hx.shape[0]):
        reach = min(box_factor * te[i] / math.sqrt(lam_min), box_cap * te[i])
        if hsup[i] >= strong * s_min and max(abs(hx[i]), abs(hy[i])) <= 3.0 * reach:
            keep[i] = True
        else:
            keep[i] = False
            _, _, f00, f01, f10, f11 = _one(hx, hy, rs, rho0, rt, pq, i, 0.0, 0.0)
            r = real[i]
            lin[r, 0] += f00
            lin[r, 1] += f01
            lin[r, 2] += f10
            lin[r, 3] += f11


@njit(**JIT_OPTIONS)
def enclosed(rs, rho0, rt, radius, out):
    """``R alpha(R)`` of each halo: its projected mass within ``R`` over pi (arcsec^2).

    ``radius <= 0`` takes ``R`` far outside the truncation radius, where it
    is the squared point-mass Einstein radius of the total mass.
    """
    for k in range(rs.shape[0]):
        big = radius if radius > 0.0 else 1e4 * max(rt[k], rs[k])
        ax, _, _, _, _ = deflection_hessian(PROFILE_TNFW, rs[k], rho0[k], rt[k], big, 0.0)
        out[k] = max(ax * big, 0.0)


@njit(**JIT_OPTIONS)
def hessian_sup(rs, rho0, rt, out):
    """Largest Hessian norm of each halo: at lenstronomy's floor ``R = 0.001 Rs``,
    where its convergence and mean convergence peak."""
    for k in range(rs.shape[0]):
        out[k] = _norm_at(rs[k], rho0[k], rt[k], _FLOOR * rs[k])
