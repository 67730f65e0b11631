"""Mock JWST-like cutouts of the fold pair of arcs, rendered with lenstronomy.

:func:`render_mock_images` paints the lensed host galaxy (a Sérsic source)
and the point sources of a constellation on one small cutout per arc and
band, convolves them with the band's PSF and adds sky, Poisson and read
noise. The cutouts are `~astropy.nddata.CCDData` with a celestial WCS, an
uncertainty and a unit, ready for :mod:`lensdual.detection`.
:func:`write_mock_images` and :func:`read_mock_images` store them as FITS
files.
"""

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.io import fits
from astropy.nddata import CCDData, StdDevUncertainty
from astropy.table import QTable
from astropy.wcs import WCS
from scipy.special import erf

from .._frames import tangent_to_sky
from .._lens.model import LensModelBase
from .._pairs_table import POSITION_COLUMNS, arc_xy, flux_col
from .._validation import as_angle_scalar, as_int, as_positions, as_real
from . import _clusters, _psf, _scene
from ._clusters import CLUSTER_RADIUS_RANGE, draw_cluster_radii
from ._psf import HEX_PSF_WAVELENGTH, hexagonal_pupil_psf
from ._scene import MOCK_CLUMPS, MOCK_ICL, MOCK_MEMBER, MOCK_PATCH
from .lens_system import LensSystem

__all__ = [
    "CLUSTER_RADIUS_RANGE",
    "DEFAULT_SKY_CENTER",
    "HEX_PSF_WAVELENGTH",
    "MOCK_CLUMPS",
    "MOCK_HOST",
    "MOCK_ICL",
    "MOCK_MEMBER",
    "MOCK_PATCH",
    "PSF_FWHM",
    "MockImages",
    "draw_cluster_radii",
    "hexagonal_pupil_psf",
    "lens_to_sky",
    "read_mock_images",
    "render_mock_images",
    "write_mock_images",
]

#: Gaussian-equivalent PSF FWHM of JWST/NIRCam wide bands (approximate, from
#: the JWST User Documentation; F150W and F200W as used by lensdual's tests).
#: A band that is not listed needs an explicit ``psf``.
PSF_FWHM = {
    "F090W": 0.030 * u.arcsec,
    "F115W": 0.037 * u.arcsec,
    "F150W": 0.050 * u.arcsec,
    "F200W": 0.066 * u.arcsec,
    "F277W": 0.092 * u.arcsec,
    "F356W": 0.116 * u.arcsec,
    "F444W": 0.145 * u.arcsec,
}

#: Sky position of the lens centre (the origin of the lens frame): the
#: SMACS J0723.3-7327 cluster (ICRS).
DEFAULT_SKY_CENTER = SkyCoord(110.8270 * u.deg, -73.4545 * u.deg, frame="icrs")

#: The default host galaxy: a circular Sérsic source of index n = 0.5 (a
#: Gaussian profile), half-light radius 0.3 arcsec and unlensed total flux
#: 300 nJy in every band, centred on the constellation (``center=None``: the
#: mean of the point sources' source-plane positions). Its radial arcs are
#: smooth on the 5-pixel scale of the detection filter, so that the filter
#: picks out the point sources rather than the arc's ridge.
#: ``host=dict(...)`` overrides single keys.
MOCK_HOST = {
    "flux": 300.0 * u.nJy,
    "R_sersic": 0.3 * u.arcsec,
    "n_sersic": 0.5,
    "e1": 0.0,
    "e2": 0.0,
    "center": None,
}

# 3631 Jy in nJy: f = _AB_NJY * 10**(-0.4 m)
_AB_NJY = 3631e9
_GAUSS_FWHM = 2.0 * math.sqrt(2.0 * math.log(2.0))
_IMAGE_UNIT = u.nJy
_ARCS = ("L1", "L2")
_TRUTH_FILE = "truth_pairs.ecsv"


# ---------------------------------------------------------------------------
# result container
# ---------------------------------------------------------------------------


class MockImages(Mapping):
    """The cutouts of :func:`render_mock_images`: a mapping ``(arc, band) -> CCDData``.

    Keys are ``(arc, band)`` tuples, e.g. ``("L1", "F150W")``; iteration
    follows the arcs, then the bands. Made by :func:`render_mock_images`
    and :func:`read_mock_images`.

    Parameters
    ----------
    images : dict of (str, str) to `~astropy.nddata.CCDData`
        The cutouts.
    pairs : `~astropy.table.QTable`, optional
        The truth table.
    host_model, point_source_model, image_plane_model : dict, optional
        The noiseless components, keyed like ``images``.

    Attributes
    ----------
    pairs : `~astropy.table.QTable` or None
        The truth: the pairs table used for the point sources (positions in
        the lens frame, magnifications, fluxes), plus the columns
        ``snr1_<band>`` and ``snr2_<band>``, the PSF-weighted (optimal)
        signal-to-noise ratio of each image on its own arc's cutout under
        the noise model (NaN if the image lies outside the cutout). None
        when read back from files without a truth table.
    host_model, point_source_model : dict of tuple to `~astropy.units.Quantity`
        Per ``(arc, band)``, the noiseless lensed, PSF-convolved host and
        point sources (nJy per pixel, sky-subtracted). Empty when read back
        from files.
    image_plane_model : dict of tuple to `~astropy.units.Quantity`
        Per ``(arc, band)``, the noiseless light that is not lensed: the
        cluster member, the intracluster light and the diffuse patch of
        ``render_mock_images(member=..., icl=..., patch=...)`` (nJy per
        pixel); zeros when there is none, empty when read back from files.
    """

    def __init__(self, images, *, pairs=None, host_model=None, point_source_model=None,
                 image_plane_model=None):
        self._images = dict(images)
        for key, image in self._images.items():
            if not (isinstance(key, tuple) and len(key) == 2
                    and all(isinstance(k, str) for k in key)):
                raise TypeError(f"the keys of images must be (arc, band) tuples of strings, "
                                f"got {key!r}")
            if not isinstance(image, CCDData):
                raise TypeError(f"images[{key!r}] must be a CCDData, got {type(image).__name__}")
        self.pairs = pairs
        self.host_model = dict(host_model or {})
        self.point_source_model = dict(point_source_model or {})
        self.image_plane_model = dict(image_plane_model or {})

    def __getitem__(self, key):
        return self._images[key]

    def __iter__(self):
        return iter(self._images)

    def __len__(self):
        return len(self._images)

    def __repr__(self):
        shapes = sorted({im.shape for im in self._images.values()})
        return (f"<MockImages arcs={list(self.arcs)} bands={list(self.bands)} "
                f"shape={shapes[0] if len(shapes) == 1 else shapes}>")

    @property
    def arcs(self):
        """tuple of str: the arcs, in order of first appearance."""
        return tuple(dict.fromkeys(k[0] for k in self._images))

    @property
    def bands(self):
        """tuple of str: the bands, in order of first appearance."""
        return tuple(dict.fromkeys(k[1] for k in self._images))

    def arc(self, arc):
        """The bands of one arc, ``{band: CCDData}``, as :func:`find_point_sources` takes.

        Parameters
        ----------
        arc : str
            One of :attr:`arcs` (``"L1"`` or ``"L2"``).

        Returns
        -------
        images : dict of str to `~astropy.nddata.CCDData`
        """
        out = {band: image for (a, band), image in self._images.items() if a == arc}
        if not out:
            raise ValueError(f"arc must be one of {list(self.arcs)}, got {arc!r}")
        return out

    def truth_pixels(self, arc):
        """0-based pixel positions ``(x, y)`` of the true images on ``arc``'s cutouts.

        Parameters
        ----------
        arc : {"L1", "L2"}

        Returns
        -------
        pixels : `~numpy.ndarray`, shape (N, 2)
            One row per row of :attr:`pairs` (all bands of an arc share the
            pixel grid), through the cutouts' WCS.
        """
        if self.pairs is None:
            raise ValueError("no truth table: these images carry no pairs")
        image = next(iter(self.arc(arc).values()))
        sky = lens_to_sky(arc_xy(self.pairs, arc) * u.arcsec, _sky_center_of(image))
        px, py = image.wcs.world_to_pixel(sky)
        return np.column_stack([px, py])


