"""Model-independent relative Jacobian and size magnification (paper Sect. 4)."""

import warnings

import numpy as np
from astropy import units as u
from astropy.table import QTable

from .._validation import (
    as_angle_scalar,
    as_int,
    as_positions,
    as_real,
    check_unique_rows,
)
from ..exceptions import EstimatorWarning
from . import _kernels

__all__ = ["METHODS", "relative_jacobian", "size_magnification"]

#: Estimators known to :func:`relative_jacobian`, with the smallest number of
#: pairs each one needs.
METHODS = {"2v": 3, "quad": 3, "quad2": 3}

_METHOD_CODES = {
    "2v": _kernels.METHOD_2V,
    "quad": _kernels.METHOD_QUAD,
    "quad2": _kernels.METHOD_QUAD2,
}

# Largest condition estimate accepted for the (column-equilibrated)
# least-squares design of the Quad estimators.
_COND_MAX = 1e10

# Bootstrap realisations are generated and processed in chunks of at most
# this many (realisation x pair) entries, to bound memory.
_CHUNK_ENTRIES = 2**20


def _check_method(method):
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    return method


def _prepare(theta1, theta2, method, weight_power, min_angle):
    """Validate the common inputs; return plain arrays and kernel parameters."""
    method = _check_method(method)
    t1 = as_positions(theta1, "theta1")
    t2 = as_positions(theta2, "theta2")
    if t1.shape[0] != t2.shape[0]:
        raise ValueError(
            "theta1 and theta2 must hold the same number of pairs, got "
            f"{t1.shape[0]} and {t2.shape[0]}"
        )
    n_min = METHODS[method]
    if t1.shape[0] < n_min:
        raise ValueError(
            f"method {method!r} needs at least {n_min} pairs, got {t1.shape[0]}"
        )
    check_unique_rows(t1, "theta1")
    check_unique_rows(t2, "theta2")
    wp = as_real(weight_power, "weight_power", minimum=0.0)
    if not isinstance(min_angle, u.Quantity) or min_angle.unit.physical_type != "angle":
        raise TypeError(f"min_angle must be an angle Quantity, got {min_angle!r}")
    ang = float(min_angle.to_value(u.deg))
    if not 0.0 <= ang < 90.0:
        raise ValueError(f"min_angle must be in [0, 90) deg, got {min_angle}")
    min_sin = np.sin(np.deg2rad(ang))
    return t1, t2, _METHOD_CODES[method], wp, min_sin


def _jacobians(t1, t2, code, wp, min_sin):
    n = t1.shape[0]
    jac = np.empty((n, 2, 2))
    status = np.empty(n, dtype=np.int64)
    _kernels.relative_jacobians(t1, t2, code, wp, min_sin, _COND_MAX, jac, status)
    return jac, status


def _warn_status(status, method):
    no_tri = np.flatnonzero(status == _kernels.STATUS_NO_TRIANGLE)
    ill = np.flatnonzero(status == _kernels.STATUS_ILL_CONDITIONED)
    if no_tri.size:
        warnings.warn(
            f"2v Jacobian: no well-conditioned triangle for pair(s) {no_tri.tolist()} "
            "(all neighbour baselines nearly collinear); their Jacobian is NaN",
            EstimatorWarning,
            stacklevel=3,
        )
    fallback = np.flatnonzero(status == _kernels.STATUS_FALLBACK)
    if fallback.size:
        warnings.warn(
            f"quad2 Jacobian: too few or degenerate baselines for the second-order fit of "
            f"pair(s) {fallback.tolist()} (it needs at least 6 pairs); the first-order quad "
            "Jacobian is used there",
            EstimatorWarning,
            stacklevel=3,
        )
    if ill.size:
        warnings.warn(
            f"{method} Jacobian: ill-conditioned least squares for pair(s) {ill.tolist()} "
            "(baselines nearly collinear); their Jacobian is NaN",
            EstimatorWarning,
            stacklevel=3,
        )


