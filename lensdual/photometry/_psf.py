"""PSF photometry of point sources on bright lens arcs, and the pairs table.

:func:`psf_photometry` fits a PSF to each point source of one image,
starting from given positions, with a local background model that copes
with the bright, curved arc underneath; :func:`measure_pairs` runs it on
every band of two arcs and fills a :ref:`pairs table <pairs-table>` with
positions in one common tangent-plane frame and per-band fluxes.
"""

import enum
import warnings
from collections.abc import Mapping

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.modeling import Fittable2DModel, Parameter
from astropy.nddata import (
    InverseVariance,
    NDData,
    StdDevUncertainty,
    VarianceUncertainty,
)
from astropy.table import QTable, Table
from astropy.wcs.wcsapi import BaseHighLevelWCS, BaseLowLevelWCS, HighLevelWCSWrapper
from scipy.ndimage import gaussian_filter
from scipy.special import erf

from .._frames import mean_direction, tangent_to_sky, tangent_xy
from .._validation import as_int, as_positions, as_real, split_image
from ..exceptions import LensdualWarning

__all__ = [
    "BACKGROUND_STRATEGIES",
    "PhotometryFlag",
    "UNUSABLE_FLAGS",
    "describe_flags",
    "psf_photometry",
    "measure_pairs",
]

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

# Gaussian blurs of the high-pass filter: those of lensdual.detection.
_BLUR_MODE = "reflect"
_BLUR_TRUNCATE = 4.0

_FWHM_TO_SIGMA = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))

_BKG_TERMS = {
    None: (),
    0: ("bkg",),
    1: ("bkg", "bkg_dx", "bkg_dy"),
    2: ("bkg", "bkg_dx", "bkg_dy", "bkg_dxx", "bkg_dxy", "bkg_dyy"),
}

# x/y column names understood in a positions table, in order of preference
_X_NAMES = ("x_fit", "x_centroid", "xcentroid", "x_init", "x_0", "x")
_Y_NAMES = ("y_fit", "y_centroid", "ycentroid", "y_init", "y_0", "y")


class PhotometryFlag(enum.IntFlag):
    """The bits of the ``flags`` columns of :func:`psf_photometry` and :func:`measure_pairs`.

    Bits 1 to 2048 are photutils' `~photutils.psf.PSFPhotometry` flags, with
    the same meaning (see `~photutils.psf.decode_psf_flags`); lensdual's own
    bits start at 2**16 and never reuse a photutils bit. A flag in
    :data:`UNUSABLE_FLAGS` makes the measurement unusable: :func:`measure_pairs`
    sets its fluxes (and its share of the position) to NaN.
    """

    N_PIXELS_FIT_PARTIAL = 1
    OUTSIDE_BOUNDS = 2
    NON_POSITIVE_FLUX = 4
    NO_CONVERGENCE = 8
    NO_COVARIANCE = 16
    NEAR_BOUND = 32
    NO_OVERLAP = 64
    FULLY_MASKED = 128
    TOO_FEW_PIXELS = 256
    NON_FINITE_POSITION = 512
    NON_FINITE_FLUX = 1024
    NON_FINITE_LOCALBKG = 2048
    OUTSIDE_IMAGE = 1 << 16
    BAD_ERROR = 1 << 17
    FIT_FAILED = 1 << 18


_FLAG_WORDS = {
    PhotometryFlag.N_PIXELS_FIT_PARTIAL: "fitting box partly off the image or masked",
    PhotometryFlag.OUTSIDE_BOUNDS: "fitted position outside the image",
    PhotometryFlag.NON_POSITIVE_FLUX: "non-positive flux",
    PhotometryFlag.NO_CONVERGENCE: "fit may not have converged",
    PhotometryFlag.NO_COVARIANCE: "no covariance (no errors) from the fit",
    PhotometryFlag.NEAR_BOUND: "fitted position at its bound (xy_bounds)",
    PhotometryFlag.NO_OVERLAP: "fitting box does not overlap the data",
    PhotometryFlag.FULLY_MASKED: "fitting box fully masked",
    PhotometryFlag.TOO_FEW_PIXELS: "too few valid pixels to fit",
    PhotometryFlag.NON_FINITE_POSITION: "non-finite fitted position",
    PhotometryFlag.NON_FINITE_FLUX: "non-finite fitted flux",
    PhotometryFlag.NON_FINITE_LOCALBKG: "non-finite local background",
    PhotometryFlag.OUTSIDE_IMAGE: "initial position outside the image or not finite (not fitted)",
    PhotometryFlag.BAD_ERROR: "flux error not finite and positive",
    PhotometryFlag.FIT_FAILED: "the fitter raised an error",
}

#: The flags that make a measurement unusable (its flux and position are not used).
UNUSABLE_FLAGS = (
    PhotometryFlag.NON_POSITIVE_FLUX
    | PhotometryFlag.NO_CONVERGENCE
    | PhotometryFlag.NO_COVARIANCE
    | PhotometryFlag.NO_OVERLAP
    | PhotometryFlag.FULLY_MASKED
    | PhotometryFlag.TOO_FEW_PIXELS
    | PhotometryFlag.NON_FINITE_POSITION
    | PhotometryFlag.NON_FINITE_FLUX
    | PhotometryFlag.OUTSIDE_IMAGE
    | PhotometryFlag.BAD_ERROR
    | PhotometryFlag.FIT_FAILED
)
_BAD_FLAGS = int(UNUSABLE_FLAGS)


def describe_flags(flags, *, unusable_only=False):
    """The flags of one measurement in words.

    Parameters
    ----------
    flags : int or `PhotometryFlag`
        A value of a ``flags`` column.
    unusable_only : bool, optional
        Name only the flags of :data:`UNUSABLE_FLAGS`.

    Returns
    -------
    str
        The reasons, separated by ", " ("" for 0); an unknown bit is named
        by its value.

    Examples
    --------
    >>> from lensdual.photometry import describe_flags
    >>> describe_flags(4 | 16)
    'non-positive flux, no covariance (no errors) from the fit'
    """
    value = int(flags)
    if unusable_only:
        value &= _BAD_FLAGS
    words = []
    for bit in range(value.bit_length()):
        b = 1 << bit
        if value & b:
            try:
                words.append(_FLAG_WORDS[PhotometryFlag(b)])
            except (KeyError, ValueError):
                words.append(f"flag bit {b}")
    return ", ".join(words)


# ---------------------------------------------------------------------------
# PSF profiles (unit total flux, pixel-integrated where analytic)
# ---------------------------------------------------------------------------


def _erf_diff(t, k):
    return 0.5 * (erf((t + 0.5) * k) - erf((t - 0.5) * k))


def _erf_diff_deriv(t, k):
    return (k / np.sqrt(np.pi)) * (
        np.exp(-(((t + 0.5) * k) ** 2)) - np.exp(-(((t - 0.5) * k) ** 2))
    )


def _gauss_prf(dx, dy, sigma):
    """Pixel-integrated circular Gaussian of unit flux, sigma in pixels."""
    k = 1.0 / (np.sqrt(2.0) * sigma)
    return _erf_diff(dx, k) * _erf_diff(dy, k)


def _gauss_prf_grad(dx, dy, sigma):
    """Derivatives of :func:`_gauss_prf` with respect to dx and dy."""
    k = 1.0 / (np.sqrt(2.0) * sigma)
    ex, ey = _erf_diff(dx, k), _erf_diff(dy, k)
    return _erf_diff_deriv(dx, k) * ey, ex * _erf_diff_deriv(dy, k)


class _GaussianProfile:
    """Gaussian PRF, optionally high-pass filtered: PRF_s - PRF_sqrt(s^2 + h^2).

    A Gaussian of sigma s blurred by a Gaussian of sigma h is a Gaussian of
    sigma sqrt(s^2 + h^2) with the same flux, so the high-pass filtered PSF is
    exact in closed form (the pixel integration commutes with the blur).
    """

    def __init__(self, fwhm, highpass):
        self.fwhm = float(fwhm)
        self.highpass = highpass

    def _sigmas(self, fwhm):
        s = (self.fwhm if fwhm is None else fwhm) * _FWHM_TO_SIGMA
        return s, (np.sqrt(s**2 + self.highpass**2) if self.highpass else None)

    def __call__(self, dx, dy, fwhm=None):
        s, sb = self._sigmas(fwhm)
        out = _gauss_prf(dx, dy, s)
        if sb is not None:
            out = out - _gauss_prf(dx, dy, sb)
        return out

    def grad(self, dx, dy, fwhm=None):
        s, sb = self._sigmas(fwhm)
        gx, gy = _gauss_prf_grad(dx, dy, s)
        if sb is not None:
            bx, by = _gauss_prf_grad(dx, dy, sb)
            gx, gy = gx - bx, gy - by
        return gx, gy

    def radius(self):
        s, sb = self._sigmas(None)
        return int(np.ceil(4.0 * (s if sb is None else sb))) + 1

    def describe(self):
        return f"Gaussian FWHM {self.fwhm:.4g} px"


class _ImageProfile:
    """A photutils ImagePSF evaluated at unit flux (high-pass filtered if asked)."""

    def __init__(self, psf, highpass):
        from photutils.psf import ImagePSF

        self.highpass = highpass
        self.fwhm = _image_fwhm(psf)
        if highpass:
            osy, osx = (float(v) for v in psf.oversampling)
            pad_y = int(np.ceil(_BLUR_TRUNCATE * highpass * osy)) + 2
            pad_x = int(np.ceil(_BLUR_TRUNCATE * highpass * osx)) + 2
            data = np.pad(np.asarray(psf.data, dtype=np.float64), ((pad_y, pad_y), (pad_x, pad_x)))
            blurred = gaussian_filter(
                data, (highpass * osy, highpass * osx), mode="constant", truncate=_BLUR_TRUNCATE
            )
            origin = np.asarray(psf.origin, dtype=np.float64) + [pad_x, pad_y]
            psf = ImagePSF(
                data - blurred, origin=origin, oversampling=psf.oversampling, fill_value=0.0
            )
        self.psf = psf
        half = np.array(psf.data.shape[::-1], dtype=np.float64) / np.asarray(psf.oversampling)[::-1]
        self._radius = int(np.ceil(half.max() / 2.0)) + 1

    def __call__(self, dx, dy, fwhm=None):
        return self.psf.evaluate(dx, dy, 1.0, 0.0, 0.0)

    def grad(self, dx, dy, fwhm=None):
        h = 1e-3
        gx = (
            self.psf.evaluate(dx + h, dy, 1.0, 0.0, 0.0)
            - self.psf.evaluate(dx - h, dy, 1.0, 0.0, 0.0)
        ) / (2 * h)
        gy = (
            self.psf.evaluate(dx, dy + h, 1.0, 0.0, 0.0)
            - self.psf.evaluate(dx, dy - h, 1.0, 0.0, 0.0)
        ) / (2 * h)
        return gx, gy

    def radius(self):
        return self._radius

    def describe(self):
        return (
            f"image PSF {self.psf.data.shape} oversampling "
            f"{np.asarray(self.psf.oversampling).tolist()}"
        )


def _image_fwhm(psf):
    """Effective FWHM (pixels) of an image PSF: diameter of its area above half maximum."""
    data = np.asarray(psf.data, dtype=np.float64)
    area = np.count_nonzero(data >= 0.5 * data.max()) / float(np.prod(psf.oversampling))
    return max(1.0, 2.0 * np.sqrt(area / np.pi))


