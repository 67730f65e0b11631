"""Hostile inputs to ``lensdual run``: each case reproduced on a broken copy
of the demo's configuration, asserting the exit code, the message and that nothing
half-written is left."""

import sys

import numpy as np
import pytest
from _demo_config import absolute_config, write
from astropy.io import fits
from astropy.table import QTable

from lensdual.cli import main
from lensdual.pipeline import format_pairs_table, verdict

# ------------------------------------------------------------------------------- helpers


def no_leftovers(tmp_path, out):
    assert not out.exists()
    assert not [p for p in tmp_path.rglob("*") if ".partial-" in p.name]


def copy_fits(src, dst, fn):
    with fits.open(src) as hdul:
        fn(hdul)
        hdul.writeto(dst, overwrite=True)
    return dst


def _product(path, kind, rng, pixar=2.0e-14):
    """A JWST *_i2d-like (SCI, ERR, WHT in MJy/sr) or HST *_drz-like (SCI, WHT, CTX)
    file of pure noise with a WCS."""
    from astropy.wcs import WCS

    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [110.8, -73.45]
    w.wcs.crpix = [20.0, 20.0]
    w.wcs.cdelt = [-1e-5, 1e-5]
    shape = (40, 40)
    sigma = 0.3
    sci = fits.ImageHDU(rng.normal(1.0, sigma, shape), w.to_header(), name="SCI")
    hdus = [fits.PrimaryHDU(), sci]
    if kind == "jwst":
        sci.header["BUNIT"] = "MJy/sr"
        sci.header["PIXAR_SR"] = pixar
        hdus += [fits.ImageHDU(np.full(shape, sigma), name="ERR"),
                 fits.ImageHDU(np.full(shape, 5.0), name="WHT")]
    else:
        sci.header["BUNIT"] = "electron/s"
        hdus[0].header["D001WTSC"] = "exp"
        hdus += [fits.ImageHDU(np.full(shape, 1000.0), name="WHT"),
                 fits.ImageHDU(np.ones(shape, dtype=np.int32), name="CTX")]
    fits.HDUList(hdus).writeto(path)
    return path, sigma


# ----------------------------------------------------------- images, error maps and PSFs


def test_error_map_in_other_units_is_refused(demo_dir, tmp_path, capsys):
    cfg = absolute_config(demo_dir)
    spec = cfg["arcs"]["L1"]["F150W"]
    src = spec.get("error", spec["image"])

    def to_mjy_sr(hdul):
        index = 1 if "error_hdu" in spec else 0
        hdul[index].header["BUNIT"] = "MJy/sr"

    spec["error"] = str(copy_fits(src, tmp_path / "err.fits", to_mjy_sr))
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out)]) == 2
    err = capsys.readouterr().err
    assert "[arcs.L1.F150W] error" in err and "not convertible" in err and "MJy / sr" in err
    no_leftovers(tmp_path, out)


def test_error_map_far_below_the_noise_warns(demo_dir, tmp_path, capsys):
    cfg = absolute_config(demo_dir)
    spec = cfg["arcs"]["L1"]["F150W"]
    src = spec.get("error", spec["image"])
    index = 1 if "error_hdu" in spec else 0

    def tiny(hdul):
        hdul[index].data = np.full(hdul[index].data.shape, 1e-12)

    spec["error"] = str(copy_fits(src, tmp_path / "err.fits", tiny))
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out),
                 "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "times the measured noise" in err and "arc L1" in err
    assert "times the measured noise" in (out / "report.txt").read_text()


