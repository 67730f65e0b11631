"""Tests of lensdual.sensitivity (sub-halo flux excess) and its Numba kernels."""

import numpy as np
import pytest
from astropy import units as u
from scipy import ndimage

from lensdual.abundance import einstein_radius
from lensdual.sensitivity import _kernels as K
from lensdual.sensitivity import (
    detection_snr_map,
    effective_radius,
    effective_radius_ellipse,
    flux_excess,
    flux_excess_distribution,
    micro_images,
    offsets_on_ellipse,
    plot_detection_snr_map,
    smacs0723_reference,
    subhalo_einstein_radius,
)
from lensdual.simulation.halos import mass_concentration, tnfw_halo

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


def _chang_refsdal_caustic_offsets(a, b, te=1.0):
    """Analytic caustic of a point mass in the field diag(a, b), as sub-halo offsets d.

    Critical curve: ``s^2 - s (b - a) cos(2 phi) - a b = 0`` with
    ``s = theta_E^2 / r^2``; its points map to the caustic
    ``y = A0 x - theta_E^2 x / r^2``, which the source reaches when the
    sub-halo sits at ``d = -A0^-1 y``.
    """
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
        yy = xx @ A0.T - te**2 * xx / r[:, None] ** 2
        pts.append(-np.linalg.solve(A0, yy.T).T)
    return A0, np.vstack(pts)


@pytest.mark.parametrize("a,b", [(-0.6354, 0.2228), (-0.3, 0.3)])
def test_unit_ellipse_on_point_mass_caustic(a, b):
    """Point mass in a uniform saddle field (Chang-Refsdal), analytic caustic.

    definition="caustic": the caustic lies at 0.98 <= r_eff <= 1.15, its
    cusps on the axis of the negative eigenvalue exactly at r_eff = 1.
    definition="paper" (|d| / theta_E): those cusps lie at 2 / sqrt(|a|).
    """
    te = 1.0
    A0, d = _chang_refsdal_caustic_offsets(a, b, te)
    reff = effective_radius(d * u.arcsec, A0, te * u.arcsec, definition="caustic")
    assert 0.98 < reff.min() and reff.max() < 1.15
    # on the x axis (eigenvalue a < 0) the critical curve has s = -a (a cusp:
    # y = 2 a r, d = -y / a = 2 theta_E / sqrt(-a)) and s = b (further out,
    # (b - a) / sqrt(-a b) >= 2 theta_E / sqrt(-a))
    on_axis = np.abs(d[:, 1]) < 1e-9 * np.abs(d[:, 0]).max()
    np.testing.assert_allclose(np.abs(d[on_axis, 0]).min(), 2 * te / np.sqrt(-a), rtol=1e-9)
    cusp = np.array([[2 * te / np.sqrt(-a), 0.0]]) * u.arcsec
    assert effective_radius(cusp, A0, te * u.arcsec, definition="caustic")[0] == pytest.approx(
        1.0, rel=1e-12)
    assert effective_radius(cusp, A0, te * u.arcsec)[0] == pytest.approx(2 / np.sqrt(-a),
                                                                         rel=1e-12)


