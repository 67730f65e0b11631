"""The diffuse-light doubt: pairs whose images sit on different light that is not lensed."""

import warnings

import numpy as np
import pytest
from astropy import units as u
from astropy.table import QTable
from scipy import stats

from lensdual._diffuse_light import (
    DIFFUSE_LIGHT_ALPHA,
    MIN_DIFFUSE_PAIRS,
    diffuse_light_threshold,
    doubt_diffuse_light,
    studentized_residuals,
)
from lensdual._doubts import no_doubts

SB = u.nJy / u.arcsec**2


def _externally_studentized(X, d):
    """The textbook form from the full fit alone: r_i / (s_(i) sqrt(1 - h_ii)), with
    s_(i)^2 = (RSS - r_i^2 / (1 - h_ii)) / (n - p - 1)."""
    hat = X @ np.linalg.solve(X.T @ X, X.T)
    r = d - hat @ d
    h = np.diag(hat)
    n, p = X.shape
    s2 = (r @ r - r**2 / (1 - h)) / (n - p - 1)
    return r / np.sqrt(s2 * (1 - h))


def _design(x, y, f):
    return np.column_stack([np.ones_like(x), x, y, f])


def test_leave_one_out_residuals_are_the_externally_studentized_ones():
    rng = np.random.default_rng(3)
    x, y, f = rng.uniform(-2, 2, 15), rng.uniform(-1, 1, 15), rng.normal(0, 1, 15)
    d = 0.3 + 0.2 * x - 0.5 * y + 0.1 * f + rng.normal(0, 0.1, 15)
    X = _design(x, y, f)
    np.testing.assert_allclose(studentized_residuals(X, d), _externally_studentized(X, d),
                               rtol=1e-10)
    # positions on a line: the others do not determine the fit (NaN, no error)
    X[:, 2] = 2 * X[:, 1]
    assert np.all(np.isnan(studentized_residuals(X, d)))


def test_false_doubts_per_constellation_are_alpha():
    """Normal scatter about the model: a constellation has a doubtful pair with
    probability at most alpha (Bonferroni), close to it for a small alpha."""
    rng = np.random.default_rng(4)
    n, trials = 12, 4000
    threshold = diffuse_light_threshold(n)
    assert threshold == pytest.approx(stats.t.ppf(1 - DIFFUSE_LIGHT_ALPHA / (2 * n), n - 5))
    hits = 0
    for _ in range(trials):
        x, y, f = rng.uniform(-2, 2, n), rng.uniform(-1, 1, n), rng.normal(0, 1, n)
        d = 1.0 - 0.4 * x + 0.3 * f + rng.normal(0, 0.2, n)
        hits += np.any(np.abs(studentized_residuals(_design(x, y, f), d)) > threshold)
    rate = hits / trials
    # alpha = 1 %: within four binomial errors below it, and at most it plus four
    err = np.sqrt(DIFFUSE_LIGHT_ALPHA * (1 - DIFFUSE_LIGHT_ALPHA) / trials)
    assert DIFFUSE_LIGHT_ALPHA - 4 * err < rate < DIFFUSE_LIGHT_ALPHA + 4 * err


def _table(n=12, patch=None, seed=5, bands=("F150W", "F200W"), units=None, leak=0.0,
           boost=None):
    """A pairs table with the photometry's backgrounds: a gradient of light that is
    not lensed on L1, the same lensed arc light under both images, ``leak`` times each
    image's flux (a PSF model unlike the source), noise; ``patch`` (index, surface
    brightness) adds light under one L1 image, ``boost`` (index, factor) multiplies
    one L1 image's flux (a sub-halo)."""
    rng = np.random.default_rng(seed)
    t = QTable()
    t["pair_id"] = np.arange(1, n + 1)
    x1, y1 = rng.uniform(-3, 3, n), rng.uniform(-1, 1, n)
    t["x1"], t["y1"] = x1 * u.arcsec, y1 * u.arcsec
    f2 = rng.uniform(100, 600, n)
    f1 = 1.8 * f2
    if boost is not None:
        f1[boost[0]] *= boost[1]
    for k, band in enumerate(bands):
        unit = SB if units is None else units[k]
        arc = rng.uniform(200, 400, n)
        icl = 50 + 20 * x1 - 10 * y1
        b1 = arc + icl + leak * f1 + rng.normal(0, 5, n)
        b2 = arc + leak * f2 + rng.normal(0, 5, n)
        if patch is not None:
            b1[patch[0]] += patch[1]
        t[f"bkg1_{band}"] = b1 * unit
        t[f"bkg2_{band}"] = b2 * unit
        t[f"flux1_{band}"] = f1 * u.nJy
        t[f"flux2_{band}"] = f2 * u.nJy
    return t


