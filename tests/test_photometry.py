"""Tests of lensdual.photometry: PSF photometry on bright arcs and the pairs table.

The synthetic scenes are made here: Gaussian point sources (pixel-integrated)
on a bright, curved arc whose cross profile is a cored exponential (Sérsic
n = 1 away from the crest) with a steep gradient on its flanks, blurred by the
PSF, with read noise plus photon noise and an exact StdDevUncertainty.
"""

import re
import warnings

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.nddata import CCDData, NDData, StdDevUncertainty
from astropy.table import QTable, Table
from astropy.wcs import WCS
from scipy.ndimage import gaussian_filter
from scipy.special import erf

from lensdual.exceptions import LensdualWarning
from lensdual.photometry import (
    BACKGROUND_STRATEGIES,
    UNUSABLE_FLAGS,
    PhotometryFlag,
    describe_flags,
    measure_pairs,
    psf_photometry,
)

FWHM = 2.5  # pixels
SHAPE = (110, 200)
ARC_RADIUS = 190.0
ARC_CENTRE = (100.0, 58.0 - ARC_RADIUS)  # the crest crosses x = 100 at y = 58
ARC_PEAK = 40.0  # crest surface brightness per pixel (before the PSF)
ARC_SCALE = 3.0  # exponential scale across the arc, pixels
ARC_CORE = 2.0  # core of the cross profile, pixels
READ_NOISE = 1.0
GAIN = 20.0
SCALE = 0.03  # arcsec / pixel
CRVAL = (110.84, -73.45)


# ---------------------------------------------------------------------------
# synthetic scenes
# ---------------------------------------------------------------------------


def prf(dx, dy, fwhm=FWHM):
    """Unit-flux circular Gaussian integrated over the pixels."""
    k = 1.0 / (np.sqrt(2.0) * fwhm / (2.0 * np.sqrt(2.0 * np.log(2.0))))

    def side(t):
        return 0.5 * (erf((t + 0.5) * k) - erf((t - 0.5) * k))

    return side(dx) * side(dy)


def arc_image(
    shape=SHAPE, centre=ARC_CENTRE, radius=ARC_RADIUS, peak=ARC_PEAK, fwhm=FWHM, oversample=3
):
    """A curved ridge: cored exponential across, slowly varying along, PSF-blurred."""
    ny, nx = shape
    yy, xx = np.mgrid[: ny * oversample, : nx * oversample]
    xx = (xx + 0.5) / oversample - 0.5
    yy = (yy + 0.5) / oversample - 0.5
    rho = np.hypot(xx - centre[0], yy - centre[1])
    along = rho * np.arctan2(xx - centre[0], yy - centre[1])
    d = rho - radius
    img = (
        peak
        * (1.0 + 0.3 * np.sin(along / 40.0))
        * np.exp(-(np.sqrt(d**2 + ARC_CORE**2) - ARC_CORE) / ARC_SCALE)
    )
    img = gaussian_filter(img, fwhm / 2.3548 * oversample)
    return img.reshape(ny, oversample, nx, oversample).mean(axis=(1, 3))


def arc_sources(
    rng,
    *,
    centre=ARC_CENTRE,
    radius=ARC_RADIUS,
    shape=SHAPE,
    spacing=14.0,
    offsets=(-5.0, -2.5, 0.0, 2.5, 5.0),
    flux_range=(150.0, 4000.0),
    n_off=4,
):
    """Sources along the arc every ``spacing`` px, at cycling offsets across it, plus a few
    off the arc; fluxes log-uniform."""
    ny, nx = shape
    xy = []
    phi_max = np.arcsin((nx / 2 - 9) / radius)
    n = int(2 * phi_max * radius / spacing)
    for k, phi in enumerate(np.linspace(-phi_max, phi_max, n)):
        rho = radius + offsets[k % len(offsets)] + rng.uniform(-0.5, 0.5)
        xy.append((centre[0] + rho * np.sin(phi), centre[1] + rho * np.cos(phi)))
    for _ in range(n_off):
        xy.append((rng.uniform(12, nx - 12), rng.uniform(12, 30)))
    xy = np.array(xy)
    keep = (xy[:, 0] > 8) & (xy[:, 0] < nx - 9) & (xy[:, 1] > 8) & (xy[:, 1] < ny - 9)
    xy = xy[keep]
    flux = np.exp(rng.uniform(*np.log(flux_range), len(xy)))
    return xy, flux


def render(background, xy, flux, rng, *, fwhm=FWHM, wcs=None, unit=u.nJy):
    """CCDData of background + point sources + read and photon noise, exact uncertainty."""
    ny, nx = background.shape
    yy, xx = np.mgrid[:ny, :nx]
    model = background.copy()
    for (x, y), f in zip(xy, flux, strict=True):
        model += f * prf(xx - x, yy - y, fwhm)
    var = READ_NOISE**2 + np.clip(model, 0, None) / GAIN
    data = model + rng.normal(size=model.shape) * np.sqrt(var)
    return CCDData(data, unit=unit, uncertainty=StdDevUncertainty(np.sqrt(var)), wcs=wcs), var


def crb_flux_error(xy, var, fwhm=FWHM):
    """Smallest possible flux error (known position and background)."""
    ny, nx = var.shape
    yy, xx = np.mgrid[:ny, :nx]
    return np.array([1.0 / np.sqrt(np.sum(prf(xx - x, yy - y, fwhm) ** 2 / var)) for x, y in xy])


def make_wcs(shape=SHAPE, crval=CRVAL, scale=SCALE, rotation=0.0):
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = list(crval)
    w.wcs.crpix = [shape[1] / 2 + 0.5, shape[0] / 2 + 0.5]
    w.wcs.cdelt = [-scale / 3600, scale / 3600]
    c, s = np.cos(np.radians(rotation)), np.sin(np.radians(rotation))
    w.wcs.pc = [[c, -s], [s, c]]
    return w


@pytest.fixture(scope="module")
def arc():
    return arc_image()


@pytest.fixture(scope="module")
def runs(arc):
    """Three noise realisations: truth, the default (ridge) fit and a naive fit."""
    rows = []
    for seed in (11, 12, 13):
        rng = np.random.default_rng(seed)
        xy, flux = arc_sources(rng)
        image, var = render(arc, xy, flux, rng, wcs=make_wcs())
        start = xy + rng.normal(scale=0.3, size=xy.shape)
        default = psf_photometry(image, start, psf=FWHM)
        naive = psf_photometry(image, start, psf=FWHM, background="none")
        rows.append((xy, flux, crb_flux_error(xy, var), default, naive, image))
    return rows


def stack(runs, which):
    true = np.concatenate([r[1] for r in runs])
    snr = true / np.concatenate([r[2] for r in runs])
    xy = np.concatenate([r[0] for r in runs])
    res = [r[which] for r in runs]
    flux = np.concatenate([t["flux"].to_value(u.nJy) for t in res])
    err = np.concatenate([t["flux_err"].to_value(u.nJy) for t in res])
    dx = np.concatenate([t["x_fit"] for t in res]) - xy[:, 0]
    dy = np.concatenate([t["y_fit"] for t in res]) - xy[:, 1]
    ex = np.concatenate([t["x_err"] for t in res])
    ey = np.concatenate([t["y_err"] for t in res])
    return true, snr, flux, err, dx, dy, ex, ey


# ---------------------------------------------------------------------------
# psf_photometry on the arc
# ---------------------------------------------------------------------------


def test_default_is_ridge():
    assert BACKGROUND_STRATEGIES[0] == "ridge"
    assert psf_photometry.__kwdefaults__["background"] == "ridge"


def test_fluxes_recovered(runs):
    true, snr, flux, err, *_ = stack(runs, 3)
    assert true.size >= 45
    pull = (flux - true) / err
    assert np.all(np.isfinite(pull))
    assert np.all(np.abs(pull) < 3.5)
    assert np.mean(np.abs(pull) < 3) >= 0.97
    high = snr >= 30
    assert high.sum() >= 30
    assert np.median(np.abs(np.log(flux[high] / true[high]))) < 0.05
    assert abs(np.median(np.log(flux[high] / true[high]))) < 0.01


def test_flux_errors_honest(runs):
    true, _, flux, err, dx, dy, ex, ey = stack(runs, 3)
    assert 0.7 < np.std((flux - true) / err) < 1.4
    assert abs(np.mean((flux - true) / err)) < 0.4
    pos_pull = np.concatenate([dx / ex, dy / ey])
    assert 0.7 < np.std(pos_pull) < 1.4


def test_positions_at_high_snr(runs):
    _, snr, _, _, dx, dy, *_ = stack(runs, 3)
    high = snr >= 30
    assert np.sqrt(np.mean(dx[high] ** 2 + dy[high] ** 2)) < 0.1
    assert np.sqrt(np.mean(dx[snr >= 100] ** 2 + dy[snr >= 100] ** 2)) < 0.05


