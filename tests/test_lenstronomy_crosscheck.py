"""Cross-check of the estimators and the duality test against lenstronomy.

A power-law elliptical lens (EPL, slope 1.4: shallower than isothermal, so the
arcs are magnified radially too, as in a cluster) with external shear; a
constellation of 30 point sources just inside a fold of the tangential
caustic; image positions from lenstronomy's LensEquationSolver and the true
ratio ``|mu(L1)/mu(L2)|`` from lenstronomy's magnification.
"""

import numpy as np
import pytest
from astropy import units as u
from astropy.table import QTable
from scipy.optimize import brentq

from lensdual.duality import check_duality
from lensdual.estimators import size_magnification

lenstronomy = pytest.importorskip("lenstronomy")
from lenstronomy.LensModel.lens_model import LensModel  # noqa: E402
from lenstronomy.LensModel.Solver.lens_equation_solver import LensEquationSolver  # noqa: E402

THETA_E = 30.0
KWARGS = [
    {"theta_E": THETA_E, "gamma": 1.4, "e1": 0.1, "e2": 0.05, "center_x": 0.0, "center_y": 0.0},
    {"gamma1": 0.03, "gamma2": -0.02},
]


def _det_a(model, x, y):
    fxx, fxy, fyx, fyy = model.hessian(x, y, KWARGS)
    return (1 - fxx) * (1 - fyy) - fxy * fyx


@pytest.fixture(scope="module")
def fold_constellation():
    model = LensModel(["EPL", "SHEAR"])
    solver = LensEquationSolver(model)
    # a point of the tangential critical curve (det A changes sign near theta_E)
    phi = -0.6
    r_crit = brentq(
        lambda r: _det_a(model, r * np.cos(phi), r * np.sin(phi)), 0.5 * THETA_E, 1.5 * THETA_E
    )
    xc, yc = r_crit * np.cos(phi), r_crit * np.sin(phi)
    beta_c = np.array(model.ray_shooting(xc, yc, KWARGS))
    centre = 0.7 * beta_c  # just inside the fold caustic
    x0, y0 = solver.image_position_from_source(
        *centre, KWARGS, search_window=3 * THETA_E, min_distance=0.1, precision_limit=1e-12
    )
    mu0 = model.magnification(x0, y0, KWARGS)
    # the fold pair: the two most magnified images (opposite parity)
    top = np.argsort(-np.abs(mu0))[:2]
    assert np.sign(mu0[top[0]]) != np.sign(mu0[top[1]])
    ref1 = np.array([x0, y0])[:, top[np.argmax(mu0[top])]]  # positive parity: arc L1
    ref2 = np.array([x0, y0])[:, top[np.argmin(mu0[top])]]  # negative parity: arc L2

    rng = np.random.default_rng(2)
    sources = centre + 0.08 * rng.standard_normal((30, 2))
    theta = {1: [], 2: []}
    for beta in sources:
        for arc, ref in ((1, ref1), (2, ref2)):
            x, y = solver.image_position_from_source(
                *beta, KWARGS, search_window=4.0, x_center=ref[0], y_center=ref[1],
                min_distance=0.02, precision_limit=1e-12, num_iter_max=100,
            )
            k = np.argmin(np.hypot(x - ref[0], y - ref[1]))
            theta[arc].append([x[k], y[k]])
    t1, t2 = np.array(theta[1]), np.array(theta[2])
    # the images really solve the lens equation for their source
    for t in (t1, t2):
        np.testing.assert_allclose(np.column_stack(model.ray_shooting(*t.T, KWARGS)), sources,
                                   atol=1e-6)
    mu1 = model.magnification(*t1.T, KWARGS)
    mu2 = model.magnification(*t2.T, KWARGS)
    assert (mu1 > 0).all() and (mu2 < 0).all()
    return t1, t2, mu1, mu2


def test_quad_recovers_lenstronomy_magnification_ratio(fold_constellation):
    t1, t2, mu1, mu2 = fold_constellation
    true = np.abs(mu1 / mu2)
    tab = size_magnification(t1 * u.arcsec, t2 * u.arcsec, "quad", n_bootstrap=20, seed=0)
    frac = np.asarray(tab["mu_size"]) / true - 1
    assert np.median(np.abs(frac)) < 0.05
    assert (tab["parity"] == -1).all()  # a fold pair
    # the second-order estimator does better still
    tab2 = size_magnification(t1 * u.arcsec, t2 * u.arcsec, "quad2", n_bootstrap=20, seed=0)
    frac2 = np.asarray(tab2["mu_size"]) / true - 1
    assert np.median(np.abs(frac2)) < 0.5 * np.median(np.abs(frac))


def test_injected_flux_anomaly_is_flagged_alone(fold_constellation):
    t1, t2, mu1, mu2 = fold_constellation
    rng = np.random.default_rng(11)
    n = len(t1)
    intrinsic = 10 ** rng.uniform(1, 2, n)
    pairs = QTable()
    pairs["pair_id"] = np.arange(1, n + 1)
    pairs["x1"], pairs["y1"] = t1.T * u.arcsec
    pairs["x2"], pairs["y2"] = t2.T * u.arcsec
    anomalous = 7
    for band in ("F150W", "F200W"):
        f1 = np.abs(mu1) * intrinsic
        f2 = np.abs(mu2) * intrinsic
        f2[anomalous] *= 2.0
        for arc, f in (("1", f1), ("2", f2)):
            pairs[f"flux{arc}_{band}"] = f * (1 + 0.02 * rng.standard_normal(n)) * u.nJy
            pairs[f"flux_err{arc}_{band}"] = 0.02 * f * u.nJy
    res = check_duality(pairs, sigma_pos=0.01 * u.arcsec, n_bootstrap=500, seed=3)
    assert np.flatnonzero(res["anomalous"]).tolist() == [anomalous]
    np.testing.assert_allclose(res["duality_ratio"][anomalous], 0.5, rtol=0.15)
