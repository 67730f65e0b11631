"""lensdual.inference: the abundance posterior recalibrated on mock universes."""

import warnings
from dataclasses import replace

import numpy as np
import pytest
from astropy import units as u
from scipy import stats

pytest.importorskip("pyHalo")

from lensdual import check_duality  # noqa: E402
from lensdual.exceptions import EstimatorWarning  # noqa: E402
from lensdual.inference import (  # noqa: E402
    MIN_REALISATIONS,
    PosteriorCalibration,
    SubhaloPopulation,
    abundance_posterior,
    apply_population,
    calibrate_posterior,
    half_mode_posterior,
    simulate_anomalies,
)
from lensdual.inference._calibration import (  # noqa: E402
    Recalibration,
    latin_hypercube_partner,
    mock_pit,
    stratified_truths,
)
from lensdual.simulation import noisy_constellation  # noqa: E402
from lensdual.simulation.families import calibration_system, clean_constellation  # noqa: E402

KPC2 = u.kpc**-2
SIGMA_POS = 5 * u.mas


def _reference(log_grid, cdf, truths, mock_lls, level=0.5):
    """The recalibrated CDF and the quantile ``level`` in plain numpy: each mock's
    posterior CDF on the grid (trapezoids; its upper tail summed from the top), its
    truth's PIT, and their empirical CDF with atoms at 0 and 1, linear between the
    mid-ranks of the distinct PITs (no ties between them here); the quantile
    through the uncalibrated CDF."""
    u = []
    for ll, t in zip(mock_lls, truths, strict=True):
        p = np.exp(ll - ll.max())
        cells = (p[1:] + p[:-1]) / 2 * np.diff(log_grid)
        up = np.concatenate([[0.0], np.cumsum(cells)]) / cells.sum()
        down = np.concatenate([np.cumsum(cells[::-1])[::-1], [0.0]]) / cells.sum()
        lower = np.interp(t, log_grid, up)
        u.append(lower if lower <= 0.5 else 1 - np.interp(t, log_grid, down))
    u = np.sort(u)
    m = u.size
    n0, n1 = int(np.sum(u <= 0)), int(np.sum(u >= 1))
    inner = u[(u > 0) & (u < 1)]
    x = np.concatenate([[0.0], inner, [1.0]])
    y = np.concatenate([[n0 / m], (n0 + np.arange(inner.size) + 0.5) / m, [1 - n1 / m]])
    g = np.where(cdf >= 1, 1.0, np.interp(cdf, x, y))
    quantile = np.interp(np.interp(level, y, x), cdf, log_grid)
    return g, quantile


def _calibration(truths, lls, log_grid, n_tested=None, seed=0):
    n = truths.size
    return PosteriorCalibration(truths, lls, 10**log_grid * KPC2, "geometric",
                                np.ones(n, int) if n_tested is None else n_tested, (), seed)


def _gaussian_calibration(log_grid, n, k, s, rng):
    """Mocks whose Gaussian likelihood (width s) is centred a N(0, (k s)^2) draw off
    their truth: the uncalibrated posterior is k times too narrow."""
    truths = stratified_truths(log_grid, n)
    centres = truths + k * s * rng.standard_normal(n)
    return _calibration(truths, -0.5 * ((log_grid[None, :] - centres[:, None]) / s) ** 2,
                        log_grid)


# ------------------------------------------------------------------ closed forms


@pytest.mark.parametrize("k", [0.6, 1.0, 1.7])
def test_recalibration_of_gaussian_pit_is_the_closed_form(k):
    """PITs Phi(k z), z standard normal: G(x) = Phi(Phi^-1(x) / k)."""
    z = stats.norm.ppf((np.arange(20000) + 0.5) / 20000)
    pit = stats.norm.cdf(k * z)
    x = np.linspace(0.01, 0.99, 99)
    np.testing.assert_allclose(Recalibration(pit)(x), stats.norm.cdf(stats.norm.ppf(x) / k),
                               atol=2e-4)


