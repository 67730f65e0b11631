"""The resolved-source fit: the PSF convolved with an elliptical Gaussian.

A slightly resolved source (a star cluster stretched along an arc) is
modelled as its flux times the PSF convolved with an elliptical Gaussian of
covariance ``C`` (pixels squared); ``C = 0`` is the point source. The
convolution is done on a fine grid of the PSF profile (``_FineKernel``), in
Fourier space: the transform of the Gaussian is ``exp(-k^T C k / 2)``, the
sub-pixel offset of the source a phase. The fitted flux is the model's total
flux, so it does not depend on how much of the light the PSF alone catches.

The fit (``fit_resolved``) takes one or several stamps (a source's fitting
box on one image, its data with the other sources removed, its errors and
background columns). Their shapes are tied: stamp ``j`` has the covariance
``M_j C M_j^T`` of one fitted reference covariance ``C``, with ``M_j`` a
given 2 x 2 map (the identity for a stamp fitted alone). Positions are free
per stamp; the fluxes and the background coefficients enter linearly and are
solved for at every step (variable projection).
"""

from typing import NamedTuple

import numpy as np
from scipy import fft as sfft
from scipy.optimize import least_squares

from ._background import _box_centre

#: Samples per pixel of the fine grid of the PSF profile.
_FINE_SAMPLING = 4
#: The Fourier factor of a covariance with a negative direction (a source
#: fitted narrower than the PSF, as noise does to a point source) is capped
#: at this value, so that the PSF's high frequencies are not amplified.
_NEGATIVE_CAP = 4.0
#: Lowest fitted variance along x and y, in units of the PSF's variance: a
#: point source's fitted size scatters about 0 on both sides.
_NEGATIVE_FRACTION = 0.5
#: A source is too resolved to be used when more than this fraction of its
#: fitted model's flux falls outside its fitting box: its flux is then an
#: extrapolation of the assumed Gaussian profile.
MAX_FLUX_OUTSIDE_BOX = 0.1
#: Largest fitted standard deviation along x or y, in pixels per pixel of
#: the fitting box's half-width: the fit stops there and the source is
#: flagged as too resolved.
MAX_SIGMA_PER_HALF_BOX = 1.5