def test_ridge_beats_naive_fit(runs):
    true, snr, flux, err, dx, dy, *_ = stack(runs, 3)
    _, _, flux0, err0, dx0, dy0, *_ = stack(runs, 4)
    high = snr >= 30
    lnr = np.median(np.abs(np.log(flux[high] / true[high])))
    lnr0 = np.median(np.abs(np.log(flux0[high] / true[high])))
    assert lnr0 > 0.1  # the naive fit adds the arc's light to the sources
    assert lnr < lnr0 / 5
    assert np.std((flux0 - true) / err0) > 5 * np.std((flux - true) / err)
    assert np.sqrt(np.mean(dx0**2 + dy0**2)) > 2 * np.sqrt(np.mean(dx**2 + dy**2))


def test_output_table(runs):
    xy, _, _, res, _, image = runs[0]
    assert isinstance(res, QTable)
    for name in (
        "id",
        "x_init",
        "y_init",
        "x_fit",
        "y_fit",
        "x_err",
        "y_err",
        "flux",
        "flux_err",
        "bkg",
        "sky",
        "group_size",
        "qfit",
        "cfit",
        "reduced_chi2",
        "n_pixels_fit",
        "flags",
    ):
        assert name in res.colnames
    assert res["id"].tolist() == list(range(1, len(xy) + 1))
    assert res["flux"].unit == u.nJy and res["flux_err"].unit == u.nJy
    assert np.all(res["flags"] == 0)
    sky = image.wcs.pixel_to_world(res["x_fit"], res["y_fit"])
    assert np.all(sky.separation(res["sky"]).to_value(u.arcsec) < 1e-6)
    # the background under the sources: the arc's brightness (blurred by the PSF)
    arc = arc_image()
    truth = arc[np.round(xy[:, 1]).astype(int), np.round(xy[:, 0]).astype(int)]
    on_arc = truth > 10
    rel = res["bkg"].to_value(u.nJy)[on_arc] / truth[on_arc]
    assert np.median(np.abs(rel - 1)) < 0.1
    assert res.meta["background"] == "ridge"
    assert res.meta["fit_shape"] == (11, 11)
    assert res.meta["weighted"] is True


def test_input_not_modified(arc):
    rng = np.random.default_rng(5)
    xy, flux = arc_sources(rng, n_off=0)
    image, _ = render(arc, xy, flux, rng, wcs=make_wcs())
    data, unc = image.data.copy(), image.uncertainty.array.copy()
    positions = xy.copy()
    psf_photometry(image, positions, psf=FWHM)
    np.testing.assert_array_equal(image.data, data)
    np.testing.assert_array_equal(image.uncertainty.array, unc)
    np.testing.assert_array_equal(positions, xy)


@pytest.mark.parametrize("strategy", [s for s in BACKGROUND_STRATEGIES if s != "none"])
def test_all_strategies_exact_on_empty_background(strategy):
    """Without an arc every strategy is unbiased; for "residual" this checks that the
    high-pass filter applied to the PSF model restores the full flux."""
    rng = np.random.default_rng(21)
    xy, flux = arc_sources(rng, flux_range=(1000, 3000), n_off=0)
    image, _ = render(np.zeros(SHAPE), xy, flux, rng)
    res = psf_photometry(image, xy, psf=FWHM, background=strategy)
    f = res["flux"].to_value(u.nJy)
    assert np.median(np.abs(np.log(f / flux))) < 0.02
    assert np.all(np.abs(f - flux) < 4 * res["flux_err"].to_value(u.nJy))


def test_highpass_psf_model_needed():
    """The residual image holds only part of a source's flux: ~9 % is removed by the
    sigma-5 blur at FWHM 2.5 px, which the filtered PSF model puts back."""
    from lensdual.photometry import _GaussianProfile

    yy, xx = np.mgrid[-30:31, -30:31]
    filtered = _GaussianProfile(FWHM, 5.0)(xx, yy)
    img = prf(xx, yy)
    direct = img - gaussian_filter(img, 5.0, mode="reflect", truncate=4.0)
    np.testing.assert_allclose(filtered, direct, atol=2e-6)
    # a least-squares fit of the *unfiltered* PSF to the filtered source loses flux
    lost = 1 - np.sum(direct * img) / np.sum(img * img)
    assert 0.01 < lost < 0.2


def test_psf_forms_agree(arc):
    from photutils.psf import ImagePSF

    rng = np.random.default_rng(8)
    xy, flux = arc_sources(rng, flux_range=(800, 3000), n_off=0)
    image, _ = render(arc, xy, flux, rng)
    gauss = psf_photometry(image, xy, psf=FWHM)
    yy, xx = np.mgrid[-10:11, -10:11]
    array = psf_photometry(image, xy, psf=prf(xx, yy), fit_shape=11)
    oversampled = np.mgrid[-40:41, -40:41] / 4.0
    image_psf = ImagePSF(prf(oversampled[1], oversampled[0]), oversampling=4)
    ipsf = psf_photometry(image, xy, psf=image_psf, fit_shape=11)
    pix = psf_photometry(image, xy, psf=FWHM * u.pix)
    ang = psf_photometry(CCDData(image, wcs=make_wcs()), xy, psf=FWHM * SCALE * u.arcsec)
    for other in (array, ipsf, pix, ang):
        diff = (other["flux"] - gauss["flux"]) / gauss["flux_err"]
        assert np.max(np.abs(diff)) < 0.3
        assert (
            np.max(np.hypot(other["x_fit"] - gauss["x_fit"], other["y_fit"] - gauss["y_fit"]))
            < 0.03
        )


def test_fwhm_estimated_when_psf_is_none(arc):
    rng = np.random.default_rng(9)
    xy, flux = arc_sources(rng, flux_range=(500, 4000))
    image, _ = render(arc, xy, flux, rng)
    res = psf_photometry(image, xy)
    assert res.meta["fwhm_estimated"] is True
    assert res.meta["fwhm"] == pytest.approx(FWHM, rel=0.04)
    assert np.median(np.abs(np.log(res["flux"].to_value(u.nJy) / flux))) < 0.03


def test_positions_as_table_and_skycoord(runs):
    xy, _, _, res, _, image = runs[0]
    cat = QTable()
    cat["id"] = np.arange(101, 101 + len(xy))
    cat["x_centroid"] = res["x_fit"]
    cat["y_centroid"] = res["y_fit"]
    from_table = psf_photometry(image, cat, psf=FWHM)
    assert from_table["id"].tolist() == cat["id"].tolist()
    from_sky = psf_photometry(image, res["sky"], psf=FWHM)
    np.testing.assert_allclose(from_sky["x_init"], res["x_fit"], atol=1e-6)
    np.testing.assert_allclose(from_sky["flux"], from_table["flux"], rtol=1e-6)


def test_masked_and_nan_pixels(arc):
    rng = np.random.default_rng(4)
    xy, flux = arc_sources(rng, flux_range=(1500, 3000), n_off=0)
    image, _ = render(arc, xy, flux, rng)
    clean = psf_photometry(image, xy, psf=FWHM)
    mask = np.zeros(SHAPE, bool)
    x0, y0 = np.round(xy[0]).astype(int)
    mask[y0 + 2, x0 - 1 : x0 + 2] = True
    data = image.data.copy()
    x1, y1 = np.round(xy[1]).astype(int)
    data[y1 - 3, x1] = np.nan
    masked = psf_photometry(
        CCDData(data, unit=image.unit, uncertainty=image.uncertainty, mask=mask), xy, psf=FWHM
    )
    assert masked["n_pixels_fit"][0] == 121 - 3
    assert masked["n_pixels_fit"][1] == 120
    assert np.all(np.isfinite(masked["flux"]))
    diff = (masked["flux"] - clean["flux"]) / clean["flux_err"]
    assert np.max(np.abs(diff[:2])) < 1


def test_unweighted_plain_array(arc):
    rng = np.random.default_rng(6)
    xy, flux = arc_sources(rng, flux_range=(1000, 3000), n_off=0)
    image, _ = render(arc, xy, flux, rng)
    res = psf_photometry(np.asarray(image.data), xy, psf=FWHM)
    assert not isinstance(res["flux"], u.Quantity)
    assert res.meta["weighted"] is False
    assert np.median(np.abs(np.log(res["flux"] / flux))) < 0.03


def test_flagged_fit_warns():
    """A "source" that is a hole in the image gets a negative flux: flagged, one warning."""
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[:40, :40]
    data = rng.normal(size=(40, 40)) - 200 * prf(xx - 20.2, yy - 19.7)
    image = CCDData(data, unit=u.nJy, uncertainty=StdDevUncertainty(np.ones((40, 40))))
    positions = [(20.0, 20.0), (10.0, 30.0)]
    with pytest.warns(LensdualWarning, match="fits flagged"):
        res = psf_photometry(image, positions, psf=FWHM, background="plane")
    assert res["flags"][0] & 4 and res["flux"][0] < 0 * u.nJy
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        psf_photometry(image, positions, psf=FWHM, background="plane", warn=False)