def test_zero_error_pixels_are_masked_with_a_warning_naming_the_file(demo_dir, tmp_path,
                                                                      capsys):
    """A 15 x 15 block of zero errors around the brightest L1 source: the block is
    masked, and the run says so, naming the error map and the pixel count. No pair is
    lost without a word: the two L1 images on the block (the brightest and its
    neighbour) are not detected, and their pairs are reported untested, naming the
    masked pixels; the neighbours' fluxes are not corrupted (the masked pixels drop
    out of their fits, no more)."""
    cfg = absolute_config(demo_dir)
    spec = cfg["arcs"]["L1"]["F150W"]
    cat = QTable.read(demo_dir / "catalog_L1.ecsv", format="ascii.ecsv")
    k = int(np.argmax(np.asarray(cat["flux_F150W"])))
    x, y = int(round(float(cat["x_pix"][k]))), int(round(float(cat["y_pix"][k])))
    index = 1 if "error_hdu" in spec else 0

    def zero_block(hdul):
        hdul[index].data[y - 7:y + 8, x - 7:x + 8] = 0.0

    spec["error"] = str(copy_fits(spec.get("error", spec["image"]), tmp_path / "err.fits",
                                  zero_block))
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out),
                 "--quiet"]) == 0
    err = capsys.readouterr().err
    said = ("arc L1, L1_F150W_sci.fits (error map err.fits): 225 pixel(s) with data have an "
            "error that is zero")
    assert said in err
    report = (out / "report.txt").read_text()
    assert said in report
    before = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    after = QTable.read(out / "pairs.ecsv", format="ascii.ecsv")
    # every pair of the undamaged run is still there (L2 is untouched: same ids)
    assert len(after) == len(before)
    assert sorted(np.asarray(after["id2"])) == sorted(np.asarray(before["id2"]))
    on_block = (np.abs(np.asarray(cat["x_pix"]) - x) <= 7.5) & \
        (np.abs(np.asarray(cat["y_pix"]) - y) <= 7.5)
    lost_l2 = np.asarray(before["id2"])[np.isin(before["id1"], cat["id"][on_block])]
    assert len(lost_l2) == 2
    lost = np.isin(np.asarray(after["id2"]), lost_l2)
    assert not after["tested"][lost].any()
    for pid, doubt in zip(after["pair_id"][lost], after["doubt"][lost], strict=True):
        assert ("no L1 partner in the pairing" in doubt and "L1_F150W_sci.fits has" in doubt
                and "masked pixel(s)" in doubt)
        assert f"pair {pid} (--, " in report
    # the other pairs' L1 fluxes are those of the undamaged run within their errors
    # (the issue: 11.9 +- 31.9 nJy instead of 20.3 +- 0.45)
    row = {i: k for k, i in enumerate(np.asarray(before["id2"]))}
    kept = np.flatnonzero(~lost)
    old = before[[row[i] for i in np.asarray(after["id2"])[kept]]]
    f_new = np.asarray(after["flux1_F150W"][kept].to_value("nJy"))
    e_new = np.asarray(after["flux_err1_F150W"][kept].to_value("nJy"))
    f_old = np.asarray(old["flux1_F150W"].to_value("nJy"))
    e_old = np.asarray(old["flux_err1_F150W"].to_value("nJy"))
    assert np.all(np.abs(f_new - f_old) < 3 * e_new)
    assert np.all(e_new < 4 * e_old)


@pytest.mark.parametrize("shift", [1, 2])
def test_an_off_centre_psf_is_refused_naming_it(demo_dir, tmp_path, capsys, shift):
    """A PSF image whose peak is 1-2 pixels off its central pixel made nearly every pair
    untestable, and the message blamed the constellation or sigma_pos: the
    configuration is refused (exit 2, before any work), naming the band's PSF file and
    the offset."""
    cfg = absolute_config(demo_dir)
    spec = cfg["bands"]["F200W"]

    def roll(hdul):
        hdul[0].data = np.roll(hdul[0].data, (shift, shift), axis=(0, 1))

    spec["psf"] = str(copy_fits(spec["psf"], tmp_path / "psf.fits", roll))
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out)]) == 2
    err = capsys.readouterr().err
    assert (f"[bands.F200W] psf: the PSF image in {tmp_path / 'psf.fits'} is not centred on "
            f"its central pixel (7, 7): its core (the pixels above half its peak) is centred "
            f"(+{shift}.00, +{shift}.00) detector pixels (x, y) away") in err
    assert "sigma_pos" not in err and "constellation" not in err
    no_leftovers(tmp_path, out)


def test_unit_typo_on_one_band_is_refused(demo_dir, tmp_path, capsys):
    cfg = absolute_config(demo_dir)
    cfg["arcs"]["L2"]["F200W"]["unit"] = "Jy"
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out)]) == 2
    err = capsys.readouterr().err
    assert "[arcs.L2.F200W] unit: 'Jy' is given, but the BUNIT" in err
    cfg["arcs"]["L2"]["F200W"]["unit"] = "nJy / arcsec2"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out)]) == 2
    assert "cannot be converted" in capsys.readouterr().err
    no_leftovers(tmp_path, out)


def test_bands_on_different_pixel_grids_are_refused(demo_dir, tmp_path, capsys):
    from astropy.wcs import WCS

    cfg = absolute_config(demo_dir)
    spec = cfg["arcs"]["L1"]["F200W"]

    def rotate(hdul):
        # the same sky, stored rotated by 90 degrees with a correct WCS
        w = WCS(hdul[0].header)
        hdul[0].data = np.rot90(hdul[0].data).copy()
        ny, nx = hdul[0].data.shape
        new = w.deepcopy()
        new.wcs.pc = w.wcs.get_pc() @ np.array([[0.0, -1.0], [1.0, 0.0]])
        new.wcs.crpix = [w.wcs.crpix[1], nx + 1 - w.wcs.crpix[0]]
        hdul[0].header.update(new.to_header())
        for k in range(1, len(hdul)):
            if hdul[k].data is not None and hdul[k].data.shape == (nx, ny):
                hdul[k].data = np.rot90(hdul[k].data).copy()

    rotated = copy_fits(spec["image"], tmp_path / "rot.fits", rotate)
    spec["image"] = str(rotated)
    if "error" in spec:
        spec["error"] = str(rotated)
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out)]) == 2
    err = capsys.readouterr().err
    assert "[arcs.L1.F200W] image: its pixel grid differs from band F150W" in err
    assert "reproject" in err
    no_leftovers(tmp_path, out)


