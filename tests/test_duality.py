"""Tests of lensdual.duality.check_duality."""

import warnings

import numpy as np
import pytest
from astropy import units as u
from astropy.table import QTable, Table

from lensdual.duality import check_duality as _check_duality
from lensdual.duality import flux_ratios, pair_bands
from lensdual.estimators import size_magnification as _size_magnification
from lensdual.exceptions import LensdualWarning


# These tests exercise the bootstrap path with the paper's Quad estimator
# (the default of these tests); the adaptive default is tested in
# test_calibration.py.
def check_duality(pairs, method="quad", **kwargs):
    return _check_duality(pairs, method, **kwargs)


def size_magnification(theta1, theta2, method="quad", **kwargs):
    return _size_magnification(theta1, theta2, method, **kwargs)

BANDS = ("F150W", "F200W")


def make_pairs(n=15, det=-1.5, seed=0, flux_unit=u.nJy, rel_err=0.02, noise=True):
    """An affine constellation with fluxes that obey duality exactly (before noise)."""
    rng = np.random.default_rng(seed)
    A = np.array([[1.0, 0.4], [0.2, 0.0]])
    A[1, 1] = (det + A[0, 1] * A[1, 0]) / A[0, 0]
    t2 = rng.normal(scale=0.5, size=(n, 2))
    t1 = t2 @ A.T + [10.0, -3.0]
    tab = QTable()
    tab["pair_id"] = np.arange(1, n + 1)
    tab["x1"], tab["y1"] = t1.T * u.arcsec
    tab["x2"], tab["y2"] = t2.T * u.arcsec
    for band, colour in zip(BANDS, (1.0, 1.4), strict=True):
        f2 = rng.uniform(50, 500, n) * colour
        f1 = abs(det) * f2
        for arc, f in (("1", f1), ("2", f2)):
            err = rel_err * f
            val = f + (rng.normal(size=n) * err if noise else 0.0)
            tab[f"flux{arc}_{band}"] = val * flux_unit
            tab[f"flux_err{arc}_{band}"] = err * flux_unit
    tab.meta["bands"] = list(BANDS)
    return tab


def test_columns_and_values_on_exact_duality():
    pairs = make_pairs(noise=False)
    res = check_duality(pairs, sigma_pos=0.005 * u.arcsec, n_bootstrap=200, seed=1)
    expected = [
        "jacobian",
        "parity",
        "mu_size",
        "mu_size_err",
        "mu_flux_F150W",
        "mu_flux_err_F150W",
        "mu_flux_F200W",
        "mu_flux_err_F200W",
        "mu_flux",
        "mu_flux_err",
        "duality_ratio",
        "snr",
        "snr_paper",
        "anomalous",
        "chromatic_chi2",
        "chromatic_pvalue",
    ]
    for name in expected:
        assert name in res.colnames, name
    np.testing.assert_allclose(res["mu_size"], 1.5, rtol=1e-10)
    np.testing.assert_allclose(res["mu_flux"], 1.5, rtol=1e-10)
    np.testing.assert_allclose(res["duality_ratio"], 1.0, rtol=1e-10)
    assert (res["parity"] == -1).all()
    np.testing.assert_allclose(res["snr"], 0.0, atol=1e-8)
    assert not res["anomalous"].any()
    # the per-band errors: 2 % on each flux -> sqrt(2) * 2 % on the ratio
    np.testing.assert_allclose(
        res["mu_flux_err_F150W"] / res["mu_flux_F150W"], np.sqrt(2) * 0.02, rtol=1e-10
    )
    # two equal-error bands combined: error shrinks by sqrt(2)
    np.testing.assert_allclose(res["mu_flux_err"] / res["mu_flux"], 0.02, rtol=1e-10)
    assert res.meta["bands"] == list(BANDS)
    assert res.meta["duality"]["method"] == "quad"


def test_input_not_modified_and_plain_table_accepted():
    pairs = make_pairs()
    before = pairs.copy()
    plain = Table(pairs)
    res = check_duality(plain, n_bootstrap=20, seed=0)
    assert pairs.colnames == before.colnames
    assert "mu_size" not in plain.colnames
    assert len(res) == len(pairs)
    assert res["mu_flux"].unit is None or res["mu_flux"].unit == u.dimensionless_unscaled


def test_pair_id_added_and_bands_inferred():
    pairs = make_pairs()
    del pairs["pair_id"]
    pairs.meta.clear()
    assert pair_bands(pairs) == list(BANDS)
    res = check_duality(pairs, n_bootstrap=20, seed=0)
    np.testing.assert_array_equal(res["pair_id"], np.arange(1, len(pairs) + 1))
    assert res.colnames[0] == "pair_id"


