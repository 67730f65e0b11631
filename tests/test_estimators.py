"""Tests of lensdual.estimators against closed forms and plain-numpy references."""

import _reference as ref
import numpy as np
import pytest
from astropy import units as u
from astropy.table import QTable

from lensdual.estimators import _kernels, relative_jacobian
from lensdual.estimators import size_magnification as _size_magnification
from lensdual.exceptions import EstimatorWarning

# The bootstrap estimators of the paper (and quad2); the adaptive default is
# tested in test_calibration.py.
METHODS = {"2v": 3, "quad": 3, "quad2": 3}


def size_magnification(theta1, theta2, method="quad", **kwargs):
    """The estimators' bootstrap path, with "quad" as these tests' default."""
    return _size_magnification(theta1, theta2, method, **kwargs)

ALL_METHODS = sorted(METHODS)


def random_rotation(rng):
    phi = rng.uniform(0, 2 * np.pi)
    return np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])


def random_affine(rng, det):
    """A random 2x2 matrix with the given (signed) determinant."""
    stretch = rng.uniform(0.3, 3.0)
    diag = np.diag([stretch, det / stretch])
    return random_rotation(rng) @ diag @ random_rotation(rng)


def nonlinear_map(t2):
    """A smooth non-linear image-to-image map, L2 -> L1 (arcsec)."""
    x, y = t2.T
    return np.column_stack(
        [
            1.3 * x - 0.4 * y + 0.05 * x * y + 0.02 * np.sin(3 * y) + 7.0,
            -0.3 * x - 0.9 * y + 0.04 * x**2 - 0.03 * y**2 - 2.0,
        ]
    )


@pytest.fixture
def constellation():
    rng = np.random.default_rng(42)
    t2 = rng.normal(scale=0.5, size=(25, 2))
    return nonlinear_map(t2), t2


# --------------------------------------------------------------------------- exactness


@pytest.mark.parametrize("method", ALL_METHODS)
@pytest.mark.parametrize("det", [0.1, -0.1, 0.5, -1.0, 1.0, 3.0, -10.0, 10.0])
def test_affine_maps_recovered_exactly(method, det):
    rng = np.random.default_rng(abs(int(det * 100)) + (det < 0))
    for _ in range(3):
        A = random_affine(rng, det)
        t2 = rng.normal(size=(20, 2))
        t1 = t2 @ A.T + rng.normal(size=2) * 10
        J = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, method)
        assert J.shape == (20, 2, 2)
        np.testing.assert_allclose(
            J, np.broadcast_to(A, J.shape), rtol=0, atol=1e-10 * np.abs(A).max()
        )
        np.testing.assert_allclose(np.linalg.det(J), det, rtol=1e-10)


@pytest.mark.parametrize("method", ALL_METHODS)
def test_size_magnification_affine_and_parity(method):
    rng = np.random.default_rng(3)
    A = random_affine(rng, -2.5)
    t2 = rng.normal(size=(12, 2))
    t1 = t2 @ A.T
    tab = size_magnification(t1 * u.arcsec, t2 * u.arcsec, method, n_bootstrap=50, seed=1)
    assert isinstance(tab, QTable)
    np.testing.assert_allclose(tab["mu_size"], 2.5, rtol=1e-10)
    assert (tab["parity"] == -1).all()
    assert tab["jacobian"].shape == (12, 2, 2)
    assert (tab["mu_size_err"] > 0).all()
    assert (tab["mu_size_p16"] <= tab["mu_size_p50"]).all()
    assert (tab["mu_size_p50"] <= tab["mu_size_p84"]).all()
    assert tab.meta["method"] == method


def test_units_are_converted():
    rng = np.random.default_rng(5)
    t2 = rng.normal(size=(10, 2))
    t1 = nonlinear_map(t2)
    J_arcsec = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec)
    J_mixed = relative_jacobian((t1 / 3600) * u.deg, (t2 * 1000) * u.mas)
    np.testing.assert_allclose(J_mixed, J_arcsec, rtol=1e-12)


# --------------------------------------------------------------------------- invariances


