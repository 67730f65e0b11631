"""Finite-size star clusters in the mock images (``render_mock_images(r_eff=...)``)."""

import math
import warnings

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


# ---------------------------------------------------------------------------
# the realistic scene's other parts: PSF with spikes, member, ICL, patch, clumps
# ---------------------------------------------------------------------------


def _azimuthal(kernel, r_min, r_max, width=3):
    """Mean of kernel * r in azimuth bins of ``width`` degrees between two radii (samples)."""
    n = kernel.shape[0]
    c = (n - 1) / 2
    y, x = np.mgrid[:n, :n] - c
    r = np.hypot(x, y)
    theta = np.degrees(np.arctan2(y, x)) % 360
    ring = (r > r_min) & (r < r_max)
    bins = np.arange(0, 360, width)
    prof = np.array([(kernel * r)[ring & (theta >= a) & (theta < a + width)].mean()
                     for a in bins])
    return bins, prof / np.median(prof)


def test_poppy_psf_has_six_spikes_and_the_diffraction_limited_core():
    pytest.importorskip("poppy")
    from lensdual.simulation import hexagonal_pupil_psf
    from lensdual.simulation._psf import half_max_fwhm

    sample = 0.008  # arcsec: 0.04 arcsec pixels, supersampling 5
    kernel = hexagonal_pupil_psf("F150W", 0.04 * u.arcsec, supersampling=5)
    assert kernel.shape == (255, 255) and kernel.sum() == pytest.approx(1.0, abs=1e-12)
    assert kernel.min() >= 0 and np.unravel_index(kernel.argmax(), kernel.shape) == (127, 127)
    # spikes: the six diagonal/vertical directions 30 + 60 k degrees and the
    # horizontal pair of the vertical strut stand out; between them (15 degrees
    # off) the profile is at its median
    bins, prof = _azimuthal(kernel, 30, 125)
    def at(angle):
        return prof[(bins == angle % 360) | (bins == (angle - 3) % 360)].max()
    spikes = [at(30 + 60 * k) for k in range(6)]
    assert min(spikes) > 1.5, spikes
    assert max(spikes) / min(spikes) < 1.8  # six-fold
    assert min(at(0), at(180)) > 1.5  # the strut's extra pair
    between = [at(15 + 60 * k) for k in range(6)] + [at(45 + 60 * k) for k in range(6)]
    assert max(between) < 1.2, between
    # the core: FWHM 1.03 lambda / D for the 6.5 m effective aperture, within 10 %
    lam_d = (1.5e-6 / 6.5) * 206264.8
    fwhm = half_max_fwhm(kernel) * sample
    assert fwhm == pytest.approx(1.03 * lam_d, rel=0.10)
    # it scales with the wavelength
    long = hexagonal_pupil_psf("F200W", 0.04 * u.arcsec, supersampling=5)
    assert half_max_fwhm(long) * sample / fwhm == pytest.approx(2.0 / 1.5, rel=0.05)


def test_poppy_psf_in_the_renderer(sheet):
    pytest.importorskip("poppy")
    mocks = _render(sheet, None, psf="poppy")
    image = mocks[("L1", "F150W")]
    assert image.meta["PSFTYPE"] == "POPPY"
    assert image.psf.shape == (51, 51) and image.psf.sum() == pytest.approx(1.0)
    assert 0.045 < image.meta["PSFFWHM"] < 0.06
    # the point's flux, apart from the part of the spikes beyond the cutout
    assert mocks.point_source_model[("L1", "F150W")].value.sum() == pytest.approx(100, rel=0.03)