def test_jwst_and_hst_products_are_read_with_their_extensions(tmp_path):
    import astropy.units as u

    from lensdual.config import load_config, load_images
    from lensdual.exceptions import LensdualWarning

    rng = np.random.default_rng(3)
    for kind in ("jwst", "hst"):
        paths = {arc: _product(tmp_path / f"{kind}_{arc}.fits", kind, rng)[0]
                 for arc in ("L1", "L2")}
        cfg = {"bands": {"F150W": {"psf_fwhm": "0.07 arcsec"}},
               "arcs": {arc: {"F150W": {"image": str(p)}} for arc, p in paths.items()}}
        config = load_config(write(tmp_path / f"{kind}.toml", cfg))
        spec = config.arcs["L1"].images["F150W"]
        if kind == "jwst":
            assert (spec.error_hdu, spec.weight) == ("ERR", None)
            ccd = load_images(config)["L1"]["F150W"]
            # MJy/sr times the pixel area, in nJy per pixel
            factor = (1 * u.MJy).to_value(u.nJy) * 2.0e-14
            assert ccd.unit == u.nJy
            np.testing.assert_allclose(np.median(ccd.data), factor, rtol=0.05)
            np.testing.assert_allclose(ccd.uncertainty.array, 0.3 * factor)
        else:
            assert (spec.weight_hdu, spec.error) == ("WHT", None)
            with pytest.warns(LensdualWarning, match="exposure-time weight"):
                ccd = load_images(config)["L1"]["F150W"]
            # errors scaled to the sky noise (0.3), not 1/sqrt(1000)
            np.testing.assert_allclose(np.median(ccd.uncertainty.array), 0.3, rtol=0.1)


def test_psf_oversampling_key_and_webbpsf_header(tmp_path):
    from lensdual.config import ConfigError, band_oversampling, load_config

    rng = np.random.default_rng(4)
    paths = {arc: _product(tmp_path / f"{arc}.fits", "jwst", rng)[0] for arc in ("L1", "L2")}
    yy, xx = np.mgrid[-22:23, -22:23]
    psf = fits.PrimaryHDU(np.exp(-(xx**2 + yy**2) / 50.0))
    psf.header["OVERSAMP"] = 4  # as WebbPSF / STPSF write HDU 0
    psf.writeto(tmp_path / "psf.fits")
    cfg = {"bands": {"F150W": {"psf": str(tmp_path / "psf.fits")}},
           "arcs": {arc: {"F150W": {"image": str(p)}} for arc, p in paths.items()}}
    config = load_config(write(tmp_path / "a.toml", cfg))
    assert band_oversampling(config) == {"F150W": 4}
    cfg["bands"]["F150W"]["psf_oversampling"] = [2, 2]
    assert band_oversampling(load_config(write(tmp_path / "b.toml", cfg))) == {"F150W": (2, 2)}
    cfg["bands"]["F150W"]["psf_oversampling"] = 0
    with pytest.raises(ConfigError, match=r"psf_oversampling: expected an integer >= 1"):
        load_config(write(tmp_path / "c.toml", cfg))
    cfg["bands"]["F150W"] = {"psf_fwhm": "0.07 arcsec", "psf_oversampling": 4}
    with pytest.raises(ConfigError, match=r"psf_oversampling: given without psf"):
        load_config(write(tmp_path / "d.toml", cfg))


def test_single_plane_cube_names_its_shape(tmp_path):
    from astropy.wcs import WCS

    from lensdual.config import ConfigError, load_config

    w = WCS(naxis=3)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN", "WAVE"]
    w.wcs.crval = [110.8, -73.45, 1.5e-6]
    w.wcs.crpix = [20, 20, 1]
    w.wcs.cdelt = [-1e-5, 1e-5, 1e-7]
    fits.PrimaryHDU(np.zeros((1, 40, 40)), w.to_header()).writeto(tmp_path / "cube.fits")
    cfg = {"bands": {"F150W": {"psf_fwhm": "0.07 arcsec"}},
           "arcs": {arc: {"F150W": {"image": str(tmp_path / "cube.fits")}}
                    for arc in ("L1", "L2")}}
    with pytest.raises(ConfigError, match=r"HDU 0 has shape \(1, 40, 40\): a cube of one plane"):
        load_config(write(tmp_path / "c.toml", cfg))


