"""Tests of lensdual.simulation.mock: mock JWST-like cutouts of the fold pair of arcs."""

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.io import fits
from astropy.nddata import CCDData, StdDevUncertainty
from astropy.table import QTable
from scipy.spatial import cKDTree

from lensdual.detection import find_point_sources
from lensdual.simulation import LensSystem, smacs0723_analog
from lensdual.simulation.mock import (
    DEFAULT_SKY_CENTER,
    PSF_FWHM,
    MockImages,
    lens_to_sky,
    read_mock_images,
    render_mock_images,
    write_mock_images,
)

BANDS = ("F150W", "F200W")
SCALE = 0.04  # arcsec per pixel (the default)


@pytest.fixture(scope="module")
def system():
    return smacs0723_analog(seed=1)


@pytest.fixture(scope="module")
def grid_pairs(system):
    """A resolvable constellation: 12 sources on a jittered 3 x 4 source-plane grid.

    The default constellation (sigma = 0.06 arcsec) puts most images within
    a pixel or two of a neighbour, too crowded for a detection test; the grid
    spacing (0.3 arcsec across the arcs, 0.12 arcsec along them) separates the
    images by >= 5 pixels. Fluxes are fixed (3-10 nJy unlensed).
    """
    gx, gy = np.meshgrid([0.35, 0.65, 0.95], [6.70, 6.82, 6.94, 7.06])
    beta = np.column_stack([gx.ravel(), gy.ravel()])
    beta += np.random.default_rng(0).uniform(-0.02, 0.02, beta.shape)
    return system.constellation(beta * u.arcsec, intrinsic_flux=_intrinsic(len(beta)))


def _intrinsic(m):
    f0 = 10 ** np.random.default_rng(1).uniform(np.log10(3.0), 1.0, m)
    return {"F150W": f0, "F200W": 0.9 * f0}


@pytest.fixture(scope="module")
def mock(system, grid_pairs):
    return render_mock_images(system, pairs=grid_pairs, seed=3)


@pytest.fixture(scope="module")
def clean(system, grid_pairs):
    return render_mock_images(system, pairs=grid_pairs, noise=False, seed=3)


def _isolated(pairs, arc, min_sep):
    """Rows of ``pairs`` whose image on ``arc`` has no other image within min_sep px."""
    k = arc[-1]
    xy = np.column_stack([pairs[f"x{k}"].to_value(u.arcsec), pairs[f"y{k}"].to_value(u.arcsec)])
    d, _ = cKDTree(xy / SCALE).query(xy / SCALE, 2)
    return np.flatnonzero(d[:, 1] > min_sep)


# --------------------------------------------------------------------------- structure


def test_structure(mock, grid_pairs):
    assert isinstance(mock, MockImages)
    assert list(mock) == [(a, b) for a in ("L1", "L2") for b in BANDS]
    assert mock.arcs == ("L1", "L2") and mock.bands == BANDS
    assert set(mock.arc("L1")) == set(BANDS)
    for (arc, band), image in mock.items():
        assert isinstance(image, CCDData)
        assert image.shape == (125, 125)  # 5 arcsec at 0.04 arcsec/px
        assert image.unit == u.nJy
        assert isinstance(image.uncertainty, StdDevUncertainty)
        assert image.uncertainty.array.shape == image.shape
        assert (image.uncertainty.array > 0).all()
        assert image.meta["BAND"] == band and image.meta["ARC"] == arc
        assert image.meta["PIXSCALE"] == pytest.approx(SCALE)
        assert image.meta["PSFFWHM"] == pytest.approx(PSF_FWHM[band].to_value(u.arcsec))
        assert image.meta["PSFTYPE"] == "GAUSSIAN"
        assert image.psf.sum() == pytest.approx(1.0)
        assert image.psf.shape[0] % 2 == 1
        assert mock.host_model[(arc, band)].unit == u.nJy
        assert mock.point_source_model[(arc, band)].shape == image.shape
    # the truth is the input pairs plus the SNR columns
    for name in grid_pairs.colnames:
        np.testing.assert_array_equal(np.asarray(mock.pairs[name]), np.asarray(grid_pairs[name]))
    for band in BANDS:
        for k in "12":
            snr = np.asarray(mock.pairs[f"snr{k}_{band}"])
            assert np.isfinite(snr).all() and (snr > 5).all()
    with pytest.raises(ValueError, match="arc must be one of"):
        mock.arc("L3")
    assert "MockImages" in repr(mock)