@pytest.mark.parametrize("method", ALL_METHODS)
def test_common_rotation_translation(method, constellation):
    t1, t2 = constellation
    rng = np.random.default_rng(7)
    R = random_rotation(rng)
    shift = np.array([3.0, -1.5])
    J = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, method)
    Jr = relative_jacobian((t1 @ R.T + shift) * u.arcsec, (t2 @ R.T - shift) * u.arcsec, method)
    np.testing.assert_allclose(Jr, R @ J @ R.T, atol=1e-10)
    np.testing.assert_allclose(np.linalg.det(Jr), np.linalg.det(J), rtol=1e-10)


@pytest.mark.parametrize("method", ALL_METHODS)
def test_common_permutation(method, constellation):
    t1, t2 = constellation
    perm = np.random.default_rng(8).permutation(len(t1))
    J = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, method)
    Jp = relative_jacobian(t1[perm] * u.arcsec, t2[perm] * u.arcsec, method)
    np.testing.assert_allclose(Jp, J[perm], rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("method", ALL_METHODS)
@pytest.mark.parametrize("s", [0.3, 2.0])
def test_rescaling_arc_l1(method, s, constellation):
    t1, t2 = constellation
    a = size_magnification(t1 * u.arcsec, t2 * u.arcsec, method, n_bootstrap=20, seed=0)
    b = size_magnification(s * t1 * u.arcsec, t2 * u.arcsec, method, n_bootstrap=20, seed=0)
    np.testing.assert_allclose(b["mu_size"], s**2 * a["mu_size"], rtol=1e-10)
    np.testing.assert_allclose(b["jacobian"], s * a["jacobian"], rtol=1e-10, atol=1e-13)


def test_mirror_flips_parity(constellation):
    t1, t2 = constellation
    a = size_magnification(t1 * u.arcsec, t2 * u.arcsec, n_bootstrap=10, seed=0)
    b = size_magnification(t1 * [-1, 1] * u.arcsec, t2 * u.arcsec, n_bootstrap=10, seed=0)
    np.testing.assert_array_equal(b["parity"], -a["parity"])
    np.testing.assert_allclose(b["mu_size"], a["mu_size"], rtol=1e-12)


def test_common_rescaling_keeps_mu_size(constellation):
    """Both arcs scaled together: the Jacobian does not change."""
    t1, t2 = constellation
    J = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec)
    J2 = relative_jacobian(4 * t1 * u.arcsec, 4 * t2 * u.arcsec)
    np.testing.assert_allclose(J2, J, rtol=1e-10)


# --------------------------------------------------------------------------- references


@pytest.mark.parametrize("power", [2.0, 1.0, 3.5])
def test_quad_kernel_matches_numpy_reference(constellation, power):
    t1, t2 = constellation
    J = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "quad", weight_power=power)
    np.testing.assert_allclose(J, ref.jacobian_quad(t1, t2, power), rtol=1e-10, atol=1e-12)


def test_quad2_kernel_matches_numpy_reference(constellation):
    t1, t2 = constellation
    J = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "quad2")
    np.testing.assert_allclose(J, ref.jacobian_quad(t1, t2, order=2), rtol=1e-10, atol=1e-12)


def test_2v_kernel_matches_numpy_reference(constellation):
    t1, t2 = constellation
    J = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "2v")
    np.testing.assert_allclose(J, ref.jacobian_2v(t1, t2), rtol=1e-10, atol=1e-12)


def test_quad_qr_fallback_matches_reference():
    """Badly conditioned baselines take the QR path; it still matches lstsq."""
    rng = np.random.default_rng(11)
    x = rng.uniform(-1, 1, 15)
    t2 = np.column_stack([x, 1e-4 * rng.normal(size=15)])  # nearly collinear
    t1 = nonlinear_map(t2)
    J = np.empty((15, 2, 2))
    status = np.empty(15, dtype=np.int64)
    _kernels.relative_jacobians(t1, t2, _kernels.METHOD_QUAD, 2.0, 0.0, 1e10, J, status)
    assert (status == _kernels.STATUS_OK).all()
    np.testing.assert_allclose(J, ref.jacobian_quad(t1, t2), rtol=1e-6)


