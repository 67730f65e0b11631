"""Tests of lensdual.parametric: dPIE kernels, the Lenstool reader, SMACS0723."""

from pathlib import Path

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.cosmology import FlatLambdaCDM, LambdaCDM

from lensdual.parametric import (
    DPIELensModel,
    LenstoolModel,
    read_lenstool,
    read_lenstool_images,
)
from lensdual.parametric import _kernels as K
from lensdual.simulation import LensSystem

DATA = Path(__file__).parents[2] / "shared" / "data" / "smacs0723_mahler2022"
ARCSEC = 180 / np.pi * 3600
C_KMS = 299792.458


# --------------------------------------------------------------------------- numpy twin
# Lenstool's own formulation, written independently of the kernels (which use
# Keeton & Kochanek's real form): the complex cored-isothermal deflection of
# Kassiola & Kovner (Lenstool's ci05) and its complex derivatives.


def _kk_terms(X, Y, eps, rc):
    """ci05 and its X, Y derivatives for one core radius (eps > 0)."""
    sqe = np.sqrt(eps)
    cx1 = (1 - eps) / (1 + eps)
    cxro = (1 + eps) ** 2
    cyro = (1 - eps) ** 2
    w = np.sqrt(rc * rc + X * X / cxro + Y * Y / cyro)
    zci = -0.5j * (1 - eps * eps) / sqe
    znum = cx1 * X + 1j * (2 * sqe * w - Y / cx1)
    zden = X + 1j * (2 * rc * sqe - Y)
    q = zci * np.log(znum / zden)
    dqx = zci * ((cx1 + 2j * sqe * X / (cxro * w)) / znum - 1 / zden)
    dqy = zci * (1j * (2 * sqe * Y / (cyro * w) - 1 / cx1) / znum + 1j / zden)
    return q, dqx, dqy


def twin(x, y, params):
    """(alpha_x, alpha_y, f_xx, f_xy, f_yy) of a sum of dPIEs, plain numpy."""
    out = np.zeros((5, len(x)))
    for xc, yc, th, eps, a, s, b0 in params:
        c, sn = np.cos(th), np.sin(th)
        dx, dy = x - xc, y - yc
        X = dx * c + dy * sn
        Y = dy * c - dx * sn
        amp = b0 * s / (s - a)
        if eps == 0:  # Eliasdottir et al. 2007, eq. A23 and its derivative
            u2 = X * X + Y * Y
            g = amp * (np.sqrt(u2 + a * a) - a - np.sqrt(u2 + s * s) + s) / u2
            dg = amp * (0.5 / np.sqrt(u2 + a * a) - 0.5 / np.sqrt(u2 + s * s)) / u2 - g / u2
            qx, qy = g * X, g * Y
            hxx, hxy, hyy = g + 2 * dg * X * X, 2 * dg * X * Y, g + 2 * dg * Y * Y
        else:
            qa, dxa, dya = _kk_terms(X, Y, eps, a)
            qs, dxs, dys = _kk_terms(X, Y, eps, s)
            qx, qy = amp * (qa - qs).real, amp * (qa - qs).imag
            hxx = amp * (dxa - dxs).real
            hxy = amp * (dxa - dxs).imag
            hyy = amp * (dya - dys).imag
        out[0] += qx * c - qy * sn
        out[1] += qx * sn + qy * c
        out[2] += c * c * hxx - 2 * c * sn * hxy + sn * sn * hyy
        out[3] += c * sn * (hxx - hyy) + (c * c - sn * sn) * hxy
        out[4] += sn * sn * hxx + 2 * c * sn * hxy + c * c * hyy
    return out


def twin_kappa(x, y, params):
    """Convergence of a sum of dPIEs from the definition (Lenstool profile 81)."""
    kap = np.zeros_like(x)
    for xc, yc, th, eps, a, s, b0 in params:
        c, sn = np.cos(th), np.sin(th)
        X = (x - xc) * c + (y - yc) * sn
        Y = (y - yc) * c - (x - xc) * sn
        r2 = X**2 / (1 + eps) ** 2 + Y**2 / (1 - eps) ** 2
        kap += 0.5 * b0 * s / (s - a) * (1 / np.sqrt(a * a + r2) - 1 / np.sqrt(s * s + r2))
    return kap


def random_params(rng, m, eps_max=0.7):
    return np.column_stack([
        rng.uniform(-10, 10, m), rng.uniform(-10, 10, m), rng.uniform(-np.pi, np.pi, m),
        rng.uniform(0.01, eps_max, m), rng.uniform(0.01, 2.0, m), rng.uniform(3.0, 80.0, m),
        rng.uniform(0.1, 5.0, m),
    ])


# --------------------------------------------------------------------------- kernels