def test_default_depth_gives_snr_20_to_100(system):
    """Default constellation and depth: point-source SNRs of a few tens."""
    m = render_mock_images(system, seed=11, cutout_size=60)
    snr = np.concatenate([np.asarray(m.pairs[f"snr{k}_{b}"]) for k in "12" for b in BANDS])
    snr = snr[np.isfinite(snr)]
    assert 30 < np.median(snr) < 100
    assert np.percentile(snr, 10) > 15
    assert np.percentile(snr, 90) < 200
    # the depth knob: 4x the exposure time halves the sky-limited noise
    deep = render_mock_images(system, pairs=m.pairs, seed=11, cutout_size=60,
                              exposure_time=40 * u.ks, noise=False)
    sig = m["L1", "F150W"].uncertainty.array[0, 0]
    assert deep["L1", "F150W"].uncertainty.array[0, 0] == pytest.approx(sig / 2, rel=0.02)


# --------------------------------------------------------------------------- WCS


def test_wcs_orientation(mock):
    image = mock["L1", "F150W"]
    w = image.wcs
    n = image.shape[0]
    c = (n - 1) // 2
    scales = w.proj_plane_pixel_scales()
    for s in scales:
        assert s.to_value(u.arcsec) == pytest.approx(SCALE)
    here = w.pixel_to_world(c, c)
    east = w.pixel_to_world(c + 1, c)
    north = w.pixel_to_world(c, c + 1)
    assert east.ra < here.ra  # x points west: RA decreases with x
    assert north.dec > here.dec
    assert here.separation(east).to_value(u.arcsec) == pytest.approx(SCALE, rel=1e-6)
    # the central pixel is at (CENX, CENY) in the lens frame, the lens centre at CRVAL
    cen = lens_to_sky([[image.meta["CENX"], image.meta["CENY"]]] * u.arcsec)
    assert here.separation(cen[0]).to_value(u.arcsec) < 1e-6
    assert lens_to_sky([[0.0, 0.0]] * u.arcsec)[0].separation(DEFAULT_SKY_CENTER) < 1e-9 * u.deg
    lx, ly = w.world_to_pixel(DEFAULT_SKY_CENTER)
    assert lx == pytest.approx(c - image.meta["CENX"] / SCALE, abs=1e-6)
    assert ly == pytest.approx(c - image.meta["CENY"] / SCALE, abs=1e-6)


