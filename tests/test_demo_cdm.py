"""``simulate_demo(subhalo="cdm")``: the pyHalo-convention CDM population of the demo."""

import warnings

import astropy.units as u
import numpy as np
import pytest

pytest.importorskip("pyHalo")

from lensdual.demo import (  # noqa: E402
    DEMO_CDM_LOG_MASS,
    DEMO_CDM_THRESHOLD,
    compare_with_truth,
    simulate_demo,
    truth_paragraph,
)

N_SOURCES = 6


@pytest.fixture(scope="module")
def cdm():
    return simulate_demo(subhalo="cdm", n_sources=N_SOURCES, seed=1)


@pytest.fixture(scope="module")
def smooth():
    return simulate_demo(subhalo="none", n_sources=N_SOURCES, seed=1)


def test_the_population_is_drawn_at_pyhalos_abundance():
    """The counts in the discs, summed over seeds, match number_density x area (Poisson)."""
    from lensdual.demo import _cdm_population

    _, truth = simulate_demo(subhalo="none", n_sources=N_SOURCES, seed=0)
    counts, expected = 0, 0.0
    for seed in range(8):
        components, table = _cdm_population(truth, seed)
        assert len(components) == len(table)
        counts += len(table)
        expected += table.meta["expected_number"]
        m = table["mass"].to_value(u.Msun)
        assert np.all((m >= 10 ** DEMO_CDM_LOG_MASS[0]) & (m <= 10 ** DEMO_CDM_LOG_MASS[1]))
        for arc, (x0, y0, r) in table.meta["discs"].items():
            sel = table["arc"] == arc
            d = np.hypot(table["x"][sel].value - x0, table["y"][sel].value - y0)
            assert np.all(d <= r)
    assert expected > 100
    assert abs(counts - expected) < 4 * np.sqrt(expected)


def test_the_components_are_tnfw_with_the_drawn_parameters(cdm, smooth):
    system, truth = cdm
    halos = truth.meta["subhaloes"]
    n_base = len(smooth[0].components)
    added = system.components[n_base:]
    assert len(added) == len(halos) > 0
    for comp, row in zip(added, halos, strict=True):
        assert comp.profile == "TNFW"
        assert comp.kwargs == pytest.approx({
            "Rs": row["rs"].value, "alpha_Rs": row["alpha_rs"].value,
            "r_trunc": row["r_trunc"].value, "center_x": row["x"].value,
            "center_y": row["y"].value})


def test_mu_true_is_lenstronomys_and_subhalo_marks_the_departures(cdm, smooth):
    """An independent LensModel from the components gives mu_true; ``subhalo`` is the
    documented threshold on ln(mu_true/mu_macro); the macro sources are unchanged."""
    from lenstronomy.LensModel.lens_model import LensModel

    system, truth = cdm
    model = LensModel([c.profile for c in system.components])
    kwargs = [dict(c.kwargs) for c in system.components]
    mu = [model.magnification(truth[f"x{a}"].value, truth[f"y{a}"].value, kwargs)
          for a in (1, 2)]
    assert np.abs(mu[0] / mu[1]) == pytest.approx(np.asarray(truth["mu_true"]), rel=1e-6)
    base = smooth[1]
    rows = [list(base["source"]).index(s) for s in truth["source"]]
    assert np.asarray(truth["mu_macro"]) == pytest.approx(np.asarray(base["mu_true"])[rows])
    assert np.asarray(truth["beta_x"].value) == pytest.approx(base["beta_x"].value[rows])
    shift = np.abs(np.log(truth["mu_true"] / truth["mu_macro"]))
    assert np.array_equal(truth["subhalo"], shift > DEMO_CDM_THRESHOLD)
    # the nearest sub-halo of each image is the nearest of the table
    halos = truth.meta["subhaloes"]
    for a in (1, 2):
        d = np.hypot(truth[f"x{a}"].value[:, None] - halos["x"].value[None, :],
                     truth[f"y{a}"].value[:, None] - halos["y"].value[None, :])
        assert np.array_equal(truth[f"nearest_subhalo{a}"], np.argmin(d, axis=1))
        assert truth[f"nearest_sep{a}"].value == pytest.approx(d.min(axis=1))