def test_unit_ellipse_geometry():
    te = 0.0232 * u.arcsec
    lam, vec = np.linalg.eigh(A_SMACS)
    # paper: the Einstein ring mapped by A0, semi-axes |lambda_i| theta_E
    axes, ang = effective_radius_ellipse(A_SMACS, te)
    assert axes.unit == u.arcsec and ang.unit == u.deg
    np.testing.assert_allclose(axes.value, np.sort(np.abs(lam))[::-1] * te.value, rtol=1e-12)
    major = vec[:, np.argmax(np.abs(lam))]
    assert abs(np.cos(np.radians(ang.value)) * major[1]
               - np.sin(np.radians(ang.value)) * major[0]) < 1e-12
    axes_i, _ = effective_radius_ellipse(A_SMACS, te, plane="image")
    np.testing.assert_allclose(axes_i.value, [te.value, te.value], rtol=1e-12)
    # caustic: 2 theta_E / sqrt|lambda| in the image plane, 2 theta_E sqrt|lambda| in the source
    axes_c, _ = effective_radius_ellipse(A_SMACS, te, definition="caustic", plane="image")
    np.testing.assert_allclose(axes_c.value, np.sort(2 * te.value / np.sqrt(np.abs(lam)))[::-1],
                               rtol=1e-12)
    axes_cs, _ = effective_radius_ellipse(A_SMACS, te, definition="caustic")
    np.testing.assert_allclose(axes_cs.value, np.sort(2 * te.value * np.sqrt(np.abs(lam)))[::-1],
                               rtol=1e-12)
    ang = np.arange(0, 360, 30) * u.deg
    for definition in ("paper", "caustic"):
        d = offsets_on_ellipse([1.0, 2.0], ang, A_SMACS, te, definition=definition)
        reff = effective_radius(d, A_SMACS, te, definition=definition)
        np.testing.assert_allclose(reff, np.repeat([1.0, 2.0], 12), rtol=1e-12)
        # the same r_eff from the source-plane offsets -A0 d
        b = -(d.value @ A_SMACS.T) * u.arcsec
        np.testing.assert_allclose(
            effective_radius(b, A_SMACS, te, definition=definition, plane="source"), reff,
            rtol=1e-12)
    # paper: r_eff is the image-plane distance in Einstein radii
    d = [[0.0232, 0.0], [0.0, -0.0464], [0.03, 0.04]] * u.arcsec
    np.testing.assert_allclose(effective_radius(d, A_SMACS, te), [1.0, 2.0, 0.05 / 0.0232],
                               rtol=1e-12)
    # source-plane points of the unit circle of offsets lie on the source-plane ellipse
    b = offsets_on_ellipse([1.0], ang, A_SMACS, te).value @ A_SMACS.T
    axes, angle = effective_radius_ellipse(A_SMACS, te)
    c, s = np.cos(np.radians(angle.value)), np.sin(np.radians(angle.value))
    u1 = (b[:, 0] * c + b[:, 1] * s) / axes[0].value
    u2 = (-b[:, 0] * s + b[:, 1] * c) / axes[1].value
    np.testing.assert_allclose(u1**2 + u2**2, 1.0, rtol=1e-10)


def test_paper_unit_ellipse_follows_overconcentrated_caustic():
    """Fig. 7: the unit ellipse approximately follows the over-concentrated sub-halo's caustic.

    Table 1's 1e8 Msun, c = 100 TNFW on the analogue's L2 image: the
    placements with 3 micro-images (source inside the caustic) reach
    r_eff ~ 0.6 along the negative-eigenvalue axis and stay inside the unit
    ellipse; in the "caustic" definition they stay below 0.3.
    """
    te = 0.023213 * u.arcsec  # point-mass Einstein radius of 1e8 Msun
    g = np.linspace(-1.2, 1.2, 121) * te.value
    X, Y = np.meshgrid(g, g)
    d = np.column_stack([X.ravel(), Y.ravel()]) * u.arcsec
    _, counts = flux_excess(A_SMACS, OVER, d, return_counts=True, n_grid=200)
    inside = counts >= 3
    assert inside.sum() > 20
    r_paper = effective_radius(d[inside], A_SMACS, te)
    r_caustic = effective_radius(d[inside], A_SMACS, te, definition="caustic")
    assert 0.5 < r_paper.max() < 1.0
    assert r_caustic.max() < 0.3