def test_recalibration_handles_ties_and_ends():
    """PITs of exactly 0 and 1 are atoms at the ends: G(0) is the fraction at 0, G
    reaches 1 - (the fraction at 1) just below 1; ties inside share their mid-rank."""
    g = Recalibration(np.array([0.0, 0.0, 0.3, 0.3, 0.3, 1.0]))
    assert (g.low, g.high) == (pytest.approx(1 / 3), pytest.approx(1 / 6))
    # 0.3 at mid-ranks 2.5/6, 3.5/6, 4.5/6: mean 7/12
    np.testing.assert_allclose(g(np.array([0.0, 0.15, 0.3, 0.65, 0.999999, 1.0])),
                               [1 / 3, 11 / 24, 7 / 12, 17 / 24, 5 / 6, 1.0], atol=1e-6)
    assert g.inverse(0.2) == 0.0 and g.inverse(0.9) == 1.0
    assert g.inverse(7 / 12) == pytest.approx(0.3)
    assert np.all(np.diff(g(np.linspace(0, 1, 101))) >= 0)


def test_pit_tails_are_symmetric():
    """Two mocks mirrored about a narrow posterior's centre: PITs u and 1 - u, the
    upper one not rounded to 1 (summed from the top)."""
    log_grid = np.linspace(-3, -0.5, 301)
    ll = -0.5 * ((log_grid - (-1.75)) / 0.03) ** 2
    cal = _calibration(np.array([-1.75 - 0.2, -1.75 + 0.2]), np.vstack([ll, ll]), log_grid)
    pit, left_out = mock_pit(log_grid, [cal], [1.0])
    assert left_out == 0
    assert 0 < pit[0] < 1e-10 and 0 < 1 - pit[1] < 1e-10
    assert pit[0] == pytest.approx(1 - pit[1], rel=1e-6)


def test_mocks_without_a_test_or_a_likelihood_are_left_out():
    log_grid = np.linspace(-3, -0.5, 31)
    truths = stratified_truths(log_grid, 6)
    lls = -0.5 * ((log_grid[None, :] - truths[:, None]) / 0.3) ** 2
    lls[1] = -np.inf
    lls[2, ::2] = np.nan
    one = _calibration(truths, lls, log_grid, np.array([3, 3, 3, 0, 3, 3]), seed=1)
    other = _calibration(truths, np.zeros_like(lls), log_grid, np.array([3, 3, 3, 3, 3, 0]),
                         seed=2)
    pit, left_out = mock_pit(log_grid, [one], [1.0])
    assert left_out == 2 and pit.size == 4 and np.isfinite(pit).all()
    pit, left_out = mock_pit(log_grid, [one, other], [1.0, 1.0])
    assert left_out == 3 and pit.size == 3


def test_widened_gaussian_posterior_holds_on_fresh_universes():
    """Mock likelihoods 1.8 times too narrow: uncalibrated 68 % intervals hold about
    42 % of fresh truths, recalibrated ones 68 %, and the calibrated interval of a
    posterior far from the prior's ends is 1.8 times wider."""
    rng = np.random.default_rng(1)
    log_grid = np.linspace(-3, -0.5, 401)
    s, k = 0.08, 1.8
    cal = _gaussian_calibration(log_grid, 2000, k, s, rng)
    pit, _ = mock_pit(log_grid, [cal], [1.0])
    covered = {"raw": [], "calibrated": []}
    for t in rng.uniform(-2.6, -0.9, 1500):
        ll = -0.5 * ((log_grid - (t + k * s * rng.standard_normal())) / s) ** 2
        p = np.exp(ll - ll.max())
        cdf = np.concatenate([[0.0], np.cumsum((p[1:] + p[:-1]) / 2 * np.diff(log_grid))])
        cdf /= cdf[-1]
        for key, c in (("raw", cdf), ("calibrated", Recalibration(pit)(cdf))):
            lo, hi = np.interp([0.16, 0.84], c, log_grid)
            covered[key].append(lo <= t <= hi)
    assert np.mean(covered["raw"]) == pytest.approx(2 * stats.norm.cdf(1 / k) - 1, abs=0.04)
    assert np.mean(covered["calibrated"]) == pytest.approx(0.68, abs=0.035)
    centre = -1.7
    ll = -0.5 * ((log_grid - centre) / s) ** 2
    p = np.exp(ll)
    cdf = np.concatenate([[0.0], np.cumsum((p[1:] + p[:-1]) / 2 * np.diff(log_grid))])
    lo, hi = np.interp([0.16, 0.84], Recalibration(pit)(cdf / cdf[-1]), log_grid)
    assert (hi - lo) / 2 == pytest.approx(k * s, rel=0.06)


