"""lensdual.inference: pyHalo populations, the multi-halo forward model, the posterior."""

import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from astropy import units as u
from astropy.table import QTable

pytest.importorskip("pyHalo")

from lensdual import check_duality  # noqa: E402
from lensdual.inference import (  # noqa: E402  # noqa: E402
    MIN_REALISATIONS,
    AnomalySimulation,
    SubhaloPopulation,
    _forward,
    _kernels,
    abundance_posterior,
    apply_population,
    half_mode_posterior,
    pair_anomalies,
    simulate_anomalies,
)
from lensdual.sensitivity._kernels import tnfw_rho0  # noqa: E402
from lensdual.simulation import noisy_constellation  # noqa: E402
from lensdual.simulation.families import calibration_system, clean_constellation  # noqa: E402
from lensdual.simulation.halos import nfw_angular_parameters  # noqa: E402

ZL, ZS = 0.39, 2.2
KPC2 = u.kpc**-2


@pytest.fixture(scope="module")
def population():
    return SubhaloPopulation(ZL, ZS)


@pytest.fixture(scope="module")
def lens_and_pairs():
    system, _ = calibration_system("smacs_analog")
    return system, clean_constellation("smacs_analog", 8, seed=3)


# ---------------------------------------------------------------- population


def test_number_density_matches_pyhalo_normalisation(population):
    from pyHalo.Rendering.MassFunctions.mass_function_base import CDMPowerLaw
    from pyHalo.Rendering.subhalos import normalization_sigmasub

    radius = 2.0  # arcsec
    kpc = population._kpc_per_arcsec
    norm = normalization_sigmasub(0.025, 10**15, ZL, kpc, 2 * radius, -1.9, 1e8, 0.55, 0.37)
    expected = CDMPowerLaw(6.0, 10.0, -1.9, False, norm).n_mean
    ours = population.number_density(0.025 * KPC2).to_value(u.arcsec**-2) * np.pi * radius**2
    assert ours == pytest.approx(expected, rel=1e-10)


def test_masses_follow_pyhalo_mass_function(population):
    from pyHalo.Rendering.MassFunctions.mass_function_base import CDMPowerLaw
    from scipy import stats

    np.random.seed(4)  # noqa: NPY002  (pyHalo draws from the global generator)
    ref = CDMPowerLaw(6.0, 10.0, -1.9, False, 1.2e9).draw()
    ours = population._masses(np.random.default_rng(5), ref.size)
    assert ref.size > 2000
    assert stats.ks_2samp(np.log10(ref), np.log10(ours)).pvalue > 0.01


def test_wdm_turnover_removes_small_haloes():
    cdm = SubhaloPopulation(ZL, ZS)
    wdm = SubhaloPopulation(ZL, ZS, model="WDM", log_mhm=8.0)
    n_cdm = cdm.number_density(0.02 * KPC2).value
    n_wdm = wdm.number_density(0.02 * KPC2).value
    # SHMF_LOVELL2020 turnover (1 + 36.15 (m_hm / m)^2.5)^-0.2, integrated over the power law
    lm = np.linspace(6, 10, 4001)
    m = 10**lm
    w = m**-0.9
    frac = np.trapezoid(w * (1 + 36.15 * (1e8 / m) ** 2.5) ** -0.2, lm) / np.trapezoid(w, lm)
    assert n_wdm / n_cdm == pytest.approx(frac, rel=1e-4)
    rng = np.random.default_rng(0)
    drawn = [wdm.draw(rng, 0.02, np.array([20.0, 0.0]), 1.0)["mass"].size for _ in range(40)]
    assert np.mean(drawn) == pytest.approx(n_wdm * np.pi, rel=0.05)


def test_draw_parameters_are_lenstronomy_tnfw(population):
    from lenstronomy.Cosmo.lens_cosmo import LensCosmo

    h = population.draw(np.random.default_rng(1), 0.05, np.array([10.0, 5.0]), 0.5)
    assert h["mass"].size > 50
    assert (h["mass"] >= 1e6).all() and (h["mass"] <= 1e10).all()
    assert (np.hypot(h["x"] - 10.0, h["y"] - 5.0) <= 0.5).all()
    # Rs recovers a concentration near LUDLOW2016's median (0.2 natural-log scatter)
    lc = LensCosmo(ZL, ZS, population.cosmology)
    rs_med, _ = lc.nfw_physical2angle(M=h["mass"], c=np.exp(np.interp(
        np.log10(h["mass"]), population._log_m_grid, population._log_c_grid)))
    ratio = np.log(h["rs"] / rs_med)
    assert abs(np.median(ratio)) < 0.1 and 0.03 < np.std(ratio) < 0.3
    assert (h["r_trunc"] > 0).all()