@pytest.mark.parametrize("method", ALL_METHODS)
def test_bootstrap_kernel_matches_reference(method, constellation):
    t1, t2 = constellation
    rng = np.random.default_rng(3)
    noise1 = rng.normal(scale=0.01, size=(20, len(t1), 2))
    noise2 = rng.normal(scale=0.01, size=(20, len(t1), 2))
    dets = np.empty((20, len(t1)))
    code = {"quad": 1, "quad2": 2, "2v": 0}[method]
    _kernels.bootstrap_determinants(
        t1, t2, noise1, noise2, code, 2.0, np.sin(np.deg2rad(5.0)), 1e10, dets
    )
    np.testing.assert_allclose(
        dets, ref.bootstrap_determinants(t1, t2, noise1, noise2, method), rtol=1e-9, atol=1e-12
    )


@pytest.mark.parametrize("method", ALL_METHODS)
def test_size_magnification_matches_reference(method, constellation):
    t1, t2 = constellation
    tab = size_magnification(
        t1 * u.arcsec, t2 * u.arcsec, method, sigma_pos=0.02 * u.arcsec, n_bootstrap=40, seed=9
    )
    mu, err, (p16, p50, p84) = ref.size_magnification(
        t1, t2, 0.02, 40, np.random.default_rng(9), method
    )
    np.testing.assert_allclose(tab["mu_size"], mu, rtol=1e-10)
    np.testing.assert_allclose(tab["mu_size_err"], err, rtol=1e-8)
    np.testing.assert_allclose(tab["mu_size_p50"], p50, rtol=1e-8)
    assert (tab["n_bootstrap_valid"] == 40).all()


def test_bootstrap_error_scales_with_sigma(constellation):
    t1, t2 = constellation
    small = size_magnification(
        t1 * u.arcsec, t2 * u.arcsec, sigma_pos=1 * u.mas, n_bootstrap=400, seed=1
    )
    large = size_magnification(
        t1 * u.arcsec, t2 * u.arcsec, sigma_pos=4 * u.mas, n_bootstrap=400, seed=1
    )
    ratio = np.median(large["mu_size_err"] / small["mu_size_err"])
    assert 3.0 < ratio < 5.0  # linear error propagation in the small-noise limit
    zero = size_magnification(
        t1 * u.arcsec, t2 * u.arcsec, sigma_pos=0 * u.arcsec, n_bootstrap=5, seed=1
    )
    np.testing.assert_allclose(zero["mu_size_err"], 0, atol=1e-12)


def test_seed_reproducible_and_generator_accepted(constellation):
    t1, t2 = constellation
    a = size_magnification(t1 * u.arcsec, t2 * u.arcsec, n_bootstrap=30, seed=5)
    b = size_magnification(
        t1 * u.arcsec, t2 * u.arcsec, n_bootstrap=30, seed=np.random.default_rng(5)
    )
    c = size_magnification(t1 * u.arcsec, t2 * u.arcsec, n_bootstrap=30, seed=6)
    np.testing.assert_array_equal(a["mu_size_err"], b["mu_size_err"])
    assert not np.array_equal(a["mu_size_err"], c["mu_size_err"])


def test_per_pair_sigma(constellation):
    t1, t2 = constellation
    n = len(t1)
    sig = np.full(n, 0.01)
    sig[0] = 0.0
    sig2 = np.vstack([sig, sig])
    a = size_magnification(
        t1 * u.arcsec, t2 * u.arcsec, sigma_pos=sig * u.arcsec, n_bootstrap=30, seed=2
    )
    b = size_magnification(
        t1 * u.arcsec, t2 * u.arcsec, sigma_pos=sig2 * u.arcsec, n_bootstrap=30, seed=2
    )
    np.testing.assert_array_equal(a["mu_size_err"], b["mu_size_err"])
    with pytest.raises(ValueError, match="sigma_pos must be a scalar, shape"):
        size_magnification(t1 * u.arcsec, t2 * u.arcsec, sigma_pos=[0.1, 0.2] * u.arcsec)


