"""The profile-likelihood duality SNR (snr_definition="profile") and the
Jacobian covariance of the adaptive estimator it reads."""

import warnings

import numpy as np
import pytest
from astropy import units as u
from scipy.optimize import minimize

from lensdual._profile_kernels import profile_snr as _kernel
from lensdual.duality import check_duality, flux_ratios, profile_snr
from lensdual.estimators import size_magnification
from lensdual.estimators.core import inverse_covariance
from lensdual.exceptions import EstimatorWarning
from lensdual.simulation import clean_constellation


def _reference_t(jac, cov, var_rest, ln_r, rng, starts=25):
    """The profile statistic by direct minimisation over J (Nelder-Mead from
    many starts, both parities reachable), plain numpy/scipy."""
    ci = np.linalg.inv(cov)
    best = np.inf
    for s in range(starts):
        x0 = jac + (0.0 if s == 0 else 1.0) * rng.multivariate_normal(np.zeros(4), cov)

        def f(x):
            d = x[0] * x[3] - x[1] * x[2]
            if d == 0.0:
                return 1e300
            r = x - jac
            return r @ ci @ r + (ln_r - np.log(abs(d))) ** 2 / var_rest

        res = minimize(f, x0, method="Nelder-Mead",
                       options={"xatol": 1e-11, "fatol": 1e-13, "maxiter": 40000})
        best = min(best, res.fun)
    return np.sqrt(best)


def _run(jac, cov, var_rest, ln_r):
    out = np.empty(len(jac))
    _kernel(np.ascontiguousarray(jac), np.ascontiguousarray(cov), np.asarray(var_rest, float),
            np.asarray(ln_r, float), out)
    return out


def test_kernel_matches_direct_minimisation():
    rng = np.random.default_rng(3)
    jac, cov, v, lr = [], [], [], []
    for _ in range(10):
        j = rng.normal(size=4)
        a = rng.normal(size=(4, 4)) * rng.uniform(0.05, 0.4)
        jac.append(j)
        cov.append(a @ a.T + 0.005 * np.eye(4))
        v.append(rng.uniform(0.001, 0.1))
        lr.append(np.log(abs(j[0] * j[3] - j[1] * j[2])) + rng.normal() * 0.8)
    got = _run(np.array(jac), np.array(cov), v, lr)
    ref = [_reference_t(*args, rng) for args in zip(jac, cov, v, lr, strict=True)]
    np.testing.assert_allclose(got, ref, rtol=2e-5, atol=1e-7)


def test_linear_limit_equals_the_log_snr():
    """With a small error of ln|det J| the profile SNR is the linearised one."""
    rng = np.random.default_rng(5)
    n = 50
    jac = rng.normal(size=(n, 4)) + np.array([2.0, 0.0, 0.0, 1.0])
    det = jac[:, 0] * jac[:, 3] - jac[:, 1] * jac[:, 2]
    cov = np.tile(np.eye(4) * 1e-12, (n, 1, 1))
    g = np.column_stack([jac[:, 3], -jac[:, 2], -jac[:, 1], jac[:, 0]]) / det[:, None]
    var_j = np.einsum("ni,nij,nj->n", g, cov, g)
    v = np.full(n, 1e-12)
    lr = np.log(np.abs(det)) + rng.normal(size=n) * np.sqrt(var_j + v) * 3
    lin = np.abs(lr - np.log(np.abs(det))) / np.sqrt(var_j + v)
    np.testing.assert_allclose(_run(jac, cov, v, lr), lin, rtol=2e-3)