def test_mu_true_departs_from_mu_macro_through_the_haloes_near_the_images(cdm, smooth):
    """Without the population's haloes near a pair (within 0.5 arcsec of one of its
    images), that pair's ratio moves back towards the macro one."""
    from lenstronomy.LensModel.lens_model import LensModel

    system, truth = cdm
    n_base = len(smooth[0].components)
    halos = truth.meta["subhaloes"]
    hx, hy = halos["x"].value, halos["y"].value
    comps = system.components
    for i in range(len(truth)):
        near = np.zeros(len(halos), dtype=bool)
        for a in (1, 2):
            near |= np.hypot(hx - truth[f"x{a}"].value[i], hy - truth[f"y{a}"].value[i]) < 0.5
        keep = list(comps[:n_base]) + [c for c, n in zip(comps[n_base:], near, strict=True)
                                       if not n]
        model = LensModel([c.profile for c in keep])
        kwargs = [dict(c.kwargs) for c in keep]
        mu = [model.magnification(truth[f"x{a}"].value[i], truth[f"y{a}"].value[i], kwargs)
              for a in (1, 2)]
        far = abs(np.log(abs(mu[0] / mu[1]) / truth["mu_macro"][i]))
        full = abs(np.log(truth["mu_true"][i] / truth["mu_macro"][i]))
        assert far <= full + 0.02


def test_the_comparison_names_the_nearest_subhalo(cdm):
    """compare_with_truth on the truth itself (as if the pipeline measured it): the nearest
    sub-halo of each pair and the counts of the report."""
    from astropy.coordinates import SkyCoord

    from lensdual.simulation import lens_to_sky

    _, truth = cdm
    centre = SkyCoord(110.8 * u.deg, -73.45 * u.deg)
    result = truth.copy()
    result.meta = {}
    for a in (1, 2):
        xy = np.column_stack([truth[f"x{a}"].value, truth[f"y{a}"].value]) * u.arcsec
        result[f"sky{a}"] = lens_to_sky(xy, centre)
    result["mu_size"] = truth["mu_macro"]
    result["mu_flux"] = truth["mu_true"]
    result["anomalous"] = truth["subhalo"]
    comp = compare_with_truth(result, truth, centre)
    assert np.array_equal(comp["source"], np.arange(len(truth)))
    sep = np.minimum(truth["nearest_sep1"], truth["nearest_sep2"])
    assert comp["nearest_sep"].value == pytest.approx(sep.value)
    assert comp.meta["n_subhaloes"] == len(truth.meta["subhaloes"])
    assert comp.meta["n_subhalo_pairs"] == comp.meta["n_subhalo_flagged"] == truth["subhalo"].sum()
    assert comp.meta["false_flags"] == 0
    text = truth_paragraph(comp)
    assert f"A CDM population of {len(truth.meta['subhaloes'])} sub-haloes" in text
    if truth["subhalo"].any():
        assert "Flagged, with the nearest sub-halo: pair" in text


def test_subhalo_source_is_refused_with_cdm():
    with pytest.raises(ValueError, match="cdm"):
        simulate_demo(subhalo="cdm", n_sources=N_SOURCES, subhalo_source=1)


def test_the_default_demo_is_unchanged():
    """The default demo (seed 0, 12 sources) has no population, and one sub-haloed pair
    with its reference anomaly."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, truth = simulate_demo(seed=0)
    assert "subhaloes" not in truth.meta
    assert "nearest_sep1" not in truth.colnames
    assert np.flatnonzero(truth["subhalo"]).tolist() == [4]
    assert np.log(truth["mu_true"][4] / truth["mu_macro"][4]) == pytest.approx(-0.566, abs=5e-4)


def test_the_command_writes_the_population(tmp_path, capsys):
    from astropy.table import QTable

    from lensdual.cli import main

    out = tmp_path / "demo"
    assert main(["demo", "--subhalo", "cdm", "--outdir", str(out), "--n-sources", "9",
                 "--n-bootstrap", "100", "--null-realisations", "0", "--seed", "1"]) == 0
    text = capsys.readouterr().out
    halos = QTable.read(out / "subhaloes.ecsv")
    assert f"A CDM population of {len(halos)} sub-haloes" in text
    comparison = QTable.read(out / "truth_comparison.ecsv")
    assert "nearest_sep" in comparison.colnames
    assert comparison.meta["n_subhaloes"] == len(halos)
