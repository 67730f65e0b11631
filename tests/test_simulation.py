"""Tests of lensdual.simulation: haloes, LensSystem, the SMACS0723 analogue."""

import numpy as np
import pytest
from astropy import constants as const
from astropy import units as u
from astropy.cosmology import FlatLambdaCDM, Planck18

from lensdual.simulation import (
    LensComponent,
    LensSystem,
    elliptical_nfw_halo,
    mass_concentration,
    nfw_angular_parameters,
    tnfw_halo,
)

ZL, ZS = 0.39, 2.2
COSMO = FlatLambdaCDM(H0=70, Om0=0.3)


# --------------------------------------------------------------------------- haloes


@pytest.mark.parametrize(("mass", "c_table"), [(2e12, 9.7), (1e11, 13.5), (1e9, 22.2),
                                                (1e8, 28.6)])
def test_mass_concentration_reproduces_table1(mass, c_table):
    assert mass_concentration(mass * u.Msun) == pytest.approx(c_table, abs=0.05)


def test_mass_concentration_array_and_errors():
    c = mass_concentration([1e8, 1e12] * u.Msun)
    np.testing.assert_allclose(c, [10**1.020 * 1e-4**-0.109, 10**1.020])
    with pytest.raises(TypeError, match="mass must be an astropy Quantity"):
        mass_concentration(1e8)
    with pytest.raises(ValueError, match="mass must be finite and positive"):
        mass_concentration(-1e8 * u.Msun)


@pytest.mark.parametrize(("mass", "c"), [(5e14, 9.6), (1e8, 100.0), (2e12, 9.7)])
def test_nfw_angles_closed_form(mass, c):
    """Rs and alpha_Rs against the NFW closed form, written out independently."""
    rs, alpha_rs = nfw_angular_parameters(mass * u.Msun, c, z_lens=ZL, z_source=ZS)
    rho_c = COSMO.critical_density(ZL)
    r200 = (3 * mass * u.Msun / (4 * np.pi * 200 * rho_c)) ** (1 / 3)
    r_s = (r200 / c).to(u.Mpc)
    d_l = COSMO.angular_diameter_distance(ZL)
    d_s = COSMO.angular_diameter_distance(ZS)
    d_ls = COSMO.angular_diameter_distance(ZL, ZS)
    rs_angle = (r_s / d_l).to(u.arcsec, u.dimensionless_angles())
    rho_s = 200 / 3 * rho_c * c**3 / (np.log(1 + c) - c / (1 + c))
    sigma_cr = const.c**2 * d_s / (4 * np.pi * const.G * d_l * d_ls)
    kappa_s = (rho_s * r_s / sigma_cr).decompose()
    alpha = 4 * kappa_s * rs_angle * (1 + np.log(0.5))
    assert rs.to_value(u.arcsec) == pytest.approx(rs_angle.value, rel=1e-6)
    # lenstronomy carries its own values of G, c and the Mpc (3e-4 from astropy's)
    assert alpha_rs.to_value(u.arcsec) == pytest.approx(alpha.value, rel=1e-3)


def test_tnfw_component():
    comp = tnfw_halo(1e8 * u.Msun, position=(1.0, -2.0) * u.arcsec, z_lens=ZL, z_source=ZS)
    assert comp.profile == "TNFW"
    assert comp.kwargs["r_trunc"] == pytest.approx(30 * comp.kwargs["Rs"])
    assert comp.kwargs["center_x"] == 1.0 and comp.kwargs["center_y"] == -2.0
    assert comp.meta["concentration"] == pytest.approx(28.6, abs=0.05)
    over = tnfw_halo(1e8 * u.Msun, 100, z_lens=ZL, z_source=ZS)
    assert over.kwargs["Rs"] < comp.kwargs["Rs"]
    other = tnfw_halo(1e8 * u.Msun, z_lens=ZL, z_source=ZS, cosmology=Planck18)
    assert other.kwargs["alpha_Rs"] != comp.kwargs["alpha_Rs"]