@pytest.mark.parametrize(("separation", "grouped"), [(2.9, True), (6.0, False)])
def test_close_pairs(arc, separation, grouped):
    """Two sources on the arc 1.2 or 2.4 FWHM apart: fitted each on its own, each takes
    light from the other; the joint fit of a group (closer than 2 FWHM) or the
    neighbour-subtraction passes fix that."""
    rng = np.random.default_rng(14)
    x0, y0 = 97.3, 57.6
    xy = np.array([[x0, y0], [x0 + 0.96 * separation, y0 + 0.28 * separation], [60.2, 52.4]])
    flux = np.array([2500.0, 1500.0, 2000.0])
    image, _ = render(arc, xy, flux, rng)
    start = xy + 0.3
    alone = psf_photometry(image, start, psf=FWHM, neighbour_passes=0, group_radius=0)
    refined = psf_photometry(image, start, psf=FWHM)
    pull_alone = np.abs(alone["flux"].value - flux) / alone["flux_err"].value
    pull = np.abs(refined["flux"].value - flux) / refined["flux_err"].value
    assert np.all(pull < 3)
    assert pull_alone[:2].max() > 5
    assert refined["group_size"].tolist() == ([2, 2, 1] if grouped else [1, 1, 1])
    assert np.all(refined["flags"] == 0)
    assert np.max(np.hypot(refined["x_fit"] - xy[:, 0], refined["y_fit"] - xy[:, 1])) < 0.1


# ---------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_image():
    rng = np.random.default_rng(0)
    return CCDData(
        rng.normal(size=(30, 40)),
        unit=u.nJy,
        wcs=make_wcs((30, 40)),
        uncertainty=StdDevUncertainty(np.ones((30, 40))),
    )


@pytest.mark.parametrize("position", [(-3.0, 10.0), (10.0, 29.6), (40.2, 3.0), (np.nan, 5.0)])
def test_positions_outside_image(small_image, position):
    """A position off the image is not fitted: NaN and OUTSIDE_IMAGE, the others go on."""
    with pytest.warns(
        LensdualWarning, match=r"positions \[1\] \(ids \[2\]\) are outside the image"
    ):
        res = psf_photometry(small_image, [(20.0, 15.0), position], psf=FWHM)
    assert res["flags"][1] == PhotometryFlag.OUTSIDE_IMAGE
    assert np.isnan(res["flux"][1]) and np.isnan(res["x_fit"][1]) and np.isnan(res["flux_err"][1])
    assert "outside the image" in res["flag_note"][1]
    assert res["group_size"][1] == 0 and res["n_pixels_fit"][1] == 0
    assert np.isfinite(res["flux"][0]) and not res["flags"][0] & UNUSABLE_FLAGS
    # all positions off: a table of NaN, no error
    with pytest.warns(LensdualWarning, match="outside the image"):
        res = psf_photometry(small_image, [position], psf=FWHM)
    assert res["flags"][0] == PhotometryFlag.OUTSIDE_IMAGE and np.isnan(res["flux"][0])


@pytest.mark.parametrize("fwhm", [0.0, -2.0, -2.0 * u.pix, 0 * u.arcsec, np.inf])
def test_non_positive_fwhm(small_image, fwhm):
    with pytest.raises(ValueError, match="psf .*FWHM.* must be finite and positive"):
        psf_photometry(small_image, [(10.0, 10.0)], psf=fwhm)


def test_bad_arguments(small_image):
    pos = [(10.0, 10.0)]
    with pytest.raises(TypeError, match="psf must be"):
        psf_photometry(small_image, pos, psf="gauss")
    with pytest.raises(TypeError, match="psf as a Quantity"):
        psf_photometry(small_image, pos, psf=2 * u.s)
    with pytest.raises(ValueError, match="needs an image with a celestial WCS"):
        psf_photometry(small_image.data, pos, psf=0.07 * u.arcsec)
    with pytest.raises(ValueError, match="background must be one of"):
        psf_photometry(small_image, pos, psf=FWHM, background="median")
    with pytest.raises(TypeError, match="background must be a string"):
        psf_photometry(small_image, pos, psf=FWHM, background=3)
    with pytest.raises(ValueError, match="fit_shape must be an odd integer"):
        psf_photometry(small_image, pos, psf=FWHM, fit_shape=8)
    with pytest.raises(ValueError, match="fit_shape must be an odd integer"):
        psf_photometry(small_image, pos, psf=FWHM, fit_shape=(9, 1))
    with pytest.raises(TypeError, match="image must be"):
        psf_photometry([[1.0, 2.0]], pos, psf=FWHM)
    with pytest.raises(ValueError, match="image must be a 2-D image"):
        psf_photometry(np.zeros(5), pos, psf=FWHM)
    with pytest.raises(ValueError, match=r"positions must have shape \(N, 2\)"):
        psf_photometry(small_image, [(1.0, 2.0, 3.0)], psf=FWHM)
    with pytest.raises(ValueError, match="positions given as a SkyCoord need"):
        psf_photometry(small_image.data, SkyCoord(CRVAL[0], CRVAL[1], unit="deg"), psf=FWHM)
    with pytest.raises(ValueError, match="positions .*table.* must have pixel columns"):
        psf_photometry(small_image, Table({"a": [1.0]}), psf=FWHM)
    with pytest.raises(ValueError, match="smooth_sigma must be >"):
        psf_photometry(small_image, pos, psf=FWHM, smooth_sigma=0)
    with pytest.raises(ValueError, match="psf as an array must be a 2-D PSF image"):
        psf_photometry(small_image, pos, psf=np.ones((3, 3)))


# ---------------------------------------------------------------------------
# measure_pairs
# ---------------------------------------------------------------------------

REFERENCE = SkyCoord(CRVAL[0] * u.deg, CRVAL[1] * u.deg)
AFFINE = np.array([[1.2, 0.3], [0.1, -0.8]])  # theta1 = AFFINE @ theta2 + SHIFT
SHIFT = np.array([1.6, -0.9])  # arcsec
RATIO = 1.5  # F(L1) / F(L2)
BANDS = {"F150W": (0.03, 0.0, 1.0), "F200W": (0.04, 25.0, 0.8)}  # scale, rotation, colour
PSF_FWHM = 0.075 * u.arcsec


def offset_sky(x, y):
    """Sky positions of frame offsets (arcsec, x west, y north), independently of lensdual."""
    return REFERENCE.spherical_offsets_by(-np.asarray(x) * u.arcsec, np.asarray(y) * u.arcsec)


def arc_cutout(centre_xy, band, theta, flux, rng, npix):
    """One band of one arc: a ridge through the cut-out plus the sources."""
    scale, rotation, colour = BANDS[band]
    shape = (npix, npix)
    wcs = make_wcs(shape, crval=(0, 0), scale=scale, rotation=rotation)
    centre = offset_sky(*centre_xy)
    wcs.wcs.crval = [centre.ra.deg, centre.dec.deg]
    fwhm = PSF_FWHM.to_value(u.arcsec) / scale
    xpix, ypix = wcs.world_to_pixel(offset_sky(theta[:, 0], theta[:, 1]))
    ridge = arc_image(
        shape, centre=(npix / 2, npix / 2 - 150.0), radius=150.0, peak=30.0, fwhm=fwhm
    )
    image, _ = render(ridge, np.column_stack([xpix, ypix]), colour * flux, rng, fwhm=fwhm, wcs=wcs)
    return image


@pytest.fixture(scope="module")
def two_arcs():
    rng = np.random.default_rng(42)
    t = np.linspace(-1, 1, 8)
    theta2 = np.column_stack([-1.2 + 0.7 * t, 0.8 + 0.25 * t**2 + rng.normal(0, 0.05, 8)])
    theta1 = theta2 @ AFFINE.T + SHIFT
    flux2 = rng.uniform(2000, 5000, 8)
    images = {}
    for arc, theta, flux in (("1", theta1, RATIO * flux2), ("2", theta2, flux2)):
        centre = theta.mean(axis=0)
        images[arc] = {
            band: arc_cutout(centre, band, theta, flux, rng, 120 if band == "F150W" else 90)
            for band in BANDS
        }
    pairs = QTable()
    pairs["pair_id"] = np.arange(1, 9)
    jitter = rng.normal(scale=0.005, size=(4, 8))
    pairs["sky1"] = offset_sky(theta1[:, 0] + jitter[0], theta1[:, 1] + jitter[1])
    pairs["sky2"] = offset_sky(theta2[:, 0] + jitter[2], theta2[:, 1] + jitter[3])
    pairs["note"] = ["x"] * 8
    return images, pairs, theta1, theta2, flux2


@pytest.fixture(scope="module")
def measured(two_arcs):
    images, pairs, *_ = two_arcs
    before = pairs.copy()
    return before, measure_pairs(images["1"], images["2"], pairs, psf=PSF_FWHM, reference=REFERENCE)