class _FineKernel:
    """A unit-flux PSF profile on a fine grid, convolved with Gaussians on demand.

    Parameters
    ----------
    profile : callable
        ``profile(dx, dy)``: the PSF at pixel offsets (pixel-integrated,
        sum 1 over the pixels), e.g. ``_GaussianProfile`` or ``_ImageProfile``.
    half : int
        Half-width (pixels) of the region where the model is wanted.
    max_sigma : float
        Largest standard deviation (pixels) of the Gaussians convolved.
    """

    def __init__(self, profile, half, max_sigma):
        os_ = _FINE_SAMPLING
        self.half = int(half)
        self.max_sigma = float(max_sigma)
        reach = int(profile.radius()) + int(np.ceil(4.0 * max_sigma)) + 2
        # the grid's period exceeds half + reach: no wrap-around into the wanted region
        size = (self.half + reach) // 2 + 2
        n = 2 * size * os_ + 1
        t = (np.arange(n) - n // 2) / os_
        grid = profile(t[None, :], t[:, None])
        self.n = n
        self.spectrum = sfft.rfft2(sfft.ifftshift(grid))
        self.ky = 2.0 * np.pi * sfft.fftfreq(n, d=1.0 / os_)[:, None]
        self.kx = 2.0 * np.pi * sfft.rfftfreq(n, d=1.0 / os_)[None, :]
        self.kxx, self.kxy, self.kyy = self.kx**2, 2.0 * self.kx * self.ky, self.ky**2
        self.sampling = os_

    def model(self, cov, mx, my, frac):
        """The unit-flux model at integer pixel offsets ``(mx, my)`` of a source
        ``frac`` = (fx, fy) pixels from their origin, with Gaussian covariance ``cov``."""
        quad = cov[0, 0] * self.kxx + cov[0, 1] * self.kxy + cov[1, 1] * self.kyy
        factor = np.exp(np.minimum(-0.5 * quad, np.log(_NEGATIVE_CAP)))
        phase = np.exp(-1j * (self.kx * frac[0] + self.ky * frac[1]))
        img = sfft.fftshift(sfft.irfft2(self.spectrum * factor * phase, s=(self.n, self.n)))
        c = self.n // 2
        os_ = self.sampling
        return img[c + my * os_, c + mx * os_]


class Stamp(NamedTuple):
    """One source's fitting box on one image.

    ``xx``, ``yy`` are the integer pixel coordinates of the box's valid
    pixels, ``data`` the image there with the other sources removed,
    ``error`` the 1-sigma errors (None: unweighted), ``background`` the
    background columns (list of arrays, may be empty), ``x0``, ``y0`` the
    starting position, ``kernel`` the `_FineKernel` of the image's PSF,
    ``bound`` the largest shift (pixels) of the position.
    """

    xx: np.ndarray
    yy: np.ndarray
    data: np.ndarray
    error: np.ndarray | None
    background: list
    x0: float
    y0: float
    kernel: _FineKernel
    bound: float


class ResolvedFit(NamedTuple):
    """The result of `fit_resolved`: per stamp, arrays of one value each."""

    flux: np.ndarray
    flux_err: np.ndarray
    x: np.ndarray
    y: np.ndarray
    x_err: np.ndarray
    y_err: np.ndarray
    cov: np.ndarray  # (n_stamps, 2, 2): the fitted covariance in each stamp's pixels^2
    cov_err: np.ndarray  # (3,): errors of the reference covariance's cxx, cxy, cyy
    shape_params: np.ndarray  # (3,): the fitted reference covariance's cxx, cxy, cyy
    shape_cov: np.ndarray  # (3, 3): their covariance
    flux_cov: np.ndarray  # (n_stamps, n_stamps): the covariance of the fluxes
    outside: np.ndarray  # fraction of each model's flux outside its box
    at_bound: bool  # the size stopped at its upper bound
    chi2: float
    dof: int
    success: bool


def _cov_of(p):
    return np.array([[p[0], p[1]], [p[1], p[2]]])


def _stamp_columns(stamp, cov, x, y):
    """The unit-flux model of ``stamp`` at (x, y) with covariance ``cov``, on its pixels."""
    ix, iy = int(np.round(x)), int(np.round(y))
    return stamp.kernel.model(cov, stamp.xx - ix, stamp.yy - iy, (x - ix, y - iy))


def _weights(stamp):
    return np.ones(stamp.data.size) if stamp.error is None else 1.0 / stamp.error


def _design(stamp, cov, x, y):
    """The weighted design matrix (model, background columns) of one stamp."""
    w = _weights(stamp)
    cols = [_stamp_columns(stamp, cov, x, y), *stamp.background]
    return np.column_stack(cols) * w[:, None], stamp.data * w


def _solve_linear(a, b):
    coef = np.linalg.lstsq(a, b, rcond=None)[0]
    return coef, b - a @ coef


def _residuals(q, stamps, maps):
    """The weighted residuals of all stamps for the nonlinear parameters ``q``
    (3 shape parameters, then x, y per stamp), the linear ones solved for."""
    c_ref = _cov_of(q[:3])
    out = []
    for j, stamp in enumerate(stamps):
        cov = maps[j] @ c_ref @ maps[j].T
        a, b = _design(stamp, cov, q[3 + 2 * j], q[4 + 2 * j])
        out.append(_solve_linear(a, b)[1])
    return np.concatenate(out)


def _full_jacobian(q, stamps, maps, coefs):
    """The Jacobian of the weighted model with respect to every parameter: the
    nonlinear ones (numerical) and, per stamp, the flux and background ones."""
    n_lin = [1 + len(s.background) for s in stamps]
    sizes = [s.data.size for s in stamps]
    n_rows, n_q = sum(sizes), q.size
    jac = np.zeros((n_rows, n_q + sum(n_lin)))

    def model(qq):
        c_ref = _cov_of(qq[:3])
        parts = []
        for j, stamp in enumerate(stamps):
            a, _ = _design(stamp, maps[j] @ c_ref @ maps[j].T, qq[3 + 2 * j], qq[4 + 2 * j])
            parts.append(a @ coefs[j])
        return np.concatenate(parts)

    for i in range(n_q):
        h = 1e-4 * max(1.0, abs(q[i]))
        qp, qm = q.copy(), q.copy()
        qp[i] += h
        qm[i] -= h
        jac[:, i] = (model(qp) - model(qm)) / (2.0 * h)
    row, col = 0, n_q
    c_ref = _cov_of(q[:3])
    for j, stamp in enumerate(stamps):
        a, _ = _design(stamp, maps[j] @ c_ref @ maps[j].T, q[3 + 2 * j], q[4 + 2 * j])
        jac[row:row + sizes[j], col:col + n_lin[j]] = a
        row += sizes[j]
        col += n_lin[j]
    return jac


def _outside_fraction(stamp, cov, x, y):
    """The fraction of the unit-flux model outside the stamp's pixels (valid or not)."""
    half = stamp.kernel.half
    ix, iy = int(np.round(x)), int(np.round(y))
    x_lo, x_hi = int(stamp.xx.min()) - ix, int(stamp.xx.max()) - ix
    y_lo, y_hi = int(stamp.yy.min()) - iy, int(stamp.yy.max()) - iy
    my, mx = np.mgrid[max(y_lo, -half):min(y_hi, half) + 1, max(x_lo, -half):min(x_hi, half) + 1]
    inside = stamp.kernel.model(cov, mx.ravel(), my.ravel(), (x - ix, y - iy)).sum()
    return float(np.clip(1.0 - inside, 0.0, 1.0))


def fit_resolved(stamps, maps, psf_variance, start_cov=None):
    """Fit the PSF convolved with an elliptical Gaussian to one or more stamps.

    Parameters
    ----------
    stamps : list of `Stamp`
        The stamps fitted together.
    maps : list of (2, 2) ndarray
        Per stamp, ``M_j``: its covariance is ``M_j C M_j^T`` (pixels^2)
        with ``C`` the fitted reference covariance.
    psf_variance : float
        The variance (pixels^2 of the reference frame) of the PSF along one
        axis: sets the lowest fitted variance and the scales.
    start_cov : (2, 2) ndarray, optional
        The starting reference covariance (default 0: a point source).

    Returns
    -------
    `ResolvedFit`
    """
    c_max = min(s.kernel.max_sigma for s in stamps) ** 2
    c_min = -_NEGATIVE_FRACTION * psf_variance
    c0 = np.zeros(3) if start_cov is None else np.array(
        [start_cov[0, 0], start_cov[0, 1], start_cov[1, 1]])
    q0 = [*np.clip(c0, [c_min, -c_max, c_min], [c_max, c_max, c_max])]
    lo, hi = [c_min, -c_max, c_min], [c_max, c_max, c_max]
    for s in stamps:
        q0 += [s.x0, s.y0]
        lo += [s.x0 - s.bound, s.y0 - s.bound]
        hi += [s.x0 + s.bound, s.y0 + s.bound]
    q0 = np.clip(np.array(q0), np.array(lo) + 1e-9, np.array(hi) - 1e-9)
    scale = np.array([psf_variance] * 3 + [0.1] * (2 * len(stamps)))
    res = least_squares(_residuals, q0, bounds=(lo, hi), args=(stamps, maps), x_scale=scale,
                        diff_step=1e-4, max_nfev=200)
    q = res.x
    c_ref = _cov_of(q[:3])
    covs = [maps[j] @ c_ref @ maps[j].T for j in range(len(stamps))]
    coefs = []
    for j, s in enumerate(stamps):
        a, b = _design(s, covs[j], q[3 + 2 * j], q[4 + 2 * j])
        coefs.append(_solve_linear(a, b)[0])
    resid = _residuals(q, stamps, maps)
    chi2 = float(resid @ resid)
    jac = _full_jacobian(q, stamps, maps, coefs)
    dof = max(resid.size - jac.shape[1], 1)
    weighted = all(s.error is not None for s in stamps)
    try:
        pcov = np.linalg.pinv(jac.T @ jac)
    except np.linalg.LinAlgError:
        pcov = np.full((jac.shape[1],) * 2, np.nan)
    if not weighted:
        pcov = pcov * chi2 / dof
    err = np.sqrt(np.clip(np.diag(pcov), 0.0, None))
    n_q = q.size
    col = n_q
    flux, flux_err = np.empty(len(stamps)), np.empty(len(stamps))
    at = []
    for j, s in enumerate(stamps):
        flux[j], flux_err[j] = coefs[j][0], err[col]
        at.append(col)
        col += 1 + len(s.background)
    at_bound = bool(np.any(np.isclose(q[[0, 2]], c_max, rtol=1e-3)))
    return ResolvedFit(
        flux=flux,
        flux_err=flux_err,
        x=q[3::2].copy(),
        y=q[4::2].copy(),
        x_err=err[3:n_q:2],
        y_err=err[4:n_q:2],
        cov=np.array(covs),
        cov_err=err[:3],
        shape_params=q[:3].copy(),
        shape_cov=pcov[:3, :3],
        flux_cov=pcov[np.ix_(at, at)],
        outside=np.array([_outside_fraction(s, covs[j], q[3 + 2 * j], q[4 + 2 * j])
                          for j, s in enumerate(stamps)]),
        at_bound=at_bound,
        chi2=chi2,
        dof=dof,
        success=bool(res.success),
    )


def make_stamp(data, error, invalid, x0, y0, fit_shape, basis, kernel, bound):
    """The `Stamp` of a source at (x0, y0) on ``data`` (the other sources removed).

    ``basis`` gives the background columns about the box centre, as the PSF
    fits do; ``invalid`` marks pixels to leave out (None: all valid).
    """
    ny, nx = data.shape
    hy, hx = fit_shape[0] // 2, fit_shape[1] // 2
    ix, iy = int(np.round(x0)), int(np.round(y0))
    yy, xx = np.mgrid[max(iy - hy, 0):min(iy + hy + 1, ny), max(ix - hx, 0):min(ix + hx + 1, nx)]
    xx, yy = xx.ravel(), yy.ravel()
    if invalid is not None:
        keep = ~invalid[yy, xx]
        xx, yy = xx[keep], yy[keep]
    xf, yf = xx.astype(np.float64), yy.astype(np.float64)
    columns = basis.columns(xf, yf, centre=_box_centre(xf, yf)) if xx.size else []
    return Stamp(xx, yy, data[yy, xx], None if error is None else error[yy, xx],
                 list(columns), float(x0), float(y0), kernel, float(bound))


#: Result columns that the resolved fit adds to those of the PSF fit.
RESOLVED_COLUMNS = ("flux_point", "flux_point_err", "size", "size_minor", "size_angle",
                    "size_snr", "flux_outside")


def _major_axis(params, shape_cov):
    """The standard deviations along the major and minor axes (signed square roots of
    the eigenvalues), the major axis' angle (degrees from +x) and the significance
    of the major-axis variance (its value over its error)."""
    cov = _cov_of(params)
    vals, vecs = np.linalg.eigh(cov)
    e = vecs[:, 1]
    grad = np.array([e[0] ** 2, 2.0 * e[0] * e[1], e[1] ** 2])
    var_err = float(np.sqrt(max(grad @ shape_cov @ grad, 0.0)))
    signed = np.sign(vals) * np.sqrt(np.abs(vals))
    angle = float(np.degrees(np.arctan2(e[1], e[0])) % 180.0)
    snr = vals[1] / var_err if var_err > 0 else np.nan
    return float(signed[1]), float(signed[0]), angle, float(snr)


def psf_variance(profile):
    """The variance (pixels^2) of a PSF profile along one axis: that of the Gaussian of
    its FWHM plus the pixel's 1/12."""
    return (profile.fwhm / (2.0 * np.sqrt(2.0 * np.log(2.0)))) ** 2 + 1.0 / 12.0


def refit_resolved(fitter, res):
    """Refit every source of a finished PSF fit with the resolved-source model.

    Each source is fitted alone in its fitting box (centred on its PSF
    position), on the image minus the models of the other sources, with the
    same background columns; the other sources' models are their PSF fits
    in a first pass and their resolved fits in a second one (only when some
    source has a neighbour within reach).

    Parameters
    ----------
    fitter : ``_SourceFitter``
        The PSF fitter after its ``fit``.
    res : dict of str to ndarray
        Its results; updated in place: ``flux_fit``, ``flux_err``, the
        positions and their errors become the resolved fit's, the PSF
        fluxes move to ``flux_point`` and ``flux_point_err``, and the
        columns of `RESOLVED_COLUMNS` are added (sizes in pixels, angle in
        degrees). Sources too resolved to be used get
        ``PhotometryFlag.TOO_RESOLVED``.

    Returns
    -------
    list of str
        The fits that raised, in words.
    """
    from ._flags import _BAD_FLAGS, PhotometryFlag

    sc = fitter.scene
    n = sc.x.size
    half_box = min(fitter.fit_shape) // 2
    bound = 1.0
    # the kernel reaches the neighbours' boxes: their models are subtracted there
    kernel = _FineKernel(fitter.profile,
                         max(fitter.fit_shape) // 2 + fitter.profile.radius() + int(bound) + 3,
                         MAX_SIGMA_PER_HALF_BOX * half_box)
    p2 = psf_variance(fitter.profile)
    res["flux_point"] = res["flux_fit"].copy()
    res["flux_point_err"] = res["flux_err"].copy()
    for col in RESOLVED_COLUMNS[2:]:
        res[col] = np.full(n, np.nan)
    usable = (np.isfinite(res["flux_fit"]) & np.isfinite(res["x_fit"])
              & np.isfinite(res["y_fit"]) & ((res["flags"] & _BAD_FLAGS) == 0))
    reach = max(fitter.fit_shape) + fitter.profile.radius()
    near = (np.abs(sc.x[:, None] - sc.x) < reach) & (np.abs(sc.y[:, None] - sc.y) < reach)
    passes = 2 if (near.sum() > n) else 1
    fits, failed = {}, []
    for _ in range(passes):
        model = np.zeros_like(sc.data)
        for k in range(n):
            if k in fits:
                _add_resolved(model, kernel, fits[k])
            else:
                fitter._add(model, k, 1.0)
        for k in np.flatnonzero(usable):
            own = np.zeros_like(sc.data)
            if k in fits:
                _add_resolved(own, kernel, fits[k])
            else:
                fitter._add(own, k, 1.0)
            data = sc.data - sc.local_bkg[k] - (model - own)
            stamp = make_stamp(data, sc.error, sc.invalid, res["x_fit"][k], res["y_fit"][k],
                               fitter.fit_shape, fitter.basis, kernel, bound)
            if stamp.data.size <= 6 + len(stamp.background) + 2:
                continue
            try:
                fits[k] = (fit_resolved([stamp], [np.eye(2)], p2), stamp)
            except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
                failed.append(f"resolved fit of source {int(k)}: {exc}")
    for k, (fit, _) in fits.items():
        res["flux_fit"][k], res["flux_err"][k] = fit.flux[0], fit.flux_err[0]
        res["x_fit"][k], res["y_fit"][k] = fit.x[0], fit.y[0]
        res["x_err"][k], res["y_err"][k] = fit.x_err[0], fit.y_err[0]
        res["reduced_chi2"][k] = fit.chi2 / fit.dof
        major, minor, angle, snr = _major_axis(fit.shape_params, fit.shape_cov)
        res["size"][k], res["size_minor"][k] = major, minor
        res["size_angle"][k], res["size_snr"][k] = angle, snr
        res["flux_outside"][k] = fit.outside[0]
        flags = int(res["flags"][k])
        if fit.at_bound or fit.outside[0] > MAX_FLUX_OUTSIDE_BOX:
            flags |= int(PhotometryFlag.TOO_RESOLVED)
        if not fit.success:
            flags |= int(PhotometryFlag.NO_CONVERGENCE)
        if not fit.flux[0] > 0:
            flags |= int(PhotometryFlag.NON_POSITIVE_FLUX)
        res["flags"][k] = flags
    return failed


def _add_resolved(img, kernel, fitted):
    """Add a resolved fit's model (all of its kernel's reach) to ``img`` in place."""
    fit, _ = fitted
    x, y, flux, cov = fit.x[0], fit.y[0], fit.flux[0], fit.cov[0]
    if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(flux)):
        return
    ny, nx = img.shape
    ix, iy = int(np.round(x)), int(np.round(y))
    h = kernel.half
    y0, y1, x0, x1 = max(iy - h, 0), min(iy + h + 1, ny), max(ix - h, 0), min(ix + h + 1, nx)
    if x0 >= x1 or y0 >= y1:
        return
    my, mx = np.mgrid[y0 - iy:y1 - iy, x0 - ix:x1 - ix]
    img[y0:y1, x0:x1] += flux * kernel.model(cov, mx, my, (x - ix, y - iy))