def test_chunked_bootstrap_is_consistent(monkeypatch, constellation):
    """Chunking the bootstrap (for memory) does not change its statistics."""
    from lensdual.estimators import core

    t1, t2 = constellation
    a = size_magnification(
        t1 * u.arcsec, t2 * u.arcsec, n_bootstrap=2000, seed=4, sigma_pos=0.01 * u.arcsec
    )
    monkeypatch.setattr(core, "_CHUNK_ENTRIES", 7 * len(t1))
    b = size_magnification(
        t1 * u.arcsec, t2 * u.arcsec, n_bootstrap=2000, seed=4, sigma_pos=0.01 * u.arcsec
    )
    np.testing.assert_allclose(b["mu_size_err"], a["mu_size_err"], rtol=0.15)


# --------------------------------------------------------------------------- 2v details


def test_2v_skips_collinear_nearest_neighbours():
    # a's two nearest neighbours are collinear with it; the third closes a triangle.
    t2 = np.array([[0.0, 0.0], [0.1, 0.0], [-0.12, 0.0], [0.0, 0.5], [0.3, 0.4]])
    A = np.array([[1.5, 0.2], [-0.3, 0.7]])
    t1 = t2 @ A.T
    J = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "2v")
    np.testing.assert_allclose(J[0], A, atol=1e-12)


def test_2v_nan_and_warning_when_no_triangle():
    t2 = np.column_stack([np.arange(5.0), np.zeros(5)])  # all collinear
    t1 = t2 * 2
    with pytest.warns(EstimatorWarning, match="no well-conditioned triangle for pair"):
        J = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "2v")
    assert np.isnan(J).all()


def test_quad_nan_and_warning_when_collinear():
    t2 = np.column_stack([np.arange(5.0), np.zeros(5)])
    t1 = t2 * 2
    with pytest.warns(EstimatorWarning, match="ill-conditioned least squares"):
        tab = size_magnification(
            t1 * u.arcsec, t2 * u.arcsec, sigma_pos=0 * u.arcsec, n_bootstrap=3
        )
    assert np.isnan(tab["mu_size"]).all()
    assert (tab["parity"] == 0).all()
    assert (tab["n_bootstrap_valid"] == 0).all()


def test_quad2_beats_quad_on_curved_map():
    """The second-order fit removes the curvature bias of the first-order one."""
    rng = np.random.default_rng(1)
    t2 = rng.normal(scale=1.0, size=(30, 2))
    t1 = nonlinear_map(t2)
    x, y = t2.T
    # analytic Jacobian of nonlinear_map
    true = np.empty((30, 2, 2))
    true[:, 0, 0] = 1.3 + 0.05 * y
    true[:, 0, 1] = -0.4 + 0.05 * x + 0.06 * np.cos(3 * y)
    true[:, 1, 0] = -0.3 + 0.08 * x
    true[:, 1, 1] = -0.9 - 0.06 * y
    mu_true = np.abs(np.linalg.det(true))
    err = {}
    for method in ALL_METHODS:
        J = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, method)
        err[method] = np.median(np.abs(np.abs(np.linalg.det(J)) / mu_true - 1))
    assert err["quad2"] < 0.5 * err["quad"]
    assert err["quad"] < 0.05


# --------------------------------------------------------------------------- bad input


GOOD = np.array([[0.0, 0.0], [1.0, 0.1], [0.2, 1.0], [1.3, 1.2]])


