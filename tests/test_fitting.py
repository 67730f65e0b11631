"""Tests of lensdual.parametric.fitting (parametric lens fits to a constellation)."""

import importlib.util
import sys
import warnings

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import QTable
from astropy.wcs import WCS

from lensdual.duality import check_duality
from lensdual.exceptions import LensdualWarning
from lensdual.parametric import parametric_comparison
from lensdual.parametric.fitting import (
    ParametricFit,
    compare_with_parametric,
    fit_parametric_lens,
    plot_parametric_comparison,
)
from lensdual.simulation import LensComponent, LensSystem

TRUTH = [
    {"theta_E": 1.5, "e1": 0.1, "e2": -0.05, "center_x": 0.0, "center_y": 0.0},
    {"gamma1": 0.04, "gamma2": 0.02, "ra_0": 0.0, "dec_0": 0.0},
]
ZL, ZS = 0.5, 2.0
FIXED_CENTRE = {"SIE": {"center_x": 0.0, "center_y": 0.0}}

needs_emcee = pytest.mark.skipif(importlib.util.find_spec("emcee") is None,
                                 reason="emcee (lensdual[mcmc]) is not installed")
needs_corner = pytest.mark.skipif(importlib.util.find_spec("corner") is None,
                                  reason="corner (lensdual[mcmc]) is not installed")


@pytest.fixture(scope="module")
def system():
    return LensSystem([LensComponent("SIE", TRUTH[0]), LensComponent("SHEAR", TRUTH[1])],
                      z_lens=ZL, z_source=ZS)


@pytest.fixture(scope="module")
def pairs(system):
    """16 noiseless pairs on the fold pair of arcs of an SIE + shear lens."""
    rng = np.random.default_rng(3)
    beta = (np.array([0.0, 0.25]) + rng.uniform(-0.06, 0.06, (16, 2))) * u.arcsec
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a source may miss one arc: not under test here
        tab = system.constellation(beta, half_width=4 * u.arcsec, grid_spacing=0.1 * u.arcsec,
                                   seed=1)
    assert len(tab) >= 10
    return tab


@pytest.fixture(scope="module")
def fit(pairs):
    return fit_parametric_lens(pairs, model=("SIE", "SHEAR"), z_lens=ZL, z_source=ZS,
                               fixed_params=FIXED_CENTRE, n_starts=2, n_samples=50, seed=1)


def test_recovers_truth(fit, pairs):
    # fixed: the SIE centre (0, 0) and the shear reference point; free: theta_E, e1, e2,
    # gamma1, gamma2
    assert isinstance(fit, ParametricFit)
    assert fit.dof == 2 * len(pairs) - 5
    assert fit.chi2 < 1e-6
    assert len(fit.param_names) == 5
    for key in ("theta_E", "e1", "e2"):
        assert fit.kwargs_fitted[0][key] == pytest.approx(TRUTH[0][key], rel=0.01, abs=1e-4)
    for key in ("gamma1", "gamma2"):
        assert fit.kwargs_fitted[1][key] == pytest.approx(TRUTH[1][key], rel=0.01, abs=1e-4)
    assert fit.kwargs_fitted[0]["center_x"] == 0.0


def test_predictions_match_lenstronomy(fit, pairs, system):
    from lenstronomy.LensModel.lens_model import LensModel

    pred = fit.predictions
    assert isinstance(pred, QTable)
    for col in ("pair_id", "mu1_model", "mu2_model", "mu_model", "mu_model_err", "dx1", "dy2"):
        assert col in pred.colnames
    lm = LensModel(["SIE", "SHEAR"])
    mu1 = lm.magnification(pairs["x1"].value, pairs["y1"].value, TRUTH)
    mu2 = lm.magnification(pairs["x2"].value, pairs["y2"].value, TRUTH)
    np.testing.assert_allclose(pred["mu1_model"], mu1, rtol=1e-3)
    np.testing.assert_allclose(pred["mu2_model"], mu2, rtol=1e-3)
    np.testing.assert_allclose(pred["mu_model"], np.abs(mu1 / mu2), rtol=1e-3)
    assert np.all(np.sign(pred["mu1_model"]) == -np.sign(pred["mu2_model"]))
    assert np.all(np.asarray(pred["mu_model_err"]) > 0)
    assert np.max(np.abs(pred["dx1"].to_value(u.arcsec))) < 1e-3


