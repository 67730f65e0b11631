"""The adaptive estimator, the calibrated duality test and the null calibration."""

from concurrent.futures import ThreadPoolExecutor

import _reference as ref
import numpy as np
import pytest
from astropy import units as u
from astropy.table import QTable
from scipy.stats import chi2, norm
from scipy.stats import t as t_dist

from lensdual.duality import (
    check_duality,
    duality_significance,
    gaussian_p_value,
    holm_adjust,
    null_calibration,
)
from lensdual.estimators import _adaptive, relative_jacobian, size_magnification
from lensdual.estimators.core import _chi2_critical
from lensdual.exceptions import EstimatorWarning

# ------------------------------------------------------------------------------- helpers


def _curved_map(t2):
    """A smooth, curved L2 -> L1 map with its exact Jacobian (fold-like parity)."""
    x, y = t2[:, 0], t2[:, 1]
    t1 = np.column_stack([
        0.8 * x + 0.2 * y + 0.06 * x**2 - 0.04 * x * y + 0.02 * y**3,
        0.1 * x - 0.7 * y + 0.05 * y**2 + 0.03 * x**2 * y,
    ])
    jac = np.empty((len(x), 2, 2))
    jac[:, 0, 0] = 0.8 + 0.12 * x - 0.04 * y
    jac[:, 0, 1] = 0.2 - 0.04 * x + 0.06 * y**2
    jac[:, 1, 0] = 0.1 + 0.06 * x * y
    jac[:, 1, 1] = -0.7 + 0.1 * y + 0.03 * x**2
    return t1, jac


def _constellation(n, seed, span=1.0):
    rng = np.random.default_rng(seed)
    t2 = rng.uniform(-span, span, (n, 2))
    t1, jac = _curved_map(t2)
    return t1, t2, np.abs(np.linalg.det(jac))


def _kernel_one_pass(t1, t2, s1, s2):
    n = len(t1)
    pilot = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "quad")
    crit = _chi2_critical(n)
    jac = np.empty((n, 2, 2))
    sd = np.empty(n)
    st = np.empty(n, dtype=np.int64)
    dof = np.empty(n)
    _adaptive.adaptive_jacobians(t1, t2, s1, s2, crit, n, 2.0,
                                 _adaptive.SETTINGS._replace(n_pass=1), jac,
                                 np.empty((n, 4, 4)), sd, st, dof)
    return (jac, sd, st, dof), ref.adaptive(t1, t2, s1, s2, pilot, crit)


def _kernel_matches_twin(t1, t2, s, rng):
    """Add position noise ``s`` to both arcs, check that the kernel's one pass
    equals the numpy twin's (statuses, Jacobians, errors) and return the
    noisy positions, the statuses, the twin's errors and the Quad pilot."""
    n = len(t1)
    t1 = t1 + s[:, None] * rng.standard_normal((n, 2))
    t2 = t2 + s[:, None] * rng.standard_normal((n, 2))
    (jac, sd, st, _), (jac_ref, sd_ref, st_ref, _) = _kernel_one_pass(t1, t2, s, s)
    np.testing.assert_array_equal(st, st_ref)
    np.testing.assert_allclose(jac, jac_ref, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(sd, sd_ref, rtol=1e-6)
    return t1, t2, st, sd_ref, relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "quad")


def _galaxy_fold_8(seed, sig):
    from lensdual.simulation import clean_constellation

    t = clean_constellation("galaxy_fold", 8, seed=seed)
    t1 = np.column_stack([t["x1"].to_value(u.arcsec), t["y1"].to_value(u.arcsec)])
    t2 = np.column_stack([t["x2"].to_value(u.arcsec), t["y2"].to_value(u.arcsec)])
    rng = np.random.default_rng(seed)
    s = np.full(len(t1), sig)
    return (t1 + sig * rng.standard_normal(t1.shape), t2 + sig * rng.standard_normal(t2.shape),
            s, s)


def _quadratic_map_points(n=14, seed=5):
    rng = np.random.default_rng(seed)
    t2 = rng.uniform(-1.0, 1.0, (n, 2))
    x, y = t2.T
    t1 = np.column_stack([1.4 * x + 0.2 * y + 0.15 * x * x - 0.1 * x * y,
                          -0.3 * x + 0.9 * y + 0.05 * y * y + 0.12 * x * y])
    return t1, t2


def _reverse_quadratic_constellation(n=20, seed=3):
    """An L1 -> L2 map that is exactly quadratic and nearly singular at one end:
    the L2 -> L1 map (its inverse, a square root) expands without bound there."""
    rng = np.random.default_rng(seed)
    t1 = np.column_stack([rng.uniform(-1, 1.05, n), rng.uniform(-1, 1, n)])
    x, y = t1.T
    t2 = np.column_stack([x - 0.45 * x**2, 0.6 * y + 0.1 * x**2])
    det_k = (1 - 0.9 * x) * 0.6  # det of the L1 -> L2 Jacobian; mu_true = 1 / det_k
    return t1, t2, 1.0 / det_k


def _pairs(n=16, seed=0, sig=0.003, anomaly=None, flux_err=0.01):
    t1, t2, mu = _constellation(n, seed)
    rng = np.random.default_rng(seed + 1000)
    o1 = t1 + sig * rng.standard_normal(t1.shape)
    o2 = t2 + sig * rng.standard_normal(t2.shape)
    f2 = rng.uniform(1, 10, n)
    f1 = f2 * mu
    if anomaly is not None:
        f1[anomaly[0]] *= anomaly[1]
    e1, e2 = flux_err * f1, flux_err * f2
    f1 = f1 + e1 * rng.standard_normal(n)
    f2 = f2 + e2 * rng.standard_normal(n)
    tab = QTable()
    tab["x1"], tab["y1"] = o1[:, 0] * u.arcsec, o1[:, 1] * u.arcsec
    tab["x2"], tab["y2"] = o2[:, 0] * u.arcsec, o2[:, 1] * u.arcsec
    tab["flux1_F150W"], tab["flux2_F150W"] = f1 * u.nJy, f2 * u.nJy
    tab["flux_err1_F150W"], tab["flux_err2_F150W"] = e1 * u.nJy, e2 * u.nJy
    return tab


# ------------------ the adaptive kernels against their numpy twins (tests/_reference.py)