def test_point_mass_image_count_changes_at_caustic_cusps():
    """Point mass: on the negative-eigenvalue axis the caustic spans r_eff = 1.00-1.14.

    (In the "caustic" definition.)
    """
    te = 0.0232 * u.arcsec
    r = np.array([0.9, 0.99, 1.01, 1.05, 1.13, 1.15, 1.3])
    for angle in (0.0, 180.0):
        d = offsets_on_ellipse(r, [angle] * u.deg, A_SMACS, te, definition="caustic")
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
    t = flux_excess_distribution(A_SMACS, OVER, [0.2, 50.0, 200.0], n_angles=12, theta_e=te)
    assert set(t.colnames) >= {"r_eff", "angle", "flux_excess", "n_images"}
    assert t.meta["definition"] == "paper"
    far = np.abs(np.asarray(t["flux_excess"]) - 1)
    # -> 1 as the sub-halo's shear, ~ (theta_E / r)^2, far from its centre
    assert far[t["r_eff"] == 200.0].max() < 2e-4
    ratio = far[t["r_eff"] == 50.0].max() / far[t["r_eff"] == 200.0].max()
    assert ratio == pytest.approx(16, rel=0.05)
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
    """Default grid vs cells half as wide in a box twice as large: same images."""
    rng = np.random.default_rng(1)
    for sub in (OVER, {"theta_E": 0.0232}):
        te = subhalo_einstein_radius(sub).value
        # half uniform, half in the thin band around the negative-eigenvalue
        # axis where the saddle caustics lie
        lam, vec = np.linalg.eigh(A_SMACS)
        band = rng.uniform([-3, -0.4], [3, 0.4], (150, 2)) @ vec.T
        d = np.vstack([rng.uniform(-3, 3, (150, 2)), band]) * te * u.arcsec
        f1, c1 = flux_excess(A_SMACS, sub, d, return_counts=True)
        f2, c2 = flux_excess(A_SMACS, sub, d, return_counts=True, n_grid=1600, box=20)
        np.testing.assert_array_equal(c1, c2)
        np.testing.assert_allclose(f1, f2, rtol=1e-8)
        assert (c1 >= 3).any()  # some placements inside the caustic


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


def test_detection_snr_map_matches_direct_computation():
    """Each row from flux_excess at the same placements, with numpy's percentiles."""
    masses = [3e7, 2e9] * u.Msun
    r = [0.3, 1.0, 2.5, 60.0]
    q = (50, 90)
    kw = dict(jacobian=A_SMACS, sigma_rel=0.1, concentration=5.0, n_angles=12, percentiles=q)
    t = detection_snr_map(masses, r, **kw)
    t_log = detection_snr_map(masses, r, **dict(kw, signal="log", sigma_rel=0.2))
    t_inv = detection_snr_map(masses, r, **dict(kw, signal="inverse"))
    assert len(t) == 8 and t["mass"].unit == u.Msun and t["theta_e"].unit == u.arcsec
    ang = np.arange(12) * 30.0 * u.deg
    for i, m in enumerate(masses):
        c = 5 * mass_concentration(m)
        sub = tnfw_halo(m, c, z_lens=0.39, z_source=2.2)
        te = einstein_radius(m, 0.39, 2.2)
        f = flux_excess(A_SMACS, sub, offsets_on_ellipse(r, ang, A_SMACS, te)).reshape(4, 12)
        rows = slice(4 * i, 4 * i + 4)
        np.testing.assert_allclose(t["concentration"][rows], c, rtol=1e-12)
        np.testing.assert_allclose(t["theta_e"][rows].value, te.value, rtol=1e-12)
        # the paper's Eq. (einstein-radius): 0.0232 arcsec (M / 1e8 Msun)^1/2
        np.testing.assert_allclose(t["theta_e"][rows].value, 0.0232 * np.sqrt(m.value / 1e8),
                                   rtol=1e-3)
        for name, tab, snr in [("ratio", t, np.abs(f - 1) / 0.1),
                               ("log", t_log, np.abs(np.log(f)) / 0.2),
                               ("inverse", t_inv, np.abs(1 / f - 1) / 0.1)]:
            np.testing.assert_allclose(tab["snr_mean"][rows], snr.mean(axis=1), rtol=1e-10,
                                       err_msg=name)
            for qq in q:
                np.testing.assert_allclose(tab[f"snr_p{qq}"][rows],
                                           np.percentile(snr, qq, axis=1), rtol=1e-10,
                                           err_msg=name)
        np.testing.assert_allclose(t["flux_excess_median"][rows], np.median(f, axis=1),
                                   rtol=1e-12)
    # far from the sub-halo there is no signal
    far = np.asarray(t["r_eff"]) == 60.0
    assert np.asarray(t["snr_p90"])[far].max() < 0.02