def test_a_patch_under_one_image_makes_its_pair_doubtful():
    t = _table(patch=(4, 60.0))
    doubt = no_doubts(len(t))
    summary = doubt_diffuse_light(t, ["F150W", "F200W"], doubt)
    assert summary["n_pairs"] == 12
    assert summary["threshold"] == pytest.approx(diffuse_light_threshold(12))
    assert summary["bands"] == ["F150W", "F200W"]
    assert np.all(doubt == "")  # the pairing's doubts are not touched
    reason = np.asarray(t["flux_doubt"])
    assert reason[4].startswith("diffuse light differs between the images (t = ")
    assert np.all(reason[np.arange(12) != 4] == "")
    assert abs(t["diffuse_light_t"][4]) > summary["threshold"]
    # the same table without the patch: nothing doubtful
    clean = _table()
    doubt = no_doubts(len(clean))
    doubt_diffuse_light(clean, ["F150W", "F200W"], doubt)
    assert np.all(clean["flux_doubt"] == "") and np.all(np.isfinite(clean["diffuse_light_t"]))


def test_a_sub_halo_seen_through_a_psf_leak_is_not_doubtful():
    """A PSF model unlike the sources puts 5 % of each image's flux (per arcsec^2) into
    its background; a sub-halo doubles one L1 image's flux, and so its background
    difference: the flux difference's fitted multiple explains it, where a plane
    alone would not."""
    t = _table(leak=0.05, boost=(4, 2.0))
    doubt = no_doubts(len(t))
    doubt_diffuse_light(t, ["F150W", "F200W"], doubt)
    assert np.all(t["flux_doubt"] == "")
    assert abs(t["diffuse_light_t"][4]) < 3
    plane = np.column_stack([np.ones(12), t["x1"].value, t["y1"].value])
    d = np.mean([(t[f"bkg1_{b}"] - t[f"bkg2_{b}"]).value for b in ("F150W", "F200W")], axis=0)
    assert abs(studentized_residuals(plane, d)[4]) > diffuse_light_threshold(12)
    # the patch is still found under the leak
    t = _table(leak=0.05, patch=(4, 60.0))
    doubt_diffuse_light(t, ["F150W", "F200W"], no_doubts(len(t)))
    reason = np.asarray(t["flux_doubt"])
    assert reason[4] != "" and np.all(reason[np.arange(12) != 4] == "")


def test_a_pair_missing_a_band_is_compared_in_the_others():
    """A pair whose fit failed in one band is compared in the bands it has, against
    the others' fit in those bands: not doubted for the other band's light (the
    bands' light differs sixfold), found under a patch (a patch bright enough to
    break one band's fit must not pass unseen), and counted in the Bonferroni
    correction; its threshold has the degrees of freedom of its fit."""
    for patch in (None, (3, 60.0)):
        t = _table(patch=patch)
        t["bkg1_F200W"] = t["bkg1_F200W"] * 6
        t["bkg2_F200W"] = t["bkg2_F200W"] * 6
        t["bkg1_F200W"][3] = np.nan
        summary = doubt_diffuse_light(t, ["F150W", "F200W"], no_doubts(len(t)))
        assert summary["n_pairs"] == 12 and summary["n_pairs_fewer_bands"] == 1
        assert summary["threshold"] == pytest.approx(diffuse_light_threshold(12, n_fit=11))
        # pair 3's t is the F150W difference alone against the fit to all the others
        d = (t["bkg1_F150W"] - t["bkg2_F150W"]).value
        f = (t["flux1_F150W"] - t["flux2_F150W"]).value
        expected = studentized_residuals(_design(t["x1"].value, t["y1"].value, f), d)[3]
        assert t["diffuse_light_t"][3] == pytest.approx(expected, rel=1e-9)
        assert np.all(np.isfinite(t["diffuse_light_t"]))
        reason = np.asarray(t["flux_doubt"])
        if patch is None:
            assert np.all(reason == "")
        else:
            assert reason[3].startswith("diffuse light differs")
            assert f"beyond {diffuse_light_threshold(12):.1f}" in reason[3]
            assert np.all(reason[np.arange(12) != 3] == "")