def test_population_bad_input():
    with pytest.raises(ValueError, match="model must be one of"):
        SubhaloPopulation(ZL, ZS, model="SIDM")
    with pytest.raises(ValueError, match="needs log_mhm"):
        SubhaloPopulation(ZL, ZS, model="WDM")
    with pytest.raises(ValueError, match="log_mhigh"):
        SubhaloPopulation(ZL, ZS, log_mlow=9, log_mhigh=7)
    with pytest.raises(ValueError, match="z_source"):
        SubhaloPopulation(1.0, 0.5)


# ---------------------------------------------------------------- kernel


def _case(kappa, gamma1, halos, strong):
    """(lenstronomy sum |mu| |det A|, images), (lensdual's), for the image at the origin."""
    from lenstronomy.LensModel.lens_model import LensModel
    from lenstronomy.LensModel.Solver.lens_equation_solver import LensEquationSolver

    lm = LensModel(["CONVERGENCE", "SHEAR"] + ["TNFW"] * len(halos))
    kw = [{"kappa": kappa}, {"gamma1": gamma1, "gamma2": 0.0}] + [
        {"Rs": rs, "alpha_Rs": ars, "r_trunc": rt, "center_x": x, "center_y": y}
        for x, y, rs, ars, rt in halos]
    bx, by = lm.ray_shooting(0.0, 0.0, kw)
    xs, ys = LensEquationSolver(lm).image_position_from_source(
        bx, by, kw, min_distance=0.002, search_window=1.0, precision_limit=1e-12,
        num_iter_max=200, arrival_time_sort=False)
    a = np.diag([1 - kappa - gamma1, 1 - kappa + gamma1])
    ref = np.sum(np.abs(lm.magnification(xs, ys, kw))) * abs(np.linalg.det(a))
    h = np.array(halos)
    hx, hy, rs, ars, rt = (np.ascontiguousarray(h[:, i]) for i in range(5))
    rho0 = tnfw_rho0(rs, ars)
    te = np.empty(rs.size)
    _kernels.enclosed(rs, rho0, rt, 0.0, te)
    hsup = np.empty(rs.size)
    _kernels.hessian_sup(rs, rho0, rt, hsup)
    ex = np.empty((1, 1))
    n = np.empty((1, 1), dtype=np.int64)
    _kernels.excess_grid(a[0, 0], 0.0, 0.0, a[1, 1], 0.0, hx, hy, rs, rho0, rt, np.sqrt(te),
                         hsup, np.zeros(rs.size), np.array([0, rs.size]), np.array([1.0]),
                         float(np.abs(np.diag(a)).min()), strong, 2.0, 20.0, 32, 32,
                         np.empty((0, 17)), np.zeros(2, dtype=np.int64), np.zeros((1, 4)), ex, n)
    return (ref, len(xs)), (ex[0, 0], n[0, 0])


def _configuration(trial):
    """Macro convergence and shear, and four tNFW haloes within 0.06 arcsec of the image
    (concentrations from the MCR, or 30 for trials 4-7)."""
    rng = np.random.default_rng(3 + trial)
    kappa, gamma1 = [(0.6, 0.3), (0.5, 0.6), (0.45, 0.45), (0.3, 0.2)][trial % 4]
    halos = []
    for m in (3e9, 3e8, 1e8, 1e7):
        rs, ars = nfw_angular_parameters(m * u.Msun, 30.0 if trial >= 4 else None,
                                         z_lens=ZL, z_source=ZS)
        r, phi = rng.uniform(0.0, 0.06), rng.uniform(0, 2 * np.pi)
        halos.append((r * np.cos(phi), r * np.sin(phi), rs.value, ars.value, 10 * rs.value))
    return kappa, gamma1, halos


@pytest.mark.parametrize("trial", range(8))
@pytest.mark.parametrize("strong", [0.0, _forward._STRONG])
def test_flux_excess_matches_lenstronomy(trial, strong):
    (ref, n_ref), (ours, n_ours) = _case(*_configuration(trial), strong)
    assert n_ours == n_ref
    assert ours == pytest.approx(ref, rel=1e-5)


