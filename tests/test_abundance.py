"""Tests of lensdual.abundance (paper Sect. 5.3 and Eq. einstein-radius)."""

import numpy as np
import pytest
from astropy import constants as const
from astropy import units as u
from astropy.cosmology import FlatLambdaCDM, Planck18
from scipy import stats
from scipy.integrate import quad

from lensdual import abundance
from lensdual.abundance import (
    detection_probability_limit,
    einstein_radius,
    einstein_radius_physical,
    surface_density_limit,
)

Z_LENS, Z_SOURCE = 0.39, 2.2
M8 = 1e8 * u.Msun


def _round_sig(x, sig):
    return float(f"{x:.{sig - 1}e}")


def _hand_distances(z_lens, z_source, h0=70.0, om0=0.3):
    """Angular-diameter distances of a flat, radiation-free LCDM, integrated by hand (Mpc)."""

    def comoving(z):
        integral, _ = quad(lambda x: 1.0 / np.sqrt(om0 * (1 + x) ** 3 + 1 - om0), 0, z,
                           epsabs=0, epsrel=1e-12)
        return const.c.to_value(u.km / u.s) / h0 * integral

    dc_l, dc_s = comoving(z_lens), comoving(z_source)
    return dc_l / (1 + z_lens), dc_s / (1 + z_source), (dc_s - dc_l) / (1 + z_source)


# -- the paper's numbers -------------------------------------------------------------


def test_api():
    assert sorted(abundance.__all__) == sorted(
        ["einstein_radius", "einstein_radius_physical", "detection_probability_limit",
         "surface_density_limit"]
    )


def test_paper_einstein_radius():
    theta = einstein_radius(M8, Z_LENS, Z_SOURCE)
    assert isinstance(theta, u.Quantity)
    assert theta.unit == u.arcsec
    assert theta.isscalar
    assert _round_sig(theta.value, 3) == 0.0232
    assert theta.value == pytest.approx(0.02321, abs=5e-6)


def test_paper_einstein_radius_physical():
    radius = einstein_radius_physical(M8, Z_LENS, Z_SOURCE)
    assert radius.unit == u.kpc
    assert radius.value == pytest.approx(0.1228, abs=5e-5)
    # 5.290 kpc per arcsec at z = 0.39
    theta = einstein_radius(M8, Z_LENS, Z_SOURCE)
    assert (radius / theta).to_value(u.kpc / u.arcsec) == pytest.approx(5.290, abs=5e-4)
    # the paper's 0.388 kpc is the Einstein radius of 1e9 Msun, not of 1e8 Msun
    assert radius.value != pytest.approx(0.388, rel=0.1)
    r9 = einstein_radius_physical(1e9 * u.Msun, Z_LENS, Z_SOURCE)
    assert r9.value == pytest.approx(0.388, abs=5e-4)


def test_paper_detection_probability():
    p = detection_probability_limit(12, n_arcs=2, confidence=0.95)
    assert isinstance(p, float)
    assert round(p, 3) == 0.142
    assert p == pytest.approx(1 - 0.025 ** (1 / 24), rel=1e-14)
    assert detection_probability_limit(12) == p
    assert detection_probability_limit(12, method="paper") == p


def test_paper_surface_density_and_consistent_values():
    # The paper's 0.300 kpc^-2 is 0.142 / (pi 0.388^2): zeta = 1 with the 0.388 kpc radius.
    assert 0.142 / (np.pi * 0.388**2) == pytest.approx(0.300, abs=5e-4)
    p = detection_probability_limit(12)
    r_e = einstein_radius_physical(M8, Z_LENS, Z_SOURCE).to_value(u.kpc)

    sigma1 = surface_density_limit(p, M8, z_lens=Z_LENS, z_source=Z_SOURCE, zeta=1)
    assert sigma1.unit == u.kpc**-2
    assert sigma1.value == pytest.approx(p / (np.pi * r_e**2), rel=1e-12)
    assert sigma1.value == pytest.approx(3.007, abs=1e-3)
    assert sigma1.value != pytest.approx(0.300, rel=0.5)

    sigma3 = surface_density_limit(p, M8, z_lens=Z_LENS, z_source=Z_SOURCE)
    assert sigma3.value == pytest.approx(p / (np.pi * (3 * r_e) ** 2), rel=1e-12)
    assert sigma3.value == pytest.approx(0.334, abs=1e-3)
    assert sigma3.value == pytest.approx(sigma1.value / 9, rel=1e-12)
    assert surface_density_limit(p, M8, z_lens=Z_LENS, z_source=Z_SOURCE, zeta=3) == sigma3

    # zeta = 1 with 1e9 Msun (whose radius is the paper's 0.388 kpc) reproduces the 0.300
    sigma9 = surface_density_limit(0.142, 1e9 * u.Msun, z_lens=Z_LENS, z_source=Z_SOURCE, zeta=1)
    assert sigma9.value == pytest.approx(0.300, abs=2e-3)


