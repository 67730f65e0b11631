"""Tests of lensdual.config: the TOML configuration of ``lensdual run``."""

import copy
import dataclasses
import pickle
import re
import tomllib

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.io import fits
from astropy.nddata import CCDData, Cutout2D, StdDevUncertainty
from astropy.table import QTable, Table
from astropy.wcs import WCS

from lensdual.config import (
    FIELDS,
    ArcSpec,
    BandSpec,
    ConfigError,
    ImageSpec,
    KnotSpec,
    ParametricSpec,
    RunConfig,
    band_psfs,
    format_config,
    load_config,
    load_images,
    write_config,
)
from lensdual.config import _schema as schema

SHAPE = (40, 40)
PIXEL = 0.04  # arcsec
CENTER = (110.8, -73.45)  # deg


def make_wcs(crval=CENTER):
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.cunit = ["deg", "deg"]
    w.wcs.cdelt = [-PIXEL / 3600, PIXEL / 3600]
    w.wcs.crpix = [20.5, 20.5]
    w.wcs.crval = list(crval)
    return w


def sky_string(x, y, wcs=None):
    """'RA Dec' in degrees of pixel (x, y)."""
    c = (wcs or make_wcs()).pixel_to_world(x, y)
    return f"{c.ra.deg:.10f} {c.dec.deg:.10f}"


def write_ecsv(table, path):
    table.write(path, format="ascii.ecsv", overwrite=True)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """Images, maps, PSFs, catalogues and pairs files, good and bad."""
    d = tmp_path_factory.mktemp("data")
    rng = np.random.default_rng(1)
    w = make_wcs()
    for arc in ("L1", "L2"):
        for band in ("F150W", "F200W"):
            img = rng.normal(10.0, 1.0, SHAPE)
            img[14, 11] = np.nan
            # L2 F200W has no BUNIT: its unit comes from the configuration
            unit = "" if (arc, band) == ("L2", "F200W") else "nJy"
            CCDData(img, unit=unit, wcs=w).write(d / f"{arc}_{band}.fits")
    fits.writeto(d / "L1_F150W_err.fits", np.full(SHAPE, 0.5) + rng.uniform(0, 0.1, SHAPE))
    wht = np.full(SHAPE, 4.0)
    wht[10:12, 5:8] = 0.0
    wht[12, 9] = -1.0
    fits.writeto(d / "L1_F200W_wht.fits", wht)
    yy, xx = np.mgrid[-7:8, -7:8]
    fits.writeto(d / "psf.fits", 3.0 * np.exp(-(xx**2 + yy**2) / 4.0))
    # bad inputs
    fits.writeto(d / "psf_even.fits", np.ones((14, 14)))
    fits.writeto(d / "err_small.fits", np.ones((30, 30)))
    fits.writeto(d / "nowcs.fits", np.ones(SHAPE))
    hdr = w.to_header()
    hdr["BUNIT"] = "ELECTRONS/S"
    fits.writeto(d / "badunit.fits", np.ones(SHAPE), hdr)
    (d / "notfits.fits").write_text("hello\n")
    # a JWST-like multi-extension file: empty primary, SCI, ERR and a table
    sci = fits.ImageHDU(np.full(SHAPE, 2.0), w.to_header(), name="SCI")
    sci.header["BUNIT"] = "MJy/sr"
    table = fits.BinTableHDU.from_columns([fits.Column(name="a", format="E", array=[1.0])],
                                          name="TAB")
    fits.HDUList([fits.PrimaryHDU(), sci, fits.ImageHDU(np.full(SHAPE, 0.1), name="ERR"),
                  table]).writeto(d / "mef.fits")
    (d / "best.par").write_text("runmode\n  reference 3 110.8 -73.45\n  end\n")
    (d / "a_directory").mkdir()
    (d / "outdir_is_a_file").write_text("")
    # catalogues: L1 with ra/dec, L2 with a SkyCoord column
    sky = w.pixel_to_world([5.0, 20.0, 30.0, 12.0], [8.0, 25.0, 10.0, 33.0])
    write_ecsv(Table({"id": [1, 2, 3, 4], "ra": sky.ra.deg * u.deg, "dec": sky.dec.deg * u.deg}),
               d / "L1.ecsv")
    write_ecsv(QTable({"id": [11, 12, 13, 14], "sky": sky}), d / "L2.ecsv")
    write_ecsv(Table({"name": [1, 2], "ra": [1.0, 2.0], "dec": [1.0, 2.0]}), d / "noid.ecsv")
    write_ecsv(Table({"id": [1, 2, 3], "x": [1.0, 2.0, 3.0]}), d / "nosky.ecsv")
    write_ecsv(Table({"id1": [1, 2, 3], "id2": [11, 12, 13]}), d / "pairs.ecsv")
    write_ecsv(Table({"pair_id": [1, 2, 1], "id1": [1, 2, 3], "id2": [11, 12, 13]}),
               d / "pairs_dup_pair_id.ecsv")
    write_ecsv(Table({"id1": [1, 2, 3]}), d / "pairs_noid2.ecsv")
    write_ecsv(Table({"id1": [1.0, 2.0, 3.0], "id2": [11, 12, 13]}), d / "pairs_float.ecsv")
    write_ecsv(Table({"id1": [1, 2, 99], "id2": [11, 12, 13]}), d / "pairs_unknown.ecsv")
    return d


