"""Finite-size star clusters in the mock images (``render_mock_images(r_eff=...)``)."""

import math

import astropy.units as u
import numpy as np
import pytest
from astropy.table import QTable

from lensdual.simulation import (
    CLUSTER_RADIUS_RANGE,
    LensSystem,
    draw_cluster_radii,
    render_mock_images,
    smacs0723_analog,
)
from lensdual.simulation._clusters import source_sigmas

# a constant lens map (convergence + shear): the first-order image of a
# Gaussian source is exact, so ray tracing and the ellipse must agree
KAPPA, GAMMA1, GAMMA2 = 0.5, 0.2, 0.2
THETA0 = np.array([0.31, -0.17])  # the cluster's image on arc L1 [arcsec]


@pytest.fixture(scope="module")
def sheet():
    from lenstronomy.LensModel.lens_model import LensModel

    model = LensModel(["CONVERGENCE", "SHEAR"])
    kwargs = [{"kappa": KAPPA, "ra_0": 0.0, "dec_0": 0.0},
              {"gamma1": GAMMA1, "gamma2": GAMMA2, "ra_0": 0.0, "dec_0": 0.0}]
    return LensSystem.from_model(model, kwargs, z_lens=0.39, z_source=2.2)


def _jacobian():
    return np.array([[1 - KAPPA - GAMMA1, -GAMMA2], [-GAMMA2, 1 - KAPPA + GAMMA1]])


def _pairs(flux):
    """One pair: the cluster on L1 at THETA0, its partner far away on L2."""
    t = QTable()
    t["x1"], t["y1"] = [THETA0[0]] * u.arcsec, [THETA0[1]] * u.arcsec
    t["x2"], t["y2"] = [4.0] * u.arcsec, [3.0] * u.arcsec
    t["flux1_F150W"] = [flux] * u.nJy
    t["flux2_F150W"] = [flux] * u.nJy
    return t


def _render(system, r_eff, flux=100.0, **kwargs):
    kwargs = {"bands": ["F150W"], "noise": False, "host": False, "pairs": _pairs(flux),
              **kwargs}
    return render_mock_images(system, r_eff=r_eff, **kwargs)


def _moments(image, scale):
    """Flux, centroid and second-moment matrix (arcsec) of an image."""
    n = image.shape[0]
    yy, xx = np.mgrid[:n, :n] * scale
    total = image.sum()
    mx, my = (image * xx).sum() / total, (image * yy).sum() / total
    dx, dy = xx - mx, yy - my
    cxx = (image * dx * dx).sum() / total
    cxy = (image * dx * dy).sum() / total
    cyy = (image * dy * dy).sum() / total
    return total, np.array([mx, my]), np.array([[cxx, cxy], [cxy, cyy]])


def test_second_moments_are_the_psf_plus_the_lensed_source(sheet):
    scale = 0.04
    r_eff = 0.02 * u.arcsec
    s = 0.02 / math.sqrt(2 * math.log(2))
    inv = np.linalg.inv(_jacobian())
    expected = s ** 2 * inv @ inv.T
    point = _render(sheet, 0 * u.arcsec).point_source_model[("L1", "F150W")].value
    mocks = _render(sheet, r_eff)
    extended = mocks.point_source_model[("L1", "F150W")].value
    f0, c0, m0 = _moments(point, scale)
    f1, c1, m1 = _moments(extended, scale)
    # the pixel-integrated Gaussian PSF: sigma_p^2 + pixel^2 / 12 per axis
    sigma_p = 0.050 / (2 * math.sqrt(2 * math.log(2)))
    np.testing.assert_allclose(m0, np.diag([1, 1]) * (sigma_p ** 2 + scale ** 2 / 12),
                               rtol=0.01, atol=1e-7)
    np.testing.assert_allclose(m1 - m0, expected, rtol=0.01, atol=2e-3 * expected.max())
    # the centroids: the image position, from the pixel (0, 0) of the cutout
    # (the point's to 0.1 mas: its PSF is undersampled by the pixels)
    offset = THETA0 - (np.round(THETA0 / scale) - (point.shape[0] - 1) / 2) * scale
    np.testing.assert_allclose(c1, offset, atol=1e-6)
    np.testing.assert_allclose(c0, offset, atol=1e-4)
    assert f1 == pytest.approx(100.0, rel=1e-9)
    assert mocks.pairs["stretch1"][0] == pytest.approx(np.linalg.svd(inv)[1][0])
    assert mocks.pairs["r_eff_angle"].unit == u.mas


def test_ellipse_matches_a_ray_traced_gaussian_source(sheet):
    """A resolved Gaussian source ray-traced through the constant map (the host,
    Sérsic n = 1/2) is the same image as the cluster of the same width."""
    from lenstronomy.LensModel.Profiles.sersic_utils import SersicUtil

    jac = _jacobian()
    mu = 1 / abs(np.linalg.det(jac))
    beta0 = jac @ THETA0
    r_eff = 0.02 * u.arcsec
    # lenstronomy's Sérsic has b(1/2) = 0.6725 (an approximation), not ln 2:
    # this R_sersic gives the Gaussian of half-light radius r_eff
    r_sersic = r_eff * math.sqrt(SersicUtil.b_n(0.5) / math.log(2))
    host = {"flux": 10.0 * u.nJy, "R_sersic": r_sersic, "n_sersic": 0.5,
            "center": beta0 * u.arcsec}
    traced = _render(sheet, None, flux=0.0, host=host).host_model[("L1", "F150W")].value
    cluster = _render(sheet, r_eff, flux=10.0 * mu).point_source_model[("L1", "F150W")].value
    assert cluster.sum() == pytest.approx(traced.sum(), rel=2e-3)
    assert np.abs(cluster - traced).max() < 0.01 * traced.max()