def test_image_chi2_agrees(pairs):
    fit = fit_parametric_lens(pairs, model=["SIE", "SHEAR"], z_lens=ZL, z_source=ZS,
                              fixed_params=FIXED_CENTRE, n_starts=1, n_samples=10, seed=2,
                              chi2="image")
    assert fit.chi2 < 1e-6
    assert fit.kwargs_fitted[0]["theta_E"] == pytest.approx(1.5, rel=0.01)


def test_fixed_profiles_and_reproducible(pairs):
    # a far, light fixed perturber changes little; the same seed gives the same fit
    fixed = [("SIS", {"theta_E": 0.01, "center_x": 10.0, "center_y": 10.0})]
    kw = dict(model=("SIE", "SHEAR"), z_lens=ZL, z_source=ZS, fixed_params=FIXED_CENTRE,
              fixed=fixed, n_starts=1, n_samples=10, max_nfev=200, seed=5)
    a = fit_parametric_lens(pairs, **kw)
    b = fit_parametric_lens(pairs, **kw)
    assert len(a.kwargs_lens) == 3
    assert a.kwargs_fitted == b.kwargs_fitted
    np.testing.assert_array_equal(a.predictions["mu_model_err"], b.predictions["mu_model_err"])


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"model": ("SIE", "NOT_A_PROFILE")}, ValueError, "unknown or unsupported profile"),
        ({"model": ()}, ValueError, "at least one"),
        ({"model": (3,)}, TypeError, "profile names"),
        ({"z_lens": None}, ValueError, "z_lens and z_source are required"),
        ({"z_source": None}, ValueError, "z_lens and z_source are required"),
        ({"z_source": 0.3}, ValueError, "z_source must be larger"),
        ({"sigma_pos": 0.06}, TypeError, "sigma_pos"),
        ({"chi2": "pixels"}, ValueError, "chi2 must be one of"),
        ({"fixed_params": {"EPL": {"gamma": 2.0}}}, ValueError, "fixed_params.*not in the model"),
        ({"fixed_params": {"SIE": {"q": 0.5}}}, ValueError, "unknown parameter"),
        ({"bounds": {"SIE": {"theta_E": (2.0, 1.0)}}}, ValueError, "lower"),
        ({"init": {"SIE": {"theta_E": 500.0}}}, ValueError, "outside its bounds"),
        ({"fixed": [("NOPE", {})]}, ValueError, "fixed\\[0\\]: unknown"),
        ({"n_starts": 0}, ValueError, "n_starts"),
        ({"mcmc": "yes"}, TypeError, "mcmc"),
        ({"n_walkers": 1.5}, TypeError, "n_walkers"),
        pytest.param({"mcmc": True, "n_walkers": 8}, ValueError,
                     "n_walkers must be >= 2 \\* n_free = 10", marks=needs_emcee),
        pytest.param({"mcmc": True, "n_mcmc": 100, "n_walkers": 40}, ValueError,
                     "2 step\\(s\\) per walker for 40 walkers; need n_mcmc >= 160",
                     marks=needs_emcee),
    ],
)
def test_bad_arguments(pairs, monkeypatch, kwargs, exc, match):
    import scipy.optimize

    def boom(*args, **kw):
        raise AssertionError("fitting started")

    monkeypatch.setattr(scipy.optimize, "least_squares", boom)
    base = dict(model=("SIE", "SHEAR"), z_lens=ZL, z_source=ZS, fixed_params=FIXED_CENTRE)
    base.update(kwargs)
    with pytest.raises(exc, match=match):
        fit_parametric_lens(pairs, **base)


def test_too_few_pairs(pairs, monkeypatch):
    import scipy.optimize

    monkeypatch.setattr(scipy.optimize, "least_squares",
                        lambda *a, **k: (_ for _ in ()).throw(AssertionError("fitting started")))
    # EPL (6 free) + SHEAR (2 free) = 8 free parameters > 2 * 3 constraints
    with pytest.raises(ValueError, match="too few pairs.*6 constraints.*8 free"):
        fit_parametric_lens(pairs[:3], model=("EPL", "SHEAR"), z_lens=ZL, z_source=ZS)
    with pytest.raises(TypeError, match="pairs must be an astropy Table"):
        fit_parametric_lens(np.zeros((3, 4)), z_lens=ZL, z_source=ZS)
    plain = QTable(pairs[:5], copy=True)
    plain["x1"] = plain["x1"].value
    with pytest.raises(TypeError, match="x1"):
        fit_parametric_lens(plain, model="SIS", z_lens=ZL, z_source=ZS)