def test_unsubtracted_sky_is_named(demo_dir, tmp_path, capsys):
    cfg = absolute_config(demo_dir)
    for band, spec in cfg["arcs"]["L1"].items():
        if band == "cutout":
            continue
        src = spec["image"]

        def pedestal(hdul):
            hdul[0].data = hdul[0].data + 1000.0 * np.nanmax(np.abs(hdul[0].data))

        new = copy_fits(src, tmp_path / f"sky_{band}.fits", pedestal)
        if "error" not in spec and "error_hdu" in spec:
            spec["error"] = src  # keep the error map of the original file
        spec["image"] = str(new)
    out = tmp_path / "out"
    code = main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out), "--quiet"])
    assert code == 1
    err = capsys.readouterr().err
    assert "point source(s) found on arc L1" in err and "not to be subtracted" in err
    no_leftovers(tmp_path, out)


def test_the_same_image_for_both_arcs_is_refused(demo_dir, tmp_path, capsys):
    """L2 given L1's files: a configuration problem (exit 2), before any work."""
    cfg = absolute_config(demo_dir)
    cfg["arcs"]["L2"] = {band: dict(spec) for band, spec in cfg["arcs"]["L1"].items()}
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out)]) == 2
    err = capsys.readouterr().err
    assert "[arcs.L2.F150W] image: the same image as [arcs.L1.F150W]" in err
    assert "[arcs.L2.F200W] image" in err
    no_leftovers(tmp_path, out)


def test_copies_of_one_image_for_both_arcs_are_refused(demo_dir, tmp_path, capsys):
    """L2 given copies of L1's files: every pair is one point of the sky; exit 1 with
    a message saying so, never "no sub-halo is detected"."""
    import shutil

    cfg = absolute_config(demo_dir)
    l2 = {}
    for band, spec in cfg["arcs"]["L1"].items():
        l2[band] = {}
        for key in ("image", "error"):
            if key in spec:
                copy = tmp_path / f"copy_{band}_{key}.fits"
                shutil.copy(spec[key], copy)
                l2[band][key] = str(copy)
    cfg["arcs"]["L2"] = l2
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out),
                 "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "arcs L1 and L2 are the same image" in err and "no sub-halo" not in err
    no_leftovers(tmp_path, out)


# ------------------------------------------------------------------ catalogues and bands


def test_a_catalogue_in_hours_read_as_degrees_is_named():
    """RA in hours without a unit puts every source off the image: say so, and why."""
    import astropy.units as u
    from astropy.coordinates import SkyCoord
    from astropy.nddata import CCDData
    from astropy.wcs import WCS

    from lensdual.pipeline import PipelineError, _check_catalogue_footprint

    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval, w.wcs.crpix = [110.8, -73.45], [50, 50]
    w.wcs.cdelt = [-0.03 / 3600, 0.03 / 3600]
    image = {"F150W": CCDData(np.zeros((100, 100)), unit="adu", wcs=w)}
    on = w.pixel_to_world([20, 60], [30, 70])
    _check_catalogue_footprint({"sky": on}, image, "L1")  # on the image: no complaint
    hours = SkyCoord(on.ra.hour * u.deg, on.dec)  # hours read as degrees
    with pytest.raises(PipelineError, match="arc L1 catalogue falls on its F150W image.*"
                                            "look like hours"):
        _check_catalogue_footprint({"sky": hours}, image, "L1")
    far = SkyCoord(on.ra + 1 * u.deg, on.dec)
    with pytest.raises(PipelineError, match="falls on its F150W image") as info:
        _check_catalogue_footprint({"sky": far}, image, "L2")
    assert "hours" not in str(info.value)


def test_bands_swapped_on_one_arc_are_named():
    """Swapped bands on arc L1 make every coloured pair chromatic: the error says so
    instead of suggesting another estimator."""
    import astropy.units as u

    from lensdual.duality import check_duality

    rng = np.random.default_rng(3)
    theta2 = rng.uniform(-1, 1, (12, 2))
    theta1 = theta2 @ np.array([[1.5, 0.3], [0.1, -0.8]]).T
    colour = rng.uniform(0.4, 2.5, 12)  # F200W / F150W of each source
    f2 = {"F150W": np.full(12, 100.0), "F200W": 100.0 * colour}
    f1 = {"F150W": 1.23 * f2["F200W"], "F200W": 1.23 * f2["F150W"]}  # swapped on L1
    pairs = QTable({"x1": theta1[:, 0] * u.arcsec, "y1": theta1[:, 1] * u.arcsec,
                    "x2": theta2[:, 0] * u.arcsec, "y2": theta2[:, 1] * u.arcsec})
    for band in ("F150W", "F200W"):
        pairs[f"flux1_{band}"] = f1[band]
        pairs[f"flux2_{band}"] = f2[band]
        pairs[f"flux_err1_{band}"] = 0.01 * f1[band]
        pairs[f"flux_err2_{band}"] = 0.01 * f2[band]
    with pytest.raises(ValueError, match="bands swapped on one arc") as info:
        check_duality(pairs, sigma_pos=0.002 * u.arcsec)
    assert "another estimator would not help" in str(info.value)
    assert "use 'quad2'" not in str(info.value)


