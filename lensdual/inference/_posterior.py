"""The likelihood of the measured anomalies and the posterior on the abundance (private)."""

import numpy as np
from astropy import units as u
from astropy.table import QTable, Table
from scipy import special, stats

from ..duality import LOG_SNR_DEFINITIONS
from ._calibration import MIN_CALIBRATION_MOCKS, Recalibration, check_calibrations, mock_pit
from ._forward import AnomalySimulation

__all__ = ["pair_anomalies", "abundance_posterior", "half_mode_posterior", "composite_weight",
           "INTERVALS", "ANOMALIES"]

#: The credible intervals reported in ``meta["inference"]`` (equal-tailed).
INTERVALS = {"68": (0.16, 0.84), "95": (0.025, 0.975)}


#: The anomalies the likelihood reads: against the geometry (``mu_size``) or
#: against the joint test's prediction (geometry and the neighbours' flux field).
ANOMALIES = ("geometric", "joint")


def pair_anomalies(table, anomaly="geometric"):
    """Each tested pair's measured log flux anomaly and its error.

    The anomaly is the log of the flux ratio over the ratio it is tested
    against: ``ln(mu_flux / mu_size)`` (``anomaly="geometric"``, any duality
    table: a joint-test table keeps the geometric test's columns) or ``ln
    mu_flux - ln_mu_predicted`` (``anomaly="joint"``, a joint-test table; its
    error adds the flux ratio's error to the prediction's). Its error
    follows Student's t with the test's degrees of freedom.

    Parameters
    ----------
    table : `~astropy.table.Table`
        A :func:`~lensdual.check_duality` result (``snr_definition="log"``, or
        ``"conservative"``, whose anomalies and errors are the same).
    anomaly : {"geometric", "joint"}
        Which anomaly (default ``"geometric"``: the one whose posterior
        coverage holds on the inference page; the joint test's prediction
        uses the neighbours' flux ratios, which the same population
        perturbs, and its 68 % intervals cover less).

    Returns
    -------
    anomalies : `~astropy.table.QTable`
        ``pair_id``, ``delta``, ``delta_err`` and ``dof`` of the pairs that
        test tested.

    Raises
    ------
    TypeError
        ``table`` is not a Table.
    ValueError
        ``table`` is not a duality result with fluxes, has no tested pair,
        or is not a joint-test table where ``anomaly="joint"``.
    """
    if not isinstance(table, Table):
        raise TypeError(f"table must be an astropy Table, got {type(table).__name__}")
    if anomaly not in ANOMALIES:
        raise ValueError(f"anomaly must be one of {list(ANOMALIES)}, got {anomaly!r}")
    meta = table.meta.get("duality")
    if meta is None or "mu_flux" not in table.colnames:
        raise ValueError("the constellation has no flux ratios tested for duality: measure its "
                         "fluxes and run check_duality (or the pipeline) first")
    if meta.get("snr_definition", "log") not in LOG_SNR_DEFINITIONS:
        # "conservative" flags by the smaller of two SNRs; its anomalies and their
        # errors are the log ones
        raise ValueError("the anomalies are log ratios: run check_duality with "
                         "snr_definition='log' (or 'conservative')")
    joint_table = meta.get("test", "geometric") == "joint"
    if anomaly == "joint" and not joint_table:
        raise ValueError("anomaly='joint' reads the joint test's prediction: run "
                         "check_duality with test='joint' (the table's test is "
                         f"{meta.get('test', 'geometric')!r})")
    ln_flux = np.log(np.asarray(table["mu_flux"], dtype=float))
    ln_flux_err = np.asarray(table["mu_flux_err"], dtype=float) / np.asarray(table["mu_flux"],
                                                                            dtype=float)
    if anomaly == "joint":
        tested = np.asarray(table["tested"], dtype=bool)
        pred = np.asarray(table["ln_mu_predicted"], dtype=float)
        err = np.hypot(ln_flux_err, np.asarray(table["ln_mu_predicted_err"], dtype=float))
        dof = np.asarray(table["snr_dof"], dtype=float)
    else:
        pred = np.log(np.asarray(table["mu_size"], dtype=float))
        ratio = np.asarray(table["duality_ratio"], dtype=float)
        err = np.asarray(table["duality_ratio_err"], dtype=float) / ratio
        if joint_table:
            # the geometric test's columns: its significance (NaN where untested)
            # and its degrees of freedom
            if "snr_dof_geometric" not in table.colnames:
                raise ValueError("the joint-test table has no column 'snr_dof_geometric' "
                                 "(made before lensdual kept it): run check_duality again")
            tested = np.isfinite(np.asarray(table["significance_geometric"], dtype=float))
            dof = np.asarray(table["snr_dof_geometric"], dtype=float)
        else:
            tested = np.asarray(table["tested"], dtype=bool)
            dof = np.asarray(table["snr_dof"], dtype=float)
    if not tested.any():
        raise ValueError("no pair of the constellation was tested for duality")
    out = QTable()
    out["pair_id"] = np.asarray(table["pair_id"], dtype=int)[tested]
    out["delta"] = (ln_flux - pred)[tested]
    out["delta_err"] = err[tested]
    out["dof"] = dof[tested]
    return out