@needs_emcee
def test_mcmc_posterior(pairs):
    # 200 evaluations: 10 walkers x 20 steps, the first 5 discarded; far too short a chain
    with pytest.warns(LensdualWarning, match="emcee chain too short.*increase n_mcmc"):
        fit = fit_parametric_lens(pairs, model=("SIE", "SHEAR"), z_lens=ZL, z_source=ZS,
                                  fixed_params=FIXED_CENTRE, n_starts=1, mcmc=True, n_mcmc=200,
                                  n_samples=20, seed=4)
    assert fit.samples.shape == (150, 5)
    assert 0 <= fit.acceptance <= 1
    assert np.all(np.isfinite(fit.predictions["mu_model_err"]))
    info = fit.mcmc_info
    assert info["sampler"] == "emcee.EnsembleSampler"
    assert (info["n_walkers"], info["n_steps"], info["burn_in"]) == (10, 20, 5)
    assert info["acceptance_fraction"] == fit.acceptance and not info["converged"]
    assert list(info["autocorr_time"]) == fit.param_names
    assert fit.autocorr_time.shape == (5,)
    assert fit.predictions.meta["mcmc"] == info


MCMC_KW = dict(model=("SIE", "SHEAR"), z_lens=ZL, z_source=ZS, fixed_params=FIXED_CENTRE,
               n_starts=1, mcmc=True, n_samples=10)


@needs_emcee
def test_mcmc_seeded(pairs):
    def run(seed):
        with pytest.warns(LensdualWarning, match="chain too short"):
            return fit_parametric_lens(pairs, n_mcmc=200, seed=seed, **MCMC_KW)

    a, b, c = run(7), run(7), run(8)
    np.testing.assert_array_equal(a.samples, b.samples)
    assert a.acceptance == b.acceptance
    np.testing.assert_array_equal(a.autocorr_time, b.autocorr_time)
    np.testing.assert_array_equal(a.predictions["mu_model_err"], b.predictions["mu_model_err"])
    assert not np.array_equal(a.samples, c.samples)


@pytest.fixture(scope="module")
def mcmc_fit(pairs):
    """An emcee posterior of the SIE + shear fit, tight (sigma_pos = 5 mas) and Gaussian."""
    if importlib.util.find_spec("emcee") is None:
        pytest.skip("emcee (lensdual[mcmc]) is not installed")
    with pytest.warns(LensdualWarning, match="chain too short"):  # 400 steps: ~20 tau
        return fit_parametric_lens(pairs, model=("SIE", "SHEAR"), z_lens=ZL, z_source=ZS,
                                   sigma_pos=0.005 * u.arcsec, fixed_params=FIXED_CENTRE,
                                   n_starts=1, mcmc=True, n_mcmc=4000, n_samples=200, seed=1)


def test_mcmc_recovers_truth(mcmc_fit, pairs):
    fit = mcmc_fit
    assert fit.samples.shape == (10 * 300, 5)
    assert 0.1 < fit.acceptance < 0.9
    truth = [TRUTH[0]["theta_E"], TRUTH[0]["e1"], TRUTH[0]["e2"], TRUTH[1]["gamma1"],
             TRUTH[1]["gamma2"]]
    for level in (0.6827, 0.95):
        tab = fit.parameter_intervals(level)
        assert list(tab["name"]) == fit.param_names and tab.meta["source"] == "posterior sample"
        assert np.all((tab["lower"] < truth) & (truth < tab["upper"])), tab
    # the posterior is near the Laplace approximation here: compare the 68 % widths
    laplace = fit.parameter_intervals()
    laplace_fit = ParametricFit(**{**fit.__dict__, "samples": None})
    lap = laplace_fit.parameter_intervals()
    assert lap.meta["source"] == "Laplace"
    ratio = ((laplace["upper"] - laplace["lower"]) / (lap["upper"] - lap["lower"]))
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio
    # and the quoted mu_model intervals hold the true ratios
    pred = fit.predictions
    true_ratio = truth_ratio(pairs)
    assert np.all((pred["mu_model_p16"] <= true_ratio) & (true_ratio <= pred["mu_model_p84"]))


