"""The smooth map L2 -> L1 that the null calibration takes as the truth.

A polyharmonic smoothing spline (kernel ``-r^5`` with a quadratic polynomial
part, scipy's ``"quintic"`` RBF) of the L1 positions on the L2 positions,
weighted by the pairs' position errors, with its smoothing chosen by the data:
the one that minimises the unbiased risk estimate (UBRE, Mallows' C_p; Craven &
Wahba 1979, Wahba 1990 Sect. 4.7) of the fitted positions, which needs no
threshold because the position errors are known. A map that the constellation
samples finely gets the small smoothing its curvature needs; a nearly
quadratic one, or one sampled by few pairs, is smoothed towards its weighted
quadratic fit. The kernel's fourth derivatives are continuous, so the spline
is as smooth at the pairs as the estimator's local cubic fits assume (the
thin-plate kernel ``r^2 ln r`` is kept for comparison: its curvature is
log-singular at every pair).

In whitened units (each pair's residual divided by its error) the fit is an
unweighted spline with kernel ``K~ = W^1/2 K W^1/2`` under the constraint
``P~^T c~ = 0`` (``P~ = W^1/2 P``, ``P`` the polynomial columns). With ``Q2``
the orthogonal complement of ``P~`` and ``Q2^T K~ Q2 = V diag(e) V^T``, the
residual of each coordinate is ``lambda Q2 V (e + lambda)^-1 V^T Q2^T y~`` and
the trace of the hat matrix ``n - sum lambda / (e + lambda)``, so every
smoothing costs O(n).
"""

from typing import NamedTuple

import numpy as np
from scipy.optimize import minimize_scalar

__all__ = ["NullMap", "spline_map"]

# The smoothing is searched over this many decades around the kernel's
# eigenvalues, from interpolation to the affine fit.
_DECADES_BELOW = 8.0
_DECADES_ABOVE = 4.0
_GRID = 121


class NullMap(NamedTuple):
    """The null's map at the L2 positions.

    Parameters
    ----------
    mapped : ndarray (N, 2)
        The map's L1 positions of the pairs, arcsec.
    jacobian : ndarray (N, 2, 2)
        Its Jacobian ``d theta1 / d theta2`` there.
    chi2_dof : float
        Weighted residual chi-square per residual degree of freedom
        (``2 (N - dof)``).
    dof : float
        The map's effective degrees of freedom per coordinate (the trace of
        its hat matrix: the polynomial part's 6 (3 for the thin plate) for
        the weighted polynomial fit, N for interpolation).
    description : str
        What the map is, for messages.
    smoothing : float
        The chosen smoothing ``lambda``: the spline minimises
        ``sum_i w_i |theta1_i - f(u_i)|^2 + lambda c^T K c`` with ``u`` the L2
        positions centred and divided by their largest distance from the centre,
        and ``w_i`` the pairs' inverse variances.
    weights : ndarray (N,)
        Those ``w_i``, arcsec^-2.
    """

    mapped: np.ndarray
    jacobian: np.ndarray
    chi2_dof: float
    dof: float
    description: str
    smoothing: float
    weights: np.ndarray


def _kernel(u, kind):
    """The kernel between the rows of ``u`` and its gradient in the first argument:
    ``r^2 ln r`` (thin plate) or ``-r^5`` (quintic polyharmonic)."""
    d = u[:, None, :] - u[None, :, :]
    r2 = (d**2).sum(axis=-1)
    if kind == "quintic":
        r = np.sqrt(r2)
        return -(r2**2) * r, d * (-5.0 * r2 * r)[..., None]
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(r2 > 0, 0.5 * r2 * np.log(r2), 0.0)
        g = np.where(r2 > 0, np.log(r2) + 1.0, 0.0)  # grad of r^2 ln r: (u - u_j)(2 ln r + 1)
    return k, d * g[..., None]


def _poly(u, degree):
    """The polynomial part's columns at ``u`` and their x and y derivatives."""
    x, y = u[:, 0], u[:, 1]
    one, zero = np.ones_like(x), np.zeros_like(x)
    cols, dx, dy = [one, x, y], [zero, one, zero], [zero, zero, one]
    if degree >= 2:
        cols += [x * x, x * y, y * y]
        dx += [2 * x, y, zero]
        dy += [zero, x, 2 * y]
    return np.column_stack(cols), np.column_stack(dx), np.column_stack(dy)


#: The kernel: ``"quintic"`` (the null's) or ``"tps"`` (thin plate, for the
#: benchmark that compares them, benchmarks/null_map_calibration.py).
KERNEL = "quintic"
_DEGREE = {"tps": 1, "quintic": 2}