# -- einstein_radius -----------------------------------------------------------------


@pytest.mark.parametrize(("z_lens", "z_source"), [(0.39, 2.2), (0.1, 0.5), (1.0, 6.0)])
def test_einstein_radius_closed_form(z_lens, z_source):
    d_l, d_s, d_ls = _hand_distances(z_lens, z_source)
    mass_kg = 3e8 * const.M_sun.value
    theta = np.sqrt(4 * const.G.value * mass_kg / const.c.value**2 * d_ls / (d_l * d_s)
                    / u.Mpc.to(u.m))
    got = einstein_radius(3e8 * u.Msun, z_lens, z_source)
    assert got.to_value(u.rad) == pytest.approx(theta, rel=1e-6)
    got_phys = einstein_radius_physical(3e8 * u.Msun, z_lens, z_source)
    assert got_phys.to_value(u.Mpc) == pytest.approx(theta * d_l, rel=1e-6)


def test_einstein_radius_sqrt_mass_scaling():
    t1 = einstein_radius(M8, Z_LENS, Z_SOURCE)
    for factor in (0.01, 4.0, 100.0):
        t = einstein_radius(factor * M8, Z_LENS, Z_SOURCE)
        assert (t / t1).to_value(u.one) == pytest.approx(np.sqrt(factor), rel=1e-12)


def test_einstein_radius_mass_units_and_arrays():
    t = einstein_radius(M8, Z_LENS, Z_SOURCE)
    assert einstein_radius(M8.to(u.kg), Z_LENS, Z_SOURCE).value == pytest.approx(t.value, rel=1e-12)

    masses = np.array([1e6, 1e7, 1e8, 1e9]) * u.Msun
    arr = einstein_radius(masses, Z_LENS, Z_SOURCE)
    assert arr.shape == (4,)
    assert arr.unit == u.arcsec
    np.testing.assert_allclose(arr.value, t.value * np.sqrt(masses.value / 1e8), rtol=1e-12)
    np.testing.assert_allclose(
        arr.value, [einstein_radius(m, Z_LENS, Z_SOURCE).value for m in masses], rtol=1e-14
    )
    grid = einstein_radius(masses.reshape(2, 2), Z_LENS, Z_SOURCE)
    assert grid.shape == (2, 2)
    phys = einstein_radius_physical(masses, Z_LENS, Z_SOURCE)
    assert phys.shape == (4,)
    sig = surface_density_limit(0.1, masses, z_lens=Z_LENS, z_source=Z_SOURCE)
    assert sig.shape == (4,)
    np.testing.assert_allclose(sig.value, 0.1 / (np.pi * (3 * phys.value) ** 2), rtol=1e-12)
    # integer redshifts are fine
    assert einstein_radius(M8, 1, 3).unit == u.arcsec


def test_custom_cosmology():
    default = einstein_radius(M8, Z_LENS, Z_SOURCE)
    explicit = einstein_radius(M8, Z_LENS, Z_SOURCE, cosmology=FlatLambdaCDM(H0=70, Om0=0.3))
    assert explicit.value == pytest.approx(default.value, rel=1e-14)

    planck = einstein_radius(M8, Z_LENS, Z_SOURCE, cosmology=Planck18)
    assert planck.value != pytest.approx(default.value, rel=1e-3)

    # All distances scale as 1/H0: theta_E ~ sqrt(H0), R_E = theta_E D_l ~ 1/sqrt(H0).
    half = FlatLambdaCDM(H0=35, Om0=0.3)
    t_half = einstein_radius(M8, Z_LENS, Z_SOURCE, cosmology=half)
    assert t_half.value == pytest.approx(default.value / np.sqrt(2), rel=1e-10)
    r_half = einstein_radius_physical(M8, Z_LENS, Z_SOURCE, cosmology=half)
    r_def = einstein_radius_physical(M8, Z_LENS, Z_SOURCE)
    assert r_half.value == pytest.approx(r_def.value * np.sqrt(2), rel=1e-10)
    s_half = surface_density_limit(0.1, M8, z_lens=Z_LENS, z_source=Z_SOURCE, cosmology=half)
    s_def = surface_density_limit(0.1, M8, z_lens=Z_LENS, z_source=Z_SOURCE)
    assert s_half.value == pytest.approx(s_def.value / 2, rel=1e-10)

    d_l, d_s, d_ls = _hand_distances(Z_LENS, Z_SOURCE, h0=35)
    theta = np.sqrt(4 * const.G * M8 / const.c**2 * d_ls / (d_l * d_s) / u.Mpc).decompose()
    assert t_half.to_value(u.rad) == pytest.approx(theta.value, rel=1e-6)


