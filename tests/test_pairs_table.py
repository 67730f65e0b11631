"""Tests of lensdual._pairs_table: the column names and the check of a pairs table."""

import warnings

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import QTable, Table

from lensdual import duality
from lensdual._pairs_table import (
    ID_COLUMNS,
    NEEDS,
    POS_ERR_COLUMNS,
    POSITION_COLUMNS,
    SKY_COLUMNS,
    arc_xy,
    band_flux_cols,
    band_fluxes,
    check_pairs_table,
    flags_col,
    flux_col,
    flux_err_col,
    id_col,
    mu_flux_col,
    mu_flux_err_col,
    pair_bands,
    pos_err_col,
    positions,
    sky_col,
    x_col,
    xy_cols,
    y_col,
)

BANDS = ("F150W", "F200W")
ALL = ("positions", "fluxes", "position_errors", "ids", "sky")


def make_pairs(n=5, bands=BANDS):
    """A complete pairs table: ids, positions, errors, sky and fluxes of every band."""
    rng = np.random.default_rng(0)
    tab = QTable()
    tab["pair_id"] = np.arange(1, n + 1)
    tab["id1"], tab["id2"] = np.arange(n), np.arange(n) + 100
    for arc in (1, 2):
        x, y = xy_cols(arc)
        tab[x] = rng.normal(size=n) * u.arcsec
        tab[y] = rng.normal(size=n) * u.arcsec
        tab[pos_err_col(arc)] = np.full(n, 0.01) * u.arcsec
        tab[sky_col(arc)] = SkyCoord(rng.uniform(10, 11, n) * u.deg, rng.uniform(-1, 1, n) * u.deg)
    for band in bands:
        for arc in (1, 2):
            f = rng.uniform(50, 500, n)
            tab[flux_col(arc, band)] = f * u.nJy
            tab[flux_err_col(arc, band)] = 0.02 * f * u.nJy
    tab.meta["bands"] = list(bands)
    return tab


def test_names():
    assert POSITION_COLUMNS == ("x1", "y1", "x2", "y2")
    assert duality.POSITION_COLUMNS == POSITION_COLUMNS
    assert ID_COLUMNS == ("id1", "id2")
    assert SKY_COLUMNS == ("sky1", "sky2")
    assert POS_ERR_COLUMNS == ("pos_err1", "pos_err2")
    assert band_flux_cols("F150W") == ("flux1_F150W", "flux2_F150W",
                                       "flux_err1_F150W", "flux_err2_F150W")
    assert flags_col(2, "F200W") == "flags2_F200W"
    assert mu_flux_col("F150W") == "mu_flux_F150W"
    assert mu_flux_err_col("F150W") == "mu_flux_err_F150W"
    for arc in (1, "1", "L1"):
        assert (id_col(arc), x_col(arc), y_col(arc), sky_col(arc), pos_err_col(arc)) == (
            "id1", "x1", "y1", "sky1", "pos_err1")
        assert flux_col(arc, "F150W") == "flux1_F150W"
        assert flux_err_col(arc, "F150W") == "flux_err1_F150W"
    for arc in (2, "2", "L2"):
        assert xy_cols(arc) == ("x2", "y2")
    for bad in (0, 3, "L3", "x1", None):
        with pytest.raises(ValueError, match="arc must be 1 or 2"):
            flux_col(bad, "F150W")


def test_pair_bands_round_trip():
    """The bands a table is built with are the bands pair_bands reads back."""
    bands = ["F090W", "F150W", "F444W"]
    tab = make_pairs(bands=bands)
    assert pair_bands(tab) == bands
    del tab.meta["bands"]
    assert pair_bands(tab) == bands  # from the flux1_<band> columns
    assert duality.pair_bands is pair_bands  # public in duality
    assert pair_bands(QTable(meta={"bands": "F150W"})) == ["F150W"]
    with pytest.raises(ValueError, match="the pairs table names no bands"):
        pair_bands(QTable({"x1": [0.0]}))


def test_positions_and_arc_xy():
    tab = make_pairs()
    tab["x2"] = tab["x2"].to(u.mas)
    theta1, theta2 = positions(tab)
    assert theta1.unit == u.arcsec and theta1.shape == (5, 2)
    np.testing.assert_allclose(theta2.value, arc_xy(tab, 2))
    np.testing.assert_allclose(arc_xy(tab, "L1")[:, 1], tab["y1"].to_value(u.arcsec))
    # a Table with unit columns reads the same as a QTable
    plain = Table(make_pairs())
    np.testing.assert_array_equal(positions(plain)[0].value, positions(make_pairs())[0].value)


