"""Tests of Lenstool's NFW (profile 12): kernels, parameter conversions, reader."""

import numpy as np
import pytest
from _lenstool_text import par_file
from astropy import constants as const
from astropy import units as u
from astropy.cosmology import FlatLambdaCDM

from lensdual.parametric import (
    LenstoolLensModel,
    read_lenstool,
)
from lensdual.parametric import _kernels as K

COSMO = FlatLambdaCDM(H0=70.0, Om0=0.3, Tcmb0=0.0)
ZL, ZS = 0.4, 2.0
# Lenstool's 1/G (include/constant.h), in Msun / (km/s)^2 / Mpc
G_LT = 1.0 / 2.325968e8 * u.Mpc * (u.km / u.s) ** 2 / u.Msun


# --------------------------------------------------------------------------- numpy twin
# Lenstool's own formulation (e_nfw.c, e_grad.c, e_grad2.c), written independently
# of the kernels: nfw_g and nfw_f with their arctanh / arctan branches, the
# pseudo-elliptical deflection, and the Hessian from kappa_eps and gamma_eps of
# Golse & Kneib (2002, eq. 17-18) and Dumet-Montoya et al. (2012).


def lt_g(x):
    x = np.asarray(x, dtype=float)
    lo, hi = x < 1, x > 1
    out = np.full_like(x, 1.0 + np.log(0.5))
    out[lo] = np.log(x[lo] / 2) + 2 / np.sqrt(1 - x[lo] ** 2) * np.arctanh(
        np.sqrt((1 - x[lo]) / (1 + x[lo])))
    out[hi] = np.log(x[hi] / 2) + 2 / np.sqrt(x[hi] ** 2 - 1) * np.arctan(
        np.sqrt((x[hi] - 1) / (x[hi] + 1)))
    return out


def lt_f(x):
    x = np.asarray(x, dtype=float)
    lo, hi = x < 1, x > 1
    out = np.full_like(x, 1.0 / 3.0)
    out[lo] = (1 - 2 / np.sqrt(1 - x[lo] ** 2) * np.arctanh(
        np.sqrt((1 - x[lo]) / (1 + x[lo])))) / (x[lo] ** 2 - 1)
    out[hi] = (1 - 2 / np.sqrt(x[hi] ** 2 - 1) * np.arctan(
        np.sqrt((x[hi] - 1) / (x[hi] + 1)))) / (x[hi] ** 2 - 1)
    return out


def lt_potential_radial(x):
    """h(x) with psi = b r_s h(x): dh/dx = g(x) / x."""
    x = np.asarray(x, dtype=float)
    out = 0.5 * np.log(x / 2) ** 2
    lo, hi = x < 1, x > 1
    out[lo] -= 0.5 * np.arccosh(1 / x[lo]) ** 2
    out[hi] += 0.5 * np.arccos(1 / x[hi]) ** 2
    return out


def twin(x, y, nfw):
    """alpha_x, alpha_y, f_xx, f_xy, f_yy of a sum of Lenstool NFWs."""
    out = np.zeros((5, len(x)))
    for xc, yc, theta, e, rs, b in nfw:
        cs, sn = np.cos(theta), np.sin(theta)
        dx, dy = x - xc, y - yc
        X, Y = dx * cs + dy * sn, -dx * sn + dy * cs
        u_ = np.sqrt((1 - e) * X**2 + (1 + e) * Y**2)
        dpl = b * rs / u_ * lt_g(u_ / rs)
        gx, gy = dpl * (1 - e) * X / u_, dpl * (1 + e) * Y / u_
        out[0] += gx * cs - gy * sn
        out[1] += gx * sn + gy * cs
        phi = np.arctan2(np.sqrt(1 + e) * Y, np.sqrt(1 - e) * X)
        kap = b / 2 / rs * lt_f(u_ / rs)
        gam = dpl / u_ - kap
        kap_e = kap + e * np.cos(2 * phi) * gam
        g1 = gam * np.cos(2 * phi) + e * kap
        g2 = -np.sqrt(1 - e * e) * gam * np.sin(2 * phi)
        loc = np.array([[kap_e - g1, g2], [g2, kap_e + g1]])
        rot = np.array([[cs, -sn], [sn, cs]])
        sky = np.einsum("ij,jkn,lk->iln", rot, loc, rot)
        out[2] += sky[0, 0]
        out[3] += sky[0, 1]
        out[4] += sky[1, 1]
    return out