def full_config():
    """A valid configuration using every table (paths relative to the data directory)."""
    return {
        "output": {"outdir": "results"},
        "analysis": {"estimator": "quad", "sigma_pos": "10 mas", "n_bootstrap": 200,
                     "snr_threshold": 2, "seed": 7},
        "bands": {"F150W": {"psf": "psf.fits"}, "F200W": {"psf_fwhm": "0.066 arcsec"}},
        "arcs": {
            "L1": {
                "F150W": {"image": "L1_F150W.fits", "error": "L1_F150W_err.fits"},
                "F200W": {"image": "L1_F200W.fits", "weight": "L1_F200W_wht.fits"},
                "cutout": {"center": sky_string(12.0, 15.0), "size": ["0.6 arcsec", "0.8 arcsec"]},
            },
            "L2": {
                "F150W": {"image": "L2_F150W.fits", "hdu": 0},
                "F200W": {"image": "L2_F200W.fits", "unit": "uJy"},
                "cutout": {
                    "center": make_wcs().pixel_to_world(2, 3).to_string(
                        "hmsdms", sep=":", precision=6),
                    "size": "1 arcsec",
                },
            },
        },
        "catalogs": {"L1": "L1.ecsv", "L2": "L2.ecsv"},
        "pairing": {"method": "manual", "file": "pairs.ecsv"},
        "parametric": {"lenstool": "best.par", "fit": True, "model": ["SIE", "SHEAR"],
                       "z_lens": 0.39, "z_source": 2.2},
    }


def minimal_config():
    return {
        "bands": {"F150W": {}},
        "arcs": {"L1": {"F150W": {"image": "L1_F150W.fits"}},
                 "L2": {"F150W": {"image": "L2_F150W.fits"}}},
    }


def write(data_dir, name, cfg):
    path = data_dir / f"{name}.toml"
    write_config(path, cfg)
    return path


# ---------------------------------------------------------------------------
# valid configurations
# ---------------------------------------------------------------------------


def test_full_config(data_dir):
    path = write(data_dir, "full", full_config())
    cfg = load_config(path)
    d = data_dir.resolve()
    assert isinstance(cfg, RunConfig)
    assert cfg.path == path.resolve()
    assert cfg.outdir == d / "results"
    assert cfg.estimator == "quad"
    assert cfg.sigma_pos == 10 * u.mas
    assert (cfg.n_bootstrap, cfg.seed) == (200, 7)
    assert cfg.snr_threshold == 2.0 and isinstance(cfg.snr_threshold, float)
    assert list(cfg.bands) == ["F150W", "F200W"]
    assert cfg.bands["F150W"] == BandSpec("F150W", psf=d / "psf.fits")
    assert cfg.bands["F200W"].psf is None
    assert cfg.bands["F200W"].psf_fwhm == 0.066 * u.arcsec
    assert list(cfg.arcs) == ["L1", "L2"]
    l1 = cfg.arcs["L1"]
    assert isinstance(l1, ArcSpec) and list(l1.images) == ["F150W", "F200W"]
    assert l1.images["F150W"] == ImageSpec(image=d / "L1_F150W.fits",
                                           error=d / "L1_F150W_err.fits")
    assert l1.images["F200W"].weight == d / "L1_F200W_wht.fits"
    assert l1.cutout_center.separation(make_wcs().pixel_to_world(12, 15)) < 1e-6 * u.arcsec
    assert u.allclose(l1.cutout_size, [0.6, 0.8] * u.arcsec)
    l2 = cfg.arcs["L2"]
    assert l2.images["F150W"].hdu == 0
    assert l2.images["F200W"].unit == u.uJy
    assert l2.cutout_center.separation(make_wcs().pixel_to_world(2, 3)) < 1e-3 * u.arcsec
    assert cfg.catalogs == {"L1": d / "L1.ecsv", "L2": d / "L2.ecsv"}
    assert (cfg.pairing_method, cfg.pairs_file) == ("manual", d / "pairs.ecsv")
    assert cfg.parametric == ParametricSpec(lenstool=d / "best.par", fit=True,
                                            model=("SIE", "SHEAR"), z_lens=0.39, z_source=2.2)


def test_defaults_and_outdir(data_dir, tmp_path, monkeypatch):
    path = write(data_dir, "minimal", minimal_config())
    cfg = load_config(path)
    assert cfg.outdir == data_dir.resolve() / "lensdual-output"
    assert (cfg.estimator, cfg.sigma_pos, cfg.n_bootstrap) == ("adaptive", "auto", 1000)
    assert (cfg.snr_threshold, cfg.seed, cfg.test) == (3.0, 0, "auto")
    assert cfg.snr_definition == "auto"
    assert cfg.source_model == "point"
    assert load_config(write(data_dir, "resolved", minimal_config() | {
        "analysis": {"source_model": "resolved"}})).source_model == "resolved"
    assert cfg.catalogs is None and cfg.parametric is None
    assert (cfg.pairing_method, cfg.pairs_file) == ("auto", None)
    assert cfg.bands["F150W"] == BandSpec("F150W")
    assert cfg.arcs["L1"].cutout_center is None and cfg.arcs["L1"].cutout_size is None
    # an outdir argument is relative to the current directory
    monkeypatch.chdir(tmp_path)
    assert load_config(path, outdir="elsewhere").outdir == tmp_path.resolve() / "elsewhere"
    # a relative config path is relative to the current directory too
    monkeypatch.chdir(data_dir)
    assert load_config("minimal.toml").path == path.resolve()
    # the default model of [parametric]
    cfg = minimal_config() | {"parametric": {}}
    par = load_config(write(data_dir, "par_default", cfg)).parametric
    assert par == ParametricSpec(lenstool=None, fit=False, model=("NFW_ELLIPSE_CSE", "SHEAR"))