def _affine_weights(t1, t2, sigma):
    """Inverse variances of the L1 residuals of the pairs: ``sigma1^2`` plus
    ``sigma2^2`` through the affine fit's ``|J|_F^2 / 2``."""
    p = np.column_stack([np.ones(len(t2)), t2])
    w0 = 1.0 / (sigma[0] ** 2 + sigma[1] ** 2)
    sw = np.sqrt(w0)[:, None]
    coef = np.linalg.lstsq(p * sw, t1 * sw, rcond=None)[0]
    jnorm2 = float((coef[1:] ** 2).sum())
    return 1.0 / (sigma[0] ** 2 + sigma[1] ** 2 * 0.5 * jnorm2)


def _ubre(log_lam, e, z2, n):
    """The unbiased risk estimate of both coordinates (up to a constant)."""
    lam = np.exp(log_lam)
    shrink = lam / (e + lam)
    rss = float((shrink**2 * z2).sum())
    trace = n - float(shrink.sum())
    return rss + 4.0 * trace


def _gml(log_lam, e, z2, n):
    """Minus the log marginal likelihood of both coordinates (up to a constant)."""
    lam = np.exp(log_lam)
    var = 1.0 + e / lam
    return float(0.5 * (z2 / var).sum() + np.log(var).sum())


_CRITERIA = {"ubre": _ubre, "gml": _gml}
#: The smoothing criterion: ``"ubre"`` (the null's) or ``"gml"`` (the marginal
#: likelihood, for the benchmark that compares them).
CRITERION = "ubre"


def spline_map(t1, t2, sigma):
    """The null's smooth map L2 -> L1 fitted to the pairs.

    Parameters
    ----------
    t1, t2 : ndarray (N, 2)
        The pairs' positions on arcs L1 and L2, arcsec.
    sigma : ndarray (2, N)
        Their position errors per coordinate on L1 and L2, arcsec (> 0).

    Returns
    -------
    NullMap
    """
    n = t2.shape[0]
    centre = t2.mean(axis=0)
    scale = float(np.max(np.hypot(*(t2 - centre).T)))
    u = (t2 - centre) / scale
    w = _affine_weights(t1, t2, sigma)
    sw = np.sqrt(w)
    k, grad = _kernel(u, KERNEL)
    poly, poly_x, poly_y = _poly(u, _DEGREE[KERNEL])
    kt = sw[:, None] * k * sw[None, :]
    pt = sw[:, None] * poly
    # the polynomial part's column space and its complement (rank-revealing: pairs on
    # a line or a conic leave some polynomial columns dependent)
    q, sv, _ = np.linalg.svd(pt, full_matrices=True)
    rank = int(np.count_nonzero(sv > sv[0] * 1e-10))
    q2 = q[:, rank:]
    e, v = np.linalg.eigh(q2.T @ kt @ q2)
    e = np.clip(e, 0.0, None)
    yt = sw[:, None] * t1
    z = v.T @ (q2.T @ yt)  # (n - rank, 2)
    z2 = (z**2).sum(axis=1)
    top = max(float(e.max()), np.finfo(float).tiny)
    grid = np.log(top) + np.log(10.0) * np.linspace(-_DECADES_BELOW, _DECADES_ABOVE, _GRID)
    crit = _CRITERIA[CRITERION]
    values = [crit(g, e, z2, n) for g in grid]
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, _GRID - 1)]
    log_lam = (minimize_scalar(crit, bounds=(lo, hi), args=(e, z2, n), method="bounded").x
               if hi > lo else grid[i])
    lam = float(np.exp(log_lam))
    shrink = lam / (e + lam)
    gamma = v @ (z / (e + lam)[:, None])
    ct = q2 @ gamma
    fitted_t = kt @ ct
    dcoef = np.linalg.lstsq(pt, yt - fitted_t, rcond=None)[0]  # the polynomial part
    c = sw[:, None] * ct
    mapped = k @ c + poly @ dcoef
    jac = np.einsum("ijk,jc->ick", grad, c)
    jac += np.stack([poly_x @ dcoef, poly_y @ dcoef], axis=-1)
    jac = jac / scale
    resid_t = sw[:, None] * (t1 - mapped)
    chi = float((resid_t**2).sum())
    dof = n - float(shrink.sum())
    res_dof = 2.0 * (n - dof)
    chi2_dof = chi / res_dof if res_dof > 0 else np.nan
    what = "a thin-plate spline" if KERNEL == "tps" else f"a {KERNEL} spline"
    return NullMap(mapped, jac, chi2_dof, dof,
                   f"{what} with {dof:.1f} degrees of freedom per coordinate for {n} pairs",
                   lam, w)