def test_elliptical_halo_axis_ratio():
    from lenstronomy.Util.param_util import ellipticity2phi_q

    comp = elliptical_nfw_halo(5e14 * u.Msun, 9.6, axis_ratio=0.85,
                               position_angle=30 * u.deg, z_lens=ZL, z_source=ZS)
    phi, q = ellipticity2phi_q(comp.kwargs["e1"], comp.kwargs["e2"])
    assert q == pytest.approx(0.85)
    assert np.rad2deg(phi) == pytest.approx(30.0)
    assert comp.profile == "NFW_ELLIPSE_CSE"


@pytest.mark.parametrize(
    ("call", "exc", "match"),
    [
        (lambda: tnfw_halo(1e8 * u.Msun, -3, z_lens=ZL, z_source=ZS), ValueError,
         "concentration must be > 0"),
        (lambda: tnfw_halo(0 * u.Msun, z_lens=ZL, z_source=ZS), ValueError,
         "mass must be finite and positive"),
        (lambda: tnfw_halo(1e8 * u.kpc, z_lens=ZL, z_source=ZS), TypeError,
         "mass must have mass units"),
        (lambda: tnfw_halo(1e8 * u.Msun, z_lens=2.2, z_source=0.39), ValueError,
         "z_source must be larger than z_lens"),
        (lambda: tnfw_halo(1e8 * u.Msun, z_lens=0.5, z_source=0.5), ValueError,
         "z_source must be larger than z_lens"),
        (lambda: tnfw_halo(1e8 * u.Msun, position=(1, 2), z_lens=ZL, z_source=ZS), TypeError,
         "position must be an angle Quantity"),
        (lambda: tnfw_halo(1e8 * u.Msun, truncation=0, z_lens=ZL, z_source=ZS), ValueError,
         "truncation must be > 0"),
        (lambda: elliptical_nfw_halo(5e14 * u.Msun, axis_ratio=1.5, z_lens=ZL, z_source=ZS),
         ValueError, "axis_ratio must be <= 1"),
        (lambda: elliptical_nfw_halo(5e14 * u.Msun, position_angle=30, z_lens=ZL, z_source=ZS),
         TypeError, "position_angle must be an angle Quantity"),
    ],
)
def test_halo_bad_input(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


# --------------------------------------------------------------------------- LensSystem


@pytest.fixture(scope="module")
def cluster():
    main = elliptical_nfw_halo(5e14 * u.Msun, 9.6, axis_ratio=0.85, z_lens=ZL, z_source=ZS)
    member = tnfw_halo(2e12 * u.Msun, position=(3.0, -6.5) * u.arcsec, z_lens=ZL, z_source=ZS)
    return LensSystem([main, member], z_lens=ZL, z_source=ZS)


def test_lens_system_matches_lenstronomy(cluster):
    from lenstronomy.LensModel.lens_model import LensModel

    rng = np.random.default_rng(0)
    theta = rng.uniform(-20, 20, (50, 2))
    model = LensModel(["NFW_ELLIPSE_CSE", "TNFW"])
    kw = [c.kwargs for c in cluster.components]
    bx, by = model.ray_shooting(theta[:, 0], theta[:, 1], kw)
    np.testing.assert_allclose(cluster.ray_shoot(theta * u.arcsec).value,
                               np.column_stack([bx, by]), rtol=1e-12)
    np.testing.assert_allclose(cluster.deflection(theta * u.arcsec).value,
                               theta - np.column_stack([bx, by]), atol=1e-10)
    np.testing.assert_allclose(cluster.magnification(theta * u.arcsec),
                               model.magnification(theta[:, 0], theta[:, 1], kw), rtol=1e-10)


def test_jacobian_is_derivative_of_ray_shoot(cluster):
    """The analytic Jacobian against central finite differences of beta(theta)."""
    rng = np.random.default_rng(1)
    theta = rng.uniform(-15, 15, (20, 2))
    h = 1e-5
    jac = cluster.jacobian(theta * u.arcsec)
    for j, step in enumerate(np.eye(2) * h):
        plus = cluster.ray_shoot((theta + step) * u.arcsec).value
        minus = cluster.ray_shoot((theta - step) * u.arcsec).value
        np.testing.assert_allclose(jac[:, :, j], (plus - minus) / (2 * h), atol=1e-6)


def test_critical_curve_of_sis_is_einstein_ring():
    sis = LensSystem([LensComponent("SIS", {"theta_E": 1.5, "center_x": 0.2,
                                            "center_y": -0.1})], z_lens=ZL, z_source=ZS)
    curves = sis.critical_curves(half_width=3 * u.arcsec, grid_spacing=0.02 * u.arcsec)
    assert len(curves) == 1
    r = np.hypot(curves[0][:, 0].value - 0.2, curves[0][:, 1].value + 0.1)
    np.testing.assert_allclose(r, 1.5, atol=2e-3)
    np.testing.assert_allclose(curves[0][0].value, curves[0][-1].value)  # closed
    caustic = sis.caustics(half_width=3 * u.arcsec, grid_spacing=0.02 * u.arcsec)[0]
    np.testing.assert_allclose(caustic.value, [[0.2, -0.1]] * len(caustic), atol=2e-3)


def test_critical_curves_have_vanishing_determinant(cluster):
    curves = cluster.critical_curves(half_width=25 * u.arcsec, grid_spacing=0.1 * u.arcsec)
    assert len(curves) >= 2  # radial and tangential
    for curve in curves:
        mu = cluster.magnification(curve)
        assert np.median(np.abs(mu)) > 50  # det A ~ 0 on the curve


@pytest.mark.parametrize(
    ("make", "exc", "match"),
    [
        (lambda: LensSystem([], z_lens=ZL, z_source=ZS), ValueError, "at least one component"),
        (lambda: LensSystem([("SIS", {})], z_lens=ZL, z_source=ZS), TypeError,
         "component 0 must be a LensComponent"),
        (lambda: LensSystem([LensComponent("NOPE", {})], z_lens=ZL, z_source=ZS), ValueError,
         "unknown lenstronomy profile 'NOPE'"),
        (lambda: LensSystem([LensComponent("SIS", {"theta_E": 1.0, "center_x": 0})],
                            z_lens=ZL, z_source=ZS), ValueError,
         r"missing keyword\(s\) \['center_y'\]"),
        (lambda: LensSystem([LensComponent("SIS", {"theta_E": 1.0, "center_x": 0,
                                                   "center_y": 0, "q": 1})],
                            z_lens=ZL, z_source=ZS), ValueError,
         r"unknown keyword\(s\) \['q'\]"),
        (lambda: LensSystem([LensComponent("SIS", {"theta_E": np.nan, "center_x": 0,
                                                   "center_y": 0})],
                            z_lens=ZL, z_source=ZS), ValueError, "non-finite value"),
        (lambda: LensSystem([LensComponent("SIS", {"theta_E": 1.0, "center_x": 0,
                                                   "center_y": 0})],
                            z_lens=1.0, z_source=0.5), ValueError,
         "z_source must be larger than z_lens"),
    ],
)
def test_lens_system_bad_input(make, exc, match):
    with pytest.raises(exc, match=match):
        make()


def test_lens_system_positions_need_units(cluster):
    with pytest.raises(TypeError, match="theta must be an astropy Quantity"):
        cluster.ray_shoot(np.zeros((3, 2)))
    with pytest.raises(ValueError, match=r"theta must have shape \(N, 2\)"):
        cluster.magnification(np.zeros(3) * u.arcsec)


def test_add_returns_new_system(cluster):
    sub = tnfw_halo(1e8 * u.Msun, 100, (1.0, 1.0) * u.arcsec, z_lens=ZL, z_source=ZS,
                    label="sub")
    bigger = cluster.add(sub)
    assert len(bigger.components) == len(cluster.components) + 1
    assert "sub" in repr(bigger)
    theta = [[1.05, 1.0]] * u.arcsec
    assert not np.allclose(bigger.deflection(theta), cluster.deflection(theta))


def test_from_model_wraps_any_lenstronomy_like_model(cluster):
    wrapped = LensSystem.from_model(cluster.lens_model, cluster.kwargs_lens, z_lens=ZL,
                                    z_source=ZS)
    theta = np.random.default_rng(3).uniform(-10, 10, (10, 2)) * u.arcsec
    np.testing.assert_array_equal(wrapped.magnification(theta), cluster.magnification(theta))
    with pytest.raises(TypeError, match="add\\(\\) needs a system built from LensComponents"):
        wrapped.add(tnfw_halo(1e8 * u.Msun, z_lens=ZL, z_source=ZS))
    with pytest.raises(TypeError, match="model must have a ray_shooting"):
        LensSystem.from_model(object(), z_lens=ZL, z_source=ZS)


# --------------------------------------------------------------------------- constellations


@pytest.fixture(scope="module")
def analog():
    from lensdual.simulation import smacs0723_analog

    system = smacs0723_analog(seed=1)
    return system, system.constellation(seed=2)


def test_smacs0723_analog_components():
    from lensdual.simulation import SMACS0723, smacs0723_analog

    plain = smacs0723_analog(seed=0)
    assert [c.profile for c in plain.components] == ["NFW_ELLIPSE_CSE"]
    assert plain.sources.shape == (16, 2)
    centre = SMACS0723["source_centre"].to_value(u.arcsec)
    assert np.allclose(plain.sources.value.mean(axis=0), centre, atol=0.06)
    members = smacs0723_analog(perturbers=True, seed=0, n_sources=5)
    assert [c.profile for c in members.components] == ["NFW_ELLIPSE_CSE", "TNFW", "TNFW"]
    assert members.components[1].meta["mass"] == 2e12 * u.Msun
    np.testing.assert_array_equal(smacs0723_analog(seed=3).sources,
                                  smacs0723_analog(seed=3).sources)


def test_smacs0723_analog_subhalo_sits_on_l2_image():
    from lensdual.simulation import smacs0723_analog

    base = smacs0723_analog(seed=4)
    with_sub = smacs0723_analog(seed=4, subhalo="overconcentrated", subhalo_source=2)
    sub = with_sub.components[-1]
    assert sub.profile == "TNFW" and sub.meta["concentration"] == 100.0
    pairs = base.constellation()
    row = np.flatnonzero(np.asarray(pairs["source"]) == 2)[0]
    assert sub.kwargs["center_x"] == pytest.approx(pairs["x2"][row].value)
    assert sub.kwargs["center_y"] == pytest.approx(pairs["y2"][row].value)
    massive = smacs0723_analog(seed=4, subhalo="massive").components[-1]
    assert massive.meta["concentration"] == pytest.approx(22.2, abs=0.05)


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"subhalo": "huge"}, ValueError, "subhalo must be None, a LensComponent or one of"),
        ({"n_sources": 2}, ValueError, "n_sources must be >= 3"),
        ({"perturbers": "yes"}, TypeError, "perturbers must be True or False"),
        ({"subhalo": "small", "subhalo_source": 16}, ValueError,
         "subhalo_source must be < n_sources"),
    ],
)
def test_smacs0723_analog_bad_input(kwargs, exc, match):
    from lensdual.simulation import smacs0723_analog

    with pytest.raises(exc, match=match):
        smacs0723_analog(**kwargs)


