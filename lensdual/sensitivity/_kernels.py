"""Numba kernels of :mod:`lensdual.sensitivity` (private).

Plain float64 arithmetic, no astropy. Angles in arcsec.

Sub-halo profiles (``profile`` code, parameters ``p0, p1, p2``):

- ``PROFILE_TNFW`` (0): circular truncated NFW of Baltz, Marshall & Oguri
  (2009) exactly as lenstronomy's ``TNFW`` implements it, ``p0 = Rs``,
  ``p1 = rho0`` (from :func:`tnfw_rho0`), ``p2 = r_trunc``; the same floor
  ``R >= 0.001 Rs`` as lenstronomy.
- ``PROFILE_POINT`` (1): point mass, ``p0 = theta_E`` (p1, p2 unused).

The local lens equation of a sub-halo at image-plane offset ``d`` from a
macro image, in the sub-halo frame ``x = theta - theta0 - d``, is
``G(x) = A0 x - alpha(x) = -A0 d``; its Jacobian is ``A0 - H(x)``.
"""

import math

import numpy as np
from numba import njit

__all__ = []

from .._numba import JIT_OPTIONS  # noqa: F401  (the package-wide options)

PROFILE_TNFW = 0
PROFILE_POINT = 1
_S = 0.001  # lenstronomy's TNFW floor on R / Rs


def tnfw_rho0(Rs, alpha_Rs):
    """lenstronomy's ``alpha2rho0`` (the truncation is neglected there too)."""
    return alpha_Rs / (4.0 * Rs**2 * (1.0 + math.log(0.5)))


@njit(**JIT_OPTIONS)
def _nfw_F(x):
    x = max(x, _S)
    if x < 1.0:
        return (1.0 - x * x) ** -0.5 * math.atanh(math.sqrt(1.0 - x * x))
    if x > 1.0:
        return (x * x - 1.0) ** -0.5 * math.atan(math.sqrt(x * x - 1.0))
    return 1.0


@njit(**JIT_OPTIONS)
def _tnfw_L(x, tau):
    x = max(x, _S)
    return math.log(x / (tau + math.sqrt(tau * tau + x * x)))


@njit(**JIT_OPTIONS)
def _tnfw_g(x, tau):
    x = max(x, _S)
    t2 = tau * tau
    return t2 / (t2 + 1.0) ** 2 * (
        (t2 + 1.0 + 2.0 * (x * x - 1.0)) * _nfw_F(x)
        + tau * math.pi
        + (t2 - 1.0) * math.log(tau)
        + math.sqrt(t2 + x * x) * (-math.pi + _tnfw_L(x, tau) * (t2 - 1.0) / tau)
    )


@njit(**JIT_OPTIONS)
def _tnfw_Fk(X, tau):
    """Projected density shape (lenstronomy ``TNFW._F``)."""
    t2 = tau * tau
    X = max(X, _S)
    F = _nfw_F(X)
    a = t2 / (t2 + 1.0) ** 2
    if X == 1.0:
        b = (t2 + 1.0) / 3.0
    else:
        b = (t2 + 1.0) / (X * X - 1.0) * (1.0 - F)
    c = 2.0 * F
    d = -math.pi / math.sqrt(t2 + X * X)
    e = (t2 - 1.0) / (tau * math.sqrt(t2 + X * X)) * _tnfw_L(X, tau)
    return a * (b + c + d + e)


@njit(**JIT_OPTIONS)
def deflection_hessian(profile, p0, p1, p2, x, y):
    """Deflection and Hessian of one profile at (x, y) from its centre.

    Returns ``(ax, ay, fxx, fxy, fyy)``.
    """
    if profile == PROFILE_POINT:
        r2 = x * x + y * y
        if r2 == 0.0:
            return 0.0, 0.0, math.inf, 0.0, math.inf
        t2 = p0 * p0
        inv = t2 / r2
        inv2 = t2 / (r2 * r2)
        return inv * x, inv * y, inv2 * (y * y - x * x), -2.0 * inv2 * x * y, inv2 * (x * x - y * y)
    rs = p0
    rho0 = p1
    tau = p2 / rs
    r_true = math.sqrt(x * x + y * y)
    R = max(r_true, _S * rs)
    X = R / rs
    g = _tnfw_g(X, tau)
    a = 4.0 * rho0 * rs * g / (X * X)
    ax = a * x
    ay = a * y
    kappa = 2.0 * rho0 * rs * _tnfw_Fk(r_true / rs, tau)
    ag = 2.0 * rho0 * rs * (2.0 * g / (X * X) - _tnfw_Fk(X, tau))
    g1 = ag * (y * y - x * x) / (R * R)
    g2 = -ag * 2.0 * x * y / (R * R)
    return ax, ay, kappa + g1, g2, kappa - g1


