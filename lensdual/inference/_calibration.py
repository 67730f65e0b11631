"""Calibration of the abundance posterior, and of the joint posterior with the half-mode
mass, by simulation (private)."""

import warnings
from dataclasses import dataclass

import numpy as np
from astropy import units as u
from astropy.utils.exceptions import AstropyDeprecationWarning

from .._parallel import check_client, run_tasks
from ..exceptions import EstimatorWarning
from ._forward import AnomalySimulation

__all__ = ["PosteriorCalibration", "calibrate_posterior", "MIN_CALIBRATION_MOCKS"]

#: The fewest mocks a calibration is made of, and used with: the binomial error
#: of a 68 % interval's coverage is then 6.6 points.
MIN_CALIBRATION_MOCKS = 50


@dataclass(frozen=True, eq=False)
class PosteriorCalibration:
    """The mock universes that calibrate one constellation's abundance posterior, or
    its joint posterior with the half-mode mass.

    Made by :func:`calibrate_posterior`; passed to
    :func:`abundance_posterior` or :func:`half_mode_posterior`
    (``calibrations=``). Every parameter is also an attribute.

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
        population, pair ids and disc radii (a tuple of these, one per
        half-mode mass, for the half-mode posterior).
    seed : int
        The entropy of the mocks' random numbers.
    log10_mhm_truth : ndarray (M,), optional
        For :func:`half_mode_posterior`: each mock's true ``log10`` half-mode
        mass, also stratified (a Latin hypercube with ``log10_truth``, the
        same for every constellation); None for the abundance posterior.
    log10_mhm : ndarray (K,), optional
        The half-mode masses of the simulations, increasing; then
        ``log_likelihood`` is (M, K, S).
    """

    log10_truth: np.ndarray
    log_likelihood: np.ndarray
    sigma_sub: u.Quantity
    anomaly: str
    n_tested: np.ndarray
    simulation_key: tuple
    seed: int
    log10_mhm_truth: np.ndarray | None = None
    log10_mhm: np.ndarray | None = None

    @property
    def half_mode(self):
        """Whether the mocks calibrate the joint posterior with the half-mode mass."""
        return self.log10_mhm is not None

    def __repr__(self):
        masses = (f" x {self.log10_mhm.size} half-mode masses" if self.half_mode else "")
        return (f"<PosteriorCalibration: {self.log10_truth.size} mocks on "
                f"{self.sigma_sub.size} abundances{masses}, anomaly={self.anomaly!r}>")


def simulation_key(simulation):
    """The population's settings, pair ids and disc radii of an `AnomalySimulation`."""
    pop = simulation.population
    return (None if pop is None else pop._settings(),
            tuple(int(p) for p in simulation.pair_id),
            tuple(float(r) for r in np.ravel(simulation.radius)))


def stratified_truths(log_grid, n):
    """The midpoints of ``n`` equal-probability strata of the log-uniform prior."""
    return log_grid[0] + (np.arange(n) + 0.5) / n * (log_grid[-1] - log_grid[0])


def latin_hypercube_partner(log_grid, n):
    """The second coordinate of ``n`` stratified truths: the midpoints of ``n``
    strata of ``log_grid``'s range, the k-th mock's stratum the rank of
    ``frac((k + 1/2) phi)`` (phi the golden ratio), so that each coordinate fills
    its prior evenly and the pairs spread over the plane, the same for every
    call."""
    ranks = np.argsort(np.argsort(np.modf((np.arange(n) + 0.5) * _GOLDEN)[0]))
    return stratified_truths(log_grid, n)[ranks]


_GOLDEN = (1 + np.sqrt(5)) / 2


def population_at(population, log_mhm):
    """``population`` with the half-mode mass ``log_mhm`` (its other settings kept)."""
    from ._population import SubhaloPopulation

    return SubhaloPopulation(**{**population._arguments(), "model": "WDM",
                                "log_mhm": float(log_mhm)})


def mock_log_likelihood(pairs, lens, simulation, truth, seeds, *, sigma_pos, flux_rel_err,
                        anomaly, check_kwargs, log_mhm=None):
    """One mock universe at abundance ``truth`` (kpc^-2): its log-likelihood on the
    simulation's grid (None without a tested pair) and its duality table; ``seeds``
    are those of the population's realisation, the noise and the test. With
    ``simulation`` a list (one per half-mode mass) the population is that of its
    first entry at half-mode mass ``log_mhm`` and the log-likelihood is (K, S)."""
    from .. import check_duality
    from ..simulation import noisy_constellation
    from ._forward import _apply_population
    from ._posterior import _system_log_likelihood

    seed_population, seed_noise, seed_test = (int(x) for x in seeds)
    sims = simulation if isinstance(simulation, list) else [simulation]
    population = (sims[0].population if log_mhm is None
                  else population_at(sims[0].population, log_mhm))
    mock = _apply_population(pairs, lens, population, truth, sims[0].radius, seed_population)
    noisy = noisy_constellation(mock, sigma_pos=sigma_pos, flux_rel_err=flux_rel_err,
                                seed=seed_noise)
    with warnings.catch_warnings():
        # a mock's untestable pairs are part of what the mocks measure
        warnings.simplefilter("ignore", EstimatorWarning)
        result = check_duality(noisy, sigma_pos=sigma_pos, seed=seed_test, **check_kwargs)
    if not np.asarray(result["tested"], dtype=bool).any():
        return None, result
    lls = [_system_log_likelihood(result, s, anomaly)[0] for s in sims]
    return (np.array(lls) if isinstance(simulation, list) else lls[0]), result