def _pair_log_likelihood(delta, err, dof, sims):
    """Log of the Monte-Carlo likelihood of one pair on the grid (a mean over the
    realisations, summed in log space so that a far tail stays finite)."""
    z = (delta - sims) / err  # (R, S)
    ok = np.isfinite(z)
    logpdf = stats.norm.logpdf(np.where(ok, z, 0.0)) if not np.isfinite(dof) else \
        stats.t.logpdf(np.where(ok, z, 0.0), dof)
    logpdf = np.where(ok, logpdf, -np.inf)
    n = np.maximum(ok.sum(axis=0), 1)
    return special.logsumexp(logpdf, axis=0) - np.log(n) - np.log(err)


def _system_log_likelihood(table, sim, anomaly="geometric"):
    data = pair_anomalies(table, anomaly)
    if not isinstance(sim, AnomalySimulation):
        raise TypeError(f"simulations must be AnomalySimulation objects, got {type(sim).__name__}")
    index = {int(p): i for i, p in enumerate(sim.pair_id)}
    missing = [int(p) for p in data["pair_id"] if int(p) not in index]
    if missing:
        raise ValueError(f"the simulation has no pair(s) {missing} of the constellation: "
                         "simulate the same pairs table")
    logl = np.zeros(sim.sigma_sub.size)
    for row in data:
        logl += _pair_log_likelihood(float(row["delta"]), float(row["delta_err"]),
                                     float(row["dof"]), sim.delta[index[int(row["pair_id"])]])
    return logl, len(data)


def _model_key(population):
    """What must agree between systems combined into one posterior (their
    redshifts and hosts may differ)."""
    if population is None:
        return None
    return (population.model, population.log_mlow, population.log_mhigh,
            population.shmf_log_slope, population.los_normalization, population.log_mhm)


def _quantile(log_grid, cdf, q):
    return float(np.interp(q, cdf, log_grid))


def _calibrated_quantile(log_grid, cdf, a):
    """The grid value at uncalibrated CDF level ``a`` (the calibration's
    ``G^-1(q)``): through the uncalibrated CDF, linear between the nodes as the
    mocks' PITs are; the grid's ends at levels 0 and 1."""
    return log_grid[0] if a <= 0 else log_grid[-1] if a >= 1 else _quantile(log_grid, cdf, a)


def _check_mock_count(pit, n_left):
    if len(pit) < MIN_CALIBRATION_MOCKS:
        raise ValueError(f"only {len(pit)} of the calibration's {len(pit) + n_left} mocks have "
                         "a tested pair in every system and a likelihood on the grid; at least "
                         f"{MIN_CALIBRATION_MOCKS} are needed: calibrate with more mocks "
                         "(n_mocks; [inference] n_calibration of lensdual infer)")


def _coverage(pit):
    """How often the mocks' uncalibrated equal-tailed intervals held their truths."""
    return {k: float(np.mean((pit >= lo) & (pit <= hi))) for k, (lo, hi) in INTERVALS.items()}