def test_constellation_schema_and_truth(analog):
    system, pairs = analog
    for name in ("pair_id", "x1", "y1", "x2", "y2", "mu_true", "mu1", "mu2",
                 "flux1_F150W", "flux2_F200W", "flux_err1_F150W", "flux_err2_F200W"):
        assert name in pairs.colnames
    assert pairs.meta["bands"] == ["F150W", "F200W"]
    assert len(pairs) == 16
    assert (pairs["mu1"] > 0).all() and (pairs["mu2"] < 0).all()
    np.testing.assert_array_equal(pairs["pair_id"], np.arange(1, 17))
    beta = np.column_stack([pairs["beta_x"], pairs["beta_y"]])
    for arc in ("1", "2"):
        theta = np.column_stack([pairs[f"x{arc}"], pairs[f"y{arc}"]])
        np.testing.assert_allclose(system.ray_shoot(theta).value, beta.value, atol=1e-7)
        np.testing.assert_allclose(system.magnification(theta), pairs[f"mu{arc}"], rtol=1e-8)
    np.testing.assert_allclose(pairs["mu_true"], np.abs(pairs["mu1"] / pairs["mu2"]))
    for band in pairs.meta["bands"]:
        ratio = pairs[f"flux1_{band}"] / pairs[f"flux2_{band}"]
        np.testing.assert_allclose(ratio, pairs["mu_true"], rtol=1e-10)
    colour1 = pairs["flux1_F150W"] / pairs["flux1_F200W"]
    colour2 = pairs["flux2_F150W"] / pairs["flux2_F200W"]
    np.testing.assert_allclose(colour1, colour2, rtol=1e-10)  # same colour on both arcs