def test_detection_snr_map_reproduces_paper_statements():
    """Paper Sect. 5.2.3 on its Fig. 9, with the reproduction settings (see the docs).

    Over-concentrated (5 x MCR): 95th percentile of tens around the unit
    ellipse (measured 22 and 30), about 5 at r_eff = 2 (5.0 and 6.4); on the
    MCR: modest (median SNR < 3 beyond r_eff = 0.5, 95th percentile < 5 at
    r_eff >= 1).
    """
    masses = [1e8, 1e9] * u.Msun
    r = [0.5, 0.75, 1.0, 1.25, 2.0]
    kw = dict(jacobian=A_SMACS, sigma_rel=0.1, n_angles=36)
    over = detection_snr_map(masses, r, concentration=5.0, **kw)
    mcr = detection_snr_map(masses, r, **kw)
    p95 = np.asarray(over["snr_p95"]).reshape(2, 5)
    assert (p95[:, :4].max(axis=1) > 15).all()
    assert (p95[:, 4] > 4).all()
    assert (np.asarray(mcr["snr_p50"]) < 3).all()
    assert (np.asarray(mcr["snr_p95"]).reshape(2, 5)[:, 2:] < 5).all()
    assert (np.asarray(over["max_images"]) >= 3).any()
    assert (np.asarray(mcr["max_images"]) == 1).all()  # no extra critical curve on the MCR
    # the former normalisation (the point-mass caustic, "caustic") is 2.5-4x
    # further out and loses most of the signal: the first discrepancy found
    caustic = detection_snr_map(masses, r, concentration=5.0, definition="caustic", **kw)
    p95_caustic = np.asarray(caustic["snr_p95"]).reshape(2, 5)
    assert p95_caustic[:, 2:].max() < 5
    assert (p95[:, 1:4].max(axis=1) > 2.5 * p95_caustic[:, 1:4].max(axis=1)).all()


def test_detection_snr_map_serial_executor_dask_identical():
    """Chunks on a 2-worker dask LocalCluster (processes) and a thread pool give the serial map."""
    from concurrent.futures import ThreadPoolExecutor

    distributed = pytest.importorskip("distributed")
    masses = np.geomspace(1e7, 1e9, 5) * u.Msun
    r = [0.25, 1.0, 2.0]
    kw = dict(jacobian=A_SMACS, sigma_rel=0.1, concentration=5.0, n_angles=8, n_grid=150,
              seed=7)
    serial = detection_snr_map(masses, r, **kw)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        on_dask = detection_snr_map(masses, r, client=client, chunk_size=2, **kw)
    with ThreadPoolExecutor(2) as ex:
        on_threads = detection_snr_map(masses, r, executor=ex, chunk_size=3, **kw)
    assert len(serial) == 15
    for other in (on_dask, on_threads):
        assert other.colnames == serial.colnames
        for c in serial.colnames:
            np.testing.assert_array_equal(np.asarray(serial[c]), np.asarray(other[c]))
    # the seed sets the angles (per mass and r_eff), and it matters
    reseeded = detection_snr_map(masses, r, **dict(kw, seed=8))
    assert not np.array_equal(np.asarray(serial["snr_p50"]), np.asarray(reseeded["snr_p50"]))
    # a Generator is accepted and reproducible
    g1, g2 = (detection_snr_map(masses[:2], r, **dict(kw, seed=np.random.default_rng(3)))
              for _ in range(2))
    np.testing.assert_array_equal(np.asarray(g1["snr_p95"]), np.asarray(g2["snr_p95"]))