# -------------------------------------------- pairs that must never look like sub-haloes


def test_too_few_pairs_stop_the_adaptive_estimator_and_warn_with_the_others(demo_dir, tmp_path,
                                                                           capsys):
    previous = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    QTable({"id1": previous["id1"][:4], "id2": previous["id2"][:4]}).write(
        tmp_path / "pairs.ecsv", format="ascii.ecsv")
    cfg = absolute_config(demo_dir)
    cfg["pairing"] = {"method": "manual", "file": str(tmp_path / "pairs.ecsv")}
    out = tmp_path / "out"
    # the default estimator refuses: its error bars need 7 pairs
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out),
                 "--quiet"]) == 1
    assert "needs at least 7" in capsys.readouterr().err
    no_leftovers(tmp_path, out)
    # the paper's estimators run, with a loud warning in the verdict
    cfg["analysis"]["estimator"] = "quad"
    assert main(["run", str(write(tmp_path / "q.toml", cfg)), "--outdir", str(out),
                 "--quiet"]) == 0
    assert "WARNING: only 4 pairs" in (out / "report.txt").read_text()


def test_nan_mu_size_is_never_a_pass():
    import astropy.units as u

    from lensdual.duality import check_duality

    rng = np.random.default_rng(0)
    t2 = rng.uniform(-1, 1, (8, 2))
    t1 = t2 @ np.array([[1.3, 0.2], [0.1, -0.9]]).T
    pairs = QTable({"id1": np.arange(8), "id2": np.arange(8),
                    "x1": t1[:, 0] * u.arcsec, "y1": t1[:, 1] * u.arcsec,
                    "x2": t2[:, 0] * u.arcsec, "y2": t2[:, 1] * u.arcsec,
                    "flux1_F150W": np.full(8, 1.17), "flux2_F150W": np.ones(8),
                    "flux_err1_F150W": np.full(8, 0.01), "flux_err2_F150W": np.full(8, 0.01)})
    res = check_duality(pairs, "quad", sigma_pos=0.001 * u.arcsec, n_bootstrap=50, seed=0)
    res["mu_size"][2] = np.nan  # e.g. the 2v estimator on collinear neighbours
    res["tested"][2] = False
    res["snr"][2] = np.nan
    text = verdict(res, 0.001 * u.arcsec)
    assert "could not be tested and are NOT passes" in text and "no mu_size: pair 3" in text
    table = format_pairs_table(res)
    assert "untested (no mu_size)" in table.splitlines()[4]
    res["tested"][:] = False
    res["anomalous"][:] = False
    text = verdict(res, 0.001 * u.arcsec)
    assert "No pair could be tested" in text and "no conclusion" in text


def test_swapped_manual_ids_are_doubtful_never_anomalous(demo_dir, tmp_path):
    previous = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    id1, id2 = list(previous["id1"]), list(previous["id2"])
    id2[1], id2[4] = id2[4], id2[1]
    QTable({"id1": id1, "id2": id2}).write(tmp_path / "pairs.ecsv", format="ascii.ecsv")
    cfg = absolute_config(demo_dir)
    cfg["pairing"] = {"method": "manual", "file": str(tmp_path / "pairs.ecsv")}
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out),
                 "--quiet"]) == 0
    result = QTable.read(out / "pairs.ecsv", format="ascii.ecsv")
    swapped = np.isin(np.arange(len(result)), [1, 4])
    assert not result["anomalous"][swapped].any()
    assert not result["tested"][swapped].any()
    assert all("pairing" in str(d) for d in result["doubt"][swapped])
    assert np.all(result["mu_size_status"][swapped] == "excluded")
    report = (out / "report.txt").read_text()
    assert "Doubtful pairings are left out" in report


def test_spurious_candidates_never_look_like_subhaloes(demo_dir, tmp_path, capsys):
    from astropy.coordinates import SkyCoord

    rng = np.random.default_rng(2)
    cfg = absolute_config(demo_dir)
    paths = {}
    for arc in ("L1", "L2"):
        cat = QTable.read(demo_dir / f"catalog_{arc}.ecsv", format="ascii.ecsv")
        ra, dec = cat["sky"].ra.deg, cat["sky"].dec.deg
        n = 25
        sky = SkyCoord(np.concatenate([ra, rng.uniform(ra.min(), ra.max(), n)]),
                       np.concatenate([dec, rng.uniform(dec.min(), dec.max(), n)]), unit="deg")
        ids = np.concatenate([np.asarray(cat["id"]), np.arange(1000, 1000 + n)])
        QTable({"id": ids, "sky": sky}).write(tmp_path / f"{arc}.ecsv", format="ascii.ecsv")
        paths[arc] = str(tmp_path / f"{arc}.ecsv")
    cfg["catalogs"] = paths
    out = tmp_path / "out"
    code = main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out), "--quiet"])
    if code == 0:
        result = QTable.read(out / "pairs.ecsv", format="ascii.ecsv")
        spurious = (np.asarray(result["id1"]) >= 1000) | (np.asarray(result["id2"]) >= 1000)
        assert not np.any(result["anomalous"] & spurious)
    else:
        # too few trustworthy pairs left: a clear refusal naming the doubtful ones
        assert code == 1
        err = capsys.readouterr().err
        assert "doubtful pair(s) left out" in err
        no_leftovers(tmp_path, out)