def test_some_lenstronomy_cases_have_extra_images():
    counts = [_case(*_configuration(trial), 0.0)[0][1] for trial in range(8)]
    assert max(counts) >= 3 and min(counts) == 1  # the comparison covers both regimes


def test_linearised_haloes_change_nothing(population, lens_and_pairs, monkeypatch):
    """Haloes too weak to make images enter through their Hessian at the image: the
    same excess as summing every halo in full, on real population draws."""
    system, pairs = lens_and_pairs
    xy1, _ = _forward._positions(pairs)
    jac = system.jacobian(xy1[:1] * u.arcsec)[0]
    grid = np.array([0.01, 0.05, 0.2])
    task = _forward._ImageTask(jac, xy1[0], 0.3, grid, 100, np.random.SeedSequence(7),
                               population)
    default = _forward._image_task(task)[0]
    monkeypatch.setattr(_forward, "_STRONG", 0.0)
    np.testing.assert_allclose(default, _forward._image_task(task)[0], rtol=1e-9)


# ---------------------------------------------------------------- forward model


@pytest.fixture(scope="module")
def simulation(population, lens_and_pairs):
    system, pairs = lens_and_pairs
    return simulate_anomalies(pairs, system, population, np.geomspace(0.002, 0.2, 6) * KPC2,
                              n_realisations=MIN_REALISATIONS, seed=2)


def test_simulation_shapes_and_null(simulation, lens_and_pairs):
    _, pairs = lens_and_pairs
    assert isinstance(simulation, AnomalySimulation)
    assert simulation.delta.shape == (len(pairs), MIN_REALISATIONS, 6)
    assert np.isfinite(simulation.delta).all()
    spread = np.std(simulation.delta, axis=(0, 1))
    assert (np.diff(spread) > 0).all()  # more sub-haloes, larger anomalies
    # the mean convergence is removed: the anomalies are centred near zero
    assert (np.abs(np.median(simulation.delta, axis=(0, 1))) < 0.5 * spread).all()


def test_sheet_is_the_mean_convergence_of_the_draws(population):
    """The sheet removed equals the mean, over draws, of the haloes' convergence at
    the disc's centre."""
    from lensdual.sensitivity._kernels import deflection_hessian

    rng = np.random.default_rng(8)
    centre, radius, sigma = np.array([15.0, 3.0]), 0.2, 0.02
    kbar = _forward._mean_convergence(population, centre, radius, sigma)
    sums = []
    for _ in range(1500):
        h = population.draw(rng, sigma, centre, radius)
        rho0 = tnfw_rho0(h["rs"], h["alpha_rs"])
        k = 0.0
        for i in range(h["mass"].size):
            _, _, fxx, _, fyy = deflection_hessian(0, h["rs"][i], rho0[i], h["r_trunc"][i],
                                                   centre[0] - h["x"][i], centre[1] - h["y"][i])
            k += 0.5 * (fxx + fyy)
        sums.append(k)
    sums = np.array(sums)
    assert kbar > 0
    assert abs(np.mean(sums) - kbar) < 4 * np.std(sums) / np.sqrt(sums.size)


def test_simulation_parallel_is_serial(population, lens_and_pairs, simulation):
    system, pairs = lens_and_pairs
    with ThreadPoolExecutor(2) as pool:
        par = simulate_anomalies(pairs, system, population, simulation.sigma_sub,
                                 n_realisations=MIN_REALISATIONS, seed=2, client=pool)
    np.testing.assert_array_equal(par.delta, simulation.delta)


def test_simulation_on_dask_is_serial(population, lens_and_pairs, simulation):
    distributed = pytest.importorskip("distributed")
    system, pairs = lens_and_pairs
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        on_dask = simulate_anomalies(pairs, system, population, simulation.sigma_sub,
                                     n_realisations=MIN_REALISATIONS, seed=2, client=client)
    np.testing.assert_array_equal(on_dask.delta, simulation.delta)


def test_apply_population_scales_fluxes(population, lens_and_pairs):
    system, pairs = lens_and_pairs
    mock = apply_population(pairs, system, population, 0.05 * KPC2, seed=4)
    for band in ("F150W", "F200W"):
        np.testing.assert_allclose(mock[f"flux1_{band}"] / pairs[f"flux1_{band}"],
                                   mock["subhalo_excess1"])
    np.testing.assert_allclose(mock["subhalo_delta"],
                               np.log(mock["subhalo_excess1"] / mock["subhalo_excess2"]))
    assert np.std(mock["subhalo_delta"]) > 0