def test_constellation_passes_duality_and_estimators(analog):
    from lensdual.duality import check_duality

    _, pairs = analog
    res = check_duality(pairs, method="quad2", sigma_pos=0.005 * u.arcsec, n_bootstrap=100,
                        seed=0)
    assert not res["anomalous"].any()
    # a fold: every estimated det J is negative; the table reports the parity
    # where 1 / ln_mu_size_err reaches the threshold (0 elsewhere)
    assert (np.linalg.det(np.asarray(res["jacobian"], dtype=float)) < 0).all()
    determined = np.asarray(res["parity_snr"]) >= 3.0
    assert determined.sum() >= 10
    np.testing.assert_array_equal(res["parity"], np.where(determined, -1, 0))
    err = np.abs(res["mu_size"] / pairs["mu_true"] - 1)
    assert np.median(err) < 0.01


def test_solve_images_table(analog):
    system, _ = analog
    beta = system.sources[:3]
    images = system.solve_images(beta)
    assert set(images.colnames) >= {"source", "x", "y", "magnification", "parity", "arc"}
    assert set(np.asarray(images["source"])) == {0, 1, 2}
    theta = np.column_stack([images["x"], images["y"]])
    np.testing.assert_allclose(system.ray_shoot(theta).value,
                               beta.value[np.asarray(images["source"])], atol=1e-7)
    # odd number of images for a non-singular lens
    assert all(np.sum(images["source"] == k) % 2 == 1 for k in range(3))