@pytest.mark.parametrize("r_eff", [1 * u.pc, 20 * u.pc, 80 * u.pc, 0.05 * u.arcsec])
def test_flux_is_the_points(sheet, r_eff):
    image = _render(sheet, r_eff).point_source_model[("L1", "F150W")].value
    assert image.sum() == pytest.approx(100.0, rel=1e-6)



@pytest.fixture(scope="module")
def analog():
    system = smacs0723_analog(seed=1)
    pairs = render_mock_images(system, seed=42, noise=False, host=False).pairs
    return system, pairs


def test_small_clusters_are_points(analog):
    system, pairs = analog
    kwargs = {"noise": False, "host": False, "pairs": pairs[[c for c in pairs.colnames
                                                              if not c.startswith("snr")]]}
    points = render_mock_images(system, **kwargs)
    for r_eff in (0 * u.pc, 0.01 * u.pc):
        tiny = render_mock_images(system, r_eff=r_eff, **kwargs)
        for key, model in points.point_source_model.items():
            a, b = model.value, tiny.point_source_model[key].value
            assert b.sum() == pytest.approx(a.sum(), rel=1e-9)
            # lenstronomy shifts the PSF by linear interpolation, the clusters
            # by Fourier phases: they differ by ~1% of the peak
            assert np.abs(a - b).max() < 0.02 * a.max()
        np.testing.assert_allclose(tiny.pairs["snr1_F150W"], points.pairs["snr1_F150W"],
                                   rtol=0.02)
    assert "r_eff" not in points.pairs.colnames
    assert np.all(tiny.pairs["r_eff"] == 0.01 * u.pc)


def test_r_eff_in_pc_uses_the_source_redshift(sheet):
    angle, sigma = source_sigmas(10 * u.pc, 2, sheet)
    expected = (10 * u.pc / sheet.cosmology.angular_diameter_distance(2.2)).to_value(
        u.dimensionless_unscaled) * u.rad
    np.testing.assert_allclose(angle, expected.to_value(u.arcsec))
    assert 0.001 < angle[0] < 0.0015  # 1.2 mas
    np.testing.assert_allclose(sigma * math.sqrt(2 * math.log(2)), angle)


@pytest.mark.parametrize(("r_eff", "error", "match"), [
    (-1 * u.pc, ValueError, ">= 0"),
    (np.nan * u.pc, ValueError, "finite"),
    (1 * u.s, TypeError, "length"),
    (5.0, TypeError, "Quantity"),
    ([1, 2, 3] * u.pc, ValueError, "one value per row"),
])
def test_bad_r_eff(sheet, r_eff, error, match):
    with pytest.raises(error, match=match):
        _render(sheet, r_eff)


def test_draw_cluster_radii():
    r = draw_cluster_radii(2000, seed=3)
    assert r.unit == u.pc and r.shape == (2000,)
    lo, hi = (v.to_value(u.pc) for v in CLUSTER_RADIUS_RANGE)
    assert lo <= r.value.min() and r.value.max() <= hi
    # log-uniform: the median is the geometric mean of the range
    assert np.median(r.value) == pytest.approx(math.sqrt(lo * hi), rel=0.1)
    np.testing.assert_array_equal(r, draw_cluster_radii(2000, seed=3))
    assert draw_cluster_radii(3, low=1 * u.mas, high=2 * u.mas, seed=0).unit == u.mas
    with pytest.raises(ValueError, match="low <= high"):
        draw_cluster_radii(3, low=5 * u.pc, high=1 * u.pc)
    with pytest.raises(TypeError, match="both be lengths or both angles"):
        draw_cluster_radii(3, low=1 * u.pc, high=1 * u.arcsec)
    with pytest.raises(TypeError, match="length"):
        draw_cluster_radii(3, low=1.0)


def test_demo_scenes():
    from lensdual.demo import render_demo, simulate_demo

    system, truth = simulate_demo(n_sources=6, seed=2)
    point = render_demo(system, truth, seed=2)
    again = render_demo(system, truth, seed=2, scene="point")
    for key, image in point.mocks.items():
        np.testing.assert_array_equal(image.data, again.mocks[key].data)
    real = render_demo(system, truth, seed=2, scene="realistic",
                       cluster_radii=(10 * u.pc, 20 * u.pc))
    r = real.mocks.pairs["r_eff"]
    assert r.unit == u.pc and np.all((r >= 10 * u.pc) & (r <= 20 * u.pc))
    assert "r_eff" not in point.mocks.pairs.colnames
    with pytest.raises(ValueError, match="scene must be one of"):
        render_demo(system, truth, scene="messy")