def test_simulation_bad_input(population, lens_and_pairs):
    system, pairs = lens_and_pairs
    grid = np.geomspace(0.01, 0.1, 3) * KPC2
    with pytest.raises(ValueError, match=">= 100"):
        simulate_anomalies(pairs, system, population, grid, n_realisations=50)
    with pytest.raises(ValueError, match="increase strictly"):
        simulate_anomalies(pairs, system, population, grid[::-1])
    with pytest.raises(ValueError, match="> 0"):
        simulate_anomalies(pairs, system, population, np.array([0.0, 0.1]) * KPC2)
    with pytest.raises(TypeError, match="kpc"):
        simulate_anomalies(pairs, system, population, np.array([0.01, 0.1]))
    with pytest.raises(ValueError, match="z_source"):
        simulate_anomalies(pairs, system, SubhaloPopulation(ZL, 1.5), grid)
    shifted = QTable(pairs, copy=True)
    shifted["x1"] = shifted["x1"] + 3 * u.arcsec
    result = check_duality(noisy_constellation(pairs, sigma_pos=2 * u.mas, flux_rel_err=0.02,
                                               seed=1), sigma_pos=2 * u.mas, seed=0)
    result["x1"] = result["x1"] + 3 * u.arcsec
    with pytest.raises(ValueError, match="does not reproduce the constellation's magnification"):
        simulate_anomalies(result, system, population, grid)


# ---------------------------------------------------------------- posterior


def _fake_simulation(pair_id, sigma, delta):
    z = np.ones_like(delta)
    return AnomalySimulation(np.asarray(pair_id), sigma, delta, z, z, z.astype(int),
                             z.astype(int), None, np.array([0.1, 0.1]))


def _table(delta, err):
    n = len(delta)
    t = QTable()
    t["pair_id"] = np.arange(1, n + 1)
    t["mu_flux"] = np.exp(delta)
    t["mu_flux_err"] = np.exp(delta) * err / np.sqrt(2)
    t["mu_size"] = np.ones(n)
    t["duality_ratio"] = np.exp(delta)
    t["duality_ratio_err"] = np.exp(delta) * err
    t["snr_dof"] = np.full(n, np.inf)
    t["tested"] = np.ones(n, bool)
    t.meta["duality"] = {"test": "geometric", "snr_definition": "log"}
    return t


def test_posterior_matches_gaussian_closed_form():
    """Anomalies N(0, s(sigma)^2) and Gaussian errors: the likelihood of each pair is
    N(delta; 0, s^2 + err^2), which the Monte Carlo must reproduce."""
    rng = np.random.default_rng(0)
    sigma = np.geomspace(0.001, 1.0, 13) * KPC2
    s = 0.2 * np.sqrt(sigma.value / 0.1)
    n_pairs, n_real = 6, 100000
    err = 0.05
    delta_obs = rng.normal(0, np.hypot(0.2, err), n_pairs)
    sims = rng.standard_normal((n_pairs, n_real, 1)) * s[None, None, :]
    post = abundance_posterior(_table(delta_obs, err),
                               _fake_simulation(np.arange(1, n_pairs + 1), sigma, sims))
    var = s**2 + err**2
    exact = np.sum(-0.5 * delta_obs[:, None] ** 2 / var - 0.5 * np.log(2 * np.pi * var), axis=0)
    np.testing.assert_allclose(post["log_likelihood"], exact, atol=0.05)
    log_grid = np.log10(sigma.value)
    assert np.trapezoid(post["posterior"], log_grid) == pytest.approx(1.0)


def test_the_conservative_snr_gives_the_same_anomalies():
    """A result of snr_definition="conservative" has the log anomalies and errors
    (only its flags differ): the same posterior; the paper's definition is refused."""
    rng = np.random.default_rng(3)
    sigma = np.geomspace(0.001, 1.0, 5) * KPC2
    delta = rng.normal(0, 0.1, 4)
    sims = rng.standard_normal((4, 500, 5)) * 0.1
    log = abundance_posterior(_table(delta, 0.05),
                              _fake_simulation([1, 2, 3, 4], sigma, sims))
    t = _table(delta, 0.05)
    t.meta["duality"]["snr_definition"] = "conservative"
    cons = abundance_posterior(t, _fake_simulation([1, 2, 3, 4], sigma, sims))
    np.testing.assert_array_equal(cons["posterior"], log["posterior"])
    t.meta["duality"]["snr_definition"] = "paper"
    with pytest.raises(ValueError, match="snr_definition='log'"):
        abundance_posterior(t, _fake_simulation([1, 2, 3, 4], sigma, sims))