def test_a_patch_is_seen_when_other_pairs_lose_a_band():
    """The bands a pair is compared in are chosen by which pairs were measured, not by
    the values: a fit of fewer bands over more pairs where the full mix has too few
    pairs (7 pairs, one without F200W: all 7 compared in F150W), or leaves too few
    degrees of freedom (10 pairs in three bands, three without C: compared in A and B
    over all 10, not in A, B, C over 7 with 2 degrees of freedom)."""
    t = _table(n=7, patch=(2, 500.0))
    t["bkg1_F200W"][0] = np.nan
    summary = doubt_diffuse_light(t, ["F150W", "F200W"], no_doubts(7))
    assert summary["n_pairs"] == 7 and summary["bands"] == ["F150W"]
    assert summary["n_pairs_fewer_bands"] == 6  # pair 0 had F150W alone
    assert summary["threshold"] == pytest.approx(diffuse_light_threshold(7))
    reason = np.asarray(t["flux_doubt"])
    assert reason[2] != "" and np.all(reason[np.arange(7) != 2] == "")
    bands = ["A", "B", "C"]
    for lost in ([], [2, 5, 8]):
        t = _table(n=10, bands=bands, patch=(0, 80.0))
        t["bkg2_C"][lost] = np.nan
        summary = doubt_diffuse_light(t, bands, no_doubts(10))
        assert summary["n_pairs"] == 10
        assert t["flux_doubt"][0] != ""
        expected = ["A", "B", "C"] if not lost else ["A", "B"]
        assert summary["bands"] == expected
        assert summary["threshold"] == pytest.approx(diffuse_light_threshold(10))
        # pair 0's t is its mean over the chosen bands against the fit to the others
        d = np.mean([(t[f"bkg1_{b}"] - t[f"bkg2_{b}"]).value for b in expected], axis=0)
        f = np.mean([(t[f"flux1_{b}"] - t[f"flux2_{b}"]).value for b in expected], axis=0)
        ref = studentized_residuals(_design(t["x1"].value, t["y1"].value, f), d)[0]
        assert t["diffuse_light_t"][0] == pytest.approx(ref, rel=1e-9)
    # every pair without F200W: compared in F150W, the threshold reported is the one used
    t = _table(patch=(4, 60.0))
    t["bkg2_F200W"] = np.nan * t["bkg2_F200W"]
    summary = doubt_diffuse_light(t, ["F150W", "F200W"], no_doubts(12))
    assert summary["bands"] == ["F150W"] and summary["n_pairs_fewer_bands"] == 0
    assert summary["threshold"] == pytest.approx(diffuse_light_threshold(12))
    assert f"beyond {summary['threshold']:.1f}" in t["flux_doubt"][4]