@pytest.mark.parametrize("bend", [0.0, 1.0])
def test_adaptive_kernel_matches_numpy_reference(bend):
    """Kernel vs the plain-numpy twin, on a smooth map and on one too curved to fit."""
    n = 16
    t1, t2, _ = _constellation(n, 0)
    t1 = t1 + bend * np.column_stack([np.sin(3 * t2[:, 0]), np.cos(3 * t2[:, 1])])
    rng = np.random.default_rng(1)
    s1 = rng.uniform(0.002, 0.006, n) * (1 - 0.9 * bend)
    s2 = rng.uniform(0.002, 0.006, n) * (1 - 0.9 * bend)
    t1 = t1 + s1[:, None] * rng.standard_normal((n, 2))
    t2 = t2 + s2[:, None] * rng.standard_normal((n, 2))
    (jac, sd, st, dof), (jac_ref, sd_ref, st_ref, dof_ref) = _kernel_one_pass(t1, t2, s1, s2)
    np.testing.assert_array_equal(st, st_ref)
    np.testing.assert_array_equal(dof[st != 2], dof_ref[st != 2])
    if bend:
        assert set(st.tolist()) - {0}, "the curved case must exercise the misfit tiers"
    np.testing.assert_allclose(jac, jac_ref, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(sd, sd_ref, rtol=1e-6)


def test_cubic_alias_bias_term_matches_reference():
    """The bias that the row's cubic terms alias into a quadratic report.

    An elongated constellation (4 x 0.8 arcsec) on a map with cubic terms,
    10 mas noise: the quadratic fits that a linear test licenses at its ends
    are one-sided. The kernel's errors equal the numpy twin's (GLS cubic on
    every point, alias through the quadratic's GLS operator, written
    independently), and on some pairs the twin without the term gives
    smaller errors, so the term is exercised.
    """
    rng = np.random.default_rng(0)
    n = 20
    x, y = rng.uniform(-2, 2, n), rng.uniform(-0.4, 0.4, n)
    t2 = np.column_stack([x, y])
    t1 = np.column_stack([1.2 * x + 0.1 * y + 0.05 * x**2 + 0.03 * x**3,
                          -0.8 * y + 0.1 * x + 0.02 * x**2 * y])
    s = np.full(n, 0.01)
    t1, t2, st, sd_ref, pilot = _kernel_matches_twin(t1, t2, s, rng)
    _, sd_without, _, _ = ref.adaptive(t1, t2, s, s, pilot, _chi2_critical(n),
                                       cubic_nsig=np.inf)
    widened = sd_ref > sd_without * (1 + 1e-9)
    assert widened.any() and (st[widened] == 0).all()
    assert np.all(sd_ref >= sd_without * (1 - 1e-12))


def test_adaptive_misfit_curvature_term_matches_reference():
    """A galaxy fold with 8 sources: misfit fits whose map bends by ln|det J| ~ 1-4
    across the neighbourhood; kernel and twin agree on the widened errors."""
    t1, t2, s1, s2 = _galaxy_fold_8(2, 0.01)
    (jac, sd, st, dof), (jac_ref, sd_ref, st_ref, dof_ref) = _kernel_one_pass(t1, t2, s1, s2)
    np.testing.assert_array_equal(st, st_ref)
    misfit = st == 1
    assert misfit.sum() >= 4
    np.testing.assert_allclose(sd[st != 2], sd_ref[st != 2], rtol=1e-6)
    # the curvature term is what widens them (the twin without it is narrower)
    pilot = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "quad")
    _, sd0, _, _ = ref.adaptive(t1, t2, s1, s2, pilot, _chi2_critical(len(t1)), curv_coef=0.0)
    assert (sd[misfit] >= sd0[misfit] * (1 - 1e-9)).all()
    assert (sd[misfit] > 1.5 * sd0[misfit]).any()


def test_adaptive_top_order_ranking_matches_reference():
    """Next to a cusp, 20 sources at 5 mas: several neighbourhoods pass their
    test, and the ranking's top-order term (the change of ln|det J| that the
    reported fit's highest-degree terms predict, beyond noise) moves the choice
    of some pairs; kernel and twin agree."""
    from lensdual.simulation import clean_constellation

    t = clean_constellation("cluster_cusp", 20, seed=2)
    t1 = np.column_stack([t["x1"].to_value(u.arcsec), t["y1"].to_value(u.arcsec)])
    t2 = np.column_stack([t["x2"].to_value(u.arcsec), t["y2"].to_value(u.arcsec)])
    rng = np.random.default_rng(4)
    sig = 0.005
    s = np.full(len(t1), sig)
    t1 = t1 + sig * rng.standard_normal(t1.shape)
    t2 = t2 + sig * rng.standard_normal(t2.shape)
    (jac, sd, st, dof), (jac_ref, sd_ref, st_ref, _) = _kernel_one_pass(t1, t2, s, s)
    np.testing.assert_array_equal(st, st_ref)
    np.testing.assert_allclose(jac, jac_ref, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(sd, sd_ref, rtol=1e-6)
    # without the term the twin chooses other neighbourhoods for some "ok" pairs
    pilot = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "quad")
    _, sd0, st0, _ = ref.adaptive(t1, t2, s, s, pilot, _chi2_critical(len(t1)), top_coef=0.0)
    ok = (st == 0) & (st0 == 0)
    assert (ok & ~np.isclose(sd, sd0, rtol=1e-9)).sum() >= 2


@pytest.mark.filterwarnings("ignore::lensdual.exceptions.EstimatorWarning")
def test_adaptive_two_scale_estimates_match_reference():
    """Kernel vs twin where two-scale estimates win pairs (24 points, 10 mas):
    the same choices, Jacobians and errors, and the twin without the
    two-scale candidates chooses differently there."""
    n = 24
    t1, t2, _ = _constellation(n, 2)
    rng = np.random.default_rng(5)
    s = np.full(n, 0.01)
    t1, t2, st, sd_ref, pilot = _kernel_matches_twin(t1, t2, s, rng)
    orig = ref._two_scale
    try:  # the twin without two-scale candidates: never chosen
        ref._two_scale = lambda *args: (orig(*args)[0], orig(*args)[1] * 1e12)
        _, sd_one, st_one, _ = ref.adaptive(t1, t2, s, s, pilot, _chi2_critical(n))
    finally:
        ref._two_scale = orig
    ok = (st == 0) & (st_one == 0)
    won = ok & ~np.isclose(sd_ref, sd_one)
    assert won.sum() >= 2


