"""Model-independent relative Jacobian and size magnification (paper Sect. 4)."""

import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from astropy import units as u
from astropy.table import QTable
from scipy.spatial import cKDTree
from scipy.stats import chi2 as _chi2

from .._parallel import available_threads
from .._validation import (
    as_angle_scalar,
    as_int,
    as_positions,
    as_real,
    check_unique_rows,
)
from ..exceptions import EstimatorWarning
from . import _adaptive as _adaptive_kernels
from . import _kernels

__all__ = ["METHODS", "DEFAULT_METHOD", "DEFAULT_N_BOOTSTRAP", "DEFAULT_MAX_NEIGHBOURS",
           "ADAPTIVE_STATUS", "TESTABLE_STATUS", "relative_jacobian", "size_magnification",
           "estimate_sigma_pos"]

#: Estimators known to :func:`relative_jacobian`, with the smallest number of
#: pairs each one needs. ``"adaptive"`` (the default of
#: :func:`size_magnification`) needs 7: its smallest fit is a quadratic on
#: a pair and six neighbours.
METHODS = {"2v": 3, "quad": 3, "quad2": 3, "adaptive": 7}

#: The default estimator of :func:`size_magnification` and
#: :func:`~lensdual.duality.check_duality`.
DEFAULT_METHOD = "adaptive"

#: The default number of bootstrap realisations of the paper's estimators
#: (:func:`size_magnification`, :func:`~lensdual.duality.check_duality`,
#: ``lensdual run``).
DEFAULT_N_BOOTSTRAP = 1000

_METHOD_CODES = {
    "2v": _kernels.METHOD_2V,
    "quad": _kernels.METHOD_QUAD,
    "quad2": _kernels.METHOD_QUAD2,
    "adaptive": _adaptive_kernels.METHOD_ADAPTIVE,
}

#: Status of an adaptive estimate (column ``mu_size_status``).
ADAPTIVE_STATUS = {
    _adaptive_kernels.ADAPTIVE_OK: "ok",
    _adaptive_kernels.ADAPTIVE_MISFIT: "misfit",
    _adaptive_kernels.ADAPTIVE_FAILED: "failed",
    _adaptive_kernels.ADAPTIVE_UNTESTABLE: "untestable",
}

#: Statuses whose pairs :func:`~lensdual.duality.check_duality` tests.
TESTABLE_STATUS = ("ok", "misfit")

#: What the adaptive estimator's too-few-pairs error advises.
FEW_PAIRS_HINT = " (with fewer pairs use 'quad2', whose errors hold the position noise only)"

_COND_MAX = _kernels.COND_MAX

#: Default cap on the points each pair's estimate uses: the pair and its
#: ``DEFAULT_MAX_NEIGHBOURS - 1`` nearest neighbours in L2. Constellations of
#: up to this many pairs are estimated exactly as without a cap (every pair
#: sees every point); above it the estimators are local, and their cost grows
#: as N instead of N^2 (``"adaptive"``: N^3). See the "Scale" section of the
#: performance page for the measurements behind the value.
DEFAULT_MAX_NEIGHBOURS = 64

# The adaptive estimator runs its pairs in this many threads at most (the
# kernels release the GIL; the pairs are independent), from this many pairs on.
_MAX_THREADS = 8
_THREAD_MIN_PAIRS = 2000

# Bootstrap realisations are generated and processed in chunks of at most
# this many (realisation x pair) entries, to bound memory.
_CHUNK_ENTRIES = 2**20


def _check_method(method):
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    return method


def _max_neighbours(max_neighbours, method):
    """Validate ``max_neighbours`` (None: no cap)."""
    if max_neighbours is None:
        return None
    low = max(METHODS[method], 3)
    return as_int(max_neighbours, "max_neighbours", minimum=low)


def _neighbour_rows(t2, max_neighbours):
    """The neighbour rows of the kernels (see ``_kernels``) for a cap, in L2.

    Up to ``max_neighbours`` pairs (or without a cap): one shared row of
    every point, the uncapped estimators bit for bit. Above: each pair and
    its ``max_neighbours - 1`` nearest neighbours in L2 (k-d tree).
    """
    n = t2.shape[0]
    if max_neighbours is None or n <= max_neighbours:
        return _kernels.all_rows(n)
    _, rows = cKDTree(t2).query(t2, k=max_neighbours)
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    # the pair itself is its own nearest point (positions are unique); make sure
    own = np.arange(n)
    missing = ~(rows == own[:, None]).any(axis=1)
    rows[missing, -1] = own[missing]
    return rows


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
            + (FEW_PAIRS_HINT if method == "adaptive" else "")
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


def _jacobians(t1, t2, nbr, code, wp, min_sin):
    n = t1.shape[0]
    jac = np.empty((n, 2, 2))
    status = np.empty(n, dtype=np.int64)
    _kernels.relative_jacobians_knn(t1, t2, nbr, code, wp, min_sin, _COND_MAX, jac, status)
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


