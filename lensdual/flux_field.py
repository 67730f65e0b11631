"""The flux field: each pair's ln mu predicted from its neighbours' flux ratios.

On a clean constellation every pair's flux ratio measures the same smooth
relative magnification field, ``ln mu(theta2)``, through duality. A sub-halo
whose (magnified) Einstein radius is below the inter-source spacing changes one
pair's flux ratio and not its neighbours'. :func:`flux_field_prediction`
predicts each pair's ``ln mu`` from the *other* pairs' flux ratios
(leave-one-out), with an error that includes the fit's own truncation error;
:func:`lensdual.duality.check_duality` with ``test="joint"`` tests the pair's
flux ratio against it and the geometric ``mu_size`` together.

The prediction at pair ``i`` (see :ref:`joint-test` for the specification):

0. it is made only where the pair is *resolved* (for
   :func:`~lensdual.duality.check_duality`: its geometric fit passed its
   chi-square test) and so are those neighbours, up to
   :data:`MAX_UNRESOLVED` of them (the failures that chance explains);
1. the :data:`N_LOCAL` nearest usable neighbours of ``i`` on arc L2 (``i``
   itself excluded) get a weighted quadratic fit of ``ln mu_flux`` in the
   whitened local frame centred on ``i``; the weights are the inverse
   variances of the neighbours' ``ln mu_flux``, widened by their position
   error times the fitted gradient (a refit), and the prediction is the fit's
   value at ``i``;
2. its truncation error is estimated against a cubic fit to the
   :data:`N_CHECK` nearest: the difference ``d`` of the two predictions is
   the quadratic's bias plus noise of known variance ``V`` (the two fits'
   prediction weights applied to the neighbours' errors). The bias is given a
   prior ``N(0, tau^2 G)``, ``G`` being how much cubic terms of unit
   coefficients in the whitened frame move the quadratic's prediction;
   ``tau^2`` is the maximum-likelihood value over the constellation's
   predicted pairs (empirical Bayes), and the variance added is the posterior
   mean of the squared bias, ``k^2 d^2 + k V`` with ``k = tau^2 G / (tau^2 G
   + V)``. With fewer than five predicted pairs ``d^2`` itself is added;
3. ``i``'s own position error moves the point the field is read at: the
   fitted gradient times that error is added too;
4. the leave-one-out residuals of all pairs, over their errors, must have the
   median absolute value of a unit Gaussian (0.674): where they are wider,
   one common model variance is added to every prediction until they are;
5. steps 1 to 4 are made for every neighbourhood size of the quadratic from
   :data:`N_LOCAL` to :data:`N_CHECK` (:data:`N_LOCAL_SIZES`), and the
   prediction is their average weighted by each size's leave-one-out log
   score on the pair's :data:`N_CHECK` nearest other pairs (pseudo-Bayesian
   model averaging, ``size_weights``); its variance is the weighted mean
   of the sizes' variances plus the spread of their predictions about the
   average. Steps 0's gate, the status and the neighbour counts are those of
   the :data:`N_LOCAL` fits.
"""

from typing import NamedTuple

import numpy as np
from astropy import units as u
from astropy.table import QTable
from scipy.spatial import cKDTree
from scipy.stats import binom, norm

from . import _flux_field_kernels as _kernels
from .estimators._adaptive import SETTINGS as ADAPTIVE_SETTINGS
from .estimators.core import as_sigma

__all__ = ["flux_field_prediction", "FIELD_STATUS", "N_LOCAL", "N_CHECK", "N_LOCAL_SIZES",
           "MAX_UNRESOLVED", "DROP_LEVEL", "MAX_DROP"]

#: Fewest neighbours of the quadratic fit (6 coefficients, so 4 residual degrees of
#: freedom): the resolution gate of step 0 and the first of :data:`N_LOCAL_SIZES`.
N_LOCAL = 10
#: Neighbours of the cubic fit (10 coefficients) that bounds the quadratic's truncation error.
N_CHECK = 16
#: Level at which a neighbourhood's count of unresolved neighbours is more than chance.
_UNRESOLVED_LEVEL = 0.05