def test_bad_manual_candidates_are_untested_and_the_rest_analysed(demo_dir, tmp_path):
    """Two manual pairs with a bad L2 candidate: one on blank sky within the image (no
    point source: its PSF flux is a noise fluctuation), one off the image. Neither
    stops the run; each is untested with its reason and left out of the others' size
    magnifications, and the other pairs are analysed, the sub-haloed one flagged."""
    from astropy.coordinates import SkyCoord
    from astropy.wcs import WCS

    cfg = absolute_config(demo_dir)
    previous = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    blank = WCS(fits.getheader(cfg["arcs"]["L2"]["F150W"]["image"])).pixel_to_world(100, 100)
    cats = {}
    for arc in ("L1", "L2"):
        cat = QTable.read(demo_dir / f"catalog_{arc}.ecsv", format="ascii.ecsv")
        ra, dec = list(cat["sky"].ra.deg), list(cat["sky"].dec.deg)
        ids = list(np.asarray(cat["id"]))
        if arc == "L2":  # blank sky 1 arcsec from the arc, and a source 1 degree away
            ra += [blank.ra.deg, ra[0]]
            dec += [blank.dec.deg, dec[0] + 1.0]
            ids += [998, 999]
        QTable({"id": ids, "sky": SkyCoord(ra, dec, unit="deg")}).write(
            tmp_path / f"{arc}.ecsv", format="ascii.ecsv")
        cats[arc] = str(tmp_path / f"{arc}.ecsv")
    id1, id2 = list(previous["id1"]), list(previous["id2"])
    id2[-1], id2[-2] = 998, 999
    QTable({"id1": id1, "id2": id2}).write(tmp_path / "pairs.ecsv", format="ascii.ecsv")
    cfg["catalogs"] = cats
    cfg["pairing"] = {"method": "manual", "file": str(tmp_path / "pairs.ecsv")}
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out),
                 "--quiet"]) == 0
    result = QTable.read(out / "pairs.ecsv", format="ascii.ecsv")
    bad = np.arange(len(result)) >= len(result) - 2
    assert not result["tested"][bad].any() and not result["anomalous"][bad].any()
    on_sky, off_image = result[-1], result[-2]
    assert str(on_sky["doubt"]).startswith("no point source on L2: its PSF flux is below 3 "
                                           "sigma")
    assert "outside the image" in str(off_image["doubt"])
    assert np.isfinite(np.asarray(result["mu_size"])[~bad]).all()
    assert result["tested"][~bad].sum() >= 6
    assert np.array_equal(np.asarray(result["anomalous"])[~bad],
                          np.asarray(previous["anomalous"])[~bad])
    report = (out / "report.txt").read_text()
    assert "could not be tested" in report and "no point source on L2" in report
    assert "median nan" not in report


def test_a_pair_without_position_errors_is_untested_and_the_rest_analysed(
        demo_dir, tmp_path, capsys, monkeypatch):
    """A candidate whose PSF fit gives no position error (empty sky) does not stop the
    run with "sigma_pos must be finite": it is untested, with the reason."""
    import astropy.units as u

    import lensdual.photometry as photometry

    real = photometry.measure_pairs

    def blank_pair(*args, **kwargs):
        table = real(*args, **kwargs)
        table["pos_err2"][4] = np.nan * u.arcsec
        return table

    monkeypatch.setattr(photometry, "measure_pairs", blank_pair)
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", absolute_config(demo_dir))),
                 "--outdir", str(out), "--quiet"]) == 0
    pairs = QTable.read(out / "pairs.ecsv", format="ascii.ecsv")
    assert not pairs["tested"][4]
    assert "no position error from the PSF fit on arc L2" in pairs["doubt"][4]
    others = np.arange(len(pairs)) != 4
    assert np.isfinite(np.asarray(pairs["mu_size"])[others]).all()
    assert "no position error" in (out / "report.txt").read_text()