def test_stratified_truths_fill_the_prior_evenly():
    t = stratified_truths(np.log10([1e-3, 1e-2, 0.3]), 4)
    span = np.log10(0.3) + 3
    np.testing.assert_allclose(t, -3 + span * np.array([0.125, 0.375, 0.625, 0.875]))


# ------------------------------------------------------------------ the pipeline


@pytest.fixture(scope="module")
def setup():
    system, info = calibration_system("smacs_analog")
    pairs = clean_constellation("smacs_analog", 8, seed=3)
    pop = SubhaloPopulation(info["z_lens"], info["z_source"])
    sim = simulate_anomalies(pairs, system, pop, np.geomspace(0.002, 0.2, 6) * KPC2,
                             n_realisations=MIN_REALISATIONS, seed=2)
    cal = calibrate_posterior(pairs, system, sim, sigma_pos=SIGMA_POS, flux_rel_err=0.02,
                              n_mocks=50, seed=4)
    return system, pairs, pop, sim, cal


def _data(system, pairs, pop, sigma, seed):
    mock = apply_population(pairs, system, pop, sigma * KPC2, seed=seed)
    noisy = noisy_constellation(mock, sigma_pos=SIGMA_POS, flux_rel_err=0.02, seed=seed + 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EstimatorWarning)
        return check_duality(noisy, sigma_pos=SIGMA_POS, seed=0)