def _max_unresolved(n_local, alpha):
    """The most unresolved neighbours among ``n_local`` that chance explains.

    Each neighbour's adaptive fit fails its chi-square test at level ``alpha``
    by chance where the map is resolved, so the count of unresolved neighbours
    is at most Binomial(``n_local``, ``alpha``) there. The largest count ``k``
    whose upper tail ``P(K >= k)`` is at least :data:`_UNRESOLVED_LEVEL` is
    returned (2 of 10 at ``alpha`` = 0.05).
    """
    k = 0
    while k < n_local and binom.sf(k, n_local, alpha) >= _UNRESOLVED_LEVEL:
        k += 1
    return k


#: Most unresolved neighbours among the quadratic's N_LOCAL that chance explains (2).
MAX_UNRESOLVED = _max_unresolved(N_LOCAL, ADAPTIVE_SETTINGS.alpha)
#: Family-wise level, over a quadratic fit's N_LOCAL neighbours, at which a neighbour
#: off the quadratic through the others is dropped from the pair's fits.
DROP_LEVEL = 0.05
#: Most neighbours dropped from one pair's fits.
MAX_DROP = 2
#: Neighbourhood sizes of the quadratic fit whose predictions step 5 averages: every
#: size from N_LOCAL to the cubic check's N_CHECK.
N_LOCAL_SIZES = tuple(range(N_LOCAL, N_CHECK + 1))
#: Per size of N_LOCAL_SIZES: (size, the studentised deletion residual beyond which
#: step 1 drops a neighbour: the Bonferroni bound over that many neighbours).
_SIZE_SETTINGS = tuple((k, float(norm.isf(DROP_LEVEL / (2 * k)))) for k in N_LOCAL_SIZES)
#: Fewest neighbours of the cubic check: two residual degrees of freedom.
_MIN_CHECK = 12
#: Fewest pairs with flux ratios for which the field predicts any pair (a pair and
#: the cubic check's neighbours).
MIN_PAIRS = _MIN_CHECK + 1
#: Median of |Z| for a unit Gaussian Z.
_GAUSS_MEDIAN_ABS = 0.6744897501960817
#: Fewest predictions for the bias scale of step 2 and the common model variance of step 4.
_MIN_CALIBRATION = 5
#: Search interval of ln tau^2 in step 2 (tau^2 in the units of ln mu squared).
_LN_TAU2_BOUNDS = (-40.0, 5.0)
#: Grid of ln tau^2 over that interval (steps of 0.5) from which step 2's search refines.
_LN_TAU2_GRID = 91
#: Largest ratio of the largest to the smallest pivot of a fit's (column-equilibrated)
#: R factor.
_COND_MAX = 1e9

#: The values of ``field_status``: ``"ok"`` (predicted), ``"too few neighbours"``
#: (fewer than the cubic check's 12 usable neighbours), ``"unresolved"`` (the
#: pair, or more than MAX_UNRESOLVED of its quadratic's neighbours, not ``resolved``),
#: ``"ill-conditioned"`` (the neighbours lie on a curve a quadratic cannot be
#: fitted on), and ``"excluded"`` (the pair's position is not measured).
FIELD_STATUS = ("ok", "too few neighbours", "unresolved", "ill-conditioned", "excluded")


def _common_variance(resid, var):
    """Step 4: the model variance that brings median |resid| / sd to 0.674."""
    ok = np.isfinite(resid) & np.isfinite(var)
    r, v = np.abs(resid[ok]), var[ok]
    if r.size < _MIN_CALIBRATION:
        return 0.0
    return float(_kernels.common_variance(np.ascontiguousarray(r, dtype=float),
                                          np.ascontiguousarray(v, dtype=float),
                                          _GAUSS_MEDIAN_ABS))


def bias_scale(dev, var_dev, sens):
    """Step 2: the maximum-likelihood ``tau^2`` of ``dev ~ N(0, tau^2 sens + var_dev)``
    over the pairs given (0 where fewer than :data:`_MIN_CALIBRATION`)."""
    if dev.size < _MIN_CALIBRATION:
        return 0.0
    lo, hi = _LN_TAU2_BOUNDS
    ln_tau2 = _kernels.max_likelihood_ln_tau2(
        np.ascontiguousarray(dev**2, dtype=float), np.ascontiguousarray(sens, dtype=float),
        np.ascontiguousarray(var_dev, dtype=float), lo, hi, _LN_TAU2_GRID, 1e-9)
    return float(np.exp(ln_tau2))


