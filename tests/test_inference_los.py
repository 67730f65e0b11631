"""lensdual.inference with line-of-sight haloes: pyHalo's field-halo rendering, the
two-plane linearisation against lenstronomy's multi-plane ray tracing."""

import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from astropy import units as u

pytest.importorskip("pyHalo")

from lensdual.inference import (  # noqa: E402
    SubhaloPopulation,
    _forward,
    _kernels,
    simulate_anomalies,
)
from lensdual.simulation.families import calibration_system, clean_constellation  # noqa: E402

# pyHalo's geometry and cosmology call astropy's deprecated distance method
pytestmark = pytest.mark.filterwarnings(
    "ignore::astropy.utils.exceptions.AstropyDeprecationWarning")

ZL, ZS = 0.39, 2.2
KPC2 = u.kpc**-2


@pytest.fixture(scope="module")
def los_population():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return SubhaloPopulation(ZL, ZS, los_normalization=1.0)


def _pyhalo_geometry(population, opening=6.0):
    from pyHalo.Cosmology.cosmology import Cosmology
    from pyHalo.Cosmology.geometry import Geometry

    cosmo = population.cosmology
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pyHalo calls astropy's deprecated distance method
        ph = Cosmology(astropy_instance=cosmo,
                       cosmo_kwargs={"H0": float(cosmo.H0.value), "Om0": float(cosmo.Om0)})
        return Geometry(ph, ZL, ZS, opening, "DOUBLE_CONE")


# ---------------------------------------------------------------- rendering


def test_los_density_is_pyhalos_sheth_tormen(los_population):
    """In front of the lens (where pyHalo's double cone is a cone) the haloes per
    arcsec^2 of each plane equal pyHalo's ShethTormen mean count over its cone's area."""
    from pyHalo.Rendering.MassFunctions.density_peaks import ShethTormen

    geometry = _pyhalo_geometry(los_population)
    los = los_population._los
    kwargs = {"log_mlow": 6.0, "log_mhigh": 10.0, "m_pivot": 1e8, "LOS_normalization": 1.0,
              "delta_power_law_index": 0.0, "draw_poisson": False}
    checked = 0
    for j in np.flatnonzero(los["z"] < ZL - 0.01)[::4]:
        dz = los["z"][j + 1] - los["z"][j]
        mf = ShethTormen.from_redshift(los["z"][j], dz, geometry, kwargs)
        expected = mf.n_mean / (np.pi * 3.0**2)
        # pyHalo takes the slab's volume at its near edge times dz, lensdual integrates it
        assert los["density"][j] == pytest.approx(expected, rel=1e-2)
        checked += 1
    assert checked >= 4


def test_two_halo_term_boosts_the_lens_plane(los_population):
    without = SubhaloPopulation(ZL, ZS, los_normalization=1.0, two_halo=False)
    at = np.argmin(np.abs(los_population._los["z"] - ZL))
    ratio = los_population._los["density"] / without._los["density"]
    assert ratio[at] > 2.0  # a 1e15 Msun host's correlated structure
    np.testing.assert_array_equal(np.delete(ratio, at), 1.0)


def test_los_draw_follows_the_planes(los_population):
    from lenstronomy.Cosmo.lens_cosmo import LensCosmo

    los = los_population._los
    radius, n_real = 0.3, 400
    h = los_population._los_draw(np.random.default_rng(2), radius, n_real)
    counts = np.bincount(h["plane"], minlength=los["z"].size)
    expected = los["density"] * np.pi * radius**2 * n_real
    assert counts.sum() == pytest.approx(expected.sum(), rel=0.02)
    big = expected > 500
    assert np.all(np.abs(counts[big] - expected[big]) < 5 * np.sqrt(expected[big]))
    assert (np.hypot(h["x"], h["y"]) <= radius).all()
    assert np.array_equal(np.bincount(h["real"], minlength=n_real).sum(), h["mass"].size)
    # one plane: truncation at r_50 and Rs at the LUDLOW2016 median of its redshift
    j = int(np.argmax(counts))
    sel = h["plane"] == j
    m = h["mass"][sel]
    cosmo = los_population.cosmology
    rho = cosmo.critical_density(los["z"][j]).to_value(u.Msun / u.kpc**3)
    kpc = cosmo.kpc_proper_per_arcmin(los["z"][j]).to_value(u.kpc / u.arcsec)
    np.testing.assert_allclose(h["r_trunc"][sel], (3 * m / (4 * np.pi * 50 * rho)) ** (1 / 3)
                               / kpc, rtol=1e-10)
    from pyHalo.concentration_models import preset_concentration_models

    cls, kw = preset_concentration_models("LUDLOW2016", {"cosmo": cosmo})
    kw = dict(kw, scatter=False)
    c_med = cls(**kw).nfw_concentration(m[:200], los["z"][j])
    rs_med, _ = LensCosmo(los["z"][j], ZS, cosmo).nfw_physical2angle(M=m[:200], c=c_med)
    ratio = np.log(h["rs"][sel][:200] / rs_med)
    assert abs(np.median(ratio)) < 0.1 and 0.03 < np.std(ratio) < 0.3


