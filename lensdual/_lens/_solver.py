"""Finding all images of many point sources at once (private module).

The method (App. A of the paper):

1. A regular image-plane grid (spacing ``grid_spacing`` over the square
   ``center +- half_width``) is traced to the source plane once, together with
   the analytic Jacobian ``A = d beta / d theta`` (lenstronomy's ``hessian``).
   Every grid cell is split into two triangles.
2. Cells crossed by a critical curve (the signs of ``det A`` at their corners
   differ) and their neighbours are subdivided ``refine`` times per side and
   traced too; cells where an entry of ``A`` varies by more than
   ``refine_threshold`` between corners (compact perturbers, the centre of a
   cuspy profile) are subdivided recursively, up to ``refine_levels`` times.
   The resulting mesh need not be conforming (see the tolerance below).
3. Every triangle maps to a source-plane triangle through the piecewise-linear
   (barycentric) interpolation. Where the signs of ``det A`` agree on the three
   vertices the mapping is one-to-one, and a source inside the mapped triangle
   has one image inside the image triangle, first guess the barycentric
   interpolation. To make this robust to the curvature of the true mapping,
   each triangle carries a tolerance ``tol`` (twice the triangle diameter times
   the largest deviation of a vertex Jacobian from the piecewise-linear one, an
   upper estimate of the interpolation error): a source within ``tol`` of the
   mapped triangle is a candidate too. The search goes through a source-plane
   bucket grid built once (:mod:`lensdual._lens._kernels`).
4. Triangles that straddle a critical curve (mixed signs of ``det A``, or a
   mapped orientation that disagrees with the vertex signs) or that are very
   non-linear (``tol`` larger than half the mapped triangle) are searched with
   the same tolerance and start Newton not only from the barycentric guess
   but from each of their three vertices as well (once per source and
   vertex): near a fold, Newton started on either side of the critical curve
   converges to the image on that side, so both images of a highly magnified
   pair are found even when they lie in the same triangle.
5. All starts are refined together by a damped Newton iteration (backtracking
   on ``|beta(theta) - beta|``, steps capped at two triangle diameters) with
   the analytic Jacobian: one ``ray_shooting`` and at most one ``hessian``
   call per iteration for all starts. Below ``precision`` the iteration goes
   on while it still decreases the residual (usually down to rounding).
   Starts that do not reach ``precision`` are dropped; images of the same
   source closer than ``1e-5`` base grid spacings (1e-6" for 0.1") are merged.

Limitations:

* Only images inside the square ``center +- half_width`` are returned, and a
  source outside the bounding box of the traced grid is refused.
* Two images of one source in the same triangle are found as one unless the
  triangle is flagged as above (fold or strongly non-linear): e.g.
  micro-images of a sub-halo much smaller than the grid spacing whose
  Jacobian variation the grid vertices do not see. Keep the grid spacing (or
  ``refine`` times it) below the Einstein radius of the smallest perturber.
* Triangles with a vertex where the lens model is not finite are skipped.
* Beyond ``|mu| ~ 1e5-1e6`` (sources within ~1e-6" of a cusp) the lens
  equation is ill-conditioned in double precision (a source-plane residual
  ``r`` allows an image-plane error ``|mu| r``): images can then come out
  twice, a few 1e-6" apart, or be missed.
* Triangles around a singular centre (SIE, point mass) have a huge tolerance
  and are tested against every source: wasted Newton starts, not wrong images.
"""

import math

import numpy as np

from .._validation import as_int, as_real, as_xy_array
from . import _kernels

__all__ = ["ImageFinder"]

#: Largest number of base-grid points accepted by :class:`ImageFinder`.
MAX_GRID_POINTS = 20_000_000

_CHUNK = 250_000  # points per lenstronomy call while tracing the grid
_TOL_SAFETY = 2.0  # factor on the interpolation-error estimate of a triangle
_MAX_COVER = 256  # a triangle covering more buckets goes to the global list
_TRIANGLES_PER_BUCKET = 2.0


def _real(value, name):
    return as_real(value, name, minimum=0.0, inclusive=False)