def squared_bias(dev, var_dev, sens, calib):
    """Step 2: each pair's posterior mean squared bias (see the module docstring);
    ``dev**2`` everywhere where fewer than :data:`_MIN_CALIBRATION` pairs calibrate
    ``tau^2``."""
    use = calib & np.isfinite(dev) & np.isfinite(var_dev) & np.isfinite(sens) & (var_dev > 0)
    if np.count_nonzero(use) < _MIN_CALIBRATION:
        return dev**2
    tau2 = bias_scale(dev[use], var_dev[use], sens[use])
    prior = tau2 * sens
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.where(prior + var_dev > 0, prior / (prior + var_dev), 0.0)
    return k**2 * dev**2 + k * var_dev


class _Field(NamedTuple):
    """The flux field of every pair (see :func:`field_arrays`)."""

    value: np.ndarray  # predicted ln mu, NaN where not "ok"
    var: np.ndarray  # its variance, the common model variance included
    status: np.ndarray  # FIELD_STATUS per pair
    n_used: np.ndarray  # neighbours of the cubic check
    n_dropped: np.ndarray  # neighbours dropped as off the quadratic through the others
    model_var: float  # the common model variance of step 4 (N_LOCAL neighbours)


def _field_of_size(n_local, t_drop, pos, y, s, sig2, placed, finite, usable, resolved):
    """Steps 0 to 4 with quadratic fits of ``n_local`` neighbours (the resolution gate
    of step 0 always reads the :data:`N_LOCAL` nearest)."""
    n = y.size
    value, var, dev, var_dev, sens = (np.empty(n) for _ in range(5))
    code = np.empty(n, dtype=np.int64)
    n_used = np.empty(n, dtype=np.int64)
    n_dropped = np.empty(n, dtype=np.int64)
    _kernels.predict_all(np.ascontiguousarray(np.where(placed[:, None], pos, 0.0)),
                         np.where(finite, y, 0.0), np.where(finite, s, 1.0),
                         np.ascontiguousarray(sig2, dtype=float),
                         np.ascontiguousarray(usable, dtype=np.bool_),
                         np.ascontiguousarray(resolved, dtype=np.bool_), n_local, N_LOCAL,
                         N_CHECK, _MIN_CHECK, _COND_MAX, MAX_UNRESOLVED, t_drop, MAX_DROP,
                         value, var, dev, var_dev, sens, code, n_used, n_dropped)
    ok = (code == _kernels.OK) & placed
    calib = ok & usable
    var = var + squared_bias(dev, var_dev, sens, calib)
    model_var = _common_variance(y[calib] - value[calib], s[calib] ** 2 + var[calib])
    status = np.where(placed, np.asarray(FIELD_STATUS)[code], "excluded")
    return _Field(np.where(ok, value, np.nan), np.where(ok, var + model_var, np.nan), status,
                  n_used, n_dropped, model_var)