# ---------------------------------------------------------------------------
# frames
# ---------------------------------------------------------------------------


def lens_to_sky(xy, sky_center=DEFAULT_SKY_CENTER):
    """Sky positions of lens-frame positions, the convention of the mock images.

    The lens frame (arcsec, origin at the lens centre) is the gnomonic (TAN)
    plane about ``sky_center`` with ``x`` pointing west and ``y`` north:
    RA decreases with ``x``, Dec increases with ``y``.

    Parameters
    ----------
    xy : `~astropy.units.Quantity`, shape (N, 2)
        Lens-frame positions (angles).
    sky_center : `~astropy.coordinates.SkyCoord`
        Sky position of the lens centre (default :data:`DEFAULT_SKY_CENTER`).

    Returns
    -------
    sky : `~astropy.coordinates.SkyCoord`, shape (N,)
        ICRS positions.
    """
    if not isinstance(sky_center, SkyCoord) or not sky_center.isscalar:
        raise TypeError(f"sky_center must be a scalar SkyCoord, got {sky_center!r}")
    sky_center = sky_center.icrs
    arr = as_positions(xy, "xy")
    return tangent_to_sky(arr[:, 0], arr[:, 1], sky_center)


def _sky_center_of(image):
    hdr = image.meta
    return SkyCoord(float(hdr["LENSRA"]) * u.deg, float(hdr["LENSDEC"]) * u.deg, frame="icrs")


def _tan_wcs(sky_center, scale, origin):
    """TAN WCS: 0-based pixel (i, j) <-> lens frame (origin + scale * (i, j)) arcsec."""
    w = WCS(naxis=2)
    w.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    w.wcs.cunit = ["deg", "deg"]
    w.wcs.radesys = "ICRS"
    w.wcs.crval = [sky_center.ra.deg, sky_center.dec.deg]
    w.wcs.cdelt = [-scale / 3600.0, scale / 3600.0]
    # lens x = 0 at 0-based pixel -origin/scale, i.e. FITS pixel 1 - origin/scale
    w.wcs.crpix = [1.0 - origin[0] / scale, 1.0 - origin[1] / scale]
    w.wcs.set()
    return w


# ---------------------------------------------------------------------------
# input checks
# ---------------------------------------------------------------------------


def _as_quantity_scalar(value, name, unit, *, allow_zero=True):
    if not isinstance(value, u.Quantity):
        raise TypeError(f"{name} must be a scalar Quantity in units of {unit}, got {value!r}")
    try:
        v = value.to_value(unit)
    except u.UnitsError:
        raise TypeError(f"{name} must have units convertible to {unit}, got {value.unit!s}"
                        ) from None
    if np.ndim(v) != 0:
        raise ValueError(f"{name} must be a scalar, got shape {np.shape(v)}")
    v = float(v)
    if not np.isfinite(v) or v < 0 or (not allow_zero and v == 0):
        raise ValueError(f"{name} must be finite and {'>=' if allow_zero else '>'} 0, "
                         f"got {value}")
    return v