def _log_likelihood(tables, simulations, weights, anomaly="geometric"):
    """The weighted log-likelihood of the constellations ``tables`` on the grid of their
    ``simulations`` (lists, one per constellation), checked; returns it, the number
    of tested pairs and the weights as a list."""
    if not tables or len(tables) != len(simulations):
        raise ValueError(f"give one simulation per constellation: {len(tables)} table(s), "
                         f"{len(simulations)} simulation(s)")
    grid = simulations[0].sigma_sub
    for s in simulations[1:]:
        if s.sigma_sub.shape != grid.shape or not np.allclose(s.sigma_sub, grid, rtol=1e-12):
            raise ValueError("the simulations must share one sigma_sub grid")
    models = {_model_key(s.population) for s in simulations}
    if len(models) > 1:
        raise ValueError("the simulations must share one dark-matter model (model, mass range, "
                         "slope, line-of-sight normalisation, half-mode mass); got "
                         f"{sorted(models, key=str)}")
    if weights is None:
        weights = [1.0] * len(tables)
    weights = list(np.atleast_1d(np.asarray(weights, dtype=float)))
    if len(weights) != len(tables) or not all(0 < w <= 1 for w in weights):
        raise ValueError(f"weights must be one number in (0, 1] per constellation, got {weights}")
    logl = np.zeros(grid.size)
    n_pairs = 0
    for t, s, w in zip(tables, simulations, weights, strict=True):
        ll, n = _system_log_likelihood(t, s, anomaly)
        logl += w * ll
        n_pairs += n
    if not np.isfinite(logl).any():
        raise ValueError("the data have zero likelihood on the whole grid (no finite "
                         "simulated anomaly)")
    return logl, n_pairs, weights


def _marginal(log_grid, dens):
    """The normalised density on ``log_grid`` and its cdf (trapezoids)."""
    dens = dens / np.trapezoid(dens, log_grid)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(log_grid))])
    return dens, cdf / cdf[-1]