def size_weights(pos, y, s, values, variances, usable):
    """Step 5: each pair's weights of the neighbourhood sizes, shape ``(K, N)``.

    ``values`` and ``variances`` (K, N) are the predictions of the K sizes
    (NaN where a size does not predict). A size's score at pair ``i`` is its
    leave-one-out log score on the :data:`N_CHECK` nearest other pairs that
    are usable and predicted by every size, ``sum_j ln v_j + (y_j - f_j)^2 /
    v_j`` with ``v_j = s_j^2 + variance_j`` (minus twice the log predictive
    density, up to a constant); its weight is ``exp(-score / 2)``,
    normalised over the sizes that predict ``i``. ``i``'s own residual is not
    in its scores. Where fewer than :data:`_MIN_CALIBRATION` pairs are
    scored, the first size takes all the weight.
    """
    n_sizes, n = values.shape
    predicted = np.isfinite(values) & np.isfinite(variances)
    scored = usable & predicted.all(axis=0)
    weights = np.zeros((n_sizes, n))
    if np.count_nonzero(scored) < _MIN_CALIBRATION:
        weights[0] = predicted[0]
        return weights
    idx = np.flatnonzero(scored)
    v = s[idx] ** 2 + variances[:, idx]
    terms = np.log(v) + (y[idx] - values[:, idx]) ** 2 / v
    # the m nearest scored pairs of every placed pair (their places in idx), itself
    # left out (a k-d tree: no N x N distance matrix for large constellations)
    m = min(N_CHECK, idx.size - 1)
    k = min(N_CHECK + 1, idx.size)
    rows = np.flatnonzero(np.isfinite(pos).all(axis=1))
    found = cKDTree(pos[idx]).query(pos[rows], k=k)[1].reshape(rows.size, k)
    own_last = np.argsort(idx[found] == rows[:, None], axis=1, kind="stable")
    nearest = np.take_along_axis(found, own_last, axis=1)[:, :m]
    score = np.full((n_sizes, n), np.inf)
    score[:, rows] = terms[:, nearest].sum(axis=2)
    score = np.where(predicted, score, np.inf)
    best = np.min(score, axis=0)
    has = np.isfinite(best)
    weights = np.where(predicted & has, np.exp(-0.5 * (score - np.where(has, best, 0.0))), 0.0)
    total = weights.sum(axis=0)
    return np.where(total > 0, weights / np.where(total > 0, total, 1.0), 0.0)


def field_arrays(pos, y, s, sig2, usable=None, resolved=None):
    """The flux field of checked arrays (arcsec), see the module docstring.

    Pairs with a NaN position, value or error, or a non-positive error, inform
    nobody; a NaN position gets status "excluded". Status, neighbours used and
    dropped, and the common model variance are those of the :data:`N_LOCAL`
    neighbour fits; a pair is predicted where those predict it.
    """
    n = y.size
    placed = np.isfinite(pos).all(axis=1)
    finite = np.isfinite(y) & np.isfinite(s) & (s > 0) & placed
    usable = finite if usable is None else usable & finite
    resolved = np.ones(n, dtype=bool) if resolved is None else resolved
    fields = [_field_of_size(k, t, pos, y, s, sig2, placed, finite, usable, resolved)
              for k, t in _SIZE_SETTINGS]
    first = fields[0]
    ok = np.isfinite(first.value)
    # a size predicts where its quadratic has that many neighbours (with fewer, a
    # larger size repeats a smaller one's fit)
    full = [ok & (f.n_used >= k) for f, (k, _) in zip(fields, _SIZE_SETTINGS, strict=True)]
    values = np.array([np.where(m, f.value, np.nan) for f, m in zip(fields, full, strict=True)])
    variances = np.array([np.where(m, f.var, np.nan) for f, m in zip(fields, full, strict=True)])
    w = size_weights(pos, y, s, values, variances, usable)
    used = w > 0
    value = np.sum(np.where(used, w * values, 0.0), axis=0)
    spread = np.where(used, values - value, 0.0)
    var = np.sum(np.where(used, w * (variances + spread**2), 0.0), axis=0)
    return _Field(np.where(ok, value, np.nan), np.where(ok, var, np.nan), first.status,
                  first.n_used, first.n_dropped, first.model_var)