# ---------------------------------------------------------------------------
# background bases (about the centre of the fitting box) and fitted models
# ---------------------------------------------------------------------------


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


class _PSFBackgroundModel(Fittable2DModel):
    """Base of the fitted models (PSF + linear background); see :func:`_model_class`."""

    _with_shape = False

    def __init__(self, profile=None, basis=None, **kwargs):
        super().__init__(**kwargs)
        self._profile = profile
        self._basis = basis

    def _split(self, params):
        if self._with_shape:
            return params[0], params[1:]
        return None, params

    def evaluate(self, x, y, flux, x_0, y_0, *params):
        shape, coeffs = self._split(params)
        out = flux * self._profile(x - x_0, y - y_0, shape)
        if coeffs:
            for c, col in zip(coeffs, self._basis.columns(x, y), strict=True):
                out = out + c * col
        return out

    def fit_deriv(self, x, y, flux, x_0, y_0, *params):
        shape, _ = self._split(params)
        dx, dy = x - x_0, y - y_0
        p = self._profile(dx, dy, shape)
        gx, gy = self._profile.grad(dx, dy, shape)
        out = [p, -flux * gx, -flux * gy]
        if self._with_shape:
            h = 1e-4 * shape
            out.append(
                flux
                * (self._profile(dx, dy, shape + h) - self._profile(dx, dy, shape - h))
                / (2 * h)
            )
        return out + self._basis.columns(x, y)

    def copy(self):
        """Copy the parameters only; the profile and basis are shared."""
        import copy

        new = object.__new__(self.__class__)
        for key, val in self.__dict__.items():
            new.__dict__[key] = copy.copy(val) if key in self.param_names else val
        return new


_MODEL_CLASSES = {}


def _model_class(names, with_shape):
    key = (tuple(names), with_shape)
    if key not in _MODEL_CLASSES:
        attrs = {
            "flux": Parameter(default=1.0),
            "x_0": Parameter(default=0.0),
            "y_0": Parameter(default=0.0),
        }
        if with_shape:
            attrs["fwhm"] = Parameter(default=2.0, bounds=(0.3, 50.0))
        for name in names:
            attrs[name] = Parameter(default=0.0)
        attrs["_with_shape"] = with_shape
        attrs["__module__"] = __name__
        attrs["__doc__"] = "PSF plus a linear background (lensdual internal)."
        cname = f"_PSF{len(names)}{'Shape' if with_shape else ''}"
        _MODEL_CLASSES[key] = type(cname, (_PSFBackgroundModel,), attrs)
    return _MODEL_CLASSES[key]


# ---------------------------------------------------------------------------
# input handling
# ---------------------------------------------------------------------------


def _as_wcs(wcs, name):
    if wcs is None or isinstance(wcs, BaseHighLevelWCS):
        return wcs
    if isinstance(wcs, BaseLowLevelWCS):
        return HighLevelWCSWrapper(wcs)
    raise TypeError(f"{name} must be an astropy WCS or None, got {type(wcs).__name__}")


# meta keys that may hold the file an image was read from (FITS headers are
# case-insensitive; dict metas are not)
_FILE_KEYS = ("FILENAME", "filename", "file", "FILE", "path")


def _file_of(image):
    """The file an NDData was read from, from its ``meta`` (None when unknown)."""
    meta = getattr(image, "meta", None)
    if not meta:
        return None
    for key in _FILE_KEYS:
        try:
            value = meta.get(key)
        except Exception:  # noqa: BLE001 - an odd meta: no file name
            return None
        if isinstance(value, str) and value.strip():
            return value.strip()
    return None


def _describe_input(name, image, label=None):
    """``label`` or ``name``, with the file the image was read from when known."""
    text = name if label is None else str(label)
    path = _file_of(image)
    if path is not None and path not in text:
        text += f" (file {path})"
    return text


def _plane_wcs(wcs):
    """The 2-D celestial WCS of a cube with one plane (numpy axis 0 dropped)."""
    from astropy.wcs import WCS
    from astropy.wcs.wcsapi import SlicedLowLevelWCS

    if wcs is None:
        return None
    if isinstance(wcs, WCS):
        if wcs.naxis == 2:
            return wcs
        if wcs.has_celestial and wcs.celestial.naxis == 2:
            return wcs.celestial
    low = getattr(wcs, "low_level_wcs", wcs)
    if isinstance(low, BaseLowLevelWCS) and low.pixel_n_dim == 3:
        return SlicedLowLevelWCS(low, (0, slice(None), slice(None)))
    return wcs


def _squeeze_plane(image, name):
    """A 2-D image from a cube with a single plane (shape (1, ny, nx)), with a warning.

    Other inputs are returned as they are (2-D, or wrong in a way that
    ``split_image`` reports); a cube with several planes is a ValueError.
    """
    data = image.data if isinstance(image, NDData) else image
    shape = np.shape(data) if hasattr(data, "shape") else None
    if shape is None or len(shape) != 3:
        return image
    where = _describe_input(name, image)
    if shape[0] != 1:
        raise ValueError(
            f"{where} must be a 2-D image, got shape {shape}: a cube of {shape[0]} planes "
            "along NAXIS3. Pass the plane to measure (e.g. data[k]) or the right FITS "
            "extension"
        )
    warnings.warn(
        f"{where} has shape {shape} (a cube with NAXIS3 = 1): its only plane, of shape "
        f"{shape[1:]}, is used",
        LensdualWarning,
        stacklevel=4,
    )
    if not isinstance(image, NDData):
        return image[0]
    mask = image.mask
    if mask is not None and np.ndim(mask) == 3:
        mask = np.asarray(mask)[0]
    unc = image.uncertainty
    if unc is not None and np.ndim(unc.array) == 3:
        unc = type(unc)(np.asarray(unc.array)[0], unit=unc.unit)
    return NDData(
        np.asarray(data)[0],
        mask=mask,
        uncertainty=unc,
        unit=image.unit,
        wcs=_plane_wcs(image.wcs),
        meta=image.meta,
    )


def _split_parts(image, name, label=None):
    """The parts of an image, nothing copied: (where, data, mask, unit, wcs, uncertainty)."""
    where = _describe_input(name, image, label)
    image = _squeeze_plane(image, where)
    data, mask, unit, wcs, unc = split_image(image, name)
    wcs = _as_wcs(wcs, f"{name}.wcs")
    return where, data, mask, unit, wcs, unc


def _in_box(array, shape, box):
    """``array`` (broadcast to ``shape``) restricted to ``box`` (a pair of slices, or None)."""
    if box is None:
        return array
    array = np.asarray(array)
    if array.shape != shape:
        array = np.broadcast_to(array, shape)
    return array[box]


def _unpack_image(image, name, label=None, box=None, parts=None):
    """Return (float64 data copy, invalid mask or None, error or None, unit, wcs).

    With ``box`` (a pair of slices) only that part of the image is copied and
    checked: data, mask and error map are cut before any conversion, so that
    nothing of the size of the whole image is allocated. ``parts`` are those
    of :func:`_split_parts` when already at hand.
    """
    where, data, mask, unit, wcs, unc = _split_parts(image, name, label) if parts is None else parts
    full_shape = data.shape
    data = _in_box(data, full_shape, box)
    if mask is not None:
        mask = _in_box(mask, full_shape, box)
    error = None
    if unc is not None:
        arr = np.asarray(_in_box(unc.array, full_shape, box), dtype=np.float64)
        if isinstance(unc, StdDevUncertainty):
            error = arr
        elif isinstance(unc, VarianceUncertainty):
            error = np.sqrt(arr)
        elif isinstance(unc, InverseVariance):
            with np.errstate(divide="ignore"):
                error = 1.0 / np.sqrt(arr)
        else:
            raise TypeError(
                f"{name}.uncertainty must be a StdDevUncertainty, VarianceUncertainty "
                f"or InverseVariance, got {type(unc).__name__}"
            )
        eunit = unc.unit
        if isinstance(unc, VarianceUncertainty) and eunit is not None:
            eunit = eunit**0.5
        elif isinstance(unc, InverseVariance) and eunit is not None:
            eunit = eunit**-0.5
        if eunit is not None and unit is not None and eunit != unit:
            try:
                error = error * float(eunit.to(unit))
            except u.UnitsError:
                raise ValueError(
                    f"{name}.uncertainty has unit {eunit!s}, not convertible to the "
                    f"image unit {unit!s}"
                ) from None
    data = np.array(data, dtype=np.float64)  # a copy: the input is never modified
    invalid = ~np.isfinite(data)
    if invalid.all():
        raise ValueError(
            f"{where} has no valid pixel: all {data.size} pixels of the image (shape "
            f"{data.shape}) are NaN or infinite. Check that the right file and extension "
            "(e.g. SCI) are read and that the cut-out overlaps the exposed data"
        )
    if error is not None:
        error = np.array(np.broadcast_to(error, data.shape), dtype=np.float64)
        good_error = np.isfinite(error) & (error > 0)
        if not good_error.any():
            finite = error[np.isfinite(error)]
            if finite.size == error.size and np.all(finite == 0):
                what = "zero"
            elif finite.size == 0:
                what = "NaN or infinite"
            else:
                what = "zero, negative or NaN"
            raise ValueError(
                f"{where} has no valid pixel: its error map (uncertainty) is {what} at every "
                "pixel. Check the error file and extension (e.g. ERR, in the image's unit), "
                "give a weight map instead, or no error map at all"
            )
        invalid |= ~good_error
    if mask is not None:
        if mask.shape != data.shape:
            mask = np.broadcast_to(mask, data.shape)
        mask = mask.astype(bool)
        if mask.all():
            raise ValueError(
                f"{where} has no valid pixel: its mask is True (bad) at every pixel"
                + (
                    " (an error map that is zero everywhere masks every pixel)"
                    if error is None
                    else ""
                )
            )
        invalid |= mask
    if invalid.all():
        raise ValueError(
            f"{where} has no valid pixel (all NaN, masked or with error <= 0, each in a "
            "different place)"
        )
    if not invalid.any():
        invalid = None
    else:
        data[invalid] = 0.0
        if error is not None:
            error[invalid] = 1.0
    return data, invalid, error, unit, wcs


def _pixel_scale(wcs, shape, name):
    """Pixel scale (arcsec / pixel, square root of the pixel area) at the image centre."""
    yc, xc = (shape[0] - 1) / 2.0, (shape[1] - 1) / 2.0
    try:
        sky = wcs.pixel_to_world([xc, xc + 1, xc], [yc, yc, yc + 1])
    except Exception:  # noqa: BLE001 - any WCS failure means: no usable celestial WCS
        sky = None
    if not isinstance(sky, SkyCoord):
        raise ValueError(f"{name} needs a celestial WCS to convert angles to pixels")
    xs, ys = tangent_xy(sky, sky[0])
    area = abs((xs[1] - xs[0]) * (ys[2] - ys[0]) - (xs[2] - xs[0]) * (ys[1] - ys[0]))
    return float(np.sqrt(area))