@pytest.mark.filterwarnings("ignore::lensdual.exceptions.EstimatorWarning")
@pytest.mark.parametrize("coef, noise, off", [
    # a linear test also needs the quadratic terms of its neighbourhood to be
    # insignificant (6 degrees of freedom): twice the curvature of _curved_map
    ((0.12, -0.08, 0.02, 0.0, 0.1, 0.03), 0.02, "nest_alpha"),
    # the larger neighbourhood of a two-scale estimate also needs its cubic
    # terms to be insignificant (8 degrees of freedom): a map with cubic terms
    ((0.06, -0.04, 0.0, 0.1, 0.05, 0.1), 0.01, "two_nest_alpha"),
])
def test_nested_tests_match_reference(coef, noise, off):
    """The nested (likelihood-ratio) tests of steps 2 and 3, on maps where they
    matter (24 points): kernel and twin agree, and the twin without the test
    (``off=None``) chooses other estimates for some "ok" pairs (so the test is
    exercised)."""
    n = 24
    t2 = np.random.default_rng(0).uniform(-1, 1, (n, 2))
    x, y = t2.T
    a, b, c, d, e, f = coef
    t1 = np.column_stack([0.8 * x + 0.2 * y + a * x**2 + b * x * y + c * y**3 + d * x**3,
                          0.1 * x - 0.7 * y + e * y**2 + f * x**2 * y])
    s = np.full(n, noise)
    t1, t2, st, sd_ref, pilot = _kernel_matches_twin(t1, t2, s, np.random.default_rng(10))
    _, sd_no, st_no, _ = ref.adaptive(t1, t2, s, s, pilot, _chi2_critical(n), **{off: None})
    changed = (st == 0) & (st_no == 0) & ~np.isclose(sd_ref, sd_no)
    assert changed.sum() >= 3


# ----------------------------------------- the adaptive estimator's estimates and errors


def test_adaptive_recovers_affine_map_exactly():
    rng = np.random.default_rng(3)
    t2 = rng.uniform(-1, 1, (12, 2))
    a = np.array([[1.3, -0.4], [0.2, -0.9]])
    t1 = t2 @ a.T + [0.5, -2.0]
    tab = size_magnification(t1 * u.arcsec, t2 * u.arcsec, sigma_pos=1 * u.mas)
    np.testing.assert_allclose(np.asarray(tab["mu_size"]), abs(np.linalg.det(a)), rtol=1e-9)
    assert (tab["parity"] == -1).all()
    assert (tab["mu_size_status"] == "ok").all()
    assert tab.meta["method"] == "adaptive"
    np.testing.assert_allclose(tab["jacobian"], np.broadcast_to(a, (12, 2, 2)), atol=1e-9)


@pytest.mark.filterwarnings("ignore::lensdual.exceptions.EstimatorWarning")
def test_adaptive_errors_hold_on_a_curved_map():
    """Pulls of ln mu_size: width ~1 and Gaussian tails (independent noise draws)."""
    pulls, n_ok, n_all = [], 0, 0
    for seed in range(30):
        t1, t2, mu = _constellation(20, seed)
        rng = np.random.default_rng(100 + seed)
        sig = 0.005
        o1 = t1 + sig * rng.standard_normal(t1.shape)
        o2 = t2 + sig * rng.standard_normal(t2.shape)
        tab = size_magnification(o1 * u.arcsec, o2 * u.arcsec, sigma_pos=sig * u.arcsec)
        ok = np.asarray(tab["mu_size_status"]) == "ok"
        n_ok, n_all = n_ok + ok.sum(), n_all + ok.size
        pulls.append((np.log(np.asarray(tab["mu_size"])) - np.log(mu))[ok]
                     / np.asarray(tab["ln_mu_size_err"])[ok])
    assert n_ok / n_all > 0.95
    pulls = np.concatenate(pulls)
    q16, q50, q84 = np.percentile(pulls, [15.87, 50, 84.13])
    assert 0.8 < 0.5 * (q84 - q16) < 1.2
    assert abs(q50) < 0.2
    assert np.mean(np.abs(pulls) > 3) < 0.01
    # quad2's bootstrap (position noise only) is not calibrated on the same data
    t1, t2, mu = _constellation(20, 0, span=2.0)
    tab = size_magnification(t1 * u.arcsec, t2 * u.arcsec, "quad", sigma_pos=1 * u.mas,
                              n_bootstrap=100, seed=0)
    err = np.log(np.asarray(tab["mu_size"]) / mu)
    assert np.median(np.abs(err) / np.asarray(tab["ln_mu_size_err"])) > 3


def test_curvature_noise_matches_monte_carlo():
    """The standard error of t(u) = tr(J^-1 H u), the change of ln|det J| that a
    quadratic fit predicts across its neighbourhood, against the scatter of t
    over 2000 noisy copies (noise on L1 only, so that the design is exact; J^-1
    held at the noise-free fit's, as the error assumes)."""
    t1, t2 = _quadratic_map_points()
    n = len(t1)
    sig = 0.002
    s1, s2 = np.full(n, sig), np.zeros(n)
    idx = np.arange(n)
    pilot = np.array([[1.4, 0.2], [-0.3, 0.9]])
    t0, sd0 = ref._curvature_terms(t1, t2, 0, idx, 2, s1, s2, pilot)
    jinv = np.linalg.inv(ref._gls_fit(t1, t2, 0, idx, 2, s1, s2, pilot)[0])
    rng = np.random.default_rng(1)
    draws = np.array([ref._curvature_terms(t1 + sig * rng.standard_normal(t1.shape), t2, 0, idx,
                                           2, s1, s2, pilot, jinv=jinv)[0]
                      for _ in range(2000)])
    far = sd0 > 0  # the centre itself has t = 0 exactly
    assert far.sum() == n - 1
    np.testing.assert_allclose(draws.std(axis=0)[far], sd0[far], rtol=0.08)
    np.testing.assert_allclose(draws.mean(axis=0)[far], t0[far], atol=4 * sd0[far].max() / 40)


def test_curvature_of_a_linear_map_is_noise():
    """For an exactly linear map, the second-order terms of a quadratic fit are
    noise: the raw curvature max |t(u)| is positive in every noisy copy, while
    the de-noised one (less twice its error at each point) is zero in most."""
    t1, t2 = _quadratic_map_points()
    t1 = t2 @ np.array([[1.4, 0.2], [-0.3, 0.9]]).T
    n = len(t1)
    sig = 0.01
    s = np.full(n, sig)
    idx = np.arange(n)
    rng = np.random.default_rng(2)
    raw, dn = [], []
    for _ in range(200):
        o1 = t1 + sig * rng.standard_normal(t1.shape)
        o2 = t2 + sig * rng.standard_normal(t2.shape)
        pilot = relative_jacobian(o1 * u.arcsec, o2 * u.arcsec, "quad")[0]
        raw.append(ref._curvature(o1, o2, 0, idx, 2, s, s, pilot, n_sig=0.0))
        dn.append(ref._curvature(o1, o2, 0, idx, 2, s, s, pilot))
    raw, dn = np.array(raw), np.array(dn)
    assert (raw > 0).all()
    assert np.mean(dn == 0.0) > 0.6
    assert np.median(dn) < 0.2 * np.median(raw)