@njit(**JIT_OPTIONS)
def deflection_hessian_array(profile, p0, p1, p2, x, y, out):
    """Vectorised :func:`deflection_hessian`; ``out`` (N, 5) receives ax, ay, fxx, fxy, fyy."""
    for i in range(x.shape[0]):
        r = deflection_hessian(profile, p0, p1, p2, x[i], y[i])
        for k in range(5):
            out[i, k] = r[k]


@njit(**JIT_OPTIONS)
def source_grid(a00, a01, a10, a11, profile, p0, p1, p2, half_width, n, gx, gy):
    """``G(x) = A0 x - alpha(x)`` on the (n+1)^2 nodes of the box [-h, h]^2."""
    step = 2.0 * half_width / n
    for i in range(n + 1):
        xi = -half_width + i * step
        for j in range(n + 1):
            yj = -half_width + j * step
            ax, ay, _, _, _ = deflection_hessian(profile, p0, p1, p2, xi, yj)
            gx[i, j] = a00 * xi + a01 * yj - ax
            gy[i, j] = a10 * xi + a11 * yj - ay


@njit(**JIT_OPTIONS)
def _newton(a00, a01, a10, a11, profile, p0, p1, p2, tx, ty, x, y, scale):
    """Polish a root of ``G(x) = t``; returns (x, y, residual, det)."""
    ax, ay, fxx, fxy, fyy = deflection_hessian(profile, p0, p1, p2, x, y)
    rx = a00 * x + a01 * y - ax - tx
    ry = a10 * x + a11 * y - ay - ty
    res = math.hypot(rx, ry)
    for _ in range(100):
        j00 = a00 - fxx
        j01 = a01 - fxy
        j10 = a10 - fxy
        j11 = a11 - fyy
        det = j00 * j11 - j01 * j10
        if det == 0.0 or not math.isfinite(det):
            break
        dx = (j11 * rx - j01 * ry) / det
        dy = (-j10 * rx + j00 * ry) / det
        lam = 1.0
        improved = False
        for _k in range(40):
            xn = x - lam * dx
            yn = y - lam * dy
            bx, by, gxx, gxy, gyy = deflection_hessian(profile, p0, p1, p2, xn, yn)
            sx = a00 * xn + a01 * yn - bx - tx
            sy = a10 * xn + a11 * yn - by - ty
            rn = math.hypot(sx, sy)
            if rn < res or rn == 0.0:
                improved = True
                break
            lam *= 0.5
        if not improved:
            break
        step = lam * math.hypot(dx, dy)
        x, y, rx, ry, res = xn, yn, sx, sy, rn
        fxx, fxy, fyy = gxx, gxy, gyy
        if res <= 1e-14 * scale or step <= 1e-15 * scale:
            break
    j00 = a00 - fxx
    j01 = a01 - fxy
    j10 = a10 - fxy
    j11 = a11 - fyy
    return x, y, res, j00 * j11 - j01 * j10


@njit(**JIT_OPTIONS)
def add_image(x, y, det, pos, mu, n_found, dedup):
    for k in range(n_found):
        if math.hypot(pos[k, 0] - x, pos[k, 1] - y) <= dedup:
            return n_found
    if n_found < pos.shape[0]:
        pos[n_found, 0] = x
        pos[n_found, 1] = y
        mu[n_found] = 1.0 / det
        return n_found + 1
    return n_found


@njit(**JIT_OPTIONS)
def in_triangle(ux, uy, vx, vy, wx, wy, tx, ty):
    """Barycentric weights (wv, ww) of t in triangle (u, v, w), or (-1, -1) outside."""
    e1x = vx - ux
    e1y = vy - uy
    e2x = wx - ux
    e2y = wy - uy
    den = e1x * e2y - e1y * e2x
    if den == 0.0:
        return -1.0, -1.0
    px = tx - ux
    py = ty - uy
    b1 = (px * e2y - py * e2x) / den
    b2 = (e1x * py - e1y * px) / den
    eps = 1e-12
    if b1 >= -eps and b2 >= -eps and b1 + b2 <= 1.0 + eps:
        return b1, b2
    return -1.0, -1.0