def test_los_masses_follow_pyhalos_draw(los_population):
    from pyHalo.Rendering.MassFunctions.density_peaks import ShethTormen
    from scipy import stats

    geometry = _pyhalo_geometry(los_population, opening=60.0)
    los = los_population._los
    j = int(np.argmin(np.abs(los["z"] - 0.2)))
    kwargs = {"log_mlow": 6.0, "log_mhigh": 10.0, "m_pivot": 1e8, "LOS_normalization": 1.0,
              "delta_power_law_index": 0.0, "draw_poisson": False}
    np.random.seed(3)  # noqa: NPY002  (pyHalo draws from the global generator)
    ref = ShethTormen.from_redshift(los["z"][j], 0.02, geometry, kwargs).draw()
    h = los_population._los_draw(np.random.default_rng(4), 1.0, 200)
    ours = h["mass"][h["plane"] == j]
    assert ref.size > 300 and ours.size > 300
    assert stats.ks_2samp(np.log10(ref), np.log10(ours)).pvalue > 0.01


def test_wdm_turnover_thins_los_haloes():
    cdm = SubhaloPopulation(ZL, ZS, los_normalization=1.0)
    wdm = SubhaloPopulation(ZL, ZS, model="WDM", log_mhm=8.0, los_normalization=1.0)
    n_cdm = cdm._los_draw(np.random.default_rng(0), 0.5, 50)["mass"].size
    h = wdm._los_draw(np.random.default_rng(0), 0.5, 50)
    # pyHalo's LOVELL2020 field-halo turnover, (1 + 1.95 (m_hm / m)^0.8)^-1
    lm = np.linspace(6, 10, 4001)
    w = 10 ** (-0.9 * lm)
    frac = np.trapezoid(w / (1 + 1.95 * (1e8 / 10**lm) ** 0.8), lm) / np.trapezoid(w, lm)
    assert h["mass"].size / n_cdm == pytest.approx(frac, rel=0.05)


def test_high_source_redshift_builds():
    """pyHalo's distance tables end at z = 4; the two-halo term does not need the
    source's distance."""
    far = SubhaloPopulation(ZL, 6.0, los_normalization=1.0)
    assert far._los["z"].max() < 6.0 and np.isfinite(far._los["density"]).all()
    near = SubhaloPopulation(ZL, ZS, los_normalization=1.0)
    at = np.argmin(np.abs(near._los["z"] - ZL))
    assert far._los["density"][at] == pytest.approx(near._los["density"][at], rel=1e-12)
    h = far._los_draw(np.random.default_rng(0), 0.2, 10)
    assert np.isfinite(h["rs"]).all() and (h["alpha_rs"] > 0).all()


def test_los_bad_input():
    with pytest.raises(ValueError, match="los_normalization"):
        SubhaloPopulation(ZL, ZS, los_normalization=-1.0)
    with pytest.raises(TypeError, match="two_halo"):
        SubhaloPopulation(ZL, ZS, los_normalization=1.0, two_halo="yes")


# ---------------------------------------------------------------- two-plane kernel


