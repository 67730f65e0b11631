"""Tests of the point-source image finder (``lensdual._lens._solver``).

* the Numba kernels against plain-numpy twins on random input;
* a galaxy lens (SIE + external shear) and a cluster lens (elliptical NFW,
  ``NFW_ELLIPSE_CSE``, 5e14 Msun, c = 4, z = 0.39 / 2.2): lens equation,
  magnification, image parity counts;
* an independent brute-force reference kept here (fine image-plane grid, local
  minima of ``|beta(theta) - beta|``, zoomed grids around magnified images,
  polished with ``scipy.optimize.root``) on sources near a fold and near a cusp;
* lenstronomy's ``LensEquationSolver`` on 200 sources near the caustic of the
  galaxy lens;
* input validation.
"""

import numpy as np
import pytest
from astropy.cosmology import FlatLambdaCDM
from lenstronomy.Cosmo.lens_cosmo import LensCosmo
from lenstronomy.LensModel.lens_model import LensModel
from lenstronomy.LensModel.lens_model_extensions import LensModelExtensions
from lenstronomy.LensModel.Solver.lens_equation_solver import LensEquationSolver
from scipy import ndimage, optimize

from lensdual._lens import _kernels
from lensdual._lens._solver import MAX_GRID_POINTS, ImageFinder

PRECISION = 1e-8
MATCH = 1e-6  # arcsec: two image positions are "the same image"
MU_MAX = 1e4  # images less magnified than this must never be missed


# --------------------------------------------------------------------------- references


