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
    log = check_duality(t, sigma_pos=0.005 * u.arcsec, seed=0)
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


def test_profile_definition_needs_the_adaptive_method():
    t = clean_constellation("cluster_fold", 10, seed=0)
    with pytest.raises(ValueError, match="needs method 'adaptive'"):
        check_duality(t, "quad", sigma_pos=0.005 * u.arcsec, snr_definition="profile")
