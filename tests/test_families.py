"""Tests of lensdual.simulation.families: clean constellations of the lens families."""

import numpy as np
import pytest
from astropy import units as u
from scipy.spatial.distance import cdist, pdist

from lensdual.simulation import (
    FAMILIES,
    FAMILY_PARAMETERS,
    calibration_system,
    clean_constellation,
)
from lensdual.simulation import families as fam_module

LENSTRONOMY_FAMILIES = ("cluster_fold", "cluster_cusp", "galaxy_fold", "smacs_analog",
                        "galaxy_sie_compact", "group_fold", "galaxy_epl_compact")


def _system_or_skip(family):
    try:
        return calibration_system(family)
    except FileNotFoundError as err:
        pytest.skip(str(err))


def _xy(pairs, arc):
    return np.column_stack([pairs[f"x{arc}"].to_value(u.arcsec),
                            pairs[f"y{arc}"].to_value(u.arcsec)])


def _independent_magnification(system, xy):
    """Magnification straight from the lens model (lenstronomy or Lenstool kernels)."""
    return np.asarray(system.lens_model.magnification(xy[:, 0], xy[:, 1], system.kwargs_lens))


@pytest.mark.parametrize("family", FAMILIES)
def test_clean_constellation_is_resolved_exact_and_on_one_arc_pair(family):
    system, info = _system_or_skip(family)
    n = 20
    pairs = clean_constellation(family, n, seed=3)
    assert len(pairs) == n
    assert pairs.meta["family"] == family
    x1, x2 = _xy(pairs, 1), _xy(pairs, 2)
    # every image resolved: on L1, on L2 and across the arcs
    assert pdist(x1).min() >= 0.08
    assert pdist(x2).min() >= 0.08
    assert cdist(x1, x2).min() >= 0.08
    # one unmerged image per arc, L1 positive and L2 negative parity
    assert np.all(pairs["n_images1"] == 1) and np.all(pairs["n_images2"] == 1)
    assert np.all(pairs["mu1"] > 0) and np.all(pairs["mu2"] < 0)
    # the positions are images of the sources (1e-6 arcsec)
    beta = np.column_stack([pairs["beta_x"].to_value(u.arcsec),
                            pairs["beta_y"].to_value(u.arcsec)])
    for xy in (x1, x2):
        np.testing.assert_allclose(system.ray_shoot(xy * u.arcsec).to_value(u.arcsec), beta,
                                   atol=1e-6)
    # the sources lie in the family's region
    from matplotlib.path import Path

    assert Path(info["source_region"].to_value(u.arcsec)).contains_points(beta).all()
    # mu_true is the ratio of the model's own magnifications (lenstronomy / Lenstool)
    mu1 = _independent_magnification(system, x1)
    mu2 = _independent_magnification(system, x2)
    np.testing.assert_allclose(pairs["mu1"], mu1, rtol=1e-8)
    np.testing.assert_allclose(pairs["mu_true"], np.abs(mu1 / mu2), rtol=1e-8)
    # exact fluxes: their ratio is mu_true, errors are the default 2 %
    for band in pairs.meta["bands"]:
        f1, f2 = pairs[f"flux1_{band}"], pairs[f"flux2_{band}"]
        np.testing.assert_allclose((f1 / f2).to_value(u.one), pairs["mu_true"], rtol=1e-12)
        np.testing.assert_allclose((pairs[f"flux_err1_{band}"] / f1).to_value(u.one), 0.02)
    # one pair of arcs: the Jacobian keeps its sign between neighbouring images
    assert not fam_module._parity_breaks(system, x1, 1, k=6)
    assert not fam_module._parity_breaks(system, x2, -1, k=6)


def test_lenstronomy_families_match_a_fresh_lenstronomy_model():
    """mu_true against a LensModel built here from the components (not the system's)."""
    from lenstronomy.LensModel.lens_model import LensModel

    for family in LENSTRONOMY_FAMILIES:
        system, _ = calibration_system(family)
        model = LensModel([c.profile for c in system.components])
        kwargs = [dict(c.kwargs) for c in system.components]
        pairs = clean_constellation(family, 8, seed=11)
        mu1 = model.magnification(*_xy(pairs, 1).T, kwargs)
        mu2 = model.magnification(*_xy(pairs, 2).T, kwargs)
        np.testing.assert_allclose(pairs["mu_true"], np.abs(mu1 / mu2), rtol=1e-8,
                                   err_msg=family)


@pytest.mark.parametrize("n", [8, 40])
def test_exact_number_of_sources_at_the_limits(n):
    pairs = clean_constellation("smacs_analog", n, seed=0)
    assert len(pairs) == n
    assert len(np.unique(pairs["source"])) == n
    assert pdist(_xy(pairs, 1)).min() >= 0.08 and pdist(_xy(pairs, 2)).min() >= 0.08


def test_reproducible_with_seed():
    a = clean_constellation("cluster_fold", 12, seed=7)
    b = clean_constellation("cluster_fold", 12, seed=7)
    c = clean_constellation("cluster_fold", 12, seed=8)
    for col in a.colnames:
        np.testing.assert_array_equal(np.asarray(a[col]), np.asarray(b[col]))
    assert not np.allclose(_xy(a, 1), _xy(c, 1))