def twin_potential(x, y, nfw):
    psi = np.zeros(len(x))
    for xc, yc, theta, e, rs, b in nfw:
        cs, sn = np.cos(theta), np.sin(theta)
        dx, dy = x - xc, y - yc
        X, Y = dx * cs + dy * sn, -dx * sn + dy * cs
        u_ = np.sqrt((1 - e) * X**2 + (1 + e) * Y**2)
        psi += b * rs * lt_potential_radial(u_ / rs)
    return psi


def random_nfw(rng, k, eps_max=0.5):
    return np.column_stack([rng.uniform(-5, 5, k), rng.uniform(-5, 5, k),
                            rng.uniform(-np.pi, np.pi, k), rng.uniform(0, eps_max, k),
                            rng.uniform(2, 40, k), rng.uniform(1, 20, k)])


def kernel(x, y, nfw):
    return K.nfw_deflection_hessian(np.ascontiguousarray(x), np.ascontiguousarray(y),
                                    np.ascontiguousarray(nfw)).T


# --------------------------------------------------------------------------- kernels


def test_radial_functions_match_mpmath():
    mp = pytest.importorskip("mpmath")
    mp.mp.dps = 40
    xs = np.concatenate([np.geomspace(1e-8, 1e4, 400), 1 + np.geomspace(1e-12, 0.3, 80),
                         1 - np.geomspace(1e-12, 0.3, 80), [1.0]])
    for x in xs:
        xm = mp.mpf(float(x))
        if xm < 1:
            h = mp.acosh(1 / xm) / mp.sqrt(1 - xm * xm)
        elif xm > 1:
            h = mp.acos(1 / xm) / mp.sqrt(xm * xm - 1)
        else:
            h = mp.mpf(1)
        g_ref = float(mp.log(xm / 2) + h)
        f_ref = float((1 - h) / (xm * xm - 1)) if xm != 1 else 1 / 3
        g, f = K.nfw_radial(float(x))
        assert g == pytest.approx(g_ref, rel=1e-13), x
        assert f == pytest.approx(f_ref, rel=1e-13), x


def test_kernels_match_numpy_twin():
    rng = np.random.default_rng(2)
    nfw = random_nfw(rng, 3)
    x = rng.uniform(-80, 80, 3000)
    y = rng.uniform(-80, 80, 3000)
    got = kernel(x, y, nfw)
    ref = twin(x, y, nfw)
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-11 * np.abs(b).max())
    np.testing.assert_array_equal(K.nfw_deflection(x, y, nfw), got[:2].T)
    np.testing.assert_array_equal(K.nfw_hessian(x, y, nfw), got[2:].T)
    np.testing.assert_allclose(K.nfw_convergence(x, y, nfw), 0.5 * (ref[2] + ref[4]),
                               rtol=1e-9)