def _multiplane(kappa, gamma1, halos, z_halos, sheets=()):
    """lenstronomy's multi-plane model: a convergence sheet and shear at ZL (exactly
    linear), tNFW haloes and convergence sheets at their own redshifts."""
    from lenstronomy.LensModel.lens_model import LensModel

    names = ["CONVERGENCE", "SHEAR"] + ["TNFW"] * len(halos) + ["CONVERGENCE"] * len(sheets)
    zs = [ZL, ZL] + list(z_halos) + [z for z, _ in sheets]
    kw = [{"kappa": kappa}, {"gamma1": gamma1, "gamma2": 0.0}] + [
        {"Rs": rs, "alpha_Rs": ars, "r_trunc": rt, "center_x": x, "center_y": y}
        for x, y, rs, ars, rt in halos] + [{"kappa": k} for _, k in sheets]
    from astropy.cosmology import FlatLambdaCDM

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "Cosmology is provided": it is ours
        lm = LensModel(names, z_source=ZS, lens_redshift_list=zs, multi_plane=True,
                       cosmo=FlatLambdaCDM(H0=70, Om0=0.3))
    return lm, kw


def _ours(population, a, halos, planes, strong, extra_hessian=None):
    """Flux excess and image count of the image at the origin through _los_terms'
    steps: the plane maps, los_split and excess_grid."""
    h = np.asarray(halos, dtype=float)
    hx, hy, rs, rho0, rt, te, hsup, pq = _forward.los_halo_columns(
        _forward._los_maps(population, a), np.asarray(planes), h[:, 0], h[:, 1], h[:, 2],
        h[:, 3], h[:, 4])
    keep = np.empty(rs.size, dtype=np.bool_)
    lin = np.zeros((1, 4))
    lam_min = float(np.abs(np.diag(a)).min())
    _kernels.los_split(hx, hy, rs, rho0, rt, te, hsup, pq, np.zeros(rs.size, dtype=np.int64),
                       1, float(np.abs(np.diag(a)).min()), lam_min, strong, _forward._BOX_FACTOR,
                       _forward._BOX_CAP, keep, lin)
    if extra_hessian is not None:
        lin += extra_hessian.ravel()
    rows = np.ascontiguousarray(np.column_stack([hx, hy, rs, rho0, rt, te, hsup, pq])[keep])
    ex = np.empty((1, 1))
    n = np.empty((1, 1), dtype=np.int64)
    empty = np.empty(0)
    _kernels.excess_grid(a[0, 0], a[0, 1], a[1, 0], a[1, 1], 0.0, empty, empty, empty, empty,
                         empty, empty, empty, empty, np.array([0, 0]), np.array([1.0]), lam_min,
                         strong, _forward._BOX_FACTOR, _forward._BOX_CAP, _forward._N_GRID,
                         _forward._MAX_IMAGES, rows, np.array([0, rows.shape[0]]), lin, ex, n)
    return ex[0, 0], n[0, 0]


# (plane redshift, macro kappa, gamma1, halo mass, concentration, the halo's position in its
# own plane, where the image's ray passes through the origin)
_CASES = [
    (0.2, 0.6, 0.3, 3e9, 25.0, 0.01, 0.003),  # in front of the lens, three images
    (0.2, 0.45, 0.45, 1e10, 25.0, 0.04, 0.012),
    (1.0, 0.6, 0.3, 3e9, 25.0, 0.005, 0.0015),  # behind it, three images
    (1.0, 0.45, 0.45, 1e10, 25.0, 0.02, 0.006),
    (0.2, 0.5, 0.6, 1e9, 12.0, 0.02, 0.006),  # one image
    (1.0, 0.3, 0.2, 3e9, 12.0, 0.01, 0.003),
    (0.05, 0.6, 0.3, 1e10, 12.0, 0.03, 0.009),
    (2.0, 0.45, 0.45, 1e9, 25.0, 0.01, 0.003),
    (0.2, 0.6, 0.3, 3e9, 25.0, 0.005, 0.0015),  # the image's fold partner within 0.004"
    # behind the lens at a nearly singular N: the halo's images 0.34 and 0.48 arcsec
    # from the image, along the direction N stretches
    (0.99, 0.33, 0.649, 4e9, 22.8, 0.00353, -0.0042),
]