@pytest.mark.parametrize(
    ("t1", "t2", "kwargs", "exc", "match"),
    [
        (GOOD, GOOD * u.arcsec, {}, TypeError, "theta1 must be an astropy Quantity"),
        (GOOD * u.arcsec, GOOD * u.m, {}, TypeError, "theta2 must have angular units"),
        (
            GOOD[:, 0] * u.arcsec,
            GOOD * u.arcsec,
            {},
            ValueError,
            r"theta1 must have shape \(N, 2\)",
        ),
        (GOOD * u.arcsec, np.ones((4, 3)) * u.arcsec, {}, ValueError, "theta2 must have shape"),
        (GOOD * u.arcsec, GOOD[:3] * u.arcsec, {}, ValueError, "same number of pairs, got 4 and 3"),
        (GOOD[:2] * u.arcsec, GOOD[:2] * u.arcsec, {}, ValueError, "needs at least 3 pairs, got 2"),
        (
            np.where(GOOD == 0.1, np.nan, GOOD) * u.arcsec,
            GOOD * u.arcsec,
            {},
            ValueError,
            r"theta1 contains NaN or infinite positions at row\(s\) \[1\]",
        ),
        (
            GOOD * u.arcsec,
            np.where(GOOD == 1.2, np.inf, GOOD) * u.arcsec,
            {},
            ValueError,
            "theta2 contains NaN or infinite",
        ),
        (
            np.vstack([GOOD, GOOD[:1]]) * u.arcsec,
            np.vstack([GOOD, [[5, 5]]]) * u.arcsec,
            {},
            ValueError,
            r"theta1 contains duplicate positions \(rows \[0, 4\]\)",
        ),
        (GOOD * u.arcsec, GOOD * u.arcsec, {"method": "svd"}, ValueError, "method must be one of"),
        (GOOD * u.arcsec, GOOD * u.arcsec, {"method": None}, ValueError, "method must be one of"),
        (
            GOOD * u.arcsec,
            GOOD * u.arcsec,
            {"weight_power": -1},
            ValueError,
            "weight_power must be >= 0",
        ),
        (
            GOOD * u.arcsec,
            GOOD * u.arcsec,
            {"min_angle": 5},
            TypeError,
            "min_angle must be an angle",
        ),
        (
            GOOD * u.arcsec,
            GOOD * u.arcsec,
            {"min_angle": 95 * u.deg},
            ValueError,
            r"min_angle must be in \[0, 90\) deg",
        ),
    ],
)
def test_bad_input(t1, t2, kwargs, exc, match):
    with pytest.raises(exc, match=match):
        relative_jacobian(t1, t2, **kwargs)
    with pytest.raises(exc, match=match):
        size_magnification(t1, t2, **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"sigma_pos": -0.1 * u.arcsec}, ValueError, "sigma_pos must be finite and >= 0"),
        ({"sigma_pos": 0.06}, TypeError, "sigma_pos must be a Quantity with angular units"),
        ({"sigma_pos": 0.06 * u.s}, TypeError, "sigma_pos must be a Quantity with angular units"),
        ({"sigma_pos": [0.1, -1, 0.1, 0.1] * u.arcsec}, ValueError, "sigma_pos must be finite"),
        ({"n_bootstrap": 0}, ValueError, "n_bootstrap must be >= 1"),
        ({"n_bootstrap": 10.5}, TypeError, "n_bootstrap must be an integer"),
    ],
)
def test_bad_bootstrap_input(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        size_magnification(GOOD * u.arcsec, GOOD * u.arcsec, **kwargs)


def test_nan_percentiles_match_numpy():
    from lensdual.estimators.core import _nan_percentiles

    rng = np.random.default_rng(0)
    x = rng.normal(size=(57, 6))
    x[rng.random(x.shape) < 0.3] = np.nan
    x[:, 2] = np.nan  # no finite value at all
    x[:56, 3] = np.nan  # a single finite value
    n_valid = np.isfinite(x).sum(axis=0)
    got = _nan_percentiles(x, n_valid, (16.0, 50.0, 84.0))
    ok = n_valid > 0
    expected = np.nanpercentile(x[:, ok], [16, 50, 84], axis=0)
    np.testing.assert_allclose(got[:, ok], expected, rtol=1e-14)
    assert np.isnan(got[:, 2]).all()


def test_quad2_falls_back_to_quad_with_few_pairs():
    rng = np.random.default_rng(12)
    t2 = rng.normal(size=(5, 2))
    t1 = nonlinear_map(t2)
    with pytest.warns(EstimatorWarning, match=r"the first-order quad Jacobian is used"):
        J2 = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "quad2")
    J1 = relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, "quad")
    np.testing.assert_allclose(J2, J1, rtol=1e-10)
    # and the bootstrap of such a constellation is complete, not NaN
    with pytest.warns(EstimatorWarning, match="first-order quad"):
        tab = size_magnification(t1 * u.arcsec, t2 * u.arcsec, "quad2", n_bootstrap=20, seed=0)
    assert (tab["n_bootstrap_valid"] == 20).all()


