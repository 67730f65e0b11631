"""Calibration of the abundance posterior by simulation (private)."""

import warnings
from dataclasses import dataclass

import numpy as np
from astropy import units as u

from .._parallel import check_client, run_tasks
from ..exceptions import EstimatorWarning
from ._forward import AnomalySimulation

__all__ = ["PosteriorCalibration", "calibrate_posterior", "MIN_CALIBRATION_MOCKS"]

#: The fewest mocks a calibration is made of, and used with: the binomial error
#: of a 68 % interval's coverage is then 6.6 points.
MIN_CALIBRATION_MOCKS = 50


@dataclass(frozen=True, eq=False)
class PosteriorCalibration:
    """The mock universes that calibrate one constellation's abundance posterior.

    Made by :func:`calibrate_posterior`; passed to
    :func:`abundance_posterior` (``calibrations=``). Every parameter is also
    an attribute.

    Parameters
    ----------
    log10_truth : ndarray (M,)
        Each mock's true ``log10 sigma_sub`` (kpc^-2): the midpoints of ``M``
        equal-probability strata of the log-uniform prior, so that every
        constellation calibrated on one grid with the same ``n_mocks`` has the
        same truths and their mocks combine into mocks of the systems
        together.
    log_likelihood : ndarray (M, S)
        Each mock's log-likelihood on the simulation's grid (zero where the
        mock has no tested pair).
    sigma_sub : `~astropy.units.Quantity`
        The grid (kpc^-2).
    anomaly : str
        The anomalies the mocks' likelihoods read.
    n_tested : ndarray (M,)
        Each mock's number of tested pairs; a mock without one is left out of
        the calibration (the data always have one).
    simulation_key : tuple
        What identifies the simulation the mocks were scored on: its
        population, pair ids and disc radii.
    seed : int
        The entropy of the mocks' random numbers.
    """

    log10_truth: np.ndarray
    log_likelihood: np.ndarray
    sigma_sub: u.Quantity
    anomaly: str
    n_tested: np.ndarray
    simulation_key: tuple
    seed: int

    def __repr__(self):
        return (f"<PosteriorCalibration: {self.log10_truth.size} mocks on "
                f"{self.sigma_sub.size} abundances, anomaly={self.anomaly!r}>")


def simulation_key(simulation):
    """The population, pair ids and disc radii of an `AnomalySimulation`."""
    return (repr(simulation.population), tuple(int(p) for p in simulation.pair_id),
            tuple(float(r) for r in np.ravel(simulation.radius)))


def stratified_truths(log_grid, n):
    """The midpoints of ``n`` equal-probability strata of the log-uniform prior."""
    return log_grid[0] + (np.arange(n) + 0.5) / n * (log_grid[-1] - log_grid[0])


def mock_log_likelihood(pairs, lens, simulation, truth, seeds, *, sigma_pos, flux_rel_err,
                        anomaly, check_kwargs):
    """One mock universe at abundance ``truth`` (kpc^-2): its log-likelihood on the
    simulation's grid (None without a tested pair) and its duality table; ``seeds``
    are those of the population's realisation, the noise and the test."""
    from .. import check_duality
    from ..simulation import noisy_constellation
    from ._forward import _apply_population
    from ._posterior import _system_log_likelihood

    seed_population, seed_noise, seed_test = (int(x) for x in seeds)
    mock = _apply_population(pairs, lens, simulation.population, truth, simulation.radius,
                             seed_population)
    noisy = noisy_constellation(mock, sigma_pos=sigma_pos, flux_rel_err=flux_rel_err,
                                seed=seed_noise)
    with warnings.catch_warnings():
        # a mock's untestable pairs are part of what the mocks measure
        warnings.simplefilter("ignore", EstimatorWarning)
        result = check_duality(noisy, sigma_pos=sigma_pos, seed=seed_test, **check_kwargs)
    if not np.asarray(result["tested"], dtype=bool).any():
        return None, result
    return _system_log_likelihood(result, simulation, anomaly)[0], result


def draw_mock_seeds(rng):
    """The three seeds of one mock (population, noise, test), drawn in that order."""
    return tuple(int(rng.integers(2**31)) for _ in range(3))


def _calibration_task(task):
    """One calibration mock: its log-likelihood (zeros without a tested pair) and its
    number of tested pairs."""
    pairs, lens, simulation, truth, seeds, kwargs = task
    ll, result = mock_log_likelihood(pairs, lens, simulation, truth, seeds, **kwargs)
    if ll is None:
        return np.zeros(simulation.sigma_sub.size), 0
    return ll, int(np.asarray(result["tested"], dtype=bool).sum())