def test_circular_limit_matches_lenstronomy_nfw():
    from lenstronomy.LensModel.lens_model import LensModel

    rs, b = 12.0, 5.0
    rng = np.random.default_rng(4)
    r = rs * np.concatenate([np.geomspace(1e-3, 0.999, 300), np.geomspace(1.001, 50, 300)])
    phi = rng.uniform(0, 2 * np.pi, r.size)
    x, y = 3.0 + r * np.cos(phi), -2.0 + r * np.sin(phi)
    got = kernel(x, y, np.array([[3.0, -2.0, 0.7, 0.0, rs, b]]))
    # alpha(r) = b g(x) / x, so the deflection at r_s is b g(1) = b (1 + ln 1/2)
    kw = [{"Rs": rs, "alpha_Rs": b * (1 + np.log(0.5)), "center_x": 3.0, "center_y": -2.0}]
    lm = LensModel(["NFW"])
    ref = (*lm.alpha(x, y, kw), *np.array(lm.hessian(x, y, kw))[[0, 1, 3]])
    for a, c in zip(got, ref, strict=True):
        np.testing.assert_allclose(a, c, rtol=1e-8, atol=1e-12)


def _lenstronomy_e1e2(eps, theta):
    """lenstronomy's (e1, e2) of a potential (1 -/+ eps) X^2 ... (q2e(q) = eps)."""
    q = np.sqrt((1 - eps) / (1 + eps))
    c = (1 - q) / (1 + q)
    return c * np.cos(2 * theta), c * np.sin(2 * theta)