def abundance_posterior(tables, simulations, *, weights=None, anomaly="geometric",
                        calibrations=None):
    r"""Posterior on the sub-halo abundance ``sigma_sub`` from one or many constellations.

    Given the population, a sub-halo's effect is local, so the pairs are
    treated as independent: the likelihood of a constellation is the
    product over its tested pairs of the Monte-Carlo likelihood

    .. math::

       L_a(\sigma) = \frac{1}{R}\sum_r \frac{1}{s_a}\,
       t_{\nu_a}\!\left(\frac{\delta_a - \delta_{a,r}(\sigma)}{s_a}\right),

    with :math:`\delta_a, s_a, \nu_a` the measured anomaly, its error and
    degrees of freedom (:func:`pair_anomalies`) and :math:`\delta_{a,r}`
    the forward-modelled anomalies (:func:`simulate_anomalies`). Systems
    multiply. The prior is log-uniform on the simulations' grid (its ends
    are the prior's bounds).

    The product treats the pairs' errors as independent, and neighbouring
    pairs share baselines: with ``calibrations`` (:func:`calibrate_posterior`)
    the posterior's CDF :math:`F` is replaced by :math:`G(F)`, where
    :math:`G` is the distribution of :math:`F(\sigma_{\rm true})` over mock
    universes of the same systems, so that its intervals hold the truth as
    often as they say, averaged over the prior.

    Parameters
    ----------
    tables : Table or list of Table
        :func:`~lensdual.check_duality` results, one per constellation.
    simulations : AnomalySimulation or list of AnomalySimulation
        The matching :func:`simulate_anomalies` results, on one common
        ``sigma_sub`` grid.
    weights : float or list of float, optional
        Each system's composite-likelihood weight in (0, 1]
        (:func:`composite_weight`): its log-likelihood is multiplied by it.
        Default 1 (the pairs' errors independent).
    anomaly : {"geometric", "joint"}
        The pairs' anomalies, see :func:`pair_anomalies` (default
        ``"geometric"``, whatever test the tables ran).
    calibrations : PosteriorCalibration or list of PosteriorCalibration, optional
        One per constellation (:func:`calibrate_posterior`, on the
        simulations' grid with one ``n_mocks``): the posterior is
        recalibrated on their mocks, each system's mock log-likelihoods
        weighted by its weight and summed mock by mock.

    Returns
    -------
    posterior : `~astropy.table.QTable`
        ``sigma_sub`` (kpc^-2), ``log10_sigma_sub``, ``log_likelihood``,
        ``posterior`` (density per dex) and ``cdf``; with calibrations also
        ``cdf_uncalibrated``. ``meta["inference"]`` holds ``median``,
        ``interval_68``, ``interval_95`` and ``upper_95`` (kpc^-2),
        ``n_pairs``, ``n_systems``, ``prior``, the population and
        ``calibrated``; with calibrations ``n_mocks`` (those used: with a
        tested pair in every system), ``n_mocks_left_out``,
        ``mass_at_grid_ends`` (the fractions of the mocks whose truth lay
        beyond all their posterior's mass, below and above: the calibrated
        posterior's atoms at the grid's ends, in ``cdf`` but not in
        ``posterior``) and ``mock_coverage_uncalibrated``, the fractions of
        the mocks whose uncalibrated 68 % and 95 % intervals held their
        truths.

    Raises
    ------
    TypeError, ValueError
        Mismatched inputs (see :func:`pair_anomalies`), or grids that differ
        between the simulations.
    """
    if isinstance(tables, Table):
        tables = [tables]
    if isinstance(simulations, AnomalySimulation):
        simulations = [simulations]
    tables = list(tables)
    simulations = list(simulations)
    logl, n_pairs, weights = _log_likelihood(tables, simulations, weights, anomaly)
    grid = simulations[0].sigma_sub
    log_grid = np.log10(grid.to_value(u.kpc**-2))
    w = np.exp(logl - np.nanmax(logl))
    dens, cdf = _marginal(log_grid, np.where(np.isfinite(w), w, 0.0))
    out = QTable()
    out["sigma_sub"] = grid.to(u.kpc**-2)
    out["log10_sigma_sub"] = log_grid
    out["log_likelihood"] = logl
    calibration = {"calibrated": calibrations is not None}
    uncalibrated = cdf
    level = float  # the uncalibrated CDF level of a quantile
    if calibrations is not None:
        calibrations = check_calibrations(calibrations, simulations, anomaly)
        pit, n_left = mock_pit(log_grid, calibrations, weights)
        _check_mock_count(pit, n_left)
        g = Recalibration(pit)
        level = g.inverse
        out["cdf_uncalibrated"] = cdf
        cdf = g(cdf)
        dens = np.gradient(cdf, log_grid)
        calibration.update({
            "n_mocks": int(pit.size),
            "n_mocks_left_out": n_left,
            "mass_at_grid_ends": [g.low, g.high],
            "mock_coverage_uncalibrated": _coverage(pit),
        })
    out["posterior"] = dens
    out["cdf"] = cdf

    def q(p):
        return 10 ** _calibrated_quantile(log_grid, uncalibrated, level(p)) * u.kpc**-2

    out.meta["inference"] = {
        "median": q(0.5),
        "interval_68": u.Quantity([q(a) for a in INTERVALS["68"]]),
        "interval_95": u.Quantity([q(a) for a in INTERVALS["95"]]),
        "upper_95": q(0.95),
        "n_pairs": n_pairs,
        "n_systems": len(tables),
        "prior": f"log-uniform on [{grid[0]:.4g}, {grid[-1]:.4g}]",
        "n_realisations": int(simulations[0].delta.shape[1]),
        "weights": [float(w) for w in weights],
        "population": repr(simulations[0].population),
        "anomaly": anomaly,
        **calibration,
    }
    return out