def test_measure_pairs(two_arcs, measured):
    images, pairs, theta1, theta2, flux2 = two_arcs
    before, out = measured
    # the input is untouched, the output is a new table with the extra columns kept
    assert pairs.colnames == before.colnames
    assert np.all(pairs["sky1"].separation(before["sky1"]) == 0 * u.deg)
    assert out["note"].tolist() == ["x"] * 8
    assert out.meta["bands"] == ["F150W", "F200W"]
    assert out.meta["reference"] == REFERENCE
    # both arcs in one frame: the injected positions to 5 mas
    for arc, theta in (("1", theta1), ("2", theta2)):
        assert out[f"x{arc}"].unit == u.arcsec
        dx = out[f"x{arc}"].to_value(u.arcsec) - theta[:, 0]
        dy = out[f"y{arc}"].to_value(u.arcsec) - theta[:, 1]
        assert np.max(np.hypot(dx, dy)) < 0.005
        err = out[f"pos_err{arc}"].to_value(u.arcsec)
        assert np.all((err > 0) & (err < 0.002))
        sep = out[f"sky{arc}"].separation(offset_sky(theta[:, 0], theta[:, 1]))
        assert np.max(sep.to_value(u.arcsec)) < 0.005
    # the affine map between the arcs
    t1 = np.column_stack([out["x1"].value, out["y1"].value])
    t2 = np.column_stack([out["x2"].value, out["y2"].value])
    design = np.column_stack([t2, np.ones(8)])
    coef = np.linalg.lstsq(design, t1, rcond=None)[0]
    np.testing.assert_allclose(coef[:2].T, AFFINE, atol=2e-3)
    # the flux ratio, band by band
    for band, (_, _, colour) in BANDS.items():
        f1, f2 = out[f"flux1_{band}"], out[f"flux2_{band}"]
        e1, e2 = out[f"flux_err1_{band}"], out[f"flux_err2_{band}"]
        assert f1.unit == u.nJy
        ratio = (f1 / f2).to_value(u.one)
        ratio_err = ratio * np.hypot(e1 / f1, e2 / f2).to_value(u.one)
        assert np.all(np.abs(ratio - RATIO) < 3.5 * ratio_err)
        assert np.median(ratio) == pytest.approx(RATIO, rel=0.01)
        assert np.median(np.abs(np.log(f2.to_value(u.nJy) / (colour * flux2)))) < 0.02
        assert np.all(out[f"flags1_{band}"] == 0)


def test_measure_pairs_frame_sign(measured):
    """x grows to the west: a source west of the reference (smaller RA) has x > 0."""
    _, out = measured
    for arc in ("1", "2"):
        west = out[f"sky{arc}"].ra < REFERENCE.ra
        assert np.all((out[f"x{arc}"] > 0) == west)
        north = out[f"sky{arc}"].dec > REFERENCE.dec
        assert np.all((out[f"y{arc}"] > 0) == north)
    assert np.any(out["x1"] > 0) and np.any(out["x2"] < 0)


def test_measure_pairs_xy_input_and_default_reference(two_arcs):
    images, pairs, theta1, theta2, _ = two_arcs
    xy = QTable()
    xy["x1"], xy["y1"] = theta1.T * u.arcsec
    xy["x2"], xy["y2"] = theta2.T * u.arcsec
    out = measure_pairs(
        images["1"], images["2"], xy, psf=PSF_FWHM, reference=REFERENCE, bands=["F150W"]
    )
    assert out["pair_id"].tolist() == list(range(1, 9))
    assert out.meta["bands"] == ["F150W"]
    assert "flux1_F200W" not in out.colnames
    assert np.max(np.abs(out["x1"].to_value(u.arcsec) - theta1[:, 0])) < 0.005
    # default reference: the mean of all initial positions; the map is unchanged
    free = measure_pairs(images["1"], images["2"], pairs, psf=PSF_FWHM, bands="F150W")
    ref = free.meta["reference"]
    mean = offset_sky(*np.vstack([theta1, theta2]).mean(axis=0))
    assert ref.separation(mean).to_value(u.arcsec) < 0.02
    d1 = np.diff(free["x1"].to_value(u.arcsec))
    np.testing.assert_allclose(d1, np.diff(out["x1"].to_value(u.arcsec)), atol=1e-3)


def test_measure_pairs_bad_input(two_arcs):
    images, pairs, theta1, theta2, _ = two_arcs
    l1, l2 = images["1"], images["2"]
    no_wcs = {b: CCDData(img.data, unit=img.unit) for b, img in l1.items()}
    with pytest.raises(ValueError, match=r"images_l1\['F150W'\] has no WCS"):
        measure_pairs(no_wcs, l2, pairs, psf=PSF_FWHM)
    linear = WCS(naxis=2)
    linear.wcs.ctype = ["LINEAR", "LINEAR"]
    with pytest.raises(ValueError, match=r"images_l2\['F150W'\] has no celestial WCS"):
        measure_pairs(
            l1,
            {**l2, "F150W": CCDData(l2["F150W"].data, unit="nJy", wcs=linear)},
            pairs,
            psf=PSF_FWHM,
        )
    with pytest.raises(ValueError, match=r"band\(s\) \['F200W'\] missing from images_l2"):
        measure_pairs(l1, {"F150W": l2["F150W"]}, pairs, psf=PSF_FWHM)
    with pytest.raises(ValueError, match=r"missing from images_l1"):
        measure_pairs(l1, l2, pairs, psf=PSF_FWHM, bands=["F150W", "F444W"])
    with pytest.raises(TypeError, match="images_l2 must be a dict"):
        measure_pairs(l1, list(l2.values()), pairs, psf=PSF_FWHM)
    with pytest.raises(TypeError, match=r"images_l1\['F150W'\] must be a CCDData"):
        measure_pairs({"F150W": l1["F150W"].data}, l2, pairs, psf=PSF_FWHM, bands=["F150W"])
    xy = QTable()
    xy["x1"], xy["y1"] = theta1.T * u.arcsec
    xy["x2"], xy["y2"] = theta2.T * u.arcsec
    with pytest.raises(ValueError, match="pass reference"):
        measure_pairs(l1, l2, xy, psf=PSF_FWHM)
    with pytest.raises(ValueError, match="pairs must have SkyCoord columns sky1 and sky2"):
        measure_pairs(l1, l2, QTable({"a": [1]}), psf=PSF_FWHM)
    with pytest.raises(TypeError, match="reference must be a scalar SkyCoord"):
        measure_pairs(l1, l2, pairs, psf=PSF_FWHM, reference=(1.0, 2.0))
    with pytest.raises(TypeError, match="pairs must be an astropy Table"):
        measure_pairs(l1, l2, {"sky1": pairs["sky1"]}, psf=PSF_FWHM)
    nd = {b: NDData(img.data, wcs=img.wcs) for b, img in l2.items()}
    with pytest.raises(ValueError, match="must both have flux units or both have none"):
        measure_pairs(l1, nd, pairs, psf=PSF_FWHM)


def test_measure_pairs_flagged_fit_is_nan(two_arcs):
    """A pair whose L2 'source' is a hole: negative flux, flagged, NaN, one warning."""
    images, pairs, theta1, theta2, _ = two_arcs
    l2 = images["2"]["F150W"]
    extra1 = np.array([theta1[0, 0] + 0.3, theta1[0, 1] - 0.3])
    extra2 = np.array([theta2[0, 0] - 0.2, theta2[0, 1] - 0.35])
    px, py = l2.wcs.world_to_pixel(offset_sky(*extra2))
    ny, nx = l2.shape
    yy, xx = np.mgrid[:ny, :nx]
    holed = CCDData(
        l2.data - 800 * prf(xx - px, yy - py), unit=l2.unit, uncertainty=l2.uncertainty, wcs=l2.wcs
    )
    more = pairs.copy()
    more.add_row(
        {"pair_id": 9, "sky1": offset_sky(*extra1), "sky2": offset_sky(*extra2), "note": "hole"}
    )
    with pytest.warns(LensdualWarning, match=r"L2 F150W: pairs \[9\]"):
        out = measure_pairs(
            images["1"], {"F150W": holed}, more, psf=PSF_FWHM, bands=["F150W"], reference=REFERENCE
        )
    assert out["flags2_F150W"][8] & 4
    assert np.isnan(out["flux2_F150W"][8]) and np.isnan(out["x2"][8])
    assert np.isnan(out["pos_err2"][8]) and np.isnan(out["sky2"][8].ra)
    assert np.all(np.isfinite(out["x2"][:8]))


# ---------------------------------------------------------------------------
# oversampled PSF images
# ---------------------------------------------------------------------------