def _check_kernel(kernel, name):
    """A user PSF as a float array, checked and normalised to sum 1."""
    if isinstance(kernel, (str, Path)):
        path = Path(kernel)
        if not path.is_file():
            raise ValueError(f"{name}: no such FITS file {str(path)!r}")
        with fits.open(path) as hdul:
            hdu = next((h for h in hdul if h.data is not None), None)
            if hdu is None:
                raise ValueError(f"{name}: FITS file {str(path)!r} holds no image")
            kernel = np.array(hdu.data, dtype=np.float64)
    elif isinstance(kernel, u.Quantity):
        kernel = kernel.value
    if not isinstance(kernel, np.ndarray) and not isinstance(kernel, (list, tuple)):
        raise TypeError(f"{name} must be None, a 2-D array or the path of a FITS file, got "
                        f"{type(kernel).__name__}")
    arr = np.asarray(kernel)
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{name} must hold real numbers, got dtype {arr.dtype}")
    arr = np.array(arr, dtype=np.float64)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array, got {arr.ndim} dimension(s)")
    if arr.shape[0] != arr.shape[1] or arr.shape[0] % 2 == 0:
        raise ValueError(f"{name} must be square with an odd number of pixels per side "
                         f"(centred on the central pixel), got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    if (arr < 0).any():
        raise ValueError(f"{name} must be non-negative, got a minimum of {arr.min():g}")
    total = arr.sum()
    if total <= 0:
        raise ValueError(f"{name} must have a positive sum")
    return arr / total


def _gaussian_kernel(fwhm, scale, supersampling):
    """Pixel-integrated Gaussian, sampled at ``scale / supersampling``, odd-sized, sum 1."""
    sigma = fwhm / _GAUSS_FWHM / (scale / supersampling)
    half = max(2, math.ceil(4.0 * fwhm / scale))  # +-4 FWHM, in pixels
    m = (2 * half + 1) * supersampling
    edges = np.arange(m + 1) - m / 2.0
    w = np.diff(0.5 * erf(edges / (math.sqrt(2.0) * sigma)))
    k = np.outer(w, w)
    return k / k.sum()


def _moment_fwhm(kernel):
    """Gaussian-equivalent FWHM (pixels) from the second moments of a kernel."""
    n = kernel.shape[0]
    c = np.arange(n) - (n - 1) / 2.0
    xx, yy = np.meshgrid(c, c)
    mx = (kernel * xx).sum()
    my = (kernel * yy).sum()
    var = 0.5 * ((kernel * (xx - mx) ** 2).sum() + (kernel * (yy - my) ** 2).sum())
    return _GAUSS_FWHM * math.sqrt(max(var, 0.0))


def _check_pairs(pairs, bands):
    if not isinstance(pairs, QTable):
        raise TypeError(f"pairs must be an astropy QTable (e.g. from "
                        f"LensSystem.constellation), got {type(pairs).__name__}")
    if len(pairs) == 0:
        raise ValueError("pairs is empty")
    needed = list(POSITION_COLUMNS) + [flux_col(k, b) for b in bands for k in "12"]
    missing = [c for c in needed if c not in pairs.colnames]
    if missing:
        raise ValueError(f"pairs lacks column(s) {missing}")
    for c in POSITION_COLUMNS:
        col = pairs[c]
        if not isinstance(col, u.Quantity) or col.unit.physical_type != "angle":
            raise ValueError(f"pairs[{c!r}] must be an angle column (arcsec)")
        if not np.isfinite(col.value).all():
            raise ValueError(f"pairs[{c!r}] contains NaN or infinite values")
    for b in bands:
        for k in "12":
            name = flux_col(k, b)
            col = pairs[name]
            if not isinstance(col, u.Quantity):
                raise ValueError(f"pairs[{name!r}] must be a Quantity column (e.g. nJy)")
            try:
                v = col.to_value(_IMAGE_UNIT)
            except u.UnitsError:
                raise ValueError(f"pairs[{name!r}] must be a flux density (e.g. nJy), "
                                 f"got unit {col.unit!s}") from None
            if not (np.isfinite(v).all() and (v >= 0).all()):
                raise ValueError(f"pairs[{name!r}] must be finite and >= 0")


def _host_params(host, bands):
    """None (no host), or the validated host parameters with per-band fluxes (nJy)."""
    p = _scene.options(host, MOCK_HOST, "host")
    if p is None:
        return None
    out = {
        "flux": _scene.per_band(p["flux"], bands, "host['flux']",
                          lambda v, n: _as_quantity_scalar(v, n, _IMAGE_UNIT)),
        "R_sersic": as_angle_scalar(p["R_sersic"], "host['R_sersic']", allow_zero=False),
        "n_sersic": as_real(p["n_sersic"], "host['n_sersic']", minimum=0.2, maximum=8.0),
        "e1": as_real(p["e1"], "host['e1']", minimum=-0.9, maximum=0.9),
        "e2": as_real(p["e2"], "host['e2']", minimum=-0.9, maximum=0.9),
        "center": None,
    }
    centre = p["center"]
    if centre is not None:
        if isinstance(centre, u.Quantity) and centre.shape not in ((2,), (1, 2)):
            raise ValueError(f"host['center'] must have shape (2,), got shape {centre.shape}")
        if isinstance(centre, u.Quantity):
            centre = centre.reshape(1, 2)
        out["center"] = as_positions(centre, "host['center']")[0]
    return out


class _LensAdapter(LensModelBase):
    """lenstronomy's LensModel interface over any ``LensSystem.lens_model``.

    Caches the last ray-shooting (the bands of a cutout share the grid); the
    magnification comes from the model's Hessian.
    """

    multi_plane = False

    def __init__(self, model, kwargs):
        self._model = model
        self._kwargs = kwargs
        self._cache = None

    def change_source_redshift(self, z_source):  # single source plane
        return None

    def ray_shooting(self, x, y, kwargs=None, **_):
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        c = self._cache
        if c is not None and c[0].shape == x.shape and np.array_equal(c[0], x) \
                and np.array_equal(c[1], y):
            return c[2], c[3]
        bx, by = self._model.ray_shooting(x, y, self._kwargs)
        self._cache = (x.copy(), y.copy(), np.asarray(bx), np.asarray(by))
        return self._cache[2], self._cache[3]

    def alpha(self, x, y, kwargs=None, **_):
        return self._model.alpha(x, y, self._kwargs)

    def hessian(self, x, y, kwargs=None, **_):
        return self._model.hessian(x, y, self._kwargs)


# ---------------------------------------------------------------------------
# rendering
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class _BandPSF:
    """One band's PSF: the kernel lenstronomy convolves with, and how it is described."""

    kernel: np.ndarray  # the kernel given to lenstronomy, sampled at scale / supersampling
    supersampling: int  # the sub-pixels per pixel side of ``kernel``
    pixel_kernel: np.ndarray  # the kernel at the pixel scale (the cutout's ``psf``)
    fwhm: float  # Gaussian-equivalent FWHM [arcsec] (POPPY: of the azimuthal mean)
    kind: str  # "GAUSSIAN" (band default), "USER" or "POPPY"


@dataclass(frozen=True)
class _RenderSettings:
    """The checked settings of :func:`render_mock_images` that all cutouts share."""

    bands: list  # band names
    scale: float  # pixel scale [arcsec]
    n: int  # pixels per cutout side (odd, >= 15)
    supersampling: int  # sub-pixels per pixel side (odd)
    noise: bool  # add noise
    sky_center: SkyCoord  # the lens centre (ICRS)
    exposure_time: float  # [s]
    sky_background: dict  # per band [MJy/sr]
    read_noise: dict  # per band [electron]
    zero_point: dict  # per band [AB mag of 1 electron/s]
    psfs: dict  # per band, a _BandPSF

    @property
    def half(self):
        """Pixels from the central pixel to the edge of a cutout."""
        return (self.n - 1) / 2.0


@dataclass(frozen=True)
class _Scene:
    """What every cutout shows: the truth's point sources and the host, in the lens frame."""

    system: LensSystem
    lens: "_LensAdapter"  # shared by all cutouts (it caches the ray shooting)
    source_model: object  # lenstronomy LightModel of the host
    pos: dict  # per arc, (N, 2) lens-frame positions [arcsec]
    flux: dict  # per (arc, band), (N,) point-source fluxes [nJy]
    all_xy: np.ndarray  # the positions of both arcs, stacked
    kwargs_host: dict | None  # lenstronomy Sérsic parameters without "amp"; None: no host
    host_amp: dict  # per band, the host's lenstronomy amplitude
    cov: np.ndarray | None = None  # (2N, 2, 2) image covariances of all_xy [arcsec^2]; None: points
    clumps: list | None = None  # lenstronomy GAUSSIAN kwargs of the host's clumps; None: none
    member: dict | None = None  # the checked member (_scene.member_params); None: none
    icl: dict | None = None  # the checked ICL gradient; None: none
    patch: dict | None = None  # the checked diffuse patch; None: none

    @property
    def has_image_plane_light(self):
        """Whether a member, ICL or a patch is to be painted."""
        return self.member is not None or self.icl is not None or self.patch is not None

    def arc_centre(self, arc):
        """The mean lens-frame position of the arc's images [arcsec]."""
        return self.pos[arc].mean(axis=0)


def _check_bands(bands):
    """The band names as a list: non-empty strings, no duplicates."""
    bands = [bands] if isinstance(bands, str) else list(bands)
    if not bands or not all(isinstance(b, str) and b for b in bands):
        raise ValueError(f"bands must be a non-empty sequence of band names, got {bands!r}")
    if len(set(bands)) != len(bands):
        raise ValueError(f"bands contains duplicates: {bands}")
    return bands


def _cutout_pixels(cutout_size, scale):
    """Pixels per cutout side from ``cutout_size``: odd and at least 15."""
    if isinstance(cutout_size, u.Quantity):
        n = math.ceil(as_angle_scalar(cutout_size, "cutout_size", allow_zero=False) / scale
                      - 1e-9)
    elif isinstance(cutout_size, (int, np.integer)) and not isinstance(cutout_size, bool):
        n = as_int(cutout_size, "cutout_size", minimum=1)
    else:
        raise TypeError(f"cutout_size must be an angle Quantity or a number of pixels, got "
                        f"{cutout_size!r}")
    return max(15, n + (1 - n % 2))


def _band_psfs(psf, bands, scale, ss):
    """Each band's `_BandPSF`: the default Gaussian of :data:`PSF_FWHM`, or the user's kernel."""
    psfs = {}
    for b in bands:
        user = psf[b] if isinstance(psf, Mapping) and b in psf else (
            None if isinstance(psf, Mapping) else psf)
        if isinstance(user, str) and user == "poppy":
            kernel = hexagonal_pupil_psf(b, scale * u.arcsec, supersampling=ss)
            pixel_kernel = _psf.bin_kernel(kernel, ss)
            fwhm = _psf.half_max_fwhm(kernel) * scale / ss
            psfs[b] = _BandPSF(kernel, ss, pixel_kernel, fwhm, "POPPY")
        elif user is None:
            if b not in PSF_FWHM:
                raise ValueError(f"band {b!r} has no default PSF (known bands: "
                                 f"{sorted(PSF_FWHM)}); pass psf= for it")
            fwhm = PSF_FWHM[b].to_value(u.arcsec)
            kernel = _gaussian_kernel(fwhm, scale, ss)
            pixel_kernel = _gaussian_kernel(fwhm, scale, 1)
            psfs[b] = _BandPSF(kernel, ss, pixel_kernel, fwhm, "GAUSSIAN")
        else:
            name = f"psf[{b!r}]" if isinstance(psf, Mapping) else "psf"
            kernel = _check_kernel(user, name)
            psfs[b] = _BandPSF(kernel, 1, kernel, _moment_fwhm(kernel) * scale, "USER")
    return psfs


def _check_render_settings(*, bands, pixel_scale, cutout_size, psf, exposure_time,
                           sky_background, read_noise, zero_point, noise, supersampling,
                           sky_center):
    """The checked `_RenderSettings` of :func:`render_mock_images`'s arguments."""
    bands = _check_bands(bands)
    scale = as_angle_scalar(pixel_scale, "pixel_scale", allow_zero=False)
    n = _cutout_pixels(cutout_size, scale)
    ss = as_int(supersampling, "supersampling", minimum=1)
    if ss % 2 == 0:
        raise ValueError(f"supersampling must be odd, got {ss}")
    if not isinstance(noise, (bool, np.bool_)):
        raise TypeError(f"noise must be True or False, got {noise!r}")
    if not isinstance(sky_center, SkyCoord) or not sky_center.isscalar:
        raise TypeError(f"sky_center must be a scalar SkyCoord, got {sky_center!r}")
    t = _as_quantity_scalar(exposure_time, "exposure_time", u.s, allow_zero=False)
    sky_sb = _scene.per_band(sky_background, bands, "sky_background",
                       lambda v, nm: _as_quantity_scalar(v, nm, u.MJy / u.sr))
    rn = _scene.per_band(read_noise, bands, "read_noise",
                   lambda v, nm: _as_quantity_scalar(v, nm, u.electron))
    zp = _scene.per_band(zero_point, bands, "zero_point",
                   lambda v, nm: as_real(v, nm, minimum=0.0, maximum=40.0))
    return _RenderSettings(bands=bands, scale=scale, n=n, supersampling=ss, noise=noise,
                           sky_center=sky_center.icrs, exposure_time=t, sky_background=sky_sb,
                           read_noise=rn, zero_point=zp,
                           psfs=_band_psfs(psf, bands, scale, ss))


def _truth_table(system, bands, pairs, intrinsic_flux, rng):
    """A copy of the checked ``pairs``, or the constellation of ``system`` when None."""
    if pairs is None:
        if intrinsic_flux is None:
            if system.sources is None:
                raise ValueError("system has no sources: pass pairs=..., or build the system "
                                 "with sources=...")
            n_src = len(system.sources)
            base = 10 ** rng.uniform(np.log10(3.0), 1.0, n_src)
            colour = 10 ** rng.uniform(-0.1, 0.1, (len(bands), n_src))
            intrinsic_flux = {b: base * colour[k] for k, b in enumerate(bands)}
        pairs = system.constellation(bands=bands, intrinsic_flux=intrinsic_flux,
                                     flux_unit=_IMAGE_UNIT, seed=rng)
    else:
        _check_pairs(pairs, bands)
    return QTable(pairs, copy=True)


def _host_kwargs(host_p, truth, system, xy_l1):
    """The host's lenstronomy Sérsic parameters (no ``amp``); default centre: the sources'."""
    centre = host_p["center"]
    if centre is None:
        if "beta_x" in truth.colnames and "beta_y" in truth.colnames:
            centre = np.array([np.mean(truth["beta_x"].to_value(u.arcsec)),
                               np.mean(truth["beta_y"].to_value(u.arcsec))])
        else:
            centre = system.ray_shoot(xy_l1 * u.arcsec).to_value(u.arcsec).mean(axis=0)
    return {"R_sersic": host_p["R_sersic"], "n_sersic": host_p["n_sersic"],
            "e1": host_p["e1"], "e2": host_p["e2"],
            "center_x": float(centre[0]), "center_y": float(centre[1])}


def _make_scene(system, truth, bands, host_p, r_eff=None, extras=None):
    """The `_Scene` of the truth table and the host parameters (None: no host).

    With ``r_eff`` (not None) the point sources are finite-size clusters: the
    truth gains ``r_eff``, ``r_eff_angle`` and ``stretch1``, ``stretch2``.
    ``extras`` holds the checked ``clumps`` (with their generator
    ``clump_rng``), ``member``, ``icl`` and ``patch`` (each None when off).
    """
    extras = extras or {}
    from lenstronomy.LightModel.light_model import LightModel

    pos = {arc: arc_xy(truth, arc) for arc in _ARCS}
    flux = {(arc, b): truth[flux_col(arc, b)].to_value(_IMAGE_UNIT)
            for arc in _ARCS for b in bands}
    source_model = LightModel(["SERSIC_ELLIPSE"])
    kwargs_host, host_amp = None, {}
    if host_p is not None:
        kwargs_host = _host_kwargs(host_p, truth, system, pos["L1"])
        unit_flux = source_model.total_flux([{**kwargs_host, "amp": 1.0}])[0]
        host_amp = {b: host_p["flux"][b] / unit_flux for b in bands}
    clumps = None
    if extras.get("clumps") is not None:
        if kwargs_host is None:  # clumps without the host's light: about its default centre
            kwargs_host = _host_kwargs(_host_params(True, bands), truth, system, pos["L1"])
            host_amp = dict.fromkeys(bands, 0.0)
        centre = np.array([kwargs_host["center_x"], kwargs_host["center_y"]])
        clumps = _scene.draw_clumps(extras["clumps"], centre, extras["clump_rng"])
        source_model = LightModel(["SERSIC_ELLIPSE"] + ["GAUSSIAN"] * len(clumps))
    lens = _LensAdapter(system.lens_model, system.kwargs_lens)
    all_xy = np.vstack([pos[a] for a in _ARCS])
    cov = None
    if r_eff is not None:
        cov = _cluster_covariances(system, lens, truth, all_xy, r_eff)
    return _Scene(system=system, lens=lens, source_model=source_model, pos=pos, flux=flux,
                  all_xy=all_xy, kwargs_host=kwargs_host, host_amp=host_amp, cov=cov,
                  clumps=clumps, member=extras.get("member"), icl=extras.get("icl"),
                  patch=extras.get("patch"))


def _cluster_covariances(system, lens, truth, all_xy, r_eff):
    """The image covariances of finite-size clusters; adds their columns to ``truth``."""
    n_rows = len(truth)
    angle, sigma = _clusters.source_sigmas(r_eff, n_rows, system)
    cov, stretch = _clusters.image_covariances(lens, all_xy, np.concatenate([sigma, sigma]))
    truth["r_eff"] = u.Quantity(np.broadcast_to(r_eff.value, (n_rows,)), r_eff.unit, copy=True)
    truth["r_eff_angle"] = (angle * u.arcsec).to(u.mas)
    truth["stretch1"] = stretch[:n_rows]
    truth["stretch2"] = stretch[n_rows:]
    return cov


def _arc_grid(settings, xy):
    """The pixel grid of an arc's cutouts: ``(PixelGrid, centre [arcsec], TAN WCS)``."""
    from lenstronomy.Data.pixel_grid import PixelGrid

    scale, n = settings.scale, settings.n
    centre_pix = np.round(xy.mean(axis=0) / scale)
    cen = centre_pix * scale
    origin = cen - settings.half * scale  # lens frame of pixel (0, 0)
    grid = PixelGrid(nx=n, ny=n, transform_pix2angle=np.diag([scale, scale]),
                     ra_at_xy_0=float(origin[0]), dec_at_xy_0=float(origin[1]))
    return grid, cen, _tan_wcs(settings.sky_center, scale, origin)


def _psf_and_numerics(band_psf, ss):
    """lenstronomy's PSF and ``kwargs_numerics`` of one band."""
    from lenstronomy.Data.psf import PSF

    kernel, k_ss = band_psf.kernel, band_psf.supersampling
    lpsf = PSF(psf_type="PIXEL", kernel_point_source=kernel,
               point_source_supersampling_factor=k_ss)
    kwargs_numerics = {"supersampling_factor": ss,
                       "supersampling_convolution": k_ss > 1,
                       "point_source_supersampling_factor": k_ss,
                       # scipy's fftconvolve: lenstronomy's "fft_static" calls
                       # numpy.fft.rfftn in a way numpy 2 deprecates
                       "convolution_type": "fft"}
    if k_ss > 1:
        kwargs_numerics["supersampling_kernel_size"] = kernel.shape[0] // k_ss
    return lpsf, kwargs_numerics


def _image_model(grid, band_psf, scene, ss):
    """lenstronomy's ImageModel of one cutout and band."""
    from lenstronomy.ImSim.image_model import ImageModel
    from lenstronomy.PointSource.point_source import PointSource

    lpsf, kwargs_numerics = _psf_and_numerics(band_psf, ss)
    return ImageModel(grid, lpsf, lens_model_class=scene.lens,
                      source_model_class=scene.source_model,
                      point_source_class=PointSource(["LENSED_POSITION"],
                                                     fixed_magnification_list=[False]),
                      kwargs_numerics=kwargs_numerics)


def _host_image(model, scene, band, n):
    """The lensed, PSF-convolved host on one cutout (nJy per pixel; zeros without host)."""
    if scene.kwargs_host is None:
        return np.zeros((n, n))
    amp = scene.host_amp[band]
    kwargs_source = [{**scene.kwargs_host, "amp": amp}] + list(scene.clumps or [])
    return np.asarray(model.source_surface_brightness(
        kwargs_source, scene.system.kwargs_lens), dtype=np.float64)


def _image_plane_image(settings, scene, arc, band, grid, cen):
    """The member, the ICL and the patch on one cutout (nJy per pixel; not lensed)."""
    from lenstronomy.ImSim.image_model import ImageModel
    from lenstronomy.LightModel.light_model import LightModel

    n = settings.n
    out = np.zeros((n, n))
    centres = {a: scene.arc_centre(a) for a in _ARCS}
    profiles, kwargs = _scene.image_plane_kwargs(scene.member, scene.patch, centres,
                                                 scene.pos, band)
    if profiles:
        lpsf, kwargs_numerics = _psf_and_numerics(settings.psfs[band], settings.supersampling)
        model = ImageModel(grid, lpsf, lens_light_model_class=LightModel(profiles),
                           kwargs_numerics=kwargs_numerics)
        out += np.asarray(model.lens_surface_brightness(kwargs), dtype=np.float64)
    if scene.icl is not None and scene.icl["arc"] == arc:
        origin = cen - settings.half * settings.scale
        out += _scene.icl_image(scene.icl, band, centres[arc], origin, settings.scale, n)
    return out


def _point_source_image(model, scene, settings, band, cen):
    """The point sources of both arcs that can touch one cutout, PSF-convolved (nJy/pixel)."""
    n, scale = settings.n, settings.scale
    band_psf = settings.psfs[band]
    reach = (settings.half + band_psf.kernel.shape[0] / band_psf.supersampling) * scale
    fl = np.concatenate([scene.flux[(a, band)] for a in _ARCS])
    all_xy = scene.all_xy
    near = (np.abs(all_xy - cen) <= reach).all(axis=1) & (fl > 0)
    ps_img = np.zeros((n, n))
    if near.any():
        ps_img = np.asarray(model.point_source(
            [{"ra_image": all_xy[near, 0], "dec_image": all_xy[near, 1],
              "point_amp": fl[near]}], scene.system.kwargs_lens), dtype=np.float64)
    return ps_img


def _add_noise(clean, settings, band, rng):
    """``(data, sigma)`` of a noiseless cutout: sky, Poisson and read noise, sky subtracted."""
    t, n, rn = settings.exposure_time, settings.n, settings.read_noise[band]
    f_e = _AB_NJY * 10 ** (-0.4 * settings.zero_point[band])  # nJy per (e-/s)
    sky_pix = (settings.sky_background[band] * u.MJy / u.sr
               * (settings.scale * u.arcsec) ** 2).to_value(u.nJy)
    electrons = (clean + sky_pix) / f_e * t
    sigma = np.sqrt(electrons + rn ** 2) * f_e / t
    if settings.noise:
        counts = rng.poisson(electrons) + rn * rng.standard_normal((n, n))
        data = counts * f_e / t - sky_pix
    else:
        data = clean.copy()
    return data, sigma


def _optimal_snr(model, scene, settings, arc, band, cen, sigma):
    """The PSF-weighted SNR of each of the arc's images on its cutout (NaN when outside)."""
    snr = np.full(len(scene.pos[arc]), np.nan)
    pos, fcol = scene.pos[arc], scene.flux[(arc, band)]
    inside = (np.abs(pos - cen) <= settings.half * settings.scale).all(axis=1) & (fcol > 0)
    for r in np.flatnonzero(inside):
        one = np.asarray(model.point_source(
            [{"ra_image": pos[r:r + 1, 0], "dec_image": pos[r:r + 1, 1],
              "point_amp": fcol[r:r + 1]}], scene.system.kwargs_lens))
        snr[r] = math.sqrt(float(np.sum((one / sigma) ** 2)))
    return snr


def _cutout_header(settings, arc, band, cen):
    """The FITS header (``meta``) of one cutout."""
    band_psf = settings.psfs[band]
    meta = fits.Header()
    meta["BAND"] = (band, "band")
    meta["ARC"] = (arc, "arc of the fold pair")
    meta["PIXSCALE"] = (settings.scale, "pixel scale [arcsec]")
    meta["PSFFWHM"] = (band_psf.fwhm, "PSF FWHM (Gaussian-equivalent) [arcsec]")
    meta["PSFTYPE"] = (band_psf.kind, "hexagonal pupil, by poppy" if band_psf.kind == "POPPY"
                       else "GAUSSIAN (band default) or USER")
    meta["EXPTIME"] = (settings.exposure_time, "exposure time [s]")
    meta["SKYBKG"] = (settings.sky_background[band], "sky background [MJy/sr], subtracted")
    meta["RDNOISE"] = (settings.read_noise[band], "read noise per pixel [electron]")
    meta["ZEROPT"] = (settings.zero_point[band], "AB magnitude of 1 electron/s")
    meta["NOISE"] = (bool(settings.noise), "noise added")
    meta["CENX"] = (float(cen[0]), "lens-frame x of the central pixel [arcsec]")
    meta["CENY"] = (float(cen[1]), "lens-frame y of the central pixel [arcsec]")
    meta["LENSRA"] = (settings.sky_center.ra.deg, "RA of the lens centre [deg]")
    meta["LENSDEC"] = (settings.sky_center.dec.deg, "Dec of the lens centre [deg]")
    return meta


def _cluster_images(scene, settings, band, cen):
    """Per row of ``scene.all_xy``, the image of its finite-size cluster on one cutout."""
    band_psf = settings.psfs[band]
    fl = np.concatenate([scene.flux[(a, band)] for a in _ARCS])
    return _clusters.cluster_images(
        scene.all_xy, fl, scene.cov, kernel=band_psf.kernel,
        kernel_supersampling=band_psf.supersampling, origin=cen - settings.half * settings.scale,
        scale=settings.scale, n=settings.n)


def _cluster_snr(images, scene, settings, arc, band, cen, sigma):
    """The optimal SNR of each of the arc's clusters on its cutout (NaN when outside)."""
    snr = np.full(len(scene.pos[arc]), np.nan)
    pos, fcol = scene.pos[arc], scene.flux[(arc, band)]
    first = 0 if arc == _ARCS[0] else len(scene.pos[_ARCS[0]])
    inside = (np.abs(pos - cen) <= settings.half * settings.scale).all(axis=1) & (fcol > 0)
    for r in np.flatnonzero(inside):
        one = images.get(first + int(r))
        snr[r] = 0.0 if one is None else math.sqrt(float(np.sum((one / sigma) ** 2)))
    return snr


def _render_cutout(settings, scene, arc, band, grid, cen, wcs, rng):
    """One arc's cutout in one band: ``(CCDData, host model, point-source model, SNRs)``."""
    model = _image_model(grid, settings.psfs[band], scene, settings.supersampling)
    host_img = _host_image(model, scene, band, settings.n)
    if scene.cov is None:
        ps_img = _point_source_image(model, scene, settings, band, cen)
    else:
        clusters = _cluster_images(scene, settings, band, cen)
        ps_img = sum(clusters.values(), np.zeros((settings.n, settings.n)))
    if scene.has_image_plane_light:
        ip_img = _image_plane_image(settings, scene, arc, band, grid, cen)
        clean = np.clip(host_img + ps_img + ip_img, 0.0, None)
    else:
        ip_img = np.zeros((settings.n, settings.n))
        clean = np.clip(host_img + ps_img, 0.0, None)
    data, sigma = _add_noise(clean, settings, band, rng)
    if scene.cov is None:
        snr = _optimal_snr(model, scene, settings, arc, band, cen, sigma)
    else:
        snr = _cluster_snr(clusters, scene, settings, arc, band, cen, sigma)
    image = CCDData(data, unit=_IMAGE_UNIT, uncertainty=StdDevUncertainty(sigma),
                    wcs=wcs.deepcopy(), meta=_cutout_header(settings, arc, band, cen),
                    psf=settings.psfs[band].pixel_kernel.copy())
    return image, host_img, ps_img, ip_img, snr


def render_mock_images(system, *, bands=("F150W", "F200W"), pixel_scale=0.04 * u.arcsec,
                       cutout_size=5.0 * u.arcsec, psf=None, host=True,
                       exposure_time=10.0 * u.ks, sky_background=0.2 * u.MJy / u.sr,
                       read_noise=10.0 * u.electron, zero_point=28.0, noise=True,
                       pairs=None, intrinsic_flux=None, supersampling=5,
                       sky_center=DEFAULT_SKY_CENTER, seed=None, r_eff=None, clumps=None,
                       member=None, icl=None, patch=None):
    r"""Mock images of the fold pair of arcs: one cutout per arc and band.

    Each cutout is centred on one arc of the constellation's fold pair (the
    mean position of the point-source images on it) and holds, rendered
    with lenstronomy (``ImageModel`` on a ``PixelGrid`` with a ``PSF``):

    * the lensed host galaxy: a Sérsic source (lenstronomy
      ``SERSIC_ELLIPSE``, :data:`MOCK_HOST` by default) centred on the
      constellation, ray-traced through ``system`` on a sub-pixel grid
      (``supersampling`` per pixel side) and convolved with the PSF;
    * the point sources of the pairs table at their image positions on both
      arcs with their lensed fluxes ``|mu| x intrinsic`` (columns
      ``flux1_<band>``, ``flux2_<band>``; lenstronomy ``LENSED_POSITION``
      with free amplitudes), or, with ``r_eff``, as finite-size star
      clusters (below);
    * sky, Poisson and read noise (below).

    Parameters
    ----------
    system : `~lensdual.simulation.LensSystem`
        The lens. Any ``lens_model`` works (also ``LensSystem.from_model``).
    bands : sequence of str
        Band names; each needs a PSF (:data:`PSF_FWHM` or ``psf``).
    pixel_scale : `~astropy.units.Quantity`
        Pixel size (default 0.04 arcsec, as NIRCam's drizzled short-wave
        mosaics).
    cutout_size : `~astropy.units.Quantity` or int
        Side of the square cutouts, as an angle or a number of pixels;
        rounded up to an odd number of pixels (>= 15) so that the arc
        centre falls on the central pixel. Default 5 arcsec (125 px).
    psf : None, array, str, `~pathlib.Path` or dict
        None: a Gaussian of the band's FWHM in :data:`PSF_FWHM`
        (integrated over (sub-)pixels; a band not in the table raises
        ValueError). ``"poppy"``: the JWST-like PSF with diffraction spikes
        of :func:`hexagonal_pupil_psf` (a hexagonal segmented pupil with
        struts, at the band's wavelength in :data:`HEX_PSF_WAVELENGTH`,
        sampled at the sub-pixels; needs poppy, the ``psf`` extra). A 2-D
        array or the path of a FITS file (first HDU with data): the PSF at
        the pixel scale, i.e. not supersampled, square, odd-sized, centred
        on its central pixel, non-negative; it is normalised to sum 1. A
        dict gives one of these per band.
    host : bool, None or dict
        True: the default host :data:`MOCK_HOST`; False or None: no host; a
        dict overrides keys of :data:`MOCK_HOST`: ``flux`` (unlensed total
        flux, a Quantity or a dict per band), ``R_sersic`` (half-light
        radius, angle), ``n_sersic``, ``e1``, ``e2`` (lenstronomy's
        ellipticity), ``center`` (source-plane position, angle Quantity of
        shape (2,); default the mean source position of the pairs).
    exposure_time : `~astropy.units.Quantity`
        Exposure time; the depth knob: the noise scales as
        ``1 / sqrt(exposure_time)`` (default 10 ks, see Notes).
    sky_background : `~astropy.units.Quantity` or dict
        Sky surface brightness (e.g. MJy/sr; default 0.2 MJy/sr, the
        zodiacal light at moderate ecliptic latitude), per band if a dict.
    read_noise : `~astropy.units.Quantity` or dict
        Effective read noise per pixel of the whole exposure, in electrons.
    zero_point : float or dict
        AB magnitude of a source that gives 1 electron/s (default 28.0,
        i.e. 1 e-/s = 22.9 nJy), per band if a dict.
    noise : bool
        False gives the noiseless images (the uncertainty is still the
        noise model's).
    pairs : `~astropy.table.QTable`, optional
        The truth: a pairs table with ``x1``, ``y1``, ``x2``, ``y2`` (lens
        frame) and ``flux1_<band>``, ``flux2_<band>`` for every band.
        Default: ``system.constellation(bands=bands,
        intrinsic_flux=intrinsic_flux, flux_unit=u.nJy, seed=rng)``.
    intrinsic_flux : dict, optional
        Unlensed point-source fluxes in nJy, ``{band: array of shape (M,)}``
        for the M sources of ``system.sources``, passed to
        ``system.constellation`` when ``pairs`` is None. Default: drawn
        log-uniformly between 3 and 10 nJy, times a colour of +-0.1 dex per
        source and band.
    supersampling : int
        Sub-pixels per pixel side for the host and the Gaussian PSF (odd,
        >= 1; default 5).
    sky_center : `~astropy.coordinates.SkyCoord`
        Sky position of the lens centre, the origin of the lens frame
        (default :data:`DEFAULT_SKY_CENTER`, SMACS0723).
    seed : int, `numpy.random.Generator` or None
        Seed of the constellation's fluxes (when drawn) and of the noise.
    r_eff : `~astropy.units.Quantity`, optional
        None (default): the point sources are points. Otherwise they are
        star clusters of these intrinsic half-light radii, a scalar or one
        per row of the pairs table (e.g. from :func:`draw_cluster_radii`),
        as lengths (e.g. pc; converted to angles with the angular-diameter
        distance of ``system.z_source`` in ``system.cosmology``) or angles;
        0 is a point (see Notes). The truth table then has the columns
        ``r_eff`` (as given), ``r_eff_angle`` (mas) and ``stretch1``,
        ``stretch2`` (the largest singular value of the inverse lens
        Jacobian at each image: how much the cluster is stretched along
        its arc).
    clumps : bool, None or dict
        True: faint clumps of the host galaxy (:data:`MOCK_CLUMPS`), round
        Gaussians in the source plane ray-traced with the host, each below
        the detection threshold; a dict overrides keys of
        :data:`MOCK_CLUMPS` (``n``, ``flux`` and ``sigma`` ranges,
        ``spread``). Their draw has a generator of its own (spawned from
        ``seed``), so the noise is the same with and without them.
    member : bool, None or dict
        True: the light of a cluster member near one arc
        (:data:`MOCK_MEMBER`: a Sérsic in the image plane, not lensed,
        PSF-convolved); a dict overrides keys (``flux``, a Quantity or a
        dict per band, ``R_sersic``, ``n_sersic``, ``e1``, ``e2``, ``arc``,
        ``offset`` from the arc's centre).
    icl : bool, None or dict
        True: an intracluster-light gradient on one arc's cutouts
        (:data:`MOCK_ICL`: exponential in the image plane); a dict
        overrides keys (``surface_brightness`` at the arc's centre,
        ``scale_length``, ``arc``, ``direction``).
    patch : bool, None or dict
        True: an extended Gaussian in the image plane under one image of
        one pair (:data:`MOCK_PATCH`: row 0's L2 image, its flux that of
        ``contrast`` 1); a dict overrides keys (``flux``, a Quantity or a
        dict per band, or ``contrast``, the patch's flux that a PSF fit of
        the image without background would take up, in units of the
        image's flux; ``sigma``; ``pair``, a row of the pairs table;
        ``arc``). The truth table gains the boolean columns ``patch1`` and
        ``patch2`` (True for the image under the patch) and
        ``meta['patch_flux']``, the patch's flux per band (nJy).

    Returns
    -------
    images : `MockImages`
        A mapping ``{(arc, band): CCDData}`` for arcs ``"L1"`` and ``"L2"``
        with the truth table in ``images.pairs`` (with the SNR columns) and
        the noiseless components in ``images.host_model`` (with the
        clumps), ``images.point_source_model`` and
        ``images.image_plane_model`` (member, ICL, patch). Each `~astropy.nddata.CCDData` has
        ``unit`` nJy (flux per pixel: sums over pixels are fluxes), a
        `~astropy.nddata.StdDevUncertainty`, a TAN ``wcs``, the pixel-scale
        PSF in ``psf`` and ``meta`` (a FITS header) with ``BAND``, ``ARC``,
        ``PIXSCALE`` and ``PSFFWHM`` (arcsec), ``PSFTYPE``, ``EXPTIME`` (s),
        ``SKYBKG`` (MJy/sr), ``RDNOISE`` (e-), ``ZEROPT``, ``NOISE``,
        ``CENX``, ``CENY`` (lens-frame position of the central pixel,
        arcsec) and ``LENSRA``, ``LENSDEC`` (sky position of the lens
        centre, deg).

    Raises
    ------
    TypeError
        Wrong type of ``system``, ``pairs``, ``psf``, ``host`` or of a
        Quantity argument (also ``r_eff`` neither a length nor an angle).
    ValueError
        A band without PSF, a bad PSF (not 2-D, not square and odd-sized,
        negative or non-finite), bad ``pairs`` columns or out-of-range
        values (also a negative ``r_eff``, or one of the wrong length; an
        unknown key of ``clumps``, ``member``, ``icl`` or ``patch``, or a
        ``patch`` pair outside the table).
    ImportError
        ``psf="poppy"`` without poppy installed.

    Notes
    -----
    **Frames.** The lens frame is lenstronomy's (arcsec, origin at the lens
    centre) with ``x`` pointing **west** and ``y`` north, taken as the
    gnomonic (TAN) plane about ``sky_center``. Pixel ``(i, j)`` (0-based,
    ``i`` the column, ``data[j, i]``) of a cutout lies at
    ``x = CENX + (i - (n - 1) / 2) * pixel_scale`` and
    ``y = CENY + (j - (n - 1) / 2) * pixel_scale``; the WCS has
    ``CRVAL = sky_center``, ``CDELT1 = -pixel_scale`` (RA decreases with
    ``i``: north up, east left), ``CDELT2 = +pixel_scale`` and ``CRPIX`` at
    the lens centre. The cutout centres are snapped to a common grid whose
    pixel centres sit at integer multiples of ``pixel_scale`` from the lens
    centre, so the cutouts are pieces of one mosaic.

    **Noise.** With ``f_e = 3631 Jy * 10**(-0.4 zero_point)`` the flux of
    1 e-/s, a pixel of model flux ``m`` (nJy) and sky ``s`` (nJy per
    pixel) collects ``N = (m + s) / f_e * t`` electrons; the image is
    ``(Poisson(N) + Normal(0, read_noise)) * f_e / t - s`` (the sky is
    subtracted exactly) and the uncertainty is
    ``sqrt(N + read_noise**2) * f_e / t`` (from the noiseless model). With
    the defaults the sky-limited pixel noise is 0.13 nJy, and the point
    sources of :func:`~lensdual.simulation.smacs0723_analog` (3-50 nJy
    after magnification) have PSF-weighted SNRs of about 20-120 (median
    about 50); see the ``snr`` columns of ``images.pairs``.

    **Finite-size clusters.** With ``r_eff`` each cluster is a circular
    Gaussian in the source plane of standard deviation
    ``s = r_eff / sqrt(2 ln 2)``; its image is the Gaussian of covariance
    ``s**2 A^-1 A^-T`` through the lens Jacobian ``A = d beta / d theta``
    at the image position (the local, first-order lens map, exact in the
    small-source limit; the lenses' Hessian), with the point's flux,
    convolved with the PSF on the PSF's (super)sampled grid in Fourier
    space and summed onto the pixels. Its second moments are the PSF's
    plus ``s**2 A^-1 A^-T``. At z = 2.2 in the default cosmology 1 pc is
    0.12 mas: the clusters are far below the sub-pixels, which is why
    they are not ray-traced (see ``lensdual/simulation/_clusters.py``).
    Where the Jacobian changes across an image (a sub-halo a few mas
    away, a critical curve) the first-order map is an approximation.

    Only the point-source images on the fold pair of arcs are painted
    (other images of the constellation, e.g. near the tangential critical
    curve, are far outside the cutouts); the only lens light is that of
    ``member`` and ``icl``. See ``lensdual/simulation/_scene.py`` for the
    clumps, the member, the ICL and the patch.
    """
    if not isinstance(system, LensSystem):
        raise TypeError(f"system must be a LensSystem, got {type(system).__name__}")
    settings = _check_render_settings(
        bands=bands, pixel_scale=pixel_scale, cutout_size=cutout_size, psf=psf,
        exposure_time=exposure_time, sky_background=sky_background, read_noise=read_noise,
        zero_point=zero_point, noise=noise, supersampling=supersampling, sky_center=sky_center)
    rng = np.random.default_rng(seed)
    host_p = _host_params(host, settings.bands)
    extras = {"clumps": _scene.clump_params(clumps),
              "member": _scene.member_params(member, settings.bands),
              "icl": _scene.icl_params(icl, settings.bands)}
    truth = _truth_table(system, settings.bands, pairs, intrinsic_flux, rng)
    extras["patch"] = _scene.patch_params(patch, settings.bands, len(truth))
    # a rendered truth table passed in again: its patch is not this render's
    truth.meta.pop("patch_flux", None)
    truth.remove_columns([c for c in ("patch1", "patch2") if c in truth.colnames])
    if extras["patch"] is not None:
        p = extras["patch"]
        image_flux = {b: truth[flux_col(p["arc"], b)][p["pair"]].to_value(_IMAGE_UNIT)
                      for b in settings.bands}
        extras["patch"] = _scene.resolve_patch_flux(
            p, image_flux, {b: settings.psfs[b].pixel_kernel for b in settings.bands},
            settings.scale)
        truth.meta["patch_flux"] = {b: float(f) for b, f in extras["patch"]["flux"].items()}
    if extras["clumps"] is not None:
        # spawning leaves rng's stream (the noise) as it is
        extras["clump_rng"] = rng.spawn(1)[0]
    scene = _make_scene(system, truth, settings.bands, host_p, r_eff, extras)
    if scene.patch is not None:
        for k, arc in enumerate(_ARCS, start=1):
            truth[f"patch{k}"] = (np.arange(len(truth)) == scene.patch["pair"]) \
                & (scene.patch["arc"] == arc)

    images, host_models, ps_models, ip_models, snr = {}, {}, {}, {}, {}
    for arc in _ARCS:
        grid, cen, wcs = _arc_grid(settings, scene.pos[arc])
        for b in settings.bands:
            key = (arc, b)
            images[key], host_img, ps_img, ip_img, snr[key] = _render_cutout(
                settings, scene, arc, b, grid, cen, wcs, rng)
            host_models[key] = host_img * _IMAGE_UNIT
            ps_models[key] = ps_img * _IMAGE_UNIT
            ip_models[key] = ip_img * _IMAGE_UNIT

    for b in settings.bands:
        truth[f"snr1_{b}"] = snr[("L1", b)]
        truth[f"snr2_{b}"] = snr[("L2", b)]
    return MockImages(images, pairs=truth, host_model=host_models,
                      point_source_model=ps_models, image_plane_model=ip_models)


# ---------------------------------------------------------------------------
# FITS I/O
# ---------------------------------------------------------------------------


def write_mock_images(images, directory, *, overwrite=False):
    """Write mock images as FITS files, one per arc and band.

    Parameters
    ----------
    images : `MockImages` or dict of (arc, band) to `~astropy.nddata.CCDData`
        The cutouts. Each is written to ``<arc>_<band>.fits`` (primary HDU:
        data, header with the WCS, ``BUNIT`` and the meta; ``UNCERT``: the
        standard deviation; ``PSFIMAGE``: the PSF, when the image has one).
        The truth table of a `MockImages` goes to ``truth_pairs.ecsv``.
    directory : str or `~pathlib.Path`
        Created if it does not exist.
    overwrite : bool
        Replace existing files (otherwise an existing file raises OSError).

    Returns
    -------
    paths : list of `~pathlib.Path`
        The files written.
    """
    if not isinstance(images, Mapping):
        raise TypeError(f"images must be a MockImages or a dict {{(arc, band): CCDData}}, "
                        f"got {type(images).__name__}")
    if not isinstance(images, MockImages):
        images = MockImages(images)
    if not isinstance(directory, (str, Path)):
        raise TypeError(f"directory must be a str or Path, got {type(directory).__name__}")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for (arc, band), image in images.items():
        for label, value in (("arc", arc), ("band", band)):
            if not value or any(c in value for c in "_/\\") or value != value.strip():
                raise ValueError(f"{label} names must be non-empty and hold no '_', '/' or "
                                 f"spaces at the ends, got {value!r}")
        path = directory / f"{arc}_{band}.fits"
        image.write(path, overwrite=overwrite, hdu_mask=None)
        paths.append(path)
    if images.pairs is not None:
        path = directory / _TRUTH_FILE
        images.pairs.write(path, format="ascii.ecsv", overwrite=overwrite)
        paths.append(path)
    return paths


def read_mock_images(directory):
    """Read the FITS files of :func:`write_mock_images` back.

    Parameters
    ----------
    directory : str or `~pathlib.Path`
        A directory with ``<arc>_<band>.fits`` files (and optionally
        ``truth_pairs.ecsv``).

    Returns
    -------
    images : `MockImages`
        ``{(arc, band): CCDData}`` with data, unit, uncertainty, WCS, PSF
        and meta as written; ``pairs`` is the truth table if the file has
        one; the noiseless models are not stored (empty dicts).
    """
    if not isinstance(directory, (str, Path)):
        raise TypeError(f"directory must be a str or Path, got {type(directory).__name__}")
    directory = Path(directory)
    if not directory.is_dir():
        raise ValueError(f"directory {str(directory)!r} does not exist")
    images = {}
    for path in sorted(directory.glob("*_*.fits")):
        arc, band = path.stem.split("_", 1)
        image = CCDData.read(path, hdu_mask=None)
        images[(str(image.meta.get("ARC", arc)), str(image.meta.get("BAND", band)))] = image
    if not images:
        raise ValueError(f"no <arc>_<band>.fits files in {str(directory)!r}")
    order = {a: k for k, a in enumerate(_ARCS)}
    images = dict(sorted(images.items(), key=lambda kv: (order.get(kv[0][0], 99), kv[0])))
    pairs = None
    truth = directory / _TRUTH_FILE
    if truth.is_file():
        pairs = QTable.read(truth, format="ascii.ecsv")
    return MockImages(images, pairs=pairs)