def half_mode_posterior(tables, simulations, *, weights=None, anomaly="geometric",
                        calibrations=None):
    r"""Joint posterior on the sub-halo abundance and the WDM half-mode mass.

    The likelihood of :func:`abundance_posterior`, evaluated for every
    half-mode mass :math:`m_{\rm hm}` of a grid of warm-dark-matter
    populations, gives :math:`L(\sigma_{\rm sub}, m_{\rm hm})`; the prior is
    log-uniform in both on the grids (their ends are the prior's bounds).
    The half-mode mass sets where pyHalo's WDM mass function turns over, so
    the lowest masses of the grid, below the smallest sub-haloes that the
    constellation feels, stand for cold dark matter; where the data cannot
    tell the masses apart, the marginal on :math:`m_{\rm hm}` stays flat.

    Parameters
    ----------
    tables : Table or list of Table
        :func:`~lensdual.check_duality` results, one per constellation.
    simulations : list
        One entry per half-mode mass: the :func:`simulate_anomalies` result
        of a ``SubhaloPopulation(..., model="WDM", log_mhm=...)``, or, with
        several constellations, a list of them (one per table, in the order
        of ``tables``). Every simulation shares one ``sigma_sub`` grid, and
        apart from ``log_mhm`` one population model (mass range, slope).
    weights : float or list of float, optional
        Each constellation's composite-likelihood weight in (0, 1], as for
        :func:`abundance_posterior`.
    anomaly : {"geometric", "joint"}
        The pairs' anomalies, as for :func:`abundance_posterior`.
    calibrations : PosteriorCalibration or list of PosteriorCalibration, optional
        One per constellation, made by :func:`calibrate_posterior` on that
        constellation's simulations of every half-mode mass (one
        ``n_mocks``, distinct seeds): each marginal's CDF :math:`F` is
        replaced by :math:`G(F)`, :math:`G` the distribution over the mocks
        of their truth's place in their own marginal, as for
        :func:`abundance_posterior`. The joint density is left as it is.

    Returns
    -------
    posterior : `~astropy.table.QTable`
        One row per (half-mode mass, abundance): ``log10_mhm``,
        ``sigma_sub`` (kpc^-2), ``log10_sigma_sub``, ``log_likelihood`` and
        ``posterior`` (the joint density per dex squared, not recalibrated).
        ``meta["inference"]`` holds the abundance's marginal (``median``,
        ``interval_68``, ``interval_95``, ``upper_95``, kpc^-2), the half-mode
        mass's (``log10_mhm_median``, ``log10_mhm_interval_68``,
        ``log10_mhm_interval_95``, ``log10_mhm_upper_95``), both marginal
        densities (``marginal_sigma_sub``, ``marginal_log10_mhm``), ``n_pairs``,
        ``n_systems``, ``prior``, the populations and ``calibrated``. With
        calibrations the marginals are the recalibrated ones, and it also
        holds ``marginal_sigma_sub_uncalibrated``,
        ``marginal_log10_mhm_uncalibrated``, ``n_mocks``,
        ``n_mocks_left_out`` and, per parameter, ``mass_at_grid_ends`` and
        ``mock_coverage_uncalibrated`` (as for :func:`abundance_posterior`;
        the half-mode mass's prefixed ``log10_mhm_``).

    Raises
    ------
    TypeError, ValueError
        Fewer than two half-mode masses, a population that is not WDM, two
        simulations of one half-mode mass, grids or models that differ,
        or mismatched tables (see :func:`abundance_posterior`).
    """
    tables = [tables] if isinstance(tables, Table) else list(tables)
    slices = [[s] if isinstance(s, AnomalySimulation) else list(s) for s in simulations]
    if len(slices) < 2:
        raise ValueError(f"give simulations for at least two half-mode masses, got "
                         f"{len(slices)}")
    for sims in slices:
        for s in sims:
            if not isinstance(s, AnomalySimulation):
                raise TypeError(f"simulations must be AnomalySimulation objects, got "
                                f"{type(s).__name__}")
            if s.population is None or s.population.model != "WDM":
                raise ValueError("every simulation must be of a WDM population (model='WDM', "
                                 "log_mhm=...): the half-mode mass is the WDM turnover's")
        if len({s.population.log_mhm for s in sims}) != 1:
            raise ValueError("the simulations of one entry must share one half-mode mass")
    log_mhm = np.array([sims[0].population.log_mhm for sims in slices], dtype=float)
    if len(set(log_mhm.tolist())) != log_mhm.size:
        raise ValueError(f"each half-mode mass once, got log_mhm {log_mhm.tolist()}")
    keys = {_model_key(s.population)[:5] for sims in slices for s in sims}
    if len(keys) > 1:
        raise ValueError("apart from log_mhm the simulations must share one population model "
                         f"(mass range, slope, line-of-sight normalisation); got "
                         f"{sorted(keys, key=str)}")
    order = np.argsort(log_mhm)
    grid = slices[order[0]][0].sigma_sub
    lls = []
    for k in order:
        other = slices[k][0].sigma_sub
        if other.shape != grid.shape or not np.allclose(other, grid, rtol=1e-12):
            raise ValueError("the simulations must share one sigma_sub grid")
        ll, n_pairs, used = _log_likelihood(tables, slices[k], weights, anomaly)
        lls.append(ll)
    logl = np.array(lls)  # (M, S)
    log_m = log_mhm[order]
    log_s = np.log10(grid.to_value(u.kpc**-2))
    w = np.exp(logl - np.nanmax(logl))
    w = np.where(np.isfinite(w), w, 0.0)
    dens = w / np.trapezoid(np.trapezoid(w, log_s, axis=1), log_m)
    marg_s, cdf_s = _marginal(log_s, np.trapezoid(dens, log_m, axis=0))
    marg_m, cdf_m = _marginal(log_m, np.trapezoid(dens, log_s, axis=1))
    out = QTable()
    out["log10_mhm"] = np.repeat(log_m, log_s.size)
    out["sigma_sub"] = np.tile(grid.to_value(u.kpc**-2), log_m.size) * u.kpc**-2
    out["log10_sigma_sub"] = np.tile(log_s, log_m.size)
    out["log_likelihood"] = logl.ravel()
    out["posterior"] = dens.ravel()
    calibration = {"calibrated": calibrations is not None}
    level_s = level_m = float  # the uncalibrated CDF level of a quantile
    if calibrations is not None:
        per_system = [[slices[k][j] for k in order] for j in range(len(tables))]
        calibrations = check_calibrations(calibrations, per_system, anomaly)
        pit, n_left = mock_pit(log_s, calibrations, used)
        _check_mock_count(pit, n_left)
        g_s, g_m = Recalibration(pit[:, 0]), Recalibration(pit[:, 1])
        level_s, level_m = g_s.inverse, g_m.inverse
        calibration.update({
            "marginal_sigma_sub_uncalibrated": marg_s.tolist(),
            "marginal_log10_mhm_uncalibrated": marg_m.tolist(),
            "n_mocks": int(len(pit)),
            "n_mocks_left_out": n_left,
            "mass_at_grid_ends": [g_s.low, g_s.high],
            "log10_mhm_mass_at_grid_ends": [g_m.low, g_m.high],
            "mock_coverage_uncalibrated": _coverage(pit[:, 0]),
            "log10_mhm_mock_coverage_uncalibrated": _coverage(pit[:, 1]),
        })
        marg_s = np.gradient(g_s(cdf_s), log_s)
        marg_m = np.gradient(g_m(cdf_m), log_m)

    def q(p):
        return 10 ** _calibrated_quantile(log_s, cdf_s, level_s(p)) * u.kpc**-2

    def qm(p):
        return _calibrated_quantile(log_m, cdf_m, level_m(p))

    out.meta["inference"] = {
        "median": q(0.5),
        "interval_68": u.Quantity([q(a) for a in INTERVALS["68"]]),
        "interval_95": u.Quantity([q(a) for a in INTERVALS["95"]]),
        "upper_95": q(0.95),
        "log10_mhm_median": qm(0.5),
        "log10_mhm_interval_68": [qm(a) for a in INTERVALS["68"]],
        "log10_mhm_interval_95": [qm(a) for a in INTERVALS["95"]],
        "log10_mhm_upper_95": qm(0.95),
        "marginal_sigma_sub": marg_s.tolist(),
        "marginal_log10_mhm": marg_m.tolist(),
        "n_pairs": n_pairs,
        "n_systems": len(tables),
        "prior": (f"log-uniform on sigma_sub in [{grid[0]:.4g}, {grid[-1]:.4g}] and on "
                  f"log10_mhm in [{log_m[0]:g}, {log_m[-1]:g}]"),
        "n_realisations": int(slices[order[0]][0].delta.shape[1]),
        "weights": [float(w) for w in used],
        "populations": [repr(slices[k][0].population) for k in order],
        "anomaly": anomaly,
        **calibration,
    }
    return out