@pytest.mark.parametrize("arc", ["L1", "L2"])
def test_wcs_maps_true_images_to_point_source_peaks(clean, grid_pairs, arc):
    """Sky position of each true image (independent of the module's WCS code) -> pixel."""
    k = arc[-1]
    x = grid_pairs[f"x{k}"].to_value(u.arcsec)
    y = grid_pairs[f"y{k}"].to_value(u.arcsec)
    # lens frame: x west, y north, about the lens centre (offset frame = TAN to ~1e-9)
    offsets = SkyCoord(lon=-x * u.arcsec, lat=y * u.arcsec,
                       frame=DEFAULT_SKY_CENTER.skyoffset_frame())
    sky = offsets.transform_to("icrs")
    rows = _isolated(grid_pairs, arc, 3.5)
    assert len(rows) >= 6
    for band in BANDS:
        image = clean[arc, band]
        ps = clean.point_source_model[arc, band].value
        px, py = image.wcs.world_to_pixel(sky)
        np.testing.assert_allclose(np.column_stack([px, py]), clean.truth_pixels(arc),
                                   atol=1e-6)
        for r in rows:
            i, j = int(round(float(px[r]))), int(round(float(py[r])))
            box = ps[j - 2:j + 3, i - 2:i + 3]
            jj, ii = np.unravel_index(np.argmax(box), box.shape)
            # the peak pixel is the one holding the true position
            assert abs(i - 2 + ii - px[r]) <= 0.5 + 1e-9
            assert abs(j - 2 + jj - py[r]) <= 0.5 + 1e-9
            yy, xx = np.mgrid[-1:2, -1:2]
            core = ps[j - 1:j + 2, i - 1:i + 2]
            # light-weighted centre of the 3x3 core: within a quarter pixel
            assert abs(i + (core * xx).sum() / core.sum() - px[r]) < 0.25
            assert abs(j + (core * yy).sum() / core.sum() - py[r]) < 0.25


# --------------------------------------------------------------------------- fluxes


@pytest.mark.parametrize("arc", ["L1", "L2"])
def test_point_source_fluxes(clean, grid_pairs, arc):
    """Noiseless image minus host, summed around a point source = |mu| x intrinsic."""
    k = arc[-1]
    rows = _isolated(grid_pairs, arc, 4.5)
    assert len(rows) >= 2
    intrinsic = _intrinsic(12)
    for band in BANDS:
        image = clean[arc, band]
        resid = image.data - clean.host_model[arc, band].to_value(u.nJy)
        pix = clean.truth_pixels(arc)
        mu = np.asarray(grid_pairs[f"mu{k}"])
        expected = np.abs(mu) * intrinsic[band][np.asarray(grid_pairs["source"])]
        for r in rows:
            i, j = (int(round(v)) for v in pix[r])
            total = resid[j - 2:j + 3, i - 2:i + 3].sum()  # 5 x 5 px box
            assert total == pytest.approx(expected[r], rel=0.03)
        # the whole cutout holds all images of this arc (and none of the other)
        total = clean.point_source_model[arc, band].sum().to_value(u.nJy)
        assert total == pytest.approx(expected.sum(), rel=1e-3)


def test_host_normalisation_unlensed():
    """Without lensing, the host's image sums to its flux; PS fluxes are exact."""

    class Identity:
        def ray_shooting(self, x, y, kwargs):
            return np.array(x, dtype=float), np.array(y, dtype=float)

        def alpha(self, x, y, kwargs):
            return np.zeros_like(x), np.zeros_like(y)

        def hessian(self, x, y, kwargs):
            z = np.zeros_like(np.asarray(x, dtype=float))
            return z, z, z, z

    system = LensSystem.from_model(Identity(), None, z_lens=0.3, z_source=1.0)
    pairs = QTable()
    pairs["x1"], pairs["y1"] = [0.1, 0.5] * u.arcsec, [0.0, 0.3] * u.arcsec
    pairs["x2"], pairs["y2"] = [4.0, 4.2] * u.arcsec, [4.1, 4.5] * u.arcsec
    for band in BANDS:
        pairs[f"flux1_{band}"] = [10.0, 20.0] * u.nJy
        pairs[f"flux2_{band}"] = [5.0, 6.0] * u.nJy
    m = render_mock_images(system, pairs=pairs, noise=False, cutout_size=3 * u.arcsec,
                           host={"center": [0.2, 0.1] * u.arcsec, "R_sersic": 0.2 * u.arcsec,
                                 "flux": {"F150W": 100 * u.nJy, "F200W": 50 * u.nJy}})
    assert m.host_model["L1", "F150W"].sum().to_value(u.nJy) == pytest.approx(100, rel=0.01)
    assert m.host_model["L1", "F200W"].sum().to_value(u.nJy) == pytest.approx(50, rel=0.01)
    assert m.point_source_model["L1", "F150W"].sum().to_value(u.nJy) == pytest.approx(30)
    assert m.point_source_model["L2", "F200W"].sum().to_value(u.nJy) == pytest.approx(11)
    assert m["L1", "F150W"].shape == (75, 75)
    # no host
    bare = render_mock_images(system, pairs=pairs, noise=False, host=False,
                              cutout_size=3 * u.arcsec)
    assert not bare.host_model["L1", "F150W"].value.any()
    np.testing.assert_allclose(bare["L1", "F150W"].data,
                               m.point_source_model["L1", "F150W"].value, atol=1e-9)