def test_valid_table_passes():
    tab = make_pairs()
    before = tab.copy()
    for need in ALL:
        check_pairs_table(tab, need=need)
    check_pairs_table(tab, need=ALL)
    check_pairs_table(Table(tab), need=("positions", "fluxes"))
    check_pairs_table(tab, need=("fluxes",), bands="F150W")
    assert tab.colnames == before.colnames and tab.meta == before.meta
    # position-only tables are pairs tables too
    check_pairs_table(tab[list(POSITION_COLUMNS)])
    # NaN: not measured
    tab["flux1_F150W"][2] = np.nan * u.nJy
    tab["flux_err1_F150W"][2] = np.nan * u.nJy
    tab["pos_err1"][1] = np.nan * u.arcsec
    check_pairs_table(tab, need=ALL)
    assert set(NEEDS) == set(ALL)


def _set(name, value):
    return lambda t: t.__setitem__(name, value(t))


@pytest.mark.parametrize(
    ("change", "need", "exc", "match"),
    [
        (lambda t: t.remove_column("y2"), ("positions",), ValueError,
         r"lacks the position column\(s\) \['y2'\]"),
        (lambda t: t.remove_columns(["x1", "x2"]), "positions", ValueError,
         r"lacks the position column\(s\) \['x1', 'x2'\]"),
        (_set("x1", lambda t: t["x1"].value), ("positions",), TypeError,
         "pairs column 'x1' must have angular units"),
        (_set("y2", lambda t: t["y2"].value * u.m), ("positions",), TypeError,
         "pairs column 'y2' must have angular units"),
        (lambda t: t.remove_column("flux_err2_F200W"), ("positions", "fluxes"), ValueError,
         r"lacks the column\(s\) \['flux_err2_F200W'\] of band 'F200W'"),
        (lambda t: t.remove_column("flux1_F150W"), ("fluxes",), ValueError,
         r"lacks the column\(s\) \['flux1_F150W'\] of band 'F150W'"),
        (_set("flux2_F150W", lambda t: t["flux2_F150W"].value * u.s), ("fluxes",), ValueError,
         "flux units of band 'F150W' do not match: flux1_F150W has unit nJy, flux2_F150W"),
        (_set("flux_err1_F200W", lambda t: t["flux_err1_F200W"].value), ("fluxes",), ValueError,
         "flux units of band 'F200W' do not match: .* flux_err1_F200W has unit None"),
        (lambda t: t["flux1_F150W"].__setitem__(3, -1 * u.nJy), ("fluxes",), ValueError,
         r"flux1_F150W must be positive for a flux ratio; non-positive at row\(s\) \[3\]"),
        (lambda t: t["flux_err2_F150W"].__setitem__(1, 0 * u.nJy), ("fluxes",), ValueError,
         r"flux_err2_F150W must be finite and positive; bad at row\(s\) \[1\]"),
        (lambda t: t.meta.__setitem__("bands", ["F150W", "F444W"]), ("fluxes",), ValueError,
         r"\['flux1_F444W', .*\] of band 'F444W'"),
        (lambda t: t.meta.__setitem__("bands", []), ("fluxes",), ValueError,
         "the pairs table names no bands"),
        (lambda t: t.remove_column("pos_err2"), ("position_errors",), ValueError,
         r"lacks the position-error column\(s\) \['pos_err2'\]"),
        (_set("pos_err1", lambda t: t["pos_err1"].value * u.nJy), ("position_errors",),
         TypeError, "pairs column 'pos_err1' must have angular units"),
        (lambda t: t["pos_err1"].__setitem__(4, 0 * u.arcsec), ("position_errors",), ValueError,
         r"pos_err1 must be positive .* row\(s\) \[4\]"),
        (lambda t: t.remove_column("id1"), ("ids",), ValueError,
         r"lacks the id column\(s\) \['id1'\]"),
        (lambda t: t.remove_column("sky2"), ("sky",), ValueError,
         r"lacks the sky column\(s\) \['sky2'\]"),
        (_set("sky1", lambda t: t["x1"]), ("sky",), TypeError,
         "pairs column 'sky1' must be a SkyCoord"),
        (lambda t: None, ("positions", "flux"), ValueError, r"unknown part\(s\) \['flux'\]"),
    ],
)
def test_bad_tables(change, need, exc, match):
    tab = make_pairs()
    change(tab)
    with pytest.raises(exc, match=match):
        check_pairs_table(tab, need=need)


def test_not_a_table():
    with pytest.raises(TypeError, match="pairs must be an astropy Table or QTable"):
        check_pairs_table({"x1": [0.0]})