def relative_jacobian(theta1, theta2, method="quad", *, weight_power=2, min_angle=5 * u.deg):
    r"""Relative Jacobian :math:`J_a = \partial\theta^{(L1)}/\partial\theta^{(L2)}` per pair.

    The baselines :math:`D_{ab} = \theta_b - \theta_a` of every pair ``a``
    obey :math:`D^{(L1)}_{ab} \approx J_a D^{(L2)}_{ab}` to first order
    (paper Sect. 4.1). ``mu_size = |det J|``; a fold pair has ``det J < 0``.

    Parameters
    ----------
    theta1, theta2 : `~astropy.units.Quantity`, shape (N, 2)
        Positions of the N point sources on arc L1 and, in the same order,
        of their counter-images on arc L2, in one common tangent-plane frame.
    method : {"quad", "2v", "quad2"}
        ``"quad"``: the paper's Quad (QW) Jacobian, a least-squares fit to all
        N-1 baselines of each pair with weights ``1/|D2|**weight_power``.
        ``"2v"``: the paper's 2v Jacobian, the exact solution on the triangle
        formed with the two nearest neighbours in L2; when these are closer
        to collinear than ``min_angle``, the neighbourhood is enlarged one
        neighbour at a time (by distance in L2) until a pair of neighbours
        closes a triangle whose two baselines are at least ``min_angle``
        apart. ``"quad2"``: as ``"quad"``, but the fit includes the
        second-order terms of the Taylor expansion of the image-to-image map
        (three second derivatives per component); this removes the bias the
        first-order fit picks up from the curvature of the map on long
        baselines. With fewer than 6 pairs, or degenerate baselines, it
        falls back to ``"quad"`` for the pairs concerned (with a warning).
    weight_power : float, optional
        Power of the baseline weights of the Quad estimators (default 2,
        as in the paper).
    min_angle : `~astropy.units.Quantity`, optional
        Smallest angle between the two baselines of a 2v triangle (default
        5 deg).

    Returns
    -------
    jacobian : `~numpy.ndarray`, shape (N, 2, 2)
        ``J[a]`` maps L2 baselines onto L1 baselines. NaN (with an
        `~lensdual.exceptions.EstimatorWarning`) where no well-conditioned
        estimate exists.

    Raises
    ------
    TypeError
        Positions without angular units.
    ValueError
        Wrong shapes, unequal numbers of pairs, too few pairs, non-finite or
        duplicate positions, an unknown method.
    """
    t1, t2, code, wp, min_sin = _prepare(theta1, theta2, method, weight_power, min_angle)
    jac, status = _jacobians(t1, t2, code, wp, min_sin)
    _warn_status(status, method)
    return jac


def _as_sigma(sigma_pos, n):
    """Return per-arc, per-pair positional sigmas as a (2, N) array in arcsec."""
    if not isinstance(sigma_pos, u.Quantity) or sigma_pos.unit.physical_type != "angle":
        raise TypeError(
            "sigma_pos must be a Quantity with angular units (e.g. 0.06 * u.arcsec), "
            f"got {sigma_pos!r}"
        )
    if sigma_pos.isscalar:
        sig = np.full((2, n), as_angle_scalar(sigma_pos, "sigma_pos"))
    else:
        sig = np.asarray(sigma_pos.to_value(u.arcsec), dtype=np.float64)
        if sig.shape == (n,):
            sig = np.broadcast_to(sig, (2, n))
        elif sig.shape != (2, n):
            raise ValueError(
                f"sigma_pos must be a scalar, shape (N,) or shape (2, N) with N = {n}, "
                f"got shape {sig.shape}"
            )
        if not np.isfinite(sig).all() or (sig < 0).any():
            raise ValueError("sigma_pos must be finite and >= 0")
    return np.ascontiguousarray(sig)