def composite_weight(pairs, lens, simulation, *, sigma_pos, flux_rel_err, n_mocks=100, seed=0,
                     anomaly="geometric", **check_kwargs):
    r"""Composite-likelihood weight of one constellation, by simulation.

    The likelihood of :func:`abundance_posterior` multiplies the pairs'
    likelihoods as if their measurement errors were independent. They are
    not: neighbouring pairs share baselines, so their geometric errors are
    correlated, and the product is then too sharp. The standard correction
    of a composite likelihood (a magnitude adjustment) raises it to the
    power :math:`w = H / J`, where :math:`H` is the mean curvature of the
    log-likelihood at the truth and :math:`J` the variance of its slope
    there, both in :math:`\log_{10}\sigma` (the median and the squared
    16-84 % half-width over the mocks: a rare mock whose anomaly only a few
    realisations explain makes the log-likelihood jump, and its slope would
    dominate a mean and a variance); for independent errors
    :math:`w = 1`. Both are measured on ``n_mocks`` mock universes: an
    abundance drawn from the grid's log-uniform prior, one realisation of
    the population applied to ``pairs`` (:func:`apply_population`), position
    and flux noise, :func:`~lensdual.check_duality`.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        The constellation without measurement noise: positions in the lens's
        frame and fluxes that obey duality in the smooth lens (e.g. the
        observed positions with the fluxes of one arc scaled by the lens's
        magnification ratios).
    lens : `~lensdual.simulation.LensSystem` or `~lensdual.parametric.LenstoolModel`
        The smooth lens of ``simulation``.
    simulation : AnomalySimulation
        :func:`simulate_anomalies` of ``pairs`` (its grid and population).
    sigma_pos : `~astropy.units.Quantity`
        Position noise per coordinate, as in the data.
    flux_rel_err : float
        Relative flux noise per image and band, as in the data.
    n_mocks : int, optional
        Mock universes, at least 20. Default 100.
    seed : int, optional
    anomaly : {"geometric", "joint"}
        The pairs' anomalies, as for :func:`abundance_posterior` (default
        ``"geometric"``: the mocks then run the geometric test, whose columns
        every test keeps).
    **check_kwargs
        Passed to :func:`~lensdual.check_duality` (its ``sigma_pos`` is
        ``sigma_pos``; its ``test`` is ``"geometric"`` with the geometric
        anomaly, and defaults to ``"joint"`` with the joint one).

    Returns
    -------
    weight : float
        :math:`\min(1, H / J)`, over the mocks with a tested pair (1 when
        fewer than two have one).

    See Also
    --------
    calibrate_posterior : the abundance posterior recalibrated on mocks, which
        holds its intervals where one weight for the whole prior does not
        (the inference page's coverage runs).
    """
    from .._validation import as_int
    from ._calibration import draw_mock_seeds, mock_check_kwargs, mock_log_likelihood

    if not isinstance(simulation, AnomalySimulation):
        raise TypeError(f"simulation must be an AnomalySimulation, got "
                        f"{type(simulation).__name__}")
    n_mocks = as_int(n_mocks, "n_mocks", minimum=20)
    check_kwargs = mock_check_kwargs(anomaly, check_kwargs)
    grid = simulation.sigma_sub.to_value(u.kpc**-2)
    if grid.size < 5:
        raise ValueError(f"the simulation's grid has {grid.size} abundances: the slope and "
                         "curvature of the log-likelihood need at least 5")
    log_grid = np.log10(grid)
    rng = np.random.default_rng(seed)
    lls, truths = [], []
    for _ in range(n_mocks):
        truth = 10 ** rng.uniform(log_grid[0], log_grid[-1])
        ll, _result = mock_log_likelihood(pairs, lens, simulation, truth, draw_mock_seeds(rng),
                                          sigma_pos=sigma_pos, flux_rel_err=flux_rel_err,
                                          anomaly=anomaly, check_kwargs=check_kwargs)
        if ll is None:
            continue  # a mock without a tested pair has a flat likelihood: no slope to measure
        lls.append(ll)
        truths.append(np.log10(truth))
    return _magnitude_weight(log_grid, np.array(lls), np.array(truths))


def _magnitude_weight(log_grid, lls, truths):
    """``min(1, H / J)`` from log-likelihoods ``lls`` (M, S) of mocks whose truths
    are ``truths`` (M,): H the median curvature, J the squared 16-84 %
    half-width of the slope at the truth (finite differences on the grid)."""
    slopes, curvatures = [], []
    for ll, t in zip(lls, truths, strict=True):
        if not np.isfinite(ll).all():
            continue
        d1 = np.gradient(ll, log_grid)
        d2 = np.gradient(d1, log_grid)
        slopes.append(np.interp(t, log_grid, d1))
        curvatures.append(-np.interp(t, log_grid, d2))
    if len(slopes) < 2:
        return 1.0
    # robust: a mock whose anomaly only a few realisations explain makes the
    # log-likelihood jump, and its slope would dominate a variance
    lo, hi = np.percentile(slopes, [15.865, 84.135])
    j = float((0.5 * (hi - lo)) ** 2)
    h = float(np.median(curvatures))
    return float(min(1.0, max(h, 0.0) / j)) if j > 0 else 1.0
