"""The fits: sources one by one (photutils), groups jointly (astropy), refinement passes."""

import warnings
from typing import NamedTuple

import numpy as np
from astropy.table import QTable
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from ._background import _box_centre
from ._flags import _BAD_FLAGS, PhotometryFlag
from ._models import _group_class, _model_class
from ._profiles import _GaussianProfile


def _box_pixels(x, y, shape, fit_shape, invalid):
    """The (x, y) pixel coordinates photutils fits for a source at (x, y)."""
    from astropy.nddata.utils import NoOverlapError, overlap_slices

    try:
        slc, _ = overlap_slices(shape, fit_shape, (y, x), mode="trim")
    except NoOverlapError:
        return np.empty(0, int), np.empty(0, int)
    yy, xx = np.mgrid[slc]
    if invalid is not None:
        good = ~invalid[slc]
        return xx[good], yy[good]
    return xx.ravel(), yy.ravel()


#: False-alarm probability of the flat-top test (`_is_flat_top`).
FLAT_TOP_ALPHA = 1e-4
# The clip levels tried: plateaus of 2 up to this many of the PSF's brightest pixels.
_FLAT_TOP_MAX_PIXELS = 12


def _weighted_chi2(columns, data, w):
    """Chi-square and coefficients of the weighted linear least-squares fit."""
    a = np.column_stack(columns) * np.sqrt(w)[:, None]
    coef = np.linalg.lstsq(a, data * np.sqrt(w), rcond=None)[0]
    return float(np.sum((a @ coef - data * np.sqrt(w)) ** 2)), coef


def _is_flat_top(data, psf, error, background=(), radius2=None, alpha=FLAT_TOP_ALPHA):
    """Whether a source is a PSF whose peak is clipped at a constant: saturated.

    On the source's fitting box (``data`` with the other sources removed,
    ``psf`` the unit-flux PSF at its fitted position), a PSF plus a constant
    and the photometry's background columns (``background``, the basis of
    its strategy) is compared with the same clipped at a free level over its
    ``j`` brightest pixels (``j`` = 2 to 12, among the pixels above a tenth of
    its peak; a clip must lie below the PSF on the plateau and above it
    elsewhere). The source is flat-topped when the best clipped model lowers
    chi-square significantly: by the extra-sum-of-squares F-test of the one
    more parameter, at ``alpha / (J - 1)`` (``J - 1`` plateaus tried), with
    the clipped model's residual chi-square per degree of freedom as the
    noise scale, so that a background the basis does not follow is not taken
    for a clip. A resolved source, flatter than the PSF but not cut off, finds
    no clip level that lies between the PSF's values at the plateau's edge.
    """
    from scipy.stats import f as f_dist

    w = 1.0 / error**2
    n = data.size
    order = np.argsort(psf)[::-1]
    n_top = min(int(np.count_nonzero(psf >= 0.1 * psf[order[0]])), _FLAT_TOP_MAX_PIXELS,
                n - 4 - len(background))
    if n_top < 2:
        return False
    bkg = [np.ones(n), *background]
    sw = np.sqrt(w)
    # the background columns are projected out once; each clip then needs a 2 x 2 solve
    u_, sv, _ = np.linalg.svd(np.column_stack(bkg) * sw[:, None], full_matrices=False)
    q = u_[:, sv > sv[0] * 1e-10]

    def resid(x):
        return x - q @ (q.T @ x)

    y_r, p_r = resid(sw * data), resid(sw * psf)
    yy = float(y_r @ y_r)
    chi_a = yy - float(p_r @ y_r) ** 2 / float(p_r @ p_r)
    pt_r, t_r = np.zeros(n), np.zeros(n)
    best = None
    for j in range(1, n_top + 1):
        i = order[j - 1]
        e_r = -(q @ q[i])
        e_r[i] += 1.0
        pt_r += sw[i] * psf[i] * e_r
        t_r += sw[i] * e_r
        if j < 2:
            continue
        u_r = p_r - pt_r
        g = np.array([[u_r @ u_r, u_r @ t_r], [u_r @ t_r, t_r @ t_r]])
        b = np.array([u_r @ y_r, t_r @ y_r])
        try:
            f, c = np.linalg.solve(g, b)
        except np.linalg.LinAlgError:
            continue
        chi_b = yy - float(b @ (f, c))
        below = psf[order[j]] if j < n else 0.0
        if not f * below <= c <= f * psf[i]:
            continue  # not a clip of this PSF
        if best is None or chi_b < best[0]:
            top = np.zeros(n)
            top[order[:j]] = 1.0
            best = (chi_b, top)
    dof = n - 2 - len(bkg)
    if best is None or dof < 2:
        return False
    chi_b, top = best
    if chi_b <= 0.0:
        return chi_a > 0.0
    if not (chi_a - chi_b) / (chi_b / dof) > f_dist.isf(alpha / (n_top - 1), 1, dof):
        return False
    if radius2 is None:
        return True
    # a resolved source: the clipped PSF's wings broadened fit significantly better
    chi_c, _ = _weighted_chi2([psf * (1.0 - top), top, psf * radius2 * (1.0 - top), *bkg],
                              data, w)
    return bool((chi_b - chi_c) / (max(chi_c, 1e-300) / (dof - 1))
                <= f_dist.isf(alpha, 1, dof - 1))