def psf_images(fwhm=FWHM, half=12, oversampling=4):
    """The Gaussian PRF on the detector grid and on a grid ``oversampling`` times finer
    (an effective PSF: the detector-pixel response at sub-pixel offsets), odd-sized."""
    t = np.arange(-half, half + 1)
    native = prf(t[None, :], t[:, None], fwhm)
    tf = np.arange(-oversampling * half, oversampling * half + 1) / oversampling
    over = prf(tf[None, :], tf[:, None], fwhm)
    return native, over / over.sum()  # normalised as a WebbPSF HDU 0 (sum 1)


def close_groups(fwhm=FWHM, seed=1):
    """Two close pairs of sources near each other: neighbouring groups, no single source."""
    rng = np.random.default_rng(seed)
    xy = np.array([[20.0, 30.0], [23.5, 30.0], [31.0, 30.0], [34.5, 30.0]])
    flux = np.array([2000.0, 1500.0, 1800.0, 1200.0])
    image, _ = render(np.zeros((60, 60)), xy, flux, rng, fwhm=fwhm, wcs=make_wcs((60, 60)))
    return image, xy, flux


@pytest.mark.parametrize("kind", ["gaussian", "native", "oversampled"])
def test_neighbouring_groups_without_single_source(kind):
    """Regression: a neighbour class made only of groups crashed with 'need at least one
    array to concatenate' (with or without an oversampled PSF)."""
    image, xy, flux = close_groups()
    native, over = psf_images()
    kw = {
        "gaussian": {"psf": FWHM},
        "native": {"psf": native},
        "oversampled": {"psf": over, "oversampling": 4},
    }[kind]
    res = psf_photometry(image, xy + 0.2, **kw)
    assert res["group_size"].tolist() == [2, 2, 2, 2]
    assert np.all(res["flags"] == 0)
    pull = (res["flux"].to_value(u.nJy) - flux) / res["flux_err"].to_value(u.nJy)
    assert np.all(np.abs(pull) < 3)


def test_an_off_centre_psf_image_is_refused():
    """A PSF image whose core is 1-2 detector pixels from its central pixel would move
    every position of its band and fail fits, and the bands' disagreement would be
    blamed on the constellation: it is refused, naming the PSF and the offset, in
    psf_photometry and measure_pairs. An oversampled PSF a quarter pixel off (one of
    its own pixels) is accepted."""
    image, xy, _ = close_groups()
    native, over = psf_images()
    for shift, psf, oversampling in ((1, native, None), (-2, native, None), (4, over, 4)):
        moved = np.roll(psf, shift, axis=1)
        dx = shift / (oversampling or 1)
        said = re.escape(f"is centred ({dx:+.2f}, +0.00) detector pixels (x, y) away")
        with pytest.raises(ValueError, match=r"psf \(a PSF image\) is not centred on its "
                                             rf"central pixel \(\d+, \d+\): its core .* {said}"):
            psf_photometry(image, xy, psf=moved, oversampling=oversampling)
    res = psf_photometry(image, xy, psf=np.roll(over, 1, axis=0), oversampling=4)
    assert np.all(np.isfinite(res["flux"]))
    l1, l2, pairs = _band_images(0.0)
    with pytest.raises(ValueError, match="is not centred on its central pixel"):
        measure_pairs(l1, l2, pairs, psf={"F150W": 2.5, "F200W": np.roll(native, 2, axis=0)})


def test_oversampled_psf_matches_native(runs):
    """A 4x oversampled PSF image gives the fluxes and positions of the detector-sampled
    one (and of the analytic PRF) on the same data, within a fraction of their errors."""
    xy, flux, _, _, _, image = runs[0]
    start = xy + np.random.default_rng(3).normal(scale=0.3, size=xy.shape)
    native, over = psf_images()
    fits = {
        "gaussian": psf_photometry(image, start, psf=FWHM, fit_shape=13),
        "native": psf_photometry(image, start, psf=native),
        "oversampled": psf_photometry(image, start, psf=over, oversampling=4),
        "pair": psf_photometry(image, start, psf=over, oversampling=(4, 4)),
    }
    ref = fits["oversampled"]
    assert ref.meta["oversampling"] == [4, 4] and ref.meta["fit_shape"] == (13, 13)
    assert ref.meta["fwhm"] == pytest.approx(FWHM, rel=0.1)
    assert np.all(ref["flags"] == 0)
    err = ref["flux_err"].to_value(u.nJy)
    pull = (ref["flux"].to_value(u.nJy) - flux) / err
    assert np.all(np.abs(pull) < 3.5)
    np.testing.assert_array_equal(fits["pair"]["flux"], ref["flux"])
    for name in ("gaussian", "native"):
        other = fits[name]
        dflux = (other["flux"].to_value(u.nJy) - ref["flux"].to_value(u.nJy)) / err
        assert np.max(np.abs(dflux)) < 0.5, name
        dpos = np.hypot(other["x_fit"] - ref["x_fit"], other["y_fit"] - ref["y_fit"])
        assert np.max(dpos / np.hypot(ref["x_err"], ref["y_err"])) < 1.0, name
        assert np.max(dpos) < 0.05, name


def test_oversampled_psf_without_oversampling_is_refused(runs):
    """An oversampled PSF passed as detector-sampled (or the reverse) never gives fluxes."""
    xy, _, _, _, _, image = runs[0]
    xy = xy[:8]  # a few sources suffice (the check fits at most the 6 brightest)
    native, over = psf_images()
    with pytest.raises(ValueError, match=r"4\.\d times wider than the point sources.*oversampl"):
        psf_photometry(image, xy, psf=over)
    with pytest.raises(ValueError, match=r"narrower than the point sources.*really oversampled"):
        psf_photometry(image, xy, psf=native, oversampling=4)
    # the check can be switched off (the fluxes are then wrong: 4x too wide a PSF)
    one, _ = render(np.zeros((80, 80)), [(40.0, 40.0)], [3000.0], np.random.default_rng(2))
    res = psf_photometry(one, [(40.0, 40.0)], psf=over, check_psf=False, warn=False)
    assert res.meta["fwhm"] > 3 * FWHM
    with pytest.raises(ValueError, match="times wider"):
        psf_photometry(one, [(40.0, 40.0)], psf=over)


def test_oversampling_arguments(small_image):
    from photutils.psf import ImagePSF

    native, over = psf_images()
    pos = [(20.0, 15.0)]
    for bad in (0, 2.5, (1, 2, 3), "4", True):
        with pytest.raises((ValueError, TypeError), match="oversampling must be an integer"):
            psf_photometry(small_image, pos, psf=over, oversampling=bad)
    with pytest.raises(ValueError, match="oversampling=.* applies to a PSF image"):
        psf_photometry(small_image, pos, psf=FWHM, oversampling=4)
    with pytest.raises(ValueError, match="oversampling=.* applies to a PSF image"):
        psf_photometry(small_image, pos, psf=None, oversampling=4)
    with pytest.raises(ValueError, match=r"ImagePSF with oversampling \[4, 4\]; oversampling="):
        psf_photometry(small_image, pos, psf=ImagePSF(over * 16, oversampling=4), oversampling=2)
    res = psf_photometry(
        small_image, pos, psf=ImagePSF(over * 16, oversampling=4), oversampling=4, warn=False
    )
    assert res.meta["oversampling"] == [4, 4]
    assert psf_photometry(small_image, pos, psf=native, oversampling=1, warn=False).meta[
        "oversampling"
    ] == [1, 1]


def test_measure_pairs_oversampled_psf(two_arcs, measured):
    """Per-band oversampled PSF images (different pixel scales) reproduce the Gaussian run."""
    images, pairs, *_ = two_arcs
    _, ref = measured
    psfs = {}
    for band, (scale, _, _) in BANDS.items():
        fwhm = PSF_FWHM.to_value(u.arcsec) / scale
        psfs[band] = psf_images(fwhm, half=10)[1]
    out = measure_pairs(
        images["1"],
        images["2"],
        pairs,
        psf=psfs,
        oversampling={"F150W": 4, "F200W": (4, 4)},
        reference=REFERENCE,
    )
    assert out.meta["photometry"]["oversampling"] == {"F150W": 4, "F200W": (4, 4)}
    assert np.all(out["photometry_flags"] == 0) and np.all(out["measured"])
    for band in BANDS:
        for arc in ("1", "2"):
            f, f0 = out[f"flux{arc}_{band}"], ref[f"flux{arc}_{band}"]
            e0 = ref[f"flux_err{arc}_{band}"]
            assert np.max(np.abs(((f - f0) / e0).to_value(u.one))) < 0.5
    for arc in ("1", "2"):
        d = np.hypot(out[f"x{arc}"] - ref[f"x{arc}"], out[f"y{arc}"] - ref[f"y{arc}"])
        assert np.max(d.to_value(u.arcsec)) < 0.002
    with pytest.raises(ValueError, match="oversampling of band 'F200W' must be an integer"):
        measure_pairs(images["1"], images["2"], pairs, psf=psfs, oversampling={"F200W": 0})