# --------------------------------------------------------------------------- neighbour cap


def _exact_mu(t2):
    """|det J| of nonlinear_map, analytically."""
    x, y = t2.T
    jac = np.empty((len(x), 2, 2))
    jac[:, 0, 0] = 1.3 + 0.05 * y
    jac[:, 0, 1] = -0.4 + 0.05 * x + 0.06 * np.cos(3 * y)
    jac[:, 1, 0] = -0.3 + 0.08 * x
    jac[:, 1, 1] = -0.9 - 0.06 * y
    return np.abs(np.linalg.det(jac))


@pytest.mark.filterwarnings("ignore::lensdual.exceptions.EstimatorWarning")
@pytest.mark.parametrize("n", [7, 20, 50])
@pytest.mark.parametrize("method", ["adaptive", *ALL_METHODS])
def test_cap_leaves_small_constellations_unchanged(method, n):
    """Up to the cap every pair sees every point: identical to no cap, bit for bit."""
    rng = np.random.default_rng(n)
    t2 = rng.uniform(-1, 1, (n, 2))
    t1 = nonlinear_map(t2) + 0.003 * rng.standard_normal((n, 2))
    kw = {"sigma_pos": 0.003 * u.arcsec, "n_bootstrap": 30, "seed": 4}
    capped = _size_magnification(t1 * u.arcsec, t2 * u.arcsec, method, **kw)
    exact_cap = _size_magnification(t1 * u.arcsec, t2 * u.arcsec, method, max_neighbours=n,
                                    **kw)
    uncapped = _size_magnification(t1 * u.arcsec, t2 * u.arcsec, method, max_neighbours=None,
                                   **kw)
    assert capped.meta["max_neighbours"] == 64
    for col in ("mu_size", "ln_mu_size_err", "mu_size_p16", "mu_size_p84", "jacobian",
                "mu_size_status"):
        np.testing.assert_array_equal(capped[col], uncapped[col])
        np.testing.assert_array_equal(exact_cap[col], uncapped[col])


@pytest.mark.parametrize("method", ALL_METHODS)
def test_knn_rows_match_the_shared_row(method, constellation):
    """The per-pair (k-d tree) rows holding every point give the shared row's result."""
    from lensdual.estimators.core import _COND_MAX

    t1, t2 = constellation
    n = len(t1)
    rows = np.argsort(((t2[:, None] - t2[None]) ** 2).sum(-1), axis=1)  # by distance
    code = {"quad": 1, "quad2": 2, "2v": 0}[method]
    out = []
    for nbr in (_kernels.all_rows(n), rows):
        jac = np.empty((n, 2, 2))
        st = np.empty(n, dtype=np.int64)
        _kernels.relative_jacobians_knn(t1, t2, nbr, code, 2.0, np.sin(np.deg2rad(5.0)),
                                        _COND_MAX, jac, st)
        out.append(jac)
    np.testing.assert_allclose(out[1], out[0], rtol=1e-12, atol=1e-13)