def test_flat_likelihood_gives_the_prior():
    sigma = np.geomspace(0.001, 1.0, 7) * KPC2
    post = abundance_posterior(_table(np.zeros(3), 0.05),
                               _fake_simulation([1, 2, 3], sigma, np.zeros((3, 200, 7))))
    np.testing.assert_allclose(post["posterior"], 1 / 3)
    assert post.meta["inference"]["median"].value == pytest.approx(10**-1.5)


def test_posterior_round_trips_through_ecsv(tmp_path):
    sigma = np.geomspace(0.001, 1.0, 7) * KPC2
    post = abundance_posterior(_table(np.zeros(3), 0.05),
                               _fake_simulation([1, 2, 3], sigma, np.zeros((3, 200, 7))))
    post.write(tmp_path / "posterior.ecsv")
    back = QTable.read(tmp_path / "posterior.ecsv")
    assert back["sigma_sub"].unit == KPC2
    np.testing.assert_allclose(back["posterior"], post["posterior"])
    assert u.allclose(back.meta["inference"]["interval_95"], post.meta["inference"]["interval_95"])


def test_systems_multiply():
    rng = np.random.default_rng(1)
    sigma = np.geomspace(0.001, 1.0, 9) * KPC2
    s = 0.2 * np.sqrt(sigma.value / 0.1)
    sims = rng.standard_normal((4, 500, 1)) * s
    t1 = _table(rng.normal(0, 0.1, 4), 0.05)
    t2 = _table(rng.normal(0, 0.1, 4), 0.05)
    f = _fake_simulation([1, 2, 3, 4], sigma, sims)
    both = abundance_posterior([t1, t2], [f, f])
    np.testing.assert_allclose(both["log_likelihood"],
                               abundance_posterior(t1, f)["log_likelihood"]
                               + abundance_posterior(t2, f)["log_likelihood"])
    assert both.meta["inference"]["n_systems"] == 2


def test_systems_must_share_the_dark_matter_model(simulation):
    wdm = simulation._replace(population=SubhaloPopulation(ZL, ZS, model="WDM", log_mhm=8.0))
    table = _table(np.zeros(8), 0.1)
    with pytest.raises(ValueError, match="one dark-matter model"):
        abundance_posterior([table, table], [simulation, wdm])
    # another host and redshift, same model: combined
    other = simulation._replace(population=SubhaloPopulation(0.5, 2.0, log_m_host=14.5))
    assert abundance_posterior([table, table], [simulation, other]).meta["inference"][
        "n_systems"] == 2


def test_posterior_bad_input(simulation):
    with pytest.raises(ValueError, match="no flux ratios"):
        pair_anomalies(QTable({"pair_id": [1], "x1": [0.0]}))
    with pytest.raises(ValueError, match="one simulation per constellation"):
        abundance_posterior([_table(np.zeros(2), 0.1)] * 2, [simulation])
    with pytest.raises(ValueError, match="has no pair"):
        abundance_posterior(_table(np.zeros(20), 0.1), simulation)


def _wdm_slices(sigma, log_mhm, scale, n_pairs, n_real, rng, **pop):
    """Fake simulations of WDM populations: anomalies N(0, (scale(m) s(sigma))^2)."""
    s = 0.2 * np.sqrt(sigma.value / 0.1)
    out = []
    for m in log_mhm:
        sims = rng.standard_normal((n_pairs, n_real, 1)) * (scale(m) * s)[None, None, :]
        fake = _fake_simulation(np.arange(1, n_pairs + 1), sigma, sims)
        out.append(fake._replace(population=SubhaloPopulation(ZL, ZS, model="WDM",
                                                              log_mhm=m, **pop)))
    return out, s