def test_calibration_mocks_are_made_as_the_data(setup):
    """The first mock, remade by hand from the calibration's seed: the same
    population draw, noise and test give the same log-likelihood."""
    system, pairs, pop, sim, cal = setup
    assert repr(cal).startswith("<PosteriorCalibration: 50 mocks on 6 abundances")
    grid = np.log10(sim.sigma_sub.to_value(KPC2))
    np.testing.assert_allclose(cal.log10_truth, stratified_truths(grid, 50))
    rng = np.random.default_rng(4)
    mock = apply_population(pairs, system, pop, 10 ** cal.log10_truth[0] * KPC2,
                            seed=int(rng.integers(2**31)))
    noisy = noisy_constellation(mock, sigma_pos=SIGMA_POS, flux_rel_err=0.02,
                                seed=int(rng.integers(2**31)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EstimatorWarning)
        result = check_duality(noisy, sigma_pos=SIGMA_POS, seed=int(rng.integers(2**31)),
                               test="geometric")
    expected = abundance_posterior(result, sim)["log_likelihood"]
    np.testing.assert_allclose(cal.log_likelihood[0], expected, rtol=1e-12)
    assert cal.n_tested[0] == int(np.sum(result["tested"]))
    again = calibrate_posterior(pairs, system, sim, sigma_pos=SIGMA_POS, flux_rel_err=0.02,
                                n_mocks=50, seed=4)
    np.testing.assert_array_equal(again.log_likelihood, cal.log_likelihood)


def test_calibrated_posterior_matches_the_plain_reference(setup):
    system, pairs, pop, sim, cal = setup
    data = _data(system, pairs, pop, 0.05, 30)
    raw = abundance_posterior(data, sim)
    post = abundance_posterior(data, sim, calibrations=cal)
    log_grid = np.asarray(post["log10_sigma_sub"])
    np.testing.assert_allclose(post["cdf_uncalibrated"], raw["cdf"])
    np.testing.assert_allclose(post["log_likelihood"], raw["log_likelihood"])
    used = cal.n_tested > 0
    ref, median = _reference(log_grid, np.asarray(raw["cdf"]), cal.log10_truth[used],
                             cal.log_likelihood[used])
    np.testing.assert_allclose(post["cdf"], ref, atol=1e-12)
    np.testing.assert_allclose(post["posterior"], np.gradient(ref, log_grid), atol=1e-12)
    m = post.meta["inference"]
    assert m["calibrated"] and not raw.meta["inference"]["calibrated"]
    assert m["n_mocks"] == used.sum() and m["n_mocks_left_out"] == (~used).sum()
    assert 0 <= m["mock_coverage_uncalibrated"]["68"] <= m["mock_coverage_uncalibrated"]["95"]
    assert np.log10(m["median"].to_value(KPC2)) == pytest.approx(median)
    for key, (lo, hi) in (("interval_68", (0.16, 0.84)), ("interval_95", (0.025, 0.975))):
        expected = [_reference(log_grid, np.asarray(raw["cdf"]), cal.log10_truth[used],
                               cal.log_likelihood[used], level)[1] for level in (lo, hi)]
        np.testing.assert_allclose(np.log10(m[key].to_value(KPC2)), expected)


def test_systems_combine_mock_by_mock(setup):
    """Two systems: the joint mocks are the sums of the systems' mocks of the same
    truth, weighted by the systems' weights."""
    system, pairs, pop, sim, cal = setup
    other = calibrate_posterior(pairs, system, sim, sigma_pos=SIGMA_POS, flux_rel_err=0.02,
                                n_mocks=50, seed=5)
    d1, d2 = _data(system, pairs, pop, 0.02, 40), _data(system, pairs, pop, 0.02, 50)
    post = abundance_posterior([d1, d2], [sim, sim], calibrations=[cal, other],
                               weights=[1.0, 0.5])
    raw = abundance_posterior([d1, d2], [sim, sim], weights=[1.0, 0.5])
    log_grid = np.asarray(post["log10_sigma_sub"])
    used = (cal.n_tested > 0) & (other.n_tested > 0)
    ref, _ = _reference(log_grid, np.asarray(raw["cdf"]), cal.log10_truth[used],
                        (cal.log_likelihood + 0.5 * other.log_likelihood)[used])
    np.testing.assert_allclose(post["cdf"], ref, atol=1e-12)


def test_calibration_bad_input(setup):
    system, pairs, pop, sim, cal = setup
    data = _data(system, pairs, pop, 0.05, 60)
    kw = {"sigma_pos": SIGMA_POS, "flux_rel_err": 0.02}
    with pytest.raises(ValueError, match="n_mocks"):
        calibrate_posterior(pairs, system, sim, n_mocks=20, **kw)
    with pytest.raises(TypeError, match="AnomalySimulation"):
        calibrate_posterior(pairs, system, "sim", **kw)
    with pytest.raises(ValueError, match="anomaly must be one of"):
        calibrate_posterior(pairs, system, sim, anomaly="other", **kw)
    with pytest.raises(TypeError, match="PosteriorCalibration"):
        abundance_posterior(data, sim, calibrations=["x"])
    with pytest.raises(ValueError, match="one per constellation"):
        abundance_posterior(data, sim, calibrations=[cal, cal])
    coarse = replace(cal, log_likelihood=cal.log_likelihood[:, :5], sigma_sub=cal.sigma_sub[:5])
    with pytest.raises(ValueError, match="another sigma_sub grid"):
        abundance_posterior(data, sim, calibrations=coarse)
    with pytest.raises(ValueError, match="read the 'joint' anomalies"):
        abundance_posterior(data, sim, calibrations=replace(cal, anomaly="joint"))
    fewer = replace(cal, log10_truth=cal.log10_truth[:40], log_likelihood=cal.log_likelihood[:40],
                    n_tested=cal.n_tested[:40], seed=99)
    with pytest.raises(ValueError, match="same n_mocks"):
        abundance_posterior([data, data], [sim, sim], calibrations=[cal, fewer])
    with pytest.raises(ValueError, match="share a seed"):
        abundance_posterior([data, data], [sim, sim], calibrations=[cal, cal])
    # a calibration of another simulation: another population
    wdm = SubhaloPopulation(pop.z_lens, pop.z_source, model="WDM", log_mhm=8)
    sim_wdm = simulate_anomalies(pairs, system, wdm, sim.sigma_sub,
                                 n_realisations=MIN_REALISATIONS, seed=2)
    with pytest.raises(ValueError, match="was not made on simulation 1"):
        abundance_posterior(data, sim_wdm, calibrations=cal)
    # too few mocks with a tested pair
    with pytest.raises(ValueError, match="mocks have a tested pair"):
        abundance_posterior(data, sim, calibrations=replace(
            cal, n_tested=np.where(np.arange(cal.n_tested.size) < 10, 0, cal.n_tested)))


def test_threaded_calibration_is_serial(setup):
    from concurrent.futures import ThreadPoolExecutor

    system, pairs, pop, sim, cal = setup
    with ThreadPoolExecutor(2) as pool:
        threaded = calibrate_posterior(pairs, system, sim, sigma_pos=SIGMA_POS,
                                       flux_rel_err=0.02, n_mocks=50, seed=4, client=pool)
    np.testing.assert_array_equal(threaded.log_likelihood, cal.log_likelihood)
    np.testing.assert_array_equal(threaded.n_tested, cal.n_tested)
    with pytest.raises(TypeError, match="client must be"):
        calibrate_posterior(pairs, system, sim, sigma_pos=SIGMA_POS, flux_rel_err=0.02,
                            n_mocks=50, client="pool")


def test_default_seed_is_fresh_entropy(setup):
    system, pairs, pop, sim, cal = setup
    kw = {"sigma_pos": SIGMA_POS, "flux_rel_err": 0.02, "n_mocks": 50}
    a = calibrate_posterior(pairs, system, sim, **kw)
    b = calibrate_posterior(pairs, system, sim, **kw)
    assert a.seed != b.seed
    assert not np.array_equal(a.log_likelihood, b.log_likelihood)
    again = calibrate_posterior(pairs, system, sim, seed=a.seed, **kw)
    np.testing.assert_array_equal(again.log_likelihood, a.log_likelihood)


# ------------------------------------------------------------------ the half-mode mass


def test_latin_hypercube_partner_is_stratified_and_spread():
    log_m = np.array([5.0, 7.0, 10.0])
    m = latin_hypercube_partner(log_m, 40)
    np.testing.assert_allclose(np.sort(m), stratified_truths(log_m, 40))
    np.testing.assert_array_equal(m, latin_hypercube_partner(log_m, 40))
    # every quarter of the abundance's strata holds mocks of every quarter of the masses
    s_quarter = np.arange(40) // 10
    m_quarter = np.floor((m - 5.0) / 5.0 * 4).astype(int)
    counts = np.zeros((4, 4), int)
    np.add.at(counts, (s_quarter, m_quarter), 1)
    assert counts.min() >= 1


#: The half-mode tests' population settings, none of them the default.
WDM_SETTINGS = {"model": "WDM", "log_m_host": 14.6, "shmf_log_slope": -1.85,
                "host_scaling_factor": 0.6, "host_centre": (0.3, -0.2) * u.arcsec}
#: Three unevenly spaced half-mode masses, given out of order.
MASSES = (9.0, 6.0, 7.0)


@pytest.fixture(scope="module")
def half_mode_setup(setup):
    system, pairs, pop, sim, cal = setup
    sims = [simulate_anomalies(pairs, system, SubhaloPopulation(
        pop.z_lens, pop.z_source, log_mhm=m, **WDM_SETTINGS), sim.sigma_sub,
        n_realisations=MIN_REALISATIONS, seed=2) for m in MASSES]
    hm = calibrate_posterior(pairs, system, sims, sigma_pos=SIGMA_POS, flux_rel_err=0.02,
                             n_mocks=60, seed=8)
    return system, pairs, pop, sims, hm


def test_half_mode_mocks_are_made_as_the_data(half_mode_setup):
    """A half-mode mock, remade by hand: the population at its true half-mode mass,
    its noise and test, scored on both masses' simulations (lightest first)."""
    system, pairs, pop, sims, hm = half_mode_setup
    assert repr(hm).startswith("<PosteriorCalibration: 60 mocks on 6 abundances x 3 half-mode")
    np.testing.assert_array_equal(hm.log10_mhm, [6.0, 7.0, 9.0])
    assert hm.log_likelihood.shape == (60, 3, 6)
    np.testing.assert_allclose(np.sort(hm.log10_mhm_truth), stratified_truths([6.0, 9.0], 60))
    rng = np.random.default_rng(8)
    seeds = [tuple(int(rng.integers(2**31)) for _ in range(3)) for _ in range(3)]
    j = 2
    wdm = SubhaloPopulation(pop.z_lens, pop.z_source, log_mhm=hm.log10_mhm_truth[j],
                            **WDM_SETTINGS)
    mock = apply_population(pairs, system, wdm, 10 ** hm.log10_truth[j] * KPC2,
                            seed=seeds[j][0])
    noisy = noisy_constellation(mock, sigma_pos=SIGMA_POS, flux_rel_err=0.02, seed=seeds[j][1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EstimatorWarning)
        result = check_duality(noisy, sigma_pos=SIGMA_POS, seed=seeds[j][2], test="geometric")
    for k, s in enumerate(sorted(sims, key=lambda s: s.population.log_mhm)):
        np.testing.assert_allclose(hm.log_likelihood[j, k],
                                   abundance_posterior(result, s)["log_likelihood"], rtol=1e-12)


def _marginal_pits(log_s, log_m, lls, truth_s, truth_m):
    """Each mock's two marginal PITs in plain numpy (trapezoids; upper tails summed
    from the top), from its joint log-likelihood on the (mass, abundance) grid."""
    out = []
    for ll, ts, tm in zip(lls, truth_s, truth_m, strict=True):
        p = np.exp(ll - ll.max())
        row = []
        for grid, dens, t in ((log_s, np.trapezoid(p, log_m, axis=0), ts),
                              (log_m, np.trapezoid(p, log_s, axis=1), tm)):
            cells = (dens[1:] + dens[:-1]) / 2 * np.diff(grid)
            up = np.concatenate([[0.0], np.cumsum(cells)]) / cells.sum()
            down = np.concatenate([np.cumsum(cells[::-1])[::-1], [0.0]]) / cells.sum()
            lower = np.interp(t, grid, up)
            row.append(lower if lower <= 0.5 else 1 - np.interp(t, grid, down))
        out.append(row)
    return np.array(out)


def test_calibrated_half_mode_marginals_match_the_plain_reference(half_mode_setup):
    system, pairs, pop, sims, hm = half_mode_setup
    data = _data(system, pairs, SubhaloPopulation(pop.z_lens, pop.z_source, log_mhm=7.5,
                                                  **WDM_SETTINGS), 0.05, 70)
    raw = half_mode_posterior(data, sims)
    post = half_mode_posterior(data, sims, calibrations=hm)
    np.testing.assert_array_equal(post["posterior"], raw["posterior"])
    m, r = post.meta["inference"], raw.meta["inference"]
    assert m["calibrated"] and not r["calibrated"]
    log_s = np.log10(sims[0].sigma_sub.to_value(KPC2))
    log_m = np.array([6.0, 7.0, 9.0])
    used = hm.n_tested > 0
    pits = _marginal_pits(log_s, log_m, hm.log_likelihood[used], hm.log10_truth[used],
                          hm.log10_mhm_truth[used])
    assert m["n_mocks"] == used.sum() and m["n_mocks_left_out"] == (~used).sum()
    for col, grid, marginal, prefix, unit in ((0, log_s, "marginal_sigma_sub", "", True),
                                              (1, log_m, "marginal_log10_mhm", "log10_mhm_",
                                               False)):
        dens = np.asarray(r[marginal])
        np.testing.assert_allclose(m[marginal + "_uncalibrated"], dens)
        cdf = np.concatenate([[0.0], np.cumsum((dens[1:] + dens[:-1]) / 2 * np.diff(grid))])
        cdf /= cdf[-1]
        g = Recalibration(pits[:, col])
        np.testing.assert_allclose(m[marginal], np.gradient(g(cdf), grid), atol=1e-12)
        cov = m[prefix + "mock_coverage_uncalibrated"]["68"]
        assert cov == pytest.approx(np.mean((pits[:, col] >= 0.16) & (pits[:, col] <= 0.84)))
        for key, levels in (("interval_68", (0.16, 0.84)), ("interval_95", (0.025, 0.975))):
            expected = [np.interp(g.inverse(q), cdf, grid) for q in levels]
            got = (np.log10(m[key].to_value(KPC2)) if unit else m[prefix + key])
            np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_half_mode_calibration_bad_input(setup, half_mode_setup):
    system, pairs, pop, sim, cal = setup
    _, _, _, sims, hm = half_mode_setup
    data = _data(system, pairs, pop, 0.05, 80)
    kw = {"sigma_pos": SIGMA_POS, "flux_rel_err": 0.02, "n_mocks": 50}
    with pytest.raises(ValueError, match="made for the abundance posterior"):
        half_mode_posterior(data, sims, calibrations=cal)
    with pytest.raises(ValueError, match="made for the half-mode posterior"):
        abundance_posterior(data, sims[1], calibrations=hm)
    with pytest.raises(ValueError, match="WDM populations"):
        calibrate_posterior(pairs, system, [sim, sims[0]], **kw)
    with pytest.raises(ValueError, match="at least two"):
        calibrate_posterior(pairs, system, [sims[0]], **kw)
    with pytest.raises(ValueError, match="each half-mode mass once"):
        calibrate_posterior(pairs, system, [sims[0], sims[0]], **kw)
    # another slope, or another host centre, at another mass: not one population
    for change in ({"shmf_log_slope": -1.8}, {"host_centre": (0.0, 0.0) * u.arcsec}):
        other = simulate_anomalies(pairs, system, SubhaloPopulation(
            pop.z_lens, pop.z_source, log_mhm=8.0, **{**WDM_SETTINGS, **change}),
            sim.sigma_sub, n_realisations=MIN_REALISATIONS, seed=2)
        with pytest.raises(ValueError, match="differ only in log_mhm"):
            calibrate_posterior(pairs, system, [sims[0], other], **kw)
    with pytest.raises(TypeError, match="or a list of them"):
        calibrate_posterior(pairs, system, [sims[0], "x"], **kw)
    # the calibration of other masses, or of the same masses with another slope
    eight = simulate_anomalies(pairs, system, SubhaloPopulation(
        pop.z_lens, pop.z_source, log_mhm=8.0, **WDM_SETTINGS), sim.sigma_sub,
        n_realisations=MIN_REALISATIONS, seed=2)
    with pytest.raises(ValueError, match="was not made on simulation 1"):
        half_mode_posterior(data, [sims[1], sims[2], eight], calibrations=hm)
    slope = [simulate_anomalies(pairs, system, SubhaloPopulation(
        pop.z_lens, pop.z_source, log_mhm=m, **{**WDM_SETTINGS, "shmf_log_slope": -1.8}),
        sim.sigma_sub, n_realisations=MIN_REALISATIONS, seed=2) for m in MASSES]
    with pytest.raises(ValueError, match="was not made on simulation 1"):
        half_mode_posterior(data, slope, calibrations=hm)


def _interleaved_tasks():
    """Two tasks that each silence UserWarning with ``catch_warnings``, interleaved so
    that the first leaves its block (restoring the filters it entered with) while the
    second, inside its own, still warns."""
    import threading

    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()

    def task(name):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            if name == "a":
                a_in.set()
                assert b_in.wait(10)
            else:
                assert a_in.wait(10)
                b_in.set()
                assert a_out.wait(10)
                warnings.warn("raised after the other task restored the filters", UserWarning,
                              stacklevel=2)
        if name == "a":
            a_out.set()
        return name

    return task


def test_run_tasks_silences_what_threaded_tasks_silence():
    """catch_warnings is not thread-safe: the second task's warning escapes its own
    block (an error under an "error" filter) unless run_tasks silences the category
    around all the tasks, as calibrate_posterior does for its threads."""
    from concurrent.futures import ThreadPoolExecutor

    from lensdual._parallel import run_tasks

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with ThreadPoolExecutor(2) as pool, pytest.raises(UserWarning, match="restored"):
            run_tasks(_interleaved_tasks(), ["a", "b"], pool)
        with ThreadPoolExecutor(2) as pool:
            assert run_tasks(_interleaved_tasks(), ["a", "b"], pool,
                             ignore=(UserWarning,)) == ["a", "b"]
        # the filters are as they were: the category is an error again
        with pytest.raises(UserWarning):
            warnings.warn("after", UserWarning, stacklevel=2)