def test_same_messages_as_check_duality():
    """check_duality reports a bad table with check_pairs_table's message."""
    tab = make_pairs(n=8)
    tab.remove_column("flux_err1_F200W")
    with pytest.raises(ValueError) as direct:
        check_pairs_table(tab, need=("positions", "fluxes"))
    with pytest.raises(ValueError) as through:
        duality.check_duality(tab, "quad", n_bootstrap=5)
    assert str(direct.value) == str(through.value)


def test_simulated_table_passes():
    from lensdual.simulation import clean_constellation

    pairs = clean_constellation("cluster_fold", 8, seed=1)
    check_pairs_table(pairs, need=("positions", "fluxes"))
    assert pair_bands(pairs) == ["F150W", "F200W"]


def test_measured_table_passes():
    """measure_pairs on the library's own mock images gives a complete pairs table."""
    from lensdual.photometry import measure_pairs
    from lensdual.simulation import render_mock_images, smacs0723_analog

    system = smacs0723_analog(seed=1)
    gx, gy = np.meshgrid([0.35, 0.65, 0.95], [6.70, 6.82])
    beta = np.column_stack([gx.ravel(), gy.ravel()]) * u.arcsec
    f0 = np.full(len(beta), 8.0)
    truth = system.constellation(beta, intrinsic_flux={"F150W": f0, "F200W": 0.9 * f0})
    mock = render_mock_images(system, pairs=truth, seed=3, host=False,
                              cutout_size=3 * u.arcsec)
    start = QTable({"pair_id": mock.pairs["pair_id"]})
    for arc in ("L1", "L2"):
        img = mock.arc(arc)["F150W"]
        xy = mock.truth_pixels(arc)
        start[sky_col(arc)] = img.wcs.pixel_to_world(xy[:, 0], xy[:, 1])
    psf = {b: mock.arc("L1")[b].psf for b in mock.bands}
    out = measure_pairs(mock.arc("L1"), mock.arc("L2"), start, psf=psf)
    assert np.all(out["measured"])
    check_pairs_table(out, need=("positions", "fluxes", "position_errors", "sky"))
    assert pair_bands(out) == list(mock.bands)
    for band in mock.bands:
        for arc in (1, 2):
            assert flags_col(arc, band) in out.colnames


def test_a_repeated_pair_id_is_refused_everywhere_a_pairs_table_enters():
    """check_pairs_table, check_duality and manual pairing name the repeated ids and rows."""
    from lensdual.duality import check_duality
    from lensdual.pairing import pairs_from_ids

    tab = make_pairs(8)
    tab["pair_id"][5] = 2
    with pytest.raises(ValueError, match=r"pair_id must identify one pair, but \[2\] occur "
                                         r"more than once \(rows \[1, 5\]\)"):
        check_pairs_table(tab)
    with pytest.raises(ValueError, match=r"\[2\] occur more than once"):
        check_duality(tab, method="quad", sigma_pos=0.01 * u.arcsec)
    ids = Table({"pair_id": [4, 4, 5], "id1": [0, 1, 2], "id2": [100, 101, 102]})
    rng = np.random.default_rng(1)
    cat1 = QTable({"id": np.arange(3), "x": rng.normal(size=3) * u.arcsec,
                   "y": rng.normal(size=3) * u.arcsec})
    cat2 = QTable({"id": np.arange(3) + 100, "x": rng.normal(size=3) * u.arcsec,
                   "y": rng.normal(size=3) * u.arcsec})
    with pytest.raises(ValueError, match=r"the id pairs given: pair_id .* \[4\] occur"):
        pairs_from_ids(cat1, cat2, ids)
    # distinct ids pass
    tab["pair_id"][5] = 99
    check_pairs_table(tab)


def _clean_pairs():
    from lensdual.simulation import clean_constellation

    return clean_constellation("cluster_fold", 12, seed=1)