# --------------------------------------------------------------------------- noise


def test_noise_statistics(mock, clean):
    for key, image in mock.items():
        model = clean[key].data
        sky = model < 0.01  # pure-sky pixels: host < 0.1 sigma
        assert sky.sum() > 2000
        sig = image.uncertainty.array
        np.testing.assert_allclose(sig, clean[key].uncertainty.array)
        scatter = np.std(image.data[sky])
        assert scatter == pytest.approx(np.median(sig[sky]), rel=0.10)
        # sky-subtracted: mean zero
        assert abs(np.mean(image.data[sky] - model[sky])) < 4 * scatter / np.sqrt(sky.sum())
        # normalised residuals over the whole image (host and point sources too)
        z = (image.data - model) / sig
        assert np.std(z) == pytest.approx(1.0, rel=0.05)
        # Poisson noise of the arc: the uncertainty grows with the model
        assert sig[model > 3].min() > np.median(sig[sky])


def test_reproducible_with_seed(system):
    kw = {"cutout_size": 41, "bands": ["F150W"]}
    a = render_mock_images(system, seed=5, **kw)
    b = render_mock_images(system, seed=5, **kw)
    c = render_mock_images(system, seed=6, **kw)
    d = render_mock_images(system, seed=np.random.default_rng(5), **kw)
    for key in a:
        np.testing.assert_array_equal(a[key].data, b[key].data)
        np.testing.assert_array_equal(a[key].data, d[key].data)
        assert not np.array_equal(a[key].data, c[key].data)
    np.testing.assert_array_equal(a.pairs["flux1_F150W"], b.pairs["flux1_F150W"])
    assert not np.array_equal(a.pairs["flux1_F150W"], c.pairs["flux1_F150W"])


# --------------------------------------------------------------------------- the chain


@pytest.mark.parametrize("arc", ["L1", "L2"])
def test_find_point_sources_on_mocks(mock, arc):
    """Smoke test of the whole chain: the filter of Appendix C finds the point sources."""
    table = find_point_sources(mock.arc(arc))
    assert table is not None and "sky_centroid" in table.colnames
    truth = mock.truth_pixels(arc)
    det = np.column_stack([table["x_centroid"], table["y_centroid"]])
    dist = np.hypot(*(truth[:, None, :] - det[None, :, :]).transpose(2, 0, 1))
    found = dist.min(axis=1) < 2.0
    assert found.mean() >= 0.8
    # and few detections are spurious
    assert (dist.min(axis=0) > 2.0).sum() <= 2


# --------------------------------------------------------------------------- FITS