def test_half_mode_posterior_matches_gaussian_closed_form():
    """Per half-mode mass the likelihood is that of abundance_posterior; with anomalies
    N(0, (g(m) s(sigma))^2) it is the closed form N(delta; 0, g^2 s^2 + err^2)."""
    rng = np.random.default_rng(2)
    sigma = np.geomspace(0.001, 1.0, 9) * KPC2
    log_mhm = [9.0, 6.0, 7.5]  # unsorted on purpose

    def scale(m):
        return 1.0 / (1.0 + 10 ** (m - 8.0))

    slices, s = _wdm_slices(sigma, log_mhm, scale, 5, 100000, rng)
    err = 0.05
    delta = rng.normal(0, 0.15, 5)
    post = half_mode_posterior(_table(delta, err), slices)
    assert np.unique(post["log10_mhm"]).tolist() == [6.0, 7.5, 9.0]
    for m in (6.0, 7.5, 9.0):
        rows = post[post["log10_mhm"] == m]
        var = (scale(m) * s) ** 2 + err**2
        exact = np.sum(-0.5 * delta[:, None] ** 2 / var - 0.5 * np.log(2 * np.pi * var), axis=0)
        np.testing.assert_allclose(rows["log_likelihood"], exact, atol=0.05)
        np.testing.assert_allclose(rows["sigma_sub"].to_value(KPC2), sigma.value)
    # the joint density integrates to 1, and so do both marginals
    dens = np.asarray(post["posterior"]).reshape(3, 9)
    log_s = np.log10(sigma.value)
    log_m = np.array([6.0, 7.5, 9.0])
    assert np.trapezoid(np.trapezoid(dens, log_s, axis=1), log_m) == pytest.approx(1.0)
    meta = post.meta["inference"]
    assert np.trapezoid(meta["marginal_sigma_sub"], log_s) == pytest.approx(1.0)
    assert np.trapezoid(meta["marginal_log10_mhm"], log_m) == pytest.approx(1.0)
    np.testing.assert_allclose(meta["marginal_log10_mhm"],
                               np.trapezoid(dens, log_s, axis=1), rtol=1e-12)


def test_half_mode_posterior_with_a_flat_likelihood_is_the_prior():
    sigma = np.geomspace(0.001, 1.0, 7) * KPC2
    slices, _ = _wdm_slices(sigma, [6.0, 8.0, 10.0], lambda m: 0.0, 3, 50,
                            np.random.default_rng(0))
    meta = half_mode_posterior(_table(np.zeros(3), 0.05), slices).meta["inference"]
    assert meta["log10_mhm_median"] == pytest.approx(8.0)
    assert meta["log10_mhm_interval_95"] == pytest.approx([6.1, 9.9])
    assert meta["median"].value == pytest.approx(10**-1.5)


def test_large_anomalies_bound_the_half_mode_mass():
    """Where heavy half-mode masses remove the haloes that make the anomalies, data
    with large anomalies put an upper limit on the half-mode mass."""
    rng = np.random.default_rng(3)
    sigma = np.geomspace(0.01, 1.0, 7) * KPC2
    log_mhm = [5.0, 6.0, 7.0, 8.0, 9.0, 10.0]
    slices, _ = _wdm_slices(sigma, log_mhm, lambda m: 1.0 if m <= 7 else 0.05, 8, 3000, rng)
    delta = rng.normal(0, 0.3, 8)
    post = half_mode_posterior(_table(delta, 0.02), slices)
    meta = post.meta["inference"]
    # the density vanishes from the first suppressing mass on; the limit falls in the
    # grid's step from 7 to 8 (the trapezoids interpolate the density linearly)
    assert max(meta["marginal_log10_mhm"][3:]) < 1e-3 * min(meta["marginal_log10_mhm"][:3])
    assert 7.0 < meta["log10_mhm_upper_95"] < 8.0
    # the same data and the weakest suppression alone: abundance_posterior's likelihood
    one = abundance_posterior(_table(delta, 0.02), slices[0])
    np.testing.assert_allclose(post["log_likelihood"][post["log10_mhm"] == 5.0],
                               one["log_likelihood"])


def test_half_mode_posterior_round_trips_through_ecsv(tmp_path):
    sigma = np.geomspace(0.001, 1.0, 5) * KPC2
    slices, _ = _wdm_slices(sigma, [6.0, 9.0], lambda m: 1.0, 3, 200,
                            np.random.default_rng(4))
    post = half_mode_posterior(_table(np.full(3, 0.1), 0.05), slices)
    post.write(tmp_path / "posterior.ecsv")
    back = QTable.read(tmp_path / "posterior.ecsv")
    np.testing.assert_allclose(back["posterior"], post["posterior"])
    assert back.meta["inference"]["log10_mhm_upper_95"] == pytest.approx(
        post.meta["inference"]["log10_mhm_upper_95"])


