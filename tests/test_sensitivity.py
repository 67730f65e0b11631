"""Tests of lensdual.sensitivity (sub-halo flux excess) and its Numba kernels."""

import numpy as np
import pytest
from astropy import units as u
from scipy import ndimage

from lensdual import _sensitivity_kernels as K
from lensdual.sensitivity import (
    effective_radius,
    effective_radius_ellipse,
    flux_excess,
    flux_excess_distribution,
    micro_images,
    offsets_on_ellipse,
    subhalo_einstein_radius,
)

# L2 image of source 0 of smacs0723_analog(seed=0) (saddle, mu = -7.06)
A_SMACS = np.array([[-0.61630019, 0.12659241], [0.12659241, 0.20366946]])
# Table-1 sub-haloes at z_l = 0.39, z_s = 2.2 (tnfw_halo kwargs)
OVER = {"Rs": 0.015790810207090382, "alpha_Rs": 0.0028893862914270894,
        "r_trunc": 0.47372430621271144}
SMALL = {"Rs": 0.055259177154333324, "alpha_Rs": 0.001236409770070008,
         "r_trunc": 1.6577753146299996}


@pytest.mark.parametrize("Rs,alpha_Rs", [(0.35, 0.012), (0.0158, 0.00289), (2.0, 0.5)])
def test_tnfw_kernel_vs_lenstronomy(Rs, alpha_Rs):
    from lenstronomy.LensModel.lens_model import LensModel

    rt = 30 * Rs
    r = np.geomspace(1e-5, 1e3, 300) * Rs
    phi = np.linspace(0.1, 6.0, r.size)
    x, y = r * np.cos(phi), r * np.sin(phi)
    out = np.empty((r.size, 5))
    K.deflection_hessian_array(K.PROFILE_TNFW, Rs, K.tnfw_rho0(Rs, alpha_Rs), rt, x, y, out)
    lm = LensModel(["TNFW"])
    kw = [{"Rs": Rs, "alpha_Rs": alpha_Rs, "r_trunc": rt, "center_x": 0.0, "center_y": 0.0}]
    ax, ay = lm.alpha(x, y, kw)
    fxx, fxy, _, fyy = lm.hessian(x, y, kw)
    ref = np.column_stack([ax, ay, fxx, fxy, fyy])
    amp = np.hypot(ax, ay)[:, None]
    hmag = np.abs(ref[:, 2:]).max(axis=1, keepdims=True)
    err = np.hstack([np.abs(out[:, :2] - ref[:, :2]) / amp, np.abs(out[:, 2:] - ref[:, 2:]) / hmag])
    far = r > 0.01 * Rs  # r ~ Rs, r >> r_trunc, and down to 0.01 Rs
    assert err[far].max() < 1e-10
    # r << Rs: both implementations lose digits to the cancellation in g ~ x^2 ln x
    assert err[~far].max() < 5e-9


def test_unit_ellipse_on_point_mass_caustic():
    """Chang-Refsdal: the saddle caustic, mapped to offsets, has r_eff in [0.98, 1.15]."""
    te = 1.0
    for a, b in [(-0.6354, 0.2228), (-0.3, 0.3)]:
        A0 = np.diag([a, b])
        phi = np.linspace(0, 2 * np.pi, 20001)
        c = np.cos(2 * phi)
        disc = (b - a) ** 2 * c**2 + 4 * a * b
        ok = disc >= 0
        pts = []
        for sgn in (1, -1):
            s = ((b - a) * c[ok] + sgn * np.sqrt(disc[ok])) / 2
            good = s > 0
            r = te / np.sqrt(s[good])
            xx = np.column_stack([r * np.cos(phi[ok][good]), r * np.sin(phi[ok][good])])
            # det(A0 - H) = 0 there
            yy = xx @ A0.T - te**2 * xx / r[:, None] ** 2  # caustic (sub-halo frame)
            pts.append(-np.linalg.solve(A0, yy.T).T)  # offsets d putting the source on it
        d = np.vstack(pts)
        reff = effective_radius(d * u.arcsec, A0, te * u.arcsec)
        # the caustic hugs the unit ellipse near the cusps on the axis of the
        # negative eigenvalue (which lie exactly on it)
        assert 0.98 < reff.min() and reff.max() < 1.15
    axes, ang = effective_radius_ellipse(A_SMACS, 0.0232 * u.arcsec)
    assert axes.unit == u.arcsec and ang.unit == u.deg
    d = offsets_on_ellipse([1.0, 2.0], np.arange(0, 360, 30) * u.deg, A_SMACS, 0.0232 * u.arcsec)
    np.testing.assert_allclose(effective_radius(d, A_SMACS, 0.0232 * u.arcsec),
                               np.repeat([1.0, 2.0], 12), rtol=1e-12)