def test_fits_round_trip(mock, tmp_path):
    paths = write_mock_images(mock, tmp_path / "mocks")
    names = sorted(p.name for p in paths)
    assert names == ["L1_F150W.fits", "L1_F200W.fits", "L2_F150W.fits", "L2_F200W.fits",
                     "truth_pairs.ecsv"]
    back = read_mock_images(tmp_path / "mocks")
    assert list(back) == list(mock)
    for key, image in mock.items():
        other = back[key]
        np.testing.assert_array_equal(other.data, image.data)
        assert other.unit == u.nJy
        assert isinstance(other.uncertainty, StdDevUncertainty)
        np.testing.assert_array_equal(other.uncertainty.array, image.uncertainty.array)
        np.testing.assert_array_equal(other.psf, image.psf)
        assert other.meta["BAND"] == key[1] and other.meta["PSFFWHM"] == image.meta["PSFFWHM"]
        pix = np.array([[0, 0], [62, 62], [124, 17]])
        a = image.wcs.pixel_to_world(pix[:, 0], pix[:, 1])
        b = other.wcs.pixel_to_world(pix[:, 0], pix[:, 1])
        assert (a.separation(b) < 1e-6 * u.arcsec).all()
    for name in mock.pairs.colnames:
        np.testing.assert_allclose(np.asarray(back.pairs[name], dtype=float),
                                   np.asarray(mock.pairs[name], dtype=float))
    assert back.pairs["x1"].unit == u.arcsec
    np.testing.assert_allclose(back.truth_pixels("L2"), mock.truth_pixels("L2"))
    assert back.host_model == {}
    with pytest.raises(OSError):
        write_mock_images(mock, tmp_path / "mocks")
    write_mock_images(dict(mock), tmp_path / "plain", overwrite=True)
    assert read_mock_images(tmp_path / "plain").pairs is None
    with pytest.raises(ValueError, match="no <arc>_<band>.fits"):
        read_mock_images(tmp_path)
    with pytest.raises(ValueError, match="does not exist"):
        read_mock_images(tmp_path / "nowhere")


# --------------------------------------------------------------------------- PSFs


def _gauss(n, sigma):
    c = np.arange(n) - (n - 1) / 2
    g = np.exp(-0.5 * (c / sigma) ** 2)
    return np.outer(g, g)


def test_custom_psf(system, grid_pairs, clean, tmp_path):
    """A user PSF (array, FITS file, per band) is normalised and used as given."""
    kernel = 7.0 * _gauss(11, 0.9)  # any normalisation
    path = tmp_path / "psf.fits"
    fits.PrimaryHDU(_gauss(13, 1.2)).writeto(path)
    m = render_mock_images(system, pairs=grid_pairs, noise=False,
                           psf={"F150W": kernel, "F200W": path})
    img = m["L1", "F150W"]
    assert img.meta["PSFTYPE"] == "USER"
    np.testing.assert_allclose(img.psf, kernel / kernel.sum())
    assert img.meta["PSFFWHM"] == pytest.approx(2.3548 * 0.9 * SCALE, rel=0.01)
    assert m["L1", "F200W"].meta["PSFFWHM"] == pytest.approx(2.3548 * 1.2 * SCALE, rel=0.01)
    # the same point-source flux, spread wider than the default PSF
    for key in m:
        total = m.point_source_model[key].sum().to_value(u.nJy)
        assert total == pytest.approx(clean.point_source_model[key].sum().value, rel=1e-3)
        assert m.point_source_model[key].max() < clean.point_source_model[key].max()
    # a band outside the table works with an explicit PSF
    pairs = QTable(grid_pairs)
    pairs["flux1_F999X"] = pairs["flux1_F150W"]
    pairs["flux2_F999X"] = pairs["flux2_F150W"]
    other = render_mock_images(system, pairs=pairs, bands=["F999X"], psf=kernel,
                               cutout_size=31, seed=0)
    assert other.bands == ("F999X",)


@pytest.mark.parametrize(
    ("psf", "match"),
    [
        (np.ones((4, 4)), "odd number of pixels"),
        (np.ones((5, 7)), "square"),
        (np.ones((5, 5, 5)), "2-D array"),
        (np.ones(5), "2-D array"),
        (_gauss(5, 1.0) - 0.1, "non-negative"),
        (np.zeros((5, 5)), "positive sum"),
        (np.full((5, 5), np.nan), "NaN"),
        ("no_such_file.fits", "no such FITS file"),
    ],
)
def test_bad_psf(system, grid_pairs, psf, match):
    with pytest.raises(ValueError, match=match):
        render_mock_images(system, pairs=grid_pairs, psf=psf)