def _one_halo(population, case):
    """A macro field and one tNFW halo of another plane near the image (its angles in
    its own plane, where the image's ray passes through the origin)."""
    z_target, kappa, gamma1, m, c, x, y = _CASES[case]
    los = population._los
    j = int(np.argmin(np.abs(los["z"] - z_target)))
    rs, ars = los["cosmo"][j].nfw_physical2angle(M=m, c=c)
    halo = (x, y, float(rs), float(ars), 10 * float(rs))
    return kappa, gamma1, halo, j


def _reference(lm, kw, a, half=0.6, n=1500):
    """Every image of the source of the ray through the origin, by lenstronomy's ray
    shooting: triangles of a fine grid that cover the source, polished by a root
    finder; magnifications from central differences."""
    from scipy.optimize import root

    bx, by = lm.ray_shooting(0.0, 0.0, kw)
    g = np.linspace(-half, half, n + 1)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    sx, sy = (v.reshape(xx.shape) - b for v, b in zip(lm.ray_shooting(
        xx.ravel(), yy.ravel(), kw), (bx, by), strict=True))
    seeds = []
    for tri in ((0, 0), (1, 0), (1, 1)), ((0, 0), (1, 1), (0, 1)):
        (i0, j0), (i1, j1), (i2, j2) = tri
        p0 = np.stack([sx[i0:n + i0, j0:n + j0], sy[i0:n + i0, j0:n + j0]], -1)
        e1 = np.stack([sx[i1:n + i1, j1:n + j1], sy[i1:n + i1, j1:n + j1]], -1) - p0
        e2 = np.stack([sx[i2:n + i2, j2:n + j2], sy[i2:n + i2, j2:n + j2]], -1) - p0
        det = e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]
        u1 = (-p0[..., 0] * e2[..., 1] + p0[..., 1] * e2[..., 0]) / det
        u2 = (-e1[..., 0] * p0[..., 1] + e1[..., 1] * p0[..., 0]) / det
        inside = (u1 >= -1e-9) & (u2 >= -1e-9) & (u1 + u2 <= 1 + 1e-9)
        seeds += list(zip(xx[:n, :n][inside], yy[:n, :n][inside], strict=True))

    def residual(p):
        x, y = lm.ray_shooting(p[0], p[1], kw)
        return [x - bx, y - by]

    images = []
    for x0, y0 in seeds:
        sol = root(residual, [x0, y0], tol=1e-14)
        if np.hypot(*residual(sol.x)) < 1e-12 and all(
                np.hypot(*(sol.x - im)) > 1e-7 for im in images):
            images.append(sol.x)
    h = 1e-6
    total = 0.0
    for x, y in images:
        cols = []
        for dx, dy in ((h, 0.0), (0.0, h)):
            plus = np.array(lm.ray_shooting(x + dx, y + dy, kw))
            minus = np.array(lm.ray_shooting(x - dx, y - dy, kw))
            cols.append((plus - minus) / (2 * h))
        total += 1.0 / abs(np.linalg.det(np.column_stack(cols)))
    return total * abs(np.linalg.det(a)), len(images)


_REFERENCES = {}


@pytest.mark.parametrize("case", range(len(_CASES)))
@pytest.mark.parametrize("strong", [0.0, _forward._STRONG])
def test_los_halo_matches_lenstronomy_multiplane(los_population, case, strong):
    """With the main lens linear, one halo of another plane reduces exactly to the
    main plane: the flux excess (all images) equals lenstronomy's multi-plane one."""
    kappa, gamma1, halo, j = _one_halo(los_population, case)
    a = np.diag([1 - kappa - gamma1, 1 - kappa + gamma1])
    if case not in _REFERENCES:
        lm, kw = _multiplane(kappa, gamma1, [halo], [los_population._los["z"][j]])
        _REFERENCES[case] = _reference(lm, kw, a)
    ref, n_ref = _REFERENCES[case]
    ours, n_ours = _ours(los_population, a, [halo], [j], strong)
    assert n_ours == n_ref
    assert ours == pytest.approx(ref, rel=1e-5)


def test_los_cases_cover_extra_images_in_both_planes(los_population):
    counts = {True: [], False: []}
    for case in range(len(_CASES)):
        kappa, gamma1, halo, j = _one_halo(los_population, case)
        a = np.diag([1 - kappa - gamma1, 1 - kappa + gamma1])
        counts[bool(los_population._los["front"][j])].append(
            _ours(los_population, a, [halo], [j], 0.0)[1])
    for n in counts.values():
        assert max(n) >= 3 and min(n) == 1