# -- detection_probability_limit -----------------------------------------------------


@pytest.mark.parametrize("confidence", [0.5, 0.68, 0.9, 0.95, 0.99])
@pytest.mark.parametrize(("n_sources", "n_arcs"), [(1, 1), (12, 2), (5, 3), (100, 2)])
def test_detection_limit_vs_binomial(n_sources, n_arcs, confidence):
    n = n_sources * n_arcs
    exact = detection_probability_limit(n_sources, n_arcs, confidence, method="exact")
    paper = detection_probability_limit(n_sources, n_arcs, confidence, method="paper")
    # zero successes in n trials: P(0 | n, p_limit) is the tail probability
    assert stats.binom.pmf(0, n, exact) == pytest.approx(1 - confidence, rel=1e-10)
    assert stats.binom.cdf(0, n, paper) == pytest.approx((1 - confidence) / 2, rel=1e-10)
    # the paper's bound is the upper end of the two-sided Clopper-Pearson interval
    ci = stats.binomtest(0, n).proportion_ci(confidence_level=confidence, method="exact")
    assert ci.high == pytest.approx(paper, rel=1e-8)
    # ... and the exact one-sided bound at confidence 1 - delta/2
    one_sided = detection_probability_limit(
        n_sources, n_arcs, 1 - (1 - confidence) / 2, method="exact"
    )
    assert one_sided == pytest.approx(paper, rel=1e-12)
    assert 0 < exact < paper < 1


def test_detection_limit_exact_paper_config():
    exact = detection_probability_limit(12, method="exact")
    assert exact == pytest.approx(1 - 0.05 ** (1 / 24), rel=1e-14)
    assert round(exact, 4) == 0.1173


def test_detection_limit_integers_and_monotonic():
    assert detection_probability_limit(np.int64(12), np.int32(2)) == detection_probability_limit(
        12, 2
    )
    # 12 sources on 2 arcs are 24 trials, like 24 sources on 1 arc
    assert detection_probability_limit(12, 2) == pytest.approx(
        detection_probability_limit(24, 1), rel=1e-14
    )
    limits = [detection_probability_limit(n) for n in (1, 2, 5, 10, 100, 10**6)]
    assert all(a > b for a, b in zip(limits, limits[1:], strict=False))
    # tiny limits keep full precision
    big = detection_probability_limit(10**9, method="exact")
    assert big == pytest.approx(-np.log(0.05) / (2 * 10**9), rel=1e-8)


def test_surface_density_p_det_one_allowed():
    s = surface_density_limit(1.0, M8, z_lens=Z_LENS, z_source=Z_SOURCE, zeta=0.5)
    r = einstein_radius_physical(M8, Z_LENS, Z_SOURCE)
    assert s.value == pytest.approx(1 / (np.pi * (0.5 * r.value) ** 2), rel=1e-12)


# -- bad input -----------------------------------------------------------------------


@pytest.mark.parametrize("func", [einstein_radius, einstein_radius_physical])
def test_einstein_radius_bad_input(func):
    with pytest.raises(ValueError, match="mass must be finite and positive"):
        func(-1e8 * u.Msun, Z_LENS, Z_SOURCE)
    with pytest.raises(ValueError, match="mass must be finite and positive"):
        func(0 * u.Msun, Z_LENS, Z_SOURCE)
    with pytest.raises(ValueError, match="mass must be finite and positive"):
        func([1e8, np.nan] * u.Msun, Z_LENS, Z_SOURCE)
    with pytest.raises(TypeError, match="mass must be an astropy Quantity with mass units"):
        func(1e8, Z_LENS, Z_SOURCE)
    with pytest.raises(TypeError, match="mass must be an astropy Quantity with mass units"):
        func(np.array([1e8]), Z_LENS, Z_SOURCE)
    with pytest.raises(TypeError, match="mass must have mass units"):
        func(1e8 * u.kpc, Z_LENS, Z_SOURCE)
    with pytest.raises(ValueError, match="z_source must be larger than z_lens"):
        func(M8, 2.2, 0.39)
    with pytest.raises(ValueError, match="z_source must be larger than z_lens"):
        func(M8, 0.39, 0.39)
    with pytest.raises(ValueError, match="z_lens must be > 0"):
        func(M8, 0.0, 2.2)
    with pytest.raises(ValueError, match="z_lens must be > 0"):
        func(M8, -0.1, 2.2)
    with pytest.raises(ValueError, match="z_source must be finite"):
        func(M8, 0.39, np.inf)
    with pytest.raises(TypeError, match="z_lens must be a real number"):
        func(M8, "0.39", 2.2)
    with pytest.raises(TypeError, match="z_source must be a real number"):
        func(M8, 0.39, [2.2])
    with pytest.raises(TypeError, match="cosmology must be an astropy.cosmology.Cosmology"):
        func(M8, Z_LENS, Z_SOURCE, cosmology="Planck18")