@needs_emcee
def test_mcmc_long_chain_no_warning(pairs):
    # one free parameter (an SIS of fixed centre): 8 walkers x 500 steps are > 50 tau, and
    # the session's filterwarnings = error would fail on the short-chain warning
    fit = fit_parametric_lens(pairs, model="SIS", z_lens=ZL, z_source=ZS,
                              fixed_params={"SIS": {"center_x": 0.0, "center_y": 0.0}},
                              n_starts=1, mcmc=True, n_mcmc=4000, n_samples=10, seed=1)
    assert fit.mcmc_info["converged"]
    assert fit.mcmc_info["n_autocorr"] >= 50
    assert fit.autocorr_time[0] == fit.mcmc_info["autocorr_time"]["SIS[0].theta_E"]
    assert 375 / fit.autocorr_time[0] == pytest.approx(fit.mcmc_info["n_autocorr"])


@needs_corner
def test_plot_corner(mcmc_fit, fit):
    from matplotlib.figure import Figure

    matplotlib.use("Agg")
    names = mcmc_fit.param_names
    d = len(names)
    truths = {"SIE[0].theta_E": 1.5, "SHEAR[1].gamma1": 0.04}
    fig = mcmc_fit.plot_corner(truths=truths)
    assert isinstance(fig, Figure)
    axes = np.array(fig.axes).reshape(d, d)
    # a histogram per parameter on the diagonal, a panel per parameter pair below it
    for i in range(d):
        for j in range(d):
            assert axes[i, j].get_frame_on() == (j <= i)
    assert sum(axes[i, j].get_frame_on() for i in range(d) for j in range(i)) == d * (d - 1) // 2
    assert [axes[-1, j].get_xlabel() for j in range(d)] == names
    assert [axes[i, 0].get_ylabel() for i in range(1, d)] == names[1:]
    # the truth of theta_E is marked on its marginal (a vertical line at 1.5)
    xs = [line.get_xdata()[0] for line in axes[0, 0].get_lines() if len(line.get_xdata())]
    assert any(np.isclose(x, 1.5) for x in xs)
    plt.close(fig)
    fig = mcmc_fit.plot_corner(truths="best", labels=[f"p{k}" for k in range(d)])
    assert fig.axes[-1].get_xlabel() == f"p{d - 1}"
    plt.close(fig)
    with pytest.raises(ValueError, match="one value per free parameter"):
        mcmc_fit.plot_corner(truths=[1.5])
    with pytest.raises(ValueError, match="unknown parameter"):
        mcmc_fit.plot_corner(truths={"theta_E": 1.5})
    with pytest.raises(ValueError, match="no posterior sample.*mcmc=True"):
        fit.plot_corner()


def test_mcmc_without_emcee(pairs, monkeypatch):
    import scipy.optimize

    monkeypatch.setitem(sys.modules, "emcee", None)  # import emcee raises ImportError
    real = scipy.optimize.least_squares

    def boom(*args, **kw):
        raise AssertionError("fitting started")

    monkeypatch.setattr(scipy.optimize, "least_squares", boom)
    with pytest.raises(ImportError, match=r'emcee.*pip install "lensdual\[mcmc\]"'):
        fit_parametric_lens(pairs, n_mcmc=200, seed=1, **MCMC_KW)
    # the Laplace approximation needs no emcee
    monkeypatch.setattr(scipy.optimize, "least_squares", real)
    fit = fit_parametric_lens(pairs, model=("SIE", "SHEAR"), z_lens=ZL, z_source=ZS,
                              fixed_params=FIXED_CENTRE, n_starts=1, n_samples=10, seed=1)
    assert fit.samples is None and fit.mcmc_info is None and fit.autocorr_time is None
    assert fit.chi2 < 1e-6
    assert np.all(np.asarray(fit.predictions["mu_model_err"]) > 0)


def test_plot_corner_without_corner(fit, monkeypatch):
    monkeypatch.setitem(sys.modules, "corner", None)
    with pytest.raises(ImportError, match=r'corner.*pip install "lensdual\[mcmc\]"'):
        fit.plot_corner()