@njit(**JIT_OPTIONS)
def solve_offset(a00, a01, a10, a11, profile, p0, p1, p2, dx, dy, half_width, n, gx, gy,
                 pos, mu):
    """All images of the local lens equation for a sub-halo at offset (dx, dy).

    ``gx, gy`` from :func:`source_grid` (same box). Candidates: every grid
    triangle whose source-plane image contains the target ``t = -A0 d``
    (inverse ray shooting on a triangulated grid, which finds both images
    of a fold pair in separate triangles), the unperturbed macro image
    ``x = -d``, and the point-mass-like central image ``x ~ theta_E^2 t / |t|^2``;
    each polished by damped Newton and deduplicated. ``pos`` (K, 2)
    receives positions in the sub-halo frame, ``mu`` signed magnifications.
    Returns the number of images (at most K).
    """
    tx = -(a00 * dx + a01 * dy)
    ty = -(a10 * dx + a11 * dy)
    step = 2.0 * half_width / n
    scale = max(half_width, math.hypot(dx, dy))
    dedup = 1e-8 * scale
    accept = 1e-9 * scale
    n_found = 0
    # macro image start (may lie outside the box)
    xs, ys, res, det = _newton(a00, a01, a10, a11, profile, p0, p1, p2, tx, ty, -dx, -dy, scale)
    if res <= accept and det != 0.0:
        n_found = add_image(xs, ys, det, pos, mu, n_found, dedup)
    # central image start: deflection dominated, alpha(x) ~ A0 (x + d)
    t2 = tx * tx + ty * ty
    if t2 > 0.0:
        if profile == PROFILE_POINT:
            te2 = p0 * p0
        else:
            te2 = step * step
        xs, ys, res, det = _newton(a00, a01, a10, a11, profile, p0, p1, p2, tx, ty,
                                   -te2 * tx / t2, -te2 * ty / t2, scale)
        if res <= accept and det != 0.0:
            n_found = add_image(xs, ys, det, pos, mu, n_found, dedup)
    for i in range(n):
        for j in range(n):
            # quick reject: target outside the bounding box of the cell's corners
            c0x = gx[i, j]
            c1x = gx[i + 1, j]
            c2x = gx[i + 1, j + 1]
            c3x = gx[i, j + 1]
            if tx < min(min(c0x, c1x), min(c2x, c3x)) or tx > max(max(c0x, c1x), max(c2x, c3x)):
                continue
            c0y = gy[i, j]
            c1y = gy[i + 1, j]
            c2y = gy[i + 1, j + 1]
            c3y = gy[i, j + 1]
            if ty < min(min(c0y, c1y), min(c2y, c3y)) or ty > max(max(c0y, c1y), max(c2y, c3y)):
                continue
            x0 = -half_width + i * step
            y0 = -half_width + j * step
            for tri in range(2):
                if tri == 0:
                    b1, b2 = in_triangle(c0x, c0y, c1x, c1y, c2x, c2y, tx, ty)
                    sx = x0 + b1 * step + b2 * step
                    sy = y0 + b2 * step
                else:
                    b1, b2 = in_triangle(c0x, c0y, c2x, c2y, c3x, c3y, tx, ty)
                    sx = x0 + b1 * step
                    sy = y0 + b1 * step + b2 * step
                if b1 < 0.0:
                    continue
                xs, ys, res, det = _newton(a00, a01, a10, a11, profile, p0, p1, p2, tx, ty,
                                           sx, sy, scale)
                if res <= accept and det != 0.0:
                    n_found = add_image(xs, ys, det, pos, mu, n_found, dedup)
    return n_found


@njit(**JIT_OPTIONS)
def flux_excess_many(a00, a01, a10, a11, profile, p0, p1, p2, offsets, half_width, n, gx, gy,
                     max_images, excess, counts):
    """Flux excess ``sum |mu_i| * |det A0|`` and image counts for many offsets."""
    det0 = abs(a00 * a11 - a01 * a10)
    pos = np.empty((max_images, 2))
    mu = np.empty(max_images)
    for k in range(offsets.shape[0]):
        m = solve_offset(a00, a01, a10, a11, profile, p0, p1, p2, offsets[k, 0], offsets[k, 1],
                         half_width, n, gx, gy, pos, mu)
        s = 0.0
        for i in range(m):
            s += abs(mu[i])
        excess[k] = s * det0
        counts[k] = m