@pytest.mark.parametrize("confidence", [0, 1, 0.0, 1.0, -0.5, 1.5, 95])
def test_detection_limit_bad_confidence(confidence):
    with pytest.raises(ValueError, match="confidence must be strictly between 0 and 1"):
        detection_probability_limit(12, confidence=confidence)


def test_detection_limit_bad_input():
    with pytest.raises(ValueError, match="confidence must be finite"):
        detection_probability_limit(12, confidence=np.nan)
    with pytest.raises(TypeError, match="confidence must be a real number"):
        detection_probability_limit(12, confidence="95%")
    with pytest.raises(ValueError, match="n_sources must be >= 1"):
        detection_probability_limit(0)
    with pytest.raises(ValueError, match="n_sources must be >= 1"):
        detection_probability_limit(-3)
    with pytest.raises(TypeError, match="n_sources must be an integer"):
        detection_probability_limit(2.5)
    with pytest.raises(TypeError, match="n_sources must be an integer"):
        detection_probability_limit(12.0)
    with pytest.raises(TypeError, match="n_sources must be an integer"):
        detection_probability_limit(True)
    with pytest.raises(ValueError, match="n_arcs must be >= 1"):
        detection_probability_limit(12, n_arcs=0)
    with pytest.raises(TypeError, match="n_arcs must be an integer"):
        detection_probability_limit(12, n_arcs=2.5)
    with pytest.raises(ValueError, match="method must be one of"):
        detection_probability_limit(12, method="bayesian")
    with pytest.raises(ValueError, match="method must be one of"):
        detection_probability_limit(12, method="Paper")
    with pytest.raises(ValueError, match="method must be one of"):
        detection_probability_limit(12, method=None)


@pytest.mark.parametrize("p_det", [0, 0.0, -0.1, 1.0000001, 2])
def test_surface_density_bad_p_det(p_det):
    with pytest.raises(ValueError, match=r"p_det must be in \(0, 1\]"):
        surface_density_limit(p_det, M8, z_lens=Z_LENS, z_source=Z_SOURCE)


@pytest.mark.parametrize("zeta", [0, 0.0, -3])
def test_surface_density_bad_zeta(zeta):
    with pytest.raises(ValueError, match="zeta must be > 0"):
        surface_density_limit(0.1, M8, z_lens=Z_LENS, z_source=Z_SOURCE, zeta=zeta)


def test_surface_density_bad_input():
    with pytest.raises(ValueError, match="zeta must be finite"):
        surface_density_limit(0.1, M8, z_lens=Z_LENS, z_source=Z_SOURCE, zeta=np.inf)
    with pytest.raises(TypeError, match="zeta must be a real number"):
        surface_density_limit(0.1, M8, z_lens=Z_LENS, z_source=Z_SOURCE, zeta="3")
    with pytest.raises(ValueError, match="p_det must be finite"):
        surface_density_limit(np.nan, M8, z_lens=Z_LENS, z_source=Z_SOURCE)
    with pytest.raises(TypeError, match="p_det must be a real number"):
        surface_density_limit(0.1 * u.one, M8, z_lens=Z_LENS, z_source=Z_SOURCE)
    with pytest.raises(ValueError, match="mass must be finite and positive"):
        surface_density_limit(0.1, -M8, z_lens=Z_LENS, z_source=Z_SOURCE)
    with pytest.raises(TypeError, match="mass must be an astropy Quantity"):
        surface_density_limit(0.1, 1e8, z_lens=Z_LENS, z_source=Z_SOURCE)
    with pytest.raises(ValueError, match="z_source must be larger than z_lens"):
        surface_density_limit(0.1, M8, z_lens=Z_SOURCE, z_source=Z_LENS)
    with pytest.raises(TypeError, match="cosmology must be an astropy.cosmology.Cosmology"):
        surface_density_limit(0.1, M8, z_lens=Z_LENS, z_source=Z_SOURCE, cosmology=70)
    # redshifts are keyword-only
    with pytest.raises(TypeError):
        surface_density_limit(0.1, M8, Z_LENS, Z_SOURCE)