def test_load_images(data_dir):
    cfg = load_config(write(data_dir, "images", full_config()))
    images = load_images(cfg)
    assert set(images) == {"L1", "L2"} and set(images["L1"]) == {"F150W", "F200W"}
    w = make_wcs()
    raw = fits.getdata(data_dir / "L1_F150W.fits")
    err = fits.getdata(data_dir / "L1_F150W_err.fits")

    # L1 F150W: cutout, error map, NaN mask and PSF
    ccd = images["L1"]["F150W"]
    ref = Cutout2D(raw, cfg.arcs["L1"].cutout_center, cfg.arcs["L1"].cutout_size, wcs=w,
                   mode="trim")
    assert isinstance(ccd, CCDData) and ccd.shape == ref.shape == (15, 20)
    np.testing.assert_array_equal(ccd.data, ref.data)
    np.testing.assert_allclose(ccd.wcs.wcs.crpix, ref.wcs.wcs.crpix)
    y0, x0 = (s.start for s in ref.slices_original)
    assert ccd.wcs.pixel_to_world(0, 0).separation(w.pixel_to_world(x0, y0)) < 1e-9 * u.arcsec
    assert ccd.unit == u.nJy
    assert isinstance(ccd.uncertainty, StdDevUncertainty)
    np.testing.assert_array_equal(ccd.uncertainty.array, err[ref.slices_original])
    assert ccd.mask.sum() == 1 and ccd.mask[14 - y0, 11 - x0]
    assert ccd.psf.shape == (15, 15) and ccd.psf.sum() == pytest.approx(1.0)
    assert np.unravel_index(np.argmax(ccd.psf), ccd.psf.shape) == (7, 7)
    assert "CRPIX1" not in ccd.meta and "BUNIT" not in ccd.meta

    # L1 F200W: weight map -> 1 / sqrt(w), NaN and masked where w <= 0
    ccd = images["L1"]["F200W"]
    wht = fits.getdata(data_dir / "L1_F200W_wht.fits")[ref.slices_original]
    good = wht > 0
    assert (~good).any() and good.any()
    np.testing.assert_allclose(ccd.uncertainty.array[good], 1 / np.sqrt(wht[good]))
    assert np.isnan(ccd.uncertainty.array[~good]).all()
    assert ccd.mask[~good].all()
    assert ccd.psf is None

    # L2: a cutout trimmed at the image corner, unit from BUNIT or the config
    ccd = images["L2"]["F150W"]
    ref = Cutout2D(fits.getdata(data_dir / "L2_F150W.fits"), cfg.arcs["L2"].cutout_center,
                   1 * u.arcsec, wcs=w, mode="trim")
    assert ccd.shape == ref.shape and ccd.shape[0] < 25 and ccd.shape[1] < 25
    np.testing.assert_allclose(ccd.wcs.wcs.crpix, ref.wcs.wcs.crpix)
    assert ccd.uncertainty is None and ccd.mask.sum() == 1 and ccd.mask[14, 11]
    assert images["L2"]["F200W"].unit == u.uJy
    assert images["L2"]["F200W"].wcs.has_celestial


def test_band_psfs(data_dir):
    psfs = band_psfs(load_config(write(data_dir, "psfs", full_config())))
    assert psfs["F200W"] == 0.066 * u.arcsec
    assert psfs["F150W"].shape == (15, 15) and psfs["F150W"].sum() == pytest.approx(1.0)
    cfg = minimal_config()
    assert band_psfs(load_config(write(data_dir, "nopsf", cfg))) == {"F150W": None}


def test_error_extension_of_image_file(data_dir):
    # error_hdu without error: an extension of the image's file; hdu by default: the
    # first HDU with 2-D data; a sexagesimal cutout centre with unit letters
    cfg = minimal_config()
    cfg["arcs"]["L1"]["F150W"] = {"image": "mef.fits", "error_hdu": "ERR"}
    # both arcs of a band in convertible units (flux ratios): L2 in MJy/sr too
    cfg["arcs"]["L2"]["F150W"] = {"image": "mef.fits"}
    c = make_wcs().pixel_to_world(20, 20).to_string("hmsdms", precision=4)
    cfg["arcs"]["L1"]["cutout"] = {"center": c, "size": "0.4 arcsec"}
    config = load_config(write(data_dir, "mef", cfg))
    spec = config.arcs["L1"].images["F150W"]
    assert spec.image == spec.error == (data_dir / "mef.fits").resolve()
    assert (spec.hdu, spec.error_hdu) == (None, "ERR")
    ccd = load_images(config)["L1"]["F150W"]
    assert ccd.shape == (10, 10) and ccd.unit == u.MJy / u.sr
    np.testing.assert_array_equal(ccd.data, 2.0)
    np.testing.assert_array_equal(ccd.uncertainty.array, 0.1)


def test_cutout_without_overlap_in_load_images(data_dir):
    cfg = load_config(write(data_dir, "overlap", full_config()))
    far = SkyCoord(CENTER[0] + 1, CENTER[1], unit="deg")
    arcs = dict(cfg.arcs, L2=ArcSpec("L2", cfg.arcs["L2"].images, far, 1 * u.arcsec))
    moved = RunConfig(**{**cfg.__dict__, "arcs": arcs})
    with pytest.raises(ConfigError, match="does not overlap"):
        load_images(moved)


# ---------------------------------------------------------------------------
# invalid configurations
# ---------------------------------------------------------------------------


def _set(*keys_and_value):
    """A mutation setting cfg[k1][k2]... = value (value None: delete the key)."""
    *keys, value = keys_and_value

    def mutate(cfg):
        target = cfg
        for k in keys[:-1]:
            target = target.setdefault(k, {})
        if value is None:
            del target[keys[-1]]
        else:
            target[keys[-1]] = value

    return mutate