def test_two_scale_estimate_exact_on_a_quadratic_map_with_its_covariance():
    """The two-scale estimate (linear fit of the h nearest points less the alias
    of the quadratic terms fitted on b > h points) is exact on a quadratic map,
    and its covariance matches the Monte Carlo scatter of the estimate."""
    rng = np.random.default_rng(7)
    t2 = rng.uniform(-1, 1, (20, 2))
    x, y = t2.T
    t1 = np.column_stack([0.9 * x + 0.3 * y + 0.2 * x**2 - 0.1 * x * y + 0.15 * y**2,
                          -0.2 * x + 0.7 * y + 0.05 * x**2 + 0.25 * x * y - 0.1 * y**2])
    a = 3
    jac_true = np.array([[0.9 + 0.4 * x[a] - 0.1 * y[a], 0.3 - 0.1 * x[a] + 0.3 * y[a]],
                         [-0.2 + 0.1 * x[a] + 0.25 * y[a], 0.7 + 0.25 * x[a] - 0.2 * y[a]]])
    order = np.argsort(((t2 - t2[a]) ** 2).sum(axis=1), kind="stable")
    s1 = np.full(20, 0.004)
    s2 = np.zeros(20)  # noise on L1 only: the effective variance is then exact
    jac, cov = ref._two_scale(t1, t2, a, order, 8, 20, s1, s2, jac_true)
    np.testing.assert_allclose(jac, jac_true, atol=1e-10)
    # the linear fit of 8 points alone is biased by the curvature
    lin, _, _, _ = ref._gls_fit(t1, t2, a, order[:8], 1, s1, s2, jac_true)
    assert np.max(np.abs(lin - jac_true)) > 0.05
    draws = np.array([ref._two_scale(t1 + 0.004 * rng.standard_normal(t1.shape), t2, a, order,
                                     8, 20, s1, s2, jac_true)[0].ravel() for _ in range(3000)])
    np.testing.assert_allclose(np.cov(draws.T), cov, rtol=0.1, atol=0.05 * np.max(cov))


@pytest.mark.filterwarnings("ignore::lensdual.exceptions.EstimatorWarning")
def test_own_position_noise_moves_the_point_where_j_is_taken():
    """A pair measured 20 mas off its true L2 position, its neighbours 0.1 mas:
    every fit takes J at the noisy position, so the scatter of ln mu_size is
    s2 |grad ln|det J|| (closed form for an exactly quadratic map) and the
    quoted error must hold it; without the term it would be ~50 times smaller."""
    ca, cb = 0.3, -0.2  # F(x, y) = (x + ca x^2, y + cb y^2): J = diag(1 + 2 ca x, 1 + 2 cb y)
    rng = np.random.default_rng(11)
    t2 = rng.uniform(-1.0, 1.0, (20, 2))
    t2[0] = [0.2, -0.1]
    t1 = np.column_stack([t2[:, 0] + ca * t2[:, 0] ** 2, t2[:, 1] + cb * t2[:, 1] ** 2])
    mu0 = (1 + 2 * ca * t2[0, 0]) * (1 + 2 * cb * t2[0, 1])
    grad = np.array([2 * ca / (1 + 2 * ca * t2[0, 0]), 2 * cb / (1 + 2 * cb * t2[0, 1])])
    s2 = np.full(20, 1e-4)
    s2[0] = 0.02
    sigma = np.vstack([np.full(20, 1e-4), s2]) * u.arcsec
    expected = s2[0] * np.hypot(*grad)
    ln_mu, quoted, status = [], [], []
    for _ in range(300):
        o1 = t1 + 1e-4 * rng.standard_normal(t1.shape)
        o2 = t2 + s2[:, None] * rng.standard_normal(t2.shape)
        tab = size_magnification(o1 * u.arcsec, o2 * u.arcsec, sigma_pos=sigma)
        status.append(tab["mu_size_status"][0])
        ln_mu.append(np.log(tab["mu_size"][0]))
        quoted.append(tab["ln_mu_size_err"][0])
    # a pair drawn ~3 sigma off fails the quadratic test now and then (its own
    # point's residual); the others are "ok"
    status = np.array(status)
    assert np.mean(status == "ok") > 0.97
    keep = np.isin(status, ["ok", "misfit"])
    ln_mu, quoted = np.array(ln_mu)[keep], np.array(quoted)[keep]
    # the scatter is the closed form (300 draws: its standard error is 4 %)
    assert np.std(ln_mu) == pytest.approx(expected, rel=0.15)
    assert abs(np.mean(ln_mu) - np.log(mu0)) < 4 * expected / np.sqrt(300)
    # and the quoted error holds it
    assert np.median(quoted) == pytest.approx(expected, rel=0.15)
    pulls = (ln_mu - np.log(mu0)) / quoted
    assert 0.85 < np.std(pulls) < 1.15


def test_chi2_critical_values():
    crit = _chi2_critical(5)
    assert crit.shape == (11,) and np.isinf(crit[0])
    np.testing.assert_allclose(crit[1:], chi2.isf(0.05, np.arange(1, 11)))


def test_nested_test_critical_value():
    """The kernel's nested-test thresholds are the chi-square quantiles they claim."""
    st = _adaptive.SETTINGS
    assert st.nest_crit6 == pytest.approx(chi2.isf(st.nest_alpha, 6), rel=1e-12)
    assert st.two_nest_crit8 == pytest.approx(chi2.isf(st.two_nest_alpha, 8), rel=1e-12)


# -------------------------------------------------------- untestable pairs and bad input


def test_untestable_pairs_are_reported_and_not_tested():
    # a map that bends far faster than the constellation samples it
    rng = np.random.default_rng(5)
    t2 = rng.uniform(-1, 1, (9, 2))
    t1 = np.column_stack([np.sin(3 * t2[:, 0]) + t2[:, 1], np.cos(3 * t2[:, 1]) - t2[:, 0]])
    with pytest.warns(EstimatorWarning, match="no local polynomial"):
        tab = size_magnification(t1 * u.arcsec, t2 * u.arcsec, sigma_pos=0.1 * u.mas)
    assert (tab["mu_size_status"] == "untestable").all()
    assert np.isfinite(tab["mu_size"]).all()
    pairs = QTable()
    pairs["x1"], pairs["y1"] = t1[:, 0] * u.arcsec, t1[:, 1] * u.arcsec
    pairs["x2"], pairs["y2"] = t2[:, 0] * u.arcsec, t2[:, 1] * u.arcsec
    pairs["flux1_F150W"] = 100.0 * np.ones(9)  # far from any mu_size: would be flagged
    pairs["flux2_F150W"] = np.ones(9)
    pairs["flux_err1_F150W"] = pairs["flux_err2_F150W"] = 0.01 * np.ones(9)
    with pytest.warns(EstimatorWarning):
        res = check_duality(pairs, sigma_pos=0.1 * u.mas)
    assert not res["tested"].any() and not res["anomalous"].any()
    assert np.isnan(res["p_value"]).all()
    assert res.meta["duality"]["n_tested"] == 0