def relative_jacobian(theta1, theta2, method="quad", *, weight_power=2, min_angle=5 * u.deg,
                      sigma_pos=None, max_neighbours=DEFAULT_MAX_NEIGHBOURS):
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
        ``"adaptive"``: the locality-adaptive local-polynomial estimator
        (see :func:`size_magnification`); it needs ``sigma_pos``.
    weight_power : float, optional
        Power of the baseline weights of the Quad estimators (default 2,
        as in the paper).
    min_angle : `~astropy.units.Quantity`, optional
        Smallest angle between the two baselines of a 2v triangle (default
        5 deg).
    sigma_pos : `~astropy.units.Quantity`, optional
        Position errors, as in :func:`size_magnification`; required by
        ``"adaptive"`` (its fits are tested against them), ignored otherwise.
    max_neighbours : int or None, optional
        Largest number of points each pair's estimate uses: the pair and its
        ``max_neighbours - 1`` nearest neighbours in L2 (default
        `DEFAULT_MAX_NEIGHBOURS`, 64). With at most that many pairs every
        pair uses every point, as without a cap (the results are
        identical); with more, "all N-1 baselines" above reads "the
        baselines to the ``max_neighbours - 1`` nearest neighbours", and the
        cost grows as N instead of N^2. None: no cap.

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

    Examples
    --------
    Eight pairs related by an exactly linear map, ``theta1 = J theta2``:
    every pair recovers ``J``, whose negative determinant marks a fold pair.

    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.estimators import relative_jacobian
    >>> rng = np.random.default_rng(1)
    >>> theta2 = rng.uniform(-1, 1, (8, 2)) * u.arcsec
    >>> J = np.array([[1.5, 0.3], [0.1, -0.8]])
    >>> jac = relative_jacobian(theta2 @ J.T, theta2, method="quad")
    >>> jac.shape
    (8, 2, 2)
    >>> np.round(jac[0], 3)
    array([[ 1.5,  0.3],
           [ 0.1, -0.8]])
    >>> np.round(np.linalg.det(jac), 3).tolist()
    [-1.23, -1.23, -1.23, -1.23, -1.23, -1.23, -1.23, -1.23]
    """
    t1, t2, code, wp, min_sin = _prepare(theta1, theta2, method, weight_power, min_angle)
    cap = _max_neighbours(max_neighbours, method)
    if method == "adaptive":
        if sigma_pos is None:
            raise ValueError("method 'adaptive' needs sigma_pos (the position errors its "
                             "local fits are tested against)")
        sigma = as_sigma(sigma_pos, t1.shape[0], positive=True)
        jac, _, _, status, _, _ = _adaptive(t1, t2, sigma, wp, cap)
        _warn_adaptive(status)
        return jac
    jac, status = _jacobians(t1, t2, _neighbour_rows(t2, cap), code, wp, min_sin)
    _warn_status(status, method)
    return jac


def _chi2_critical(n, alpha=None):
    """Upper ``alpha`` quantiles of chi-square for 0..2n degrees of freedom."""
    alpha = _adaptive_kernels.SETTINGS.alpha if alpha is None else alpha
    crit = np.full(2 * n + 1, np.inf)
    crit[1:] = _chi2.isf(alpha, np.arange(1, 2 * n + 1))
    return crit


def _adaptive_settings(nbr, n_points, wp):
    """The adaptive kernels' arguments after the errors (critical values,
    ``k_dense``, weight power, :class:`~lensdual.estimators._adaptive_kernels.AdaptiveSettings`)
    for the neighbour rows ``nbr`` of ``n_points`` points (capped when the
    rows are shorter)."""
    st = _adaptive_kernels.SETTINGS
    k = nbr.shape[1]
    k_dense = st.k_dense if k < n_points else k
    return _chi2_critical(k), k_dense, float(wp), st


def _testable_codes(status):
    return (status == _adaptive_kernels.ADAPTIVE_OK) | (status == _adaptive_kernels.ADAPTIVE_MISFIT)


def _reverse_wins(status, status_rev, det_rev):
    """Where the L1-to-L2 fit replaces the L2-to-L1 one: the forward fit is not
    testable, the reverse one is, and its Jacobian can be inverted."""
    with np.errstate(invalid="ignore"):
        invertible = np.abs(det_rev) > 0.0
    return ~_testable_codes(status) & _testable_codes(status_rev) & invertible


def _adaptive(t1, t2, sigma, wp, max_neighbours=DEFAULT_MAX_NEIGHBOURS):
    """The adaptive estimator: Jacobians, their covariances (N, 4, 4), errors of
    ln|det J|, status codes, the errors' degrees of freedom, and which pairs
    took the reverse map.

    Where the L2-to-L1 fit is not testable ("untestable" or "failed"), the
    L1-to-L2 map is fitted the same way (:func:`_adaptive_forward` on the
    swapped arcs) and, where that fit is testable, its Jacobian ``K`` gives
    ``J = K^-1`` (``ln|det J| = -ln|det K|``, same error; the covariance
    propagated by ``dJ = -J dK J``).
    """
    jac, jcov, ln_sd, status, dof = _adaptive_forward(t1, t2, sigma, wp, max_neighbours)
    reverse = np.zeros(t1.shape[0], dtype=bool)
    need = np.flatnonzero(~_testable_codes(status))
    if _adaptive_kernels.SETTINGS.reverse and need.size:
        # the reverse fit of the pairs that need it only (the others: "failed")
        jr, cr, sr, str_, dr = _adaptive_forward(t2, t1, np.ascontiguousarray(sigma[::-1]),
                                                 wp, max_neighbours, rows=need)
        with np.errstate(invalid="ignore"):
            reverse = _reverse_wins(status, str_, np.linalg.det(jr))
        jac[reverse] = np.linalg.inv(jr[reverse])
        jcov[reverse] = inverse_covariance(jac[reverse], cr[reverse])
        ln_sd[reverse] = sr[reverse]
        status[reverse] = str_[reverse]
        dof[reverse] = dr[reverse]
    return jac, jcov, ln_sd, status, dof, reverse


def inverse_covariance(jac, cov_k):
    """The covariance (M, 4, 4) of ``vec J`` for ``J = K^-1`` (``jac`` (M, 2, 2))
    from that of ``vec K`` (``cov_k``), to first order: ``dJ = -J dK J``."""
    t = -np.einsum("mik,mlj->mijkl", jac, jac).reshape(-1, 4, 4)
    return t @ cov_k @ np.swapaxes(t, 1, 2)


def _adaptive_forward(t1, t2, sigma, wp, max_neighbours=DEFAULT_MAX_NEIGHBOURS, rows=None):
    """Run the adaptive kernel on the L2-to-L1 map: Jacobians, errors of
    ln|det J|, status codes and the errors' degrees of freedom; for the pairs
    ``rows`` only where given (the others NaN and "failed"; each pair's
    estimate is the same as in a run on every pair)."""
    n = t1.shape[0]
    nbr = _neighbour_rows(t2, max_neighbours)
    rows = np.arange(n) if rows is None else np.asarray(rows, dtype=np.int64)
    settings = _adaptive_settings(nbr, n, wp)
    no_noise = np.empty((0, n, 2))
    outputs = _adaptive_outputs(1, n)

    def run(part):
        need = np.zeros((1, n), dtype=bool)
        need[0, part] = True
        _adaptive_kernels.run_adaptive(*_kernel_arrays(t1, t2, nbr, no_noise, no_noise, sigma),
                                       *settings, need, *outputs)

    threads = available_threads(_MAX_THREADS)
    if rows.size < _THREAD_MIN_PAIRS or threads < 2:
        run(rows)
    else:
        # independent pairs: chunks in threads (same result as one call, bit for bit)
        edges = np.linspace(0, rows.size, 4 * threads + 1).astype(int)
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(run, [rows[edges[i]:edges[i + 1]] for i in range(len(edges) - 1)]))
    return tuple(out[0] for out in outputs)


def _adaptive_outputs(copies, n):
    """The adaptive kernel's outputs for ``copies`` copies of ``n`` pairs, as
    for pairs it does not estimate: NaN Jacobians, covariances and errors,
    "failed", 0 degrees of freedom."""
    return (np.full((copies, n, 2, 2), np.nan), np.full((copies, n, 4, 4), np.nan),
            np.full((copies, n), np.nan),
            np.full((copies, n), _adaptive_kernels.ADAPTIVE_FAILED, dtype=np.int64),
            np.zeros((copies, n)))


def _kernel_arrays(t1, t2, nbr, noise1, noise2, sigma):
    """The array arguments of the adaptive kernel before its settings, each
    contiguous, writeable float64 (one compiled version of the kernel)."""
    arrays = (t1, t2, noise1, noise2, sigma[0], sigma[1])
    t1, t2, noise1, noise2, s1, s2 = (np.require(a, np.float64, ["C", "W"]) for a in arrays)
    return t1, t2, np.require(nbr, np.int64, ["C", "W"]), noise1, noise2, s1, s2


def adaptive_batch(t1, t2, noise1, noise2, sigma, wp=2.0,
                    max_neighbours=DEFAULT_MAX_NEIGHBOURS, with_ok=False,
                    with_jacobian=False):
    """The adaptive estimator on noisy copies ``t + noise`` (shape (B, N, 2)).

    Returns ``|det J|``, the error of its logarithm, whether the status is
    "ok" or "misfit" (the pair is tested) and the error's degrees of freedom,
    each of shape (B, N); with ``with_ok``, also whether the status is "ok"
    (the fit passed its chi-square test); with ``with_jacobian``, then the
    Jacobians (B, N, 2, 2) and their covariances (B, N, 4, 4) too (those of
    :func:`_adaptive`). No validation: for
    :func:`lensdual.duality.null_calibration`. The neighbour rows are those
    of ``t2`` (the copies re-rank the points within them); as in
    :func:`_adaptive`, pairs with no testable L2-to-L1 fit take the
    L1-to-L2 map's (neighbour rows of ``t1``) where that one is testable.
    """
    det, ln_sd, status, dof, jac, jcov = _adaptive_batch_forward(t1, t2, noise1, noise2, sigma,
                                                                 wp, max_neighbours)
    testable = _testable_codes(status)
    fit_ok = status == _adaptive_kernels.ADAPTIVE_OK
    # the reverse map where the forward one is not testable (as _adaptive), on
    # the copies that need it only
    rows = (np.flatnonzero(~testable.all(axis=1)) if _adaptive_kernels.SETTINGS.reverse
            else np.empty(0, int))
    if rows.size:
        # and on their untestable pairs only
        dr, sr, str_, dfr, jr, cr = _adaptive_batch_forward(
            t2, t1, noise2[rows], noise1[rows], np.ascontiguousarray(sigma[::-1]), wp,
            max_neighbours, need=~testable[rows])
        r, c = np.nonzero(_reverse_wins(status[rows], str_, dr))
        det[rows[r], c] = 1.0 / dr[r, c]
        if with_jacobian and r.size:
            inv = np.linalg.inv(jr[r, c])
            jac[rows[r], c] = inv
            jcov[rows[r], c] = inverse_covariance(inv, cr[r, c])
        ln_sd[rows[r], c] = sr[r, c]
        dof[rows[r], c] = dfr[r, c]
        testable[rows[r], c] = True
        fit_ok[rows[r], c] = str_[r, c] == _adaptive_kernels.ADAPTIVE_OK
    out = (np.abs(det), ln_sd, testable, dof) + ((fit_ok,) if with_ok else ())
    return out + ((jac, jcov) if with_jacobian else ())


def _adaptive_batch_forward(t1, t2, noise1, noise2, sigma, wp, max_neighbours, need=None):
    """The adaptive kernel on noisy copies, L2-to-L1 map only: signed
    determinants, errors, status codes and degrees of freedom, each (B, N),
    the Jacobians and their covariances;
    where ``need`` (B, N) is given, for those pairs only (the others NaN and
    "failed")."""
    b, n = noise1.shape[:2]
    nbr = _neighbour_rows(t2, max_neighbours)
    need = np.ones((b, n), dtype=bool) if need is None else np.ascontiguousarray(need)
    jac, jcov, ln_sd, status, dof = outputs = _adaptive_outputs(b, n)
    _adaptive_kernels.run_adaptive(*_kernel_arrays(t1, t2, nbr, noise1, noise2, sigma),
                                   *_adaptive_settings(nbr, n, wp), need, *outputs)
    det = jac[..., 0, 0] * jac[..., 1, 1] - jac[..., 0, 1] * jac[..., 1, 0]
    return det, ln_sd, status, dof, jac, jcov


def _warn_adaptive(status):
    untestable = np.flatnonzero(status == _adaptive_kernels.ADAPTIVE_UNTESTABLE)
    failed = np.flatnonzero(status == _adaptive_kernels.ADAPTIVE_FAILED)
    if untestable.size:
        warnings.warn(
            f"adaptive Jacobian: no local polynomial (up to cubic) describes the map around "
            f"pair(s) {untestable.tolist()} within the position errors, from L2 to L1 or "
            "from L1 to L2 (the constellation is "
            "too sparse for how fast the map bends there, or sigma_pos is too small); their "
            "mu_size_status is 'untestable' and check_duality does not test them",
            EstimatorWarning,
            stacklevel=3,
        )
    if failed.size:
        warnings.warn(
            f"adaptive Jacobian: no usable local fit for pair(s) {failed.tolist()} "
            "(too few or degenerate baselines); their Jacobian is NaN",
            EstimatorWarning,
            stacklevel=3,
        )


def as_sigma(sigma_pos, n, positive=False):
    """Return per-arc, per-pair positional sigmas as a (2, N) array in arcsec.

    With ``positive``, zero errors are refused (the adaptive estimator
    weights by them).
    """
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
    if positive and not (sig > 0).all():
        raise ValueError("sigma_pos must be > 0 for method 'adaptive' (its local fits are "
                         "weighted by and tested against the position errors)")
    return np.ascontiguousarray(sig)


def _bootstrap_determinants(t1, t2, nbr, code, wp, min_sin, sigma, n_bootstrap, rng):
    """Signed det J for each bootstrap realisation, shape (n_bootstrap, N).

    The neighbour rows ``nbr`` are those of the measured positions and stay
    fixed; each realisation re-ranks the points within them.
    """
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
        _kernels.bootstrap_determinants_knn(
            t1, t2, nbr, noise1, noise2, code, wp, min_sin, _COND_MAX, dets[start:stop]
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
    method=DEFAULT_METHOD,
    *,
    sigma_pos=0.06 * u.arcsec,
    n_bootstrap=DEFAULT_N_BOOTSTRAP,
    seed=None,
    weight_power=2,
    min_angle=5 * u.deg,
    max_neighbours=DEFAULT_MAX_NEIGHBOURS,
):
    """Size magnification ``mu_size = |det J|`` per pair, with errors that hold.

    The default estimator, ``"adaptive"``, fits the L2-to-L1 map around each
    pair by weighted local polynomials on its ``k`` nearest neighbours in L2
    (the pair included), for every ``k`` and for degrees 1 and 2. The
    position errors of both arcs enter as the effective variance
    ``sigma1^2 + sigma2^2 J J^T`` of each point. A fit of degree ``d`` is
    accepted when its chi-square is consistent with those errors (5 %
    test; a linear fit also needs its quadratic terms to be insignificant,
    by the likelihood-ratio test against the quadratic at 1 %); the
    estimate of that neighbourhood is then the fit of degree
    ``d + 1`` on the same points, whose truncation bias is one order
    smaller than the tested fit's misfit (robust bias correction). A
    linear fit that passed its test may also take its bias correction from
    a larger neighbourhood whose quadratic fit passed its own and whose
    cubic terms are insignificant (likelihood-ratio test against the cubic
    at 5 %): the linear fit's slopes less the alias of that quadratic's
    terms (a *two-scale* estimate, with less variance than the quadratic on
    the smaller neighbourhood). It is used only where that quadratic is
    known to be gentle: the change of ``ln|det J|`` across the larger
    neighbourhood that it predicts, plus twice its noise, is at most 0.5. Among
    the accepted estimates the one with the smallest error wins, with
    a penalty for the change of ``ln|det J|`` across the neighbourhood that
    the reported fit's highest-degree terms predict beyond their noise (a
    proxy of the truncation the test cannot see). The
    error of ``ln mu_size`` is the exact linear propagation of the position
    errors through that fit: no bootstrap is needed, and ``n_bootstrap`` is
    ignored. ``mu_size_status`` is then ``"ok"``.

    Where no tested fit passes (the map bends faster than the constellation
    samples it at this precision), the reported fits that are consistent
    with the errors on their own (chi-square test of the reported fit)
    are used: the one with the smallest error, scaled by its leave-one-out
    (PRESS) misfit, and widened by an estimate of its bias: the mean of the
    squared differences beyond noise between its ``ln mu_size`` and that of
    the other self-consistent fits (the model uncertainty) and of one more
    term, the square of a truncation error that grows as
    the square of the fit's curvature (the largest change of
    ``ln|det J|`` across its neighbourhood that its second-order terms
    predict, less twice its noise: with few residuals a strongly bent map
    passes the chi-square with a biased derivative);
    ``mu_size_status`` is ``"misfit"``, and the pair is tested.
    That error is itself estimated from the chosen fit's ``2 (k - p)``
    residual degrees of freedom (``k`` points, ``p`` coefficients per
    component), given in ``ln_mu_size_err_dof``: its significance follows
    Student's t with that many degrees of freedom, not a Gaussian (see
    :func:`~lensdual.duality.check_duality`). With fewer than two
    self-consistent fits, or none, the least-bad estimate is returned with
    ``mu_size_status = "untestable"``:
    :func:`~lensdual.duality.check_duality` does not test such pairs (an
    `~lensdual.exceptions.EstimatorWarning` names them).

    Where no L2-to-L1 fit is testable, the same estimator runs on the
    reverse map, L1 to L2 (the arcs swapped, neighbours taken in L1), and
    where that fit is testable its Jacobian ``K`` gives ``J = K^-1`` (same
    error, status and degrees of freedom): next to a critical curve of arc
    L1 the L2-to-L1 map expands without bound while the reverse map stays
    smooth. ``meta["reverse_map_rows"]`` lists those pairs. See the
    design-decisions page of the docs for the measurements behind these choices.

    ``"2v"``, ``"quad"`` and ``"quad2"`` are the paper's estimators and
    their second-order variant; their errors come from a bootstrap over
    ``sigma_pos`` and hold the position noise only, not their truncation
    error.

    Parameters
    ----------
    theta1, theta2 : `~astropy.units.Quantity`, shape (N, 2)
        Positions on arcs L1 and L2 (pair ``a`` is row ``a`` of both).
    method : {"adaptive", "quad", "2v", "quad2"}
        Estimator, see :func:`relative_jacobian` (default ``"adaptive"``).
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
    max_neighbours : int or None, optional
        Largest number of points each pair's estimate uses: the pair and its
        ``max_neighbours - 1`` nearest neighbours in L2, found with a k-d
        tree (default `DEFAULT_MAX_NEIGHBOURS`, 64; None: every pair uses
        every point). Up to that many pairs nothing changes (every pair
        already uses every point); with more, ``"adaptive"`` tries the
        neighbourhoods ``k <= max_neighbours`` only, and the Quad estimators
        fit the baselines to these neighbours only, so that the cost grows
        as N (``"adaptive"`` without a cap: N^3, Quad: N^2). The bootstrap
        keeps each pair's neighbours of the measured positions and re-ranks
        them in every realisation. See the "Scale" section of the
        performance page for what the cap changes and by how much.

    Returns
    -------
    table : `~astropy.table.QTable`
        One row per pair, in input order, with columns

        - ``mu_size``: ``|det J|`` on the measured positions;
        - ``mu_size_err``: half the 16-84 % width of the bootstrap
          distribution of ``|det J|`` (``"adaptive"``: of the log-normal
          ``mu_size * exp(+-ln_mu_size_err)``);
        - ``ln_mu_size_err``: the error of ``ln mu_size``;
        - ``ln_mu_size_err_dof``: the degrees of freedom that error was
          estimated with: infinite where it is the propagation of the known
          position errors (status ``"ok"``, and the bootstrap methods), the
          chosen fit's residual degrees of freedom for ``"misfit"`` and
          ``"untestable"``, NaN for ``"failed"``;
        - ``mu_size_p16``, ``mu_size_p50``, ``mu_size_p84``: the bootstrap
          percentiles (``"adaptive"``: ``mu_size * exp(-1, 0, +1 sigma)``);
        - ``n_bootstrap_valid``: realisations with a finite estimate (the
          percentiles ignore the others; 0 for ``"adaptive"``);
        - ``mu_size_status``: ``"ok"``, ``"misfit"``, ``"untestable"`` or
          ``"failed"`` (``"adaptive"``, see above; the other methods give
          ``"ok"`` or, for a NaN Jacobian, ``"failed"``);
        - ``parity``: sign of ``det J`` (-1 for a fold pair, 0 when undefined);
        - ``jacobian``: the (2, 2) relative Jacobian;
        - ``jacobian_cov`` (``"adaptive"`` only): the (4, 4) covariance of
          its entries ``(J00, J01, J10, J11)``, from the chosen fit, scaled
          as its error (a "misfit" fit's by its PRESS misfit): the part of
          the error of ``ln mu_size`` that the Jacobian carries
          (``g^T C g``, ``g`` the gradient of ``ln|det J|``); the rest is
          the model error and the pair's own position noise. NaN where the
          status is "failed". :func:`~lensdual.duality.check_duality`
          reads it for ``snr_definition="profile"``.

        ``meta`` records the method and the bootstrap settings.

    Examples
    --------
    The same linear map as in :func:`relative_jacobian`, ``|det J| = 1.23``,
    with the default adaptive estimator and 0.01 arcsec position errors:

    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.estimators import size_magnification
    >>> rng = np.random.default_rng(1)
    >>> theta2 = rng.uniform(-1, 1, (8, 2)) * u.arcsec
    >>> theta1 = theta2 @ np.array([[1.5, 0.3], [0.1, -0.8]]).T
    >>> tab = size_magnification(theta1, theta2, sigma_pos=0.01 * u.arcsec)
    >>> np.round(tab["mu_size"], 3).tolist()
    [1.23, 1.23, 1.23, 1.23, 1.23, 1.23, 1.23, 1.23]
    >>> tab["parity"].tolist()
    [-1, -1, -1, -1, -1, -1, -1, -1]
    >>> tab["mu_size_status"].tolist()
    ['ok', 'ok', 'ok', 'ok', 'ok', 'ok', 'ok', 'ok']

    The paper's Quad estimator, with bootstrap errors:

    >>> tab = size_magnification(theta1, theta2, method="quad", sigma_pos=0.01 * u.arcsec,
    ...                          n_bootstrap=200, seed=0)
    >>> round(float(tab["mu_size"][0]), 3), int(tab["n_bootstrap_valid"][0])
    (1.23, 200)
    """
    t1, t2, code, wp, min_sin = _prepare(theta1, theta2, method, weight_power, min_angle)
    n = t1.shape[0]
    sigma = as_sigma(sigma_pos, n, positive=method == "adaptive")
    n_bootstrap = as_int(n_bootstrap, "n_bootstrap", minimum=1)
    cap = _max_neighbours(max_neighbours, method)
    if method == "adaptive":
        table = _adaptive_table(t1, t2, sigma, wp, sigma_pos, cap)
        table.meta["max_neighbours"] = cap
        return table
    rng = np.random.default_rng(seed)

    nbr = _neighbour_rows(t2, cap)
    jac, status = _jacobians(t1, t2, nbr, code, wp, min_sin)
    _warn_status(status, method)
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]

    boot = np.abs(_bootstrap_determinants(t1, t2, nbr, code, wp, min_sin, sigma, n_bootstrap,
                                          rng))
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

    with np.errstate(divide="ignore", invalid="ignore"):
        ln_err = 0.5 * (np.log(pct[2]) - np.log(pct[0]))
    table = _size_table(det, jac, pct, ln_err, n_valid,
                        np.where(np.isfinite(det), "ok", "failed"))
    table.meta["method"] = method
    table.meta["max_neighbours"] = cap
    table.meta["n_bootstrap"] = n_bootstrap
    table.meta["sigma_pos"] = _sigma_meta(sigma_pos)
    if method != "2v":
        table.meta["weight_power"] = wp
    else:
        table.meta["min_angle"] = min_angle
    return table


def determined_parity(parity, ln_mu_size_err, testable, snr_threshold):
    """The significance of the sign of ``det J`` and the parity where it is
    determined.

    Under the linear propagation the errors use, the sign of ``det J`` is
    known to ``|det J| / sigma(det J) = 1 / sigma(ln|det J|)`` standard
    deviations. Returns ``(parity_snr, parity)``: that significance (NaN
    where ``testable`` is False) and ``parity`` where it reaches
    ``snr_threshold``, 0 elsewhere (undetermined).
    """
    ln_err = np.asarray(ln_mu_size_err, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        parity_snr = np.where(testable, 1.0 / ln_err, np.nan)
    determined = np.asarray(testable, dtype=bool) & (np.nan_to_num(parity_snr) >= snr_threshold)
    return parity_snr, np.where(determined, np.asarray(parity), 0).astype(int)


def _sigma_meta(sigma_pos):
    return sigma_pos if sigma_pos.isscalar else "per-pair (see sigma_pos argument)"


def _size_table(det, jac, pct, ln_err, n_valid, status, ln_err_dof=None):
    table = QTable()
    table["mu_size"] = np.abs(det)
    table["mu_size_err"] = 0.5 * (pct[2] - pct[0])
    table["ln_mu_size_err"] = ln_err
    table["ln_mu_size_err_dof"] = (np.full(len(det), np.inf) if ln_err_dof is None
                                   else np.asarray(ln_err_dof, dtype=float))
    table["mu_size_p16"] = pct[0]
    table["mu_size_p50"] = pct[1]
    table["mu_size_p84"] = pct[2]
    table["n_bootstrap_valid"] = n_valid
    table["mu_size_status"] = np.asarray(status, dtype="U10")
    table["parity"] = np.where(np.isfinite(det), np.sign(det), 0).astype(int)
    table["jacobian"] = jac
    return table


def _adaptive_table(t1, t2, sigma, wp, sigma_pos, max_neighbours=DEFAULT_MAX_NEIGHBOURS):
    """size_magnification for method 'adaptive' (analytic errors, no bootstrap)."""
    jac, jcov, ln_sd, status, dof, reverse = _adaptive(t1, t2, sigma, wp, max_neighbours)
    _warn_adaptive(status)
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    mu = np.abs(det)
    # an error of ln mu_size beyond ~709 (|det J| ~ 0, or a map no polynomial
    # follows) has an unbounded upper limit: inf, without an overflow warning
    with np.errstate(over="ignore"):
        pct = np.vstack([mu * np.exp(-ln_sd), mu, mu * np.exp(ln_sd)])
    names = np.array([ADAPTIVE_STATUS[int(c)] for c in status])
    dof = np.where(status == _adaptive_kernels.ADAPTIVE_FAILED, np.nan, dof)
    table = _size_table(det, jac, pct, ln_sd, np.zeros(len(mu), dtype=int), names, dof)
    table["jacobian_cov"] = jcov
    table.meta["method"] = "adaptive"
    table.meta["error_model"] = (
        "linear propagation of sigma_pos through the accepted local fit (chi-square test "
        f"at {_adaptive_kernels.SETTINGS.alpha:g}, reported degree one above the tested one)"
    )
    table.meta["sigma_pos"] = _sigma_meta(sigma_pos)
    table.meta["weight_power"] = wp
    # rows whose Jacobian is the inverse of the L1-to-L2 map's (see _adaptive)
    table.meta["reverse_map_rows"] = np.flatnonzero(reverse).tolist()
    return table


def _poly_terms(u, degree):
    """Monomials of degree <= ``degree`` and their x and y derivatives (also the
    null map of :func:`lensdual.duality.null_calibration`)."""
    x, y = u[:, 0], u[:, 1]
    f, fx, fy = [], [], []
    for deg in range(degree + 1):
        for i in range(deg + 1):
            px, py = deg - i, i
            f.append(x**px * y**py)
            fx.append(px * x ** max(px - 1, 0) * y**py)
            fy.append(py * x**px * y ** max(py - 1, 0))
    return np.column_stack(f), np.column_stack(fx), np.column_stack(fy)


def _global_fit(t1, t2, degree):
    """Least-squares polynomial map L2 -> L1: (residuals, Jacobians, leverages, n_coef)."""
    centre = t2.mean(axis=0)
    scale = np.max(np.abs(t2 - centre)) or 1.0
    uu = (t2 - centre) / scale
    design, dx, dy = _poly_terms(uu, degree)
    q, r = np.linalg.qr(design)
    coef = np.linalg.solve(r, q.T @ t1)
    resid = t1 - design @ coef
    jac = np.empty((len(t1), 2, 2))
    jac[:, :, 0] = (dx @ coef) / scale
    jac[:, :, 1] = (dy @ coef) / scale
    return resid, jac, np.sum(q * q, axis=1), design.shape[1]


def estimate_sigma_pos(theta1, theta2, *, max_degree=3, alpha=0.05, full_output=False):
    """Position error per coordinate, measured from a constellation's own residuals.

    Published catalogues round positions (e.g. to 1e-5 deg = 0.036 arcsec)
    and rarely quote errors. If both arcs carry the same Gaussian error
    ``sigma`` per coordinate, the residual of a smooth map L2 -> L1 fitted to
    the pairs has covariance ``sigma^2 (I + J J^T)`` (``J`` the relative
    Jacobian). This function fits global polynomial maps of degree 1 to
    ``max_degree``, keeps raising the degree while an F-test at ``alpha``
    says the next degree removes real misfit, and returns

    ``sigma^2 = RSS / sum_a (1 - h_a) (2 + |J_a|_F^2)``

    of the chosen fit (``h_a`` the leverage of pair ``a``), which is unbiased
    when the map is a polynomial of that degree and errs high (the safe
    side) when the map bends more than the fit can follow.

    Parameters
    ----------
    theta1, theta2 : `~astropy.units.Quantity`, shape (N, 2)
        Positions on arcs L1 and L2.
    max_degree : int
        Highest polynomial degree tried (default 3); a degree is tried only
        when at least twice as many pairs as coefficients are available.
    alpha : float
        False-alarm probability of the F-test between degrees.
    full_output : bool
        Also return the chosen degree and the residual degrees of freedom.

    Returns
    -------
    sigma_pos : `~astropy.units.Quantity`
        The position error per coordinate (arcsec).
    degree, dof : int
        Only with ``full_output``: the degree of the fit and ``2 (N - n_coef)``.

    Examples
    --------
    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.estimators import estimate_sigma_pos
    >>> rng = np.random.default_rng(0)
    >>> t2 = rng.uniform(-2, 2, (40, 2))
    >>> t1 = t2 @ np.array([[1.5, 0.3], [0.1, -0.8]]).T + 0.05 * t2**2
    >>> s = 0.01
    >>> est = estimate_sigma_pos((t1 + s * rng.standard_normal(t1.shape)) * u.arcsec,
    ...                          (t2 + s * rng.standard_normal(t2.shape)) * u.arcsec)
    >>> bool(0.007 < est.to_value(u.arcsec) < 0.013)
    True
    """
    from scipy.stats import f as _f

    t1 = as_positions(theta1, "theta1")
    t2 = as_positions(theta2, "theta2")
    if len(t1) != len(t2):
        raise ValueError(f"theta1 and theta2 differ in length ({len(t1)} != {len(t2)})")
    max_degree = as_int(max_degree, "max_degree", minimum=1)
    alpha = as_real(alpha, "alpha", minimum=0.0, maximum=1.0, inclusive=False)
    n = len(t1)
    if n < 6:
        raise ValueError(f"estimate_sigma_pos needs at least 6 pairs (twice the 3 coefficients "
                         f"of an affine map), got {n}")
    fits = []
    for degree in range(1, max_degree + 1):
        n_coef = (degree + 1) * (degree + 2) // 2
        if n < 2 * n_coef:
            break
        resid, jac, lev, _ = _global_fit(t1, t2, degree)
        fits.append((degree, n_coef, float(np.sum(resid**2)), jac, lev))
    chosen = fits[0]
    for nxt in fits[1:]:
        d_num = 2 * (nxt[1] - chosen[1])
        d_den = 2 * (n - nxt[1])
        f_stat = ((chosen[2] - nxt[2]) / d_num) / (nxt[2] / d_den)
        if _f.sf(f_stat, d_num, d_den) < alpha:
            chosen = nxt
        else:
            break
    degree, n_coef, rss, jac, lev = chosen
    weight = np.sum((1.0 - lev) * (2.0 + np.sum(jac**2, axis=(1, 2))))
    sigma = np.sqrt(rss / weight) * u.arcsec
    return (sigma, degree, 2 * (n - n_coef)) if full_output else sigma