def draw_mock_seeds(rng):
    """The three seeds of one mock (population, noise, test), drawn in that order."""
    return tuple(int(rng.integers(2**31)) for _ in range(3))


def _calibration_task(task):
    """One calibration mock: its log-likelihood (zeros without a tested pair) and its
    number of tested pairs."""
    pairs, lens, simulation, truth, log_mhm, seeds, kwargs = task
    ll, result = mock_log_likelihood(pairs, lens, simulation, truth, seeds, log_mhm=log_mhm,
                                     **kwargs)
    if ll is None:
        shape = ((len(simulation), simulation[0].sigma_sub.size) if log_mhm is not None
                 else simulation.sigma_sub.size)
        return np.zeros(shape), 0
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

    Given the simulations of one constellation for several WDM half-mode
    masses (as :func:`half_mode_posterior` takes them), the mocks calibrate
    the joint posterior's two marginals: each mock has a true abundance and
    a true half-mode mass (stratified in both, paired as a Latin hypercube;
    the population at that mass, between the grid's masses too), and
    :func:`half_mode_posterior` recalibrates each marginal on its own
    PITs.

    Parameters
    ----------
    pairs, lens, sigma_pos, flux_rel_err
        As for :func:`composite_weight`: the constellation without measurement
        noise, its smooth lens, and the data's position noise per coordinate
        and relative flux noise per image and band.
    simulation : AnomalySimulation or list of AnomalySimulation
        The constellation's :func:`simulate_anomalies` result; or, for the
        half-mode posterior, one per half-mode mass (WDM populations that
        differ only in ``log_mhm``, on one grid, pairs and radius).
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
        ``simulation`` is not an `AnomalySimulation` (or a list of them).
    ValueError
        ``n_mocks`` below 50, an unknown ``anomaly``, a grid of fewer than
        two abundances, or half-mode simulations that are not WDM, repeat a
        mass, or differ in anything but the mass.
    """
    from .._validation import as_int

    sims, log_mhm = _calibrated_simulations(simulation)
    n_mocks = as_int(n_mocks, "n_mocks", minimum=MIN_CALIBRATION_MOCKS)
    check_kwargs = mock_check_kwargs(anomaly, check_kwargs)
    grid = sims[0].sigma_sub.to_value(u.kpc**-2)
    if grid.size < 2:
        raise ValueError("the simulation's grid has one abundance: there is no posterior to "
                         "calibrate")
    truths = stratified_truths(np.log10(grid), n_mocks)
    mhm_truths = (None if log_mhm is None else latin_hypercube_partner(log_mhm, n_mocks))
    entropy = int(np.random.SeedSequence(seed).entropy)
    rng = np.random.default_rng(entropy)
    kwargs = {"sigma_pos": sigma_pos, "flux_rel_err": flux_rel_err, "anomaly": anomaly,
              "check_kwargs": check_kwargs}
    target = sims[0] if log_mhm is None else sims
    tasks = [(pairs, lens, target, 10**t, None if mhm_truths is None else float(mhm_truths[k]),
              draw_mock_seeds(rng), kwargs) for k, t in enumerate(truths)]
    results = run_tasks(_calibration_task, tasks, check_client(client),
                        ignore=(EstimatorWarning, AstropyDeprecationWarning))
    lls = np.array([r[0] for r in results])
    n_tested = np.array([r[1] for r in results], dtype=int)
    key = (simulation_key(sims[0]) if log_mhm is None
           else tuple(simulation_key(s) for s in sims))
    return PosteriorCalibration(truths, lls, sims[0].sigma_sub.to(u.kpc**-2), anomaly,
                                n_tested, key, entropy, mhm_truths, log_mhm)


def _calibrated_simulations(simulation):
    """The simulations of a calibration as a list (sorted by half-mode mass) and the
    masses (None for a single simulation), checked."""
    if isinstance(simulation, AnomalySimulation):
        return [simulation], None
    sims = list(simulation) if isinstance(simulation, (list, tuple)) else None
    if not sims or not all(isinstance(s, AnomalySimulation) for s in sims):
        raise TypeError(f"simulation must be an AnomalySimulation, or a list of them (one per "
                        f"half-mode mass), got {type(simulation).__name__}")
    if len(sims) < 2:
        raise ValueError("a half-mode calibration needs the simulations of at least two "
                         "half-mode masses")
    if any(s.population is None or s.population.model != "WDM" for s in sims):
        raise ValueError("the simulations of a half-mode calibration must be of WDM "
                         "populations (model='WDM', log_mhm=...)")
    masses = np.array([s.population.log_mhm for s in sims], dtype=float)
    if np.unique(masses).size != masses.size:
        raise ValueError(f"each half-mode mass once, got log_mhm {masses.tolist()}")
    order = np.argsort(masses)
    sims = [sims[k] for k in order]

    def rest(s):
        # every setting but log_mhm, the pairs, radii and grid
        return (s.population._settings(leave_out=("log_mhm",)), *simulation_key(s)[1:],
                s.sigma_sub.to_value(u.kpc**-2).tobytes())

    if len({rest(s) for s in sims}) != 1:
        raise ValueError("the half-mode simulations must differ only in log_mhm (one grid, "
                         "pairs, radius and population otherwise)")
    return sims, masses[order]


def check_calibrations(calibrations, simulations, anomaly):
    """The calibrations as a list, one per system, each made on that system's
    simulation (its grid, population, pairs and radii; for the half-mode posterior
    the list of its simulations, one per half-mode mass, increasing) for ``anomaly``,
    with one set of truths and distinct seeds."""
    if isinstance(calibrations, PosteriorCalibration):
        calibrations = [calibrations]
    calibrations = list(calibrations)
    if not all(isinstance(c, PosteriorCalibration) for c in calibrations):
        raise TypeError("calibrations must be PosteriorCalibration objects "
                        "(calibrate_posterior)")
    if len(calibrations) != len(simulations):
        raise ValueError(f"calibrations must be one per constellation: {len(calibrations)} for "
                         f"{len(simulations)}")
    half_mode = isinstance(simulations[0], list)
    first = simulations[0][0] if half_mode else simulations[0]
    grid = first.sigma_sub.to_value(u.kpc**-2)
    for k, (c, sim) in enumerate(zip(calibrations, simulations, strict=True)):
        if c.half_mode != half_mode:
            raise ValueError(
                f"calibration {k + 1} was made for the "
                f"{'half-mode' if c.half_mode else 'abundance'} posterior: calibrate with "
                + ("the simulations of every half-mode mass" if half_mode
                   else "the abundance's one simulation"))
        if (c.sigma_sub.size != grid.size
                or not np.allclose(c.sigma_sub.to_value(u.kpc**-2), grid, rtol=1e-12)):
            raise ValueError("a calibration was made on another sigma_sub grid than the "
                             "simulations'")
        key = tuple(simulation_key(s) for s in sim) if half_mode else simulation_key(sim)
        if c.simulation_key != key:
            raise ValueError(f"calibration {k + 1} was not made on simulation {k + 1} (another "
                             "population, pairs, radius or half-mode masses): give each "
                             "constellation the calibration of its own simulation")
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


def _cdf_and_survival(log_grid, p):
    """The CDF and survival function of the density ``p`` (not normalised, NaN read
    as 0) on the grid (trapezoids), each summed from its own end so that neither
    tail rounds to 0 or 1 before it must."""
    p = np.where(np.isfinite(p), p, 0.0)
    cells = 0.5 * (p[1:] + p[:-1]) * np.diff(log_grid)
    total = cells.sum()
    cdf = np.concatenate([[0.0], np.cumsum(cells)]) / total
    sf = np.concatenate([np.cumsum(cells[::-1])[::-1], [0.0]]) / total
    return cdf, sf


def _pit(log_grid, p, truth):
    """The truth's probability integral transform under the density ``p`` on the grid;
    the upper half from the survival function, so that 1 - tiny does not round to 1."""
    cdf, sf = _cdf_and_survival(log_grid, p)
    lower = np.interp(truth, log_grid, cdf)
    return lower if lower <= 0.5 else 1.0 - np.interp(truth, log_grid, sf)


def mock_pit(log_grid, calibrations, weights):
    """Each joint mock's probability integral transform (its truth's place in the
    posterior of the systems' weighted, summed log-likelihoods) over the mocks with a
    tested pair in every system and a likelihood somewhere on the grid, and the number
    of mocks left out. For half-mode calibrations the PITs are (n, 2): those of the
    abundance's and of the half-mode mass's marginal."""
    ll = sum(w * c.log_likelihood for w, c in zip(weights, calibrations, strict=True))
    tested = np.all([c.n_tested > 0 for c in calibrations], axis=0)
    usable = tested & np.isfinite(ll).reshape(ll.shape[0], -1).any(axis=1)
    first = calibrations[0]
    pit = []
    for j in np.flatnonzero(usable):
        with np.errstate(invalid="ignore"):
            p = np.exp(ll[j] - np.nanmax(ll[j]))
        if not first.half_mode:
            pit.append(_pit(log_grid, p, first.log10_truth[j]))
            continue
        p = np.where(np.isfinite(p), p, 0.0)
        log_m = first.log10_mhm
        pit.append((_pit(log_grid, np.trapezoid(p, log_m, axis=0), first.log10_truth[j]),
                    _pit(log_m, np.trapezoid(p, log_grid, axis=1), first.log10_mhm_truth[j])))
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