def flux_field_prediction(theta2, ln_mu_flux, ln_mu_flux_err, *, sigma_pos=None, usable=None,
                          resolved=None):
    r"""Predict each pair's ``ln mu`` from the other pairs' flux ratios (leave-one-out).

    Parameters
    ----------
    theta2 : `~astropy.units.Quantity`
        Positions on arc L2, shape (N, 2), angles.
    ln_mu_flux, ln_mu_flux_err : array-like
        ``ln mu_flux`` of every pair (bands combined) and its error, shape (N,).
        Pairs with a NaN value or error do not inform the others.
    sigma_pos : `~astropy.units.Quantity`, optional
        Position errors, as for :func:`~lensdual.estimators.size_magnification`
        (a scalar, shape (N,) or (2, N); the L2 row is used); ``None`` for
        none. They widen the neighbours' weights and the prediction's error by
        the fitted gradient of the field.
    usable : array-like of bool, optional
        Pairs that may inform the others (default: every pair with a finite
        ``ln mu_flux`` and a positive, finite error). Doubtful, chromatic or
        flagged pairs should be left out. A pair that is not usable still gets
        its own prediction.
    resolved : array-like of bool, optional
        Pairs where the constellation resolves the lens map (default: all).
        A pair is predicted only where it is resolved and at most
        :data:`MAX_UNRESOLVED` of its quadratic fit's neighbours are not;
        elsewhere ``field_status`` is ``"unresolved"``.
        :func:`~lensdual.duality.check_duality` passes the pairs whose adaptive
        geometric fit passed its chi-square test (``mu_size_status`` ``"ok"``):
        ``ln mu`` is ``ln |det J|``, the log of the map's Jacobian
        determinant, so where the map's local polynomial fails its test
        against the position errors, the constellation does not sample its
        derivative field finely enough to predict it either.

    Returns
    -------
    table : `~astropy.table.QTable`
        Columns ``ln_mu_field`` (the prediction of ``ln mu`` at the pair),
        ``ln_mu_field_err`` (its error), ``field_status`` (one of
        :data:`FIELD_STATUS`; only ``"ok"`` rows have a prediction) and
        ``field_n`` (neighbours of the cubic check) and ``field_dropped``
        (neighbours dropped from the pair's fits as off the field of the
        others, step 1), both of the :data:`N_LOCAL`-neighbour fits.
        ``meta['field_model_sd']`` is the common model error of step 4 of those
        fits (0 where their leave-one-out residuals already scatter as their
        errors say).

    Raises
    ------
    TypeError
        ``theta2`` or ``sigma_pos`` without angular units.
    ValueError
        Shapes that disagree, negative errors, or fewer than two pairs.

    Examples
    --------
    A field that is exactly quadratic is predicted exactly, whatever the noise
    the errors quote:

    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.flux_field import flux_field_prediction
    >>> rng = np.random.default_rng(0)
    >>> xy = rng.uniform(-1, 1, (20, 2))
    >>> ln_mu = 0.3 + 0.2 * xy[:, 0] - 0.1 * xy[:, 0] * xy[:, 1]
    >>> field = flux_field_prediction(xy * u.arcsec, ln_mu, np.full(20, 0.02))
    >>> bool(np.allclose(field["ln_mu_field"], ln_mu))
    True
    >>> sorted(set(field["field_status"].tolist()))
    ['ok']
    """
    if not isinstance(theta2, u.Quantity) or theta2.unit.physical_type != "angle":
        raise TypeError("theta2 must be a Quantity with angular units, shape (N, 2)")
    pos = np.asarray(theta2.to_value(u.arcsec), dtype=float)
    if pos.ndim != 2 or pos.shape[1] != 2:
        raise ValueError(f"theta2 must have shape (N, 2), got {pos.shape}")
    n = pos.shape[0]
    if n < 2:
        raise ValueError(f"the flux field needs at least 2 pairs, got {n}")
    y = np.asarray(ln_mu_flux, dtype=float)
    s = np.asarray(ln_mu_flux_err, dtype=float)
    if y.shape != (n,) or s.shape != (n,):
        raise ValueError(f"ln_mu_flux and ln_mu_flux_err must have shape ({n},), got "
                         f"{y.shape} and {s.shape}")
    if np.any(s < 0):
        raise ValueError("ln_mu_flux_err must be >= 0")
    sig2 = np.zeros(n) if sigma_pos is None else as_sigma(sigma_pos, n)[1]
    if usable is not None:
        usable = np.asarray(usable, dtype=bool)
        if usable.shape != (n,):
            raise ValueError(f"usable must have shape ({n},), got {usable.shape}")
    if resolved is not None:
        resolved = np.asarray(resolved, dtype=bool)
        if resolved.shape != (n,):
            raise ValueError(f"resolved must have shape ({n},), got {resolved.shape}")
    field = field_arrays(pos, y, s, sig2, usable, resolved)
    out = QTable()
    out["ln_mu_field"] = field.value
    out["ln_mu_field_err"] = np.sqrt(field.var)
    out["field_status"] = field.status
    out["field_n"] = field.n_used
    out["field_dropped"] = field.n_dropped
    out.meta["field_model_sd"] = float(np.sqrt(field.model_var))
    return out