def _pixel_to_tangent_errors(wcs, x, y, x_err, y_err, reference):
    """Tangent-plane positions (arcsec) of pixel positions and their per-axis error.

    The pixel errors are carried by the local Jacobian of pixel -> tangent plane;
    the error returned is the rms of the two tangent-plane axes.
    """
    h = 0.5
    xs = np.concatenate([x, x + h, x - h, x, x])
    ys = np.concatenate([y, y, y, y + h, y - h])
    tx, ty = tangent_xy(wcs.pixel_to_world(xs, ys), reference)
    n = x.size
    tx, ty = tx.reshape(5, n), ty.reshape(5, n)
    jxx, jyx = (tx[1] - tx[2]) / (2 * h), (ty[1] - ty[2]) / (2 * h)
    jxy, jyy = (tx[3] - tx[4]) / (2 * h), (ty[3] - ty[4]) / (2 * h)
    var_x = (jxx * x_err) ** 2 + (jxy * y_err) ** 2
    var_y = (jyx * x_err) ** 2 + (jyy * y_err) ** 2
    return tx[0], ty[0], np.sqrt(0.5 * (var_x + var_y))


def _as_oversampling(oversampling, name="oversampling"):
    """None, or the oversampling factors (oy, ox) as ints >= 1."""
    if oversampling is None:
        return None
    values = np.atleast_1d(np.asarray(oversampling, dtype=object))
    ok = values.size in (1, 2) and values.ndim == 1
    if ok:
        try:
            ints = [as_int(v, name, minimum=1) for v in values]
        except (TypeError, ValueError):
            ok = False
    if not ok:
        raise ValueError(
            f"{name} must be an integer >= 1 or a pair (oy, ox) of them (the PSF image's "
            f"pixels per detector pixel, e.g. 4 for a WebbPSF/STPSF OVERSAMP image), got "
            f"{oversampling!r}"
        )
    return (ints[0], ints[-1])


def _psf_spec(psf, wcs, shape, name="psf", oversampling=None):
    """Return ('gaussian', fwhm_px or None) or ('image', ImagePSF)."""
    from photutils.psf import ImagePSF

    if oversampling is not None and oversampling != (1, 1):
        if (
            psf is None
            or not isinstance(psf, (np.ndarray, list, tuple, ImagePSF))
            or (not isinstance(psf, ImagePSF) and np.ndim(psf) != 2)
        ):
            raise ValueError(
                f"oversampling={list(oversampling)} applies to a PSF image; {name} is "
                f"{psf!r:.60}, not a 2-D PSF array"
            )
    if psf is None:
        return "gaussian", None
    if isinstance(psf, ImagePSF):
        given = tuple(int(v) for v in np.broadcast_to(psf.oversampling, 2))
        if oversampling is not None and oversampling != given:
            raise ValueError(
                f"{name} is an ImagePSF with oversampling {list(given)}; oversampling="
                f"{list(oversampling)} contradicts it (leave it out with an ImagePSF)"
            )
        return "image", psf
    if isinstance(psf, u.Quantity):
        if not psf.isscalar:
            raise ValueError(f"{name} (a Gaussian FWHM) must be a scalar, got shape {psf.shape}")
        if psf.unit.physical_type == "angle":
            if wcs is None:
                raise ValueError(
                    f"{name} given as an angle ({psf}) needs an image with a celestial WCS"
                )
            fwhm = psf.to_value(u.arcsec) / _pixel_scale(wcs, shape, "image")
        elif psf.unit == u.pix:
            fwhm = psf.value
        else:
            raise TypeError(
                f"{name} as a Quantity must be an angle or in pixels (u.pix), got unit {psf.unit!s}"
            )
        return "gaussian", _check_fwhm(fwhm, psf, name)
    if isinstance(psf, (np.ndarray, list, tuple)):
        arr = np.asarray(psf, dtype=np.float64)
        if arr.ndim == 0:
            return "gaussian", _check_fwhm(float(arr), psf, name)
        if arr.ndim != 2 or min(arr.shape) < 4:
            raise ValueError(
                f"{name} as an array must be a 2-D PSF image of at least 4x4 pixels, "
                f"got shape {arr.shape}"
            )
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} contains NaN or infinite values")
        total = arr.sum()
        if not total > 0:
            raise ValueError(f"{name} must have a positive sum, got {total}")
        os_ = (1, 1) if oversampling is None else oversampling
        # photutils' convention: an oversampled image sums to oy * ox
        return "image", ImagePSF(arr * (os_[0] * os_[1] / total), oversampling=os_)
    if isinstance(psf, (int, float, np.integer, np.floating)) and not isinstance(psf, bool):
        return "gaussian", _check_fwhm(float(psf), psf, name)
    raise TypeError(
        f"{name} must be a Gaussian FWHM (Quantity angle or pixels, or a number of pixels), a 2-D "
        f"PSF array, a photutils ImagePSF or None, got {type(psf).__name__}"
    )


def _check_fwhm(fwhm, given, name):
    if not np.isfinite(fwhm) or fwhm <= 0:
        raise ValueError(f"{name} (a Gaussian FWHM) must be finite and positive, got {given}")
    return float(fwhm)


def _positions(positions, wcs, shape):
    """Return (x, y, ids) from an (N, 2) array, a table or a SkyCoord."""
    ids = None
    if isinstance(positions, SkyCoord):
        if wcs is None:
            raise ValueError("positions given as a SkyCoord need an image with a WCS")
        x, y = wcs.world_to_pixel(positions)
    elif isinstance(positions, Table):
        xname = next((n for n in _X_NAMES if n in positions.colnames), None)
        yname = next((n for n in _Y_NAMES if n in positions.colnames), None)
        if xname is None or yname is None:
            raise ValueError(
                "positions (a table) must have pixel columns such as x_centroid/y_centroid "
                f"or x/y, got columns {positions.colnames}"
            )
        x, y = positions[xname], positions[yname]
        if "id" in positions.colnames:
            ids = np.asarray(positions["id"])
    else:
        if isinstance(positions, u.Quantity):
            if positions.unit != u.pix:
                raise TypeError(
                    f"positions as a Quantity must be in pixels (u.pix), got unit "
                    f"{positions.unit!s}"
                )
            positions = positions.value
        try:
            arr = np.asarray(positions, dtype=np.float64)
        except (TypeError, ValueError):
            raise TypeError(
                "positions must be an (N, 2) array of (x, y) pixel positions, a table with "
                f"x/y columns or a SkyCoord, got {type(positions).__name__}"
            ) from None
        if arr.ndim == 1 and arr.size == 2:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != 2:
            raise ValueError(f"positions must have shape (N, 2), got shape {arr.shape}")
        x, y = arr[:, 0], arr[:, 1]
    x = np.atleast_1d(
        np.asarray(u.Quantity(x).value if isinstance(x, u.Quantity) else x, dtype=np.float64)
    )
    y = np.atleast_1d(
        np.asarray(u.Quantity(y).value if isinstance(y, u.Quantity) else y, dtype=np.float64)
    )
    if x.size == 0:
        raise ValueError("positions must hold at least one position, got none")
    ny, nx = shape
    bad = ~(
        np.isfinite(x)
        & np.isfinite(y)
        & (x >= -0.5)
        & (x <= nx - 0.5)
        & (y >= -0.5)
        & (y <= ny - 0.5)
    )
    if ids is None:
        ids = np.arange(1, x.size + 1)
    return x, y, ids, bad


def _outside_text(x, y, bad, ids, shape):
    """Words for the positions outside the image."""
    k = np.flatnonzero(bad)
    return (
        f"positions {k.tolist()[:10]} (ids {np.asarray(ids)[k].tolist()[:10]}) are outside "
        f"the image (shape {shape}) or not finite: (x, y) = "
        f"{[(float(x[i]), float(y[i])) for i in k[:3]]}; not fitted (NaN, flag OUTSIDE_IMAGE)"
    )


def _fit_shape(fit_shape, fwhm, strategy):
    if fit_shape is None:
        factor = 2.0 if strategy == "ridge" else 1.5
        half = max(4 if strategy == "ridge" else 2, int(np.ceil(factor * fwhm)))
        return (2 * half + 1, 2 * half + 1)
    if isinstance(fit_shape, (int, np.integer)) and not isinstance(fit_shape, bool):
        fit_shape = (int(fit_shape), int(fit_shape))
    try:
        shape = tuple(int(v) for v in fit_shape)
        ok = len(shape) == 2 and all(v == f for v, f in zip(shape, fit_shape, strict=True))
    except (TypeError, ValueError):
        ok = False
    if not ok or any(v < 3 or v % 2 == 0 for v in shape):
        raise ValueError(
            f"fit_shape must be an odd integer >= 3 or a pair (ny, nx) of them, got {fit_shape!r}"
        )
    return shape


def _blur(image, sigma):
    return gaussian_filter(image, sigma, mode=_BLUR_MODE, truncate=_BLUR_TRUNCATE)


#: psf_photometry works on a cut-out about the positions when its area is at most
#: this fraction of the image's (else on the whole image: the saving is small).
_CUTOUT_MAX_FRACTION = 0.5


def _reach(sigma):
    """Radius of the kernel of ``gaussian_filter(..., sigma, truncate=4)``, in pixels."""
    return int(_BLUR_TRUNCATE * float(sigma) + 0.5)


def _cutout_margin(basis_kind, fit_shape, fwhm, highpass, local_est):
    """Pixels about the positions that the photometry reads, or None (unknown reach).

    A fit reads the pixels of its ``fit_shape`` box (and the models of the other
    sources, added as stamps, only there). The high-pass image (``"residual"``
    strategies) reads ``_reach(smooth_sigma)`` pixels further; the local
    background annulus ``outer_radius``; the arc direction of the ``"ridge"``
    background, taken at a box centre, the chain of blurs of `_make_basis`
    (source discs filled with sigma ``r``, gradient, structure tensor). Beyond
    that margin the data do not enter any result, and blurs with the image edge
    inside it are the same whether the edge is the image's or the cut-out's.
    """
    half = max(fit_shape) // 2
    reach = half
    if basis_kind == "ridge":
        r = max(2.0, 1.5 * fwhm)
        reach = half + 1 + _reach(r) + _reach(max(1.0, 0.6 * fwhm)) + _reach(max(2.0, 1.6 * fwhm))
    elif local_est is not None:
        outer = getattr(local_est, "outer_radius", None)
        if outer is None or not np.isfinite(outer):
            return None
        reach = max(half, int(np.ceil(float(outer))) + 1)
    if highpass:
        reach += _reach(highpass)
    return reach + 2


def _cutout_box(x, y, shape, margin):
    """Slices (rows, columns) of the bounding box of (x, y) plus ``margin``, or None.

    None when there is no position, the margin is unknown or the box would
    cover more than ``_CUTOUT_MAX_FRACTION`` of the image.
    """
    if margin is None or x.size == 0:
        return None
    ny, nx = shape
    x0 = max(int(np.floor(np.min(x))) - margin, 0)
    x1 = min(int(np.ceil(np.max(x))) + margin + 1, nx)
    y0 = max(int(np.floor(np.min(y))) - margin, 0)
    y1 = min(int(np.ceil(np.max(y))) + margin + 1, ny)
    if (x1 - x0) * (y1 - y0) > _CUTOUT_MAX_FRACTION * nx * ny:
        return None
    return (slice(y0, y1), slice(x0, x1))


def _highpass(data, invalid, sigma):
    """``data - G_sigma(data)``, by normalised convolution where pixels are invalid."""
    if invalid is None:
        return data - _blur(data, sigma)
    return np.where(invalid, 0.0, data - _smooth_filled(data, invalid, sigma))