def test_point_mass_image_count_changes_at_caustic_cusps():
    """On the negative-eigenvalue axis the SMACS saddle caustic spans r_eff = 1.00-1.14."""
    te = 0.0232 * u.arcsec
    r = np.array([0.9, 0.99, 1.01, 1.05, 1.13, 1.15, 1.3])
    for angle in (0.0, 180.0):
        d = offsets_on_ellipse(r, [angle] * u.deg, A_SMACS, te)
        _, counts = flux_excess(A_SMACS, {"theta_E": te.value}, d, return_counts=True)
        np.testing.assert_array_equal(counts, [2, 2, 4, 4, 4, 2, 2])


@pytest.mark.parametrize("u_imp", [0.3, 1.0, 2.5])
def test_point_mass_isotropic_analytic(u_imp):
    lam = 0.5
    te = 0.02
    A0 = lam * np.eye(2)
    d = np.array([u_imp * te / np.sqrt(lam), 0.0]) * u.arcsec
    img = micro_images(A0, {"theta_E": te}, d)
    assert len(img) == 2
    expect = (u_imp**2 + 2) / (u_imp * np.sqrt(u_imp**2 + 4))
    assert np.abs(img["mu"]).sum() * lam**2 == pytest.approx(expect, rel=1e-9)
    assert flux_excess(A0, {"theta_E": te}, d)[0] == pytest.approx(expect, rel=1e-9)


def _brute_force(A0, sub, d, half, npix, rho):
    """Images by inverse ray shooting of a small source disk on a fine grid (lenstronomy)."""
    from lenstronomy.LensModel.lens_model import LensModel

    if "theta_E" in sub:
        lm = LensModel(["POINT_MASS"])
        kw = [{"theta_E": sub["theta_E"], "center_x": 0.0, "center_y": 0.0}]
    else:
        lm, kw = LensModel(["TNFW"]), [dict(sub, center_x=0.0, center_y=0.0)]
    g = (np.arange(npix) + 0.5) / npix * 2 * half - half
    X, Y = np.meshgrid(g, g, indexing="ij")
    ax, ay = lm.alpha(X.ravel(), Y.ravel(), kw)
    bx = A0[0, 0] * X.ravel() + A0[0, 1] * Y.ravel() - ax + A0[0, 0] * d[0] + A0[0, 1] * d[1]
    by = A0[1, 0] * X.ravel() + A0[1, 1] * Y.ravel() - ay + A0[1, 0] * d[0] + A0[1, 1] * d[1]
    inside = (np.hypot(bx, by) < rho).reshape(npix, npix)
    labels, n = ndimage.label(inside)
    area = (2 * half / npix) ** 2
    return n, inside.sum() * area / (np.pi * rho**2) * abs(np.linalg.det(A0))


@pytest.mark.parametrize("sub,d_over_te,expect_n", [
    (OVER, (0.15, 0.0), 3),      # super-critical, source inside the sub-halo caustic
    (OVER, (1.5, 0.3), 1),       # outside
    (SMALL, (0.3, 0.2), 1),      # sub-critical MCR sub-halo
    ({"theta_E": 0.0232}, (0.8, 0.3), 2),  # point mass outside its caustic
])
def test_micro_images_vs_brute_force(sub, d_over_te, expect_n):
    te = subhalo_einstein_radius(sub).value
    d = np.array(d_over_te) * te
    img = micro_images(A_SMACS, sub, d * u.arcsec)
    fe, cnt = flux_excess(A_SMACS, sub, d * u.arcsec, return_counts=True)
    assert len(img) == cnt[0] == expect_n
    assert fe[0] == pytest.approx(np.abs(img["mu"]).sum() * abs(np.linalg.det(A_SMACS)), rel=1e-12)
    # brute force in the sub-halo frame; box covering all images
    half = 1.2 * max(np.abs(np.column_stack([img["x"].value, img["y"].value]) - d).max(), te)
    n_bf, fe_bf = _brute_force(A_SMACS, sub, d, half, 2000, rho=0.01 * te)
    if "theta_E" not in sub:  # the point mass's central image is far below a pixel
        assert n_bf == expect_n
    assert fe[0] == pytest.approx(fe_bf, rel=0.05)


def test_flux_excess_far_and_distribution():
    te = subhalo_einstein_radius(OVER)
    t = flux_excess_distribution(A_SMACS, OVER, [0.2, 50.0], n_angles=12, theta_e=te)
    assert set(t.colnames) >= {"r_eff", "angle", "flux_excess", "n_images"}
    far = np.asarray(t["flux_excess"])[t["r_eff"] == 50.0]
    np.testing.assert_allclose(far, 1.0, atol=2e-3)
    near = np.asarray(t["flux_excess"])[t["r_eff"] == 0.2]
    assert near.max() > 1.5