@pytest.mark.filterwarnings("ignore::lensdual.exceptions.EstimatorWarning")
def test_untestable_errors_hold_the_model_error():
    """An "untestable" pair's error holds the model error, as a misfit's does.

    Eight sources on a map that bends on the constellation's scale (a sine
    ripple added to the curved map, exact Jacobian), 1 mas noise: no local
    fit is consistent with the noise, every pair is untestable. Their pulls
    (with the model error: the next neighbourhoods' changes and the truncation
    term) have a robust width within 0.7-2.0 (1.4 here) and a median within 0.4.
    """
    pulls = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        t2 = rng.uniform(-1, 1, (8, 2))
        t1, jac = _curved_map(t2)
        x, y = t2[:, 0], t2[:, 1]
        t1 = t1 + 0.3 * np.column_stack([np.sin(2 * x), np.cos(2 * y)])
        jac[:, 0, 0] += 0.6 * np.cos(2 * x)
        jac[:, 1, 1] -= 0.6 * np.sin(2 * y)
        mu = np.abs(np.linalg.det(jac))
        sig = 0.001
        t1 = t1 + sig * rng.standard_normal(t1.shape)
        t2 = t2 + sig * rng.standard_normal(t2.shape)
        tab = size_magnification(t1 * u.arcsec, t2 * u.arcsec, sigma_pos=sig * u.arcsec)
        assert (tab["mu_size_status"] == "untestable").all()
        pulls.append(np.log(np.asarray(tab["mu_size"]) / mu) / np.asarray(tab["ln_mu_size_err"]))
    q16, q50, q84 = np.percentile(np.concatenate(pulls), [15.87, 50, 84.13])
    assert 0.7 < 0.5 * (q84 - q16) < 2.0
    assert abs(q50) < 0.4


def test_reverse_map_where_the_forward_fit_is_untestable(monkeypatch):
    from lensdual.estimators import core

    t1, t2, mu_true = _reverse_quadratic_constellation()
    rng = np.random.default_rng(11)
    s = 0.5e-3
    sig = np.full((2, len(t1)), s)
    o1 = t1 + s * rng.standard_normal(t1.shape)
    o2 = t2 + s * rng.standard_normal(t2.shape)
    ok_codes = (_adaptive.ADAPTIVE_OK, _adaptive.ADAPTIVE_MISFIT)
    _, _, _, st_fwd, _ = core._adaptive_forward(o1, o2, sig, 2.0)
    jr, _, sd_r, st_r, dof_r = core._adaptive_forward(o2, o1, sig[::-1].copy(), 2.0)
    # the square root is no polynomial at 0.5 mas: most forward fits are untestable
    assert (st_fwd == _adaptive.ADAPTIVE_UNTESTABLE).sum() >= 8
    expect = ~np.isin(st_fwd, ok_codes) & np.isin(st_r, ok_codes)
    # the reverse fit runs on the pairs that need it only: a subset of the
    # pairs gets the estimates of a run on all of them, bit for bit
    sub = np.flatnonzero(~np.isin(st_fwd, ok_codes))
    assert 0 < sub.size < len(t1)
    js, _, sd_s, st_s, dof_s = core._adaptive_forward(o2, o1, sig[::-1].copy(), 2.0, rows=sub)
    np.testing.assert_array_equal(js[sub], jr[sub])
    np.testing.assert_array_equal(sd_s[sub], sd_r[sub])
    np.testing.assert_array_equal(st_s[sub], st_r[sub])
    np.testing.assert_array_equal(dof_s[sub], dof_r[sub])
    rest = np.setdiff1d(np.arange(len(t1)), sub)
    assert np.isnan(sd_s[rest]).all() and (st_s[rest] == _adaptive.ADAPTIVE_FAILED).all()
    jac, _, sd, st, dof, rev = core._adaptive(o1, o2, sig, 2.0)
    np.testing.assert_array_equal(rev, expect)
    # those pairs take the inverse of the L1 -> L2 fit, with its error and status
    np.testing.assert_allclose(jac[rev], np.linalg.inv(jr[rev]), rtol=1e-12)
    np.testing.assert_array_equal(sd[rev], sd_r[rev])
    np.testing.assert_array_equal(st[rev], st_r[rev])
    np.testing.assert_array_equal(dof[rev], dof_r[rev])
    pull = (np.log(np.abs(np.linalg.det(jac[rev]))) - np.log(mu_true[rev])) / sd[rev]
    assert np.all(np.abs(pull) < 4), pull
    # the others are the forward fit's, unchanged
    jf, _, sd_f, _, _ = core._adaptive_forward(o1, o2, sig, 2.0)
    np.testing.assert_array_equal(jac[~rev], jf[~rev])
    np.testing.assert_array_equal(sd[~rev], sd_f[~rev])
    tab = size_magnification(o1 * u.arcsec, o2 * u.arcsec, sigma_pos=s * u.arcsec)
    assert tab.meta["reverse_map_rows"] == np.flatnonzero(rev).tolist()
    assert set(tab["mu_size_status"][rev]) <= {"ok", "misfit"}
    # check_duality names them by pair_id, and tests them
    pairs = QTable()
    pairs["pair_id"] = np.arange(101, 101 + len(t1))
    pairs["x1"], pairs["y1"] = o1[:, 0] * u.arcsec, o1[:, 1] * u.arcsec
    pairs["x2"], pairs["y2"] = o2[:, 0] * u.arcsec, o2[:, 1] * u.arcsec
    pairs["flux1_F150W"] = 100.0 * mu_true
    pairs["flux2_F150W"] = 100.0 * np.ones(len(t1))
    pairs["flux_err1_F150W"] = pairs["flux_err2_F150W"] = 0.5 * np.ones(len(t1))
    res = check_duality(pairs, sigma_pos=s * u.arcsec)
    assert res.meta["duality"]["reverse_map_pairs"] == (101 + np.flatnonzero(rev)).tolist()
    assert res["tested"][rev].all()
    # with a doubtful pair left out, the ids still name the right pairs
    pairs["doubt"] = ["checked by eye"] + [""] * (len(t1) - 1)
    res = check_duality(pairs, sigma_pos=s * u.arcsec)
    sub = size_magnification(o1[1:] * u.arcsec, o2[1:] * u.arcsec, sigma_pos=s * u.arcsec)
    assert sub.meta["reverse_map_rows"]
    assert res.meta["duality"]["reverse_map_pairs"] == [
        102 + i for i in sub.meta["reverse_map_rows"]]
    # the null calibration's batches follow the same rule, copy by copy
    noise1 = s * rng.standard_normal((3, len(t1), 2))
    noise2 = s * rng.standard_normal((3, len(t1), 2))
    det_b, sd_b, ok_b, dof_b, jac_b, cov_b = core.adaptive_batch(t1, t2, noise1, noise2, sig,
                                                                 with_jacobian=True)
    n_rev = 0
    for k in range(3):
        jk, ck, sdk, stk, dofk, revk = core._adaptive(t1 + noise1[k], t2 + noise2[k], sig, 2.0)
        np.testing.assert_allclose(det_b[k], np.abs(np.linalg.det(jk)), rtol=1e-10)
        # the Jacobians and covariances the profile SNR reads, reversed pairs included
        np.testing.assert_allclose(jac_b[k][ok_b[k]], jk[ok_b[k]], rtol=1e-10)
        np.testing.assert_allclose(cov_b[k][ok_b[k]], ck[ok_b[k]], rtol=1e-8, atol=1e-300)
        n_rev += int(revk.sum())
        np.testing.assert_array_equal(ok_b[k], np.isin(stk, ok_codes))
        np.testing.assert_array_equal(sd_b[k][ok_b[k]], sdk[ok_b[k]])
        np.testing.assert_array_equal(dof_b[k][ok_b[k]], dofk[ok_b[k]])
    assert n_rev > 0
    # without the reverse map those pairs stay untestable
    monkeypatch.setattr(_adaptive, "SETTINGS", _adaptive.SETTINGS._replace(reverse=False))
    _, _, _, st_off, _, rev_off = core._adaptive(o1, o2, sig, 2.0)
    assert not rev_off.any()
    np.testing.assert_array_equal(st_off, st_fwd)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"sigma_pos": 0 * u.arcsec}, "sigma_pos must be > 0 for method 'adaptive'"),
        ({"sigma_pos": np.zeros(8) * u.arcsec}, "sigma_pos must be > 0"),
        ({"sigma_pos": -np.ones(8) * u.mas}, "sigma_pos must be finite and >= 0"),
    ],
)
def test_adaptive_bad_errors(kwargs, match):
    t1, t2, _ = _constellation(8, 0)
    with pytest.raises(ValueError, match=match):
        size_magnification(t1 * u.arcsec, t2 * u.arcsec, **kwargs)