def test_false_alarm_rate_where_ln_det_is_not_gaussian():
    """Gaussian Jacobian estimates whose determinant is poorly known (a fold:
    one small singular value): the profile SNR keeps the nominal rate of
    |Z| > 3, the linearised one (its error taken at the estimate) does not."""
    rng = np.random.default_rng(11)
    j_true = np.array([3.0, 0.0, 0.0, 0.25])  # det 0.75
    cov = np.diag([0.02, 0.01, 0.01, 0.005]) * 0.8
    n = 40000
    jac = j_true + rng.multivariate_normal(np.zeros(4), cov, n)
    det = jac[:, 0] * jac[:, 3] - jac[:, 1] * jac[:, 2]
    keep = det > 0
    jac, det = jac[keep], det[keep]
    v = np.full(len(det), 1e-4)
    lr = np.full(len(det), np.log(0.75)) + rng.normal(size=len(det)) * 1e-2
    covs = np.broadcast_to(cov, (len(det), 4, 4))
    prof = _run(jac, covs, v, lr)
    g = np.column_stack([jac[:, 3], -jac[:, 2], -jac[:, 1], jac[:, 0]]) / det[:, None]
    lin = np.abs(lr - np.log(det)) / np.sqrt(np.einsum("ni,ij,nj->n", g, cov, g) + v)
    nominal = 0.0027
    assert np.mean(lin > 3) > 2 * nominal
    assert abs(np.mean(prof > 3) - nominal) < 0.0012


def test_other_parity_is_reached_when_the_determinant_is_near_zero():
    """An estimate whose determinant sits within its noise of 0 is consistent
    with a flux ratio of either parity: the SNR is small, not the distance to
    the estimate's own sign."""
    jac = np.array([[1.0, 0.0, 0.0, 0.01]])
    cov = np.eye(4)[None] * 0.01  # det's error ~0.1: both signs within 1 sigma
    out = _run(jac, cov, [1e-4], [np.log(0.02)])
    ref = _reference_t(jac[0], cov[0], 1e-4, np.log(0.02), np.random.default_rng(0))
    assert out[0] < 1.0
    np.testing.assert_allclose(out, ref, rtol=1e-4)


def test_bad_inputs_give_nan():
    jac = np.array([[1.0, 0.0, 0.0, 1.0]] * 3)
    cov = np.array([np.eye(4) * 0.01, np.full((4, 4), np.nan), np.zeros((4, 4))])
    out = _run(jac, cov, [0.01, 0.01, 0.01], [0.1, 0.1, 0.1])
    assert np.isfinite(out[0]) and np.isnan(out[1:]).all()
    assert np.isnan(_run(jac[:1], cov[:1], [np.nan], [0.1])).all()
    assert np.isnan(_run(jac[:1], cov[:1], [0.01], [np.nan])).all()