@pytest.mark.parametrize("eps, theta", [(0.1, 0.3), (0.3, -1.2), (0.5, 2.0)])
def test_elliptical_matches_lenstronomy_nfw_ellipse_potential(eps, theta):
    from lenstronomy.LensModel.lens_model import LensModel

    rs, b = 20.0, 8.0
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-60, 60, 2000), rng.uniform(-60, 60, 2000)
    nfw = np.array([[1.0, 2.0, theta, eps, rs, b]])
    keep = away_from_rs(x, y, nfw[0])
    x, y = x[keep], y[keep]
    got = kernel(x, y, nfw)
    e1, e2 = _lenstronomy_e1e2(eps, theta)
    kw = [{"Rs": rs, "alpha_Rs": b * (1 + np.log(0.5)), "e1": e1, "e2": e2,
           "center_x": 1.0, "center_y": 2.0}]
    lm = LensModel(["NFW_ELLIPSE_POTENTIAL"])
    ax, ay = lm.alpha(x, y, kw)
    np.testing.assert_allclose(got[0], ax, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(got[1], ay, rtol=1e-10, atol=1e-12)
    # lenstronomy's own Hessian is a forward difference (step 1e-10) of a deflection
    # with ~1e-13 noise: compare with central differences of its deflection instead
    for a, c in zip(got[2:], lenstronomy_hessian(lm, x, y, kw), strict=True):
        np.testing.assert_allclose(a, c, rtol=1e-6, atol=1e-7)


def away_from_rs(x, y, nfw, tol=1e-3):
    """Points whose elliptical radius is not within ``tol`` of r_s, where lenstronomy's
    NFW functions lose precision (see test_radial_functions_match_mpmath for ours)."""
    xc, yc, theta, e, rs, _ = nfw
    dx, dy = x - xc, y - yc
    X = dx * np.cos(theta) + dy * np.sin(theta)
    Y = -dx * np.sin(theta) + dy * np.cos(theta)
    return np.abs(np.sqrt((1 - e) * X**2 + (1 + e) * Y**2) / rs - 1) > tol


def lenstronomy_hessian(lm, x, y, kw, h=1e-4):
    """f_xx, f_xy, f_yy from central differences of a lenstronomy deflection."""
    axp, ayp = lm.alpha(x + h, y, kw)
    axm, aym = lm.alpha(x - h, y, kw)
    bxp, byp = lm.alpha(x, y + h, kw)
    bxm, bym = lm.alpha(x, y - h, kw)
    fxy = 0.5 * ((ayp - aym) + (bxp - bxm)) / (2 * h)
    return (axp - axm) / (2 * h), fxy, (byp - bym) / (2 * h)


def test_derivatives_of_the_potential():
    """The deflection is the gradient of Lenstool's pseudo-elliptical potential, and
    the Hessian the derivative of the deflection."""
    rng = np.random.default_rng(6)
    nfw = random_nfw(rng, 2)
    x, y = rng.uniform(-50, 50, 500), rng.uniform(-50, 50, 500)
    h = 1e-4
    got = kernel(x, y, nfw)
    dpx = (twin_potential(x + h, y, nfw) - twin_potential(x - h, y, nfw)) / (2 * h)
    dpy = (twin_potential(x, y + h, nfw) - twin_potential(x, y - h, nfw)) / (2 * h)
    np.testing.assert_allclose(got[0], dpx, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(got[1], dpy, rtol=1e-6, atol=1e-7)
    h = 1e-5
    axp, ayp = kernel(x + h, y, nfw)[:2]
    axm, aym = kernel(x - h, y, nfw)[:2]
    bxp, byp = kernel(x, y + h, nfw)[:2]
    bxm, bym = kernel(x, y - h, nfw)[:2]
    np.testing.assert_allclose(got[2], (axp - axm) / (2 * h), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(got[3], (ayp - aym) / (2 * h), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(got[3], (bxp - bxm) / (2 * h), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(got[4], (byp - bym) / (2 * h), rtol=1e-6, atol=1e-8)


def test_centre_and_major_axis():
    nfw = np.array([[1.0, -1.0, np.deg2rad(30.0), 0.3, 10.0, 5.0]])
    out = kernel(np.array([1.0]), np.array([-1.0]), nfw)
    assert out[0, 0] == 0.0 and out[1, 0] == 0.0
    assert not np.isfinite(out[2, 0])
    # iso-convergence contours are elongated along angle_pos: at equal distance the
    # convergence is larger on the major axis than on the minor axis
    d = 4.0
    ang = np.deg2rad([30.0, 120.0])
    kap = K.nfw_convergence(1.0 + d * np.cos(ang), -1.0 + d * np.sin(ang), nfw)
    assert kap[0] > kap[1]


# --------------------------------------------------------------------------- reader

MEMBER = """\
potential G1
    profil        81
    x_centre      15.0
    y_centre      4.0
    ellipticite   0.2
    angle_pos     10.0
    core_radius   0.05
    cut_radius    8.0
    v_disp        180.0
    z_lens        0.4
    end
"""


def nfw_block(keys, name="halo", ellipticite=0.2, angle=35.0):
    lines = [f"potentiel {name}", "    profil        12", "    x_centre      2.0",
             "    y_centre     -1.0", f"    ellipticite   {ellipticite}",
             f"    angle_pos     {angle}"]
    lines += [f"    {k} {v}" for k, v in keys.items()]
    lines += ["    z_lens        0.4", "    end", ""]
    return "\n".join(lines)


def closed_form(c, m200):
    """r_s (kpc, arcsec), v_disp (km/s), rho_s, b0 (arcsec) of an NFW, from scratch."""
    rho_c = (3 * COSMO.H(ZL) ** 2 / (8 * np.pi * G_LT)).to(u.Msun / u.Mpc**3)
    r200 = (3 * m200 * u.Msun / (4 * np.pi * 200 * rho_c)) ** (1 / 3)
    rs = (r200 / c).to(u.kpc)
    rho_s = 200 / 3 * c**3 / (np.log(1 + c) - c / (1 + c)) * rho_c
    sigma = np.sqrt(8 / 3 * G_LT * rs**2 * rho_s).to(u.km / u.s)
    rs_arcsec = (rs / COSMO.angular_diameter_distance(ZL) * u.rad).to(u.arcsec)
    b0 = (6 * np.pi * (sigma / const.c) ** 2 * u.rad).to(u.arcsec)
    return {"rs_kpc": rs.value, "rs": rs_arcsec.value, "v_disp": sigma.value,
            "rhos": rho_s.value, "b0": b0.value, "r200_kpc": r200.to_value(u.kpc)}


C, M200 = 5.0, 8.0e14
REF = closed_form(C, M200)


def test_read_nfw_concentration_m200(tmp_path):
    model = read_lenstool(par_file(tmp_path, nfw_block({"concentration": C, "m200": M200}),
                                   MEMBER))
    t = model.potentials
    assert list(t["profile"]) == [12, 81]
    nfw = t[0]
    assert nfw["definition"] == "concentration, m200"
    assert nfw["scale_radius_kpc"].to_value(u.kpc) == pytest.approx(REF["rs_kpc"], rel=1e-12)
    assert nfw["scale_radius"].to_value(u.arcsec) == pytest.approx(REF["rs"], rel=1e-12)
    assert nfw["v_disp"].to_value(u.km / u.s) == pytest.approx(REF["v_disp"], rel=1e-12)
    assert nfw["b0"].to_value(u.arcsec) == pytest.approx(REF["b0"], rel=1e-12)
    assert nfw["concentration"] == C
    assert nfw["m200"].to_value(u.Msun) == pytest.approx(M200, rel=1e-12)
    assert nfw["r200_kpc"].to_value(u.kpc) == pytest.approx(REF["r200_kpc"], rel=1e-12)
    # the ellipticity of an NFW is that of the potential, used as given
    assert nfw["ellipticity"] == 0.2 and nfw["epsilon"] == 0.2
    assert np.isnan(nfw["core_radius"]) and np.isnan(t["scale_radius"][1])
    assert t["definition"][1] == "v_disp, core_radius, cut_radius"
    assert "1 dPIE + 1 NFW potentials" in repr(model)
    p12 = model.kernel_parameters(ZS, profile=12)
    assert p12.shape == (1, K.NFW_N_PARAMS)
    assert model.kernel_parameters(profile=81).shape == (1, K.N_PARAMS)
    with pytest.raises(ValueError, match="profile must be 81"):
        model.kernel_parameters(profile=8)


def test_conversion_independent_of_lenstronomy_units(tmp_path):
    """Cross-check with lenstronomy's own M200-c conversion (other constants: 1e-3)."""
    from lenstronomy.Cosmo.lens_cosmo import LensCosmo

    model = read_lenstool(par_file(tmp_path, nfw_block({"concentration": C, "m200": M200})))
    rs_l, alpha_rs_l = LensCosmo(ZL, ZS, COSMO).nfw_physical2angle(M200, C)
    p = model.kernel_parameters(ZS, profile=12)[0]
    assert p[K.NFW_RS] == pytest.approx(rs_l, rel=1e-3)
    assert p[K.NFW_B] * (1 + np.log(0.5)) == pytest.approx(alpha_rs_l, rel=1e-3)


def test_circular_model_matches_lenstronomy(tmp_path):
    from lenstronomy.LensModel.lens_model import LensModel

    path = par_file(tmp_path, nfw_block({"concentration": C, "m200": M200}, ellipticite=0.0))
    lm = read_lenstool(path).lens_model(ZS)
    dlsds = (COSMO.angular_diameter_distance(ZL, ZS) / COSMO.angular_diameter_distance(ZS)).value
    kw = [{"Rs": REF["rs"], "alpha_Rs": REF["b0"] * dlsds * (1 + np.log(0.5)),
           "center_x": 2.0, "center_y": -1.0}]
    rng = np.random.default_rng(7)
    x, y = rng.uniform(-100, 100, 2000), rng.uniform(-100, 100, 2000)
    xr = np.hypot(x - 2.0, y + 1.0) / REF["rs"]
    x, y = x[np.abs(xr - 1) > 1e-3], y[np.abs(xr - 1) > 1e-3]
    ref = LensModel(["NFW"])
    np.testing.assert_allclose(lm.alpha(x, y), ref.alpha(x, y, kw), rtol=1e-8)
    np.testing.assert_allclose(lm.hessian(x, y), ref.hessian(x, y, kw), rtol=1e-8,
                               atol=1e-14)


def test_elliptical_model_matches_lenstronomy(tmp_path):
    from lenstronomy.LensModel.lens_model import LensModel

    path = par_file(tmp_path, nfw_block({"concentration": C, "m200": M200}, ellipticite=0.25,
                                        angle=35.0))
    model = read_lenstool(path)
    lm = model.lens_model(ZS)
    dlsds = model.dls_ds(ZS)
    e1, e2 = _lenstronomy_e1e2(0.25, np.deg2rad(35.0))
    kw = [{"Rs": REF["rs"], "alpha_Rs": REF["b0"] * dlsds * (1 + np.log(0.5)), "e1": e1,
           "e2": e2, "center_x": 2.0, "center_y": -1.0}]
    rng = np.random.default_rng(8)
    x, y = rng.uniform(-100, 100, 2000), rng.uniform(-100, 100, 2000)
    keep = away_from_rs(x, y, (2.0, -1.0, np.deg2rad(35.0), 0.25, REF["rs"], 1.0))
    x, y = x[keep], y[keep]
    ref = LensModel(["NFW_ELLIPSE_POTENTIAL"])
    np.testing.assert_allclose(lm.alpha(x, y), ref.alpha(x, y, kw), rtol=1e-8)
    fxx, fxy, _, fyy = lm.hessian(x, y)
    for a, b in zip((fxx, fxy, fyy), lenstronomy_hessian(ref, x, y, kw), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)


def test_all_definitions_give_the_same_halo(tmp_path):
    """Each of Lenstool's NFW definitions of one halo gives the same r_s and v_disp."""
    m = closed_form(C, M200)
    kpc = COSMO.angular_diameter_distance(ZL).to_value(u.kpc) / 206264.80624709636
    r200 = m["r200_kpc"]
    cases = {
        "concentration, m200": {"concentration": C, "m200": M200},
        "concentration, r200": {"concentration": C, "r200_kpc": r200},
        "concentration, scale_radius": {"concentration": C, "scale_radius_kpc": m["rs_kpc"]},
        "scale_radius, m200": {"scale_radius": m["rs_kpc"] / kpc, "m200": M200},
        "scale_radius, r200": {"scale_radius_kpc": m["rs_kpc"], "virial_radius": r200 / kpc},
        "v_disp, scale_radius": {"v_disp": m["v_disp"], "scale_radius_kpc": m["rs_kpc"]},
        # Lenstool's aliases: c, masse, core_radius_kpc (the scale radius of an NFW)
        "concentration, m200 ": {"c": C, "masse": M200},
    }
    blocks = [nfw_block(keys, name=f"h{i}") for i, keys in enumerate(cases.values())]
    t = read_lenstool(par_file(tmp_path, *blocks)).potentials
    assert [d.strip() for d in t["definition"]] == [d.strip() for d in cases]
    np.testing.assert_allclose(t["scale_radius_kpc"].to_value(u.kpc), m["rs_kpc"], rtol=1e-10)
    np.testing.assert_allclose(t["v_disp"].to_value(u.km / u.s), m["v_disp"], rtol=1e-10)
    np.testing.assert_allclose(np.asarray(t["concentration"]), C, rtol=1e-9)
    np.testing.assert_allclose(t["m200"].to_value(u.Msun), M200, rtol=1e-9)


def test_mass_only_uses_maccio_relation(tmp_path):
    t = read_lenstool(par_file(tmp_path, nfw_block({"m200": 1e13}))).potentials
    # log10 c = 0.830 - 0.098 (log10 M200 - 12)
    c = 10 ** (0.830 - 0.098)
    assert t["concentration"][0] == pytest.approx(c, rel=1e-12)
    assert t["v_disp"][0].to_value(u.km / u.s) == pytest.approx(
        closed_form(c, 1e13)["v_disp"], rel=1e-12)
    assert t["definition"][0].startswith("m200")


def test_best_par_as_lenstool_writes_it(tmp_path):
    """All keys, rounded the way Lenstool writes best.par: consistent within rounding."""
    m = closed_form(C, M200)
    kpc = COSMO.angular_diameter_distance(ZL).to_value(u.kpc) / 206264.80624709636
    keys = {"scale_radius": f"{m['rs_kpc'] / kpc:.3f}",
            "scale_radius_kpc": f"{m['rs_kpc']:.3f}", "v_disp": f"{m['v_disp']:.3f}",
            "concentration": f"{C:.3f}", "m200": f"{M200:.3e}", "rhos": f"{m['rhos']:.3e}",
            "rc_slope": "0.000", "alpha": "0.000"}
    t = read_lenstool(par_file(tmp_path, nfw_block(keys))).potentials
    assert t["definition"][0] == "concentration, m200"  # Lenstool's precedence
    # a v_disp that does not match the halo is an error, not silently ignored
    keys["v_disp"] = f"{1.05 * m['v_disp']:.3f}"
    path = par_file(tmp_path, nfw_block(keys), name="bad.par")
    with pytest.raises(ValueError, match=r"bad.par, line 12, block 'potentiel halo', key "
                       r"'v_disp': .* disagrees by 5.0% with .* implied by concentration, "
                       r"m200"):
        read_lenstool(path)
    # concentration 0 and m200 0 mean "not given" (Lenstool writes them so)
    keys.update(v_disp=f"{m['v_disp']:.6f}", concentration="0.000", m200="0.000e+00",
                rhos="0.000e+00")
    t = read_lenstool(par_file(tmp_path, nfw_block(keys))).potentials
    assert t["definition"][0] == "v_disp, scale_radius"
    assert t["concentration"][0] == pytest.approx(C, rel=1e-5)


def test_ellipticity_conventions(tmp_path):
    base = {"concentration": C, "m200": M200}
    a = read_lenstool(par_file(tmp_path, nfw_block(base, ellipticite=0.3)))
    text = nfw_block(base, ellipticite=0.3).replace("ellipticite   0.3", "ellip_pot     0.1")
    b = read_lenstool(par_file(tmp_path, text, name="pot.par"))
    # Lenstool: the ellipticity of a profile-12 potential is 3 * ellip_pot
    assert b.potentials["epsilon"][0] == pytest.approx(0.3)
    x, y = np.linspace(-30, 30, 11), np.linspace(20, -25, 11)
    np.testing.assert_allclose(a.lens_model(ZS).alpha(x, y), b.lens_model(ZS).alpha(x, y),
                               rtol=1e-14)


@pytest.mark.parametrize("keys, match", [
    ({"concentration": 5.0}, r"line 4, block 'potentiel halo': the NFW \(profile 12\) is not "
     r"defined: give one of .*; it has concentration"),
    ({"v_disp": 1200.0}, r"line 4, block 'potentiel halo': the NFW .* it has v_disp"),
    ({}, r"it has none of these"),
    ({"concentration": -5.0, "m200": 1e14},
     r"line 10, block 'potentiel halo', key 'concentration': must be >= 0"),
    ({"scale_radius": -30.0, "m200": 1e14},
     r"line 10, block 'potentiel halo', key 'scale_radius': must be >= 0"),
    ({"m200": -1e14}, r"line 10, block 'potentiel halo', key 'm200': must be >= 0"),
    ({"concentration": 5.0, "r200": 0.0}, r"line 11, .* key 'r200': must be > 0"),
    ({"concentration": 5.0, "m200": 1e14, "alpha": 1.5},
     r"line 12, .* key 'alpha': must be 0 or 1 \(the generalised NFW"),
    ({"concentration": 5.0, "m200": 1e14, "core_radius": 0.2},
     r"line 12, .* key 'core_radius': 0.2 arcsec disagrees by .* with the .* arcsec implied "
     r"by concentration, m200"),
    ({"concentration": 5.0, "m200": 1e14, "sigma": 3.0},
     r"line 12, block 'potentiel halo': unknown key 'sigma' in a potential block of profile "
     r"12 \(NFW"),
    ({"concentration": 5.0, "m200": 1e14, "c": 4.0},
     r"line 12, block 'potentiel halo': key 'c' given twice \(first at line 10, as "
     r"'concentration'\)"),
    ({"concentration": "five", "m200": 1e14},
     r"line 10, block 'potentiel halo': the value 'five' of key 'concentration' is not a "
     r"number"),
])
def test_bad_nfw_blocks(tmp_path, keys, match):
    path = par_file(tmp_path, nfw_block(keys), name="bad.par")
    with pytest.raises(ValueError, match=match) as info:
        read_lenstool(path)
    assert "bad.par" in str(info.value)


def test_ellip_pot_too_large(tmp_path):
    text = nfw_block({"concentration": C, "m200": M200}).replace(
        "ellipticite   0.2", "ellip_pot     0.4")
    with pytest.raises(ValueError, match=r"line 8, .* key 'ellip_pot': must be in \[0, 1/3\)"):
        read_lenstool(par_file(tmp_path, text))


# --------------------------------------------------------------------------- mixed model


def test_mixed_model_sums_its_components(tmp_path):
    model = read_lenstool(par_file(tmp_path, nfw_block({"concentration": C, "m200": M200}),
                                   MEMBER))
    lm = model.lens_model(ZS)
    assert isinstance(lm, LenstoolLensModel)
    assert "1 dPIE + 1 NFW" in repr(lm)
    rng = np.random.default_rng(9)
    x, y = rng.uniform(-40, 40, 300), rng.uniform(-40, 40, 300)
    dpie = LenstoolLensModel(model.kernel_parameters(ZS, profile=81))
    nfw = LenstoolLensModel(nfw=model.kernel_parameters(ZS, profile=12))
    both = lm.alpha_hessian(x, y)
    parts = [a + b for a, b in zip(dpie.alpha_hessian(x, y), nfw.alpha_hessian(x, y),
                                   strict=True)]
    for a, b in zip(both, parts, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(lm.kappa(x, y), 0.5 * (both[2] + both[4]), rtol=1e-12)
    np.testing.assert_allclose(nfw.alpha(x, y), twin(x, y, nfw.nfw_params)[:2], rtol=1e-9)
    # many points over two threads: identical
    xx, yy = rng.uniform(-40, 40, 70000), rng.uniform(-40, 40, 70000)
    one = lm.alpha_hessian(xx, yy)
    two = model.lens_model(ZS, n_threads=2).alpha_hessian(xx, yy)
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(a, b)
    system = model.lens_system(ZS)
    assert [kw["center_x"] for kw in system.kwargs_lens] == [15.0, 2.0]
    theta = np.array([[5.0, 3.0], [-8.0, 1.0]]) * u.arcsec
    bx, by = lm.ray_shooting(theta[:, 0].value, theta[:, 1].value)
    np.testing.assert_allclose(system.ray_shoot(theta).to_value(u.arcsec),
                               np.column_stack([bx, by]))


def test_lens_model_validation():
    with pytest.raises(ValueError, match="at least one component"):
        LenstoolLensModel()
    with pytest.raises(ValueError, match=r"nfw must have shape \(M, 6\)"):
        LenstoolLensModel(nfw=np.zeros((1, 5)))
    with pytest.raises(ValueError, match="scale radius"):
        LenstoolLensModel(nfw=np.array([[0, 0, 0, 0.1, 0.0, 1.0]]))
    with pytest.raises(ValueError, match=r"NFW epsilon .* \[0, 1\)"):
        LenstoolLensModel(nfw=np.array([[0, 0, 0, 1.0, 3.0, 1.0]]))
    with pytest.raises(ValueError, match="finite"):
        LenstoolLensModel(nfw=np.array([[0, 0, 0, 0.1, np.nan, 1.0]]))