def test_a_saturated_source_makes_its_pair_doubtful_not_anomalous(demo_dir, tmp_path):
    """A clean pair's L2 source clipped at 40 % of its peak in both bands (a saturated,
    flat-topped core) is not reported as a sub-halo: its L2 fluxes are unusable
    (FLAT_TOP), the pair is untested with the reason, and every other pair keeps its
    measurement and its verdict."""
    from lensdual.photometry import PhotometryFlag

    before = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    clean = np.flatnonzero(np.asarray(before["tested"]) & ~np.asarray(before["anomalous"]))
    k = int(clean[np.argmax(np.asarray(before["flux2_F150W"])[clean])])  # the brightest
    cat = QTable.read(demo_dir / "catalog_L2.ecsv", format="ascii.ecsv")
    row = int(np.flatnonzero(np.asarray(cat["id"]) == before["id2"][k])[0])
    x, y = int(round(float(cat["x_pix"][row]))), int(round(float(cat["y_pix"][row])))
    cfg = absolute_config(demo_dir)
    for band, spec in cfg["arcs"]["L2"].items():

        def clip(hdul):
            stamp = hdul[0].data[y - 4:y + 5, x - 4:x + 5]
            np.minimum(stamp, 0.4 * stamp.max(), out=stamp)

        spec["image"] = str(copy_fits(spec["image"], tmp_path / f"L2_{band}.fits", clip))
    out = tmp_path / "out"
    assert main(["run", str(write(tmp_path / "c.toml", cfg)), "--outdir", str(out),
                 "--quiet"]) == 0
    after = QTable.read(out / "pairs.ecsv", format="ascii.ecsv")
    assert not after["anomalous"][k] and not after["tested"][k]
    assert "flat-topped core" in after["doubt"][k]
    flat = int(PhotometryFlag.FLAT_TOP)
    assert after["photometry_flags"][k] & flat
    others = np.arange(len(after)) != k
    assert not np.any(np.asarray(after["photometry_flags"])[others] & flat)
    assert np.array_equal(np.asarray(after["anomalous"])[others],
                          np.asarray(before["anomalous"])[others])
    assert np.array_equal(np.asarray(after["tested"])[others],
                          np.asarray(before["tested"])[others])


# ------------------------------------------------------------------------------- outputs


def test_unwritable_output_fails_before_the_analysis(demo_dir, tmp_path, capsys, monkeypatch):
    import lensdual.cli as cli

    def never(*args, **kwargs):
        raise AssertionError("the analysis ran")

    monkeypatch.setattr(cli, "analyse", never)
    blocker = tmp_path / "file"
    blocker.write_text("")
    cfg = absolute_config(demo_dir)
    path = write(tmp_path / "c.toml", cfg)
    assert main(["run", str(path), "--outdir", str(blocker / "out"), "--quiet"]) == 1
    assert "cannot write the output directory" in capsys.readouterr().err
    # an existing file as the output directory is a configuration problem (exit 2)
    assert main(["run", str(path), "--outdir", str(blocker), "--quiet"]) == 2
    assert "exists and is not a directory" in capsys.readouterr().err


def test_progress_bars_only_on_a_terminal(demo_dir, tmp_path, capsys, monkeypatch):
    cfg = absolute_config(demo_dir)
    path = write(tmp_path / "c.toml", cfg)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: False, raising=False)
    assert main(["run", str(path), "--outdir", str(tmp_path / "a")]) == 0
    assert "lensdual run:" not in capsys.readouterr().err
    assert main(["run", str(path), "--outdir", str(tmp_path / "b"), "--progress"]) == 0
    assert "lensdual run:" in capsys.readouterr().err


def test_ds9_regions(demo_dir):
    from regions import Regions

    pairs = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    reg = Regions.read(str(demo_dir / "pairs.reg"), format="ds9")
    assert len(reg) == 3 * len(pairs)
    texts = [str(r.meta.get("text")) for r in reg if "text" in r.meta]
    assert texts[:2] == [str(pairs["pair_id"][0])] * 2
    np.testing.assert_allclose(reg[0].center.ra.deg, pairs["sky1"][0].ra.deg, atol=1e-7)
    np.testing.assert_allclose(reg[1].center.dec.deg, pairs["sky2"][0].dec.deg, atol=1e-7)
    cat = QTable.read(demo_dir / "catalog_L1.ecsv", format="ascii.ecsv")
    assert len(Regions.read(str(demo_dir / "sources_L1.reg"), format="ds9")) == len(cat)


def test_constellation_figure_circles_every_pair_on_both_arcs(demo_dir):
    import matplotlib

    matplotlib.use("agg")
    from astropy.nddata import CCDData
    from astropy.visualization.wcsaxes import WCSAxes
    from matplotlib.patches import Circle

    from lensdual.visualization import plot_arc_images

    assert (demo_dir / "constellation.png").stat().st_size > 20000
    result = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    images = {arc: CCDData.read(demo_dir / "images" / f"{arc}_F150W.fits", hdu=0)
              for arc in ("L1", "L2")}
    result["anomalous"][:] = False
    result["anomalous"][1] = True
    fig = plot_arc_images(images, result)
    axes = fig.axes
    assert len(axes) == 3 and all(isinstance(a, WCSAxes) for a in axes[:2])
    for ax in axes[:2]:
        circles = [p for p in ax.patches if isinstance(p, Circle)]
        assert len(circles) == len(result)
        colours = [matplotlib.colors.to_hex(c.get_edgecolor()) for c in circles]
        assert colours[1] == "#ff0000" and colours.count("#ff0000") == 1
        # north up: the Dec axis is the vertical one
        assert ax.coords[1].get_axislabel() == "Dec"