def test_only_pairs_without_doubt_are_compared():
    t = _table(patch=(4, 60.0))
    doubt = no_doubts(len(t))
    doubt[4] = "already doubtful"
    doubt[7] = "another reason"
    summary = doubt_diffuse_light(t, ["F150W", "F200W"], doubt)
    assert summary["n_pairs"] == 10 and t["flux_doubt"][4] == ""
    assert np.isnan(t["diffuse_light_t"][4]) and np.isnan(t["diffuse_light_t"][7])
    # too few pairs: nothing compared
    small = _table(n=MIN_DIFFUSE_PAIRS - 1, patch=(1, 500.0))
    doubt = no_doubts(len(small))
    summary = doubt_diffuse_light(small, ["F150W", "F200W"], doubt)
    assert summary["threshold"] is None and np.all(small["flux_doubt"] == "")
    assert np.all(np.isnan(small["diffuse_light_t"]))
    # no background columns (another background strategy): nothing compared
    bare = QTable({"x1": [0.0] * 8 * u.arcsec, "y1": [0.0] * 8 * u.arcsec})
    doubt = no_doubts(8)
    assert doubt_diffuse_light(bare, ["F150W"], doubt)["n_pairs"] == 0
    # every L1 image on one line: no fit, no doubt, no error
    line = _table(patch=(4, 60.0))
    line["y1"] = 0.5 * line["x1"]
    doubt = no_doubts(12)
    doubt_diffuse_light(line, ["F150W", "F200W"], doubt)
    assert np.all(line["flux_doubt"] == "") and np.all(np.isnan(line["diffuse_light_t"]))


def test_bands_in_units_that_do_not_convert_are_left_out():
    """A band in counts beside one in nJy: only the first band's unit is compared,
    whatever the other band holds; a band in another convertible unit is converted."""
    counts = u.ct / u.s / u.arcsec**2
    a = _table(patch=(4, 60.0), units=[SB, counts])
    assert doubt_diffuse_light(a, ["F150W", "F200W"], no_doubts(12))["bands"] == ["F150W"]
    b = _table(patch=(4, 60.0), units=[SB, counts])
    b["bkg1_F200W"] *= 1000
    doubt_diffuse_light(b, ["F150W", "F200W"], no_doubts(12))
    assert a["flux_doubt"][4] != "" and list(a["flux_doubt"]) == list(b["flux_doubt"])
    np.testing.assert_allclose(a["diffuse_light_t"], b["diffuse_light_t"], rtol=1e-12)
    c = _table(patch=(4, 60.0))
    mjy = _table(patch=(4, 60.0))
    for arc in "12":
        mjy[f"bkg{arc}_F200W"] = mjy[f"bkg{arc}_F200W"].to(u.MJy / u.sr)
    doubt_diffuse_light(c, ["F150W", "F200W"], no_doubts(12))
    assert doubt_diffuse_light(mjy, ["F150W", "F200W"], no_doubts(12))["bands"] == [
        "F150W", "F200W"]
    np.testing.assert_allclose(c["diffuse_light_t"], mjy["diffuse_light_t"], rtol=1e-9)


def test_measure_pairs_reports_the_background_as_a_surface_brightness():
    """A flat sky of 5 per pixel under two sources, pixels of 0.04 arcsec: the
    background under each image is 5 / 0.0016 per arcsec^2."""
    from lensdual.photometry import measure_pairs

    pytest.importorskip("photutils")
    from astropy.coordinates import SkyCoord
    from astropy.nddata import CCDData, StdDevUncertainty
    from astropy.wcs import WCS

    def image(sources, scale, sky):
        w = WCS(naxis=2)
        w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
        w.wcs.crval = [150.0, 2.0]
        w.wcs.crpix = [31, 31]
        w.wcs.cdelt = [-scale / 3600, scale / 3600]
        yy, xx = np.mgrid[:60, :60]
        data = np.full((60, 60), sky)
        sig = 4.0 / 2.3548
        for x, y, f in sources:
            data += f * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * sig**2)) / (
                2 * np.pi * sig**2)
        rng = np.random.default_rng(1)
        data = data + rng.normal(0, 0.05, data.shape)
        return CCDData(data * u.nJy, wcs=w, uncertainty=StdDevUncertainty(np.full(data.shape,
                                                                                   0.05)))

    srcs = [(20.0, 30.0, 400.0), (40.0, 30.0, 300.0)]
    l1 = {"F150W": image(srcs, 0.04, 5.0)}
    l2 = {"F150W": image(srcs, 0.04, 5.0)}
    sky = l1["F150W"].wcs.pixel_to_world([20.0, 40.0], [30.0, 30.0])
    pairs = QTable({"pair_id": [1, 2], "sky1": sky, "sky2": SkyCoord(sky)})
    from photutils.background import LocalBackground

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = measure_pairs(l1, l2, pairs, psf=4.0, background="constant")
        ridge = measure_pairs(l1, l2, pairs, psf=4.0)
        local = measure_pairs(l1, l2, pairs, psf=4.0, background=LocalBackground(8, 14))
        none = measure_pairs(l1, l2, pairs, psf=4.0, background="residual")
        # an image in MJy/sr is a surface brightness already: converted, not divided
        per_sr = {"F150W": CCDData(l1["F150W"].data * 1e-15, unit=u.MJy / u.sr,
                                   wcs=l1["F150W"].wcs)}
        sr = measure_pairs(per_sr, {"F150W": per_sr["F150W"]}, pairs, psf=4.0,
                           background="constant")
    assert out["bkg1_F150W"].unit.is_equivalent(SB)
    # the ridge's cross profile is free: it follows the flat sky less closely
    for table, rtol in ((out, 0.02), (local, 0.02), (ridge, 0.05)):
        for arc in "12":
            np.testing.assert_allclose(table[f"bkg{arc}_F150W"].to_value(SB), 5.0 / 0.04**2,
                                       rtol=rtol)
    assert "bkg1_F150W" not in none.colnames
    np.testing.assert_allclose(sr["bkg1_F150W"].to_value(u.MJy / u.arcsec**2),
                               (5e-15 * u.MJy / u.sr).to_value(u.MJy / u.arcsec**2), rtol=0.02)