def test_half_mode_posterior_bad_input(simulation):
    sigma = np.geomspace(0.001, 1.0, 5) * KPC2
    rng = np.random.default_rng(5)
    slices, _ = _wdm_slices(sigma, [6.0, 9.0], lambda m: 1.0, 3, 100, rng)
    table = _table(np.zeros(3), 0.05)
    with pytest.raises(ValueError, match="at least two half-mode masses"):
        half_mode_posterior(table, slices[:1])
    cdm = slices[0]._replace(population=SubhaloPopulation(ZL, ZS))
    with pytest.raises(ValueError, match="WDM population"):
        half_mode_posterior(table, [cdm, slices[1]])
    with pytest.raises(ValueError, match="each half-mode mass once"):
        half_mode_posterior(table, [slices[0], slices[0]])
    other, _ = _wdm_slices(sigma, [9.0], lambda m: 1.0, 3, 100, rng, log_mlow=7.0)
    with pytest.raises(ValueError, match="one population model"):
        half_mode_posterior(table, [slices[0], other[0]])
    coarse, _ = _wdm_slices(sigma[::2], [9.0], lambda m: 1.0, 3, 100, rng)
    with pytest.raises(ValueError, match="one sigma_sub grid"):
        half_mode_posterior(table, [slices[0], coarse[0]])
    with pytest.raises(TypeError, match="AnomalySimulation"):
        half_mode_posterior(table, [slices[0], "nope"])


def test_end_to_end_recovers_a_large_abundance(population, lens_and_pairs, simulation):
    system, pairs = lens_and_pairs
    mock = apply_population(pairs, system, population, 0.15 * KPC2, seed=9)
    noisy = noisy_constellation(mock, sigma_pos=2 * u.mas, flux_rel_err=0.02, seed=9)
    result = check_duality(noisy, sigma_pos=2 * u.mas, seed=0)
    data = pair_anomalies(result)
    assert len(data) >= 5
    post = abundance_posterior(result, simulation)
    m = post.meta["inference"]
    assert m["n_pairs"] == len(data)
    lo, hi = m["interval_95"].to_value(KPC2)
    assert lo < 0.15 < hi
    assert lo > 0.002  # the data exclude the grid's smallest abundance


@pytest.mark.parametrize("copies", [1, 4])
def test_magnitude_weight_of_duplicated_data(copies):
    """A Gaussian datum counted ``copies`` times: the composite log-likelihood is
    ``copies`` times the true one, so H / J = 1 / copies (1 for independent data)."""
    from lensdual.inference._posterior import _magnitude_weight

    rng = np.random.default_rng(0)
    log_grid = np.linspace(-3, 0, 61)
    truths = rng.uniform(-2.5, -0.5, 4000)
    x = truths + 0.2 * rng.standard_normal(truths.size)
    lls = -copies * (log_grid[None, :] - x[:, None]) ** 2 / (2 * 0.2**2)
    assert _magnitude_weight(log_grid, lls, truths) == pytest.approx(1 / copies, rel=0.05)


def test_composite_weight_and_weighted_posterior(population, lens_and_pairs, simulation):
    from lensdual.inference import composite_weight

    system, pairs = lens_and_pairs
    w = composite_weight(pairs, system, simulation, sigma_pos=5 * u.mas, flux_rel_err=0.02,
                         n_mocks=20, seed=3)
    assert 0 < w <= 1
    mock = apply_population(pairs, system, population, 0.05 * KPC2, seed=11)
    result = check_duality(noisy_constellation(mock, sigma_pos=5 * u.mas, flux_rel_err=0.02,
                                               seed=12), sigma_pos=5 * u.mas, seed=0)
    full = abundance_posterior(result, simulation)
    half = abundance_posterior(result, simulation, weights=0.5)
    np.testing.assert_allclose(half["log_likelihood"], 0.5 * full["log_likelihood"])
    assert half.meta["inference"]["weights"] == [0.5]
    with pytest.raises(ValueError, match="weights must be one number in"):
        abundance_posterior(result, simulation, weights=1.5)
    with pytest.raises(ValueError, match="n_mocks"):
        composite_weight(pairs, system, simulation, sigma_pos=5 * u.mas, flux_rel_err=0.02,
                         n_mocks=5)