def _smooth_filled(data, invalid, sigma):
    """Gaussian blur ignoring invalid pixels (normalised convolution)."""
    w = (~invalid).astype(np.float64)
    num = _blur(np.where(invalid, 0.0, data), sigma)
    den = _blur(w, sigma)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = num / den
    return np.where(np.isfinite(out), out, 0.0)


# ---------------------------------------------------------------------------
# the fit
# ---------------------------------------------------------------------------


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


def _linear_init(data, invalid, error, x, y, profile, basis, fit_shape, local_bkg):
    """Flux and background coefficients by linear least squares at fixed positions."""
    out = np.full((x.size, 1 + len(basis.names)), np.nan)
    for i in range(x.size):
        xx, yy = _box_pixels(x[i], y[i], data.shape, fit_shape, invalid)
        if xx.size <= out.shape[1] + 2:
            continue
        d = data[yy, xx] - local_bkg[i]
        w = 1.0 if error is None else 1.0 / error[yy, xx]
        cols = [profile(xx - x[i], yy - y[i])] + basis.columns(xx.astype(float), yy.astype(float))
        a = np.stack(cols, axis=1) * np.reshape(w, (-1, 1))
        out[i] = np.linalg.lstsq(a, d * w, rcond=None)[0]
    return out


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


def _groups(x, y, radius):
    """Connected components of the sources closer than ``radius`` (only those of size > 1)."""
    n = x.size
    label = np.arange(n)
    if radius <= 0 or n < 2:
        return []
    close = np.hypot(x[:, None] - x, y[:, None] - y) < radius
    for i in range(n):  # union-find by relabelling (n is small)
        for j in np.flatnonzero(close[i]):
            a, b = label[i], label[j]
            if a != b:
                label[label == b] = a
    return [np.flatnonzero(label == v) for v in np.unique(label) if np.sum(label == v) > 1]


class _GroupModel(Fittable2DModel):
    """Several PSFs and one background (lensdual internal); see :func:`_group_class`."""

    _n = 0

    def __init__(self, profile=None, basis=None, centre=None, **kwargs):
        super().__init__(**kwargs)
        self._profile = profile
        self._basis = basis
        self._centre = centre

    def evaluate(self, x, y, *params):
        out = np.zeros(np.shape(x))
        for i in range(self._n):
            f, x0, y0 = params[3 * i : 3 * i + 3]
            out = out + f * self._profile(x - x0, y - y0)
        coeffs = params[3 * self._n :]
        if coeffs:
            cols = self._basis.columns(x, y, centre=self._centre)
            for c, col in zip(coeffs, cols, strict=True):
                out = out + c * col
        return out

    def fit_deriv(self, x, y, *params):
        out = []
        for i in range(self._n):
            f, x0, y0 = params[3 * i : 3 * i + 3]
            dx, dy = x - x0, y - y0
            gx, gy = self._profile.grad(dx, dy)
            out += [self._profile(dx, dy), -f * gx, -f * gy]
        return out + self._basis.columns(x, y, centre=self._centre)


_GROUP_CLASSES = {}


def _group_class(n, names):
    key = (n, tuple(names))
    if key not in _GROUP_CLASSES:
        attrs = {}
        for i in range(n):
            attrs[f"flux_{i}"] = Parameter(default=1.0)
            attrs[f"x_0_{i}"] = Parameter(default=0.0)
            attrs[f"y_0_{i}"] = Parameter(default=0.0)
        for name in names:
            attrs[name] = Parameter(default=0.0)
        attrs["_n"] = n
        attrs["__module__"] = __name__
        attrs["__doc__"] = "Several PSFs plus a linear background (lensdual internal)."
        _GROUP_CLASSES[key] = type(f"_Group{n}x{len(names)}", (_GroupModel,), attrs)
    return _GROUP_CLASSES[key]


def _fit_group(
    image,
    invalid,
    error,
    members,
    x,
    y,
    flux0,
    profile,
    basis,
    fit_shape,
    bound,
    maxiters,
    local_bkg,
):
    """Joint fit of the PSFs of ``members`` and one background over the union of their
    boxes, with astropy's TRF fitter; returns a dict of per-member results (and
    ``bkg_at``), or None when the group has too few pixels."""
    from astropy.modeling.fitting import TRFLSQFitter

    ny, nx = image.shape
    region = np.zeros((ny, nx), bool)
    boxes = []
    for k in members:
        xx, yy = _box_pixels(x[k], y[k], (ny, nx), fit_shape, invalid)
        region[yy, xx] = True
        boxes.append((xx, yy))
    yy, xx = np.nonzero(region)
    m = len(members)
    nparam = 3 * m + len(basis.names)
    if xx.size <= nparam + 2:
        return None
    xf, yf = xx.astype(np.float64), yy.astype(np.float64)
    centre = _box_centre(xf, yf)
    local = float(np.mean(local_bkg[members]))
    d = image[yy, xx] - local
    w = None if error is None else 1.0 / error[yy, xx]
    # starting fluxes and background: linear least squares at the starting positions
    cols = [profile(xf - x[k], yf - y[k]) for k in members] + basis.columns(xf, yf, centre)
    a = np.stack(cols, axis=1)
    ww = 1.0 if w is None else w[:, None]
    lin = np.linalg.lstsq(a * ww, d * (1.0 if w is None else w), rcond=None)[0]
    params = {}
    for i, k in enumerate(members):
        f0 = lin[i] if np.isfinite(lin[i]) and lin[i] > 0 else flux0[k]
        params[f"flux_{i}"] = f0
        params[f"x_0_{i}"] = x[k]
        params[f"y_0_{i}"] = y[k]
    for name, c in zip(basis.names, lin[m:], strict=True):
        params[name] = c
    model = _group_class(m, basis.names)(profile=profile, basis=basis, centre=centre, **params)
    for i, k in enumerate(members):
        getattr(model, f"x_0_{i}").bounds = (x[k] - bound, x[k] + bound)
        getattr(model, f"y_0_{i}").bounds = (y[k] - bound, y[k] + bound)
    fitter = TRFLSQFitter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fitted = fitter(model, xf, yf, d, weights=w, maxiter=maxiters * m)
    info = fitter.fit_info
    cov = info.get("param_cov")
    values = np.asarray(fitted.parameters, dtype=np.float64)
    errs = np.full(nparam, np.nan) if cov is None else np.sqrt(np.clip(np.diag(cov), 0, None))
    resid = d - fitted(xf, yf)
    chi = resid if w is None else resid * w
    red_chi2 = float(np.sum(chi**2) / max(xx.size - nparam, 1))
    out = {col: np.full(m, np.nan) for col in _RESULT_COLUMNS}
    out["bkg_at"] = np.full(m, np.nan)
    coeffs = values[3 * m :]
    full = int(np.prod(fit_shape))
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
        flags = PhotometryFlag(0)
        if bx.size < full:
            flags |= PhotometryFlag.N_PIXELS_FIT_PARTIAL
        if not (-0.5 <= xi <= nx - 0.5 and -0.5 <= yi <= ny - 0.5):
            flags |= PhotometryFlag.OUTSIDE_BOUNDS
        if not f > 0:
            flags |= PhotometryFlag.NON_POSITIVE_FLUX
        if not getattr(info, "success", True) or caught:
            flags |= PhotometryFlag.NO_CONVERGENCE
        if cov is None:
            flags |= PhotometryFlag.NO_COVARIANCE
        if max(abs(xi - x[k]), abs(yi - y[k])) > bound - 0.01:
            flags |= PhotometryFlag.NEAR_BOUND
        if not (np.isfinite(xi) and np.isfinite(yi)):
            flags |= PhotometryFlag.NON_FINITE_POSITION
        if not np.isfinite(f):
            flags |= PhotometryFlag.NON_FINITE_FLUX
        out["flags"][i] = int(flags)
        if coeffs.size:
            c = basis.columns(np.array([xi]), np.array([yi]), centre=centre)
            out["bkg_at"][i] = float(sum(cc * col[0] for cc, col in zip(coeffs, c, strict=True)))
        else:
            out["bkg_at"][i] = local
    return out