def test_the_pipeline_doubts_the_pair_on_a_bright_patch():
    """The realistic demo scene with its default patch under pair 0's L2 image (the
    paper's contrast, its flux ratio about 10 % off): the pair is doubtful for its
    diffuse light and untested; the run records the comparison."""
    pytest.importorskip("poppy")
    from lensdual.demo import compare_with_truth, render_demo, simulate_demo
    from lensdual.pipeline import analyse, verdict

    system, truth = simulate_demo(subhalo="none", seed=0)
    demo = render_demo(system, truth, seed=0, scene="realistic")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        analysis = analyse(demo.images, psf=demo.psf, sigma_pos="auto", seed=0)
    res = analysis.result
    comp = compare_with_truth(res, truth, demo.centre)
    pairs = demo.mocks.pairs
    assert pairs["patch2"][0] and not pairs["patch1"].any()
    under = np.asarray(pairs["source"])[np.asarray(pairs["patch2"], bool)]
    row = np.flatnonzero(np.isin(np.asarray(comp["source"]), under))
    assert row.size == 1
    (k,) = row
    assert str(res["flux_doubt"][k]).startswith("diffuse light differs between the images")
    assert not res["tested"][k] and not res["anomalous"][k]
    # its positions are not in doubt: it keeps its size magnification
    assert res["doubt"][k] == "" and np.isfinite(res["mu_size"][k])
    meta = res.meta["diffuse_light"]
    assert meta["n_pairs"] >= MIN_DIFFUSE_PAIRS and meta["alpha"] == DIFFUSE_LIGHT_ALPHA
    others = np.arange(len(res)) != k
    assert not any(np.asarray(res["flux_doubt"])[others])
    # the report lists it apart from doubtful pairings, with its reason
    text = verdict(res, analysis.sigma_pos)
    assert (f"whose flux ratio is doubtful keep their place in the geometry and are never "
            f"counted as anomalies: pair {res['pair_id'][k]}: diffuse light differs") in text
    assert "Doubtful pairings" not in text