def test_bad_arguments(system, grid_pairs):
    with pytest.raises(ValueError, match="band 'F999X' has no default PSF"):
        render_mock_images(system, pairs=grid_pairs, bands=["F150W", "F999X"])
    with pytest.raises(ValueError, match=r"psf\['F200W'\] must be square"):
        render_mock_images(system, pairs=grid_pairs, psf={"F200W": np.ones((3, 5))})
    with pytest.raises(TypeError, match="psf must be None, a 2-D array"):
        render_mock_images(system, pairs=grid_pairs, psf=3)
    with pytest.raises(TypeError, match="system must be a LensSystem"):
        render_mock_images("lens", pairs=grid_pairs)
    with pytest.raises(TypeError, match="pixel_scale"):
        render_mock_images(system, pairs=grid_pairs, pixel_scale=0.04)
    with pytest.raises(TypeError, match="cutout_size"):
        render_mock_images(system, pairs=grid_pairs, cutout_size=5.0)
    with pytest.raises(TypeError, match="exposure_time"):
        render_mock_images(system, pairs=grid_pairs, exposure_time=1e4 * u.m)
    with pytest.raises(ValueError, match="exposure_time"):
        render_mock_images(system, pairs=grid_pairs, exposure_time=0 * u.s)
    with pytest.raises(ValueError, match="supersampling must be odd"):
        render_mock_images(system, pairs=grid_pairs, supersampling=4)
    with pytest.raises(ValueError, match=r"host has unknown key\(s\) \['radius'\]"):
        render_mock_images(system, pairs=grid_pairs, host={"radius": 0.2 * u.arcsec})
    with pytest.raises(ValueError, match=r"host\['center'\] must have shape \(2,\)"):
        render_mock_images(system, pairs=grid_pairs, host={"center": [1, 2, 3] * u.arcsec})
    with pytest.raises(TypeError, match=r"host\['R_sersic'\]"):
        render_mock_images(system, pairs=grid_pairs, host={"R_sersic": 0.2})
    with pytest.raises(TypeError, match="host must be True"):
        render_mock_images(system, pairs=grid_pairs, host="sersic")
    with pytest.raises(ValueError, match=r"sky_background lacks band\(s\) \['F200W'\]"):
        render_mock_images(system, pairs=grid_pairs,
                           sky_background={"F150W": 0.2 * u.MJy / u.sr})
    with pytest.raises(ValueError, match=r"pairs lacks column\(s\) \['flux1_F277W'"):
        render_mock_images(system, pairs=grid_pairs, bands=["F277W"])
    with pytest.raises(TypeError, match="pairs must be an astropy QTable"):
        render_mock_images(system, pairs={"x1": 1})
    with pytest.raises(TypeError, match="noise must be True or False"):
        render_mock_images(system, pairs=grid_pairs, noise=1)
    with pytest.raises(TypeError, match="images must be a MockImages"):
        write_mock_images([1, 2], "somewhere")


def test_any_lens_model(system, grid_pairs, clean):
    """A system wrapping a non-lenstronomy model renders the same images."""

    class Wrapped:
        def __init__(self, model):
            self.model = model

        def ray_shooting(self, x, y, kwargs):
            return self.model.ray_shooting(x, y, kwargs)

        def alpha(self, x, y, kwargs):
            return self.model.alpha(x, y, kwargs)

        def hessian(self, x, y, kwargs):
            return self.model.hessian(x, y, kwargs)

    other = LensSystem.from_model(Wrapped(system.lens_model), system.kwargs_lens,
                                  z_lens=system.z_lens, z_source=system.z_source)
    m = render_mock_images(other, pairs=grid_pairs, noise=False, bands=["F200W"])
    np.testing.assert_allclose(m["L2", "F200W"].data, clean["L2", "F200W"].data,
                               rtol=1e-10, atol=1e-12)