def mock_check_kwargs(anomaly, check_kwargs):
    """The mocks' :func:`~lensdual.check_duality` settings: the geometric test for
    the geometric anomaly, the joint one (or the given test) for the joint one."""
    from ._posterior import ANOMALIES

    if anomaly not in ANOMALIES:
        raise ValueError(f"anomaly must be one of {list(ANOMALIES)}, got {anomaly!r}")
    return {**check_kwargs,
            "test": "geometric" if anomaly == "geometric" else check_kwargs.get("test", "joint")}


def calibrate_posterior(pairs, lens, simulation, *, sigma_pos, flux_rel_err, n_mocks=300,
                        seed=None, anomaly="geometric", client=None, **check_kwargs):
    r"""Mock universes that calibrate a constellation's abundance posterior.

    The likelihood of :func:`abundance_posterior` multiplies the pairs'
    likelihoods as if their errors were independent; neighbouring pairs share
    baselines, so their geometric errors are correlated and its intervals
    are too narrow. The calibration measures by how much, on mock universes
    made exactly as the data: ``n_mocks`` abundances spread over the prior
    (the midpoints of equal-probability strata of the log-uniform prior on
    the simulation's grid), one realisation of the population at each
    applied to ``pairs`` (:func:`apply_population`), position and flux
    noise, :func:`~lensdual.check_duality` and the likelihood. Where the
    posterior is calibrated, the probability integral transform of the
    truth, :math:`u = F(\sigma_{\rm true})` with :math:`F` the mock's
    posterior CDF, is uniform over the mocks. :func:`abundance_posterior`
    replaces the data's posterior CDF :math:`F` by :math:`G(F)`, with
    :math:`G` the distribution of the mocks' :math:`u` (a quantile
    recalibration): every quantile of the result then holds the truth as
    often as it says, averaged over the prior, to within the binomial
    error of ``n_mocks`` (2.7 points at 68 % with 300 mocks). Mocks without
    a tested pair are left out (the data always have one).

    Parameters
    ----------
    pairs, lens, simulation, sigma_pos, flux_rel_err
        As for :func:`composite_weight`: the constellation without measurement
        noise, its smooth lens, its :func:`simulate_anomalies` result, and
        the data's position noise per coordinate and relative flux noise per
        image and band.
    n_mocks : int, optional
        Mock universes, at least 50. Default 300. Systems combined into one
        posterior need the same number (and grid): their mocks share truths.
    seed : int, optional
        Seed of the realisations and the noise. Systems combined into one
        posterior need different seeds, or their mocks would share random
        numbers; the default, None, draws fresh entropy (kept in the
        result's ``seed``).
    anomaly : {"geometric", "joint"}
        The anomalies the posterior will read, as for
        :func:`abundance_posterior` (default ``"geometric"``).
    client : dask.distributed.Client or concurrent.futures.Executor, optional
        Runs the mocks as parallel tasks (a thread pool pays: the kernels
        release the GIL); the result is identical to a serial run.
    **check_kwargs
        Passed to :func:`~lensdual.check_duality`, as for
        :func:`composite_weight`.

    Returns
    -------
    PosteriorCalibration

    Raises
    ------
    TypeError
        ``simulation`` is not an `AnomalySimulation`.
    ValueError
        ``n_mocks`` below 50, an unknown ``anomaly``, or a grid of fewer than
        two abundances.
    """
    from .._validation import as_int

    if not isinstance(simulation, AnomalySimulation):
        raise TypeError(f"simulation must be an AnomalySimulation, got "
                        f"{type(simulation).__name__}")
    n_mocks = as_int(n_mocks, "n_mocks", minimum=MIN_CALIBRATION_MOCKS)
    check_kwargs = mock_check_kwargs(anomaly, check_kwargs)
    grid = simulation.sigma_sub.to_value(u.kpc**-2)
    if grid.size < 2:
        raise ValueError("the simulation's grid has one abundance: there is no posterior to "
                         "calibrate")
    truths = stratified_truths(np.log10(grid), n_mocks)
    entropy = int(np.random.SeedSequence(seed).entropy)
    rng = np.random.default_rng(entropy)
    kwargs = {"sigma_pos": sigma_pos, "flux_rel_err": flux_rel_err, "anomaly": anomaly,
              "check_kwargs": check_kwargs}
    tasks = [(pairs, lens, simulation, 10**t, draw_mock_seeds(rng), kwargs) for t in truths]
    results = run_tasks(_calibration_task, tasks, check_client(client))
    lls = np.array([r[0] for r in results])
    n_tested = np.array([r[1] for r in results], dtype=int)
    return PosteriorCalibration(truths, lls, simulation.sigma_sub.to(u.kpc**-2), anomaly,
                                n_tested, simulation_key(simulation), entropy)