def _adaptive_table(family, n, sig, seed=0):
    t = clean_constellation(family, n, seed=seed)
    rng = np.random.default_rng(seed)
    o1 = np.column_stack([t["x1"].to_value(u.arcsec), t["y1"].to_value(u.arcsec)])
    o2 = np.column_stack([t["x2"].to_value(u.arcsec), t["y2"].to_value(u.arcsec)])
    o1 = o1 + sig * rng.standard_normal(o1.shape)
    o2 = o2 + sig * rng.standard_normal(o2.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tab = size_magnification(o1 * u.arcsec, o2 * u.arcsec, "adaptive",
                                 sigma_pos=sig * u.arcsec)
    return o1, o2, tab


def _ln_det_var(tab):
    jac = np.asarray(tab["jacobian"]).reshape(-1, 4)
    det = jac[:, 0] * jac[:, 3] - jac[:, 1] * jac[:, 2]
    g = np.column_stack([jac[:, 3], -jac[:, 2], -jac[:, 1], jac[:, 0]]) / det[:, None]
    return np.einsum("ni,nij,nj->n", g, np.asarray(tab["jacobian_cov"]), g)


def test_jacobian_covariance_carries_the_fit_error():
    """For "ok" pairs of a gently bent map the error of ln mu_size is the
    Jacobian's own (the centre and alias terms are small): g^T C g equals
    its square to within those terms, and never exceeds it; C is symmetric
    and positive definite."""
    _, _, tab = _adaptive_table("cluster_fold", 20, 0.005)
    ok = np.asarray(tab["mu_size_status"]) == "ok"
    assert ok.sum() >= 15
    cov = np.asarray(tab["jacobian_cov"])[ok]
    np.testing.assert_allclose(cov, np.swapaxes(cov, 1, 2), rtol=1e-12, atol=0)
    assert (np.linalg.eigvalsh(cov) > 0).all()
    ratio = _ln_det_var(tab)[ok] / np.asarray(tab["ln_mu_size_err"])[ok] ** 2
    assert (ratio <= 1 + 1e-9).all()
    assert np.median(ratio) > 0.95


def test_jacobian_covariance_turns_with_the_l1_frame():
    """Rotating arc L1 by phi turns J into R J and C into (R x I) C (R x I)^T
    (the rotated-frame covariance of the kernel taken back to the sky)."""
    o1, o2, tab = _adaptive_table("smacs_lenstool", 12, 0.005, seed=2)
    phi = 0.7
    r = np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rot = size_magnification((o1 @ r.T) * u.arcsec, o2 * u.arcsec, "adaptive",
                                 sigma_pos=0.005 * u.arcsec)
    same = np.asarray(rot["mu_size_status"]) == np.asarray(tab["mu_size_status"])
    assert same.sum() >= 10
    big = np.kron(r, np.eye(2))
    expect = big @ np.asarray(tab["jacobian_cov"])[same] @ big.T
    np.testing.assert_allclose(np.asarray(rot["jacobian_cov"])[same], expect,
                               rtol=1e-6, atol=1e-14)


def test_inverse_covariance_matches_finite_differences():
    rng = np.random.default_rng(1)
    k = rng.normal(size=(2, 2)) + 2 * np.eye(2)
    cov_k = np.diag([1.0, 2.0, 3.0, 4.0]) * 1e-4
    j = np.linalg.inv(k)
    # the linear map vec K -> vec K^-1 by central differences
    t = np.empty((4, 4))
    h = 1e-6
    for m in range(4):
        dk = np.zeros(4)
        dk[m] = h
        t[:, m] = ((np.linalg.inv(k + dk.reshape(2, 2)) - np.linalg.inv(k - dk.reshape(2, 2)))
                   / (2 * h)).ravel()
    np.testing.assert_allclose(inverse_covariance(j[None], cov_k[None])[0], t @ cov_k @ t.T,
                               rtol=1e-6)


def test_check_duality_profile_definition():
    """snr_definition="profile" adds snr_profile and flags by it; on a clean
    cluster-scale constellation at 5 mas it is close to the log SNR."""
    t = clean_constellation("cluster_fold", 15, seed=4)
    out = check_duality(t, sigma_pos=0.005 * u.arcsec, snr_definition="profile", seed=0)
    assert out.meta["duality"]["test"] == "geometric"  # "auto": no joint profile test
    log = check_duality(t, sigma_pos=0.005 * u.arcsec, seed=0, test="geometric",
                        snr_definition="log")
    assert "snr_profile" in out.colnames and "snr_profile" not in log.colnames
    tested = np.asarray(out["tested"])
    assert tested.sum() >= 12
    np.testing.assert_allclose(np.asarray(out["snr_profile"])[tested],
                               np.asarray(log["snr"])[tested], rtol=0.15, atol=0.05)
    sig = np.asarray(out["significance"])[tested]
    assert (sig < 3).all()
    assert out.meta["duality"]["snr_definition"] == "profile"
    # the same function on the estimator's table
    ln_r = np.log(np.asarray(out["mu_flux"], dtype=float))
    size = size_magnification(np.column_stack([t["x1"], t["y1"]]),
                              np.column_stack([t["x2"], t["y2"]]), "adaptive",
                              sigma_pos=0.005 * u.arcsec)
    err = np.asarray(flux_ratios(t)["ln_mu_flux_err"], dtype=float)
    np.testing.assert_allclose(profile_snr(size, ln_r, err)[tested],
                               np.asarray(out["snr_profile"])[tested], rtol=1e-6)


@pytest.mark.parametrize("definition", ["profile", "conservative"])
def test_profile_definition_needs_the_adaptive_method(definition):
    t = clean_constellation("cluster_fold", 10, seed=0)
    with pytest.raises(ValueError, match=f"snr_definition='{definition}' needs method 'adaptive'"):
        check_duality(t, "quad", sigma_pos=0.005 * u.arcsec, snr_definition=definition)


def test_conservative_definition_is_the_smaller_snr():
    """snr_definition="conservative" flags by the smaller of the log and the
    profile SNR, with the log SNR's degrees of freedom: on a compact
    galaxy-scale constellation at 5 mas, where the two differ, its flags are
    those both definitions raise."""
    from lensdual.duality import duality_significance
    from lensdual.simulation import noisy_constellation

    clean = clean_constellation("galaxy_epl_compact", 30, seed=2)
    t = noisy_constellation(clean, sigma_pos=5 * u.mas, flux_rel_err=0.02, seed=5)
    # a few pairs brighter on L1 and fainter, so that both sides are exercised
    for band in ("F150W", "F200W"):
        t[f"flux1_{band}"][:6] *= 4.0
        t[f"flux1_{band}"][6:12] *= 0.25
    kw = dict(sigma_pos=5 * u.mas, seed=0, test="geometric")
    with warnings.catch_warnings():
        # pairs where no local polynomial fits are reported untestable
        warnings.simplefilter("ignore", EstimatorWarning)
        cons = check_duality(t, snr_definition="conservative", **kw)
        log = check_duality(t, snr_definition="log", **kw)
        prof = check_duality(t, snr_definition="profile", **kw)
    tested = np.asarray(cons["tested"])
    assert tested.sum() >= 20
    assert np.array_equal(tested, np.asarray(log["tested"]))
    snr_log = np.asarray(log["snr"], dtype=float)
    snr_prof = np.asarray(prof["snr_profile"], dtype=float)
    np.testing.assert_allclose(np.asarray(cons["snr_profile"]), snr_prof, rtol=1e-12)
    smaller = np.fmin(snr_log, snr_prof)[tested]
    # the two SNRs differ on this lens, on some pairs by more than 10 %
    assert np.any(np.abs(snr_prof - snr_log)[tested] > 0.1 * snr_log[tested])
    dof = np.asarray(log["snr_dof"], dtype=float)[tested]
    np.testing.assert_allclose(np.asarray(cons["significance"])[tested],
                               duality_significance(smaller, dof), rtol=1e-12)
    flags = np.asarray(cons["anomalous"])
    np.testing.assert_array_equal(flags, np.asarray(log["anomalous"])
                                  & np.asarray(prof["anomalous"]))
    assert flags.any()
    assert cons.meta["duality"]["snr_definition"] == "conservative"


def _reference_joint_t(jac, cov, var_g, ln_r, v_r, f, v_f, rng, starts=25):
    """The joint test's profile statistic by direct minimisation over the
    Jacobian and the common ln mu, plain numpy/scipy: the flux ratio tied to
    the common ln mu against free."""
    ci = np.linalg.inv(cov)

    def fit(with_flux):
        best = np.inf
        for s in range(starts):
            x0 = np.append(jac + (0.0 if s == 0 else 1.0)
                           * rng.multivariate_normal(np.zeros(4), cov), f)

            def obj(x):
                d = x[0] * x[3] - x[1] * x[2]
                if d == 0.0:
                    return 1e300
                r = x[:4] - jac
                h = x[4]
                out = r @ ci @ r + (h - np.log(abs(d))) ** 2 / var_g + (f - h) ** 2 / v_f
                return out + ((ln_r - h) ** 2 / v_r if with_flux else 0.0)

            res = minimize(obj, x0, method="Nelder-Mead",
                           options={"xatol": 1e-11, "fatol": 1e-13, "maxiter": 60000})
            best = min(best, res.fun)
        return best

    return np.sqrt(max(fit(True) - fit(False), 0.0))


def test_joint_profile_snr_matches_direct_minimisation():
    """The joint test's profile SNR (geometry and field, snr_definition
    "conservative") is the likelihood ratio of the flux ratio tied to the
    common ln mu, found here by brute force; with the geometry alone it is the
    geometric profile SNR."""
    from lensdual.duality import _joint_profile_snr, _profile_of

    rng = np.random.default_rng(8)
    n = 6
    jac = rng.normal(size=(n, 4)) + np.array([2.0, 0.0, 0.0, -0.5])
    cov = np.array([(a := rng.normal(size=(4, 4)) * 0.15) @ a.T + 0.004 * np.eye(4)
                    for _ in range(n)])
    det = jac[:, 0] * jac[:, 3] - jac[:, 1] * jac[:, 2]
    g = np.column_stack([jac[:, 3], -jac[:, 2], -jac[:, 1], jac[:, 0]]) / det[:, None]
    var_jac = np.einsum("ni,nij,nj->n", g, cov, g)
    var_g = rng.uniform(0.002, 0.02, n)  # the geometric error's other part (model error)
    size = {"jacobian": jac.reshape(n, 2, 2), "jacobian_cov": cov,
            "ln_mu_size_err": np.sqrt(var_jac + var_g)}
    ln_r = np.log(np.abs(det)) + rng.normal(size=n) * 0.5
    ln_r_err = np.full(n, 0.03)
    f = np.log(np.abs(det)) + rng.normal(size=n) * 0.2
    f_var = rng.uniform(0.002, 0.01, n)
    g_ok = np.ones(n, bool)
    f_ok = np.array([True] * 4 + [False] * 2)

    def profile(h, sd, rows=None):
        return profile_snr(size, h, sd)

    got = _joint_profile_snr(profile, ln_r, ln_r_err, f, f_var, g_ok, f_ok)
    # the library's callable, which runs the kernel on the rows needed only
    np.testing.assert_allclose(_joint_profile_snr(_profile_of(size), ln_r, ln_r_err, f, f_var,
                                                  g_ok, f_ok), got, rtol=1e-12)
    for i in range(4):
        ref = _reference_joint_t(jac[i], cov[i], var_g[i], ln_r[i], ln_r_err[i] ** 2, f[i],
                                 f_var[i], rng)
        np.testing.assert_allclose(got[i], ref, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(got[4:], profile_snr(size, ln_r, ln_r_err)[4:], rtol=1e-12)
    # no geometry: no profile SNR
    assert np.isnan(_joint_profile_snr(profile, ln_r, ln_r_err, f, f_var, ~g_ok, f_ok)).all()


def test_joint_test_with_the_conservative_definition():
    """test="joint" with snr_definition="conservative": the joint SNR where the
    geometry is tested is at most the linearised joint SNR of the same
    prediction, and a clear anomaly is flagged by both."""
    from lensdual.simulation import noisy_constellation

    clean = clean_constellation("cluster_fold", 20, seed=3)
    t = noisy_constellation(clean, sigma_pos=5 * u.mas, flux_rel_err=0.02, seed=1)
    for band in ("F150W", "F200W"):
        t[f"flux1_{band}"][4] *= 1.5
    kw = dict(sigma_pos=5 * u.mas, test="joint")
    log = check_duality(t, snr_definition="log", **kw)
    cons = check_duality(t, snr_definition="conservative", **kw)
    assert cons.meta["duality"]["snr_definition"] == "conservative"
    assert "jacobian_cov" in cons.colnames and "jacobian_cov" not in log.colnames
    assert cons["anomalous"][4] and log["anomalous"][4]
    tested = np.asarray(cons["tested"]) & np.asarray(log["tested"])
    geo = np.isin(np.asarray(cons["joint_basis"]), ("geometry", "geometry+field"))
    same = tested & geo & (np.asarray(cons["joint_basis"]) == np.asarray(log["joint_basis"]))
    assert same.sum() >= 10
    # the same prediction where the left-out pairs agree: the SNR can only drop
    pred_same = np.isclose(np.asarray(cons["ln_mu_predicted"], float),
                           np.asarray(log["ln_mu_predicted"], float), rtol=0, atol=1e-12)
    both = same & pred_same
    assert both.sum() >= 10
    assert np.all(np.asarray(cons["snr"])[both] <= np.asarray(log["snr"])[both] + 1e-12)
    # close to the linearised SNR on this cluster-scale fold at 5 mas
    np.testing.assert_allclose(np.asarray(cons["snr"])[both], np.asarray(log["snr"])[both],
                               rtol=0.2, atol=0.1)


def test_conservative_falls_back_to_the_log_snr_without_a_profile():
    """Where a pair's Jacobian covariance gives no profile SNR (not positive
    definite), the conservative SNR is the log one; elsewhere the smaller."""
    from astropy.table import QTable

    from lensdual.duality import _chosen_snr, _profile_of

    jac = np.array([[[2.0, 0.1], [0.2, -0.5]]] * 3)
    cov = np.array([np.eye(4) * 0.04, np.full((4, 4), np.nan), np.eye(4) * 0.04])
    size = {"jacobian": jac, "jacobian_cov": cov, "ln_mu_size_err": np.full(3, 0.3)}
    det = abs(np.linalg.det(jac[0]))
    flux = {"mu_flux": np.array([det * 0.3, det * 0.3, det * 1.01]),
            "ln_mu_flux_err": np.full(3, 0.02)}
    tab = QTable({"snr": np.array([4.0, 4.0, 0.05])})
    got = _chosen_snr(tab, size, flux, "conservative", _profile_of(size))
    prof = np.asarray(tab["snr_profile"])
    assert np.isnan(prof[1]) and np.isfinite(prof[[0, 2]]).all()
    assert got[1] == 4.0
    np.testing.assert_array_equal(got[[0, 2]], np.fmin([4.0, 0.05], prof[[0, 2]]))
    assert got[0] < 4.0  # the profile is the smaller where ln|det J| is far from log-normal


def test_the_other_parity_is_searched_as_far_as_it_can_win():
    """A profile whose minimum lies on the other parity more than 8 noise widths of
    ``ln R`` below it (a far outlier): the kernel's T is no larger than the objective
    at an explicit Jacobian of that parity (found by a direct minimisation), so a
    large SNR is not overstated."""
    jac = np.array([-0.44561255527906357, 0.09020553428838174, -0.03182167603432528,
                    -0.3557159415015701])
    cov = np.array([[7.3845667959597022e-03, 1.2520370360992286e-02,
                     -4.6015486388528546e-05, 7.0849539617795433e-04],
                    [1.2520370360992286e-02, 5.5709535967646183e-02,
                     2.9681842764619083e-02, 1.9260438635374300e-02],
                    [-4.6015486388528546e-05, 2.9681842764619083e-02,
                     4.7461328990402042e-02, 2.4973578609249897e-02],
                    [7.0849539617795433e-04, 1.9260438635374300e-02,
                     2.4973578609249897e-02, 1.4270210981362700e-02]])
    v, ln_r = 0.3, 6.176018828332776
    # a Jacobian of the other parity (det < 0, the estimate's is > 0), ln|det| 10.4
    # noise widths below ln R
    other = np.array([-0.3023692675691049, 1.3131532685459248, 1.175337124273538,
                      0.3299461830282554])
    det = other[0] * other[3] - other[1] * other[2]
    assert det < 0 < jac[0] * jac[3] - jac[1] * jac[2]
    assert (ln_r - np.log(abs(det))) / np.sqrt(v) > 8
    d = other - jac
    objective = d @ np.linalg.solve(cov, d) + (ln_r - np.log(abs(det))) ** 2 / v
    out = np.empty(1)
    _kernel(jac[None], cov[None], np.array([v]), np.array([ln_r]), out)
    assert out[0] <= np.sqrt(objective) + 1e-9
    assert out[0] == pytest.approx(np.sqrt(objective), rel=1e-6)