def test_bad_input():
    with pytest.raises(ValueError, match="Rs"):
        flux_excess(A_SMACS, dict(OVER, Rs=-1.0), [0.01, 0] * u.arcsec)
    with pytest.raises(ValueError, match="theta_E"):
        micro_images(A_SMACS, {"theta_E": -0.01}, [0.01, 0] * u.arcsec)
    with pytest.raises(ValueError, match="offsets"):
        flux_excess(A_SMACS, OVER, np.empty((0, 2)) * u.arcsec)
    with pytest.raises(TypeError, match="offsets"):
        flux_excess(A_SMACS, OVER, [0.01, 0.0])
    with pytest.raises(ValueError, match="r_eff_values"):
        flux_excess_distribution(A_SMACS, OVER, [])
    with pytest.raises(ValueError, match="jacobian"):
        flux_excess(np.zeros((2, 2)), OVER, [0.01, 0] * u.arcsec)
    with pytest.raises(TypeError, match="subhalo"):
        flux_excess(A_SMACS, 3.0, [0.01, 0] * u.arcsec)
    with pytest.raises(ValueError, match="n_grid"):
        flux_excess(A_SMACS, OVER, [0.01, 0] * u.arcsec, n_grid=2)
    with pytest.raises(TypeError, match="theta_e"):
        effective_radius([[0.01, 0]] * u.arcsec, A_SMACS, 0.02)


def test_image_finder_converged_in_grid():
    """Coarse default grid vs a 4x finer grid in a 2x larger box: same images."""
    rng = np.random.default_rng(1)
    for sub in (OVER, {"theta_E": 0.0232}):
        te = subhalo_einstein_radius(sub).value
        # half uniform, half in the thin band around the negative-eigenvalue
        # axis where the saddle caustics lie
        lam, vec = np.linalg.eigh(A_SMACS)
        band = rng.uniform([-3, -0.4], [3, 0.4], (150, 2)) @ vec.T
        d = np.vstack([rng.uniform(-3, 3, (150, 2)), band]) * te * u.arcsec
        f1, c1 = flux_excess(A_SMACS, sub, d, return_counts=True)
        f2, c2 = flux_excess(A_SMACS, sub, d, return_counts=True, n_grid=800, box=20)
        np.testing.assert_array_equal(c1, c2)
        np.testing.assert_allclose(f1, f2, rtol=1e-8)
        assert (c1 >= 3).any()  # some placements inside the caustic


def test_detection_snr_map_serial_vs_executor():
    from concurrent.futures import ThreadPoolExecutor

    from lensdual.sensitivity import detection_snr_map

    kw = dict(jacobian=A_SMACS, sigma_lnsize=0.1, concentration=5.0, n_angles=8, n_grid=200)
    masses = [1e7, 1e8, 1e9] * u.Msun
    serial = detection_snr_map(masses, [0.25, 1.0, 3.0], **kw)
    with ThreadPoolExecutor(2) as ex:
        par = detection_snr_map(masses, [0.25, 1.0, 3.0], executor=ex, chunk_size=2, **kw)
    assert len(serial) == 9
    for c in serial.colnames:
        np.testing.assert_array_equal(np.asarray(serial[c]), np.asarray(par[c]))
    snr = np.asarray(serial["snr_p95"]).reshape(3, 3)
    assert (snr[:, 0] > snr[:, 2]).all()  # closer sub-haloes are easier to detect
    with pytest.raises(ValueError, match="sigma_lnsize"):
        detection_snr_map(masses, [1.0], **dict(kw, sigma_lnsize=-1.0))
    with pytest.raises(ValueError, match="masses"):
        detection_snr_map([-1e8] * u.Msun, [1.0], **kw)
    with pytest.raises(ValueError, match="concentration"):
        detection_snr_map(masses, [1.0], **dict(kw, concentration="nfw"))
    with pytest.raises(TypeError, match="executor"):
        detection_snr_map(masses, [1.0], executor=object(), **kw)


def test_plot_flux_excess_violin():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lensdual.sensitivity import plot_flux_excess_violin

    t = flux_excess_distribution(A_SMACS, OVER, [0.5, 1.0, 2.0], n_angles=8, n_grid=100)
    ax = plot_flux_excess_violin(t, mu_size_band=(0.9, 1.1))
    assert ax.get_xlabel() == r"$r_{\rm eff}$"
    plt.close(ax.figure)
    with pytest.raises(ValueError, match="table"):
        plot_flux_excess_violin({"r_eff": [1.0]})