# ---------------------------------------------------------------------------
# one bad candidate does not stop the run
# ---------------------------------------------------------------------------


def test_flags_are_named():
    assert PhotometryFlag.NON_POSITIVE_FLUX == 4 and PhotometryFlag.TOO_FEW_PIXELS == 256
    own = [PhotometryFlag.OUTSIDE_IMAGE, PhotometryFlag.BAD_ERROR, PhotometryFlag.FIT_FAILED]
    assert all(int(f) >= 1 << 16 for f in own)  # never a photutils bit
    assert describe_flags(0) == ""
    assert describe_flags(4 | 16) == "non-positive flux, no covariance (no errors) from the fit"
    assert describe_flags(1 | int(PhotometryFlag.OUTSIDE_IMAGE), unusable_only=True).startswith(
        "initial position outside the image"
    )
    assert not UNUSABLE_FLAGS & (PhotometryFlag.N_PIXELS_FIT_PARTIAL | PhotometryFlag.NEAR_BOUND)


def test_measure_pairs_bad_candidates_do_not_stop_the_run(two_arcs):
    """A candidate on blank (unexposed) sky, one off the image: NaN, flags and notes that
    name the pair, source id, arc, band and file; the other pairs are measured as usual."""
    images, pairs, theta1, *_ = two_arcs
    l2 = dict(images["2"])
    img = l2["F150W"]
    px, py = img.wcs.world_to_pixel(pairs["sky2"][2])
    data, err = img.data.copy(), img.uncertainty.array.copy()
    yy, xx = np.mgrid[: data.shape[0], : data.shape[1]]
    blank = np.hypot(xx - px, yy - py) < 7  # no data, error 0, as outside a mosaic
    data[blank], err[blank] = np.nan, 0.0
    l2["F150W"] = CCDData(
        data,
        unit=img.unit,
        wcs=img.wcs,
        uncertainty=StdDevUncertainty(err),
        mask=blank,
        meta={"FILENAME": "l2_f150w_i2d.fits"},
    )
    more = pairs.copy()
    more["id1"], more["id2"] = np.arange(101, 109), np.arange(201, 209)
    more["sky1"][4] = offset_sky(theta1[4, 0] + 5.0, theta1[4, 1])  # off every L1 image
    with pytest.warns(LensdualWarning, match=r"pairs \[5\] cannot be tested") as rec:
        out = measure_pairs(images["1"], l2, more, psf=PSF_FWHM, reference=REFERENCE)
    text = str(rec[0].message)
    assert "L2 F150W: pairs [3]" in text and "L1 F150W: pairs [5]" in text
    # pair 3: its L2 F150W fit had no pixel; F200W still measures it
    assert out["flags2_F150W"][2] & (PhotometryFlag.FULLY_MASKED | PhotometryFlag.TOO_FEW_PIXELS)
    assert np.isnan(out["flux2_F150W"][2]) and np.isnan(out["flux_err2_F150W"][2])
    assert np.isfinite(out["flux2_F200W"][2]) and np.isfinite(out["x2"][2])
    assert out["measured"][2]
    note = out["photometry_note"][2]
    assert note.startswith("pair 3 (source id 203), L2 F150W [l2_f150w_i2d.fits]: ")
    assert "masked" in note or "too few valid pixels" in note
    # pair 5: off the L1 images, not fitted there: no L1 position, not testable
    for band in BANDS:
        assert out[f"flags1_{band}"][4] == PhotometryFlag.OUTSIDE_IMAGE
        assert np.isnan(out[f"flux1_{band}"][4])
    assert np.isnan(out["x1"][4]) and not out["measured"][4]
    assert out["photometry_flags"][4] == PhotometryFlag.OUTSIDE_IMAGE
    assert (
        "pair 5 (source id 105), L1 F150W: initial position outside" in (out["photometry_note"][4])
    )
    assert "no band measured its L1 position" in out["photometry_note"][4]
    # the others are untouched
    clean = [0, 5, 6, 7]
    assert np.all(out["photometry_flags"][clean] == 0) and np.all(out["measured"][clean])
    assert all(out["photometry_note"][k] == "" for k in clean)
    for band in BANDS:
        assert np.all(np.isfinite(out[f"flux1_{band}"][clean]))


def test_measure_pairs_negative_flux_is_named(two_arcs):
    """A 'source' that is a hole: NON_POSITIVE_FLUX, NaN, named in photometry_note."""
    images, pairs, theta1, theta2, _ = two_arcs
    l2 = images["2"]["F150W"]
    extra2 = np.array([theta2[0, 0] - 0.2, theta2[0, 1] - 0.35])
    px, py = l2.wcs.world_to_pixel(offset_sky(*extra2))
    ny, nx = l2.shape
    yy, xx = np.mgrid[:ny, :nx]
    holed = CCDData(
        l2.data - 800 * prf(xx - px, yy - py), unit=l2.unit, uncertainty=l2.uncertainty, wcs=l2.wcs
    )
    more = pairs.copy()
    more.add_row(
        {
            "pair_id": 9,
            "sky1": offset_sky(theta1[0, 0] + 0.3, theta1[0, 1] - 0.3),
            "sky2": offset_sky(*extra2),
            "note": "hole",
        }
    )
    with pytest.warns(LensdualWarning, match="pair 9, L2 F150W: non-positive flux"):
        out = measure_pairs(
            images["1"], {"F150W": holed}, more, psf=PSF_FWHM, bands=["F150W"], reference=REFERENCE
        )
    assert out["photometry_flags"][8] & PhotometryFlag.NON_POSITIVE_FLUX
    assert not out["measured"][8] and np.all(out["measured"][:8])


# ---------------------------------------------------------------------------
# messages that name the input and the fix
# ---------------------------------------------------------------------------


def test_all_nan_image_and_zero_error_map(small_image):
    pos = [(20.0, 15.0)]
    meta = {"FILENAME": "arcL1_f150w.fits"}
    nan = CCDData(np.full((30, 40), np.nan), unit="nJy", wcs=small_image.wcs, meta=meta)
    with pytest.raises(
        ValueError,
        match=r"arc L1, band F150W \(file arcL1_f150w\.fits\) has no valid pixel: all 1200 "
        r"pixels .* NaN or infinite\. Check that the right file and extension",
    ):
        psf_photometry(nan, pos, psf=FWHM, label="arc L1, band F150W")
    zero = CCDData(
        small_image.data,
        unit="nJy",
        wcs=small_image.wcs,
        uncertainty=StdDevUncertainty(np.zeros((30, 40))),
        mask=np.ones((30, 40), bool),  # as config.load_images masks error <= 0
        meta=meta,
    )
    with pytest.raises(
        ValueError, match=r"arcL1_f150w\.fits\) has no valid pixel: its error map .* is zero at"
    ):
        psf_photometry(zero, pos, psf=FWHM)
    nan_err = CCDData(
        small_image.data,
        unit="nJy",
        wcs=small_image.wcs,
        uncertainty=StdDevUncertainty(np.full((30, 40), np.nan)),
    )
    with pytest.raises(ValueError, match="error map .* is NaN or infinite at every pixel"):
        psf_photometry(nan_err, pos, psf=FWHM)
    masked = CCDData(small_image.data, unit="nJy", mask=np.ones((30, 40), bool))
    with pytest.raises(ValueError, match="image has no valid pixel: its mask is True"):
        psf_photometry(masked, pos, psf=FWHM)
    # measure_pairs names the arc and the band (and the file)
    pairs = QTable({"sky1": small_image.wcs.pixel_to_world([20.0], [15.0])})
    pairs["sky2"] = pairs["sky1"]
    with pytest.raises(
        ValueError, match=r"images_l2\['F150W'\] \(arc L2, band F150W\) \(file arcL1_f150w"
    ):
        measure_pairs({"F150W": small_image}, {"F150W": nan}, pairs, psf=FWHM)


def test_single_plane_cube_is_squeezed(small_image):
    from astropy.wcs import WCS

    pos = [(20.0, 15.0)]
    flat = psf_photometry(small_image, pos, psf=FWHM, warn=False)
    with pytest.warns(LensdualWarning, match=r"shape \(1, 30, 40\) \(a cube with NAXIS3 = 1\)"):
        res = psf_photometry(small_image.data[None], pos, psf=FWHM, warn=False)
    np.testing.assert_allclose(res["flux"], flat["flux"].value)
    w3 = WCS(naxis=3)
    w3.wcs.ctype = ["RA---TAN", "DEC--TAN", "WAVE"]
    w3.wcs.crval = [*small_image.wcs.wcs.crval, 1.5e-6]
    w3.wcs.crpix = [*small_image.wcs.wcs.crpix, 1.0]
    w3.wcs.cdelt = [*small_image.wcs.wcs.cdelt, 1e-7]
    cube = CCDData(
        small_image.data[None],
        unit="nJy",
        wcs=w3,
        uncertainty=StdDevUncertainty(small_image.uncertainty.array[None]),
    )
    with pytest.warns(LensdualWarning, match="NAXIS3 = 1"):
        res = psf_photometry(cube, pos, psf=FWHM * SCALE * u.arcsec, warn=False)
    assert "sky" in res.colnames
    np.testing.assert_allclose(res["flux"], flat["flux"], rtol=1e-6)
    with pytest.raises(ValueError, match=r"got shape \(3, 30, 40\): a cube of 3 planes"):
        psf_photometry(np.zeros((3, 30, 40)), pos, psf=FWHM)