def test_compare_with_parametric(fit, pairs):
    duality = check_duality(pairs, sigma_pos=0.01 * u.arcsec, n_bootstrap=200, seed=1)
    table = compare_with_parametric(duality, fit, n_samples=50, seed=1)
    for col in ("pair_id", "mu_flux", "mu_flux_err", "mu_size", "mu_size_err", "mu_model",
                "mu_model_err", "ratio_size", "snr_size", "ratio_model", "snr_model",
                "anomalous_size", "anomalous_model", "mu_true"):
        assert col in table.colnames
    # noiseless fluxes and a perfect model: mu_flux = mu_model, no anomaly
    np.testing.assert_allclose(table["ratio_model"], 1.0, rtol=1e-4)
    assert not np.any(table["anomalous_model"])
    np.testing.assert_allclose(table["mu_model"], fit.predictions["mu_model"], rtol=1e-12)

    # an anomalously bright L1 image is flagged against the model
    bad = QTable(duality, copy=True)
    bad["mu_flux"][2] *= 3.0
    flagged = compare_with_parametric(bad, fit, n_samples=50, seed=1, snr_threshold=3)
    assert flagged["anomalous_model"][2]
    assert flagged["ratio_model"][2] == pytest.approx(3.0, rel=1e-3)

    with pytest.raises(TypeError, match="fit must be a ParametricFit or a LenstoolModel"):
        compare_with_parametric(duality, "model")
    with pytest.raises(ValueError, match="lacks the column"):
        compare_with_parametric(pairs, fit)
    with pytest.raises(ValueError, match="snr_threshold"):
        compare_with_parametric(duality, fit, snr_threshold=-1.0)


def test_plot(fit, pairs):
    matplotlib.use("Agg")
    duality = check_duality(pairs, sigma_pos=0.01 * u.arcsec, n_bootstrap=100, seed=1)
    table = compare_with_parametric(duality, fit, n_samples=20, seed=1)
    ax = plot_parametric_comparison(table)
    assert ax.get_yscale() == "log"
    assert len(ax.get_legend().get_texts()) >= 3
    plt.close(ax.figure)
    with pytest.raises(ValueError, match="lacks the column"):
        plot_parametric_comparison(QTable({"pair_id": [1]}))