def test_weak_los_haloes_and_sheets_match_lenstronomy_multiplane(los_population):
    """Many weak haloes in many planes plus convergence sheets: the image's
    magnification from the linearised planes agrees with multi-plane ray tracing (the
    haloes' couplings with each other, neglected, are of second order)."""
    los = los_population._los
    kappa, gamma1 = 0.55, 0.35
    a = np.diag([1 - kappa - gamma1, 1 - kappa + gamma1])
    rng = np.random.default_rng(5)
    h = los_population._los_draw(rng, 0.5, 1)
    sel = h["mass"] > 1e7
    halos = np.column_stack([h["x"], h["y"], h["rs"], h["alpha_rs"], h["r_trunc"]])[sel]
    planes = h["plane"][sel]
    assert halos.shape[0] >= 10 and np.unique(los["front"][planes]).size == 2
    sheet_planes = [int(np.argmin(np.abs(los["z"] - z))) for z in (0.15, 0.9, 1.7)]
    sheets = [(los["z"][j], -0.01) for j in sheet_planes]
    p, q, _, _ = _forward._los_maps(los_population, a)
    sheet = sum(-0.01 * p[j] @ q[j] for j in sheet_planes)
    lm, kw = _multiplane(kappa, gamma1, [tuple(r) for r in halos], los["z"][planes], sheets)
    fxx, fxy, fyx, fyy = lm.hessian(0.0, 0.0, kw, diff=1e-7)
    ref = 1.0 / np.linalg.det(np.eye(2) - np.array([[fxx, fxy], [fyx, fyy]]))
    ours, n = _ours(los_population, a, halos, planes, _forward._STRONG, extra_hessian=sheet)
    ref = abs(ref * np.linalg.det(a))
    assert n == 1
    assert abs(ref - 1) > 0.02  # the haloes and sheets matter ...
    assert ours == pytest.approx(ref, rel=1e-3)  # ... and their couplings do not
    # the same haloes and sheets all put in the lens plane miss by far more
    flat, _ = _ours(los_population, a, halos, np.full(planes.size, np.argmin(
        np.abs(los["z"] - ZL))), _forward._STRONG, extra_hessian=-0.03 * np.eye(2))
    assert abs(flat / ref - 1) > 5 * abs(ours / ref - 1)


# ---------------------------------------------------------------- forward model


@pytest.fixture(scope="module")
def lens_and_pairs():
    system, _ = calibration_system("smacs_analog")
    return system, clean_constellation("smacs_analog", 8, seed=3)


def test_los_widens_the_anomalies_at_low_abundance(los_population, lens_and_pairs):
    system, pairs = lens_and_pairs
    grid = np.array([0.002, 0.2]) * KPC2
    plain = simulate_anomalies(pairs, system, SubhaloPopulation(ZL, ZS), grid,
                               n_realisations=200, seed=4)
    with_los = simulate_anomalies(pairs, system, los_population, grid, n_realisations=200,
                                  seed=4)
    assert np.isfinite(with_los.delta).all()
    sd_plain = np.std(plain.delta, axis=(0, 1))
    sd_los = np.std(with_los.delta, axis=(0, 1))
    assert sd_los[0] > 1.2 * sd_plain[0]  # the line of sight sets a floor
    assert sd_los[1] < 1.5 * sd_plain[1]  # the sub-haloes dominate at high abundance
    # the line-of-sight haloes do not move with the abundance: the largest-abundance
    # draws hold the same sub-haloes, so the anomaly grows, never jumps, with sigma
    assert (np.abs(np.median(with_los.delta, axis=(0, 1))) < 0.5 * sd_los).all()


def test_los_simulation_is_reproducible_in_parallel(los_population, lens_and_pairs):
    system, pairs = lens_and_pairs
    grid = np.array([0.01, 0.1]) * KPC2
    serial = simulate_anomalies(pairs, system, los_population, grid, n_realisations=100,
                                seed=9)
    with ThreadPoolExecutor(2) as pool:
        parallel = simulate_anomalies(pairs, system, los_population, grid,
                                      n_realisations=100, seed=9, client=pool)
    np.testing.assert_array_equal(serial.delta, parallel.delta)