def test_flux_ratio_combination_matches_hand_calculation():
    pairs = make_pairs(n=5, seed=3)
    pairs["flux_err1_F200W"] *= 3  # unequal weights
    res = flux_ratios(pairs)
    ln, var = [], []
    for band in BANDS:
        f1 = pairs[f"flux1_{band}"].value
        f2 = pairs[f"flux2_{band}"].value
        e1 = pairs[f"flux_err1_{band}"].value
        e2 = pairs[f"flux_err2_{band}"].value
        ln.append(np.log(f1 / f2))
        var.append((e1 / f1) ** 2 + (e2 / f2) ** 2)
        np.testing.assert_allclose(res[f"mu_flux_{band}"], f1 / f2)
    ln, w = np.array(ln), 1 / np.array(var)
    mean = (w * ln).sum(0) / w.sum(0)
    np.testing.assert_allclose(res["mu_flux"], np.exp(mean), rtol=1e-12)
    np.testing.assert_allclose(res["mu_flux_err"], np.exp(mean) / np.sqrt(w.sum(0)), rtol=1e-12)
    np.testing.assert_allclose(res["chromatic_chi2"], (w * (ln - mean) ** 2).sum(0), rtol=1e-10)
    assert (res["chromatic_dof"] == 1).all()


def test_chromatic_inconsistency_detected():
    pairs = make_pairs(noise=False)
    pairs["flux1_F200W"][4] *= 1.5  # a band-dependent ratio: not one lensed source
    res = check_duality(pairs, n_bootstrap=20, seed=0)
    assert res["chromatic_pvalue"][4] < 1e-6
    others = np.delete(np.asarray(res["chromatic_pvalue"]), 4)
    np.testing.assert_allclose(others, 1.0)


def test_nan_flux_drops_band_for_that_pair():
    pairs = make_pairs(noise=False)
    pairs["flux1_F150W"][2] = np.nan
    res = check_duality(pairs, n_bootstrap=20, seed=0)
    assert np.isnan(res["mu_flux_F150W"][2])
    np.testing.assert_allclose(res["mu_flux"][2], res["mu_flux_F200W"][2])
    assert res["chromatic_dof"][2] == 0
    np.testing.assert_allclose(res["mu_flux_err"][2], res["mu_flux_err_F200W"][2])
    for band in BANDS:
        pairs[f"flux2_{band}"][3] = np.nan
    with pytest.warns(LensdualWarning, match=r"no band has a finite flux ratio for row\(s\) \[3\]"):
        res = check_duality(pairs, n_bootstrap=20, seed=0)
    assert np.isnan(res["snr"][3]) and not res["anomalous"][3]


def test_snr_definitions():
    pairs = make_pairs(noise=False)
    pairs["flux2_F150W"][0] *= 3
    pairs["flux2_F200W"][0] *= 3
    res = check_duality(pairs, sigma_pos=0.02 * u.arcsec, n_bootstrap=300, seed=2)
    R = res["duality_ratio"]
    ln_size = 0.5 * np.log(res["mu_size_p84"] / res["mu_size_p16"])
    ln_flux = res["mu_flux_err"] / res["mu_flux"]
    np.testing.assert_allclose(res["snr"], np.abs(np.log(R)) / np.hypot(ln_size, ln_flux))
    np.testing.assert_allclose(
        res["snr_paper"], np.abs(R - 1) / (R * res["mu_size_err"] / res["mu_size"])
    )
    np.testing.assert_allclose(R[0], 1 / 3, rtol=1e-8)
    assert res["anomalous"][0] and res["anomalous"].sum() == 1
    paper = check_duality(
        pairs,
        sigma_pos=0.02 * u.arcsec,
        n_bootstrap=300,
        seed=2,
        snr_definition="paper",
        snr_threshold=1e6,
    )
    assert not paper["anomalous"].any()
    assert paper.meta["duality"]["snr_definition"] == "paper"


def test_mu_size_matches_estimator():
    pairs = make_pairs()
    res = check_duality(pairs, method="2v", sigma_pos=0.01 * u.arcsec, n_bootstrap=50, seed=4)
    theta1 = np.column_stack([pairs["x1"], pairs["y1"]])
    theta2 = np.column_stack([pairs["x2"], pairs["y2"]])
    ref = size_magnification(
        theta1, theta2, "2v", sigma_pos=0.01 * u.arcsec, n_bootstrap=50, seed=4
    )
    np.testing.assert_array_equal(res["mu_size"], ref["mu_size"])
    np.testing.assert_array_equal(res["mu_size_err"], ref["mu_size_err"])