def test_merge_images_sums_unresolved_micro_images():
    from astropy.table import QTable

    from lensdual._lens.system import _merge_images

    tab = QTable()
    tab["source"] = [0, 0, 0, 1]
    tab["x"] = [0.0, 0.01, 3.0, 5.0] * u.arcsec
    tab["y"] = [0.0, 0.0, 0.0, 5.0] * u.arcsec
    tab["magnification"] = [-6.0, 2.0, -1.0, -4.0]
    merged = _merge_images(tab, 0.05)
    x, y, mu, n = merged[0]
    assert mu == pytest.approx(-8.0) and n == 2
    assert x == pytest.approx(0.01 * 2 / 8)
    assert merged[1][2] == -4.0 and merged[1][3] == 1


def test_constellation_drops_sources_off_the_arcs(analog):
    from lensdual.exceptions import LensdualWarning

    system, _ = analog
    far = np.vstack([system.sources.value, [[30.0, 30.0]]]) * u.arcsec  # singly imaged
    with pytest.warns(LensdualWarning, match=r"source\(s\) \[16\] have no image"):
        pairs = system.constellation(far)
    assert 16 not in pairs["source"]
    with pytest.raises(ValueError, match="no source positions"):
        LensSystem(system.components, z_lens=ZL, z_source=ZS).constellation()