def test_plot_abundance_posterior_draws_every_posterior():
    import matplotlib.pyplot as plt

    from lensdual.visualization import plot_abundance_posterior

    rng = np.random.default_rng(2)
    sigma = np.geomspace(0.001, 1.0, 13) * KPC2
    s = 0.2 * np.sqrt(sigma.value / 0.1)
    sims = rng.standard_normal((6, 2000, 1)) * s
    f = _fake_simulation(np.arange(1, 7), sigma, sims)
    broad = abundance_posterior(_table(np.zeros(6), 0.3), f)
    sharp = abundance_posterior(_table(rng.normal(0, 0.4, 6), 0.02), f)
    ax = plot_abundance_posterior(broad, paper_bound=0.3 * KPC2, cdm=0.025 * KPC2)
    plot_abundance_posterior(sharp, ax=ax)
    assert ax.get_xscale() == "log"
    assert ax.get_ylim()[1] >= max(broad["posterior"].max(), sharp["posterior"].max())
    assert len(ax.lines) == 6  # two posteriors, their medians, the bound, the CDM line
    plt.close(ax.figure)
    with pytest.raises(ValueError, match="abundance_posterior"):
        plot_abundance_posterior(QTable({"x": [1.0]}))


def test_plot_half_mode_posterior_draws_the_density_and_the_marginal():
    import matplotlib

    matplotlib.use("Agg")
    from lensdual.visualization import plot_half_mode_posterior

    rng = np.random.default_rng(6)
    sigma = np.geomspace(0.01, 1.0, 7) * KPC2
    slices, _ = _wdm_slices(sigma, [5.0, 6.0, 7.0, 8.0, 9.0], lambda m: 1.0 if m <= 7 else 0.05,
                            8, 2000, rng)
    post = half_mode_posterior(_table(rng.normal(0, 0.3, 8), 0.02), slices)
    fig = plot_half_mode_posterior(post)
    ax, axm = fig.axes[:2]
    assert len(fig.axes) == 3  # the colour bar
    assert ax.collections and "m_{\\rm hm}" in ax.get_ylabel()
    line = axm.lines[0]
    np.testing.assert_allclose(line.get_ydata(), post.meta["inference"]["marginal_log10_mhm"])
    assert axm.lines[1].get_xdata()[0] == pytest.approx(
        post.meta["inference"]["log10_mhm_upper_95"])
    with pytest.raises(ValueError, match="half_mode_posterior"):
        plot_half_mode_posterior(abundance_posterior(_table(np.zeros(8), 0.02), slices[0]))


def test_the_geometric_anomalies_of_a_joint_table():
    """A joint-test table (the default of check_duality) gives, with the default
    anomaly="geometric", exactly the anomalies, errors and degrees of freedom of the
    geometric test on the same table; anomaly="joint" reads the joint prediction
    and needs a joint table."""
    clean = clean_constellation("cluster_fold", 20, seed=2)
    noisy = noisy_constellation(clean, sigma_pos=10 * u.mas, flux_rel_err=0.02, seed=4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        joint = check_duality(noisy, sigma_pos=10 * u.mas, seed=0)
        geometric = check_duality(noisy, sigma_pos=10 * u.mas, seed=0, test="geometric")
    assert joint.meta["duality"]["test"] == "joint"
    got, want = pair_anomalies(joint), pair_anomalies(geometric)
    assert list(got["pair_id"]) == list(want["pair_id"]) and len(got) >= 15
    for name in ("delta", "delta_err", "dof"):
        np.testing.assert_allclose(got[name], want[name], rtol=1e-12)
    field = pair_anomalies(joint, "joint")
    tested = np.asarray(joint["tested"], dtype=bool)
    ln_flux = np.log(np.asarray(joint["mu_flux"], dtype=float))
    np.testing.assert_allclose(field["delta"],
                               (ln_flux - np.asarray(joint["ln_mu_predicted"]))[tested])
    np.testing.assert_allclose(
        field["delta_err"], np.hypot(np.asarray(joint["mu_flux_err"]) / np.exp(ln_flux),
                                     np.asarray(joint["ln_mu_predicted_err"]))[tested])
    with pytest.raises(ValueError, match="anomaly='joint' reads the joint test"):
        pair_anomalies(geometric, "joint")
    with pytest.raises(ValueError, match="anomaly must be one of"):
        pair_anomalies(joint, "field")
    old = joint.copy()
    del old["snr_dof_geometric"]  # a joint table made before the column was kept
    with pytest.raises(ValueError, match="no column 'snr_dof_geometric'"):
        pair_anomalies(old)
    assert len(pair_anomalies(old, "joint")) == len(field)