def test_adaptive_too_few_pairs_and_nan():
    t1, t2, _ = _constellation(6, 0)
    with pytest.raises(ValueError, match="method 'adaptive' needs at least 7 pairs, got 6"):
        size_magnification(t1 * u.arcsec, t2 * u.arcsec, sigma_pos=1 * u.mas)
    t1, t2, _ = _constellation(8, 0)
    t1[2, 0] = np.nan
    with pytest.raises(ValueError, match="theta1"):
        size_magnification(t1 * u.arcsec, t2 * u.arcsec, sigma_pos=1 * u.mas)
    with pytest.raises(ValueError, match="needs sigma_pos"):
        relative_jacobian(t2 * u.arcsec, t2 * u.arcsec, "adaptive")


# ----------------------------------------------------------- the calibrated duality test


def test_holm_adjust_against_definition():
    p = np.array([0.01, 0.04, np.nan, 0.03, 0.2])
    adj = holm_adjust(p)
    # sorted: 0.01 (x4), 0.03 (x3), 0.04 (x2), 0.2 (x1), monotone
    np.testing.assert_allclose(adj[[0, 3, 1, 4]], [0.04, 0.09, 0.09, 0.2])
    assert np.isnan(adj[2])
    with pytest.raises(ValueError, match="one-dimensional"):
        holm_adjust(np.ones((2, 2)))


def test_gaussian_p_value():
    np.testing.assert_allclose(gaussian_p_value(3.0), 2 * norm.sf(3.0), rtol=1e-12)
    np.testing.assert_allclose(gaussian_p_value([0.0, 1.0]), [1.0, 2 * norm.sf(1.0)])


@pytest.mark.filterwarnings("ignore::lensdual.exceptions.EstimatorWarning")
def test_check_duality_calibrated_columns_and_meta():
    res = check_duality(_pairs(anomaly=(3, 1.5)), sigma_pos=3 * u.mas, snr_definition="log")
    assert res.meta["duality"]["method"] == "adaptive"
    tested = np.asarray(res["tested"])
    assert tested.all()
    # p-values: Student's t with the Welch-Satterthwaite dof for "misfit" pairs,
    # Gaussian for "ok" ones; the significance is the Gaussian equivalent
    snr, dof = np.asarray(res["snr"]), np.asarray(res["snr_dof"])
    gauss = np.isinf(dof)
    assert gauss.any()
    expect = np.where(gauss, 2 * norm.sf(snr), 2 * t_dist.sf(snr, np.where(gauss, 1, dof)))
    np.testing.assert_allclose(res["p_value"], expect, rtol=1e-10)
    np.testing.assert_allclose(res["p_value"], gaussian_p_value(np.asarray(res["significance"])),
                               rtol=1e-8)
    np.testing.assert_array_equal(np.asarray(res["significance"])[gauss], snr[gauss])
    size_dof = np.asarray(res["ln_mu_size_err_dof"])
    status = np.asarray(res["mu_size_status"])
    assert np.isinf(size_dof[status == "ok"]).all()
    assert (size_dof[status == "misfit"] >= 1).all()
    np.testing.assert_allclose(res["p_value_holm"], holm_adjust(np.asarray(res["p_value"])))
    assert list(np.flatnonzero(res["anomalous"])) == [3]
    meta = res.meta["duality"]
    assert meta["n_tested"] == 16 and meta["n_flagged"] == 1
    p3 = 2 * norm.sf(3.0)
    np.testing.assert_allclose(meta["expected_false_flags"], 16 * p3)
    np.testing.assert_allclose(meta["p_any_false_flag"], 1 - (1 - p3) ** 16)
    pmin = np.min(res["p_value"])
    np.testing.assert_allclose(meta["family_wise_p"], 1 - (1 - pmin) ** 16)
    # the paper's quad: tested columns too, bootstrap error in ln_mu_size_err
    res_q = check_duality(_pairs(), "quad", sigma_pos=3 * u.mas, n_bootstrap=50, seed=0)
    assert "ln_mu_size_err" in res_q.colnames and res_q.meta["duality"]["n_tested"] == 16