def _doubt_table(n=16):
    """16 pairs through a slightly bent map, fluxes in two bands at 1 %, pair 6's L1
    image 60 % too bright; the same table with its flux ratio doubtful, and with its
    fluxes unmeasured (NaN)."""
    rng = np.random.default_rng(7)
    theta2 = rng.uniform(-1, 1, (n, 2))
    a = np.array([[1.5, 0.3], [0.1, -0.8]])
    theta1 = theta2 @ a.T + 0.05 * theta2**2
    flux2 = rng.uniform(80, 120, n)
    flux1 = abs(np.linalg.det(a)) * flux2 * np.exp(rng.normal(0, 0.01, n))
    flux1[5] *= 1.6  # light under pair 6's L1 image
    pairs = QTable({"x1": theta1[:, 0] * u.arcsec, "y1": theta1[:, 1] * u.arcsec,
                    "x2": theta2[:, 0] * u.arcsec, "y2": theta2[:, 1] * u.arcsec})
    for band, colour in (("F150W", 1.0), ("F200W", 1.3)):
        pairs[f"flux1_{band}"] = colour * flux1
        pairs[f"flux2_{band}"] = colour * flux2
        pairs[f"flux_err1_{band}"] = 0.01 * colour * flux1
        pairs[f"flux_err2_{band}"] = 0.01 * colour * flux2
    doubted = pairs.copy()
    reasons = [""] * n
    reasons[5] = "diffuse light differs between the images"
    doubted["flux_doubt"] = reasons
    unmeasured = pairs.copy()
    for name in ("flux1_F150W", "flux2_F150W", "flux1_F200W", "flux2_F200W"):
        unmeasured[name][5] = np.nan
    return pairs, doubted, unmeasured


@pytest.mark.parametrize("test", ["geometric", "joint"])
def test_the_null_calibration_leaves_a_doubtful_flux_ratio_untested(test):
    """null_calibration with ``flux_doubt``: the pair has no null significance, and
    the others' null is that of the same table with the pair's fluxes unmeasured (the
    doubt's flux ratio tested in the null would make its family-wise rate too high)."""
    from lensdual.duality import null_calibration

    _, doubted, unmeasured = _doubt_table()
    kw = {"sigma_pos": 0.002 * u.arcsec, "seed": 3, "test": test, "n_realisations": 100,
          "snr_definition": "log"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = null_calibration(doubted, **kw)
        reference = null_calibration(unmeasured, **kw)
    null = np.asarray(got["null_snr"], dtype=float)
    assert np.isnan(null[5]).all() and not got["tested"][5]
    assert np.isfinite(null[np.arange(len(null)) != 5]).mean() > 0.5
    np.testing.assert_array_equal(null, np.asarray(reference["null_snr"], dtype=float))
    assert got.meta["false_alarm_rate"] == reference.meta["false_alarm_rate"]
    # a masked reason is no doubt, as doubts_of documents
    from astropy.table import MaskedColumn

    from lensdual._doubts import doubts_of

    masked = doubted.copy()
    masked["flux_doubt"] = MaskedColumn(list(doubted["flux_doubt"]),
                                        mask=np.arange(len(doubted)) == 5)
    assert doubts_of(masked, "flux_doubt")[5] == ""


@pytest.mark.parametrize("test", ["geometric", "joint"])
def test_a_doubtful_flux_ratio_stays_in_the_geometry(test):
    """check_duality with ``flux_doubt``: the pair keeps its size magnification and
    its place in the others' (the same as without the doubt), is not tested, and its
    flux ratio informs nothing else: the others' results are those of the same table
    with the pair's fluxes unmeasured (NaN)."""
    from lensdual.duality import check_duality

    pairs, doubted, unmeasured = _doubt_table()
    n = len(pairs)
    kw = {"sigma_pos": 0.002 * u.arcsec, "seed": 1, "test": test, "snr_definition": "log"}
    plain = check_duality(pairs, **kw)
    assert plain["anomalous"][5]
    result = check_duality(doubted, **kw)
    assert not result["tested"][5] and not result["anomalous"][5]
    assert result["doubt"][5] == "" and result["flux_doubt"][5].startswith("diffuse light")
    np.testing.assert_allclose(result["mu_size"], plain["mu_size"], rtol=1e-12)
    assert result["mu_flux"][5] == pytest.approx(plain["mu_flux"][5])
    with pytest.warns(Warning, match="no band has a finite flux ratio for row"):
        reference = check_duality(unmeasured, **kw)
    others = np.arange(n) != 5
    for name in ("significance", "tested", "anomalous") + (
            ("ln_mu_field", "ln_mu_predicted") if test == "joint" else ()):
        np.testing.assert_allclose(np.asarray(result[name], float)[others],
                                   np.asarray(reference[name], float)[others], rtol=1e-10,
                                   err_msg=name)