class ImageFinder:
    """Finds all images of many point sources for one lens (unit-free, arcsec).

    The traced grid is built once, in the constructor, and reused by every
    :meth:`solve` call; ``kwargs_lens`` must not change afterwards.

    Parameters
    ----------
    lens_model : lenstronomy.LensModel.lens_model.LensModel
        The lens model (anything with lenstronomy's ``ray_shooting(x, y, kwargs)``
        and ``hessian(x, y, kwargs)``).
    kwargs_lens : list of dict
        The lens keyword arguments.
    center : (float, float)
        Centre of the square image-plane search region (arcsec).
    half_width : float
        Half side of the search region (arcsec); only images inside it are found.
        For a cluster lens the counter-images can lie 30-50" from the centre.
    grid_spacing : float
        Spacing of the base image-plane grid (arcsec); rounded down so that the
        square holds a whole number of cells. At most ``MAX_GRID_POINTS`` points.
    precision : float
        Largest accepted source-plane residual ``|beta(theta) - beta|`` (arcsec).
    max_iter : int
        Largest number of Newton iterations (backtracking steps included).
    refine : int
        Subdivision factor (per side) of the refined cells; 1 disables the
        refinement. Base cells crossed by a critical curve (and their
        neighbours) are refined once; strongly non-linear cells recursively.
    refine_levels : int
        Largest number of recursive refinements of strongly non-linear cells
        (around compact perturbers and cuspy or singular centres): the finest
        spacing is ``grid_spacing / refine**refine_levels``.
    refine_threshold : float
        A cell is strongly non-linear, and refined, when an entry of the
        Jacobian varies by more than this between its corners.
    refine_centers : bool
        Also refine, down to the finest level, the 3 x 3 cells around the centre
        (``center_x``, ``center_y`` in ``kwargs_lens``) of every lens component:
        a perturber much smaller than a cell is invisible to the Jacobian at the
        cell corners, this refinement is what resolves its micro-images.

    Attributes
    ----------
    n_points : int
        Number of traced image-plane points (base grid plus refinement).
    n_triangles : int
        Number of triangles searched.
    spacing : float
        The actual spacing of the base grid.
    dedup_tolerance : float
        Images of the same source closer than this are merged (``1e-5 spacing``).
    n_skipped_triangles : int
        Triangles left out because the lens model is not finite at a vertex.
    n_candidates, n_starts : int
        (source, triangle) candidates and Newton starts of the last :meth:`solve`.
    """

    def __init__(self, lens_model, kwargs_lens, *, center=(0.0, 0.0), half_width=50.0,
                 grid_spacing=0.1, precision=1e-8, max_iter=50, refine=4,
                 refine_levels=3, refine_threshold=0.5, refine_centers=True):
        self._lens_model = lens_model
        self._kwargs = kwargs_lens
        half_width = _real(half_width, "half_width")
        grid_spacing = _real(grid_spacing, "grid_spacing")
        self.precision = _real(precision, "precision")
        self.max_iter = as_int(max_iter, "max_iter", minimum=1)
        self.refine = as_int(refine, "refine", minimum=1)
        self.refine_levels = as_int(refine_levels, "refine_levels", minimum=1)
        self.refine_threshold = _real(refine_threshold, "refine_threshold")
        self.refine_centers = bool(refine_centers)
        try:
            cx, cy = (float(c) for c in center)
        except (TypeError, ValueError):
            raise ValueError(f"center must be a pair of numbers, got {center!r}") from None
        if not (math.isfinite(cx) and math.isfinite(cy)):
            raise ValueError(f"center must be finite, got {center!r}")
        self.center = (cx, cy)
        self.half_width = half_width
        self.grid_spacing = grid_spacing
        per_side = 2.0 * half_width / grid_spacing
        if not per_side < 1e8:  # certainly too many, and math.ceil may overflow
            raise ValueError(
                f"the grid would have about {per_side:.3g} x {per_side:.3g} points "
                f"(half_width={half_width}, grid_spacing={grid_spacing}), more than the limit "
                f"of {MAX_GRID_POINTS}; increase grid_spacing or decrease half_width"
            )
        n = math.ceil(per_side * (1.0 - 1e-12)) + 1
        if n * n > MAX_GRID_POINTS:
            raise ValueError(
                f"the grid would have {n} x {n} = {n * n} points (half_width={half_width}, "
                f"grid_spacing={grid_spacing}), more than the limit of {MAX_GRID_POINTS}; "
                "increase grid_spacing or decrease half_width"
            )
        self._n = n
        self.spacing = 2.0 * half_width / (n - 1)
        self.dedup_tolerance = 1e-5 * self.spacing
        self._build()

    # ------------------------------------------------------------------ lens calls
    def _ray(self, x, y):
        bx, by = self._lens_model.ray_shooting(x, y, self._kwargs)
        return np.asarray(bx, dtype=np.float64), np.asarray(by, dtype=np.float64)

    def _jacobian(self, x, y):
        fxx, fxy, fyx, fyy = self._lens_model.hessian(x, y, self._kwargs)
        return (1.0 - np.asarray(fxx, dtype=np.float64), -np.asarray(fxy, dtype=np.float64),
                -np.asarray(fyx, dtype=np.float64), 1.0 - np.asarray(fyy, dtype=np.float64))

    def _trace(self, x, y):
        """beta and the Jacobian entries at many points, in chunks."""
        out = np.empty((6, x.size))
        for s in range(0, x.size, _CHUNK):
            sl = slice(s, s + _CHUNK)
            out[0, sl], out[1, sl] = self._ray(x[sl], y[sl])
            out[2:, sl] = self._jacobian(x[sl], y[sl])
        return out

    # ------------------------------------------------------------------ the grid
    def _build(self):
        n, h, r = self._n, self.spacing, self.refine
        levels = self.refine_levels if r > 1 else 0
        scale = r**levels  # base cell size in units of the finest lattice
        nf = (n - 1) * scale + 1  # finest lattice points per side
        if nf * nf >= 2**62:
            raise ValueError(
                f"refine**refine_levels = {scale} is too large for a grid of {n} x {n} points"
            )
        x0 = self.center[0] - self.half_width
        y0 = self.center[1] - self.half_width
        h_fine = h / scale
        axis = np.arange(n)
        gx, gy = np.meshgrid(x0 + h * axis, y0 + h * axis, indexing="ij")
        tx, ty = gx.ravel(), gy.ravel()  # node (i, j) has index i * n + j
        traced = self._trace(tx, ty)
        # every node has a key on the finest lattice; the base keys are increasing
        keys = (axis[:, None] * scale * nf + axis[None, :] * scale).ravel()
        order, sorted_keys = np.arange(keys.size), keys

        ci, cj = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
        ci, cj = ci.ravel(), cj.ravel()
        flag = self._cells_to_refine(traced) if levels else np.zeros(ci.size, dtype=bool)
        centers = self._component_centers() if levels else np.empty((0, 2))
        if centers.size:
            flag |= self._near_centers(ci, cj, centers, h, n - 1)
        c00 = ci[~flag] * n + cj[~flag]
        triangles = [self._split_cells(c00, c00 + n, c00 + 1, c00 + n + 1)]
        ci, cj = ci[flag], cj[flag]
        n_added = 0
        sub_a, sub_b = (g.ravel() for g in np.meshgrid(np.arange(r), np.arange(r),
                                                       indexing="ij"))
        for level in range(1, levels + 1):
            if ci.size == 0:
                break
            step = scale // r**level  # cell size of this level on the finest lattice
            ci = (ci[:, None] * r + sub_a).ravel()
            cj = (cj[:, None] * r + sub_b).ravel()
            corner_keys = [((ci + a) * nf + (cj + b)) * step for a, b in
                           ((0, 0), (1, 0), (0, 1), (1, 1))]
            wanted = np.unique(np.concatenate(corner_keys))
            pos = np.minimum(np.searchsorted(sorted_keys, wanted), sorted_keys.size - 1)
            new = wanted[sorted_keys[pos] != wanted]
            n_added += new.size
            if n_added > MAX_GRID_POINTS:
                raise ValueError(
                    f"the refinement would trace more than {MAX_GRID_POINTS} points "
                    f"({n_added} at level {level}); decrease refine or refine_levels, or "
                    "increase refine_threshold"
                )
            fi, fj = np.divmod(new, nf)
            nx, ny = x0 + h_fine * fi, y0 + h_fine * fj
            tx, ty = np.concatenate([tx, nx]), np.concatenate([ty, ny])
            traced = np.concatenate([traced, self._trace(nx, ny)], axis=1)
            keys = np.concatenate([keys, new])
            order = np.argsort(keys, kind="stable")
            sorted_keys = keys[order]
            corners = [order[np.searchsorted(sorted_keys, k)] for k in corner_keys]
            if level < levels:
                flag = self._nonlinear(np.stack([traced[2:, c] for c in corners]))
                if centers.size:
                    flag |= self._near_centers(ci, cj, centers, h / r**level,
                                               (n - 1) * r**level)
            else:
                flag = np.zeros(ci.size, dtype=bool)
            leaf = ~flag
            triangles.append(self._split_cells(*(c[leaf] for c in corners)))
            ci, cj = ci[flag], cj[flag]
        tri = np.concatenate(triangles)

        bx, by = traced[0], traced[1]
        jac = traced[2:]
        finite_node = np.isfinite(traced).all(axis=0)
        ok = finite_node[tri].all(axis=1)
        self.n_skipped_triangles = int(np.count_nonzero(~ok))
        tri = np.ascontiguousarray(tri[ok])
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            tol, multi = self._triangle_properties(tx, ty, bx, by, jac, tri)

        self._build_buckets(tx.size, bx, by, tri, tol)
        self._tx, self._ty, self._bx, self._by = tx, ty, bx, by
        self._tri, self._tol, self._multi = tri, tol, multi
        self.n_points = int(tx.size)
        self.n_triangles = int(tri.shape[0])
        self.n_candidates = self.n_starts = 0

    def _build_buckets(self, n_points, bx, by, tri, tol):
        """The bucket grid over the traced source plane (``_source_box``, ``_bucket_grid``)."""
        used = np.zeros(n_points, dtype=bool)
        used[tri.ravel()] = True
        if not used.any():
            raise ValueError("the lens model is not finite anywhere on the grid")
        x_lo, x_hi = bx[used].min(), bx[used].max()
        y_lo, y_hi = by[used].min(), by[used].max()
        self._source_box = (x_lo, x_hi, y_lo, y_hi)
        wx, wy = max(x_hi - x_lo, 1e-12), max(y_hi - y_lo, 1e-12)
        n_buckets = max(1.0, tri.shape[0] / _TRIANGLES_PER_BUCKET)
        # at most ~4000 buckets per side: floor(w / cell) + 1 <= 4001
        cell = max(math.sqrt(wx * wy / n_buckets), max(wx, wy) / 4000.0)
        nbx = math.floor(wx / cell) + 1
        nby = math.floor(wy / cell) + 1
        self._bucket_grid = (float(x_lo), float(y_lo), float(cell), nbx, nby)
        self._start, self._items, self._global = _kernels.bucket_triangles(
            bx, by, tri, tol, x_lo, y_lo, cell, nbx, nby, _MAX_COVER)

    def _component_centers(self):
        """(x, y) of the lens components that have a finite centre inside the grid."""
        if not self.refine_centers:
            return np.empty((0, 2))
        pts = []
        for kw in self._kwargs:
            try:
                x, y = float(kw["center_x"]), float(kw["center_y"])
            except (KeyError, TypeError, ValueError):
                continue
            if (math.isfinite(x) and math.isfinite(y)
                    and abs(x - self.center[0]) <= self.half_width
                    and abs(y - self.center[1]) <= self.half_width):
                pts.append((x, y))
        return np.array(pts, dtype=np.float64).reshape(-1, 2)

    def _near_centers(self, ci, cj, centers, size, n_cells):
        """Cells (ci, cj) of side ``size`` among the 3 x 3 around each centre."""
        x0 = self.center[0] - self.half_width
        y0 = self.center[1] - self.half_width
        pi = np.floor((centers[:, 0] - x0) / size).astype(np.int64)
        pj = np.floor((centers[:, 1] - y0) / size).astype(np.int64)
        d = np.arange(-1, 2)
        ni = (pi[:, None, None] + d[None, :, None]) + 0 * d[None, None, :]
        nj = (pj[:, None, None] + 0 * d[None, :, None]) + d[None, None, :]
        near = np.unique(ni.ravel() * (n_cells + 2) + nj.ravel())
        return np.isin(ci * (n_cells + 2) + cj, near)

    def _nonlinear(self, corners):
        """Cells whose Jacobian entries vary by more than ``refine_threshold`` (or are
        not finite) between corners; ``corners`` has shape (4 corners, 4 entries, ...)."""
        with np.errstate(invalid="ignore"):
            variation = (corners.max(axis=0) - corners.min(axis=0)).max(axis=0)
        return ~(variation <= self.refine_threshold)

    def _cells_to_refine(self, traced):
        """Base cells to refine: crossed by a critical curve (dilated by one cell)
        or strongly non-linear."""
        n = self._n
        grid = traced.reshape(6, n, n)
        with np.errstate(invalid="ignore", over="ignore"):
            det = grid[2] * grid[5] - grid[3] * grid[4]
        sign = np.where(np.isfinite(det), np.sign(det), 0.0)
        s00, s10, s01, s11 = sign[:-1, :-1], sign[1:, :-1], sign[:-1, 1:], sign[1:, 1:]
        mixed = ~((s00 == s10) & (s00 == s01) & (s00 == s11) & (s00 != 0))
        # dilate by one cell: a critical curve can graze a cell without a sign change
        grown = mixed.copy()
        grown[1:, :] |= mixed[:-1, :]
        grown[:-1, :] |= mixed[1:, :]
        g2 = grown.copy()
        g2[:, 1:] |= grown[:, :-1]
        g2[:, :-1] |= grown[:, 1:]
        corners = np.stack([grid[2:, :-1, :-1], grid[2:, 1:, :-1],
                            grid[2:, :-1, 1:], grid[2:, 1:, 1:]])
        return (g2 | self._nonlinear(corners)).ravel()

    @staticmethod
    def _split_cells(c00, c10, c01, c11):
        tri = np.empty((2 * c00.size, 3), dtype=np.int64)
        tri[0::2, 0], tri[0::2, 1], tri[0::2, 2] = c00, c10, c11
        tri[1::2, 0], tri[1::2, 1], tri[1::2, 2] = c00, c11, c01
        return tri

    def _triangle_properties(self, tx, ty, bx, by, jac, tri):
        """Interpolation tolerance and the 'multi-start' flag of every triangle."""
        nt = tri.shape[0]
        tol = np.empty(nt)
        multi = np.empty(nt, dtype=bool)
        floor = 1e-9 * self.spacing
        for s in range(0, nt, 4 * _CHUNK):
            t = tri[s:s + 4 * _CHUNK]
            v0, v1, v2 = t[:, 0], t[:, 1], t[:, 2]
            e11, e21 = tx[v1] - tx[v0], ty[v1] - ty[v0]
            e12, e22 = tx[v2] - tx[v0], ty[v2] - ty[v0]
            b11, b21 = bx[v1] - bx[v0], by[v1] - by[v0]
            b12, b22 = bx[v2] - bx[v0], by[v2] - by[v0]
            dete = e11 * e22 - e12 * e21
            detb = b11 * b22 - b12 * b21
            # piecewise-linear Jacobian P = B E^-1
            p11 = (b11 * e22 - b12 * e21) / dete
            p12 = (b12 * e11 - b11 * e12) / dete
            p21 = (b21 * e22 - b22 * e21) / dete
            p22 = (b22 * e11 - b21 * e12) / dete
            dev = np.zeros(t.shape[0])
            signs = np.empty((3, t.shape[0]))
            for k, v in enumerate((v0, v1, v2)):
                a11, a12, a21, a22 = jac[0, v], jac[1, v], jac[2, v], jac[3, v]
                dev = np.maximum(dev, np.sqrt((a11 - p11) ** 2 + (a12 - p12) ** 2
                                              + (a21 - p21) ** 2 + (a22 - p22) ** 2))
                signs[k] = np.sign(a11 * a22 - a12 * a21)
            diam = np.sqrt(np.maximum.reduce([e11**2 + e21**2, e12**2 + e22**2,
                                              (e12 - e11) ** 2 + (e22 - e21) ** 2]))
            bdiam = np.sqrt(np.maximum.reduce([b11**2 + b21**2, b12**2 + b22**2,
                                               (b12 - b11) ** 2 + (b22 - b21) ** 2]))
            tl = np.maximum(_TOL_SAFETY * diam * dev, floor)
            orient = np.sign(detb) * np.sign(dete)
            same = (signs[0] == signs[1]) & (signs[0] == signs[2]) & (signs[0] != 0)
            tol[s:s + t.shape[0]] = tl
            multi[s:s + t.shape[0]] = ~same | (orient != signs[0]) | (tl > 0.5 * bdiam)
        return tol, multi

    # ------------------------------------------------------------------ solving
    def _check_sources(self, beta):
        arr = as_xy_array(beta, "beta")
        x_lo, x_hi, y_lo, y_hi = self._source_box
        out = ((arr[:, 0] < x_lo) | (arr[:, 0] > x_hi) | (arr[:, 1] < y_lo)
               | (arr[:, 1] > y_hi))
        if out.any():
            i = int(np.flatnonzero(out)[0])
            x, y = float(arr[i, 0]), float(arr[i, 1])
            raise ValueError(
                f"source {i} at ({x!r}, {y!r}) lies outside the source-plane "
                f"region covered by the traced grid (x in [{x_lo:.6g}, {x_hi:.6g}], y in "
                f"[{y_lo:.6g}, {y_hi:.6g}]); increase half_width or move center"
            )
        return np.ascontiguousarray(arr)

    def _starts(self, beta):
        """Newton starting points: (source index, theta, step cap)."""
        x0, y0, cell, nbx, nby = self._bucket_grid
        src, tid, bary = _kernels.find_candidates(
            beta[:, 0].copy(), beta[:, 1].copy(), self._bx, self._by, self._tri, self._tol,
            x0, y0, cell, nbx, nby, self._start, self._items, self._global)
        verts = self._tri[tid]
        vx, vy = self._tx[verts], self._ty[verts]
        gx = (bary * vx).sum(axis=1)
        gy = (bary * vy).sum(axis=1)
        diam = np.sqrt(np.maximum.reduce([(vx[:, 0] - vx[:, 1]) ** 2 + (vy[:, 0] - vy[:, 1]) ** 2,
                                          (vx[:, 1] - vx[:, 2]) ** 2 + (vy[:, 1] - vy[:, 2]) ** 2,
                                          (vx[:, 2] - vx[:, 0]) ** 2 + (vy[:, 2] - vy[:, 0]) ** 2]))
        # extra starts from the vertices of the fold / strongly non-linear triangles,
        # once per (source, vertex)
        m = self._multi[tid]
        pair = np.repeat(src[m], 3) * self._tx.size + verts[m].ravel()
        pair, first = np.unique(pair, return_index=True)
        vsrc, vnode = np.divmod(pair, self._tx.size)
        vcap = np.repeat(diam[m], 3)[first]
        src = np.concatenate([src, vsrc])
        gx = np.concatenate([gx, self._tx[vnode]])
        gy = np.concatenate([gy, self._ty[vnode]])
        cap = 2.0 * np.concatenate([diam, vcap])
        self.n_candidates = int(tid.size)
        self.n_starts = int(src.size)
        return src, gx, gy, cap

    def _newton(self, bsx, bsy, x, y, cap):
        """Damped Newton iteration for all starts at once.

        Once the residual is below ``precision`` a start goes on for as long as
        (damped) steps decrease the residual, down to rounding (usually one or two
        steps), so that duplicates of a highly magnified image, where a
        source-plane residual of ``precision`` means an image-plane error of up to
        ``|mu| precision``, agree to within the deduplication tolerance.
        Returns (x, y, residual, converged).
        """
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return self._newton_steps(bsx, bsy, x, y, cap)

    def _newton_steps(self, bsx, bsy, x, y, cap):
        prec = self.precision
        rx, ry = self._ray(x, y)
        rx -= bsx
        ry -= bsy
        res = np.hypot(rx, ry)
        finite = np.isfinite(res)
        res[~finite] = np.inf
        # rounding level of beta(theta) - beta
        floor = 8.0 * np.finfo(np.float64).eps * (1.0 + np.hypot(bsx, bsy) + np.hypot(x, y))
        active = finite & (res > floor)
        need_jac = active.copy()
        lam = np.ones(x.size)
        dx = np.zeros(x.size)
        dy = np.zeros(x.size)
        for _ in range(self.max_iter):
            j = np.flatnonzero(need_jac & active)
            if j.size:
                a11, a12, a21, a22 = self._jacobian(x[j], y[j])
                det = a11 * a22 - a12 * a21
                sx = -(a22 * rx[j] - a12 * ry[j]) / det
                sy = -(-a21 * rx[j] + a11 * ry[j]) / det
                scale = np.minimum(1.0, cap[j] / np.hypot(sx, sy))
                good = np.isfinite(scale) & np.isfinite(sx) & np.isfinite(sy)
                active[j[~good]] = False
                dx[j] = np.where(good, sx * scale, 0.0)
                dy[j] = np.where(good, sy * scale, 0.0)
                lam[j] = 1.0
                need_jac[j] = False
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            xt = x[idx] + lam[idx] * dx[idx]
            yt = y[idx] + lam[idx] * dy[idx]
            rxt, ryt = self._ray(xt, yt)
            rxt -= bsx[idx]
            ryt -= bsy[idx]
            rt = np.hypot(rxt, ryt)
            r0 = res[idx]
            accept = rt <= (1.0 - 1e-4 * lam[idx]) * r0
            acc = idx[accept]
            x[acc], y[acc] = xt[accept], yt[accept]
            rx[acc], ry[acc], res[acc] = rxt[accept], ryt[accept], rt[accept]
            need_jac[acc] = True
            active[acc[res[acc] <= floor[acc]]] = False
            rej = idx[~accept]
            lam[rej] *= 0.5
            # below the precision already: give up polishing sooner
            active[rej[(lam[rej] < 1e-6) | ((res[rej] <= prec) & (lam[rej] < 0.01))]] = False
        return x, y, res, res <= prec

    def solve(self, beta):
        """Find all images of the sources ``beta``.

        Parameters
        ----------
        beta : array_like, shape (M, 2)
            Source positions (arcsec).

        Returns
        -------
        dict of numpy arrays, one entry per image, sorted by source then by x:
            ``"source"`` (K,) int64 index into ``beta``; ``"theta"`` (K, 2) image
            positions; ``"magnification"`` (K,) signed ``1 / det A`` at ``theta``;
            ``"residual"`` (K,) ``|beta(theta) - beta|`` (all <= ``precision``).

        Raises
        ------
        ValueError
            ``beta`` is not of shape (M, 2), is not finite, or holds a source
            outside the source-plane region covered by the traced grid.
        """
        beta = self._check_sources(beta)
        empty = {
            "source": np.empty(0, dtype=np.int64),
            "theta": np.empty((0, 2)),
            "magnification": np.empty(0),
            "residual": np.empty(0),
        }
        if beta.shape[0] == 0:
            return empty
        src, x, y, cap = self._starts(beta)
        if src.size == 0:
            return empty
        x, y, res, conv = self._newton(beta[src, 0], beta[src, 1], x, y, cap)
        cx, cy = self.center
        hw = self.half_width * (1.0 + 1e-12)
        keep = conv & (np.abs(x - cx) <= hw) & (np.abs(y - cy) <= hw)
        src, x, y, res = src[keep], x[keep], y[keep], res[keep]
        # sort by source, then x (then y, then residual, for a deterministic order)
        order = np.lexsort((res, y, x, src))
        src, x, y, res = src[order], x[order], y[order], res[order]
        keep = _kernels.dedup_sorted(src, x, y, self.dedup_tolerance)
        src, x, y, res = src[keep], x[keep], y[keep], res[keep]
        if src.size == 0:
            return empty
        a11, a12, a21, a22 = self._jacobian(x, y)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            mu = 1.0 / (a11 * a22 - a12 * a21)
        return {
            "source": src.astype(np.int64),
            "theta": np.column_stack([x, y]),
            "magnification": np.asarray(mu, dtype=np.float64),
            "residual": res,
        }