def check_calibrations(calibrations, simulations, anomaly):
    """The calibrations as a list, one per simulation, made on that simulation (its
    grid, population, pairs and radii) for ``anomaly``, with one set of truths and
    distinct seeds."""
    if isinstance(calibrations, PosteriorCalibration):
        calibrations = [calibrations]
    calibrations = list(calibrations)
    if not all(isinstance(c, PosteriorCalibration) for c in calibrations):
        raise TypeError("calibrations must be PosteriorCalibration objects "
                        "(calibrate_posterior)")
    if len(calibrations) != len(simulations):
        raise ValueError(f"calibrations must be one per constellation: {len(calibrations)} for "
                         f"{len(simulations)}")
    grid = simulations[0].sigma_sub.to_value(u.kpc**-2)
    for k, (c, sim) in enumerate(zip(calibrations, simulations, strict=True)):
        if (c.sigma_sub.size != grid.size
                or not np.allclose(c.sigma_sub.to_value(u.kpc**-2), grid, rtol=1e-12)):
            raise ValueError("a calibration was made on another sigma_sub grid than the "
                             "simulations'")
        if c.simulation_key != simulation_key(sim):
            raise ValueError(f"calibration {k + 1} was not made on simulation {k + 1} (another "
                             "population, pairs or radius): give each constellation the "
                             "calibration of its own simulation")
        if c.anomaly != anomaly:
            raise ValueError(f"a calibration's mocks read the {c.anomaly!r} anomalies, the "
                             f"posterior the {anomaly!r} ones")
        if c.log10_truth.size != calibrations[0].log10_truth.size:
            raise ValueError("the calibrations of combined systems need the same n_mocks: "
                             "their mocks share truths")
    seeds = [c.seed for c in calibrations]
    if len(set(seeds)) != len(seeds):
        raise ValueError("calibrations of combined systems share a seed, so their mocks share "
                         "random numbers: calibrate each system with its own seed")
    return calibrations


def _cdf_and_survival(log_grid, ll):
    """A posterior's CDF and survival function on the grid (trapezoids), each summed
    from its own end so that neither tail rounds to 0 or 1 before it must."""
    p = np.exp(ll - np.nanmax(ll))
    p = np.where(np.isfinite(p), p, 0.0)
    cells = 0.5 * (p[1:] + p[:-1]) * np.diff(log_grid)
    total = cells.sum()
    cdf = np.concatenate([[0.0], np.cumsum(cells)]) / total
    sf = np.concatenate([np.cumsum(cells[::-1])[::-1], [0.0]]) / total
    return cdf, sf


def mock_pit(log_grid, calibrations, weights):
    """Each joint mock's probability integral transform (its truth's place in the
    posterior of the systems' weighted, summed log-likelihoods) over the mocks with a
    tested pair in every system and a likelihood somewhere on the grid, and the number
    of mocks left out."""
    ll = sum(w * c.log_likelihood for w, c in zip(weights, calibrations, strict=True))
    tested = np.all([c.n_tested > 0 for c in calibrations], axis=0)
    usable = tested & np.isfinite(ll).any(axis=1)
    truths = calibrations[0].log10_truth
    pit = []
    for j in np.flatnonzero(usable):
        cdf, sf = _cdf_and_survival(log_grid, ll[j])
        lower = np.interp(truths[j], log_grid, cdf)
        # the upper half from the survival function: 1 - tiny does not round to 1
        pit.append(lower if lower <= 0.5 else 1.0 - np.interp(truths[j], log_grid, sf))
    return np.array(pit), int((~usable).sum())


class Recalibration:
    """The distribution ``G`` of the mocks' PIT values and its inverse.

    A PIT of exactly 0 or 1 (the truth beyond all of a mock's posterior mass)
    is an atom at that end: ``G(0)`` is the fraction of PITs at 0, and ``G``
    reaches ``1 - b`` just below 1 with ``b`` the fraction at 1. Between the
    ends ``G`` is linear through each distinct PIT at the mean of its
    mid-ranks ``(i + 1/2) / M``.
    """

    def __init__(self, pit):
        pit = np.sort(np.asarray(pit, dtype=float))
        m = pit.size
        self.low = float(np.mean(pit <= 0.0))
        self.high = float(np.mean(pit >= 1.0))
        inner = (pit > 0.0) & (pit < 1.0)
        values, inverse = np.unique(pit[inner], return_inverse=True)
        ranks = (np.flatnonzero(inner) + 0.5) / m
        levels = np.bincount(inverse, weights=ranks) / np.maximum(np.bincount(inverse), 1)
        self.x = np.concatenate([[0.0], values, [1.0]])
        self.y = np.concatenate([[self.low], levels, [1.0 - self.high]])

    def __call__(self, cdf):
        """``G(cdf)``; 1 where ``cdf`` is 1."""
        cdf = np.asarray(cdf, dtype=float)
        return np.where(cdf >= 1.0, 1.0, np.interp(cdf, self.x, self.y))

    def inverse(self, q):
        """The uncalibrated level whose ``G`` is ``q``: 0 below the lower atom, 1 above
        the upper one."""
        if q <= self.low:
            return 0.0
        if q >= 1.0 - self.high:
            return 1.0
        return float(np.interp(q, self.y, self.x))