def test_detection_snr_map_bad_input():
    kw = dict(jacobian=A_SMACS, sigma_rel=0.1, n_angles=4, n_grid=50)
    m = [1e8] * u.Msun
    with pytest.raises(ValueError, match="masses must be finite and positive"):
        detection_snr_map([-1e8] * u.Msun, [1.0], **kw)
    with pytest.raises(TypeError, match="masses"):
        detection_snr_map([1e8], [1.0], **kw)
    with pytest.raises(ValueError, match="masses must be a non-empty"):
        detection_snr_map([] * u.Msun, [1.0], **kw)
    with pytest.raises(ValueError, match="r_eff must be a non-empty"):
        detection_snr_map(m, [], **kw)
    with pytest.raises(ValueError, match="r_eff must be finite and >= 0"):
        detection_snr_map(m, [-1.0], **kw)
    with pytest.raises(ValueError, match="z_source must be larger than z_lens"):
        detection_snr_map(m, [1.0], z_lens=0.5, z_source=0.5, **kw)
    with pytest.raises(ValueError, match="percentiles"):
        detection_snr_map(m, [1.0], percentiles=(50, 101), **kw)
    with pytest.raises(ValueError, match="sigma_rel"):
        detection_snr_map(m, [1.0], **dict(kw, sigma_rel=-1.0))
    with pytest.raises(ValueError, match="sigma_rel is required"):
        detection_snr_map(m, [1.0], jacobian=A_SMACS)
    with pytest.raises(ValueError, match="not both"):
        detection_snr_map(m, [1.0], sigma_pos=0.01 * u.arcsec, **kw)
    with pytest.raises(ValueError, match="concentration"):
        detection_snr_map(m, [1.0], **dict(kw, concentration="nfw"))
    with pytest.raises(ValueError, match="concentration"):
        detection_snr_map(m, [1.0], **dict(kw, concentration=0.0))
    with pytest.raises(ValueError, match="signal"):
        detection_snr_map(m, [1.0], signal="snr", **kw)
    with pytest.raises(ValueError, match="definition"):
        detection_snr_map(m, [1.0], definition="oguri", **kw)
    with pytest.raises(ValueError, match="seed"):
        detection_snr_map(m, [1.0], seed=-1, **kw)
    with pytest.raises(TypeError, match="client"):
        detection_snr_map(m, [1.0], client=object(), **kw)
    with pytest.raises(ValueError, match="not both"):
        detection_snr_map(m, [1.0], client=object(), executor=object(), **kw)
    with pytest.raises(ValueError, match="chunk_size"):
        detection_snr_map(m, [1.0], chunk_size=0, **kw)
    with pytest.raises(ValueError, match="plane"):
        effective_radius([0.01, 0] * u.arcsec, A_SMACS, 0.02 * u.arcsec, plane="lens")
    with pytest.raises(ValueError, match="definition"):
        effective_radius_ellipse(A_SMACS, 0.02 * u.arcsec, definition=None)
    with pytest.raises(ValueError, match="image must be 1 or 2"):
        smacs0723_reference(image=3)


def test_smacs0723_reference_images():
    l2 = smacs0723_reference()
    l1 = smacs0723_reference(image=1, sigma_pos=0.005 * u.arcsec)
    np.testing.assert_allclose(l2["jacobian"], A_SMACS, atol=1e-6)
    lam1, lam2 = np.linalg.eigvalsh(l1["jacobian"]), np.linalg.eigvalsh(l2["jacobian"])
    assert (lam1 < 0).all() and lam2[0] < 0 < lam2[1]  # L1 a maximum, L2 a saddle
    # the same pair: mu_size = |mu(L1) / mu(L2)| to the estimator's accuracy
    assert l1["mu_size"] == pytest.approx(l2["mu_size"], rel=1e-12)
    assert l2["mu_size"] == pytest.approx(abs(l1["mu_macro"] / l2["mu_macro"]), rel=0.02)
    # the compact constellation: large relative error at the paper's 0.06 arcsec
    assert l2["sigma_rel"] > 0.5 and 0.05 < l1["sigma_rel"] < 0.2