def _fit_sources(
    data,
    invalid,
    error,
    x,
    y,
    profile,
    basis,
    fit_shape,
    local_bkg,
    xy_bounds,
    maxiters,
    neighbour_passes,
    group_radius=0.0,
    with_shape=False,
    fwhm_init=None,
):
    """Fit all sources; returns (dict of result arrays, caught warnings).

    Sources closer than ``group_radius`` to another are fitted jointly (one
    background per group, astropy's fitter); the others one by one with
    photutils' PSFPhotometry. Sources with neighbours are then refined by
    passes on the image minus the models of all other sources.
    """
    model = _model_class(basis.names, with_shape)(profile=profile, basis=basis)
    lin = _linear_init(data, invalid, error, x, y, profile, basis, fit_shape, local_bkg)
    n = x.size
    extra = (("fwhm",) if with_shape else ()) + tuple(basis.names)
    bound = float(min(fit_shape) // 2) if xy_bounds is None else float(xy_bounds[0])
    # starting values: linear least squares at the initial positions
    start = {"flux": np.where(np.isfinite(lin[:, 0]) & (lin[:, 0] > 0), lin[:, 0], 1.0)}
    for k, name in enumerate(basis.names):
        start[name] = np.nan_to_num(lin[:, 1 + k])
    if with_shape:
        start["fwhm"] = np.full(n, float(fwhm_init))
    columns = (
        _RESULT_COLUMNS
        + ("bkg_at", "group_size")
        + tuple(f"{e}_fit" for e in extra)
        + tuple(f"{e}_err" for e in extra)
    )
    cur = {col: np.full(n, np.nan) for col in columns}
    cur["group_size"][:] = 1
    caught = []
    failed = []  # fits that raised, in words

    def fit_singles(members, image):
        if members.size == 0:
            return
        t = QTable()
        t["id"] = np.arange(1, len(members) + 1)
        t["x_init"] = x[members]
        t["y_init"] = y[members]
        t["flux_init"] = start["flux"][members]
        t["local_bkg"] = local_bkg[members]
        for name in extra:
            t[f"{name}_init"] = start[name][members]
        try:
            res, more = _run_photutils(
                model, fit_shape, image, invalid, error, t, (bound, bound), maxiters
            )
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            if members.size > 1:  # find the culprit(s): fit them one by one
                for k in members:
                    fit_singles(np.array([k]), image)
                return
            failed.append(f"source {int(members[0])}: {exc}")
            for col in _RESULT_COLUMNS + ("bkg_at",):
                cur[col][members] = np.nan
            cur["flags"][members] = int(PhotometryFlag.FIT_FAILED)
            return
        caught.extend(more)
        for col in (
            _RESULT_COLUMNS + tuple(f"{e}_fit" for e in extra) + tuple(f"{e}_err" for e in extra)
        ):
            cur[col][members] = np.asarray(res[col], dtype=np.float64)
        for i, k in enumerate(members):
            cur["bkg_at"][k] = _bkg_at(
                basis, res, i, x[k], y[k], data.shape, fit_shape, invalid, local_bkg[k]
            )
        # the next pass starts from these fits, where they succeeded
        for name in ("flux",) + extra:
            val = cur[f"{name}_fit"][members]
            ok = np.isfinite(val) & ((val > 0) if name == "flux" else True)
            start[name][members[ok]] = val[ok]

    def fit_group(members, image):
        try:
            res = _fit_group(
                image,
                invalid,
                error,
                members,
                x,
                y,
                start["flux"],
                profile,
                basis,
                fit_shape,
                bound,
                maxiters,
                local_bkg,
            )
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            failed.append(f"group of sources {members.tolist()}: {exc}")
            for col in _RESULT_COLUMNS + ("bkg_at",):
                cur[col][members] = np.nan
            cur["flags"][members] = int(PhotometryFlag.FIT_FAILED)
            return
        if res is None:
            cur["flags"][members] = int(PhotometryFlag.TOO_FEW_PIXELS)
            return
        for col in _RESULT_COLUMNS + ("bkg_at",):
            cur[col][members] = res[col]
        cur["group_size"][members] = len(members)
        ok = np.isfinite(res["flux_fit"]) & (res["flux_fit"] > 0)
        start["flux"][members[ok]] = res["flux_fit"][ok]

    groups = [] if with_shape else _groups(x, y, group_radius)
    in_group = np.zeros(n, bool)
    for g in groups:
        in_group[g] = True
    units = [g for g in groups] + [np.array([k]) for k in np.flatnonzero(~in_group)]

    def add(img, k, sign):
        f, xf, yf = cur["flux_fit"][k], cur["x_fit"][k], cur["y_fit"][k]
        if np.isfinite(f) and np.isfinite(xf) and np.isfinite(yf):
            shp = cur["fwhm_fit"][k] if with_shape else None
            _model_stamp_add(img, profile, xf, yf, sign * f, profile.radius() + 2, shp)

    # first pass: single sources alone, groups jointly on the image minus the singles
    fit_singles(np.flatnonzero(~in_group), data)
    if groups:
        others = np.zeros_like(data)
        for k in np.flatnonzero(~in_group):
            add(others, k, 1.0)
        for g in groups:
            fit_group(g, data - others)

    reach = max(fit_shape) // 2 + profile.radius() + 1
    near = (np.abs(x[:, None] - x) < reach) & (np.abs(y[:, None] - y) < reach)
    unit_of = np.empty(n, int)
    for u_, members in enumerate(units):
        unit_of[members] = u_
    unit_near = np.zeros((len(units), len(units)), bool)
    for i, j in zip(*np.nonzero(near), strict=True):
        unit_near[unit_of[i], unit_of[j]] = True
    np.fill_diagonal(unit_near, False)
    crowded_units = np.flatnonzero(unit_near.any(axis=1))
    if crowded_units.size and neighbour_passes > 0:
        # Refinement of the sources with neighbours: refit each class of mutually
        # distant units (sources or groups) on the image minus the PSF models of all
        # the other sources (Gauss-Seidel over the classes), until nothing moves by
        # 0.05 sigma.
        crowded = np.concatenate([units[c] for c in crowded_units])
        classes = _unit_classes(unit_near, crowded_units)
        others = np.zeros_like(data)
        for k in range(n):
            add(others, k, 1.0)
        for _ in range(neighbour_passes):
            before = {k: cur[k][crowded].copy() for k in ("flux_fit", "x_fit", "y_fit")}
            for cls in classes:
                members = np.concatenate([units[c] for c in cls])
                for k in members:
                    add(others, k, -1.0)
                image = data - others
                # a class may hold only groups: nothing to fit one by one then
                singles = [units[c] for c in cls if len(units[c]) == 1]
                if singles:
                    fit_singles(np.concatenate(singles), image)
                for c in cls:
                    if len(units[c]) > 1:
                        fit_group(units[c], image)
                for k in members:
                    add(others, k, 1.0)
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
    cur["flags"] = np.where(np.isfinite(cur["flags"]), cur["flags"], 0).astype(np.int64)
    cur["n_pixels_fit"] = np.nan_to_num(cur["n_pixels_fit"]).astype(np.int64)
    cur["group_size"] = cur["group_size"].astype(np.int64)
    return cur, caught, failed


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


def _bkg_at(basis, res, i, x0, y0, shape, fit_shape, invalid, local):
    """Fitted background at the fitted position of row ``i`` of a photutils result."""
    if not basis.names:
        return local
    xf, yf = float(res["x_fit"][i]), float(res["y_fit"][i])
    xx, yy = _box_pixels(x0, y0, shape, fit_shape, invalid)
    if xx.size == 0 or not (np.isfinite(xf) and np.isfinite(yf)):
        return np.nan
    cols = basis.columns(np.array([xf]), np.array([yf]), centre=_box_centre(xx, yy))
    return float(
        sum(float(res[f"{n}_fit"][i]) * c[0] for n, c in zip(basis.names, cols, strict=True))
    )


def _estimate_fwhm(
    data,
    invalid,
    error,
    x,
    y,
    highpass,
    basis,
    fit_shape,
    local_bkg,
    xy_bounds,
    maxiters,
    max_rel_err=None,
):
    """Common Gaussian FWHM (pixels) from a fit with the FWHM free for every source."""
    start = 2.5
    profile = _GaussianProfile(start, highpass)
    res, _, _ = _fit_sources(
        data,
        invalid,
        error,
        x,
        y,
        profile,
        basis,
        fit_shape,
        local_bkg,
        xy_bounds,
        maxiters,
        0,
        with_shape=True,
        fwhm_init=start,
    )
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


def psf_photometry(
    image,
    positions,
    *,
    psf=None,
    fit_shape=None,
    background=_DEFAULT_BACKGROUND,
    smooth_sigma=5.0,
    local_radii=None,
    xy_bounds=None,
    group_radius=None,
    neighbour_passes=10,
    maxiters=100,
    warn=True,
    oversampling=None,
    check_psf=True,
    label=None,
):
    r"""PSF photometry of point sources on a bright arc, from given positions.

    Each source is fitted with photutils' `~photutils.psf.PSFPhotometry`
    (flux and position free) in a ``fit_shape`` box about its initial
    position, together with a local background model chosen by
    ``background``; see :ref:`photometry` for the strategies and how they
    compare on a bright, curved, steep arc.

    Parameters
    ----------
    image : `~astropy.nddata.CCDData`, `~astropy.nddata.NDData` or array
        The image (a `~numpy.ndarray`, masked array or `~astropy.units.Quantity`
        is accepted too). An NDData's ``mask`` (True = bad), ``uncertainty``
        (`~astropy.nddata.StdDevUncertainty`, or a variance / inverse
        variance, used as the 1-sigma pixel errors that weight the fit),
        ``unit`` and ``wcs`` are used; NaN and infinite pixels, and pixels
        whose error is not positive, are ignored. The input is not modified.
    positions : (N, 2) array, `~astropy.table.Table` or `~astropy.coordinates.SkyCoord`
        Initial positions: (x, y) pixel coordinates (0-based, as in numpy
        and photutils); a table with pixel columns (``x_centroid`` /
        ``y_centroid`` as made by `~lensdual.detection.find_point_sources`,
        or ``x`` / ``y``, ``x_init`` / ``y_init``, ``x_fit`` / ``y_fit``;
        its ``id`` column is kept); or sky positions (needs a WCS). A
        position off the image (or not finite) is not fitted: its row is NaN
        and flagged ``OUTSIDE_IMAGE``.
    psf : `~astropy.units.Quantity`, float, 2-D array, `~photutils.psf.ImagePSF` or None, optional
        The PSF: a circular Gaussian of this FWHM (an angle, which needs a
        celestial WCS, a Quantity in ``u.pix``, or a number of pixels),
        integrated over the pixels; a 2-D PSF image (any normalisation: it is
        rescaled; centred on its central pixel; detector-sampled, or
        oversampled with ``oversampling``); or a photutils
        `~photutils.psf.ImagePSF` (used as it is, with its oversampling and
        normalisation). None (default): a Gaussian whose FWHM is fitted
        first to all sources (the inverse-variance weighted median of the
        per-source FWHM), then held fixed; it is recorded in
        ``meta['fwhm']``.
    fit_shape : int or (int, int), optional
        Odd size (ny, nx) of the fitting box, >= 3. Default: 2 * ceil(2 *
        FWHM) + 1 pixels (at least 9) for ``"ridge"``, 2 * ceil(1.5 * FWHM)
        + 1 (at least 5) otherwise; the FWHM of an image PSF is the diameter
        of its area above half maximum.
    background : str or `~photutils.background.LocalBackground`, optional
        How the light of the arc under each source is handled:

        * ``"ridge"`` (default): fit, with the PSF, an arc-aligned background
          :math:`f(u) + g(u)\,v + c\,v^2`, where :math:`u` runs across the
          arc and :math:`v` along it (directions from the image's structure
          tensor at the box centre), :math:`f` and :math:`g` are
          piecewise-linear on knots about 0.6 FWHM apart. The arc's cross
          profile is free, its variation along the arc is linear (plus a
          common curvature);
        * ``"residual"``: fit the *high-pass filtered* image,
          ``image - G * image`` with ``G`` a Gaussian of ``smooth_sigma``
          pixels (the residual image of `~lensdual.detection.PointSourceFilter`,
          without its clipping), with the *same filter applied to the PSF
          model* (which makes the flux exact: the filter also removes part of
          the source's own wings), plus a fitted constant;
        * ``"residual-plane"``: the same with a fitted tilted plane;
        * ``"plane"``, ``"quadratic"``, ``"constant"``: fit PSF plus a
          polynomial of order 1, 2 or 0 in the pixel offsets to the image;
        * ``"local"``: subtract the median in an annulus (photutils
          `~photutils.background.LocalBackground`, radii ``local_radii``),
          then fit the PSF alone; a `~photutils.background.LocalBackground`
          instance can be given instead of the string;
        * ``"none"``: fit the PSF alone (only for sources on an empty
          background).
    smooth_sigma : float, optional
        Sigma, in pixels, of the Gaussian of the high-pass filter (the
        ``"residual"`` strategies); default 5, that of
        `~lensdual.detection.PointSourceFilter`. Must be > 0.
    local_radii : (float, float), optional
        Inner and outer radii (pixels) of the annulus of ``"local"``;
        default (half the fit box + 1, that + 2 FWHM).
    xy_bounds : float or None, optional
        Largest shift (pixels) of a fitted position from its initial one, in
        x and in y. None (default): half the fitting box (a source must stay
        in its box). Sources that end at the bound are flagged (``flags``
        bit 32).
    group_radius : float, optional
        Sources closer than this (pixels) to another are fitted jointly: all
        their PSFs and one background over the union of their boxes (with
        astropy's `~astropy.modeling.fitting.TRFLSQFitter`, as photutils
        would). Default: 2 FWHM; 0 fits every source on its own.
    neighbour_passes : int, optional
        Largest number of refinement passes in which every source that has
        neighbours (sources whose fitting boxes or PSF wings overlap) is
        refitted on the image minus the fitted PSFs of all the others; the
        passes stop when no flux or position changes by more than 0.05
        sigma. Default 10; 0 fits each source alone. Sources far from any
        other are fitted once.
    maxiters : int, optional
        Largest number of function evaluations of the least-squares fitter
        per source.
    warn : bool, optional
        Emit a `~lensdual.exceptions.LensdualWarning` when some fits are
        flagged (default True). photutils' own warnings are never passed
        on: they are summarised in that one warning.
    oversampling : int or (int, int), optional
        Oversampling factor(s) (oy, ox) of a 2-D PSF image ``psf``: its
        pixels per detector pixel, e.g. 4 for the ``OVERSAMP`` image (HDU 0)
        of a WebbPSF/STPSF file (header keyword ``OVERSAMP``). The image is
        used as an effective PSF, as photutils' ``ImagePSF(data,
        oversampling=...)``. Default None: not oversampled. Only for a PSF
        image (a ValueError otherwise, or when it contradicts an ImagePSF's
        own).
    check_psf : bool, optional
        With a PSF image (default True): fit a Gaussian FWHM to the (at most
        6) brightest sources before the photometry, and refuse (ValueError) a
        PSF more than 1.8 times wider than them (an oversampled PSF passed
        without ``oversampling``), or 1.8 times narrower when an
        ``oversampling`` was given; warn when it is narrower without one.
    label : str, optional
        How messages name the image, e.g. ``"arc L1, band F150W"``; the file
        in the image's ``meta['FILENAME']`` (or ``filename``, ``file``) is
        added when present. Default ``"image"``.

    Returns
    -------
    table : `~astropy.table.QTable`
        One row per position, in input order:

        * ``id``: from the positions table, or 1, 2, ...;
        * ``x_init``, ``y_init``: initial pixel position;
        * ``x_fit``, ``y_fit``, ``x_err``, ``y_err``: fitted position and its
          1-sigma errors (pixels, 0-based);
        * ``flux``, ``flux_err``: total PSF flux and its 1-sigma error, in the
          image unit (a Quantity when the image has one);
        * ``bkg``: the fitted background at the source position (for the
          ``"residual"`` strategies: in the filtered image; for ``"local"``:
          the annulus estimate), image unit;
        * ``sky``: `~astropy.coordinates.SkyCoord` of the fitted position
          (only with a celestial WCS);
        * ``group_size``: 1, or the number of sources fitted jointly with it;
        * ``qfit``, ``cfit``, ``reduced_chi2``, ``n_pixels_fit``, ``flags``:
          photutils' fit-quality columns and flags (see
          `~photutils.psf.PSFPhotometry`; ``flags == 0`` is a clean fit; the
          same definitions for jointly fitted groups, whose ``reduced_chi2``
          is that of the whole group), plus lensdual's own bits: see
          :class:`PhotometryFlag`;
        * ``flag_note``: the flags in words (:func:`describe_flags`), "" for
          a clean fit.

        The errors come from the fit covariance, marginalised over the
        background parameters: with pixel errors (an uncertainty) it is the
        inverse Fisher matrix of the weighted fit; without, it is scaled by
        the reduced chi-square. ``meta`` records the PSF, FWHM (pixels),
        fit shape, background strategy and smoothing, the PSF image's
        ``oversampling`` and ``input`` (how messages name the image).

    Raises
    ------
    TypeError
        ``image``, ``positions``, ``psf`` or ``background`` of the wrong
        type.
    ValueError
        Non-positive FWHM, a bad ``fit_shape``, an unknown background
        strategy, an angular FWHM or sky positions without a WCS, a bad
        ``oversampling``, a PSF image whose width does not match the sources
        (see ``check_psf``), an image without any valid pixel (all NaN, an
        error map zero or NaN everywhere, all masked: the message names the
        image, its file and what to check), a cube of several planes.

    Warns
    -----
    LensdualWarning
        Some fits are flagged (did not converge, no covariance, non-positive
        flux, positions off the image, ...); an image of shape (1, ny, nx)
        (a cube with NAXIS3 = 1) used as its 2-D plane.
    """
    from photutils.background import LocalBackground

    parts = _split_parts(image, "image", label)
    where, unit, wcs = parts[0], parts[3], parts[4]
    full_shape = parts[1].shape
    oversampling = _as_oversampling(oversampling)
    kind, spec = _psf_spec(psf, wcs, full_shape, oversampling=oversampling)
    x_all, y_all, ids, off = _positions(positions, wcs, full_shape)
    inside = ~off
    x_img, y_img = x_all[inside], y_all[inside]

    local_est = None
    if isinstance(background, LocalBackground):
        local_est = background
        strategy = "local"
    elif isinstance(background, str):
        if background not in _STRATEGY:
            raise ValueError(
                f"background must be one of {list(BACKGROUND_STRATEGIES)} or a photutils "
                f"LocalBackground, got {background!r}"
            )
        strategy = background
    else:
        raise TypeError(
            f"background must be a string or a photutils LocalBackground, got "
            f"{type(background).__name__}"
        )
    image_kind, basis_kind = _STRATEGY[strategy]
    smooth_sigma = as_real(smooth_sigma, "smooth_sigma", minimum=0, inclusive=False)
    neighbour_passes = as_int(neighbour_passes, "neighbour_passes", minimum=0)
    maxiters = as_int(maxiters, "maxiters", minimum=1)
    if xy_bounds is not None:
        xy_bounds = as_real(xy_bounds, "xy_bounds", minimum=0, inclusive=False)
    if group_radius is not None:
        group_radius = as_real(group_radius, "group_radius", minimum=0)
    bounds = None if xy_bounds is None else (xy_bounds, xy_bounds)
    highpass = smooth_sigma if image_kind == "highpass" else None

    if kind == "gaussian":
        fwhm0 = spec if spec is not None else 2.5
    else:
        fwhm0 = _image_fwhm(spec)
    shape = _fit_shape(fit_shape, fwhm0, strategy)

    if strategy == "local" and local_est is None:
        if local_radii is None:
            inner = max(shape) // 2 + 1.0
            local_radii = (inner, inner + 2.0 * fwhm0)
        try:
            r_in, r_out = (float(v) for v in local_radii)
        except (TypeError, ValueError):
            raise TypeError(
                f"local_radii must be a pair of numbers (pixels), got {local_radii!r}"
            ) from None
        if not (0 <= r_in < r_out):
            raise ValueError(f"local_radii must satisfy 0 <= inner < outer, got {local_radii}")
        local_est = LocalBackground(r_in, r_out)

    # Everything below reads the image only in boxes about the positions (and, for
    # the high-pass image and the arc direction of the ridge background, through
    # blurs of known reach about them): it runs on the bounding box of the
    # positions plus that reach, so that nothing of the size of the whole image is
    # allocated; the results are those on the whole image (see _cutout_margin).
    def prepare(box):
        """(data, invalid, error, fitdata, x, y, offset, box) on ``box`` (None: all)."""
        got = None
        if box is not None:
            try:
                got = _unpack_image(image, "image", label, box=box, parts=parts)
            except ValueError:  # e.g. no valid pixel there: the whole image decides
                box = None
        if box is None:
            got = _unpack_image(image, "image", label, parts=parts)
        d, inv, err = got[:3]
        off_xy = (0, 0) if box is None else (box[1].start, box[0].start)
        fd = _highpass(d, inv, smooth_sigma) if highpass else d
        return d, inv, err, fd, x_img - off_xy[0], y_img - off_xy[1], off_xy, box

    margin = _cutout_margin(basis_kind, shape, fwhm0, highpass, local_est)
    box = _cutout_box(x_img, y_img, full_shape, margin)
    data, invalid, error, fitdata, x, y, offset, box = prepare(box)

    if strategy == "local":
        if x.size:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                local_bkg = np.atleast_1d(
                    np.asarray(local_est(fitdata, x, y, mask=invalid), dtype=np.float64)
                )
            local_bkg = np.where(np.isfinite(local_bkg), local_bkg, 0.0)
        else:
            local_bkg = np.zeros(0)
    else:
        local_bkg = np.zeros(x.size)

    fwhm = fwhm0
    caught, failed = [], []
    profile = None
    if x.size == 0:  # nothing on the image: every row NaN, flagged OUTSIDE_IMAGE
        res = {col: np.full(0, np.nan) for col in _RESULT_COLUMNS + ("bkg_at",)}
        res["group_size"] = np.zeros(0, np.int64)
        if kind == "gaussian" and spec is None:
            fwhm = np.nan
    else:
        if kind == "gaussian" and spec is None:
            basis = _make_basis(basis_kind, fitdata, invalid, shape, fwhm0, x, y)
            fwhm = _estimate_fwhm(
                fitdata, invalid, error, x, y, highpass, basis, shape, local_bkg, bounds, maxiters
            )
            if fit_shape is None:
                shape = _fit_shape(None, fwhm, strategy)
            if (
                box is not None
                and _cutout_margin(basis_kind, shape, fwhm, highpass, local_est) > margin
            ):  # a wider PSF than assumed: a wider cut-out
                margin = _cutout_margin(basis_kind, shape, fwhm, highpass, local_est)
                box = _cutout_box(x_img, y_img, full_shape, margin)
                data, invalid, error, fitdata, x, y, offset, box = prepare(box)
        basis = _make_basis(basis_kind, fitdata, invalid, shape, fwhm, x, y)
        profile = (
            _GaussianProfile(fwhm, highpass)
            if kind == "gaussian"
            else _ImageProfile(spec, highpass)
        )
        if kind == "image" and check_psf:
            # before the fit: a wrong PSF (e.g. oversampled without its factor) makes
            # wide groups whose joint fits are slow, and its fluxes are wrong anyway
            _check_image_psf(
                profile,
                fitdata,
                invalid,
                error,
                x,
                y,
                highpass,
                basis,
                shape,
                local_bkg,
                bounds,
                maxiters,
                fwhm,
                oversampling,
                where,
            )
        radius = 2.0 * fwhm if group_radius is None else group_radius
        res, caught, failed = _fit_sources(
            fitdata,
            invalid,
            error,
            x,
            y,
            profile,
            basis,
            shape,
            local_bkg,
            bounds,
            maxiters,
            neighbour_passes,
            group_radius=radius,
        )
    if group_radius is None:
        group_radius = 2.0 * fwhm
    if offset != (0, 0):  # back to the pixel coordinates of the whole image
        res["x_fit"] = res["x_fit"] + offset[0]
        res["y_fit"] = res["y_fit"] + offset[1]

    # back to one row per input position
    n_all = x_all.size
    full = {}
    for col in _RESULT_COLUMNS + ("bkg_at",):
        full[col] = np.full(n_all, np.nan)
        full[col][inside] = res[col]
    full["flags"] = np.full(n_all, int(PhotometryFlag.OUTSIDE_IMAGE), np.int64)
    full["flags"][inside] = np.asarray(res["flags"], dtype=np.int64)
    full["n_pixels_fit"] = np.zeros(n_all, np.int64)
    full["n_pixels_fit"][inside] = np.nan_to_num(res["n_pixels_fit"]).astype(np.int64)
    full["group_size"] = np.zeros(n_all, np.int64)
    full["group_size"][inside] = res["group_size"]
    fitted = np.zeros(n_all, bool)
    fitted[inside] = True
    flux_ok = np.isfinite(full["flux_fit"])
    bad_err = fitted & flux_ok & ~(np.isfinite(full["flux_err"]) & (full["flux_err"] > 0))
    full["flags"][bad_err] |= int(PhotometryFlag.BAD_ERROR)
    res = full
    bkg = res["bkg_at"]

    out = QTable()
    out["id"] = ids
    out["x_init"] = x_all
    out["y_init"] = y_all
    for name in ("x_fit", "y_fit", "x_err", "y_err"):
        out[name] = res[name]
    flux, flux_err = res["flux_fit"], res["flux_err"]
    if unit is not None:
        flux, flux_err, bkg = flux * unit, flux_err * unit, bkg * unit
    out["flux"] = flux
    out["flux_err"] = flux_err
    out["bkg"] = bkg
    if wcs is not None:
        try:
            sky = wcs.pixel_to_world(res["x_fit"], res["y_fit"])
        except Exception:  # noqa: BLE001 - a WCS without celestial axes: no sky column
            sky = None
        if isinstance(sky, SkyCoord):
            out["sky"] = sky
    for name in ("group_size", "qfit", "cfit", "reduced_chi2", "n_pixels_fit", "flags"):
        out[name] = res[name]
    out["flag_note"] = [describe_flags(f) for f in res["flags"]]
    out.meta["psf"] = (
        profile.describe()
        if profile is not None
        else (
            f"Gaussian FWHM {fwhm:.4g} px" if kind == "gaussian" else f"image PSF {spec.data.shape}"
        )
    )
    out.meta["fwhm"] = fwhm
    out.meta["fwhm_estimated"] = kind == "gaussian" and spec is None
    out.meta["fit_shape"] = shape
    out.meta["background"] = strategy
    out.meta["smooth_sigma"] = smooth_sigma if highpass else None
    out.meta["neighbour_passes"] = neighbour_passes
    out.meta["group_radius"] = group_radius
    out.meta["weighted"] = error is not None
    out.meta["oversampling"] = (
        None if kind != "image" else [int(v) for v in np.broadcast_to(spec.oversampling, 2)]
    )
    out.meta["input"] = where

    bad = (out["flags"] & _BAD_FLAGS) != 0
    if warn and (bad.any() or caught or failed or off.any()):
        msgs = sorted({str(w.message) for w in caught})
        text = f"psf_photometry ({where}): {int(bad.sum())} of {len(out)} fits flagged"
        if bad.any():
            text += f" (ids {out['id'][bad].tolist()[:20]}; see the flags columns)"
        if off.any():
            text += "; " + _outside_text(x_all, y_all, off, ids, full_shape)
        if failed:
            text += "; fits that raised: " + " | ".join(failed[:5])
        if msgs:
            text += "; photutils: " + " | ".join(msgs)
        warnings.warn(text, LensdualWarning, stacklevel=2)
    return out


#: A PSF image whose FWHM differs from that of the sources by more than this
#: factor is refused (too wide) or warned about (too narrow); see _check_image_psf.
_PSF_WIDTH_TOLERANCE = 1.8
_PSF_CHECK_SOURCES = 6


def _check_image_psf(
    profile,
    fitdata,
    invalid,
    error,
    x,
    y,
    highpass,
    basis,
    shape,
    local_bkg,
    bounds,
    maxiters,
    fwhm_psf,
    oversampling,
    where,
):
    """Compare the width of an image PSF with the sources' own (a Gaussian FWHM fit).

    The Gaussian FWHM is fitted to the (at most 6) brightest sources (by
    their linear PSF amplitude), each alone in the PSF's fitting box; only
    fits whose FWHM is known to 20 % count. A PSF more than 1.8 times wider
    than the sources cannot be right (a point source is never narrower than
    the PSF) and is a ValueError: the usual cause is an oversampled PSF image
    passed without its ``oversampling``. A PSF 1.8 times narrower is a
    ValueError too when an ``oversampling`` > 1 was given (it may not apply),
    else a warning (the sources may be resolved). Without any usable fit
    nothing is checked.
    """
    lin = _linear_init(fitdata, invalid, error, x, y, profile, basis, shape, local_bkg)[:, 0]
    amp = np.where(np.isfinite(lin) & (lin > 0), lin, 0.0)
    order = np.argsort(-amp)
    pick = order[amp[order] > 0][:_PSF_CHECK_SOURCES]
    if pick.size == 0:
        return
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fwhm_data = _estimate_fwhm(
                fitdata,
                invalid,
                error,
                x[pick],
                y[pick],
                highpass,
                basis,
                shape,
                local_bkg[pick],
                bounds,
                maxiters,
                max_rel_err=0.2,
            )
    except ValueError:  # no usable Gaussian fit: nothing to compare with
        return
    ratio = fwhm_psf / fwhm_data
    given = "no oversampling" if oversampling is None else f"oversampling={list(oversampling)}"
    facts = (
        f"{where}: the PSF image (FWHM {fwhm_psf:.2f} px with {given}) is {{}} than the point "
        f"sources (Gaussian FWHM {fwhm_data:.2f} px fitted to the {pick.size} brightest)"
    )
    if ratio > _PSF_WIDTH_TOLERANCE:
        guess = max(2, int(np.round(ratio)))
        raise ValueError(
            facts.format(f"{ratio:.1f} times wider")
            + f", which would give wrong fluxes. Is the PSF oversampled (a WebbPSF/STPSF file's "
            f"HDU 0, OVERSAMP)? Pass oversampling= its factor (header keyword OVERSAMP; about "
            f"{guess} here) or use the detector-sampled PSF (HDU 1, DET_SAMP); "
            "check_psf=False skips this check"
        )
    if ratio < 1.0 / _PSF_WIDTH_TOLERANCE:
        text = facts.format(f"{1.0 / ratio:.1f} times narrower")
        if oversampling is not None and oversampling != (1, 1):
            raise ValueError(
                text + f": is the PSF image really oversampled by {list(oversampling)}? "
                "Check its OVERSAMP header keyword, or leave oversampling out for a "
                "detector-sampled PSF; check_psf=False skips this check"
            )
        warnings.warn(
            text + ": resolved sources, or a PSF image of another pixel scale; the fluxes "
            "assume point sources",
            LensdualWarning,
            stacklevel=3,
        )


# ---------------------------------------------------------------------------
# pairs
# ---------------------------------------------------------------------------


def _check_images(images, name):
    """Validate a dict of bands; return it with single-plane cubes squeezed to 2-D."""
    if not isinstance(images, Mapping):
        raise TypeError(f"{name} must be a dict {{band: CCDData}}, got {type(images).__name__}")
    if not images:
        raise ValueError(f"{name} must hold at least one band, got none")
    out = {}
    for band, img in images.items():
        if not isinstance(band, str) or not band:
            raise TypeError(
                f"the keys (band names) of {name} must be non-empty strings, got {band!r}"
            )
        if not isinstance(img, NDData):
            raise TypeError(
                f"{name}[{band!r}] must be a CCDData or NDData with a WCS, got {type(img).__name__}"
            )
        img = _squeeze_plane(img, f"{name}[{band!r}]")
        out[band] = img
        if img.wcs is None:
            raise ValueError(f"{name}[{band!r}] has no WCS; measure_pairs needs celestial WCSs")
        wcs = _as_wcs(img.wcs, f"{name}[{band!r}].wcs")
        ny, nx = np.shape(img.data)[-2:]
        try:
            sky = wcs.pixel_to_world((nx - 1) / 2.0, (ny - 1) / 2.0)
        except Exception:  # noqa: BLE001 - any failure: not a usable celestial WCS
            sky = None
        if not isinstance(sky, SkyCoord):
            raise ValueError(f"{name}[{band!r}] has no celestial WCS")
    return out


def _initial_sky(pairs, reference):
    """Initial SkyCoord positions on both arcs from a pairs table."""
    cols = pairs.colnames
    if "sky1" in cols and "sky2" in cols:
        sky1, sky2 = pairs["sky1"], pairs["sky2"]
        if not isinstance(sky1, SkyCoord) or not isinstance(sky2, SkyCoord):
            raise TypeError("pairs['sky1'] and pairs['sky2'] must be SkyCoord columns")
        return sky1, sky2
    if all(c in cols for c in ("x1", "y1", "x2", "y2")):
        if reference is None:
            raise ValueError(
                "pairs gives x1, y1, x2, y2: pass reference, the SkyCoord of the origin of "
                "their tangent-plane frame (x towards the west, y towards the north)"
            )
        out = []
        for arc in ("1", "2"):
            cols_xy = []
            for name in (f"x{arc}", f"y{arc}"):
                col = pairs[name]
                if getattr(col, "unit", None) is None or col.unit.physical_type != "angle":
                    raise TypeError(
                        f"pairs[{name!r}] must have angular units (e.g. arcsec), got "
                        f"{getattr(col, 'unit', None)}"
                    )
                cols_xy.append(u.Quantity(col).to_value(u.arcsec))
            p = as_positions(np.column_stack(cols_xy) * u.arcsec, f"pairs x{arc}, y{arc}")
            out.append(tangent_to_sky(p[:, 0], p[:, 1], reference))
        return tuple(out)
    raise ValueError(
        "pairs must have SkyCoord columns sky1 and sky2, or angle columns x1, y1, x2, y2 "
        f"(with reference=...), got columns {cols}"
    )


def measure_pairs(
    images_l1,
    images_l2,
    pairs,
    *,
    psf=None,
    bands=None,
    reference=None,
    background=_DEFAULT_BACKGROUND,
    fit_shape=None,
    xy_bounds=None,
    neighbour_passes=10,
    oversampling=None,
    check_psf=True,
):
    r"""PSF photometry of the point-source pairs of two arcs, into a pairs table.

    Every band of both arcs is measured with :func:`psf_photometry`, starting
    from the initial positions in ``pairs``; the fitted positions are put in
    one common tangent-plane frame and combined over the bands.

    Parameters
    ----------
    images_l1, images_l2 : dict of str to `~astropy.nddata.CCDData`
        The bands of arcs L1 and L2 (cut-outs or whole images), each an
        NDData/CCDData with a celestial WCS (an uncertainty, mask and unit
        are used as by :func:`psf_photometry`). The bands of one arc may have
        different pixel grids.
    pairs : `~astropy.table.Table`
        One row per pair with the initial positions: SkyCoord columns
        ``sky1`` and ``sky2``, or angle columns ``x1``, ``y1``, ``x2``,
        ``y2`` in the tangent-plane frame about ``reference`` (see Notes).
        ``pair_id`` is kept (1, 2, ... when absent); other columns are
        copied. The table is not modified.
    psf : PSF or dict of str to PSF, optional
        The PSF as for :func:`psf_photometry` (a Gaussian FWHM, a PSF image,
        an ImagePSF or None to fit the FWHM), for all bands or per band (a
        dict; a band it lacks gets None).
    bands : list of str, optional
        The bands to measure; default: all bands of ``images_l1``. Every band
        must be in both dicts.
    reference : `~astropy.coordinates.SkyCoord`, optional
        Origin of the output frame. Default: the mean initial position of all
        point sources on both arcs (the mean of their unit vectors). Needed
        when ``pairs`` gives ``x1, y1, x2, y2`` (their frame's origin, also
        used for the output).
    background, fit_shape, xy_bounds, neighbour_passes, check_psf
        Passed to :func:`psf_photometry`.
    oversampling : int, (int, int) or dict of str to those, optional
        The oversampling of PSF images (see :func:`psf_photometry`), for all
        bands or per band (a dict; a band it lacks gets None).

    Returns
    -------
    table : `~astropy.table.QTable`
        A new pairs table (see :ref:`pairs-table`): the input columns, with
        these set or replaced:

        * ``pair_id``;
        * ``x1``, ``y1``, ``x2``, ``y2`` (arcsec): fitted positions in the
          common frame, the inverse-variance weighted mean over the bands;
        * ``pos_err1``, ``pos_err2`` (arcsec): their 1-sigma error per
          coordinate, :math:`(\sum_b \sigma_b^{-2})^{-1/2}` with
          :math:`\sigma_b` the band's rms of the x and y errors in arcsec;
        * ``sky1``, ``sky2``: the same positions as SkyCoord (frame of
          ``reference``);
        * per band ``flux1_<band>``, ``flux2_<band>``, ``flux_err1_<band>``,
          ``flux_err2_<band>`` (image unit; L2 converted to the unit of L1),
          and ``flags1_<band>``, ``flags2_<band>`` (:class:`PhotometryFlag`
          bits; 0 is a clean fit);
        * ``photometry_flags``: per pair, the sum of the unusable flags
          (:data:`UNUSABLE_FLAGS`) of all its fits; 0 when all were usable;
        * ``photometry_note``: per pair, what was not measured and why, in
          words, each entry naming the pair id, the source id (columns
          ``id1``/``id2`` when present), the arc, the band and the file
          (``meta['FILENAME']`` of the image); "" when clean;
        * ``measured``: True when both positions are known and at least one
          band has both fluxes (the pair can be tested).

        ``meta['bands']`` lists the bands, ``meta['reference']`` is the
        frame origin (SkyCoord), ``meta['photometry']`` the settings.
        Fluxes of fits with an unusable flag (non-positive flux, no
        convergence, no covariance, no or too few pixels, non-finite
        results, a position off the image, a flux error that is not finite
        and positive, a fit that raised) are NaN ("not measured"), with NaN
        errors, and such fits do not enter the positions; a position that no
        band measured is NaN. One bad candidate never stops the call.

    Raises
    ------
    TypeError
        Images not dicts of NDData, ``pairs`` not a table, ``reference`` not
        a SkyCoord.
    ValueError
        An image without a celestial WCS, a band missing from one arc,
        ``pairs`` without positions, x/y positions without ``reference``,
        incompatible flux units, a bad ``oversampling``, the errors of
        :func:`psf_photometry` on a whole image (no valid pixel, a PSF image
        that does not match the sources), named with the arc, band and file.

    Warns
    -----
    LensdualWarning
        Some fits are flagged (one warning for the whole call, with the
        notes and the pairs that cannot be tested).

    Notes
    -----
    The frame is the gnomonic (tangent-plane) projection about
    ``reference``, with **x pointing west** and y north:
    :math:`x = -\xi`, :math:`y = \eta`, where :math:`(\xi, \eta)` are the
    standard coordinates (:math:`\xi \approx \Delta\alpha\cos\delta` towards
    the east), computed exactly from the offsets in
    `~astropy.coordinates.SkyOffsetFrame` about ``reference``. On an image
    with north up and east to the left, x and y thus grow with the pixel
    coordinates. The reflection relative to the usual east-north frame is
    common to both arcs and changes neither ``mu_size`` nor the parity.
    """
    images_l1 = _check_images(images_l1, "images_l1")
    images_l2 = _check_images(images_l2, "images_l2")
    if bands is None:
        bands = list(images_l1)
    elif isinstance(bands, str):
        bands = [bands]
    else:
        bands = list(bands)
    if not bands:
        raise ValueError("bands must name at least one band, got none")
    for name, images in (("images_l1", images_l1), ("images_l2", images_l2)):
        missing = [b for b in bands if b not in images]
        if missing:
            raise ValueError(f"band(s) {missing} missing from {name} (it has {list(images)})")
    if not isinstance(pairs, Table):
        raise TypeError(f"pairs must be an astropy Table or QTable, got {type(pairs).__name__}")
    if len(pairs) == 0:
        raise ValueError("pairs has no rows")
    if reference is not None:
        if not isinstance(reference, SkyCoord) or not reference.isscalar:
            raise TypeError(f"reference must be a scalar SkyCoord or None, got {reference!r}")
    for band in bands:
        u1, u2 = images_l1[band].unit, images_l2[band].unit
        if (u1 is None) != (u2 is None):
            raise ValueError(
                f"band {band!r}: images_l1 and images_l2 must both have flux units or both have "
                f"none (got {u1} and {u2})"
            )
        if u1 is not None and not u2.is_equivalent(u1):
            raise ValueError(
                f"band {band!r}: the unit {u2} of images_l2 is not convertible to the unit "
                f"{u1} of images_l1"
            )
    if isinstance(psf, Mapping):
        psf_of = {b: psf.get(b) for b in bands}
    else:
        psf_of = dict.fromkeys(bands, psf)
    if isinstance(oversampling, Mapping):
        os_of = {b: oversampling.get(b) for b in bands}
    else:
        os_of = dict.fromkeys(bands, oversampling)
    for band in bands:
        _as_oversampling(os_of[band], f"oversampling of band {band!r}")

    sky1_init, sky2_init = _initial_sky(pairs, reference)
    if reference is None:
        reference = mean_direction(sky1_init, sky2_init)

    n = len(pairs)
    out = QTable(pairs, copy=True)
    if "pair_id" not in out.colnames:
        out.add_column(np.arange(1, n + 1), name="pair_id", index=0)
    ids = np.asarray(out["pair_id"])

    per_arc = {}
    flagged = []  # per arc and band: the pairs with an unusable fit
    notes = [[] for _ in range(n)]  # per pair: why something was not measured
    pair_flags = np.zeros(n, np.int64)  # per pair: OR of the unusable flags
    for arc, images, sky_init in (("1", images_l1, sky1_init), ("2", images_l2, sky2_init)):
        sum_w = np.zeros(n)
        sum_x = np.zeros(n)
        sum_y = np.zeros(n)
        fluxes = {}
        src_ids = np.asarray(out[f"id{arc}"]) if f"id{arc}" in out.colnames else None
        for band in bands:
            img = images[band]
            wcs = _as_wcs(img.wcs, f"images_l{arc}[{band!r}].wcs")
            label = _describe_input(f"images_l{arc}[{band!r}] (arc L{arc}, band {band})", img)
            px, py = wcs.world_to_pixel(sky_init)
            px, py = np.atleast_1d(px), np.atleast_1d(py)
            res = psf_photometry(
                img,
                np.column_stack([px, py]),
                psf=psf_of[band],
                background=background,
                fit_shape=fit_shape,
                xy_bounds=xy_bounds,
                neighbour_passes=neighbour_passes,
                warn=False,
                oversampling=os_of[band],
                check_psf=check_psf,
                label=label,
            )
            flags = np.asarray(res["flags"], dtype=np.int64)
            bad = (flags & _BAD_FLAGS) != 0
            path = _file_of(img)
            if bad.any():
                flagged.append(f"L{arc} {band}: pairs {ids[bad].tolist()[:10]}")
            for i in np.flatnonzero(bad):
                src = "" if src_ids is None else f" (source id {src_ids[i]})"
                where = f"L{arc} {band}" + ("" if path is None else f" [{path}]")
                notes[i].append(
                    f"pair {ids[i]}{src}, {where}: {describe_flags(flags[i], unusable_only=True)}"
                )
                pair_flags[i] |= flags[i] & _BAD_FLAGS
            good = np.isfinite(res["x_fit"]) & np.isfinite(res["y_fit"])
            safe_x = np.where(good, res["x_fit"], np.where(np.isfinite(px), px, 0.0))
            safe_y = np.where(good, res["y_fit"], np.where(np.isfinite(py), py, 0.0))
            xb, yb, sig = _pixel_to_tangent_errors(
                wcs,
                safe_x,
                safe_y,
                np.asarray(res["x_err"]),
                np.asarray(res["y_err"]),
                reference,
            )
            xb, yb = np.where(good, xb, np.nan), np.where(good, yb, np.nan)
            ok = np.isfinite(xb) & np.isfinite(yb) & np.isfinite(sig) & (sig > 0) & ~bad
            w = np.where(ok, 1.0 / np.where(ok, sig, 1.0) ** 2, 0.0)
            sum_w += w
            sum_x += np.where(ok, xb, 0.0) * w
            sum_y += np.where(ok, yb, 0.0) * w
            flux, flux_err = res["flux"].copy(), res["flux_err"].copy()
            flux[bad] = np.nan  # not measured (pairs-table convention)
            flux_err[bad] = np.nan
            fluxes[band] = (flux, flux_err, flags)
        with np.errstate(invalid="ignore", divide="ignore"):
            xm = np.where(sum_w > 0, sum_x / sum_w, np.nan)
            ym = np.where(sum_w > 0, sum_y / sum_w, np.nan)
            err = np.where(sum_w > 0, 1.0 / np.sqrt(sum_w), np.nan)
        for i in np.flatnonzero(sum_w == 0):
            notes[i].append(f"pair {ids[i]}: no band measured its L{arc} position (NaN)")
        per_arc[arc] = (xm, ym, err, fluxes)

    for arc in ("1", "2"):
        xm, ym, err, _ = per_arc[arc]
        out[f"x{arc}"] = xm * u.arcsec
        out[f"y{arc}"] = ym * u.arcsec
        out[f"pos_err{arc}"] = err * u.arcsec
        out[f"sky{arc}"] = tangent_to_sky(xm, ym, reference)
    for band in bands:
        f1, e1, g1 = per_arc["1"][3][band]
        f2, e2, g2 = per_arc["2"][3][band]
        if isinstance(f1, u.Quantity):
            f2, e2 = f2.to(f1.unit), e2.to(f1.unit)
        out[f"flux1_{band}"] = f1
        out[f"flux2_{band}"] = f2
        out[f"flux_err1_{band}"] = e1
        out[f"flux_err2_{band}"] = e2
        out[f"flags1_{band}"] = g1
        out[f"flags2_{band}"] = g2
    positions_ok = np.ones(n, bool)
    for arc in ("1", "2"):
        positions_ok &= np.isfinite(per_arc[arc][0]) & np.isfinite(per_arc[arc][1])
    some_band = np.zeros(n, bool)
    for band in bands:
        f1, f2 = per_arc["1"][3][band][0], per_arc["2"][3][band][0]
        some_band |= np.isfinite(np.asarray(getattr(f1, "value", f1))) & np.isfinite(
            np.asarray(getattr(f2, "value", f2))
        )
    measured = positions_ok & some_band
    for i in np.flatnonzero(positions_ok & ~some_band):
        notes[i].append(f"pair {ids[i]}: no band has both fluxes (no flux ratio)")
    out["photometry_flags"] = pair_flags
    out["photometry_note"] = ["; ".join(v) for v in notes]
    out["measured"] = measured
    out.meta["bands"] = list(bands)
    out.meta["reference"] = reference
    out.meta["photometry"] = {
        "background": background if isinstance(background, str) else repr(background),
        "fit_shape": fit_shape,
        "xy_bounds": xy_bounds,
        "neighbour_passes": neighbour_passes,
        "psf": {b: repr(p) for b, p in psf_of.items()},
        "oversampling": {b: os_of[b] for b in bands},
        "frame": "gnomonic about reference, x west, y north, arcsec",
    }
    troubled = np.flatnonzero([bool(v) for v in notes])
    if troubled.size:
        dropped = np.flatnonzero(~measured)
        text = (
            f"measure_pairs: {troubled.size} of {n} pair(s) not fully measured (NaN where "
            f"unusable; see the photometry_flags, photometry_note and flags columns)"
        )
        if flagged:
            text += "; flagged fits: " + ", ".join(flagged)
        if dropped.size:
            text += f"; pairs {ids[dropped].tolist()} cannot be tested (measured = False)"
        text += ". Why: " + "; ".join(out["photometry_note"][i] for i in troubled[:30])
        warnings.warn(text, LensdualWarning, stacklevel=2)
    return out