def test_duality_significance_against_closed_forms():
    snr = np.array([0.0, 1.0, 3.0, 8.0, np.nan])
    np.testing.assert_array_equal(duality_significance(snr), snr)
    # one degree of freedom: Cauchy, two-sided p = 1 - 2 arctan(t) / pi
    p = 1 - 2 * np.arctan(snr) / np.pi
    np.testing.assert_allclose(duality_significance(snr, 1.0), norm.isf(p / 2), rtol=1e-10)
    # large dof tends to the Gaussian; fewer dof, smaller significance
    assert abs(duality_significance(3.0, 1e6) - 3.0) < 1e-4
    s = duality_significance(np.full(4, 3.0), [2.0, 4.0, 10.0, 30.0])
    assert np.all(np.diff(s) > 0) and np.all(s < 3.0)
    with pytest.raises(ValueError, match="dof must be positive"):
        duality_significance(3.0, 0.0)


@pytest.mark.parametrize("dof", [2.0, 4.0, 8.0])
def test_gaussian_equivalent_pulls_of_student_t(dof):
    """The calibration suite's ``pull_gw``: pulls of a "misfit" pair whose error
    is estimated from ``dof`` residuals follow Student's t (16-84 % half-width
    1.32 / 1.14 / 1.07, not 1); mapped through the significance the flag reads,
    they are standard normal (half-width 1, 0.27 % beyond 3)."""
    pull = t_dist.rvs(dof, size=400_000, random_state=np.random.default_rng(int(dof)))
    q16, q84 = np.percentile(pull, [15.87, 84.13])
    assert abs(0.5 * (q84 - q16) - t_dist.ppf(norm.cdf(1.0), dof)) < 0.02
    g = np.sign(pull) * duality_significance(np.abs(pull), dof)
    g16, g84 = np.percentile(g, [15.87, 84.13])
    assert abs(0.5 * (g84 - g16) - 1.0) < 0.01
    assert abs(np.mean(np.abs(g) > 3.0) - 2 * norm.sf(3.0)) < 0.0006


def test_report_words_for_student_t_pairs():
    """The report states the significance a flag is set on, and why it is below the SNR."""
    from lensdual._report import _significance, _snr_words

    tab = QTable({"snr": [4.0, 4.0], "snr_dof": [np.inf, 6.0],
                  "significance": [4.0, float(duality_significance(4.0, 6.0))]})
    assert _snr_words(tab[0]) == "SNR 4.0"
    words = _snr_words(tab[1])
    assert words.startswith("SNR 4.0 (2.7 sigma") and "6 degrees of freedom" in words
    assert _significance(tab[1]) == tab["significance"][1]


# ------------------------------------------------------------------ the null calibration


@pytest.mark.filterwarnings("ignore::lensdual.exceptions.EstimatorWarning")
def test_null_calibration_rates_and_chunking():
    pairs = _pairs(n=14, seed=2)
    null = null_calibration(pairs, sigma_pos=3 * u.mas, n_realisations=300, seed=7)
    assert null["null_snr"].shape == (14, 300)
    meta = null.meta
    assert meta["map_dof"] > 3.5  # the map is curved: more than an affine map's 3
    assert not meta["map_interpolates"]
    # the null's SNRs are |Z|-like: rates near the nominal ones
    assert meta["false_alarm_rate"] < 0.02
    frac1 = np.mean(np.abs(null["null_snr"]) > 1)
    assert 0.2 < frac1 < 0.45  # Gaussian: 0.317
    p = np.asarray(null["p_value_empirical"])
    assert ((p > 0) & (p <= 1)).all()
    # chunking and executor independence; the default runs in threads, the same
    # blocks as one after the other here
    with ThreadPoolExecutor(2) as pool:
        other = null_calibration(pairs, sigma_pos=3 * u.mas, n_realisations=300, seed=7,
                                 client=pool, chunk_size=1)
    np.testing.assert_array_equal(other["null_snr"], null["null_snr"])

    class Serial:
        def map(self, fn, tasks):
            return map(fn, tasks)

    serial = null_calibration(pairs, sigma_pos=3 * u.mas, n_realisations=300, seed=7,
                              client=Serial(), chunk_size=3)
    np.testing.assert_array_equal(serial["null_snr"], null["null_snr"])


def test_null_calibration_with_the_conservative_snr():
    """snr_definition="conservative": the observed significances are
    check_duality's, and each null significance is at most the log SNR's of the
    same realisation (the smaller of the log and the profile SNR), lower on
    some where the profile is."""
    pairs = _pairs(n=14, seed=2)
    kw = dict(sigma_pos=20 * u.mas, n_realisations=100, seed=7)
    log = null_calibration(pairs, snr_definition="log", **kw)
    cons = null_calibration(pairs, snr_definition="conservative", **kw)
    # the default is the conservative SNR, and one band the geometric test
    default = null_calibration(pairs, **kw)
    np.testing.assert_array_equal(default["null_snr"], cons["null_snr"])
    assert default.meta["snr_definition"] == "conservative"
    assert default.meta["test"] == "geometric"
    observed = check_duality(pairs, sigma_pos=20 * u.mas, snr_definition="conservative")
    np.testing.assert_allclose(np.asarray(cons["significance"], float),
                               np.asarray(observed["significance"], float), equal_nan=True)
    a, b = np.asarray(cons["null_snr"]), np.asarray(log["null_snr"])
    both = np.isfinite(a) & np.isfinite(b)
    assert both.mean() > 0.9
    assert np.all(a[both] <= b[both] + 1e-12)
    assert np.any(a[both] < b[both] - 0.01)
    assert cons.meta["false_alarm_rate"] <= log.meta["false_alarm_rate"]
    with pytest.raises(ValueError, match="snr_definition 'auto', 'log' or 'conservative'"):
        null_calibration(pairs, snr_definition="paper", **kw)
    # the pipeline's null calibration passes the definition on
    from lensdual.pipeline import _add_null_calibration

    result = observed.copy()
    _add_null_calibration(result, pairs, 20 * u.mas, 100, 3.0, 7,
                          snr_definition="conservative")
    np.testing.assert_array_equal(np.asarray(result["p_value_empirical"]),
                                  np.asarray(cons["p_value_empirical"]))


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"n_realisations": 99}, ValueError, "n_realisations must be >= 100"),
        ({"sigma_pos": 0 * u.mas}, ValueError, "sigma_pos must be > 0"),
        ({"seed": "x"}, TypeError, "seed must be"),
        ({"client": object()}, TypeError, "client must be"),
        ({"chunk_size": 0}, ValueError, "chunk_size"),
    ],
)
def test_null_calibration_bad_input(kwargs, exc, match):
    args = {"sigma_pos": 3 * u.mas, "n_realisations": 100, "seed": 0}
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        null_calibration(_pairs(n=8), **args)


def test_null_calibration_too_few_pairs():
    with pytest.raises(ValueError, match="at least 7 pairs"):
        null_calibration(_pairs(n=6), sigma_pos=3 * u.mas, n_realisations=100)


# ------------------------------------------------- the calibration tables of benchmarks/


