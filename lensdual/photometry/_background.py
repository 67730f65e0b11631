"""Background strategies and the linear background bases fitted with the PSF.

A basis has ``names`` (its coefficients, fitted with the PSF) and
``columns(x, y, centre=None)``, its functions at pixel coordinates about the
centre of the fitting box.
"""

import numpy as np
from scipy.ndimage import gaussian_filter

from ._filters import _BLUR_MODE, _smooth_filled

#: The background strategies of :func:`psf_photometry` (see its ``background``).
BACKGROUND_STRATEGIES = (
    "ridge",
    "residual",
    "residual-plane",
    "plane",
    "quadratic",
    "constant",
    "local",
    "none",
)

# strategy -> (fitted image, background basis: polynomial order, 'ridge' or None)
_STRATEGY = {
    "ridge": ("raw", "ridge"),
    "residual": ("highpass", 0),
    "residual-plane": ("highpass", 1),
    "plane": ("raw", 1),
    "quadratic": ("raw", 2),
    "constant": ("raw", 0),
    "local": ("raw", None),
    "none": ("raw", None),
}
_DEFAULT_BACKGROUND = "ridge"
#: The strategies whose fitted ``bkg`` is the light under a source in the image
#: itself (not in a filtered image, not fixed at 0).
SURFACE_BRIGHTNESS_BACKGROUNDS = ("ridge", "plane", "quadratic", "constant", "local")

_BKG_TERMS = {
    None: (),
    0: ("bkg",),
    1: ("bkg", "bkg_dx", "bkg_dy"),
    2: ("bkg", "bkg_dx", "bkg_dy", "bkg_dxx", "bkg_dxy", "bkg_dyy"),
}


def _box_centre(x, y):
    """Centre of the fitting box from the pixel coordinates photutils passes."""
    return 0.5 * (np.min(x) + np.max(x)), 0.5 * (np.min(y) + np.max(y))


class _NoBasis:
    names = ()

    def columns(self, x, y, centre=None):
        return []


class _PolyBasis:
    """Polynomial of order 0, 1 or 2 in (x - xc, y - yc), (xc, yc) the box centre."""

    def __init__(self, order):
        self.order = order
        self.names = _BKG_TERMS[order]

    def columns(self, x, y, centre=None):
        xc, yc = _box_centre(x, y) if centre is None else centre
        dx, dy = x - xc, y - yc
        cols = [np.ones(np.shape(dx))]
        if self.order >= 1:
            cols += [dx, dy]
        if self.order >= 2:
            cols += [dx * dx, dx * dy, dy * dy]
        return cols


class _RidgeBasis:
    r"""Arc-aligned background: :math:`f(u) + g(u)\,v + c\,v^2`.

    ``u`` runs across the arc and ``v`` along it, from the centre of the
    fitting box; the direction is that of the largest eigenvalue of the
    image's structure tensor at the box centre. ``f`` and ``g`` are
    piecewise-linear (hat functions on knots ``spacing`` apart over the box
    half-width ``half``, extrapolated linearly beyond).
    """

    def __init__(self, image, half, spacing, grad_sigma, tensor_sigma):
        self.k = max(2, int(np.round(half / spacing)))
        self.spacing = half / self.k
        n = 2 * self.k + 1
        self.names = (
            tuple(f"arc_f{i}" for i in range(n))
            + tuple(f"arc_g{i}" for i in range(n))
            + ("arc_vv",)
        )
        gx = gaussian_filter(image, grad_sigma, order=(0, 1), mode=_BLUR_MODE)
        gy = gaussian_filter(image, grad_sigma, order=(1, 0), mode=_BLUR_MODE)
        jxx = gaussian_filter(gx * gx, tensor_sigma, mode=_BLUR_MODE)
        jxy = gaussian_filter(gx * gy, tensor_sigma, mode=_BLUR_MODE)
        jyy = gaussian_filter(gy * gy, tensor_sigma, mode=_BLUR_MODE)
        # direction of the largest eigenvalue: across the arc
        self.angle = 0.5 * np.arctan2(2.0 * jxy, jxx - jyy)

    def _uv(self, x, y, centre):
        xc, yc = _box_centre(x, y) if centre is None else centre
        ny, nx = self.angle.shape
        iy = min(max(int(np.round(yc)), 0), ny - 1)
        ix = min(max(int(np.round(xc)), 0), nx - 1)
        a = self.angle[iy, ix]
        ca, sa = np.cos(a), np.sin(a)
        dx, dy = x - xc, y - yc
        return dx * ca + dy * sa, -dx * sa + dy * ca

    def _hats(self, u):
        k = self.k
        t = np.asarray(u, dtype=np.float64) / self.spacing
        knots = np.arange(-k, k + 1)
        h = np.clip(1.0 - np.abs(t[..., None] - knots), 0.0, None)
        hi = t > k
        if np.any(hi):
            e = t[hi] - k
            h[hi, -1] = 1.0 + e
            h[hi, -2] = -e
        lo = t < -k
        if np.any(lo):
            e = -k - t[lo]
            h[lo, 0] = 1.0 + e
            h[lo, 1] = -e
        return h

    def columns(self, x, y, centre=None):
        u, v = self._uv(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64), centre)
        h = self._hats(u)
        hv = h * v[..., None]
        return (
            [h[..., i] for i in range(h.shape[-1])]
            + [hv[..., i] for i in range(h.shape[-1])]
            + [v * v]
        )


def _make_basis(kind, fitdata, invalid, fit_shape, fwhm, x, y):
    if kind is None:
        return _NoBasis()
    if kind == "ridge":
        # The direction of the arc comes from the structure tensor of the image
        # with the point sources masked (discs of radius 1.5 FWHM about the
        # initial positions, filled by a normalised-convolution blur): a bright
        # source slightly off the box centre would dominate it otherwise.
        ny, nx = fitdata.shape
        yy, xx = np.ogrid[:ny, :nx]
        masked = np.zeros((ny, nx), bool) if invalid is None else invalid.copy()
        r = max(2.0, 1.5 * fwhm)
        ri = int(np.ceil(r))
        for xi, yi in zip(x, y, strict=True):
            x0, x1 = max(int(xi) - ri, 0), min(int(xi) + ri + 2, nx)
            y0, y1 = max(int(yi) - ri, 0), min(int(yi) + ri + 2, ny)
            masked[y0:y1, x0:x1] |= (xx[:, x0:x1] - xi) ** 2 + (yy[y0:y1] - yi) ** 2 <= r * r
        image = fitdata
        if masked.any():
            image = np.where(masked, _smooth_filled(fitdata, masked, r), fitdata)
        half = min(fit_shape) // 2
        spacing = float(np.clip(0.6 * fwhm, 1.0, 3.0))
        return _RidgeBasis(image, half, spacing, max(1.0, 0.6 * fwhm), max(2.0, 1.6 * fwhm))
    return _PolyBasis(kind)