def _demo_analysis(demo_dir):
    """The demo's analysis as the figures read it (result, pairing, catalogues) and its
    F150W images."""
    from types import SimpleNamespace

    from astropy.nddata import CCDData

    result = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    cats = {arc: QTable.read(demo_dir / f"catalog_{arc}.ecsv", format="ascii.ecsv")
            for arc in ("L1", "L2")}
    images = {arc: {"F150W": CCDData.read(demo_dir / "images" / f"{arc}_F150W.fits", hdu=0)}
              for arc in ("L1", "L2")}
    return SimpleNamespace(result=result, pairs=result, catalogs=cats), images


def test_constellation_figure_is_readable(demo_dir):
    """constellation.png: its title clears the panel titles ('arc L2' was drawn over),
    the pair numbers and circles have a dark outline (green on grey was hard to read),
    and it holds the two arcs only: the mapped view is pairing_map.png's one panel, not
    repeated as a third."""
    from types import SimpleNamespace

    import matplotlib

    matplotlib.use("agg")
    from matplotlib.colors import to_rgb
    from matplotlib.image import AxesImage
    from matplotlib.patches import Circle

    from lensdual.visualization._run import constellation_figure, pairing_map_figure

    def luminance(colour):  # WCAG relative luminance
        c = np.asarray(to_rgb(colour))
        c = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
        return float(np.dot(c, [0.2126, 0.7152, 0.0722]))

    def contrast(a, b):  # WCAG contrast ratio, at least 3 for graphics
        la, lb = sorted((luminance(a), luminance(b)))
        return (lb + 0.05) / (la + 0.05)

    analysis, images = _demo_analysis(demo_dir)
    # the whole constellation, and its eastern column on L2: a tall L2 panel that
    # reaches the top of the figure (the case where the titles collided)
    px, _ = images["L2"]["F150W"].wcs.world_to_pixel(analysis.result["sky2"])
    for result in (analysis.result, analysis.result[px > np.median(px) + 5]):
        fig = constellation_figure(SimpleNamespace(result=result), images, "demo")
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        title = fig._suptitle.get_window_extent(renderer)
        assert fig.bbox.contains(title.x0, title.y0) and fig.bbox.contains(title.x1, title.y1)
        with_images = [ax for ax in fig.axes if any(isinstance(a, AxesImage)
                                                    for a in ax.get_children())]
        assert [ax.get_title() for ax in fig.axes] == ["arc L1", "arc L2"] and \
            len(with_images) == 2
        for ax in fig.axes:
            assert not title.overlaps(ax.title.get_window_extent(renderer)), ax.get_title()
            assert not title.overlaps(ax.get_tightbbox(renderer)), ax.get_title()
            labels = [t for t in ax.texts if t.get_text().isdigit()]
            circles = [p for p in ax.patches if isinstance(p, Circle)]
            assert len(labels) == len(circles) == len(result)
            for artist in labels + circles:
                colour = artist.get_color() if artist in labels else artist.get_edgecolor()
                strokes = [e for e in artist.get_path_effects()
                           if getattr(e, "_gc", {}).get("foreground") is not None]
                assert strokes, "no outline"
                assert contrast(colour, strokes[0]._gc["foreground"]) >= 3
    fig = pairing_map_figure(analysis, "demo")
    assert len(fig.axes) == 1 and "pairing" in fig.axes[0].get_title()
    matplotlib.pyplot.close("all")


def test_figures_and_regions_skip_unmeasured_pairs(demo_dir):
    import matplotlib

    matplotlib.use("agg")
    from astropy.coordinates import SkyCoord
    from astropy.nddata import CCDData
    from matplotlib.patches import Circle

    from lensdual.visualization import ds9_regions, plot_arc_images

    result = QTable.read(demo_dir / "pairs.ecsv", format="ascii.ecsv")
    ra, dec = result["sky1"].ra.deg.copy(), result["sky1"].dec.deg.copy()
    ra[0] = dec[0] = np.nan  # pair 1 not measured on L1
    result["sky1"] = SkyCoord(ra, dec, unit="deg")
    images = {arc: CCDData.read(demo_dir / "images" / f"{arc}_F150W.fits", hdu=0)
              for arc in ("L1", "L2")}
    fig = plot_arc_images(images, result, mapped=False)
    assert len([p for p in fig.axes[0].patches if isinstance(p, Circle)]) == len(result) - 1
    assert len(ds9_regions(result)["pairs"]) == 3 * (len(result) - 1)