def test_missed_targets_of_the_calibration_tables(tmp_path):
    """benchmarks/calibration_tables.py --targets: each target, read from a
    calibration.py output written here (one passing cell, one per reason)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from calibration_tables import main, missed_targets, read

    head = ("family n_sources method noise_mas n tested ok ffr ffr_l95 ffr_u95 ffr_exact "
            "pull_med pull_w pull_gw bias sig pow10 pow25 pow50")
    rows = [
        "cluster_fold 20 adaptive 5 2e+03 1 1 0.002 0.001 0.004 0.001 0 0.9 0.9 0.001 0.05 0.2 "
        "0.82 0.99",
        "cluster_fold 40 adaptive 5 4e+03 1 1 0.002 0.001 0.004 0.001 0 0.9 0.9 0.001 0.05 0.2 "
        "0.79 0.99",
        "galaxy_fold 8 adaptive 1 800 0.3 0 0 0 0.004 0 0 0.9 0.9 0 0.05 0 0 0",
        "galaxy_fold 20 adaptive 2 2e+03 1 1 0.006 0.004 0.008 0.006 0 1.3 1.25 0.03 0.06 0 0 0",
        "galaxy_fold 40 adaptive 2 4e+03 1 1 0.008 0.006 0.01 0.006 0 1 1 0.001 0.06 0 0 0",
        "galaxy_fold 20 quad2 2 2e+03 1 1 0.5 0.4 0.6 0.5 0 5 5 0.3 0.01 1 1 1",
    ]
    path = tmp_path / "cal.txt"
    path.write_text("\n".join([head, *rows]) + "\n")
    missed = missed_targets(read(path))
    assert set(missed) == {("cluster_fold", 40, 5.0), ("galaxy_fold", 8, 1.0),
                           ("galaxy_fold", 20, 2.0), ("galaxy_fold", 40, 2.0)}
    assert missed[("cluster_fold", 40, 5.0)] == ["power 79 %"]
    assert missed[("galaxy_fold", 8, 1.0)] == ["30 % of the pairs testable"]
    assert missed[("galaxy_fold", 20, 2.0)] == ["false flags 0.60 %", "width 1.25",
                                                "bias 3.00 % (sigma 6.00 %)"]
    # an excess whose lower limit is above the target too is significant
    assert missed[("galaxy_fold", 40, 2.0)] == ["false flags 0.80 % (significant: > 0.60 %)"]
    main([str(path), "--targets"])


def test_calibration_pooled_saves_and_ffr_limits(tmp_path):
    """benchmarks/calibration.py --from-saves: per-pair saves of two runs pooled
    cell by cell give the false-flag rate of the pooled pairs (counted here
    with plain numpy), constellations numbered apart, and limits that widen
    when the flags cluster in one constellation."""
    import sys
    from pathlib import Path

    from scipy.stats import beta as beta_dist

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from calibration import _ffr_limits, cell_metrics, main, pooled_cells

    rng = np.random.default_rng(3)

    def save(folder, n_con, per_con, flagged):
        n = n_con * per_con
        err = 0.02 * rng.standard_normal(n)
        err[flagged] = 1.0  # 10 sigma: flagged whatever the flux noise
        arrays = dict(ln_err=err, ln_sd=np.full(n, 0.1), status=np.full(n, "ok"),
                      dof=np.full(n, np.inf), ln_flux_noise=0.014 * rng.standard_normal(n),
                      constellation=np.repeat(np.arange(n_con), per_con))
        folder.mkdir()
        np.savez(folder / "cluster_fold_20_adaptive_5.npz", **arrays)
        return arrays

    a = save(tmp_path / "a", 10, 200, [3, 450])
    b = save(tmp_path / "b", 5, 200, [7])
    (cell,) = list(pooled_cells([tmp_path / "a", tmp_path / "b"]))
    assert cell[:4] == ("cluster_fold", 20, "adaptive", 5.0)
    r = cell[4]
    assert r["n"] == 3000 and r["ffr"] == pytest.approx(3 / 3000)
    # the same as the metrics of the concatenation, constellations 0-14
    joined = {k: np.concatenate([a[k], b[k]]) for k in a}
    joined["constellation"] = np.concatenate([a["constellation"], b["constellation"] + 10])
    ref = cell_metrics(*(joined[k] for k in ("ln_err", "ln_sd", "status", "dof",
                                              "ln_flux_noise", "constellation")))
    for key in ("ffr", "ffr_l95", "ffr_u95", "pull_med", "pull_gw", "pow25"):
        assert r[key] == pytest.approx(ref[key])
    assert r["ffr_l95"] <= r["ffr"] <= r["ffr_u95"]
    # limits: spread flags get Clopper-Pearson's, clustered ones a wider upper limit
    spread = _ffr_limits(np.array([1.0] * 6 + [0.0] * 14), np.full(20, 500.0))
    cp_hi = beta_dist.ppf(0.95, 7, 10_000 - 6)
    assert spread[1] == pytest.approx(cp_hi)
    clustered = _ffr_limits(np.array([6.0] + [0.0] * 19), np.full(20, 500.0))
    assert clustered[1] > 1.5 * cp_hi and clustered[0] == 0.0
    main(["--from-saves", str(tmp_path / "a")])
    with pytest.raises(SystemExit):
        main(["--from-saves", str(tmp_path / "nowhere")])


def test_null_calibration_leaves_doubtful_pairs_out():
    """A doubtful pair, whose position errors may be unknown (NaN, as the pipeline
    gives them), is left out of the null as check_duality leaves it out of the
    estimate: the null of the other pairs is that of the table without it, and its
    own empirical p-value is NaN."""
    pairs = _pairs(n=14, seed=2)
    pairs["doubt"] = np.array([""] * 14, dtype=object)
    pairs["doubt"][5] = "no PSF fit: position error unknown"
    sigma = np.full((2, 14), 0.02)
    sigma[:, 5] = np.nan
    kw = dict(n_realisations=100, seed=7)
    null = null_calibration(pairs, sigma_pos=sigma * u.arcsec, **kw)
    others = np.arange(14) != 5
    without = pairs[others]
    del without["doubt"]
    ref = null_calibration(without, sigma_pos=sigma[:, others] * u.arcsec, **kw)
    np.testing.assert_array_equal(np.asarray(null["null_snr"])[others],
                                  np.asarray(ref["null_snr"]))
    np.testing.assert_array_equal(np.asarray(null["p_value_empirical"])[others],
                                  np.asarray(ref["p_value_empirical"]))
    assert np.isnan(np.asarray(null["null_snr"])[5]).all()
    assert np.isnan(null["p_value_empirical"][5]) and not null["tested"][5]
    assert null.meta["false_alarm_rate"] == ref.meta["false_alarm_rate"]