def np_point_in_triangle(px, py, ax, ay, bx, by, cx, cy, tol):
    """Numpy twin of ``_kernels.point_in_triangle``, broadcasting over all arguments.

    Returns (accepted, weights) with weights of shape ``accepted.shape + (3,)``.
    """
    px, py, ax, ay, bx, by, cx, cy, tol = np.broadcast_arrays(px, py, ax, ay, bx, by, cx, cy, tol)
    d = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    lmax = np.maximum.reduce([(bx - ax) ** 2 + (by - ay) ** 2, (cx - ax) ** 2 + (cy - ay) ** 2,
                              (cx - bx) ** 2 + (cy - by) ** 2])
    nondeg = np.abs(d) > _kernels.DEGENERATE_AREA * lmax
    with np.errstate(divide="ignore", invalid="ignore"):
        w0 = ((bx - px) * (cy - py) - (by - py) * (cx - px)) / d
        w1 = ((cx - px) * (ay - py) - (cy - py) * (ax - px)) / d
        w2 = 1.0 - w0 - w1
    inside = nondeg & (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
    # closest point on the edges ab, bc, ca
    best = np.full(px.shape, np.inf)
    weights = np.zeros(px.shape + (3,))
    for k, (ux, uy, vx, vy) in enumerate([(ax, ay, bx, by), (bx, by, cx, cy), (cx, cy, ax, ay)]):
        sx, sy = vx - ux, vy - uy
        ss = sx * sx + sy * sy
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(ss > 0, np.clip(((px - ux) * sx + (py - uy) * sy) / ss, 0, 1), 0.0)
        dd = (ux + t * sx - px) ** 2 + (uy + t * sy - py) ** 2
        better = dd < best
        best = np.where(better, dd, best)
        w = np.zeros(px.shape + (3,))
        w[..., k] = 1 - t
        w[..., (k + 1) % 3] = t
        weights = np.where(better[..., None], w, weights)
    near = best <= tol * tol
    weights = np.where(inside[..., None], np.stack([w0, w1, w2], axis=-1), weights)
    return inside | near, weights


def np_candidates(sx, sy, bx, by, tri, tol):
    """Every (source, triangle) pair tested: the O(M x N) numpy reference."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ok, w = np_point_in_triangle(sx[:, None], sy[:, None], bx[a], by[a], bx[b], by[b],
                                 bx[c], by[c], tol)
    s, t = np.nonzero(ok)  # row-major: by source, then triangle
    return s, t, w[s, t]


def np_dedup(src, x, y, tol):
    """Numpy twin of ``_kernels.dedup_sorted``: greedy, quadratic."""
    keep = np.ones(src.size, dtype=bool)
    for j in range(src.size):
        prev = np.flatnonzero(keep[:j] & (src[:j] == src[j]))
        if prev.size and (np.hypot(x[prev] - x[j], y[prev] - y[j]) <= tol).any():
            keep[j] = False
    return keep


class BruteForce:
    """Independent image finder: fine grid, local minima, zoom, scipy root polish.

    The image plane ``center +- half_width`` is traced once on a grid of
    ``spacing``. For a source, every local minimum (3 x 3) of ``|beta(theta) -
    beta|`` below ``threshold`` seeds ``scipy.optimize.root``; around each image
    found with ``|mu| > mu_zoom`` the same is repeated on a grid ``zoom`` times
    finer (+- 2 spacings), which separates close pairs near critical curves.
    """

    def __init__(self, lens_model, kwargs, *, center, half_width, spacing, zoom=20):
        self.lm, self.kw, self.h, self.zoom = lens_model, kwargs, spacing, zoom
        n = int(round(2 * half_width / spacing)) + 1
        self.xs = center[0] - half_width + spacing * np.arange(n)
        self.ys = center[1] - half_width + spacing * np.arange(n)
        gx, gy = np.meshgrid(self.xs, self.ys, indexing="ij")
        bx, by = lens_model.ray_shooting(gx.ravel(), gy.ravel(), kwargs)
        self.bx, self.by = bx.reshape(n, n), by.reshape(n, n)

    @staticmethod
    def _minima(d, threshold):
        m = (d == ndimage.minimum_filter(d, size=3, mode="nearest")) & (d < threshold)
        return np.argwhere(m)

    def _polish(self, beta, seed):
        def fun(t):
            bx, by = self.lm.ray_shooting(t[0], t[1], self.kw)
            return [bx - beta[0], by - beta[1]]

        def jac(t):
            fxx, fxy, fyx, fyy = self.lm.hessian(t[0], t[1], self.kw)
            return [[1 - fxx, -fxy], [-fyx, 1 - fyy]]

        t = optimize.root(fun, seed, jac=jac, method="hybr", options={"xtol": 1e-14}).x
        inside = (self.xs[0] <= t[0] <= self.xs[-1]) and (self.ys[0] <= t[1] <= self.ys[-1])
        return t if inside and np.hypot(*fun(t)) < 1e-10 else None

    @staticmethod
    def _add(found, t):
        if t is not None and not any(np.hypot(*(t - u)) < 1e-7 for u in found):
            found.append(t)

    def images(self, beta, threshold=1.0, mu_zoom=20.0):
        d = np.hypot(self.bx - beta[0], self.by - beta[1])
        found = []
        for i, j in self._minima(d, threshold):
            self._add(found, self._polish(beta, (self.xs[i], self.ys[j])))
        hz = self.h / self.zoom
        off = hz * np.arange(-2 * self.zoom, 2 * self.zoom + 1)
        for u in list(found):
            if abs(self.lm.magnification(u[0], u[1], self.kw)) < mu_zoom:
                continue
            zx, zy = np.meshgrid(u[0] + off, u[1] + off, indexing="ij")
            zbx, zby = self.lm.ray_shooting(zx.ravel(), zy.ravel(), self.kw)
            dz = np.hypot(zbx - beta[0], zby - beta[1]).reshape(zx.shape)
            for p, q in self._minima(dz, np.inf):
                self._add(found, self._polish(beta, (zx[p, q], zy[p, q])))
        found = np.array(found).reshape(-1, 2)
        return found[np.argsort(found[:, 0])]


def tangential_caustic(lens_model, kwargs, r_in, r_out, n=720):
    """Exact samples of the tangential critical curve (bisection of det A along rays
    from the origin, det A < 0 at ``r_in`` and > 0 at ``r_out``) and their caustic."""
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    c, s = np.cos(phi), np.sin(phi)

    def det(r):
        fxx, fxy, fyx, fyy = lens_model.hessian(r * c, r * s, kwargs)
        return (1 - fxx) * (1 - fyy) - fxy * fyx

    lo, hi = np.full(n, float(r_in)), np.full(n, float(r_out))
    assert (det(lo) < 0).all() and (det(hi) > 0).all()
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        neg = det(mid) < 0
        lo, hi = np.where(neg, mid, lo), np.where(neg, hi, mid)
    r = 0.5 * (lo + hi)
    bx, by = lens_model.ray_shooting(r * c, r * s, kwargs)
    return np.column_stack([r * c, r * s]), np.column_stack([bx, by])


def compare(found, reference, mu_reference):
    """(missed reference images with |mu| < MU_MAX, found images not in the reference)."""
    missed = [t for t, m in zip(reference, mu_reference, strict=True)
              if abs(m) < MU_MAX and (len(found) == 0 or np.hypot(*(found - t).T).min() > MATCH)]
    extra = [t for t in found
             if len(reference) == 0 or np.hypot(*(reference - t).T).min() > MATCH]
    return missed, extra


def check_images(out, lens_model, kwargs, beta):
    """Structure, order, lens equation and magnification of a solve() result."""
    k = out["source"].size
    assert out["source"].dtype == np.int64 and out["theta"].shape == (k, 2)
    assert out["magnification"].shape == (k,) and out["residual"].shape == (k,)
    assert all(out[key].dtype == np.float64 for key in ("theta", "magnification", "residual"))
    order = np.lexsort((out["theta"][:, 0], out["source"]))
    np.testing.assert_array_equal(order, np.arange(k))
    x, y = out["theta"].T
    bx, by = lens_model.ray_shooting(x, y, kwargs)
    res = np.hypot(bx - beta[out["source"], 0], by - beta[out["source"], 1])
    assert (res <= PRECISION).all()
    assert (out["residual"] <= PRECISION).all()
    np.testing.assert_allclose(out["residual"], res, rtol=0, atol=1e-12)
    mu = lens_model.magnification(x, y, kwargs)
    np.testing.assert_allclose(out["magnification"], mu, rtol=1e-10)


# --------------------------------------------------------------------------- fixtures

GALAXY_KWARGS = [
    {"theta_E": 1.5, "e1": 0.15, "e2": -0.05, "center_x": 0.02, "center_y": -0.01},
    {"gamma1": 0.04, "gamma2": 0.03},
]


@pytest.fixture(scope="module")
def galaxy():
    model = LensModel(["SIE", "SHEAR"])
    finder = ImageFinder(model, GALAXY_KWARGS, half_width=3.0, grid_spacing=0.05)
    return model, GALAXY_KWARGS, finder


@pytest.fixture(scope="module")
def cluster():
    lens_cosmo = LensCosmo(z_lens=0.39, z_source=2.2, cosmo=FlatLambdaCDM(H0=70, Om0=0.3))
    rs, alpha_rs = lens_cosmo.nfw_physical2angle(M=5e14, c=4)
    kwargs = [{"Rs": rs, "alpha_Rs": alpha_rs, "e1": 0.1, "e2": 0.05,
               "center_x": 0.0, "center_y": 0.0}]
    model = LensModel(["NFW_ELLIPSE_CSE"])
    finder = ImageFinder(model, kwargs, half_width=15.0, grid_spacing=0.1)
    return model, kwargs, finder


@pytest.fixture(scope="module")
def cluster_reference(cluster):
    model, kwargs, _ = cluster
    return BruteForce(model, kwargs, center=(0.0, 0.0), half_width=15.0, spacing=0.03)


# --------------------------------------------------------------------------- kernels


def test_point_in_triangle_matches_numpy():
    rng = np.random.default_rng(1)
    n = 4000
    v = rng.uniform(0, 1, (n, 3, 2))
    v[:300, 2] = v[:300, 0] + 0.7 * (v[:300, 1] - v[:300, 0])  # collinear (degenerate)
    v[300:400, 1] = v[300:400, 0]  # two equal vertices
    # points inside the triangles, pushed away from the centroid by a factor 1.6
    q = (rng.dirichlet([1.0, 1.0, 1.0], n)[:, :, None] * v).sum(axis=1)
    centroid = v.mean(axis=1)
    p = centroid + 1.6 * (q - centroid) + rng.normal(scale=0.01, size=(n, 2))
    tol = rng.exponential(0.05, n)
    tol[::7] = 0.0
    ok, w = np_point_in_triangle(p[:, 0], p[:, 1], v[:, 0, 0], v[:, 0, 1], v[:, 1, 0],
                                 v[:, 1, 1], v[:, 2, 0], v[:, 2, 1], tol)
    out = np.empty(3)
    for i in range(n):
        got = _kernels.point_in_triangle(p[i, 0], p[i, 1], *v[i].ravel(), tol[i], out)
        assert got == ok[i]
        if got:
            np.testing.assert_allclose(out, w[i], rtol=0, atol=1e-12)
    strictly_inside, _ = np_point_in_triangle(p[:, 0], p[:, 1], v[:, 0, 0], v[:, 0, 1],
                                              v[:, 1, 0], v[:, 1, 1], v[:, 2, 0], v[:, 2, 1], 0.0)
    # inside, accepted only thanks to the tolerance, and rejected: all well represented
    assert min(strictly_inside.sum(), (ok & ~strictly_inside).sum(), (~ok).sum()) > 500


def test_find_candidates_matches_numpy():
    rng = np.random.default_rng(2)
    nodes = rng.uniform(0, 10, (300, 2))
    tri = np.array([rng.choice(300, 3, replace=False) for _ in range(3000)], dtype=np.int64)
    tri[:100, 2] = tri[:100, 1]  # degenerate triangles
    tol = rng.exponential(0.05, tri.shape[0])
    tol[::5] = 0.0
    bx, by = nodes[:, 0].copy(), nodes[:, 1].copy()
    sx, sy = rng.uniform(0, 10, (2, 400))
    x0, y0, cell = bx.min(), by.min(), 0.8
    nbx = int((bx.max() - x0) // cell) + 1
    nby = int((by.max() - y0) // cell) + 1
    start, items, glob = _kernels.bucket_triangles(bx, by, tri, tol, x0, y0, cell, nbx, nby, 12)
    assert glob.size > 0 and items.size > 0  # both code paths exercised
    assert start.size == nbx * nby + 1 and start[-1] == items.size
    src, tid, bary = _kernels.find_candidates(sx, sy, bx, by, tri, tol, x0, y0, cell, nbx, nby,
                                              start, items, glob)
    ref_src, ref_tid, ref_bary = np_candidates(sx, sy, bx, by, tri, tol)
    assert src.dtype == np.int64 and tid.dtype == np.int64 and bary.shape == (src.size, 3)
    np.testing.assert_array_equal(src, ref_src)
    np.testing.assert_array_equal(tid, ref_tid)
    np.testing.assert_allclose(bary, ref_bary, rtol=0, atol=1e-12)
    np.testing.assert_allclose(bary.sum(axis=1), 1.0, atol=1e-12)
    assert (bary >= 0).all()


def test_dedup_matches_numpy():
    rng = np.random.default_rng(3)
    centres = rng.uniform(0, 1, (200, 2))
    pts = np.repeat(centres, 3, axis=0) + rng.normal(scale=1e-3, size=(600, 2))
    src = rng.integers(0, 4, 600).astype(np.int64)
    order = np.lexsort((pts[:, 1], pts[:, 0], src))
    src, x, y = src[order], pts[order, 0].copy(), pts[order, 1].copy()
    keep = _kernels.dedup_sorted(src, x, y, 2e-3)
    np.testing.assert_array_equal(keep, np_dedup(src, x, y, 2e-3))
    assert 0 < keep.sum() < keep.size


# --------------------------------------------------------------------------- galaxy lens


def test_galaxy_lens_equation_and_magnification(galaxy):
    model, kwargs, finder = galaxy
    beta = np.random.default_rng(4).uniform(-0.5, 0.5, (60, 2))
    out = finder.solve(beta)
    check_images(out, model, kwargs, beta)
    counts = np.bincount(out["source"], minlength=beta.shape[0])
    assert set(counts) <= {2, 4}  # singular isothermal: no central image
    assert (counts == 4).any() and (counts == 2).any()
    # the grid is built once and reused: same answer again, from the same arrays
    tri = finder._tri
    again = finder.solve(beta)
    assert finder._tri is tri
    for key in out:
        np.testing.assert_array_equal(out[key], again[key])


def test_galaxy_unconverged_images_are_dropped(galaxy):
    model, kwargs, _ = galaxy
    beta = np.random.default_rng(5).uniform(-0.5, 0.5, (20, 2))
    finder = ImageFinder(model, kwargs, half_width=3.0, grid_spacing=0.2, max_iter=2,
                         precision=1e-11)
    out = finder.solve(beta)
    assert (out["residual"] <= 1e-11).all()
    x, y = out["theta"].T
    bx, by = model.ray_shooting(x, y, kwargs)
    assert (np.hypot(bx - beta[out["source"], 0], by - beta[out["source"], 1]) <= 1e-11).all()


def test_galaxy_without_refinement_finds_the_same_images(galaxy):
    model, kwargs, finder = galaxy
    beta = np.random.default_rng(9).uniform(-0.4, 0.4, (40, 2))
    coarse = ImageFinder(model, kwargs, half_width=3.0, grid_spacing=0.1, refine=1)
    assert coarse.n_points == 61 * 61 < finder.n_points
    a, b = finder.solve(beta), coarse.solve(beta)
    np.testing.assert_array_equal(a["source"], b["source"])
    np.testing.assert_allclose(a["theta"], b["theta"], rtol=0, atol=1e-9)


def test_empty_source_list(galaxy):
    out = galaxy[2].solve(np.empty((0, 2)))
    assert out["source"].shape == (0,) and out["theta"].shape == (0, 2)
    assert out["magnification"].shape == (0,) and out["residual"].shape == (0,)


def test_galaxy_against_lenstronomy_solver(galaxy):
    """200 sources near the caustic; lenstronomy's grid solver must find no image
    that the finder misses (images either one misses are printed)."""
    model, kwargs, finder = galaxy
    ext = LensModelExtensions(model)
    _, _, ra_caustic, dec_caustic = ext.critical_curve_caustics(
        kwargs, compute_window=6.0, grid_scale=0.02)
    caustic = np.column_stack([np.concatenate(ra_caustic), np.concatenate(dec_caustic)])
    rng = np.random.default_rng(6)
    n = 200
    beta = caustic[rng.integers(0, len(caustic), n)]
    beta = beta + rng.normal(size=(n, 2)) * 10 ** rng.uniform(-4, -1.5, (n, 1))
    out = finder.solve(beta)
    check_images(out, model, kwargs, beta)
    solver = LensEquationSolver(model)
    finder_missed, lenstronomy_missed, matched = [], [], 0
    for s in range(n):
        x, y = solver.image_position_from_source(
            beta[s, 0], beta[s, 1], kwargs, search_window=6.0, min_distance=0.03,
            precision_limit=1e-10, num_iter_max=100)
        theirs = np.column_stack([x, y]).reshape(-1, 2)
        ours = out["theta"][out["source"] == s]
        missed, extra = compare(ours, theirs, np.zeros(len(theirs)))
        finder_missed += [(s, t) for t in missed]
        lenstronomy_missed += [(s, t) for t in extra]
        matched += len(theirs) - len(missed)
    mu = lambda t: float(model.magnification(t[0], t[1], kwargs))  # noqa: E731
    print(f"\n{matched} images found by both; lenstronomy missed {len(lenstronomy_missed)}:")
    for s, t in lenstronomy_missed:
        print(f"  source {s}: theta = {t}, mu = {mu(t):.4g}")
    print(f"ImageFinder missed {len(finder_missed)}:")
    for s, t in finder_missed:
        print(f"  source {s}: theta = {t}, mu = {mu(t):.4g}")
    assert not finder_missed
    assert matched >= 2 * n


# --------------------------------------------------------------------------- cluster lens


def test_cluster_lens_equation_magnification_and_parity(cluster):
    model, kwargs, finder = cluster
    beta = np.random.default_rng(7).uniform(-1.5, 1.5, (100, 2))
    out = finder.solve(beta)
    check_images(out, model, kwargs, beta)
    counts = np.bincount(out["source"], minlength=beta.shape[0])
    assert (counts % 2 == 1).all(), counts  # non-singular profile, sources off the caustics
    assert set(counts) == {1, 3, 5}
    # index theorem of a non-singular lens: one more positive-parity image than negative
    pos = np.bincount(out["source"], weights=out["magnification"] > 0, minlength=100)
    neg = np.bincount(out["source"], weights=out["magnification"] < 0, minlength=100)
    np.testing.assert_array_equal(pos - neg, 1)


def test_cluster_against_brute_force_near_fold_and_cusp(cluster, cluster_reference):
    model, kwargs, finder = cluster
    _, caustic = tangential_caustic(model, kwargs, 3.0, 12.0)
    radius = np.hypot(*caustic.T)
    fold, cusp = caustic[np.argmin(radius)], caustic[np.argmax(radius)]
    beta = np.array(
        [fold * (1 - e) for e in (1e-2, 1e-4, 1e-6)] + [fold * 1.001]
        + [cusp * (1 - e) for e in (1e-2, 1e-4)] + [cusp * 1.001]
        + [[0.1, 0.05], [0.5, -0.3]]
    )
    out = finder.solve(beta)
    check_images(out, model, kwargs, beta)
    counts = np.bincount(out["source"], minlength=beta.shape[0])
    print("\nimage counts", counts.tolist())
    assert (counts % 2 == 1).all()
    assert counts[2] >= 3  # the pair at 1e-6 of the fold (|mu| > 1e4) is found as well
    largest = 0.0
    for s, b in enumerate(beta):
        reference = cluster_reference.images(b)
        mu_ref = model.magnification(reference[:, 0], reference[:, 1], kwargs)
        ours = out["theta"][out["source"] == s]
        missed, extra = compare(ours, reference, mu_ref)
        assert not missed, (s, b, missed)
        # an extra image of the finder is allowed only beyond the reference's reach
        for t in extra:
            assert abs(model.magnification(t[0], t[1], kwargs)) >= MU_MAX, (s, t)
        largest = max(largest, np.abs(mu_ref).max())
    assert largest > 1e3  # the test did probe highly magnified pairs


def test_cluster_with_compact_subhalo(cluster):
    """A ~1e9 Msun truncated NFW sub-halo (theta_E ~ 0.014") 0.02" from a |mu| ~ 200
    image splits it into micro-images: the finder misses none of the reference's,
    with the default grid and with a coarse one (0.5", refined around the sub-halo)."""
    model0, kwargs0, finder0 = cluster
    _, caustic = tangential_caustic(model0, kwargs0, 3.0, 12.0)
    b0 = caustic[np.argmin(np.hypot(*caustic.T))] * (1 - 3e-3)
    out0 = finder0.solve(b0[None])
    arc = out0["theta"][np.argmax(np.abs(out0["magnification"]))]
    kwargs = kwargs0 + [{"Rs": 0.05, "alpha_Rs": 0.02, "r_trunc": 0.5,
                         "center_x": arc[0] + 0.02, "center_y": arc[1]}]
    model = LensModel(["NFW_ELLIPSE_CSE", "TNFW"])
    beta = b0 + np.random.default_rng(0).normal(scale=0.003, size=(4, 2))
    reference = BruteForce(model, kwargs, center=(0.0, 0.0), half_width=15.0, spacing=0.03)
    references = [reference.images(b, mu_zoom=5.0) for b in beta]
    for grid in ({"grid_spacing": 0.1}, {"grid_spacing": 0.5, "refine": 5}):
        out = ImageFinder(model, kwargs, half_width=15.0, **grid).solve(beta)
        check_images(out, model, kwargs, beta)
        counts = np.bincount(out["source"], minlength=beta.shape[0])
        print(f"\nimage counts with the sub-halo, {grid}: {counts.tolist()}")
        assert (counts % 2 == 1).all()
        assert (counts == 7).any()  # two more images than without the sub-halo
        for s, ref in enumerate(references):
            mu_ref = model.magnification(ref[:, 0], ref[:, 1], kwargs)
            missed, _ = compare(out["theta"][out["source"] == s], ref, mu_ref)
            assert not missed, (grid, s, missed)


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize("name", ["half_width", "grid_spacing", "precision"])
@pytest.mark.parametrize("value", [0.0, -1.0, np.nan, np.inf])
def test_bad_parameters(galaxy, name, value):
    model, kwargs, _ = galaxy
    with pytest.raises(ValueError, match=f"{name} must be (finite|> 0)"):
        ImageFinder(model, kwargs, **{name: value})


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"max_iter": 0}, ValueError, "max_iter must be >= 1"),
        ({"refine": 0}, ValueError, "refine must be >= 1"),
        ({"refine_levels": 0}, ValueError, "refine_levels must be >= 1"),
        ({"refine": 2.5}, TypeError, "refine must be an integer"),
        ({"refine_threshold": -1.0}, ValueError, "refine_threshold must be > 0"),
        ({"grid_spacing": "0.1"}, TypeError, "grid_spacing must be a real number"),
        ({"center": (0.0, np.nan)}, ValueError, "center must be finite"),
        ({"center": (0.0, 1.0, 2.0)}, ValueError, "center must be a pair of numbers"),
    ],
)
def test_bad_options(galaxy, kwargs, error, match):
    model, lens_kwargs, _ = galaxy
    with pytest.raises(error, match=match):
        ImageFinder(model, lens_kwargs, half_width=3.0, **kwargs)


def test_grid_too_large(galaxy):
    model, kwargs, _ = galaxy
    with pytest.raises(ValueError, match=rf"20001 x 20001 = 400040001 points .*{MAX_GRID_POINTS}"):
        ImageFinder(model, kwargs, half_width=100.0, grid_spacing=0.01)


@pytest.mark.parametrize(
    ("beta", "match"),
    [
        (np.zeros(2), r"shape \(N, 2\), got shape \(2,\)"),
        (np.zeros((3, 3)), r"shape \(N, 2\), got shape \(3, 3\)"),
        ([[0.0, 0.0], [np.nan, 0.0]], r"NaN or infinite positions at row\(s\) \[1\]"),
        ([[0.0, 0.0], [0.0, np.inf]], r"NaN or infinite positions at row\(s\) \[1\]"),
        ([[0.0, 0.0], [0.1, 0.0], [500.0, 2.0]], r"source 2 at \(500.0, 2.0\) lies outside"),
    ],
)
def test_bad_sources(galaxy, beta, match):
    with pytest.raises(ValueError, match=match):
        galaxy[2].solve(beta)