def _both(*mutations):
    """Several mutations in a row."""

    def mutate(cfg):
        for m in mutations:
            m(cfg)

    return mutate


BAD = [
    ("estimator", _set("analysis", "estimator", "quadd"),
     "[analysis] estimator: 'quadd' is not one of '2v', 'quad', 'quad2', 'adaptive' "
     "(did you mean 'quad'?)"),
    ("unknown-key", _set("analysis", "n_boostrap", 100),
     "[analysis] n_boostrap: unknown key (did you mean 'n_bootstrap'?)"),
    ("unknown-table", _set("anlysis", "seed", 1),
     "[anlysis]: unknown table (did you mean [analysis]?)"),
    ("misplaced-key", _set("estimator", "quad"),
     "estimator: unknown top-level key (it belongs in [analysis])"),
    ("image-unknown-key", _set("arcs", "L1", "F150W", "eror", "x.fits"),
     "[arcs.L1.F150W] eror: unknown key (did you mean 'error'?)"),
    ("int-as-string", _set("analysis", "n_bootstrap", "100"),
     "[analysis] n_bootstrap: expected an integer, got a string ('100')"),
    ("bool-as-int", _set("analysis", "seed", True),
     "[analysis] seed: expected an integer, got a boolean (true)"),
    ("n-bootstrap-small", _set("analysis", "n_bootstrap", 5),
     "[analysis] n_bootstrap: must be >= 10, got 5"),
    ("negative-seed", _set("analysis", "seed", -1), "[analysis] seed: must be >= 0, got -1"),
    ("snr-zero", _set("analysis", "snr_threshold", 0),
     "[analysis] snr_threshold: must be > 0, got 0"),
    ("angle-no-unit", _set("analysis", "sigma_pos", "0.01"),
     "[analysis] sigma_pos: expected \"auto\" or an angle; '0.01' has no unit: give an angle "
     "with its unit, like \"0.01 arcsec\""),
    ("angle-kg", _set("analysis", "sigma_pos", "0.01 kg"),
     "'0.01 kg' is not an angle (its unit kg is a mass)"),
    ("angle-garbage", _set("analysis", "sigma_pos", "fast"), "could not read 'fast' as an angle"),
    ("sigma-number", _set("analysis", "sigma_pos", 0.01),
     "[analysis] sigma_pos: expected \"auto\" or an angle string"),
    ("sigma-zero", _set("analysis", "sigma_pos", "0 mas"),
     "[analysis] sigma_pos: must be > 0, got '0 mas'"),
    ("fwhm-negative", _set("bands", "F200W", "psf_fwhm", "-0.1 arcsec"),
     "[bands.F200W] psf_fwhm: must be > 0"),
    ("psf-and-fwhm", _set("bands", "F150W", "psf_fwhm", "0.05 arcsec"),
     "[bands.F150W] psf_fwhm: give either psf (a PSF image) or psf_fwhm"),
    ("psf-even", _set("bands", "F150W", "psf", "psf_even.fits"),
     "must have an odd shape of at least 5x5 pixels"),
    ("band-cutout", _set("bands", "cutout", {}), "[bands.cutout]: 'cutout' is reserved"),
    ("no-bands", _set("bands", {}), "[bands]: no bands declared"),
    ("missing-arc", _set("arcs", "L2", None),
     "[arcs.L2]: missing (arcs L1 and L2 are both required)"),
    ("unknown-arc", _set("arcs", "L3", {}), "[arcs.L3]: unknown arc"),
    ("band-missing-on-arc", _set("arcs", "L2", "F200W", None),
     "[arcs.L2.F200W]: missing: band 'F200W' is declared in [bands]"),
    ("undeclared-band", _set("arcs", "L1", "F150X", {"image": "L1_F150W.fits"}),
     "[arcs.L1.F150X]: 'F150X' is not a band declared in [bands] (did you mean 'F150W'?)"),
    ("error-and-weight", _set("arcs", "L1", "F150W", "weight", "L1_F200W_wht.fits"),
     "[arcs.L1.F150W] weight: give either error"),
    ("image-missing", _set("arcs", "L1", "F150W", "image", "sub/nothing.fits"),
     "[arcs.L1.F150W] image: file not found: {d}/sub/nothing.fits"),
    ("image-key-missing", _set("arcs", "L1", "F150W", "image", None),
     "[arcs.L1.F150W] image: missing"),
    ("image-directory", _set("arcs", "L1", "F150W", "image", "a_directory"),
     "[arcs.L1.F150W] image: not a file: {d}/a_directory"),
    ("not-fits", _set("arcs", "L1", "F200W", "image", "notfits.fits"),
     "[arcs.L1.F200W] image: {d}/notfits.fits is not a readable FITS file"),
    ("hdu-index", _set("arcs", "L1", "F150W", "hdu", 5),
     "[arcs.L1.F150W] hdu: HDU 5 does not exist in {d}/L1_F150W.fits (1 HDU: 0 'PRIMARY')"),
    ("hdu-name", _set("arcs", "L1", "F150W", "hdu", "SCI"),
     "[arcs.L1.F150W] hdu: HDU 'SCI' does not exist"),
    ("hdu-table", _set("arcs", "L1", "F150W", {"image": "mef.fits", "hdu": "TAB"}),
     "[arcs.L1.F150W] hdu: HDU 'TAB' of {d}/mef.fits has no 2-D image data (it has a table)"),
    ("hdu-empty", _set("arcs", "L1", "F150W", {"image": "mef.fits", "hdu": 0}),
     "[arcs.L1.F150W] hdu: HDU 0 of {d}/mef.fits has no 2-D image data (it has no data)"),
    ("hdu-type", _set("arcs", "L1", "F150W", "hdu", 1.5),
     "[arcs.L1.F150W] hdu: expected an HDU index (integer >= 0) or EXTNAME"),
    ("error-shape", _set("arcs", "L1", "F150W", "error", "err_small.fits"),
     "[arcs.L1.F150W] error: the error map in {d}/err_small.fits has shape (30, 30), "
     "the image (40, 40)"),
    ("no-wcs", _set("arcs", "L2", "F150W", "image", "nowcs.fits"),
     "[arcs.L2.F150W] image: the header of HDU 0 of {d}/nowcs.fits has no celestial WCS"),
    ("bad-unit", _set("arcs", "L2", "F200W", "unit", "notaunit"),
     "[arcs.L2.F200W] unit: 'notaunit' is not a valid astropy unit"),
    ("bad-bunit", _set("arcs", "L2", "F150W", "image", "badunit.fits"),
     "[arcs.L2.F150W] image: the BUNIT 'ELECTRONS/S' of {d}/badunit.fits is not a valid "
     "astropy unit"),
    ("cutout-center", _set("arcs", "L1", "cutout", "center", "nowhere"),
     "[arcs.L1.cutout] center: could not read 'nowhere' as a sky position"),
    ("cutout-size", _set("arcs", "L1", "cutout", "size", "6"),
     "[arcs.L1.cutout] size: '6' has no unit"),
    ("cutout-size-list", _set("arcs", "L1", "cutout", "size", ["1 arcsec", "2 kg"]),
     "[arcs.L1.cutout] size[1]: '2 kg' is not an angle"),
    ("cutout-no-overlap", _set("arcs", "L1", "cutout", "center", "111.8 -73.45"),
     "[arcs.L1.cutout] center: the cutout does not overlap the images of bands F150W, F200W "
     "({d}/L1_F150W.fits, {d}/L1_F200W.fits)"),
    ("catalog-one", _set("catalogs", "L2", None),
     "[catalogs] L2: missing (give the catalogues of both arcs"),
    ("catalog-no-id", _set("catalogs", "L1", "noid.ecsv"),
     "[catalogs] L1: {d}/noid.ecsv has no 'id' column"),
    ("catalog-no-sky", _set("catalogs", "L1", "nosky.ecsv"),
     "needs a SkyCoord column 'sky' or columns 'ra' and 'dec'"),
    ("catalog-unreadable", _set("catalogs", "L1", "best.par"),
     "[catalogs] L1: could not read {d}/best.par as an ECSV table"),
    ("pairing-method", _set("pairing", "method", "manul"),
     "[pairing] method: 'manul' is not one of 'auto', 'manual' (did you mean 'manual'?)"),
    ("manual-no-file", _set("pairing", "file", None),
     '[pairing] file: required when method = "manual"'),
    ("auto-with-file", _set("pairing", "method", "auto"),
     '[pairing] file: a pairs file is only used with method = "manual"'),
    ("pairs-no-id2", _set("pairing", "file", "pairs_noid2.ecsv"), "lacks column(s) id2"),
    ("pairs-float", _set("pairing", "file", "pairs_float.ecsv"),
     "column 'id1' of {d}/pairs_float.ecsv must hold integers"),
    ("pairs-unknown-id", _set("pairing", "file", "pairs_unknown.ecsv"),
     "id1 value(s) [99] of {d}/pairs_unknown.ecsv are not in the [catalogs] L1 catalogue"),
    ("pairs-repeated-pair-id", _set("pairing", "file", "pairs_dup_pair_id.ecsv"),
     "pair_id value(s) [1] of {d}/pairs_dup_pair_id.ecsv occur more than once (rows [0, 2])"),
    ("fit-not-bool", _set("parametric", "fit", "yes"),
     "[parametric] fit: expected a boolean (true or false), got a string ('yes')"),
    ("model-string", _set("parametric", "model", "SIE"),
     "[parametric] model: expected a list of lenstronomy profile names"),
    ("model-unknown", _set("parametric", "model", ["NFW_ELIPSE_CSE"]),
     "unsupported profile 'NFW_ELIPSE_CSE' (did you mean 'NFW_ELLIPSE_CSE'?)"),
    ("z-lens-missing", _set("parametric", "z_lens", None),
     "[parametric] z_lens: required when fit = true"),
    ("z-order", _set("parametric", "z_source", 0.3),
     "[parametric] z_source: must be larger than z_lens (0.39), got 0.3"),
    ("lenstool-missing", _set("parametric", "lenstool", "nope.par"),
     "[parametric] lenstool: file not found: {d}/nope.par"),
    ("outdir-file", _set("output", "outdir", "outdir_is_a_file"),
     "[output] outdir: {d}/outdir_is_a_file exists and is not a directory"),
    ("max-magnification-one", _set("pairing", "max_magnification", 1.0),
     "[pairing] max_magnification: must be > 1, got 1"),
    ("test-unknown", _set("analysis", "test", "bayes"),
     "[analysis] test: 'bayes' is not one of 'auto', 'geometric', 'joint'"),
    ("source-model-unknown", _set("analysis", "source_model", "extended"),
     "[analysis] source_model: 'extended' is not one of 'point', 'resolved'"),
    ("joint-needs-adaptive", _both(_set("analysis", "test", "joint"),
                                   _set("analysis", "estimator", "quad")),
     '[analysis] test: "joint" needs estimator = "adaptive", got estimator = "quad"'),
    ("snr-definition-unknown", _set("analysis", "snr_definition", "profile"),
     "[analysis] snr_definition: 'profile' is not one of 'auto', 'log', 'conservative'"),
    ("conservative-needs-adaptive", _both(_set("analysis", "snr_definition", "conservative"),
                                          _set("analysis", "estimator", "2v")),
     '[analysis] snr_definition: "conservative" needs estimator = "adaptive", got '
     'estimator = "2v"'),
]


