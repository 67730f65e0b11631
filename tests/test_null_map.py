"""The null calibration's smooth map: a polyharmonic spline with data-chosen smoothing."""

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

from lensdual import _null_map
from lensdual._null_map import spline_map

#: scipy's name and polynomial degree of each kernel
SCIPY = {"quintic": ("quintic", 2), "tps": ("thin_plate_spline", 1)}


def _curved(t):
    x, y = t[:, 0], t[:, 1]
    return np.column_stack([1.3 * x + 0.2 * y + 0.3 * x**2 - 0.1 * y**3,
                            -0.7 * y + 0.1 * x * y + 0.2 * np.sin(2 * x)])


def _curved_jacobian(t):
    x, y = t[:, 0], t[:, 1]
    j = np.empty((len(t), 2, 2))
    j[:, 0, 0] = 1.3 + 0.6 * x
    j[:, 0, 1] = 0.2 - 0.3 * y**2
    j[:, 1, 0] = 0.1 * y + 0.4 * np.cos(2 * x)
    j[:, 1, 1] = -0.7 + 0.1 * x
    return j


def _scaled(t2):
    centre = t2.mean(axis=0)
    return (t2 - centre) / np.max(np.hypot(*(t2 - centre).T))


def _data(n, seed, noise=0.01, truth=_curved):
    """Pairs of ``truth`` with noise ``noise`` on L1 and ``noise / 2`` on L2."""
    rng = np.random.default_rng(seed)
    t2 = rng.uniform(-1, 1, (n, 2))
    sigma = np.vstack([np.full(n, noise), np.full(n, 0.5 * noise)])
    t1 = truth(t2) + noise * rng.standard_normal((n, 2))
    return t1, t2 + 0.5 * noise * rng.standard_normal((n, 2)), sigma


@pytest.mark.parametrize("kernel", ["quintic", "tps"])
@pytest.mark.parametrize("n, seed", [(8, 0), (15, 1), (40, 2)])
def test_the_spline_is_scipys_at_the_chosen_smoothing(n, seed, kernel, monkeypatch):
    """The fitted positions are scipy's RBFInterpolator of the same kernel with
    per-point smoothing lambda / w_i, and the Jacobian is its finite-difference
    derivative."""
    monkeypatch.setattr(_null_map, "KERNEL", kernel)
    t1, t2, sigma = _data(n, seed)
    m = spline_map(t1, t2, sigma)
    u = _scaled(t2)
    name, degree = SCIPY[kernel]
    ref = RBFInterpolator(u, t1, kernel=name, degree=degree, smoothing=m.smoothing / m.weights)
    np.testing.assert_allclose(m.mapped, ref(u), atol=1e-10)
    scale = np.max(np.hypot(*(t2 - t2.mean(axis=0)).T))
    h = 1e-6
    jac = np.empty((n, 2, 2))
    for k in range(2):
        step = np.zeros(2)
        step[k] = h
        jac[:, :, k] = (ref(u + step) - ref(u - step)) / (2 * h) / scale
    np.testing.assert_allclose(m.jacobian, jac, atol=1e-7)


def _explicit_ubre(t1, t2, w, lam):
    """UBRE of both coordinates from the explicit hat matrix (N x N solves)."""
    u = _scaled(t2)
    n = len(u)
    hat = np.empty((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1.0
        hat[:, j] = RBFInterpolator(u, e, kernel="quintic", degree=2, smoothing=lam / w)(u)
    resid = t1 - hat @ t1
    return float((w[:, None] * resid**2).sum() + 4 * np.trace(hat)), float(np.trace(hat))


def test_the_smoothing_minimises_the_unbiased_risk():
    """The chosen lambda minimises the UBRE computed from the explicit hat matrix,
    and the reported degrees of freedom are that matrix's trace."""
    t1, t2, sigma = _data(14, 3)
    m = spline_map(t1, t2, sigma)
    at_best, trace = _explicit_ubre(t1, t2, m.weights, m.smoothing)
    assert trace == pytest.approx(m.dof, rel=1e-8)
    for factor in (0.3, 0.7, 1.5, 3.0):
        assert _explicit_ubre(t1, t2, m.weights, factor * m.smoothing)[0] >= at_best - 1e-9


def test_an_affine_map_is_smoothed_to_the_polynomial_fit():
    """Pairs of an exactly affine map with noise: the data ask for no curvature, so
    the chosen spline is (nearly) the weighted fit of its quadratic polynomial part
    (6 degrees of freedom), with chi2/dof near 1."""
    a = np.array([[1.4, 0.3], [-0.2, 0.9]])
    dofs, chis = [], []
    for seed in range(20):
        t1, t2, sigma = _data(20, seed, truth=lambda t: t @ a.T)
        m = spline_map(t1, t2, sigma)
        dofs.append(m.dof)
        chis.append(m.chi2_dof)
    assert np.median(dofs) < 7.0  # the quadratic part has 6
    assert 0.7 < np.median(chis) < 1.3


def test_a_finely_sampled_curved_map_is_followed():
    """40 pairs of a curved map with small noise: the spline follows the curvature
    (more than its quadratic part's 6 degrees of freedom), its chi2/dof is near 1 and
    its Jacobian is near the truth, five times nearer than the affine fit's."""
    rng = np.random.default_rng(5)
    t2 = rng.uniform(-1, 1, (40, 2))
    sigma = np.full((2, 40), 0.001)
    t1 = _curved(t2) + 0.001 * rng.standard_normal((40, 2))
    m = spline_map(t1, t2, sigma)
    assert m.dof > 9.0
    assert 0.5 < m.chi2_dof < 1.6
    err = np.median(np.abs(m.jacobian - _curved_jacobian(t2)))
    p = np.column_stack([np.ones(40), t2])
    coef = np.linalg.lstsq(p, t1, rcond=None)[0]
    err_affine = np.median(np.abs(coef[1:].T[None] - _curved_jacobian(t2)))
    assert err < 0.2 * err_affine


def test_pairs_on_a_line_or_a_conic_give_a_map():
    """On a line (or a circle) some of the quadratic part's columns are dependent: the
    spline keeps the independent ones (a line leaves 3, as its affine fit) instead of
    failing on a singular matrix, and still follows the pairs within their errors."""
    s = np.linspace(-1, 1, 12)
    rng = np.random.default_rng(4)
    for t2, rank in ((np.column_stack([s, 0.5 * s]), 3),
                     (np.column_stack([np.cos(s + 1), np.sin(s + 1)]), 5)):
        t1 = _curved(t2) + 0.001 * rng.standard_normal(t2.shape)
        m = spline_map(t1, t2, np.full((2, 12), 0.001))
        assert np.isfinite(m.mapped).all() and np.isfinite(m.jacobian).all()
        assert m.dof >= rank - 1e-9
        assert np.abs(m.mapped - t1).max() < 0.005