def test_flux_units_converted():
    pairs = make_pairs(noise=False)
    pairs["flux2_F150W"] = pairs["flux2_F150W"].to(u.uJy)
    pairs["flux_err2_F150W"] = pairs["flux_err2_F150W"].to(u.mJy)
    res = check_duality(pairs, n_bootstrap=10, seed=0)
    np.testing.assert_allclose(res["mu_flux_F150W"], 1.5, rtol=1e-10)


@pytest.mark.parametrize(
    ("change", "exc", "match"),
    [
        (
            lambda t: t.remove_column("flux_err2_F200W"),
            ValueError,
            r"lacks the column\(s\) \['flux_err2_F200W'\] of band 'F200W'",
        ),
        (lambda t: t.remove_column("y2"), ValueError, r"lacks the position column\(s\) \['y2'\]"),
        (
            lambda t: t.__setitem__("x1", t["x1"].value),
            TypeError,
            "pairs column 'x1' must have angular units",
        ),
        (
            lambda t: t.__setitem__("x2", t["x2"].value * u.m),
            TypeError,
            "pairs column 'x2' must have angular units",
        ),
        (
            lambda t: t["flux1_F150W"].__setitem__(3, -1 * u.nJy),
            ValueError,
            r"flux1_F150W must be positive for a flux ratio; non-positive at row\(s\) \[3\]",
        ),
        (
            lambda t: t["flux2_F200W"].__setitem__(0, 0 * u.nJy),
            ValueError,
            "flux2_F200W must be positive",
        ),
        (
            lambda t: t["flux_err1_F150W"].__setitem__(1, 0 * u.nJy),
            ValueError,
            r"flux_err1_F150W must be finite and positive; bad at row\(s\) \[1\]",
        ),
        (
            lambda t: t.__setitem__("flux2_F150W", t["flux2_F150W"].value * u.s),
            ValueError,
            "flux units of band 'F150W' do not match",
        ),
        (
            lambda t: t.__setitem__("flux2_F150W", t["flux2_F150W"].value),
            ValueError,
            "flux units of band 'F150W' do not match",
        ),
        (lambda t: t.meta.__setitem__("bands", ["F150W", "F444W"]), ValueError, "of band 'F444W'"),
        (lambda t: t.meta.__setitem__("bands", []), ValueError, "the pairs table names no bands"),
    ],
)
def test_bad_tables(change, exc, match):
    pairs = make_pairs()
    change(pairs)
    with pytest.raises(exc, match=match):
        check_duality(pairs, n_bootstrap=5)


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"snr_definition": "linear"}, ValueError, "snr_definition must be one of"),
        ({"snr_threshold": -1}, ValueError, "snr_threshold must be >= 0"),
        ({"snr_threshold": "3"}, TypeError, "snr_threshold must be a real number"),
        ({"method": "foo"}, ValueError, "method must be one of"),
        ({"sigma_pos": -1 * u.arcsec}, ValueError, "sigma_pos must be finite and >= 0"),
        ({"n_bootstrap": 0}, ValueError, "n_bootstrap must be >= 1"),
    ],
)
def test_bad_arguments(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        check_duality(make_pairs(), **kwargs)


def test_not_a_table():
    with pytest.raises(TypeError, match="pairs must be an astropy Table or QTable"):
        check_duality({"x1": [1, 2, 3]})


def test_an_identity_map_is_refused():
    """The L1 positions given for L2 (an identity map with zero residuals: every
    mu_size and flux ratio 1 by construction) are refused, and so are positions
    within 1 mas of each other (the pipeline's rule for copies of one image); a
    translation by 1.5 mas is a map like any other."""
    from lensdual.exceptions import PipelineError, SameImageError

    pairs = make_pairs()
    pairs["x2"], pairs["y2"] = pairs["x1"], pairs["y1"]
    with pytest.raises(SameImageError, match="arcs L1 and L2 are the same image: all 15 "
                                             "pairs with both positions have their two "
                                             "images within 1 mas"):
        _check_duality(pairs)  # the adaptive default
    assert issubclass(SameImageError, ValueError) and issubclass(SameImageError, PipelineError)
    rng = np.random.default_rng(1)
    jitter = rng.uniform(-0.6, 0.6, (2, len(pairs))) * u.mas
    pairs["x2"], pairs["y2"] = pairs["x1"] + jitter[0], pairs["y1"] + jitter[1]
    pairs["x2"][0] = np.nan * u.arcsec  # a pair without its L2 position changes nothing
    with pytest.raises(SameImageError, match="all 14 pairs with both positions"):
        check_duality(pairs, n_bootstrap=5)
    pairs["x2"], pairs["y2"] = pairs["x1"] + 1.5 * u.mas, pairs["y1"]
    res = check_duality(pairs, n_bootstrap=5, sigma_pos=0.1 * u.mas)
    np.testing.assert_allclose(res["mu_size"], 1.0, rtol=1e-6)


def test_verdict_says_which_flags_the_null_calibration_confirms():
    """A flag the null calibration confirms (empirical p at most the threshold's p)
    is counted as confirmed; the verdict says when the realisations are too few to
    confirm any flag; each flagged pair carries its empirical p-value."""
    from lensdual.pipeline import _add_null_calibration, verdict

    rng = np.random.default_rng(4)
    t2 = rng.uniform(-1, 1, (12, 2))
    t1 = t2 @ np.array([[1.4, 0.2], [0.1, -0.8]]).T
    flux1 = np.full(12, 100.0) * abs(1.4 * -0.8 - 0.2 * 0.1)
    flux1[5] *= 2.0  # pair 6: twice too bright on L1
    flux1[9] *= 0.5  # pair 10: twice too faint
    pairs = QTable({"pair_id": np.arange(1, 13),
                    "x1": t1[:, 0] * u.arcsec, "y1": t1[:, 1] * u.arcsec,
                    "x2": t2[:, 0] * u.arcsec, "y2": t2[:, 1] * u.arcsec,
                    "flux1_F150W": flux1, "flux2_F150W": np.full(12, 100.0),
                    "flux_err1_F150W": 0.01 * flux1, "flux_err2_F150W": np.full(12, 1.0)})
    sigma = 0.002 * u.arcsec
    res = _check_duality(pairs, sigma_pos=sigma)  # the adaptive default, as the pipeline
    assert res.meta["duality"]["method"] == "adaptive"
    assert np.flatnonzero(res["anomalous"]).tolist() == [5, 9]
    p_thr = res.meta["duality"]["p_threshold"]
    few = res.copy()
    _add_null_calibration(few, pairs, sigma, 100, 3.0, 0)
    text = verdict(few, sigma)
    assert "cannot confirm a flag at this threshold: run at least 370" in text
    assert "empirical p = 0.99% against the null" in text  # 1 / 101: no null SNR as large
    _add_null_calibration(res, pairs, sigma, 400, 3.0, 0)
    p_emp = np.asarray(res["p_value_empirical"])[[5, 9]]
    assert np.all(p_emp < 2 / 401) and np.all(p_emp <= p_thr)  # no null SNR as large
    text = verdict(res, sigma)
    assert "The null calibration confirms 2 of the 2 flags (empirical p <= 0.27%)." in text
    assert "look at it closely" not in text and "optimistic" not in text
    # a flag the null does not confirm gets the warning
    res["p_value_empirical"][9] = 0.01
    text = verdict(res, sigma)
    assert "confirms 1 of the 2 flags" in text and "look at it closely" in text
    res["anomalous"][5] = False
    assert "does not confirm this flag" in verdict(res, sigma)
    res["anomalous"][[5, 9]] = [True, False]
    assert "The null calibration confirms this flag" in verdict(res, sigma)
    # where the null map interpolates the pairs its p-values are called uncertain
    assert "interpolates the pairs" not in verdict(res, sigma)
    res.meta["duality"]["null_calibration"]["map_interpolates"] = True
    assert "interpolates the pairs: the constellation does not sample" in verdict(res, sigma)


def test_parity_reported_only_where_its_sign_is_determined():
    """A map of det J near 0 with noisy positions: parity is sign(det J) where
    1 / ln_mu_size_err reaches snr_threshold, and 0 (undetermined) elsewhere."""
    pairs = make_pairs(n=20, det=-0.08, seed=3)
    rng = np.random.default_rng(5)
    for c in ("x1", "y1", "x2", "y2"):
        pairs[c] = pairs[c] + rng.normal(0.0, 0.03, len(pairs)) * u.arcsec
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = _check_duality(pairs, "adaptive", sigma_pos=0.03 * u.arcsec)
        res0 = _check_duality(pairs, "adaptive", sigma_pos=0.03 * u.arcsec, snr_threshold=0.0)
    testable = np.isin(np.asarray(res["mu_size_status"]), ("ok", "misfit"))
    ln_err = np.asarray(res["ln_mu_size_err"], dtype=float)
    np.testing.assert_allclose(res["parity_snr"][testable], 1.0 / ln_err[testable])
    assert np.isnan(res["parity_snr"][~testable]).all()
    sign = np.sign(np.linalg.det(np.asarray(res["jacobian"], dtype=float))).astype(int)
    determined = testable & (1.0 / ln_err >= 3.0)
    assert determined.any() and (testable & ~determined).any()
    np.testing.assert_array_equal(res["parity"], np.where(determined, sign, 0))
    np.testing.assert_array_equal(res0["parity"], np.where(testable, sign, 0))
