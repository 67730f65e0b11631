"""lensdual.inference: the abundance posterior recalibrated on mock universes."""

import warnings

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
    simulate_anomalies,
)
from lensdual.inference._calibration import mock_pit, recalibrate, stratified_truths  # noqa: E402
from lensdual.simulation import noisy_constellation  # noqa: E402
from lensdual.simulation.families import calibration_system, clean_constellation  # noqa: E402

KPC2 = u.kpc**-2
SIGMA_POS = 5 * u.mas


def _reference_cdf(log_grid, cdf, truths, mock_lls):
    """The recalibrated CDF in plain numpy: each mock's posterior CDF on the grid
    (trapezoids), its truth's PIT, and the empirical CDF of the PITs linearly
    interpolated between mid-ranks (distinct PITs)."""
    pits = []
    for ll, t in zip(mock_lls, truths, strict=True):
        p = np.exp(ll - ll.max())
        c = np.concatenate([[0.0], np.cumsum((p[1:] + p[:-1]) / 2 * np.diff(log_grid))])
        pits.append(np.interp(t, log_grid, c / c[-1]))
    pits = np.sort(pits)
    levels = (np.arange(pits.size) + 0.5) / pits.size
    x = np.concatenate([[0.0], pits, [1.0]])
    y = np.concatenate([[0.0], levels, [1.0]])
    return np.interp(cdf, x, y)


def _gaussian_calibration(log_grid, n, k, s, rng):
    """Mocks whose Gaussian likelihood (width s) is centred a N(0, (k s)^2) draw off
    their truth: the uncalibrated posterior is k times too narrow."""
    truths = stratified_truths(log_grid, n)
    centres = truths + k * s * rng.standard_normal(n)
    lls = -0.5 * ((log_grid[None, :] - centres[:, None]) / s) ** 2
    return PosteriorCalibration(truths, lls, 10**log_grid * KPC2, "geometric", np.ones(n, int))


# ------------------------------------------------------------------ closed forms


@pytest.mark.parametrize("k", [0.6, 1.0, 1.7])
def test_recalibration_of_gaussian_pit_is_the_closed_form(k):
    """PITs Phi(k z), z standard normal: G(x) = Phi(Phi^-1(x) / k)."""
    z = stats.norm.ppf((np.arange(20000) + 0.5) / 20000)
    pit = stats.norm.cdf(k * z)
    x = np.linspace(0.01, 0.99, 99)
    np.testing.assert_allclose(recalibrate(x, pit), stats.norm.cdf(stats.norm.ppf(x) / k),
                               atol=2e-4)


def test_recalibration_handles_ties_and_ends():
    pit = np.array([0.0, 0.0, 0.3, 0.3, 0.3, 1.0])
    g = recalibrate(np.array([0.0, 0.15, 0.3, 0.65, 1.0]), pit)
    # PIT 0 at mid-ranks 1/12 and 3/12 (mean 1/6), 0.3 at 5/12..9/12 (mean 7/12);
    # a PIT of 1 gives way to the end point (1, 1)
    np.testing.assert_allclose(g, [1 / 6, (1 / 6 + 7 / 12) / 2, 7 / 12, (7 / 12 + 1) / 2, 1.0])
    assert np.all(np.diff(recalibrate(np.linspace(0, 1, 101), pit)) >= 0)


def test_widened_gaussian_posterior_holds_on_fresh_universes():
    """Mock likelihoods 1.8 times too narrow: uncalibrated 68 % intervals hold about
    42 % of fresh truths, recalibrated ones 68 %, and the calibrated interval of a
    posterior far from the prior's ends is 1.8 times wider."""
    rng = np.random.default_rng(1)
    log_grid = np.linspace(-3, -0.5, 401)
    s, k = 0.08, 1.8
    cal = _gaussian_calibration(log_grid, 2000, k, s, rng)
    pit = mock_pit(log_grid, [cal], [1.0])
    covered = {"raw": [], "calibrated": []}
    for t in rng.uniform(-2.6, -0.9, 1500):
        ll = -0.5 * ((log_grid - (t + k * s * rng.standard_normal())) / s) ** 2
        p = np.exp(ll - ll.max())
        cdf = np.concatenate([[0.0], np.cumsum((p[1:] + p[:-1]) / 2 * np.diff(log_grid))])
        cdf /= cdf[-1]
        for key, c in (("raw", cdf), ("calibrated", recalibrate(cdf, pit))):
            lo, hi = np.interp([0.16, 0.84], c, log_grid)
            covered[key].append(lo <= t <= hi)
    assert np.mean(covered["raw"]) == pytest.approx(2 * stats.norm.cdf(1 / k) - 1, abs=0.04)
    assert np.mean(covered["calibrated"]) == pytest.approx(0.68, abs=0.035)
    centre = -1.7
    ll = -0.5 * ((log_grid - centre) / s) ** 2
    p = np.exp(ll)
    cdf = np.concatenate([[0.0], np.cumsum((p[1:] + p[:-1]) / 2 * np.diff(log_grid))])
    lo, hi = np.interp([0.16, 0.84], recalibrate(cdf / cdf[-1], pit), log_grid)
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
    ref = _reference_cdf(log_grid, np.asarray(raw["cdf"]), cal.log10_truth, cal.log_likelihood)
    np.testing.assert_allclose(post["cdf"], ref, atol=1e-12)
    np.testing.assert_allclose(post["posterior"], np.gradient(ref, log_grid), atol=1e-12)
    m = post.meta["inference"]
    assert m["calibrated"] and not raw.meta["inference"]["calibrated"]
    assert m["n_mocks"] == 50
    assert 0 <= m["mock_coverage_uncalibrated"]["68"] <= m["mock_coverage_uncalibrated"]["95"]
    med = 10 ** np.interp(0.5, ref, log_grid)
    assert m["median"].to_value(KPC2) == pytest.approx(med)


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
    ref = _reference_cdf(log_grid, np.asarray(raw["cdf"]), cal.log10_truth,
                         cal.log_likelihood + 0.5 * other.log_likelihood)
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
    coarse = PosteriorCalibration(cal.log10_truth, cal.log_likelihood[:, :5],
                                  cal.sigma_sub[:5], "geometric", cal.n_tested)
    with pytest.raises(ValueError, match="another sigma_sub grid"):
        abundance_posterior(data, sim, calibrations=coarse)
    joint = PosteriorCalibration(cal.log10_truth, cal.log_likelihood, cal.sigma_sub, "joint",
                                 cal.n_tested)
    with pytest.raises(ValueError, match="read the 'joint' anomalies"):
        abundance_posterior(data, sim, calibrations=joint)
    fewer = PosteriorCalibration(cal.log10_truth[:40], cal.log_likelihood[:40], cal.sigma_sub,
                                 "geometric", cal.n_tested[:40])
    with pytest.raises(ValueError, match="same n_mocks"):
        abundance_posterior([data, data], [sim, sim], calibrations=[cal, fewer])