# ---------------------------------------------------------------------------
# cut-outs: the photometry reads only boxes about the positions
# ---------------------------------------------------------------------------


def _photometry_with_and_without_cutout(monkeypatch, image, xy, **kwargs):
    """psf_photometry forced onto a cut-out, and on the whole image; the boxes used."""
    import lensdual.photometry._psf as phot

    boxes = []
    unpack = phot._unpack_image

    def spy(*args, box=None, **kw):
        boxes.append(box)
        return unpack(*args, box=box, **kw)

    monkeypatch.setattr(phot, "_unpack_image", spy)
    monkeypatch.setattr(phot, "_CUTOUT_MAX_FRACTION", 1.0)
    cut = psf_photometry(image, xy, warn=False, **kwargs)
    cut_boxes = list(boxes)
    monkeypatch.setattr(phot, "_CUTOUT_MAX_FRACTION", 0.0)
    whole = psf_photometry(image, xy, warn=False, **kwargs)
    return cut, whole, cut_boxes, boxes[len(cut_boxes) :]


@pytest.mark.parametrize(
    "kwargs",
    [
        {"psf": FWHM},
        {"psf": None},
        {"psf": FWHM, "background": "residual"},
        {"psf": FWHM, "background": "local"},
        {"psf": FWHM, "background": "plane"},
    ],
    ids=["ridge", "ridge-fwhm-estimated", "residual", "local", "plane"],
)
def test_cutout_gives_the_whole_image_result(runs, monkeypatch, kwargs):
    xy, _, _, _, _, image = runs[0]
    # the sources of the left part of the arc, with a pixel of initial offset
    pick = xy[:, 0] < 60
    start = xy[pick] + 0.4
    cut, whole, cut_boxes, whole_boxes = _photometry_with_and_without_cutout(
        monkeypatch, image, start, **kwargs
    )
    assert all(b is None for b in whole_boxes)
    assert cut_boxes and all(b is not None for b in cut_boxes)
    assert cut_boxes[-1][1].stop < image.shape[1]  # a real cut-out
    for name in ("x_fit", "y_fit", "x_err", "y_err", "bkg", "reduced_chi2"):
        np.testing.assert_allclose(cut[name], whole[name], rtol=1e-10, atol=1e-10, err_msg=name)
    for name in ("flux", "flux_err"):
        np.testing.assert_allclose(
            cut[name].to_value(u.nJy), whole[name].to_value(u.nJy), rtol=1e-10, err_msg=name
        )
    assert np.array_equal(cut["flags"], whole["flags"])
    assert cut.meta["fwhm"] == pytest.approx(whole.meta["fwhm"], rel=1e-10)
    assert cut["sky"].separation(whole["sky"]).max() < 1e-8 * u.arcsec


def test_cutout_box_and_fallback(small_image, monkeypatch):
    import lensdual.photometry._psf as phot

    # the box: bounding box of the positions plus the margin, clipped to the image
    box = phot._cutout_box(np.array([10.2, 30.7]), np.array([5.0, 8.0]), (100, 200), 4)
    assert box == (slice(1, 13), slice(6, 36))
    assert phot._cutout_box(np.array([5.0]), np.array([5.0]), (10, 10), 4) is None  # > half
    assert phot._cutout_box(np.array([]), np.array([]), (100, 200), 4) is None
    # a cut-out without any valid pixel: the whole image decides
    monkeypatch.setattr(phot, "_CUTOUT_MAX_FRACTION", 1.0)
    data = np.array(small_image.data, dtype=float)
    data[:, :20] = np.nan
    res = psf_photometry(data, [[5.0, 10.0]], psf=FWHM, warn=False)
    assert not np.isfinite(res["flux"][0])


# ---------------------------------------------------------------------------
# ArcPSFPhotometry: set up once, called on images
# ---------------------------------------------------------------------------


def _same_table(a, b):
    assert a.colnames == b.colnames
    for name in a.colnames:
        if name == "sky":
            assert np.all(a[name].separation(b[name]) == 0 * u.deg)
        elif name == "flag_note":
            assert list(a[name]) == list(b[name])
        else:
            np.testing.assert_array_equal(np.asarray(a[name]), np.asarray(b[name]), err_msg=name)
    assert a.meta == b.meta


@pytest.mark.parametrize(
    "settings",
    [
        {"psf": FWHM},
        {"psf": None, "background": "residual", "neighbour_passes": 2},
        {"psf": FWHM * SCALE * u.arcsec, "background": "local", "group_radius": 0},
    ],
    ids=["ridge", "residual-fwhm-fitted", "local-angle"],
)
def test_arc_psf_photometry_equals_psf_photometry(settings):
    from lensdual.photometry import ArcPSFPhotometry

    image, xy, _ = close_groups()
    start = np.vstack([xy, [[45.0, 12.0]]]) + 0.2
    phot = ArcPSFPhotometry(**settings)
    by_object = phot(image, start, label="scene A")
    by_function = psf_photometry(image, start, label="scene A", **settings)
    _same_table(by_object, by_function)
    assert by_object.meta["input"] == "scene A"
    # the object is reusable: a second image gives what the function gives on it
    other = CCDData(
        image.data[:, ::-1].copy(), unit=image.unit, uncertainty=image.uncertainty, wcs=image.wcs
    )
    mirrored = np.column_stack([59.0 - start[:, 0], start[:, 1]])
    _same_table(phot(other, mirrored), psf_photometry(other, mirrored, **settings))


def test_arc_psf_photometry_checks_its_settings_at_init():
    from photutils.background import LocalBackground

    from lensdual.photometry import ArcPSFPhotometry

    bad = [
        ({"psf": "gauss"}, TypeError, "psf must be"),
        ({"psf": -2.0}, ValueError, "psf .*FWHM.* must be finite and positive"),
        ({"psf": 0 * u.arcsec}, ValueError, "psf .*FWHM.* must be finite and positive"),
        ({"psf": 2 * u.s}, TypeError, "psf as a Quantity"),
        ({"psf": np.ones((3, 3))}, ValueError, "psf as an array must be a 2-D PSF image"),
        ({"psf": FWHM, "oversampling": 4}, ValueError, "applies to a PSF image"),
        ({"oversampling": 0}, ValueError, "oversampling must be an integer >= 1"),
        ({"background": "median"}, ValueError, "background must be one of"),
        ({"background": 3}, TypeError, "background must be a string"),
        ({"fit_shape": 8}, ValueError, "fit_shape must be an odd integer"),
        ({"smooth_sigma": 0}, ValueError, "smooth_sigma must be >"),
        ({"maxiters": 0}, ValueError, "maxiters"),
        ({"neighbour_passes": -1}, ValueError, "neighbour_passes"),
        ({"xy_bounds": 0}, ValueError, "xy_bounds"),
        ({"group_radius": -1}, ValueError, "group_radius"),
        ({"background": "local", "local_radii": (5, 3)}, ValueError, "0 <= inner < outer"),
        ({"background": "local", "local_radii": "wide"}, TypeError, "local_radii must be a pair"),
    ]
    for settings, error, match in bad:
        with pytest.raises(error, match=match):
            ArcPSFPhotometry(**settings)
    # settings that need the image are checked when it comes
    phot = ArcPSFPhotometry(0.07 * u.arcsec)
    with pytest.raises(ValueError, match="needs an image with a celestial WCS"):
        phot(np.zeros((20, 20)), [(10.0, 10.0)])
    # local_radii is used (and checked) only by the "local" strategy
    ArcPSFPhotometry(FWHM, local_radii="ignored")
    ArcPSFPhotometry(FWHM, background=LocalBackground(4, 8), local_radii="ignored")
    assert repr(ArcPSFPhotometry(FWHM, background="plane")).startswith(
        "ArcPSFPhotometry(psf=2.5, fit_shape=None, background='plane'"
    )


def test_warnings_name_the_caller(small_image):
    """The summary warning points at the line that called the photometry, through the
    function and the object alike."""
    from lensdual.photometry import ArcPSFPhotometry

    position = [(20.0, 15.0), (-3.0, 10.0)]
    with pytest.warns(LensdualWarning, match="outside the image") as rec:
        psf_photometry(small_image, position, psf=FWHM)
    assert rec[0].filename == __file__
    with pytest.warns(LensdualWarning, match="outside the image") as rec:
        ArcPSFPhotometry(FWHM)(small_image, position)
    assert rec[0].filename == __file__