def test_plot_detection_snr_map():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = detection_snr_map([1e7, 1e8, 1e9] * u.Msun, [0.5, 1.0, 2.0], jacobian=A_SMACS,
                          sigma_rel=0.1, concentration=5.0, n_angles=6, n_grid=100)
    axes, mesh = plot_detection_snr_map(t)
    assert len(axes) == 3 and axes[0].get_yscale() == "log"
    assert "95" in axes[2].get_title()
    assert mesh.get_array().size == 9
    plt.close(axes[0].figure)
    with pytest.raises(ValueError, match="columns"):
        plot_detection_snr_map(t, columns=["nope"])
    with pytest.raises(ValueError, match="mass"):
        plot_detection_snr_map({"r_eff": [1.0]})
    with pytest.raises(ValueError, match="one row per"):
        plot_detection_snr_map(t[:-1])


def test_subhalo_kwargs_may_be_angle_quantities():
    """theta_E (and the TNFW's Rs, alpha_Rs, r_trunc) as angles give the numbers' results;
    a non-angle is refused by name."""
    from lensdual.sensitivity import flux_excess

    d = [0.02 / np.sqrt(0.5), 0.0] * u.arcsec
    a0 = 0.5 * np.eye(2)
    plain = flux_excess(a0, {"theta_E": 0.02}, d)
    np.testing.assert_allclose(plain, 3 / np.sqrt(5), rtol=2e-3)
    np.testing.assert_array_equal(flux_excess(a0, {"theta_E": 20 * u.mas}, d), plain)
    tnfw = {"Rs": 0.05, "alpha_Rs": 0.004, "r_trunc": 0.5}
    as_angles = {k: (v * u.arcsec).to(u.mas) for k, v in tnfw.items()}
    np.testing.assert_allclose(flux_excess(a0, as_angles, d), flux_excess(a0, tnfw, d),
                               rtol=1e-12)
    with pytest.raises(ValueError, match="subhalo theta_E must be an angle"):
        flux_excess(a0, {"theta_E": 0.02 * u.kg}, d)


def test_the_joint_reference_error_is_the_joint_prediction_error():
    """test="joint": sigma_rel is the joint test's prediction error at the reference pair
    (checked against check_duality on the analogue's constellation), and the detection
    SNRs scale by the ratio of the errors."""
    import numpy as np

    from lensdual.duality import check_duality
    from lensdual.simulation.scenarios import smacs0723_analog

    sp = 0.005 * u.arcsec
    geo = smacs0723_reference(sigma_pos=sp)
    joint = smacs0723_reference(sigma_pos=sp, test="joint", flux_rel_err=0.02)
    pairs = smacs0723_analog(seed=0).constellation()
    for band in pairs.meta["bands"]:
        for k in "12":
            pairs[f"flux_err{k}_{band}"] = 0.02 * pairs[f"flux{k}_{band}"]
    row = int(np.flatnonzero(np.asarray(pairs["source"]) == 0)[0])
    r = check_duality(pairs, sigma_pos=sp, test="joint")
    assert joint["sigma_rel"] == pytest.approx(float(r["ln_mu_predicted_err"][row]))
    assert joint["sigma_rel"] < geo["sigma_rel"]
    kw = dict(n_angles=6, n_grid=120, sigma_pos=sp)
    snr_geo = detection_snr_map([1e8] * u.Msun, [1.0], **kw)
    snr_joint = detection_snr_map([1e8] * u.Msun, [1.0], test="joint", **kw)
    assert float(snr_joint["snr_mean"][0]) == pytest.approx(
        float(snr_geo["snr_mean"][0]) * geo["sigma_rel"] / joint["sigma_rel"], rel=1e-9)
    with pytest.raises(ValueError, match="pass the joint test's error as sigma_rel"):
        detection_snr_map([1e8] * u.Msun, [1.0], sigma_rel=0.1, test="joint")