def test_circular_limit_matches_lenstronomy_pjaffe():
    from lenstronomy.LensModel.lens_model import LensModel

    rng = np.random.default_rng(1)
    m = 4
    params = random_params(rng, m)
    params[:, 3] = 0.0
    # kappa = b0/2 s/(s-a) (...) = sigma0 Ra Rs/(Rs-Ra) (...): sigma0 = b0 / (2 a)
    kwargs = [dict(sigma0=p[6] / (2 * p[4]), Ra=p[4], Rs=p[5], center_x=p[0], center_y=p[1])
              for p in params]
    lm = LensModel(["PJAFFE"] * m)
    x = rng.uniform(-40, 40, 3000)
    y = rng.uniform(-40, 40, 3000)
    x[:m], y[:m] = params[:, 0] + 1e-3, params[:, 1] - 2e-3  # near the centres
    ours = K.dpie_deflection_hessian(x, y, params)
    ax, ay = lm.alpha(x, y, kwargs)
    fxx, fxy, fyx, fyy = lm.hessian(x, y, kwargs)
    for mine, theirs in zip(ours.T, (ax, ay, fxx, fxy, fyy), strict=True):
        np.testing.assert_allclose(mine, theirs, rtol=1e-8, atol=1e-8 * np.abs(theirs).max())
    np.testing.assert_allclose(fxy, fyx, rtol=1e-12)


def test_elliptical_matches_lenstronomy_nie_pair():
    """Each term is Keeton's NIE: b = b0 s/(s-a) (1-eps), core (1+eps) r, q = (1-eps)/(1+eps)."""
    from lenstronomy.LensModel.Profiles.nie import NIEMajorAxis

    nie = NIEMajorAxis()
    rng = np.random.default_rng(2)
    b0, a, s, eps = 2.0, 0.4, 12.0, 0.35
    params = np.array([[0.0, 0.0, 0.0, eps, a, s, b0]])
    x = rng.uniform(-30, 30, 2000)
    y = rng.uniform(-30, 30, 2000)
    b = b0 * s / (s - a) * (1 - eps)
    q = (1 - eps) / (1 + eps)
    ax1, ay1 = nie.derivatives(x, y, b, (1 + eps) * a, q)
    ax2, ay2 = nie.derivatives(x, y, b, (1 + eps) * s, q)
    ours = K.dpie_deflection(x, y, params)
    np.testing.assert_allclose(ours[:, 0], ax1 - ax2, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ours[:, 1], ay1 - ay2, rtol=1e-10, atol=1e-12)


def test_hessian_matches_central_differences():
    rng = np.random.default_rng(3)
    params = random_params(rng, 5)
    x = rng.uniform(-30, 30, 500)
    y = rng.uniform(-30, 30, 500)
    h = 1e-4
    d = {}
    for name, dx, dy in (("xp", h, 0), ("xm", -h, 0), ("yp", 0, h), ("ym", 0, -h)):
        d[name] = K.dpie_deflection(x + dx, y + dy, params)
    hess = K.dpie_hessian(x, y, params)
    fxx = (d["xp"][:, 0] - d["xm"][:, 0]) / (2 * h)
    fyx = (d["xp"][:, 1] - d["xm"][:, 1]) / (2 * h)
    fxy = (d["yp"][:, 0] - d["ym"][:, 0]) / (2 * h)
    fyy = (d["yp"][:, 1] - d["ym"][:, 1]) / (2 * h)
    scale = np.abs(hess).max()
    for mine, num in ((hess[:, 0], fxx), (hess[:, 1], fxy), (hess[:, 1], fyx),
                      (hess[:, 2], fyy)):
        np.testing.assert_allclose(mine, num, rtol=0, atol=1e-6 * scale)


def test_deflection_matches_brute_force_integral_of_kappa():
    """alpha(theta) = 1/pi int kappa(theta') (theta - theta') / |theta - theta'|^2 d2theta'.

    In polar coordinates around theta the 1/rho cancels the area element:
    alpha = -1/pi int drho int dphi kappa(theta + rho e) e.
    """
    params = np.array([[0.5, -0.3, np.deg2rad(30.0), 0.3, 0.3, 3.0, 1.5]])
    nphi = 256
    phi = 2 * np.pi * np.arange(nphi) / nphi
    e = np.stack([np.cos(phi), np.sin(phi)])
    nodes, weights = np.polynomial.legendre.leggauss(48)
    edges = np.concatenate([[0.0], 0.25 * 2.0 ** np.arange(15)])  # up to 4096 arcsec
    for theta in ((1.0, 0.5), (-2.0, 1.5), (4.0, -3.0), (0.6, -0.2)):
        total = np.zeros(2)
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            rho = 0.5 * (hi - lo) * nodes + 0.5 * (hi + lo)
            w = 0.5 * (hi - lo) * weights
            px = theta[0] + rho[:, None] * e[0]
            py = theta[1] + rho[:, None] * e[1]
            kap = twin_kappa(px.ravel(), py.ravel(), params).reshape(px.shape)
            total -= (w[:, None, None] * kap[:, None, :] * e[None]).sum(axis=(0, 2))
        alpha = total * (2 * np.pi / nphi) / np.pi
        ours = K.dpie_deflection(np.array([theta[0]]), np.array([theta[1]]), params)[0]
        np.testing.assert_allclose(ours, alpha, rtol=1e-6, atol=1e-8)