def test_larger_min_separation_is_honoured():
    pairs = clean_constellation("galaxy_fold", 8, seed=1, min_separation=0.2 * u.arcsec)
    x1, x2 = _xy(pairs, 1), _xy(pairs, 2)
    assert min(pdist(x1).min(), pdist(x2).min(), cdist(x1, x2).min()) >= 0.2
    assert pairs.meta["min_separation"] == 0.2 * u.arcsec


def test_galaxy_fold_spans_a_sizeable_part_of_the_arc():
    pairs = clean_constellation("galaxy_fold", 30, seed=2)
    assert pdist(_xy(pairs, 1)).max() > 1.5
    assert pdist(_xy(pairs, 2)).max() > 1.0


def test_calibration_system_info_and_cache():
    system, info = calibration_system("cluster_cusp")
    again, info2 = calibration_system("cluster_cusp")
    assert again is system  # cached per process
    info2["reference"] = None  # a copy: the cache is untouched
    assert calibration_system("cluster_cusp")[1]["reference"].shape == (2, 2)
    assert info["source_region"].unit == u.arcsec
    assert info["mu_centre"][0] > 0 > info["mu_centre"][1]
    assert info["z_lens"] == FAMILY_PARAMETERS["cluster_cusp"]["z_lens"]
    assert len(system.components) == 2  # main halo + one member, no sub-halo


def test_errors():
    with pytest.raises(ValueError, match="family must be one of .*cluster_fold"):
        clean_constellation("cluster", 10, seed=0)
    with pytest.raises(ValueError, match="family must be one of"):
        calibration_system("galaxy")
    for n in (7, 41):
        with pytest.raises(ValueError, match="n_sources must be between 8 and 40"):
            clean_constellation("smacs_analog", n, seed=0)
    with pytest.raises(TypeError, match="n_sources must be an integer"):
        clean_constellation("smacs_analog", 10.0, seed=0)
    with pytest.raises(ValueError, match="min_separation"):
        clean_constellation("smacs_analog", 10, seed=0, min_separation=0 * u.arcsec)
    with pytest.raises(RuntimeError, match="could not place 40 sources"):
        clean_constellation("smacs_analog", 40, seed=0, min_separation=0.5 * u.arcsec,
                            max_tries=2)


def test_a_lenstool_family_without_its_environment_variable_says_which(monkeypatch):
    monkeypatch.delenv("LENSDUAL_SMACS0723_DIR", raising=False)
    monkeypatch.setattr(fam_module, "_calibrated", fam_module._calibrated.__wrapped__)
    with pytest.raises(FileNotFoundError, match="set the environment variable "
                                                "LENSDUAL_SMACS0723_DIR to the folder"):
        calibration_system("smacs_lenstool")


def test_smacs_lenstool_without_data_raises(monkeypatch, tmp_path):
    monkeypatch.setenv("LENSDUAL_SMACS0723_DIR", str(tmp_path))
    monkeypatch.setattr(fam_module, "_calibrated", fam_module._calibrated.__wrapped__)
    with pytest.raises(FileNotFoundError, match="SMACS0723 Lenstool model"):
        calibration_system("smacs_lenstool")
    with pytest.raises(FileNotFoundError):
        clean_constellation("smacs_lenstool", 8, seed=0)


@pytest.mark.parametrize("family", ["macs1149_lenstool", "a2744_lenstool", "a370_lenstool",
                                    "as1063_lenstool", "as1063_s13_lenstool",
                                    "a2744_s3_lenstool", "macs1149_s5_lenstool"])
def test_hff_lenstool_without_data_raises(family, monkeypatch, tmp_path):
    monkeypatch.setenv("LENSDUAL_HFF_DIR", str(tmp_path))
    monkeypatch.setattr(fam_module, "_calibrated", fam_module._calibrated.__wrapped__)
    with pytest.raises(FileNotFoundError, match="LENSDUAL_HFF_DIR"):
        calibration_system(family)


def test_noisy_constellation_adds_the_stated_noise():
    import astropy.units as u

    from lensdual.simulation import clean_constellation, noisy_constellation

    clean = clean_constellation("cluster_fold", 40, seed=2)
    noisy = noisy_constellation(clean, sigma_pos=5 * u.mas, flux_rel_err=0.03, seed=4)
    dpos = np.concatenate([(noisy[c] - clean[c]).to_value(u.mas)
                           for c in ("x1", "y1", "x2", "y2")])
    assert np.std(dpos) == pytest.approx(5.0, rel=0.2)
    rel = np.concatenate([np.asarray(noisy[f"flux{k}_{b}"] / clean[f"flux{k}_{b}"]) - 1
                          for b in clean.meta["bands"] for k in "12"])
    assert np.std(rel) == pytest.approx(0.03, rel=0.2)
    band = clean.meta["bands"][0]
    assert np.allclose(noisy[f"flux_err1_{band}"], 0.03 * noisy[f"flux1_{band}"])
    assert np.array_equal(noisy["mu_true"], clean["mu_true"])
    again = noisy_constellation(clean, sigma_pos=5 * u.mas, flux_rel_err=0.03, seed=4)
    assert np.array_equal(again["x1"], noisy["x1"])
    with pytest.raises(ValueError, match="flux_rel_err"):
        noisy_constellation(clean, sigma_pos=5 * u.mas, flux_rel_err=-0.1)
    with pytest.raises(TypeError, match="sigma_pos"):
        noisy_constellation(clean, sigma_pos=0.005, flux_rel_err=0.02)