def test_poppy_missing_raises_a_clear_import_error(sheet, monkeypatch):
    import builtins

    from lensdual.simulation import _psf

    real_import = builtins.__import__

    def no_poppy(name, *args, **kwargs):
        if name == "poppy" or name.startswith("poppy."):
            raise ImportError("No module named 'poppy'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_poppy)
    _psf._poppy_kernel.cache_clear()
    with pytest.raises(ImportError, match=r"lensdual\[psf\]"):
        _render(sheet, None, psf="poppy")
    _psf._poppy_kernel.cache_clear()
    # the rest of the renderer works without poppy
    assert _render(sheet, None).point_source_model[("L1", "F150W")].value.sum() > 0


BIG = 8.0 * u.arcsec  # an uncropped stamp for compact profiles near the arc's centre


def test_member_and_patch_add_the_flux_asked_for(sheet):
    member = {"flux": 50 * u.nJy, "R_sersic": 0.1 * u.arcsec, "n_sersic": 1.0,
              "arc": "L1", "offset": [0.3, -0.2] * u.arcsec}
    patch = {"flux": 20 * u.nJy, "sigma": 0.1 * u.arcsec, "arc": "L1"}
    mocks = _render(sheet, None, flux=0.0, cutout_size=BIG, member=member, patch=patch)
    total = mocks.image_plane_model[("L1", "F150W")].value.sum()
    assert total == pytest.approx(70.0, rel=0.01)
    only_patch = _render(sheet, None, flux=0.0, cutout_size=BIG, patch=patch)
    model = only_patch.image_plane_model[("L1", "F150W")].value
    assert model.sum() == pytest.approx(20.0, rel=1e-3)
    # the patch is centred on the L1 image (the pair's, row 0)
    _, centroid, _ = _moments(model, 0.04)
    n = model.shape[0]
    offset = THETA0 - (np.round(THETA0 / 0.04) - (n - 1) / 2) * 0.04
    np.testing.assert_allclose(centroid, offset, atol=2e-3)
    assert only_patch.pairs["patch1"].tolist() == [True]
    assert only_patch.pairs["patch2"].tolist() == [False]
    # a member dict per band
    per_band = _render(sheet, None, flux=0.0, cutout_size=BIG, bands=["F150W", "F200W"],
                       pairs=_two_band_pairs(),
                       member={**member, "flux": {"F150W": 10 * u.nJy, "F200W": 30 * u.nJy}})
    assert per_band.image_plane_model[("L1", "F200W")].value.sum() == pytest.approx(30, rel=0.01)


def _two_band_pairs():
    t = _pairs(0.0)
    t["flux1_F200W"] = t["flux1_F150W"]
    t["flux2_F200W"] = t["flux2_F150W"]
    return t


def test_icl_gradient(sheet):
    sb, h = 300.0, 2.0
    icl = {"surface_brightness": sb * u.nJy / u.arcsec ** 2, "scale_length": h * u.arcsec,
           "direction": 90 * u.deg}
    mocks = _render(sheet, None, flux=0.0, icl=icl)
    model = mocks.image_plane_model[("L1", "F150W")].value
    n, scale = model.shape[0], 0.04
    # the integral of S0 exp((y - y_c) / h) over the cutout, in closed form
    cen = np.round(THETA0 / scale) * scale
    lo, hi = cen - (n / 2) * scale, cen + (n / 2) * scale
    expected = sb * (hi[0] - lo[0]) * h * (np.exp((hi[1] - THETA0[1]) / h)
                                           - np.exp((lo[1] - THETA0[1]) / h))
    assert model.sum() == pytest.approx(expected, rel=1e-9)
    # brighter by e per scale length along +y, flat along x
    rows = model.mean(axis=1)
    assert rows[-1] / rows[0] == pytest.approx(np.exp((n - 1) * scale / h), rel=1e-9)
    np.testing.assert_allclose(model[:, 0], model[:, -1])
    assert mocks.image_plane_model[("L2", "F150W")].value.max() == 0.0
    # default direction: towards the lens centre (THETA0 has x > 0, y < 0)
    toward = _render(sheet, None, flux=0.0, icl=True).image_plane_model[("L1", "F150W")].value
    assert toward[0, -1] < toward[-1, 0]  # brighter at small x, large y (the centre's side)


def test_patch_lies_under_exactly_the_chosen_image(analog):
    system, pairs = analog
    truth = pairs[[c for c in pairs.colnames if not c.startswith("snr")]]
    for arc, k in (("L2", "2"), ("L1", "1")):  # the default arc, then the other
        patch = {"pair": 3} if arc == "L2" else {"pair": 3, "arc": "L1"}
        mocks = render_mock_images(system, noise=False, host=False, pairs=truth,
                                   patch=patch)
        assert np.flatnonzero(mocks.pairs[f"patch{k}"]).tolist() == [3]
        assert not mocks.pairs[f"patch{'1' if k == '2' else '2'}"].any()
        model = mocks.image_plane_model[(arc, "F150W")].value
        # the patch's centroid is the chosen image, in pixels of the arc's cutout
        yy, xx = np.mgrid[:model.shape[0], :model.shape[1]]
        centroid = np.array([(model * xx).sum(), (model * yy).sum()]) / model.sum()
        pix = mocks.truth_pixels(arc)
        np.testing.assert_allclose(centroid, pix[3], atol=0.05)
        assert np.argmin(np.hypot(*(pix - centroid).T)) == 3


def test_patch_leak_is_the_closed_form_for_a_gaussian_psf():
    """For a pixel-integrated Gaussian PSF of width p and patch of width s (pixels)
    the amplitude fit takes up 2 q / (2 q + s^2 + 1/12) of the patch, q = p^2 + 1/12
    (Gaussians convolve by adding variances; a pixel adds 1/12)."""
    from lensdual.simulation._scene import patch_leak
    from lensdual.simulation.mock import _gaussian_kernel

    for fwhm, s in ((2.0, 4.0), (3.0, 1.0), (5.0, 10.0)):
        q = (fwhm / (2 * np.sqrt(2 * np.log(2)))) ** 2 + 1 / 12
        expected = 2 * q / (2 * q + s ** 2 + 1 / 12)
        got = patch_leak(_gaussian_kernel(fwhm, 1.0, 1), s)
        assert got == pytest.approx(expected, rel=0.02)
    # a patch far wider than the PSF leaks little, a narrow one nearly all
    k = _gaussian_kernel(3.0, 1.0, 1)
    assert patch_leak(k, 30.0) < 0.01 < 0.9 < patch_leak(k, 0.05)


def test_patch_contrast_sets_the_flux_a_psf_fit_takes_up(sheet):
    """contrast c: an amplitude-only fit of the pixel PSF at the image, to the
    patch's pixels alone, returns c times the image's flux, in every band."""
    pairs = _two_band_pairs()
    pairs["flux2_F150W"] = [40.0] * u.nJy
    pairs["flux2_F200W"] = [10.0] * u.nJy
    for contrast in (1.0, 0.5):
        mocks = _render(sheet, None, cutout_size=BIG, bands=["F150W", "F200W"], pairs=pairs,
                        patch={"contrast": contrast})
        assert mocks.pairs["patch2"].tolist() == [True]
        for band, image_flux in (("F150W", 40.0), ("F200W", 10.0)):
            model = mocks.image_plane_model[("L2", band)].value
            psf = np.asarray(mocks[("L2", band)].psf, dtype=float)
            psf = psf / psf.sum()
            # the PSF at the pixel nearest the image (the patch's centre)
            n, m = model.shape[0], psf.shape[0]
            cy, cx = np.unravel_index(np.argmax(model), model.shape)
            stamp = model[cy - m // 2:cy + m // 2 + 1, cx - m // 2:cx + m // 2 + 1]
            assert stamp.shape == psf.shape and n > m
            amplitude = (psf * stamp).sum() / (psf * psf).sum()
            assert amplitude == pytest.approx(contrast * image_flux, rel=0.05)
            assert model.sum() == pytest.approx(mocks.pairs.meta["patch_flux"][band], rel=0.01)
    # a rendered truth table passed in again without a patch keeps no trace of it
    again = _render(sheet, None, bands=["F150W", "F200W"], pairs=mocks.pairs, patch=None)
    assert "patch_flux" not in again.pairs.meta and "patch2" not in again.pairs.colnames
    assert again.image_plane_model[("L2", "F150W")].value.sum() == 0
    # a copy of the default with a flux: contrast None
    from lensdual.simulation import MOCK_PATCH

    with pytest.raises(ValueError, match="'contrast': None"):
        _render(sheet, None, pairs=_pairs(10.0), patch={**MOCK_PATCH, "flux": 5 * u.nJy})
    fixed = _render(sheet, None, pairs=_pairs(10.0),
                    patch={**MOCK_PATCH, "flux": 5 * u.nJy, "contrast": None})
    assert fixed.pairs.meta["patch_flux"]["F150W"] == pytest.approx(5.0)
    # the default's flux follows the image: twice as bright an image, twice the patch
    bright = pairs.copy()
    bright["flux2_F150W"] = [80.0] * u.nJy
    one, two = (_render(sheet, None, bands=["F150W", "F200W"], pairs=t, patch=True)
                .pairs.meta["patch_flux"]["F150W"] for t in (pairs, bright))
    assert two == pytest.approx(2 * one, rel=1e-12)


def test_clumps_stay_below_the_detection_threshold(analog):
    from lensdual.detection import find_point_sources
    from lensdual.simulation import MOCK_CLUMPS

    system, pairs = analog
    dark = pairs[[c for c in pairs.colnames if not c.startswith("snr")]]
    for c in dark.colnames:
        if c.startswith("flux"):
            dark[c] = 0 * dark[c]
    found = {}
    for label, scale in (("default", 1.0), ("30x", 30.0)):
        lo, hi = MOCK_CLUMPS["flux"]
        clumps = {"flux": (lo * scale, hi * scale)}
        mocks = render_mock_images(system, host=False, pairs=dark, seed=5, clumps=clumps)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cat = find_point_sources(mocks.arc("L2"))
        found[label] = 0 if cat is None else len(cat)
        assert mocks.host_model[("L2", "F150W")].value.sum() > 0
    assert found["default"] == 0
    assert found["30x"] > 0  # the same clumps, brighter, are found: the check can fail


@pytest.mark.parametrize(("kwargs", "error", "match"), [
    ({"member": {"colour": 1}}, ValueError, "unknown key"),
    ({"member": "yes"}, TypeError, "True, False, None or a dict"),
    ({"member": {"flux": 5.0}}, TypeError, "Quantity"),
    ({"member": {"flux": -1 * u.nJy}}, ValueError, ">= 0"),
    ({"member": {"arc": "L3"}}, ValueError, "'L1' or 'L2'"),
    ({"member": {"offset": [1, 2, 3] * u.arcsec}}, TypeError, "shape"),
    ({"icl": {"scale_length": 0 * u.arcsec}}, ValueError, "> 0"),
    ({"icl": {"surface_brightness": 1 * u.nJy}}, TypeError, "arcsec"),
    ({"icl": {"direction": 1.0}}, TypeError, "angle"),
    ({"patch": {"pair": 5}}, ValueError, "row of the pairs table"),
    ({"patch": {"flux": 5 * u.nJy, "contrast": 1.0}}, ValueError, "not both"),
    ({"patch": {"contrast": None}}, ValueError, "needs a 'flux' or a 'contrast'"),
    ({"patch": {"contrast": -0.5}}, ValueError, "contrast"),
    ({"patch": {"contrast": "big"}}, TypeError, "contrast"),
    ({"clumps": {"flux": (1 * u.nJy, 0.5 * u.nJy)}}, ValueError, "low <= high"),
    ({"clumps": {"sigma": 0.1 * u.arcsec}}, TypeError, "pair"),
    ({"psf": {"F150W": "poppy"}, "bands": ["F150W", "F999W"]}, ValueError, "F999W"),
])
def test_bad_scene_parts(sheet, kwargs, error, match):
    with pytest.raises(error, match=match):
        _render(sheet, None, **kwargs)


def test_hexagonal_psf_bad_input():
    from lensdual.simulation import hexagonal_pupil_psf

    with pytest.raises(ValueError, match="no wavelength"):
        hexagonal_pupil_psf("F999W", 0.04 * u.arcsec)
    with pytest.raises(ValueError, match="odd"):
        hexagonal_pupil_psf("F150W", 0.04 * u.arcsec, supersampling=2)
    with pytest.raises(TypeError, match="length"):
        hexagonal_pupil_psf("F150W", 0.04 * u.arcsec, wavelength=2 * u.s)