def test_compare_with_lenstool_model(tmp_path, pairs):
    import importlib.util
    from pathlib import Path

    from lensdual.parametric import read_lenstool

    spec = importlib.util.spec_from_file_location(
        "_lenstool_tests", Path(__file__).with_name("test_lenstool.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    path = tmp_path / "model.par"
    path.write_text(mod.PAR)
    model = read_lenstool(path)
    duality = check_duality(pairs, sigma_pos=0.01 * u.arcsec, n_bootstrap=100, seed=1)
    with pytest.raises(ValueError, match="z_source is required"):
        compare_with_parametric(duality, model)
    table = compare_with_parametric(duality, model, z_source=2.0)
    lm = model.lens_model(2.0)
    mu1 = lm.magnification(pairs["x1"].value, pairs["y1"].value)
    mu2 = lm.magnification(pairs["x2"].value, pairs["y2"].value)
    np.testing.assert_allclose(table["mu_model"], np.abs(mu1 / mu2), rtol=1e-12)
    assert np.all(table["mu_model_err"] == 0)


# ---------------------------------------------------------------------- parametric_comparison

LENS_CENTRE = SkyCoord(150.0, -30.0, unit="deg")


def tan_wcs(reference):
    """An astropy TAN WCS whose pixels are arcsec, x west, y north, origin at
    ``reference``: an independent implementation of the pairs' tangent-plane frame."""
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [reference.ra.deg, reference.dec.deg]
    w.wcs.crpix = [1.0, 1.0]
    w.wcs.cdelt = [-1.0 / 3600.0, 1.0 / 3600.0]
    return w


def with_frame(duality, sky1, sky2, reference, *, keep_sky):
    """The duality table with positions in the tangent plane about ``reference``, as
    measure_pairs writes them (and its sky1, sky2 columns when ``keep_sky``)."""
    w = tan_wcs(reference)
    out = QTable(duality, copy=True)
    for (xn, yn), sky in ((("x1", "y1"), sky1), (("x2", "y2"), sky2)):
        px, py = w.world_to_pixel(sky)
        out[xn], out[yn] = px * u.arcsec, py * u.arcsec
    if keep_sky:
        out["sky1"], out["sky2"] = sky1, sky2
    out.meta["reference"] = reference
    return out


@pytest.fixture(scope="module")
def duality(pairs):
    return check_duality(pairs, sigma_pos=0.01 * u.arcsec, n_bootstrap=100, seed=1)


def truth_ratio(pairs):
    from lenstronomy.LensModel.lens_model import LensModel

    lm = LensModel(["SIE", "SHEAR"])
    mu1 = lm.magnification(pairs["x1"].value, pairs["y1"].value, TRUTH)
    mu2 = lm.magnification(pairs["x2"].value, pairs["y2"].value, TRUTH)
    return np.abs(mu1 / mu2)


FAST_FIT = {"fixed_params": FIXED_CENTRE, "n_starts": 1, "max_nfev": 400}


def test_parametric_comparison_fit(duality, pairs):
    from matplotlib.figure import Figure

    table, fig = parametric_comparison(duality, fit=True, model=("SIE", "SHEAR"), z_lens=ZL,
                                       z_source=ZS, fit_kwargs=FAST_FIT, n_samples=20, seed=1)
    assert isinstance(table, QTable) and isinstance(fig, Figure)
    np.testing.assert_allclose(table["mu_model"], truth_ratio(pairs), rtol=1e-3)
    meta = table.meta["parametric"]
    assert meta["fit_frame"] == "pairs frame" and meta["fit_model"] == ["SIE", "SHEAR"]
    assert meta["sigma_pos"] == pytest.approx(0.01)  # the duality test's
    assert meta["chi2"] < 1e-6 and meta["lenstool"] is None
    assert fig.axes[0].get_yscale() == "log"
    plt.close(fig)


@pytest.mark.parametrize("keep_sky", [True, False])
def test_parametric_comparison_fit_about_centre(duality, pairs, keep_sky):
    # the pairs' frame is centred 40 arcsec from the lens, as measure_pairs would make it;
    # the fit works about centre, where the model is lens-centred
    w = tan_wcs(LENS_CENTRE)
    sky1 = w.pixel_to_world(pairs["x1"].value, pairs["y1"].value)
    sky2 = w.pixel_to_world(pairs["x2"].value, pairs["y2"].value)
    reference = w.pixel_to_world(30.0, -25.0)
    tab = with_frame(duality, sky1, sky2, reference, keep_sky=keep_sky)
    assert abs(tab["x1"][0] - pairs["x1"][0]) > 20 * u.arcsec
    table, fig = parametric_comparison(tab, fit=True, model=("SIE", "SHEAR"), z_lens=ZL,
                                       z_source=ZS, centre=LENS_CENTRE, fit_kwargs=FAST_FIT,
                                       n_samples=20, seed=1)
    np.testing.assert_allclose(table["mu_model"], truth_ratio(pairs), rtol=1e-3)
    assert table.meta["parametric"]["fit_frame"].startswith("tangent plane about RA=150.0000000")
    plt.close(fig)


@pytest.fixture(scope="module")
def small_lenstool(tmp_path_factory):
    """The small dPIE model of test_lenstool.py, origin (150, -30) = LENS_CENTRE."""
    import importlib.util
    from pathlib import Path

    from lensdual.parametric import read_lenstool

    spec = importlib.util.spec_from_file_location(
        "_lenstool_tests", Path(__file__).with_name("test_lenstool.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    path = tmp_path_factory.mktemp("lenstool") / "model.par"
    path.write_text(mod.PAR)
    return read_lenstool(path)


@pytest.mark.parametrize("keep_sky", [True, False])
def test_parametric_comparison_lenstool(duality, pairs, small_lenstool, keep_sky):
    model = small_lenstool
    # the pairs' model-frame positions are those of the simulation
    xy1 = np.column_stack([pairs["x1"], pairs["y1"]])
    xy2 = np.column_stack([pairs["x2"], pairs["y2"]])
    sky1, sky2 = model.to_sky(xy1), model.to_sky(xy2)
    reference = tan_wcs(model.origin).pixel_to_world(12.0, 7.0)
    tab = with_frame(duality, sky1, sky2, reference, keep_sky=keep_sky)
    table, fig = parametric_comparison(tab, lenstool=model, z_source=2.0)
    lm = model.lens_model(2.0)
    expect = np.abs(lm.magnification(xy1[:, 0].value, xy1[:, 1].value)
                    / lm.magnification(xy2[:, 0].value, xy2[:, 1].value))
    np.testing.assert_allclose(table["mu_model"], expect, rtol=1e-7)
    wrong = np.abs(lm.magnification(tab["x1"].value, tab["y1"].value)
                   / lm.magnification(tab["x2"].value, tab["y2"].value))
    assert np.max(np.abs(wrong / expect - 1)) > 1e-2  # the frame conversion matters
    assert table.meta["parametric"]["lenstool"] == str(model.path)
    assert "mu_lenstool" not in table.colnames
    plt.close(fig)


def test_parametric_comparison_lenstool_and_fit(duality, pairs, small_lenstool, tmp_path):
    model = small_lenstool
    xy1 = np.column_stack([pairs["x1"], pairs["y1"]])
    xy2 = np.column_stack([pairs["x2"], pairs["y2"]])
    tab = with_frame(duality, model.to_sky(xy1), model.to_sky(xy2), model.origin,
                     keep_sky=True)
    # read from the path; the fit works in the model's frame (lens-centred here)
    table, fig = parametric_comparison(tab, lenstool=model.path, fit=True,
                                       model=("SIE", "SHEAR"), z_source=ZS,
                                       fit_kwargs=FAST_FIT, n_samples=20, seed=1)
    np.testing.assert_allclose(table["mu_model"], truth_ratio(pairs), rtol=1e-3)
    lm = model.lens_model(ZS)
    expect = np.abs(lm.magnification(xy1[:, 0].value, xy1[:, 1].value)
                    / lm.magnification(xy2[:, 0].value, xy2[:, 1].value))
    np.testing.assert_allclose(table["mu_lenstool"], expect, rtol=1e-7)
    for col in ("ratio_lenstool", "snr_lenstool", "anomalous_lenstool"):
        assert col in table.colnames
    meta = table.meta["parametric"]
    assert meta["fit_frame"] == "Lenstool model frame" and meta["z_lens"] == 0.4
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert any("Lenstool" in t for t in labels)
    plt.close(fig)
    # what lensdual run writes: the table and its meta survive ECSV
    table.write(tmp_path / "parametric.ecsv")
    back = QTable.read(tmp_path / "parametric.ecsv")
    assert back.meta["parametric"] == meta
    np.testing.assert_array_equal(back["mu_lenstool"], table["mu_lenstool"])


@pytest.mark.parametrize(("kwargs", "exc", "match"), [
    ({}, ValueError, "nothing to compare"),
    ({"fit": True, "z_source": None}, ValueError, "z_source is required"),
    ({"fit": True}, ValueError, "z_lens is required"),
    ({"fit": "yes"}, TypeError, "fit must be True or False"),
    ({"lenstool": 3}, TypeError, "lenstool must be a path or a LenstoolModel"),
    ({"lenstool": "/nonexistent/best.par"}, FileNotFoundError, "best.par"),
    ({"fit": True, "z_lens": ZL, "centre": (150.0, -30.0)}, TypeError, "centre must be"),
    ({"fit": True, "z_lens": ZL, "centre": LENS_CENTRE}, ValueError,
     "cannot place the pairs in the frame of centre"),
    ({"fit": True, "z_lens": ZL, "fit_kwargs": {"model": "SIS"}}, TypeError, "model"),
    ({"fit": True, "z_lens": ZL, "model": ("NOPE",)}, ValueError, "unknown or unsupported"),
])
def test_parametric_comparison_errors(duality, monkeypatch, kwargs, exc, match):
    import scipy.optimize

    monkeypatch.setattr(scipy.optimize, "least_squares",
                        lambda *a, **k: (_ for _ in ()).throw(AssertionError("fitting started")))
    base = {"z_source": ZS}
    base.update(kwargs)
    with pytest.raises(exc, match=match):
        parametric_comparison(duality, **base)


def test_parametric_comparison_needs_sky_for_lenstool(duality, small_lenstool):
    with pytest.raises(ValueError, match="cannot place the pairs in the Lenstool model's frame"):
        parametric_comparison(duality, lenstool=small_lenstool, z_source=2.0)
    with pytest.raises(ValueError, match="z_source must be larger than z_lens"):
        parametric_comparison(duality, lenstool=small_lenstool, z_source=0.3)
    with pytest.raises(ValueError, match="lacks the column"):
        parametric_comparison(QTable({"x1": [1.0] * u.arcsec}), fit=True, z_source=2.0)
    with pytest.raises(TypeError, match="pairs must be an astropy Table"):
        parametric_comparison([1, 2], fit=True, z_source=2.0)