@pytest.mark.parametrize(("mutate", "fragment"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_config(data_dir, request, mutate, fragment):
    cfg = full_config()
    mutate(cfg)
    path = write(data_dir, f"bad_{request.node.callspec.id}", cfg)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    expected = fragment.format(d=data_dir.resolve())
    assert len(info.value.problems) == 1, info.value.problems
    assert expected in info.value.problems[0]
    assert str(info.value).startswith(f"{path.resolve()}: 1 problem in the configuration:\n  - ")


def test_many_problems_in_one_error(data_dir):
    cfg = full_config()
    cfg["analysis"]["estimator"] = "quadd"
    del cfg["arcs"]["L2"]
    cfg["pairing"]["file"] = "missing_pairs.ecsv"
    path = write(data_dir, "three", cfg)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    err = info.value
    assert err.path == path.resolve()
    assert len(err.problems) == 3
    text = str(err)
    assert text.startswith(f"{path.resolve()}: 3 problems in the configuration:\n")
    for fragment in ("[analysis] estimator: 'quadd'", "[arcs.L2]: missing",
                     f"[pairing] file: file not found: {data_dir.resolve()}/missing_pairs.ecsv"):
        assert f"\n  - {fragment}" in text
    again = pickle.loads(pickle.dumps(err))
    assert again.problems == err.problems and str(again) == text


def test_file_level_errors(data_dir):
    with pytest.raises(ConfigError, match="configuration file not found: .*nothing.toml"):
        load_config(data_dir / "nothing.toml")
    path = data_dir / "syntax.toml"
    path.write_text('[analysis]\nestimator = "quad"\nseed = \n')
    with pytest.raises(ConfigError, match=r"invalid TOML: .*\(at line 3, column 8\)"):
        load_config(path)
    cfg = minimal_config() | {"bands": "F150W"}
    with pytest.raises(ConfigError, match=r"\[bands\]: expected a table, got a string"):
        load_config(write(data_dir, "bands_string", cfg))


def test_a_repeated_key_is_named(data_dir):
    path = data_dir / "repeated.toml"
    path.write_text('[analysis]\nseed = 1\nestimator = "quad"\nseed = 2\n')
    with pytest.raises(ConfigError, match=r"\(at line 4, column 9\): the key 'seed' is given "
                                          r"twice in its table"):
        load_config(path)


def test_a_byte_order_mark_is_not_part_of_the_file(data_dir):
    plain = write(data_dir, "plain", minimal_config())
    bom = data_dir / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = load_config(plain), load_config(bom)
    assert a.bands == b.bands and a.arcs == b.arcs and a.estimator == b.estimator


# ---------------------------------------------------------------------------
# writing TOML
# ---------------------------------------------------------------------------


def test_format_config_round_trip(tmp_path):
    data = {
        "title": 'a "quoted" \\ back\tslash\nnew line \x01 ünïcode',
        "n": -3,
        "big": 2**62,
        "x": 0.1,
        "tiny": 1e-300,
        "huge": -2.5e20,
        "inf": float("inf"),
        "flag": False,
        "names": ["NFW_ELLIPSE_CSE", "SHEAR"],
        "values": [1.5, -2.0, 3e-7],
        "mixed": [[1, 2], ["a"]],
        "empty_list": [],
        "empty": {},
        "bands": {"F150W": {"psf": "psf.fits"}, "F200W": {"psf_fwhm": "0.066 arcsec"}},
        "arcs": {"L1": {"F150W": {"image": "a.fits", "hdu": 1},
                        "cutout": {"center": "1 2", "size": ["1 arcsec", "2 arcsec"]}}},
        "odd keys": {"a.b": {"c d": 1, "": True, "ключ": "v"}},
    }
    text = format_config(data, header="written by a test\n\nsecond paragraph")
    assert text.startswith("# written by a test\n#\n# second paragraph\n\n")
    assert tomllib.loads(text) == data
    assert "[arcs.L1.F150W]" in text and '["odd keys"."a.b"]' in text
    assert "[arcs]" not in text and "[empty]" in text
    assert tomllib.loads(format_config(full_config())) == full_config()

    path = tmp_path / "run.toml"
    path.write_text("old")
    assert write_config(path, data, header="hello") == path
    assert tomllib.loads(path.read_text(encoding="utf-8")) == data
    assert [p.name for p in tmp_path.iterdir()] == ["run.toml"]

    with pytest.raises(TypeError, match=r"format_config: x\.y is a NoneType"):
        format_config({"x": {"y": None}})
    with pytest.raises(TypeError, match="the keys must be strings"):
        format_config({1: 2})
    data2 = copy.deepcopy(data)
    data2["arcs"]["L1"]["F150W"]["hdu"] = {1, 2}
    with pytest.raises(TypeError, match="set"):
        format_config(data2)


# ---------------------------------------------------------------------------
# the schema: every key declared once (lensdual.config.FIELDS)
# ---------------------------------------------------------------------------


def knots_config():
    """A minimal catalogue-only configuration (the catalogue is only checked to exist)."""
    return {"knots": {"catalogue": "best.par", "macro_images": ["1.1", "1.2"]}}


def _loaded(cfg, field):
    """The loaded value of ``field`` in the RunConfig ``cfg``."""
    holder = {
        "output": cfg, "analysis": cfg, "pairing": cfg, "parametric": cfg.parametric,
        "knots": cfg.knots, "bands.<band>": cfg.bands.get("F150W"),
        "arcs.<arc>.<band>": cfg.arcs.get("L1") and cfg.arcs["L1"].images["F150W"],
        "arcs.<arc>.cutout": cfg.arcs.get("L1"),
    }[field.table]
    return getattr(holder, field.attribute)


def _same(a, b):
    if isinstance(a, u.Quantity) or isinstance(b, u.Quantity):
        return isinstance(a, u.Quantity) and isinstance(b, u.Quantity) and a == b
    return a == b and type(a) is type(b)


OPTIONAL = [f for f in FIELDS if not f.required and f.table != "catalogs"]


@pytest.mark.parametrize("field", OPTIONAL, ids=[f.name for f in OPTIONAL])
def test_schema_default_is_what_a_minimal_config_loads(data_dir, field):
    if field.table == "knots":
        cfg = knots_config()
    else:
        cfg = minimal_config() | {"pairing": {}, "parametric": {}}
    loaded = load_config(write(data_dir, "schema_defaults", cfg))
    if field.name == "[output] outdir":
        assert loaded.outdir == data_dir.resolve() / field.default
    else:
        assert _same(_loaded(loaded, field), field.default)


def test_schema_defaults_are_those_of_the_specification_classes():
    holders = {"output": RunConfig, "analysis": RunConfig, "pairing": RunConfig,
               "parametric": ParametricSpec, "knots": KnotSpec, "bands.<band>": BandSpec,
               "arcs.<arc>.<band>": ImageSpec, "arcs.<arc>.cutout": ArcSpec}
    checked = 0
    for field in FIELDS:
        if field.table not in holders or field.name == "[output] outdir":
            continue
        spec = {f.name: f for f in dataclasses.fields(holders[field.table])}[field.attribute]
        if field.required:
            assert spec.default in (dataclasses.MISSING, None), field.name
        else:
            assert _same(spec.default, field.default), field.name
            checked += 1
    assert checked >= 30


def test_schema_defaults_agree_with_the_library():
    """Defaults the run shares with the Python functions it calls (the library has no
    named constant for them, so a test keeps the two in step)."""
    import inspect

    from lensdual.estimators import DEFAULT_METHOD, METHODS
    from lensdual.parametric.comparison import parametric_comparison
    from lensdual.pipeline import analyse

    params = inspect.signature(analyse).parameters
    for key in ("estimator", "sigma_pos", "n_bootstrap", "snr_threshold", "seed",
                "null_realisations"):
        assert _same(schema.default("analysis", key), params[key].default), key
    assert schema.default("analysis", "estimator") is DEFAULT_METHOD
    assert schema.field("analysis", "estimator").choices == tuple(METHODS)
    assert (schema.default("parametric", "model")
            == inspect.signature(parametric_comparison).parameters["model"].default)


REQUIRED_KEYS = [
    ("[arcs.<arc>.<band>] image", _set("arcs", "L1", "F150W", "image", None),
     "[arcs.L1.F150W] image: missing"),
    ("[arcs.<arc>.cutout] center", _set("arcs", "L1", "cutout", "center", None),
     "[arcs.L1.cutout] center: missing"),
    ("[arcs.<arc>.cutout] size", _set("arcs", "L1", "cutout", "size", None),
     "[arcs.L1.cutout] size: missing"),
    ("[knots] catalogue", _set("knots", "catalogue", None), "[knots] catalogue: required"),
    ("[knots] macro_images", _set("knots", "macro_images", None),
     "[knots] macro_images: required"),
]


def test_required_keys_are_those_of_the_schema():
    assert {name for name, *_ in REQUIRED_KEYS} == {f.name for f in FIELDS if f.required}


@pytest.mark.parametrize(("mutate", "fragment"), [r[1:] for r in REQUIRED_KEYS],
                         ids=[r[0] for r in REQUIRED_KEYS])
def test_required_key_missing(data_dir, mutate, fragment):
    cfg = knots_config() if "knots" in fragment else full_config()
    mutate(cfg)
    with pytest.raises(ConfigError) as info:
        load_config(write(data_dir, "required", cfg))
    assert [p for p in info.value.problems if p.startswith(fragment)], info.value.problems


def _key_tables():
    """(schema table, concrete table path, base config) of every table with fixed keys."""
    out = []
    for table in dict.fromkeys(f.table for f in FIELDS):
        path = {"bands.<band>": ("bands", "F150W"), "arcs.<arc>.<band>": ("arcs", "L1", "F150W"),
                "arcs.<arc>.cutout": ("arcs", "L1", "cutout")}.get(table, (table,))
        out.append((table, path))
    return out


@pytest.mark.parametrize(("table", "path"), _key_tables(), ids=[t for t, _ in _key_tables()])
def test_unknown_key_rejected(data_dir, table, path):
    cfg = knots_config() if table == "knots" else full_config()
    _set(*path, "zzz_unknown", 1)(cfg)
    with pytest.raises(ConfigError) as info:
        load_config(write(data_dir, "unknown_key", cfg))
    sec = ".".join(path)
    known = ", ".join(schema.keys(table))
    assert info.value.problems == [f"[{sec}] zzz_unknown: unknown key (known keys: {known})"]


BOUNDED = [f for f in FIELDS
           if f.minimum is not None or f.above is not None or f.choices is not None]


def _bounded_config(field):
    cfg = knots_config() if field.table == "knots" else minimal_config()
    cfg.setdefault(field.table, {})
    return cfg


@pytest.mark.parametrize("field", BOUNDED, ids=[f.name for f in BOUNDED])
def test_bounds_from_the_schema(data_dir, field):
    assert len(BOUNDED) >= 9
    cfg = _bounded_config(field)
    if field.minimum is not None:
        bad, ok = field.minimum - 1, field.minimum
        message = f"{field.name}: must be >= {field.minimum}, got {bad}"
    elif field.above is not None:
        bad, ok = field.above, field.above + 1.5
        message = f"{field.name}: must be > {field.above:g}, got {bad:g}"
    else:
        bad, ok = "zzz", field.default
        listed = ", ".join(f"'{c}'" for c in field.choices)
        message = f"{field.name}: 'zzz' is not one of {listed}"
    cfg[field.table][field.key] = bad
    with pytest.raises(ConfigError) as info:
        load_config(write(data_dir, "bounds", cfg))
    assert info.value.problems == [message]
    cfg[field.table][field.key] = ok  # the bound itself (or the default) is accepted
    loaded = load_config(write(data_dir, "bounds", cfg))
    assert _loaded(loaded, field) == ok


def _doc_table(doc):
    """{key name: (type, default)} of the list-table of keys in ``doc``."""
    block = doc[doc.index(".. list-table::"):]
    if ".. rubric:: The keys of lensdual infer" in block:  # lensdual infer's table follows
        block = block[:block.index(".. rubric:: The keys of lensdual infer")]
    rows = re.findall(r"^   \* - (.*)\n     - (.*)\n     - (.*)\n     - (.*)$", block, re.M)
    return {name: (kind, shown) for name, kind, shown, _ in rows[1:]}


def test_documentation_table_agrees_with_the_schema():
    import lensdual.config

    table = _doc_table(lensdual.config.__doc__)
    assert list(table) == [f"``{f.name}``" for f in FIELDS]
    for f in FIELDS:
        kind, shown = table[f"``{f.name}``"]
        assert shown.strip("`") == f.shown_default(), f.name
        if f.minimum is not None:
            assert kind.endswith(f">= {f.minimum}"), f.name
        if f.above is not None:
            assert kind.endswith(f"> {f.above:g}"), f.name
        if not f.required and f.shown is None and f.default is not None:
            # a TOML default reads back as the default
            value = tomllib.loads(f"v = {f.shown_default()}")["v"]
            expected = f.default
            if isinstance(expected, u.Quantity):
                value = u.Quantity(value)
            elif isinstance(expected, tuple):
                value = tuple(value)
            assert _same(value, expected), f.name


def _example_tables(doc):
    """The annotated example configurations of ``doc`` (the [output] ... and the [knots]
    blocks that ``lensdual run --help`` prints), parsed."""
    import textwrap

    blocks = []
    knots = doc.index("::\n\n", doc.index("[knots]"))
    for start, last in ((doc.index("::\n\n"), "z_source"), (knots, "sigma_pos")):
        end = doc.index("\n\n", doc.index(last, start))
        text = textwrap.dedent(doc[start + 4:end])
        # the example shows alternatives (psf and psf_fwhm, error and weight): keep them
        # apart by reading every [table] on its own
        for part in re.split(r"^(?=\[)", text, flags=re.M):
            if part.strip():
                blocks.append(tomllib.loads(part))
    return blocks


def _schema_table(path):
    """The schema's table of a concrete table path, e.g. arcs.L1.F150W."""
    if path[0] == "bands" and len(path) == 2:
        return "bands.<band>"
    if path[0] == "arcs" and len(path) == 3:
        return "arcs.<arc>.cutout" if path[2] == "cutout" else "arcs.<arc>.<band>"
    return ".".join(path)


def test_annotated_example_agrees_with_the_schema():
    import lensdual.config

    # the example shows the default of these keys (for [output] and [analysis]: of all)
    shows_default = {("pairing", "method"), ("parametric", "fit"), ("parametric", "model"),
                     ("parametric", "sigma_pos"), ("parametric", "fix_centre"),
                     ("knots", "centres"), ("knots", "sigma_pos")}
    seen = set()

    def walk(table, path):
        for key, value in table.items():
            if isinstance(value, dict) and (len(path) < 3 or path[0] != "knots"):
                walk(value, (*path, key))
                continue
            f = schema.field(_schema_table(path), key)
            seen.add(f.name)
            if f.table in ("output", "analysis") or (f.table, f.key) in shows_default:
                assert tomllib.loads(f"v = {f.shown_default()}")["v"] == value, f.name

    for block in _example_tables(lensdual.config.__doc__):
        walk(block, ())
    # every key is in the example, but for weight maps: its comments name them
    assert {f.name for f in FIELDS} - seen == {"[arcs.<arc>.<band>] weight",
                                               "[arcs.<arc>.<band>] weight_hdu"}
    assert 'weight = "..." / weight_hdu' in lensdual.config.__doc__


def test_the_joint_test_is_read(data_dir):
    cfg = minimal_config()
    cfg.setdefault("analysis", {}).update(test="joint", null_realisations=200)
    cfg.setdefault("pairing", {})["max_magnification"] = 50.0
    loaded = load_config(write(data_dir, "joint_test", cfg))
    assert (loaded.test, loaded.null_realisations) == ("joint", 200)
    assert loaded.snr_definition == "auto"
    cfg["analysis"]["snr_definition"] = "conservative"
    assert load_config(write(data_dir, "joint_cons", cfg)).snr_definition == "conservative"
    assert loaded.max_magnification == 50.0