def test_groups_are_connected_components():
    """Sources are grouped through chains of close neighbours (connected components)."""
    from lensdual.photometry._fitting import _groups

    # a chain 0-2-4 (each link 4 px, ends 8 px apart), a pair 1-3, a lone source 5
    x = np.array([0.0, 50.0, 4.0, 53.0, 8.0, 90.0])
    y = np.zeros(6)
    groups = _groups(x, y, 5.0)
    assert [g.tolist() for g in groups] == [[0, 2, 4], [1, 3]]
    assert _groups(x, y, 0.0) == [] and _groups(x[:1], y[:1], 5.0) == []
    # the same sets as the pairwise-distance closure, on random scenes
    rng = np.random.default_rng(3)
    for _ in range(50):
        n = int(rng.integers(2, 40))
        x, y = rng.uniform(0, 60, (2, n))
        close = np.hypot(x[:, None] - x, y[:, None] - y) < 6.0
        reach = close.copy()
        for _ in range(n):  # transitive closure by repeated boolean products
            reach = reach | ((reach.astype(int) @ reach.astype(int)) > 0)
        expected = {tuple(np.flatnonzero(row)) for row in reach if row.sum() > 1}
        assert {tuple(g) for g in _groups(x, y, 6.0)} == expected


def test_flags_keep_the_meaning_of_photutils_bits():
    """Every photutils PSF flag bit is a PhotometryFlag of the same meaning; lensdual's
    own bits are above all of photutils'."""
    flags_module = pytest.importorskip("photutils.psf.flags")  # photutils >= 2.3
    PSF_FLAGS = flags_module.PSF_FLAGS

    # photutils' names, lensdual's where they differ
    renamed = {"negative_flux": "NON_POSITIVE_FLUX"}
    photutils_bits = dict(PSF_FLAGS.flag_dict)
    for bit, name in photutils_bits.items():
        assert PhotometryFlag(bit).name == renamed.get(name, name.upper())
    own = [f for f in PhotometryFlag if int(f) not in photutils_bits]
    assert own and all(int(f) > max(photutils_bits) for f in own)


def _band_images(shift_px, seed=0, m=8):
    """Two arcs of ``m`` Gaussian point sources in two bands; on arc L2 the F200W
    sources sit ``shift_px`` pixels off in x (a band registration error)."""
    from scipy.special import erf

    rng = np.random.default_rng(seed)
    xs, ys = rng.uniform(15, 105, m), rng.uniform(15, 105, m)
    flux = rng.uniform(400, 900, m)

    def image(x0, flux, dec):
        k = np.sqrt(2) * 2.5 / 2.3548
        data = np.full((120, 120), 10.0)
        for x, y, f in zip(x0, ys, flux, strict=True):
            px = np.diff(erf((np.arange(121) - 0.5 - x) / k)) / 2
            py = np.diff(erf((np.arange(121) - 0.5 - y) / k)) / 2
            data += f * np.outer(py, px)
        data += rng.normal(0, 0.5, data.shape)
        w = WCS(naxis=2)
        w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
        w.wcs.crval, w.wcs.crpix = [110.8, dec], [60, 60]
        w.wcs.cdelt = [-0.03 / 3600, 0.03 / 3600]
        return CCDData(data, unit="adu", wcs=w)

    l1 = {"F150W": image(xs, flux, -73.45), "F200W": image(xs, flux, -73.45)}
    l2 = {"F150W": image(xs, 0.8 * flux, -73.46),
          "F200W": image(xs + shift_px, 0.8 * flux, -73.46)}
    pairs = QTable({"sky1": l1["F150W"].wcs.pixel_to_world(xs, ys),
                    "sky2": l2["F150W"].wcs.pixel_to_world(xs, ys)})
    return l1, l2, pairs


def test_a_band_offset_is_measured_removed_and_named():
    """One band 1.5 px off on one arc: the offset is measured (45 mas, x to the west),
    removed before the bands' positions are combined, and warned about."""
    import warnings

    from lensdual.exceptions import LensdualWarning

    l1, l2, pairs = _band_images(1.5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = measure_pairs(l1, l2, pairs, psf=2.5, background="constant")
    texts = [str(w.message) for w in caught if issubclass(w.category, LensdualWarning)]
    assert any("on arc L2, band F200W is offset from F150W" in t
               and "or the bands' PSF images are not centred alike" in t for t in texts)
    offsets = out.meta["photometry"]["band_offsets"]
    assert offsets["L1"] == {}
    dx, dy = offsets["L2"]["F200W"]
    assert dx == pytest.approx(45.0, abs=1.0) and abs(dy) < 1.0
    # the combined L2 positions are those of the registered bands: the same as with
    # no offset at all, within their errors
    l1c, l2c, pairs_c = _band_images(0.0)
    clean = measure_pairs(l1c, l2c, pairs_c, psf=2.5, background="constant")
    assert clean.meta["photometry"]["band_offsets"] == {"L1": {}, "L2": {}}
    diff = np.hypot((out["x2"] - clean["x2"]).to_value("arcsec"),
                    (out["y2"] - clean["y2"]).to_value("arcsec"))
    assert np.all(diff < 5 * out["pos_err2"].to_value("arcsec"))


def _gauss_image(sources, shape=(80, 80), sky=1.0, read=0.5, gain=0.02):
    """Pixel-integrated Gaussian sources ``(x, y, flux, width factor)`` on a flat sky,
    with the error map of read noise and photon noise (``gain`` counts per variance
    unit)."""
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    img = np.full(shape, sky)
    for x, y, flux, widen in sources:
        img += flux * prf(xx - x, yy - y, FWHM * widen)
    return img, np.sqrt(read**2 + gain * img)


def _clip(img, x, y, level, half=4):
    """Clip the pixels about (x, y) at ``level`` times their largest value."""
    iy, ix = int(round(y)), int(round(x))
    stamp = img[iy - half:iy + half + 1, ix - half:ix + half + 1]
    np.minimum(stamp, level * stamp.max(), out=stamp)


def test_flat_topped_sources_are_flagged_unusable():
    """A bright source clipped at 40 % of its peak (after the noise, as an ADC or
    full well clips, or before it) is FLAT_TOP, an unusable flag, with the ridge and
    the constant background. A bright point source, a faint one clipped as deep and
    one clipped at 90 % of its peak (too little for the noise to tell) are not, nor
    is a resolved source twice the PSF's width (flatter than the PSF, but not cut
    off: its wings are broader than the PSF's too)."""
    sources = [(20.3, 20.6, 2000, 1), (50.2, 20.1, 2000, 1), (20.7, 50.4, 2000, 1),
               (55.5, 55.2, 40, 1), (35.0, 65.0, 2000, 2), (60.4, 36.6, 200, 1)]
    img, err = _gauss_image(sources)
    clean = img.copy()
    _clip(clean, 20.7, 50.4, 0.4)  # source 2: clipped before the noise
    rng = np.random.default_rng(0)
    data = clean + err * rng.standard_normal(img.shape)
    _clip(data, 20.3, 20.6, 0.4)  # source 0: clipped after the noise
    _clip(data, 55.5, 55.2, 0.4)  # source 3: faint
    _clip(data, 60.4, 36.6, 0.9)  # source 5: hardly clipped
    pos = np.array([s[:2] for s in sources])
    for background in ("ridge", "constant"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LensdualWarning)
            res = psf_photometry(NDData(data, uncertainty=StdDevUncertainty(err)), pos,
                                 psf=FWHM, background=background)
        flat = (np.asarray(res["flags"]) & int(PhotometryFlag.FLAT_TOP)) != 0
        assert flat.tolist() == [True, False, True, False, False, False]
    assert PhotometryFlag.FLAT_TOP & UNUSABLE_FLAGS
    assert "saturated" in describe_flags(PhotometryFlag.FLAT_TOP)


def test_flat_top_test_false_alarms_at_its_alpha():
    """Noisy bright point sources (the model itself plus Gaussian noise) are called
    flat-topped no more often than the test's false-alarm probability (1e-4: none
    in 3,000), and the same sources clipped at 60 % of their peak nearly always are."""
    from lensdual.photometry._fitting import _is_flat_top

    yy, xx = np.mgrid[:11, :11].reshape(2, -1).astype(float)
    x0, y0 = 5.3, 4.8
    psf = 3000.0 * prf(xx - x0, yy - y0)
    r2 = (xx - x0) ** 2 + (yy - y0) ** 2
    error = np.sqrt(1.0 + 0.05 * psf)
    rng = np.random.default_rng(1)
    calls = clipped = 0
    for _ in range(3000):
        data = psf + 2.0 + error * rng.standard_normal(psf.size)
        calls += _is_flat_top(data, psf, error, (), r2)
        clipped += _is_flat_top(np.minimum(data, 0.6 * data.max()), psf, error, (), r2)
    assert calls == 0
    assert clipped >= 2990