def test_large_constellation_is_local_and_finite():
    """N = 2000 on a smooth map: finite, capped 2v equals uncapped; the capped Quad
    estimators are closer to the exact |det J| than the uncapped ones (whose far
    baselines, each weighing as much as a near one, average the curvature in)."""
    rng = np.random.default_rng(0)
    t2 = rng.uniform(-1.5, 1.5, (2000, 2))
    t1 = nonlinear_map(t2)
    mu = _exact_mu(t2)
    for method, tol_capped in (("2v", 0.1), ("quad", 0.03), ("quad2", 0.006)):
        capped = np.abs(np.linalg.det(relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, method)))
        full = np.abs(np.linalg.det(relative_jacobian(t1 * u.arcsec, t2 * u.arcsec, method,
                                                      max_neighbours=None)))
        assert np.isfinite(capped).all()
        err_capped = np.max(np.abs(capped / mu - 1))
        assert err_capped < tol_capped
        assert err_capped <= np.max(np.abs(full / mu - 1)) + 1e-12
        if method == "2v":
            np.testing.assert_array_equal(capped, full)
        else:  # measured: quad 12 %, quad2 1.8 %
            np.testing.assert_allclose(capped, full, rtol=0.15 if method == "quad" else 0.025)
    # the bootstrap keeps the rows of the measured positions: complete and finite
    tab = size_magnification(t1 * u.arcsec, t2 * u.arcsec, "quad", sigma_pos=2 * u.mas,
                             n_bootstrap=20, seed=1)
    assert (tab["n_bootstrap_valid"] == 20).all()
    assert np.isfinite(np.asarray(tab["ln_mu_size_err"])).all()


def test_large_constellation_adaptive_is_calibrated():
    """The capped adaptive estimator on 2000 noisy pairs: finite, pulls of width ~1;
    on 200 pairs it agrees with the uncapped one within its errors."""
    rng = np.random.default_rng(0)
    t2 = rng.uniform(-1.5, 1.5, (2000, 2))
    t1 = nonlinear_map(t2)
    mu = _exact_mu(t2)
    sig = 0.002
    o1 = t1 + sig * rng.standard_normal(t1.shape)
    o2 = t2 + sig * rng.standard_normal(t2.shape)
    tab = _size_magnification(o1 * u.arcsec, o2 * u.arcsec, sigma_pos=sig * u.arcsec)
    err = np.asarray(tab["ln_mu_size_err"])
    assert np.isfinite(np.asarray(tab["mu_size"])).all() and np.isfinite(err).all()
    assert np.mean(np.asarray(tab["mu_size_status"]) == "ok") > 0.99
    pull = np.log(np.asarray(tab["mu_size"]) / mu) / err
    q16, q84 = np.percentile(pull, [15.87, 84.13])
    assert 0.8 < 0.5 * (q84 - q16) < 1.2
    assert np.mean(np.abs(pull) > 3) < 0.01
    # capped vs uncapped on 200 pairs (measured: median difference 0.16 sigma;
    # the capped fit tries neighbourhoods above 16 points on a grid only, the
    # uncapped one every neighbourhood, also above 64 points)
    sub = slice(0, 200)
    kw = {"sigma_pos": sig * u.arcsec}
    a = _size_magnification(o1[sub] * u.arcsec, o2[sub] * u.arcsec, **kw)
    b = _size_magnification(o1[sub] * u.arcsec, o2[sub] * u.arcsec, max_neighbours=None, **kw)
    z = np.abs(np.log(np.asarray(a["mu_size"]) / np.asarray(b["mu_size"])))
    z /= np.hypot(np.asarray(a["ln_mu_size_err"]), np.asarray(b["ln_mu_size_err"]))
    assert np.median(z) < 0.4
    assert np.percentile(z, 90) < 1.5
    # the capped errors are as large or larger (fewer points; the pilot differs slightly)
    ratio = np.asarray(a["ln_mu_size_err"]) / np.asarray(b["ln_mu_size_err"])
    assert np.mean(ratio > 0.98) > 0.95


@pytest.mark.parametrize(
    ("value", "exc", "match"),
    [(2, ValueError, "max_neighbours must be >= 3"), (10.5, TypeError, "max_neighbours"),
     ("64", TypeError, "max_neighbours")],
)
def test_bad_max_neighbours(value, exc, match):
    with pytest.raises(exc, match=match):
        relative_jacobian(GOOD * u.arcsec, GOOD * u.arcsec, max_neighbours=value)
    with pytest.raises(exc, match=match):
        size_magnification(GOOD * u.arcsec, GOOD * u.arcsec, max_neighbours=value)
    t2 = np.random.default_rng(0).normal(size=(10, 2))
    with pytest.raises(ValueError, match="max_neighbours must be >= 7"):
        _size_magnification(nonlinear_map(t2) * u.arcsec, t2 * u.arcsec, max_neighbours=6)