def _run_photutils(model, fit_shape, data, invalid, error, init, xy_bounds, maxiters):
    """One PSFPhotometry call; returns (results, list of caught warnings)."""
    from photutils.psf import PSFPhotometry

    phot = PSFPhotometry(
        model, fit_shape, xy_bounds=xy_bounds, fitter_maxiters=maxiters, grouper=None
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = phot(data, mask=invalid, error=error, init_params=init)
    return res, list(caught)


def _model_stamp_add(image, profile, x, y, flux, radius, shape_param=None):
    """Add ``flux * profile`` about (x, y) to ``image`` in place (flux may be < 0)."""
    ny, nx = image.shape
    ix, iy = int(np.round(x)), int(np.round(y))
    x0, x1 = max(ix - radius, 0), min(ix + radius + 1, nx)
    y0, y1 = max(iy - radius, 0), min(iy + radius + 1, ny)
    if x0 >= x1 or y0 >= y1:
        return
    yy, xx = np.mgrid[y0:y1, x0:x1]
    image[y0:y1, x0:x1] += flux * profile(xx - x, yy - y, shape_param)


_RESULT_COLUMNS = (
    "x_fit",
    "y_fit",
    "x_err",
    "y_err",
    "flux_fit",
    "flux_err",
    "qfit",
    "cfit",
    "reduced_chi2",
    "n_pixels_fit",
    "flags",
)


class _Scene(NamedTuple):
    """What the fits of one image read.

    ``data`` is the image fitted (raw or high-pass filtered; invalid pixels
    set to 0), ``invalid`` its invalid pixels (None: all valid), ``error``
    its 1-sigma pixel errors (None: an unweighted fit), ``x`` and ``y`` the
    initial pixel positions of the sources and ``local_bkg`` the background
    subtracted under each (0 except with the ``"local"`` strategy).
    """

    data: np.ndarray
    invalid: np.ndarray | None
    error: np.ndarray | None
    x: np.ndarray
    y: np.ndarray
    local_bkg: np.ndarray

    def subset(self, pick):
        """The same image with only the sources ``pick`` (an index array)."""
        return self._replace(x=self.x[pick], y=self.y[pick], local_bkg=self.local_bkg[pick])


def _groups(x, y, radius):
    """The groups of sources closer than ``radius`` (pixels) to another.

    The connected components of more than one source of the graph that joins
    every two sources closer than ``radius`` (`scipy.sparse.csgraph`); each
    lists its members in increasing order, and the groups come in the order
    of their first member.
    """
    if radius <= 0 or x.size < 2:
        return []
    close = np.hypot(x[:, None] - x, y[:, None] - y) < radius
    n_groups, label = connected_components(csr_matrix(close), directed=False)
    size = np.bincount(label, minlength=n_groups)
    return [np.flatnonzero(label == g) for g in range(n_groups) if size[g] > 1]


def _unit_classes(unit_near, units):
    """Greedy colouring of ``units`` so that no two neighbouring units share a class."""
    colour = {}
    for u_ in units:
        used = {colour[v] for v in np.flatnonzero(unit_near[u_]) if v in colour}
        c = 0
        while c in used:
            c += 1
        colour[u_] = c
    return [[u_ for u_ in units if colour[u_] == c] for c in range(max(colour.values()) + 1)]


class _SourceFitter:
    """The fit of every source of one image with one PSF profile and background basis.

    It holds what the fits of single sources (photutils'
    `~photutils.psf.PSFPhotometry`), the joint fits of groups (astropy's
    `~astropy.modeling.fitting.TRFLSQFitter`) and the refinement passes
    share: the scene, the model and its settings, the starting values (which
    every successful fit updates) and the current results.

    Parameters
    ----------
    scene : `_Scene`
        The image and the sources.
    profile : ``_GaussianProfile`` or ``_ImageProfile``
        The PSF at unit flux (see ``_profiles``).
    basis : background basis
        The background fitted with each PSF (see ``_background``).
    fit_shape : (int, int)
        Odd size (ny, nx) of the fitting box.
    xy_bound : float, optional
        Largest shift (pixels) of a fitted position from its initial one, in
        x and in y; None: half the fitting box.
    maxiters : int, optional
        Largest number of function evaluations of the fitter per source.
    with_shape : bool, optional
        Fit the FWHM of a Gaussian profile too (then no source is grouped).
    fwhm_init : float, optional
        The starting FWHM (pixels) with ``with_shape``.
    """

    def __init__(
        self,
        scene,
        profile,
        basis,
        fit_shape,
        *,
        xy_bound=None,
        maxiters=100,
        with_shape=False,
        fwhm_init=None,
    ):
        self.scene = scene
        self.profile = profile
        self.basis = basis
        self.fit_shape = fit_shape
        self.bound = float(min(fit_shape) // 2) if xy_bound is None else float(xy_bound)
        self.maxiters = maxiters
        self.with_shape = with_shape
        self.fwhm_init = fwhm_init
        self.extra = (("fwhm",) if with_shape else ()) + tuple(basis.names)
        self.model = _model_class(basis.names, with_shape)(profile=profile, basis=basis)
        self.start = {}  # per parameter: the starting value of each source's next fit
        self.cur = {}  # per result column: the current value of each source
        self.caught = []  # the warnings of photutils and astropy
        self.failed = []  # the fits that raised, in words

    def linear_init(self):
        """Flux and background coefficients by linear least squares at the initial positions.

        Returns
        -------
        (N, 1 + n_terms) ndarray
            Per source, the flux and the coefficients of the basis; NaN when
            its box has too few valid pixels.
        """
        sc = self.scene
        out = np.full((sc.x.size, 1 + len(self.basis.names)), np.nan)
        for i in range(sc.x.size):
            xx, yy = _box_pixels(sc.x[i], sc.y[i], sc.data.shape, self.fit_shape, sc.invalid)
            if xx.size <= out.shape[1] + 2:
                continue
            d = sc.data[yy, xx] - sc.local_bkg[i]
            w = 1.0 if sc.error is None else 1.0 / sc.error[yy, xx]
            cols = [self.profile(xx - sc.x[i], yy - sc.y[i])] + self.basis.columns(
                xx.astype(float), yy.astype(float)
            )
            a = np.stack(cols, axis=1) * np.reshape(w, (-1, 1))
            out[i] = np.linalg.lstsq(a, d * w, rcond=None)[0]
        return out

    def fit(self, neighbour_passes=0, group_radius=0.0):
        """Fit all sources.

        Sources closer than ``group_radius`` to another are fitted jointly
        (one background per group, astropy's fitter); the others one by one
        with photutils' PSFPhotometry. Sources with neighbours are then
        refined by at most ``neighbour_passes`` passes on the image minus
        the models of all other sources.

        Parameters
        ----------
        neighbour_passes : int, optional
            Largest number of refinement passes (0: none).
        group_radius : float, optional
            Grouping radius, pixels (0: no groups).

        Returns
        -------
        results : dict of str to ndarray
            Per column (``_RESULT_COLUMNS``, ``bkg_at``, ``group_size`` and
            the ``<name>_fit`` and ``<name>_err`` of the shape and
            background parameters), one value per source.
        caught : list of `warnings.WarningMessage`
            The warnings of the fitters.
        failed : list of str
            The fits that raised, in words.
        """
        sc = self.scene
        self._reset()
        groups = [] if self.with_shape else _groups(sc.x, sc.y, group_radius)
        in_group = np.zeros(sc.x.size, bool)
        for g in groups:
            in_group[g] = True
        singles = np.flatnonzero(~in_group)
        units = list(groups) + [np.array([k]) for k in singles]
        # first pass: single sources alone, groups jointly on the image minus the singles
        self._fit_singles(singles, sc.data)
        if groups:
            others = np.zeros_like(sc.data)
            for k in singles:
                self._add(others, k, 1.0)
            for g in groups:
                self._fit_group(g, sc.data - others)
        if neighbour_passes > 0:
            self._refine(units, neighbour_passes)
        cur = self.cur
        cur["flags"] = np.where(np.isfinite(cur["flags"]), cur["flags"], 0).astype(np.int64)
        cur["flags"][self._flat_tops()] |= int(PhotometryFlag.FLAT_TOP)
        cur["n_pixels_fit"] = np.nan_to_num(cur["n_pixels_fit"]).astype(np.int64)
        cur["group_size"] = cur["group_size"].astype(np.int64)
        return cur, self.caught, self.failed

    def _reset(self):
        """Starting values from linear least squares; results all NaN."""
        n = self.scene.x.size
        lin = self.linear_init()
        start = {"flux": np.where(np.isfinite(lin[:, 0]) & (lin[:, 0] > 0), lin[:, 0], 1.0)}
        for k, name in enumerate(self.basis.names):
            start[name] = np.nan_to_num(lin[:, 1 + k])
        if self.with_shape:
            start["fwhm"] = np.full(n, float(self.fwhm_init))
        columns = (
            _RESULT_COLUMNS
            + ("bkg_at", "group_size")
            + tuple(f"{e}_fit" for e in self.extra)
            + tuple(f"{e}_err" for e in self.extra)
        )
        self.start = start
        self.cur = {col: np.full(n, np.nan) for col in columns}
        self.cur["group_size"][:] = 1
        self.caught, self.failed = [], []

    def _mark_failed(self, members, what, exc):
        self.failed.append(f"{what}: {exc}")
        for col in _RESULT_COLUMNS + ("bkg_at",):
            self.cur[col][members] = np.nan
        self.cur["flags"][members] = int(PhotometryFlag.FIT_FAILED)

    def _fit_singles(self, members, image):
        """Fit the sources ``members`` one by one (photutils) on ``image``."""
        if members.size == 0:
            return
        sc, cur, start = self.scene, self.cur, self.start
        t = QTable()
        t["id"] = np.arange(1, len(members) + 1)
        t["x_init"] = sc.x[members]
        t["y_init"] = sc.y[members]
        t["flux_init"] = start["flux"][members]
        t["local_bkg"] = sc.local_bkg[members]
        for name in self.extra:
            t[f"{name}_init"] = start[name][members]
        try:
            res, more = _run_photutils(
                self.model,
                self.fit_shape,
                image,
                sc.invalid,
                sc.error,
                t,
                (self.bound, self.bound),
                self.maxiters,
            )
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            if members.size > 1:  # find the culprit(s): fit them one by one
                for k in members:
                    self._fit_singles(np.array([k]), image)
                return
            self._mark_failed(members, f"source {int(members[0])}", exc)
            return
        self.caught.extend(more)
        for col in (
            _RESULT_COLUMNS
            + tuple(f"{e}_fit" for e in self.extra)
            + tuple(f"{e}_err" for e in self.extra)
        ):
            cur[col][members] = np.asarray(res[col], dtype=np.float64)
        for i, k in enumerate(members):
            cur["bkg_at"][k] = self._bkg_at(res, i, k)
        # the next pass starts from these fits, where they succeeded
        for name in ("flux",) + self.extra:
            val = cur[f"{name}_fit"][members]
            ok = np.isfinite(val) & ((val > 0) if name == "flux" else True)
            start[name][members[ok]] = val[ok]

    def _bkg_at(self, res, i, k):
        """Fitted background at the fitted position of row ``i`` (source ``k``) of ``res``."""
        sc, basis = self.scene, self.basis
        if not basis.names:
            return sc.local_bkg[k]
        xf, yf = float(res["x_fit"][i]), float(res["y_fit"][i])
        xx, yy = _box_pixels(sc.x[k], sc.y[k], sc.data.shape, self.fit_shape, sc.invalid)
        if xx.size == 0 or not (np.isfinite(xf) and np.isfinite(yf)):
            return np.nan
        cols = basis.columns(np.array([xf]), np.array([yf]), centre=_box_centre(xx, yy))
        return float(
            sum(float(res[f"{n}_fit"][i]) * c[0] for n, c in zip(basis.names, cols, strict=True))
        )

    def _fit_group(self, members, image):
        """Fit the sources ``members`` jointly on ``image``; record the results."""
        cur = self.cur
        try:
            res = self._joint_fit(members, image)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            self._mark_failed(members, f"group of sources {members.tolist()}", exc)
            return
        if res is None:
            cur["flags"][members] = int(PhotometryFlag.TOO_FEW_PIXELS)
            return
        for col in _RESULT_COLUMNS + ("bkg_at",):
            cur[col][members] = res[col]
        cur["group_size"][members] = len(members)
        ok = np.isfinite(res["flux_fit"]) & (res["flux_fit"] > 0)
        self.start["flux"][members[ok]] = res["flux_fit"][ok]

    def _joint_fit(self, members, image):
        """Joint fit of the PSFs of ``members`` and one background over the union of
        their boxes, with astropy's TRF fitter.

        Returns
        -------
        dict of str to ndarray or None
            Per result column (and ``bkg_at``), one value per member; None
            when the group has too few pixels.
        """
        from astropy.modeling.fitting import TRFLSQFitter

        sc, profile, basis = self.scene, self.profile, self.basis
        x, y = sc.x, sc.y
        ny, nx = image.shape
        region = np.zeros((ny, nx), bool)
        boxes = []
        for k in members:
            xx, yy = _box_pixels(x[k], y[k], (ny, nx), self.fit_shape, sc.invalid)
            region[yy, xx] = True
            boxes.append((xx, yy))
        yy, xx = np.nonzero(region)
        m = len(members)
        nparam = 3 * m + len(basis.names)
        if xx.size <= nparam + 2:
            return None
        xf, yf = xx.astype(np.float64), yy.astype(np.float64)
        centre = _box_centre(xf, yf)
        local = float(np.mean(sc.local_bkg[members]))
        d = image[yy, xx] - local
        w = None if sc.error is None else 1.0 / sc.error[yy, xx]
        # starting fluxes and background: linear least squares at the starting positions
        cols = [profile(xf - x[k], yf - y[k]) for k in members] + basis.columns(xf, yf, centre)
        a = np.stack(cols, axis=1)
        ww = 1.0 if w is None else w[:, None]
        lin = np.linalg.lstsq(a * ww, d * (1.0 if w is None else w), rcond=None)[0]
        params = {}
        for i, k in enumerate(members):
            f0 = lin[i] if np.isfinite(lin[i]) and lin[i] > 0 else self.start["flux"][k]
            params[f"flux_{i}"] = f0
            params[f"x_0_{i}"] = x[k]
            params[f"y_0_{i}"] = y[k]
        for name, c in zip(basis.names, lin[m:], strict=True):
            params[name] = c
        model = _group_class(m, basis.names)(profile=profile, basis=basis, centre=centre, **params)
        for i, k in enumerate(members):
            getattr(model, f"x_0_{i}").bounds = (x[k] - self.bound, x[k] + self.bound)
            getattr(model, f"y_0_{i}").bounds = (y[k] - self.bound, y[k] + self.bound)
        fitter = TRFLSQFitter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            fitted = fitter(model, xf, yf, d, weights=w, maxiter=self.maxiters * m)
        info = fitter.fit_info
        cov = info.get("param_cov")
        values = np.asarray(fitted.parameters, dtype=np.float64)
        errs = np.full(nparam, np.nan) if cov is None else np.sqrt(np.clip(np.diag(cov), 0, None))
        resid = d - fitted(xf, yf)
        chi = resid if w is None else resid * w
        red_chi2 = float(np.sum(chi**2) / max(xx.size - nparam, 1))
        converged = getattr(info, "success", True) and not caught
        out = {col: np.full(m, np.nan) for col in _RESULT_COLUMNS}
        out["bkg_at"] = np.full(m, np.nan)
        coeffs = values[3 * m :]
        for i, k in enumerate(members):
            f, xi, yi = values[3 * i : 3 * i + 3]
            out["flux_fit"][i], out["x_fit"][i], out["y_fit"][i] = f, xi, yi
            out["flux_err"][i], out["x_err"][i], out["y_err"][i] = errs[3 * i : 3 * i + 3]
            bx, by = boxes[i]
            inbox = region[by, bx]
            sel = np.isin(yy * nx + xx, (by * nx + bx)[inbox])
            out["qfit"][i] = np.sum(np.abs(resid[sel])) / f if f != 0 else np.nan
            cen = (xx == int(np.ceil(x[k] - 0.5))) & (yy == int(np.ceil(y[k] - 0.5)))
            out["cfit"][i] = resid[cen][0] / f if cen.any() and f != 0 else np.nan
            out["reduced_chi2"][i] = red_chi2
            out["n_pixels_fit"][i] = bx.size
            out["flags"][i] = self._member_flags(k, f, xi, yi, bx.size, (ny, nx), converged, cov)
            if coeffs.size:
                c = basis.columns(np.array([xi]), np.array([yi]), centre=centre)
                out["bkg_at"][i] = float(
                    sum(cc * col[0] for cc, col in zip(coeffs, c, strict=True))
                )
            else:
                out["bkg_at"][i] = local
        return out

    def _member_flags(self, k, f, xi, yi, n_pixels, shape, converged, cov):
        """photutils' flags of source ``k`` of a joint fit (flux ``f`` at ``xi``, ``yi``)."""
        ny, nx = shape
        sc = self.scene
        flags = PhotometryFlag(0)
        if n_pixels < int(np.prod(self.fit_shape)):
            flags |= PhotometryFlag.N_PIXELS_FIT_PARTIAL
        if not (-0.5 <= xi <= nx - 0.5 and -0.5 <= yi <= ny - 0.5):
            flags |= PhotometryFlag.OUTSIDE_BOUNDS
        if not f > 0:
            flags |= PhotometryFlag.NON_POSITIVE_FLUX
        if not converged:
            flags |= PhotometryFlag.NO_CONVERGENCE
        if cov is None:
            flags |= PhotometryFlag.NO_COVARIANCE
        if max(abs(xi - sc.x[k]), abs(yi - sc.y[k])) > self.bound - 0.01:
            flags |= PhotometryFlag.NEAR_BOUND
        if not (np.isfinite(xi) and np.isfinite(yi)):
            flags |= PhotometryFlag.NON_FINITE_POSITION
        if not np.isfinite(f):
            flags |= PhotometryFlag.NON_FINITE_FLUX
        return int(flags)

    def _flat_tops(self):
        """The sources whose fitted PSF is clipped at a constant (see `_is_flat_top`),
        on the image minus the other sources' models; none without an error map."""
        sc, cur = self.scene, self.cur
        n = sc.x.size
        flat = np.zeros(n, bool)
        if sc.error is None:
            return flat
        model = np.zeros_like(sc.data)
        for k in range(n):
            self._add(model, k, 1.0)
        for k in range(n):
            f, xf, yf = cur["flux_fit"][k], cur["x_fit"][k], cur["y_fit"][k]
            if not (np.isfinite(xf) and np.isfinite(yf) and f > 0):
                continue
            xx, yy = _box_pixels(xf, yf, sc.data.shape, self.fit_shape, sc.invalid)
            if xx.size < 3:
                continue
            shp = cur["fwhm_fit"][k] if self.with_shape else None
            own = f * self.profile(xx - xf, yy - yf, shp)
            alone = sc.data[yy, xx] - sc.local_bkg[k] - (model[yy, xx] - own)
            xb, yb = xx.astype(np.float64), yy.astype(np.float64)
            columns = self.basis.columns(xb, yb, centre=_box_centre(xb, yb))
            flat[k] = _is_flat_top(alone, own, sc.error[yy, xx], columns,
                                   (xb - xf) ** 2 + (yb - yf) ** 2)
        return flat

    def _add(self, img, k, sign):
        """Add (``sign`` = 1) or subtract (-1) the fitted model of source ``k`` to ``img``."""
        cur = self.cur
        f, xf, yf = cur["flux_fit"][k], cur["x_fit"][k], cur["y_fit"][k]
        if np.isfinite(f) and np.isfinite(xf) and np.isfinite(yf):
            shp = cur["fwhm_fit"][k] if self.with_shape else None
            _model_stamp_add(img, self.profile, xf, yf, sign * f, self.profile.radius() + 2, shp)

    def _refine(self, units, neighbour_passes):
        """Refine the sources with neighbours.

        Each class of mutually distant units (sources or groups) is refitted
        on the image minus the PSF models of all the other sources
        (Gauss-Seidel over the classes), until nothing moves by 0.05 sigma
        or after ``neighbour_passes`` passes.
        """
        sc, cur = self.scene, self.cur
        n = sc.x.size
        reach = max(self.fit_shape) // 2 + self.profile.radius() + 1
        near = (np.abs(sc.x[:, None] - sc.x) < reach) & (np.abs(sc.y[:, None] - sc.y) < reach)
        unit_of = np.empty(n, int)
        for u_, members in enumerate(units):
            unit_of[members] = u_
        unit_near = np.zeros((len(units), len(units)), bool)
        i, j = np.nonzero(near)
        unit_near[unit_of[i], unit_of[j]] = True
        np.fill_diagonal(unit_near, False)
        crowded_units = np.flatnonzero(unit_near.any(axis=1))
        if crowded_units.size == 0:
            return
        crowded = np.concatenate([units[c] for c in crowded_units])
        classes = _unit_classes(unit_near, crowded_units)
        others = np.zeros_like(sc.data)
        for k in range(n):
            self._add(others, k, 1.0)
        for _ in range(neighbour_passes):
            before = {k: cur[k][crowded].copy() for k in ("flux_fit", "x_fit", "y_fit")}
            for cls in classes:
                self._refit_class([units[c] for c in cls], others)
            with np.errstate(invalid="ignore", divide="ignore"):
                moved = np.concatenate(
                    [
                        np.abs(cur[f"{k}_fit"][crowded] - before[f"{k}_fit"])
                        / cur[f"{k}_err"][crowded]
                        for k in ("flux", "x", "y")
                    ]
                )
            moved = moved[np.isfinite(moved)]
            if moved.size == 0 or moved.max() <= 0.05:
                break

    def _refit_class(self, class_units, others):
        """Refit the units of one class on the image minus ``others`` (the models of
        all sources, updated in place)."""
        members = np.concatenate(class_units)
        for k in members:
            self._add(others, k, -1.0)
        image = self.scene.data - others
        # a class may hold only groups: nothing to fit one by one then
        singles = [unit for unit in class_units if len(unit) == 1]
        if singles:
            self._fit_singles(np.concatenate(singles), image)
        for unit in class_units:
            if len(unit) > 1:
                self._fit_group(unit, image)
        for k in members:
            self._add(others, k, 1.0)


def _estimate_fwhm(scene, highpass, basis, fit_shape, xy_bound, maxiters, max_rel_err=None):
    """Common Gaussian FWHM (pixels) from a fit with the FWHM free for every source.

    Parameters
    ----------
    scene : `_Scene`
        The image and the sources.
    highpass : float or None
        Sigma (pixels) of the high-pass filter of the image, or None.
    basis, fit_shape, xy_bound, maxiters
        As for `_SourceFitter`.
    max_rel_err : float, optional
        Use only the sources whose FWHM is known to this fraction.

    Returns
    -------
    float
        The inverse-variance weighted median of the sources' FWHM.

    Raises
    ------
    ValueError
        No source gave a usable FWHM.
    """
    start = 2.5
    fitter = _SourceFitter(
        scene,
        _GaussianProfile(start, highpass),
        basis,
        fit_shape,
        xy_bound=xy_bound,
        maxiters=maxiters,
        with_shape=True,
        fwhm_init=start,
    )
    res, _, _ = fitter.fit(neighbour_passes=0)
    fw, fe = res["fwhm_fit"], res["fwhm_err"]
    ok = (
        np.isfinite(fw)
        & np.isfinite(fe)
        & (fe > 0)
        & (res["flux_fit"] > 0)
        & ((res["flags"] & _BAD_FLAGS) == 0)
        & (fw > 0.31)
        & (fw < 49.0)
    )
    if max_rel_err is not None:
        ok &= fe < max_rel_err * fw
    if not ok.any():
        raise ValueError(
            "psf=None: the PSF FWHM could not be estimated from the sources (no good fit); "
            "give psf explicitly"
        )
    order = np.argsort(fw[ok])
    w = (1.0 / fe[ok] ** 2)[order]
    cw = np.cumsum(w) / w.sum()
    return float(fw[ok][order][np.searchsorted(cw, 0.5)])