def test_kernels_match_numpy_twin():
    rng = np.random.default_rng(4)
    params = random_params(rng, 12, eps_max=0.8)
    params[0, 3] = 0.0  # one circular component
    params[1, 3] = 1e-7  # one nearly circular
    x = rng.uniform(-50, 50, 4000)
    y = rng.uniform(-50, 50, 4000)
    ref = twin(x, y, params)
    both = K.dpie_deflection_hessian(x, y, params)
    alpha = K.dpie_deflection(x, y, params)
    hess = K.dpie_hessian(x, y, params)
    np.testing.assert_array_equal(both[:, :2], alpha)
    np.testing.assert_array_equal(both[:, 2:], hess)
    for i in range(5):
        scale = np.abs(ref[i]).max()
        np.testing.assert_allclose(both[:, i], ref[i], rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(K.dpie_convergence(x, y, params), twin_kappa(x, y, params),
                               rtol=1e-12)
    np.testing.assert_allclose(0.5 * (both[:, 2] + both[:, 4]), twin_kappa(x, y, params),
                               rtol=1e-10)


def test_kernels_are_regular_where_the_complex_formula_is_0_over_0():
    """Kassiola & Kovner's ratio is 0/0 at (X, Y) = (0, 2 a sqrt(eps)); the kernels are not."""
    eps, a, s = 0.3, 0.5, 10.0
    params = np.array([[0.0, 0.0, 0.0, eps, a, s, 1.0]])
    y0 = 2 * a * np.sqrt(eps)
    at = K.dpie_deflection_hessian(np.array([0.0]), np.array([y0]), params)[0]
    assert np.isfinite(at).all()
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    near = K.dpie_deflection_hessian(1e-7 * np.cos(ang), y0 + 1e-7 * np.sin(ang), params)
    np.testing.assert_allclose(near, np.broadcast_to(at, near.shape), rtol=0, atol=1e-6)


def test_elementary_functions_match_numpy():
    """The branch-free arctan and log of the kernels against numpy's (libm)."""
    rng = np.random.default_rng(6)
    x = np.concatenate([rng.uniform(-1, 1, 100000),
                        rng.choice([-1, 1], 100000) * 10 ** rng.uniform(-30, 30, 100000),
                        [0.0, -0.0, 0.66, np.nextafter(0.66, 1), 2.414213562373095, 1e300,
                         np.inf, -np.inf]])
    ref = np.arctan(x)
    got = K.atan_vec(x)
    np.testing.assert_array_equal(np.signbit(got), np.signbit(ref))
    assert (np.abs(got - ref) <= 1.0 * np.spacing(np.abs(ref))).all()
    u = np.concatenate([1 + 10 ** rng.uniform(-17, 0, 100000), 10 ** rng.uniform(0, 19.2, 100000),
                        [1.0, np.sqrt(2), 2.0, 65536.0, 2.0**32, 2.0**63]])
    ref = np.log(u)
    got = K.log_ge1_vec(u)
    assert (got[u == 1.0] == 0.0).all()
    assert (np.abs(got - ref) <= 2.0 * np.spacing(ref)).all()


def test_most_elongated_component():
    """At EPS_MAX the argument of the log stays in range and results stay exact."""
    params = np.array([[0.0, 0.0, 0.3, K.EPS_MAX, 0.2, 30.0, 1.0]])
    rng = np.random.default_rng(7)
    x = rng.uniform(-60, 60, 2000)
    y = rng.uniform(-60, 60, 2000)
    got = K.dpie_deflection_hessian(x, y, params)
    ref = twin(x, y, params)
    for i in range(5):
        np.testing.assert_allclose(got[:, i], ref[i], rtol=1e-8, atol=1e-8 * np.abs(ref[i]).max())
    with pytest.raises(ValueError, match="epsilon"):
        DPIELensModel(np.array([[0.0, 0.0, 0.3, 0.9995, 0.2, 30.0, 1.0]]))
    with pytest.raises(ValueError, match="core < cut"):
        DPIELensModel(np.array([[0.0, 0.0, 0.3, 0.2, 3.0, 3.0, 1.0]]))
    with pytest.raises(ValueError, match="shape"):
        DPIELensModel(np.zeros((2, 6)))


def test_near_circular_is_continuous():
    params = np.array([[1.0, 2.0, 0.7, 0.0, 0.3, 20.0, 2.0]])
    x = np.linspace(-10, 10, 101)
    y = 0.3 * x + 0.1
    circ = K.dpie_deflection_hessian(x, y, params)
    params[0, 3] = 1e-13
    ell = K.dpie_deflection_hessian(x, y, params)
    np.testing.assert_allclose(ell, circ, rtol=0, atol=1e-11)


# --------------------------------------------------------------------------- parser

PAR = """\
#Chi2tot(dof=3): 2.5
#7.0 z:2.000000 dlsds:0.700000
runmode
    reference     3 150.000000 -30.000000
    image  1 arcs.dat
    end
grille
    nombre    128
    nlens     2
    end
image
    z_m_limit 1 7.0 0 2.0 0.0 0.0
    end
potentiel O1
    profil        81
    x_centre      1.5
    y_centre     -2.0
    ellipticite   0.4
    angle_pos     30.0
    core_radius_kpc     50.0
    cut_radius_kpc     1000.0
    v_disp        900.0
    z_lens        0.4
    end
limit O1
    x_centre   1  -5.0 5.0 0.1
    v_disp     1  500 1200 1
    end
potential G2   # a member
    profile       81
    x_centre      10.0
    y_centre      5.0
    ellipticity   0.0
    angle_pos     0.0
    core_radius   0.05
    cut_radius    5.0
    v_disp        150.0
    mag           20.5
    z_lens        0.4
    end
cosmology
    model       1
    H0          70.0
    omegaM      0.3
    omegaX      0.7
    omegaK      0.
    wX          -1.0
    wa          0.0
    end
champ
    xmin -20
    end
fini
"""


def write(tmp_path, text, name="model.par"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.fixture
def small_model(tmp_path):
    return read_lenstool(write(tmp_path, PAR))


def test_read_small_file(small_model):
    model = small_model
    assert isinstance(model, LenstoolModel)
    assert len(model) == 2
    t = model.potentials
    assert list(t["name"]) == ["O1", "G2"]
    assert list(t["line"]) == [14, 29]
    assert model.z_lens == 0.4
    assert model.origin.ra.deg == 150.0 and model.origin.dec.deg == -30.0
    assert isinstance(model.cosmology, FlatLambdaCDM)
    assert model.cosmology.H0.value == 70.0 and model.cosmology.Om0 == 0.3
    assert model.fitted_redshifts == {"7": 2.0}
    assert model.meta == {"chi2": 2.5, "dof": 3}
    kpc = model.cosmology.angular_diameter_distance(0.4).to_value(u.kpc) / ARCSEC
    assert t["core_radius"][0].to_value(u.arcsec) == pytest.approx(50.0 / kpc, rel=1e-12)
    assert t["cut_radius"][0].to_value(u.arcsec) == pytest.approx(1000.0 / kpc, rel=1e-12)
    assert t["core_radius"][1] == 0.05 * u.arcsec
    assert t["core_radius_kpc"][1].to_value(u.kpc) == pytest.approx(0.05 * kpc)
    e = 0.4
    assert t["epsilon"][0] == pytest.approx((1 - np.sqrt(1 - e * e)) / e)
    assert t["epsilon"][1] == 0.0
    assert t["b0"][0].to_value(u.arcsec) == pytest.approx(6 * np.pi * (900 / C_KMS) ** 2 * ARCSEC)
    assert t["angle_pos"][0] == 30 * u.deg
    assert np.isnan(t["mag"][0]) and t["mag"][1] == 20.5
    assert "2 dPIE potentials" in repr(model)


def test_lens_model_scaling_and_interface(small_model):
    model = small_model
    z = 2.0
    dlsds = (model.cosmology.angular_diameter_distance(0.4, z)
             / model.cosmology.angular_diameter_distance(z)).value
    assert model.dls_ds(z) == pytest.approx(dlsds, rel=1e-12)
    lm = model.lens_model(z)
    unscaled = DPIELensModel(model.kernel_parameters())
    x = np.linspace(-20, 20, 7)
    y = np.linspace(-15, 25, 7)
    ax, ay = lm.alpha(x, y, [{"ignored": 1}])
    ux, uy = unscaled.alpha(x, y)
    np.testing.assert_allclose(ax, dlsds * ux, rtol=1e-13)
    bx, by = lm.ray_shooting(x, y, None)
    np.testing.assert_allclose(bx, x - ax)
    np.testing.assert_allclose(by, y - ay)
    fxx, fxy, fyx, fyy = lm.hessian(x, y, None)
    assert fxy is fyx or np.array_equal(fxy, fyx)
    np.testing.assert_allclose(lm.kappa(x, y), 0.5 * (fxx + fyy), rtol=1e-10)
    mu = lm.magnification(x, y, None)
    np.testing.assert_allclose(mu, 1 / ((1 - fxx) * (1 - fyy) - fxy * fyx), rtol=1e-12)
    g1, g2 = lm.gamma(x, y, None)
    np.testing.assert_array_equal(g1, 0.5 * (fxx - fyy))
    np.testing.assert_array_equal(g2, fxy)
    kappa = lm.kappa(x, y)
    np.testing.assert_allclose(mu, 1 / ((1 - kappa) ** 2 - g1**2 - g2**2), rtol=1e-9)
    both = lm.alpha_hessian(x, y)
    np.testing.assert_array_equal(both[0], ax)
    np.testing.assert_array_equal(both[4], fyy)
    # shapes follow the input, like lenstronomy
    xx, yy = np.meshgrid(x, y)
    gx, gy = lm.alpha(xx, yy)
    assert gx.shape == (7, 7)
    np.testing.assert_array_equal(gx[3], lm.alpha(xx[3], yy[3])[0])
    sx, sy = lm.alpha(1.0, 2.0)
    assert np.ndim(sx) == 0 and sx == lm.alpha(np.array([1.0]), np.array([2.0]))[0][0]
    with pytest.raises(TypeError, match="plain float arrays in arcsec"):
        lm.alpha(x * u.arcsec, y * u.arcsec)
    with pytest.raises(ValueError, match="z_source must be larger than z_lens"):
        model.lens_model(0.4)
    with pytest.raises(ValueError, match="z_source must be larger than z_lens"):
        model.lens_model(0.2)
    with pytest.raises(ValueError, match="z_source must be larger than z_lens"):
        model.lens_system(0.3)


def test_threads_give_identical_results(small_model):
    rng = np.random.default_rng(5)
    x = rng.uniform(-30, 30, 70000)
    y = rng.uniform(-30, 30, 70000)
    one = small_model.lens_model(2.0).alpha_hessian(x, y)
    two = small_model.lens_model(2.0, n_threads=2).alpha_hessian(x, y)
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="n_threads"):
        small_model.lens_model(2.0, n_threads=0)


def test_lens_system(small_model):
    system = small_model.lens_system(2.0)
    assert isinstance(system, LensSystem)
    assert system.z_lens == 0.4 and system.z_source == 2.0
    theta = np.array([[1.0, 2.0], [-5.0, 3.0]]) * u.arcsec
    beta = system.ray_shoot(theta)
    bx, by = small_model.lens_model(2.0).ray_shooting(theta[:, 0].value, theta[:, 1].value)
    np.testing.assert_allclose(beta.to_value(u.arcsec), np.column_stack([bx, by]))
    assert system.jacobian(theta).shape == (2, 2, 2)


def test_frames(small_model):
    model = small_model
    # 1 arcsec West of the reference: RA smaller, x = +1
    west = SkyCoord(150.0 - 1 / 3600 / np.cos(np.deg2rad(-30.0)), -30.0, unit="deg")
    north = SkyCoord(150.0, -30.0 + 2 / 3600, unit="deg")
    xy = model.to_model_frame(SkyCoord([west.ra, north.ra], [west.dec, north.dec]))
    np.testing.assert_allclose(xy.to_value(u.arcsec), [[1.0, 0.0], [0.0, 2.0]], atol=1e-9)
    assert model.to_model_frame(west).shape == (1, 2)
    pts = np.array([[12.5, -3.0], [-40.0, 22.0]]) * u.arcsec
    back = model.to_model_frame(model.to_sky(pts))
    np.testing.assert_allclose(back.to_value(u.arcsec), pts.value, atol=1e-9)
    with pytest.raises(TypeError, match="SkyCoord"):
        model.to_model_frame(pts)
    with pytest.raises(TypeError, match="Quantity"):
        model.to_sky(pts.value)


def test_sexagesimal_reference_and_wcs_centres(tmp_path):
    ref = SkyCoord(150.0, -30.0, unit="deg")
    hms, dms = ref.to_string("hmsdms", sep=":", precision=6).split()
    text = PAR.replace("reference     3 150.000000 -30.000000", f"reference 1 {hms} {dms}")
    x_wcs = 150.0 - 10.0 / 3600 / np.cos(np.deg2rad(-30.0))
    text = text.replace("x_centre      10.0", f"x_centre_wcs  {x_wcs:.12f}")
    text = text.replace("y_centre      5.0", f"y_centre_wcs  {-30.0 + 5.0 / 3600:.12f}")
    model = read_lenstool(write(tmp_path, text))
    assert model.origin.separation(ref).to_value(u.arcsec) < 1e-5
    assert model.potentials["x_centre"][1].to_value(u.arcsec) == pytest.approx(10.0, abs=1e-4)
    assert model.potentials["y_centre"][1].to_value(u.arcsec) == pytest.approx(5.0, abs=1e-4)


def test_cosmology_from_file_and_override(tmp_path):
    text = PAR.replace("omegaX      0.7", "omegaX      0.6").replace("omegaK      0.", "")
    model = read_lenstool(write(tmp_path, text))
    assert isinstance(model.cosmology, LambdaCDM) and model.cosmology.Ode0 == 0.6
    other = FlatLambdaCDM(H0=60, Om0=0.25)
    model = read_lenstool(write(tmp_path, PAR), cosmology=other)
    assert model.cosmology is other
    kpc = other.angular_diameter_distance(0.4).to_value(u.kpc) / ARCSEC
    assert model.potentials["core_radius"][0].to_value(u.arcsec) == pytest.approx(50.0 / kpc)
    with pytest.raises(TypeError, match="cosmology"):
        read_lenstool(write(tmp_path, PAR), cosmology="Planck18")
    with pytest.raises(TypeError, match="path"):
        read_lenstool(3)


@pytest.mark.parametrize("old, new, match", [
    # a block without end: the next block starts inside it
    ("    z_lens        0.4\n    end\nlimit O1", "    z_lens        0.4\nlimit O1",
     r"line 24: 'limit' inside block 'potentiel O1' opened at line 14: that block has no 'end'"),
    ("    v_disp        900.0", "    v_disp        9OO.0",
     r"line 22, block 'potentiel O1': the value '9OO.0' of key 'v_disp' is not a number"),
    ("    reference     3 150.000000 -30.000000\n", "",
     r"line 3: the runmode block has no 'reference'"),
    ("    mag           20.5", "    magnitude     20.5",
     r"line 38, block 'potential G2': unknown key 'magnitude'"),
    ("    profil        81", "    profil        99",
     r"line 15, block 'potentiel O1', key 'profile': unknown profile 99 is not supported"),
    # Lenstool reads the dPIE radii of this block as the NFW's scale radius and r200,
    # which then disagree with its v_disp
    ("    profil        81", "    profil        12",
     r"line 22, block 'potentiel O1', key 'v_disp': 900 km/s disagrees by .* implied by "
     r"scale_radius, r200"),
    ("    profil        81", "    profil        121",
     r"profile 121 \(triaxial NFW\) is not supported \(only profile 81, the dPIE, and "
     r"profile 12, the NFW\)"),
    ("    profil        81", "    profil        8",
     r"profile 8 \(PIEMD \(not truncated\)\) is not supported"),
    ("    cut_radius    5.0", "    cut_radius    0.01",
     r"line 29, block 'potential G2': the cut radius .* must be larger than the core"),
    ("    ellipticity   0.0", "    ellipticity   1.2",
     r"line 33, block 'potential G2', key 'ellipticity': must be in \[0, 1\)"),
    ("    ellipticity   0.0", "    ellipticity   0.99999999",
     r"line 29, block 'potential G2': ellipticity 0.99999999 .* too close to 1"),
    ("    mag           20.5\n", "    mag           20.5\n    v_disp 100\n",
     r"line 39, block 'potential G2': key 'v_disp' given twice \(first at line 37\)"),
    # (a z_lens that differs from the others' makes a multi-plane model: test_lenstool_hff.py)
    ("    z_lens        0.4\n    end\ncosmology", "    z_lens        -0.5\n    end\ncosmology",
     r"line 39, block 'potential G2', key 'z_lens': must be > 0"),
    ("    angle_pos     30.0\n", "    angle_pos     30.0 deg\n",
     r"line 19, block 'potentiel O1': key 'angle_pos' needs one value, got 2"),
    ("limit O1\n", "    x_centre 2.0\nlimit O1\n",
     r"line 25: 'x_centre' is not a Lenstool section"),
    ("    nlens     2", "    nlens     1", r"line 9: nlens = 1 but the file has 2 potential"),
    ("champ\n", "potfile\n    filein 1 members.cat\n    end\nchamp\n",
     r"line 50: potfile blocks .* are not supported"),
    ("    H0          70.0", "    H0          70.0\n    sigma8 0.8",
     r"line 44, block 'cosmology': unknown key 'sigma8'"),
    ("    v_disp        150.0\n", "", r"line 29, block 'potential G2': no 'v_disp'"),
])
def test_bad_files(tmp_path, old, new, match):
    assert PAR.count(old) == 1
    path = write(tmp_path, PAR.replace(old, new), name="bad.par")
    with pytest.raises(ValueError, match=match) as info:
        read_lenstool(path)
    assert "bad.par" in str(info.value)


def test_truncated_file(tmp_path):
    text = "\n".join(PAR.splitlines()[:39])  # stops inside the last potential
    with pytest.raises(ValueError, match=r"bad.par, line 39: end of file inside block "
                       r"'potential G2' opened at line 29: the block has no 'end' "
                       r"\(truncated file\?\)"):
        read_lenstool(write(tmp_path, text, name="bad.par"))


def test_no_runmode(tmp_path):
    text = PAR.replace("runmode\n    reference     3 150.000000 -30.000000\n"
                       "    image  1 arcs.dat\n    end\n", "")
    with pytest.raises(ValueError, match="no runmode block, so no 'reference'"):
        read_lenstool(write(tmp_path, text))


# --------------------------------------------------------------------------- images

ARCS = """\
1.1 149.9990000 -29.9990000 0.100 0.100 0 1.449 24.0
1.2 150.0010000 -30.0020000 0.100 0.100 0 1.449 24.5
7.1 150.0005000 -29.9995000 0.2 0.1 10 0.0 0.0
7.2 149.9995000 -30.0005000 0.2 0.1 10 0.0 0.0
"""


def test_read_images(tmp_path, small_model):
    images = read_lenstool_images(write(tmp_path, ARCS, "arcs.dat"), reference=small_model)
    assert list(images["id"]) == ["1.1", "1.2", "7.1", "7.2"]
    assert list(images["system"]) == ["1", "1", "7", "7"]
    assert list(images["image"]) == ["1", "2", "1", "2"]
    np.testing.assert_allclose(images["z"][:2], 1.449)
    assert np.isnan(images["z"][2:]).all()
    np.testing.assert_allclose(images["z_model"], [1.449, 1.449, 2.0, 2.0])
    xy = small_model.to_model_frame(images["sky"])
    np.testing.assert_allclose(images["x"].to_value(u.arcsec), xy[:, 0].value)
    np.testing.assert_allclose(images["y"].to_value(u.arcsec), xy[:, 1].value)
    assert images["x"][0] > 0  # RA below the reference: West, x > 0
    assert images["a"].unit == u.arcsec and images["theta"].unit == u.deg
    assert images["mag"][1] == 24.5
    # a relative catalogue in Lenstool's frame gives the same positions
    rel = "#REFERENCE 3 150.0 -30.0\n" + "\n".join(
        f"{i} {x:.9f} {y:.9f} 0.1 0.1 0 0 0" for i, x, y in
        zip(images["id"], images["x"].value, images["y"].value, strict=True))
    again = read_lenstool_images(write(tmp_path, rel, "rel.dat"), reference=small_model.origin)
    np.testing.assert_allclose(again["x"].value, images["x"].value, atol=1e-6)
    np.testing.assert_allclose(again["y"].value, images["y"].value, atol=1e-6)
    assert np.isnan(again["z_model"]).all()


@pytest.mark.parametrize("text, match", [
    ("1.1 149.999 -29.999 0.1 0.1 0\n", r"line 1: expected 7 or 8 columns"),
    ("1.1 149.999 -29.999 0.1 0.1 0 1.0\n1.1 149.999 -29.999 0.1 0.1 0 1.0\n",
     r"line 2: image '1.1' already given at line 1"),
    ("1.1 149.999 -29.999 0.1 0.1 0 x\n", r"line 1: the value 'x' of key 'z' is not a number"),
    ("#REFERENCE 2 10 10\n1.1 1 1 0.1 0.1 0 1.0\n", r"line 1: expected '#REFERENCE 0'"),
    ("# nothing\n", r"no images"),
])
def test_bad_images(tmp_path, small_model, text, match):
    with pytest.raises(ValueError, match=match):
        read_lenstool_images(write(tmp_path, text, "arcs.dat"), reference=small_model)


def test_images_reference_type(tmp_path):
    with pytest.raises(TypeError, match="reference must be a LenstoolModel or a scalar"):
        read_lenstool_images(write(tmp_path, ARCS, "arcs.dat"), reference=(150.0, -30.0))


# --------------------------------------------------------------------------- SMACS0723


@pytest.fixture(scope="module")
def smacs():
    if not (DATA / "best.par").is_file() or not (DATA / "arcs.dat").is_file():
        pytest.skip(f"SMACS0723 model not found in {DATA}")
    model = read_lenstool(DATA / "best.par")
    images = read_lenstool_images(DATA / "arcs.dat", reference=model)
    return model, images


def source_scatter(model, images, transform=None, x_sign=1.0):
    """Per-system rms distance of the traced images to their mean source position."""
    out = {}
    for system in dict.fromkeys(images["system"]):
        sel = images[images["system"] == system]
        z = sel["z_model"][0]
        if not np.isfinite(z):
            continue
        params = model.kernel_parameters(z)
        if transform is not None:
            params = transform(params.copy())
        bx, by = DPIELensModel(params).ray_shooting(x_sign * sel["x"].value, sel["y"].value)
        out[str(system)] = float(np.sqrt(np.mean((bx - bx.mean()) ** 2 + (by - by.mean()) ** 2)))
    return out


def test_smacs0723_reads(smacs):
    model, images = smacs
    assert len(model) == 149
    assert model.z_lens == 0.39
    assert model.meta == {"chi2": pytest.approx(30.9132), "dof": 32}
    assert model.fitted_redshifts["4"] == pytest.approx(2.174644)
    # the arcsec radii of the file agree with its kpc radii in its cosmology
    import re

    text = (DATA / "best.par").read_text()
    core_arcsec = [float(v) for v in re.findall(r"\n\s*core_radius\s+(\S+)", text)]
    np.testing.assert_allclose(model.potentials["core_radius"].to_value(u.arcsec), core_arcsec,
                               rtol=2e-5, atol=2e-6)
    # D_ls / D_s of the header, system 4 (Lenstool's own value)
    assert model.dls_ds(model.fitted_redshifts["4"]) == pytest.approx(0.720273, rel=1e-5)
    assert len(images) == 60 and set(images["system"]) >= {"1", "4", "26"}
    assert np.isfinite(images["z_model"]).all()  # every system has a redshift


def test_smacs0723_images_meet_in_the_source_plane(smacs):
    model, images = smacs
    rms = source_scatter(model, images)
    assert len(rms) == 21
    values = np.array(list(rms.values()))
    # Lenstool: chi2 = 30.9 for 32 dof with image-plane errors of 0.1-0.5 arcsec
    assert np.median(values) < 0.15
    assert values.max() < 0.35


def _flip_angle(p):
    p[:, 2] = -p[:, 2]
    return p


def _angle_from_north(p):
    p[:, 2] += np.pi / 2
    return p


def _epsilon_is_e(p, e):
    p[:, 3] = e
    return p


def _b0_4pi(p):
    p[:, 6] *= 4 / 6
    return p


def test_smacs0723_wrong_conventions_fail(smacs):
    """The convention check: each wrong convention scatters the sources by arcsec."""
    model, images = smacs
    e = np.asarray(model.potentials["ellipticity"], dtype=float)
    wrong = {
        "x to the East": dict(x_sign=-1.0),
        "angle clockwise": dict(transform=_flip_angle),
        "angle from North": dict(transform=_angle_from_north),
        "ellipticite used as epsilon": dict(transform=lambda p: _epsilon_is_e(p, e)),
        "b0 = 4 pi (sigma/c)^2": dict(transform=_b0_4pi),
    }
    good = np.median(list(source_scatter(model, images).values()))
    for name, kwargs in wrong.items():
        bad = np.median(list(source_scatter(model, images, **kwargs).values()))
        assert bad > 1.0 and bad > 10 * good, name


def test_smacs0723_lens_system(smacs):
    model, images = smacs
    system = model.lens_system(model.fitted_redshifts["4"])
    sel = images[images["system"] == "4"]
    theta = np.column_stack([sel["x"], sel["y"]])
    beta = system.ray_shoot(theta)
    assert beta.to_value(u.arcsec).std(axis=0).max() < 0.5
    mu = system.magnification(theta)
    assert np.isfinite(mu).all() and (np.abs(mu) > 1).all()


def test_smacs0723_predicted_images(smacs):
    """Lenstool's image-plane check: the images of the mean source land on the observed ones."""
    model, images = smacs
    for name in ("2", "5"):
        sel = images[images["system"] == name]
        system = model.lens_system(sel["z_model"][0])
        assert system.kwargs_lens[0] == {
            "center_x": model.potentials["x_centre"][0].value,
            "center_y": model.potentials["y_centre"][0].value}
        theta = np.column_stack([sel["x"], sel["y"]]).to_value(u.arcsec)
        beta = system.ray_shoot(theta * u.arcsec).mean(axis=0)
        found = system.solve_images(beta[None, :], half_width=60 * u.arcsec,
                                    grid_spacing=0.25 * u.arcsec)
        pred = np.column_stack([found["x"].to_value(u.arcsec), found["y"].to_value(u.arcsec)])
        dist = np.hypot(*(theta[:, None, :] - pred[None, :, :]).transpose(2, 0, 1)).min(axis=1)
        assert dist.max() < 0.5 and np.sqrt(np.mean(dist**2)) < 0.3, name


def test_smacs0723_parametric_comparison_from_sky(smacs):
    """Pairs measured on the sky (a frame about another reference) land where the
    model's own image positions are: mu_model equals the model's ratio there."""
    import matplotlib.pyplot as plt
    from astropy.table import QTable
    from astropy.wcs import WCS

    from lensdual.parametric import parametric_comparison

    model, images = smacs
    z = model.fitted_redshifts["4"]
    first, second = [], []
    for system in dict.fromkeys(images["system"]):
        rows = np.flatnonzero(images["system"] == system)
        names = list(images["image"][rows])
        if "1" in names and "2" in names:
            first.append(rows[names.index("1")])
            second.append(rows[names.index("2")])
    first, second = np.array(first), np.array(second)
    assert len(first) >= 15
    reference = images["sky"][first[0]]
    w = WCS(naxis=2)  # the pairs' tangent-plane frame: arcsec, x west, y north
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.crval = [reference.ra.deg, reference.dec.deg]
    w.wcs.crpix = [1.0, 1.0]
    w.wcs.cdelt = [-1 / 3600, 1 / 3600]
    tab = QTable()
    tab["pair_id"] = np.arange(1, len(first) + 1)
    for k, rows in (("1", first), ("2", second)):
        px, py = w.world_to_pixel(images["sky"][rows])
        tab[f"x{k}"], tab[f"y{k}"] = px * u.arcsec, py * u.arcsec
    for name, value in (("mu_flux", 1.0), ("mu_flux_err", 0.05), ("mu_size", 1.0),
                        ("mu_size_err", 0.1)):
        tab[name] = np.full(len(tab), value)
    tab.meta["reference"] = reference
    lm = model.lens_model(z)
    expect = np.abs(lm.magnification(images["x"][first].value, images["y"][first].value)
                    / lm.magnification(images["x"][second].value, images["y"][second].value))
    with_sky = QTable(tab, copy=True)
    with_sky["sky1"], with_sky["sky2"] = images["sky"][first], images["sky"][second]
    for table_in, lenstool in ((with_sky, DATA / "best.par"), (tab, model)):
        table, fig = parametric_comparison(table_in, lenstool=lenstool, z_source=z)
        np.testing.assert_allclose(table["mu_model"], expect, rtol=1e-6)
        plt.close(fig)


def test_a_byte_order_mark_is_not_part_of_the_file(tmp_path, small_model):
    """A Lenstool file saved with a UTF-8 byte-order mark reads as the same model."""
    path = tmp_path / "bom.par"
    path.write_bytes(b"\xef\xbb\xbf" + PAR.encode())
    model = read_lenstool(path)
    assert list(model.potentials["name"]) == list(small_model.potentials["name"])
    assert model.origin.ra.deg == small_model.origin.ra.deg