def _bootstrap_determinants(t1, t2, code, wp, min_sin, sigma, n_bootstrap, rng):
    """Signed det J for each bootstrap realisation, shape (n_bootstrap, N)."""
    n = t1.shape[0]
    dets = np.empty((n_bootstrap, n))
    chunk = max(1, _CHUNK_ENTRIES // n)
    buf1 = np.empty((min(chunk, n_bootstrap), n, 2))
    buf2 = np.empty_like(buf1)
    for start in range(0, n_bootstrap, chunk):
        stop = min(start + chunk, n_bootstrap)
        noise1, noise2 = buf1[: stop - start], buf2[: stop - start]
        # same stream as rng.standard_normal(shape), without temporaries
        rng.standard_normal(out=noise1)
        noise1 *= sigma[0][None, :, None]
        rng.standard_normal(out=noise2)
        noise2 *= sigma[1][None, :, None]
        _kernels.bootstrap_determinants(
            t1, t2, noise1, noise2, code, wp, min_sin, _COND_MAX, dets[start:stop]
        )
    return dets


def _nan_percentiles(values, n_valid, qs):
    """Percentiles along axis 0 ignoring NaN (numpy's "linear" method).

    Equivalent to ``np.nanpercentile(values, qs, axis=0)`` (NaN where a column
    has no finite value), from one sort instead of a loop over columns.
    """
    ordered = np.sort(values, axis=0)  # NaN sort to the end
    cols = np.arange(values.shape[1])
    out = np.full((len(qs), values.shape[1]), np.nan)
    ok = n_valid > 0
    for i, q in enumerate(qs):
        pos = q / 100.0 * (n_valid[ok] - 1)
        lo = np.floor(pos).astype(int)
        hi = np.minimum(lo + 1, n_valid[ok] - 1)
        low = ordered[lo, cols[ok]]
        out[i, ok] = low + (ordered[hi, cols[ok]] - low) * (pos - lo)
    return out


def size_magnification(
    theta1,
    theta2,
    method="quad",
    *,
    sigma_pos=0.06 * u.arcsec,
    n_bootstrap=1000,
    seed=None,
    weight_power=2,
    min_angle=5 * u.deg,
):
    """Size magnification ``mu_size = |det J|`` per pair, with bootstrap errors.

    Parameters
    ----------
    theta1, theta2 : `~astropy.units.Quantity`, shape (N, 2)
        Positions on arcs L1 and L2 (pair ``a`` is row ``a`` of both).
    method : {"quad", "2v", "quad2"}
        Estimator, see :func:`relative_jacobian`.
    sigma_pos : `~astropy.units.Quantity`, optional
        Gaussian positional uncertainty per coordinate (default 0.06 arcsec,
        the paper's conservative JWST value). A scalar applies to every
        position; shape (N,) gives one value per pair for both arcs; shape
        (2, N) gives arc L1 (row 0) and arc L2 (row 1) separately.
    n_bootstrap : int, optional
        Number of bootstrap realisations (default 1000). In each, every
        position of both arcs is displaced by Gaussian noise of width
        ``sigma_pos`` and the estimator is re-run on all pairs.
    seed : int, `numpy.random.Generator` or None, optional
        Seed of the bootstrap noise; equal seeds give equal results.
    weight_power, min_angle
        See :func:`relative_jacobian`.

    Returns
    -------
    table : `~astropy.table.QTable`
        One row per pair, in input order, with columns

        - ``mu_size``: ``|det J|`` on the measured positions;
        - ``mu_size_err``: half the 16-84 % width of the bootstrap
          distribution of ``|det J|``;
        - ``mu_size_p16``, ``mu_size_p50``, ``mu_size_p84``: the bootstrap
          percentiles;
        - ``n_bootstrap_valid``: realisations with a finite estimate (the
          percentiles ignore the others);
        - ``parity``: sign of ``det J`` (-1 for a fold pair, 0 when undefined);
        - ``jacobian``: the (2, 2) relative Jacobian.

        ``meta`` records the method and the bootstrap settings.
    """
    t1, t2, code, wp, min_sin = _prepare(theta1, theta2, method, weight_power, min_angle)
    n = t1.shape[0]
    sigma = _as_sigma(sigma_pos, n)
    n_bootstrap = as_int(n_bootstrap, "n_bootstrap", minimum=1)
    rng = np.random.default_rng(seed)

    jac, status = _jacobians(t1, t2, code, wp, min_sin)
    _warn_status(status, method)
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]

    boot = np.abs(_bootstrap_determinants(t1, t2, code, wp, min_sin, sigma, n_bootstrap, rng))
    n_valid = np.isfinite(boot).sum(axis=0)
    pct = _nan_percentiles(boot, n_valid, (16.0, 50.0, 84.0))
    # pairs already NaN on the measured positions were warned about above
    partial = np.isfinite(det) & (n_valid < n_bootstrap)
    if partial.any():
        worst = int(np.argmin(np.where(partial, n_valid, n_bootstrap)))
        warnings.warn(
            f"{method} Jacobian undefined in some bootstrap realisations of pair(s) "
            f"{np.flatnonzero(partial).tolist()} (worst: pair {worst}, "
            f"{n_bootstrap - n_valid[worst]} of {n_bootstrap}); percentiles use the "
            "finite ones (see column n_bootstrap_valid)",
            EstimatorWarning,
            stacklevel=2,
        )

    table = QTable()
    table["mu_size"] = np.abs(det)
    table["mu_size_err"] = 0.5 * (pct[2] - pct[0])
    table["mu_size_p16"] = pct[0]
    table["mu_size_p50"] = pct[1]
    table["mu_size_p84"] = pct[2]
    table["n_bootstrap_valid"] = n_valid
    table["parity"] = np.where(np.isfinite(det), np.sign(det), 0).astype(int)
    table["jacobian"] = jac
    table.meta["method"] = method
    table.meta["n_bootstrap"] = n_bootstrap
    table.meta["sigma_pos"] = (
        sigma_pos if sigma_pos.isscalar else "per-pair (see sigma_pos argument)"
    )
    if method != "2v":
        table.meta["weight_power"] = wp
    else:
        table.meta["min_angle"] = min_angle
    return table