@pytest.mark.parametrize("kind", ["Table", "QTable"])
def test_masked_fluxes_are_missing_values_not_data(kind):
    """Masked flux entries (MaskedColumn, Masked Quantity) are "not measured", with a
    warning naming the columns and rows; the garbage under the mask is never read."""
    from astropy.table import MaskedColumn
    from astropy.utils.masked import Masked

    from lensdual.duality import check_duality
    from lensdual.exceptions import MissingValuesWarning

    clean = _clean_pairs()
    tab = (Table if kind == "Table" else QTable)(clean)
    for band in clean.meta["bands"]:
        col = flux_col(2, band)
        data = np.array(clean[col].to_value(u.nJy))
        data[3] = 1e-18  # what lies under the mask: a flux ratio of 1e18
        mask = np.zeros(len(tab), bool)
        mask[3] = True
        tab[col] = (MaskedColumn(data, mask=mask, unit=u.nJy) if kind == "Table"
                    else Masked(data * u.nJy, mask=mask))
    before = np.array(tab[flux_col(2, "F150W")].data if kind == "Table"
                      else tab[flux_col(2, "F150W")].unmasked.value)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = check_duality(tab, sigma_pos=0.005 * u.arcsec)
    texts = {str(w.message) for w in caught if issubclass(w.category, MissingValuesWarning)}
    assert any("flux2_F150W at row(s) [3]" in t for t in texts)
    assert any("flux2_F200W at row(s) [3]" in t for t in texts)
    others = [f"{w.category.__name__}: {w.message}" for w in caught
              if not issubclass(w.category, MissingValuesWarning)]
    assert others == ["LensdualWarning: no band has a finite flux ratio for row(s) [3]; "
                      "their mu_flux is NaN"], others
    assert np.isnan(result["mu_flux"][3])
    assert not result["tested"][3] and not result["anomalous"][3]
    assert np.isfinite(np.asarray(result["mu_flux"])[np.arange(12) != 3]).all()
    assert not result["anomalous"].any()
    # the input table is not changed
    after = np.array(tab[flux_col(2, "F150W")].data if kind == "Table"
                     else tab[flux_col(2, "F150W")].unmasked.value)
    np.testing.assert_array_equal(after, before)


def test_a_masked_position_is_refused_by_column_and_row():
    from astropy.table import MaskedColumn

    from lensdual.duality import check_duality

    tab = Table(_clean_pairs())
    mask = np.zeros(len(tab), bool)
    mask[[2, 7]] = True
    tab["x2"] = MaskedColumn(np.array(tab["x2"]), mask=mask, unit=u.arcsec)
    with pytest.raises(ValueError, match=r"'x2' has masked \(missing\) values at row\(s\) "
                                         r"\[2, 7\]"):
        check_duality(tab, sigma_pos=0.005 * u.arcsec)


def test_ab_magnitudes_are_read_as_fluxes():
    """Fluxes in AB magnitudes with errors in mag give the flux ratios and errors of
    the same fluxes in nJy (AB zero point: 31.4 mag is 1 nJy)."""
    from lensdual.duality import flux_ratios

    rng = np.random.default_rng(3)
    m1, m2 = rng.uniform(24, 27, 6), rng.uniform(24, 27, 6)
    dm = np.full(6, 0.02)
    mags = QTable({flux_col(1, "F1"): m1 * u.ABmag, flux_col(2, "F1"): m2 * u.ABmag,
                   flux_err_col(1, "F1"): dm * u.mag, flux_err_col(2, "F1"): dm * u.mag})
    f1, f2 = 10 ** (-0.4 * (m1 - 31.4)), 10 ** (-0.4 * (m2 - 31.4))
    k = np.log(10) / 2.5 * dm
    fluxes = QTable({flux_col(1, "F1"): f1 * u.nJy, flux_col(2, "F1"): f2 * u.nJy,
                     flux_err_col(1, "F1"): k * f1 * u.nJy, flux_err_col(2, "F1"): k * f2 * u.nJy})
    got = band_fluxes(mags, "F1")
    np.testing.assert_allclose(got[0] / got[1], 10 ** (-0.4 * (m1 - m2)), rtol=1e-12)
    for a, b in zip(got, band_fluxes(fluxes, "F1"), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6)
    a, b = flux_ratios(mags), flux_ratios(fluxes)
    np.testing.assert_allclose(np.asarray(a["mu_flux"]), np.asarray(b["mu_flux"]), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(a["mu_flux_err"]), np.asarray(b["mu_flux_err"]),
                               rtol=1e-6)


@pytest.mark.parametrize("change, match", [
    (lambda t: t.__setitem__(flux_col(1, "F1"), [25.0, 26.0] * u.mag),
     "flux1_F1 is in magnitudes without a photometric system"),
    (lambda t: t.__setitem__(flux_err_col(1, "F1"), [0.1, 0.1] * u.ABmag),
     "flux_err1_F1 is in mag\\(AB\\): a magnitude error is a difference"),
    (lambda t: t.__setitem__(flux_err_col(2, "F1"), [0.1, 0.1] * u.mag),
     "flux_err2_F1 is in magnitudes but flux2_F1 is not"),
])
def test_magnitudes_that_cannot_be_fluxes_are_refused(change, match):
    tab = QTable({flux_col(1, "F1"): [25.0, 26.0] * u.ABmag,
                  flux_col(2, "F1"): [400.0, 200.0] * u.nJy,
                  flux_err_col(1, "F1"): [0.02, 0.02] * u.mag,
                  flux_err_col(2, "F1"): [4.0, 2.0] * u.nJy})
    change(tab)
    with pytest.raises(ValueError, match=match):
        band_fluxes(tab, "F1")
