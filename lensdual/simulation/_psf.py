"""A JWST-like PSF with diffraction spikes, from a hexagonal segmented pupil (poppy).

The pupil is 18 hexagonal segments (poppy's ``MultiHexagonAperture`` with
two rings, the central segment left out) of 1.32 m flat to flat with 7 mm
gaps, a circular secondary obscuration of 0.74 m diameter and three struts
of 8 cm width: one vertical (its spikes are the horizontal pair of JWST's
PSF) and two at +-30 degrees from vertical, whose spikes fall on the
segments' diagonal spikes. The PSF is the monochromatic Fraunhofer image
of this pupil at the band's wavelength (:data:`HEX_PSF_WAVELENGTH`), by
poppy's matrix Fourier transform, sampled at the centres of the renderer's
sub-pixels; it has no wavefront error, no detector effects and no
bandwidth (the segment lattice's faint grating peaks at ``lambda / 1.32 m``
are not smeared as in a broad band). poppy is an optional dependency
(``pip install lensdual[psf]``), imported only when this PSF is asked for.

This is not WebbPSF/STPSF: those need their data files, which lensdual does
not download.
"""

import functools
import math

import numpy as np
from astropy import units as u

__all__ = ["HEX_PSF_WAVELENGTH", "hexagonal_pupil_psf"]

#: Wavelength of :func:`hexagonal_pupil_psf` per NIRCam wide band (about
#: the band's pivot wavelength).
HEX_PSF_WAVELENGTH = {
    "F090W": 0.90 * u.um,
    "F115W": 1.15 * u.um,
    "F150W": 1.50 * u.um,
    "F200W": 2.00 * u.um,
    "F277W": 2.77 * u.um,
    "F356W": 3.56 * u.um,
    "F444W": 4.40 * u.um,
}

# the pupil (metres); the circumscribed diameter of the 18 segments is 6.6 m
_FLAT_TO_FLAT = 1.32
_GAP = 0.007
_SECONDARY_RADIUS = 0.37
_STRUT_WIDTH = 0.08
_STRUT_ANGLES = (270.0, 60.0, 120.0)  # poppy's support_angle_offset, degrees
_PUPIL_DIAMETER = 6.6
_PUPIL_NPIX = 512
#: Half-width of the kernel (arcsec): the spikes reach past the cutouts'
#: point-source fitting boxes.
_HALF_WIDTH = 1.0


def _import_poppy():
    try:
        import poppy
    except ImportError as err:
        raise ImportError("the hexagonal-pupil PSF (psf='poppy') needs poppy: "
                          "pip install 'lensdual[psf]' (or pip install 'poppy>=1.1')") from err
    return poppy


@functools.lru_cache(maxsize=16)
def _poppy_kernel(wavelength_m, sample_arcsec, m):
    """The normalised monochromatic PSF, ``m`` x ``m`` samples of ``sample_arcsec``."""
    poppy = _import_poppy()
    optics = [poppy.MultiHexagonAperture(rings=2, flattoflat=_FLAT_TO_FLAT, gap=_GAP,
                                         segmentlist=list(range(1, 19)))]
    optics += [poppy.SecondaryObscuration(secondary_radius=_SECONDARY_RADIUS, n_supports=1,
                                          support_width=_STRUT_WIDTH, support_angle_offset=a)
               for a in _STRUT_ANGLES]
    osys = poppy.OpticalSystem(npix=_PUPIL_NPIX, pupil_diameter=_PUPIL_DIAMETER * u.m)
    osys.add_pupil(poppy.CompoundAnalyticOptic(opticslist=optics, name="JWST-like pupil"))
    osys.add_detector(pixelscale=sample_arcsec, fov_pixels=m, oversample=1)
    kernel = np.array(osys.calc_psf(wavelength_m)[0].data, dtype=np.float64)
    kernel = np.clip(kernel, 0.0, None)
    kernel /= kernel.sum()
    kernel.setflags(write=False)
    return kernel


def hexagonal_pupil_psf(band, pixel_scale, *, supersampling=1, wavelength=None):
    """The JWST-like PSF of a hexagonal segmented pupil with struts, by poppy.

    Parameters
    ----------
    band : str
        A band of :data:`HEX_PSF_WAVELENGTH` (or any name, with ``wavelength``).
    pixel_scale : `~astropy.units.Quantity`
        The pixel size (angle).
    supersampling : int
        Samples per pixel side (odd, >= 1): the kernel is sampled at
        ``pixel_scale / supersampling``.
    wavelength : `~astropy.units.Quantity`, optional
        Overrides the band's wavelength.

    Returns
    -------
    kernel : `~numpy.ndarray`
        Square, ``(2 * ceil(1 arcsec / pixel_scale) + 1) * supersampling``
        samples per side, centred on its central sample, sum 1 (the light
        beyond the kernel's +-1 arcsec, about 3 % at 1.5 um, is left out
        and the rest renormalised).

    Raises
    ------
    ImportError
        poppy is not installed (the ``psf`` extra).
    ValueError
        An unknown band without ``wavelength``, or bad ``supersampling``.

    Examples
    --------
    >>> import astropy.units as u
    >>> from lensdual.simulation import hexagonal_pupil_psf
    >>> k = hexagonal_pupil_psf("F150W", 0.04 * u.arcsec)  # doctest: +REQUIRES(poppy)
    >>> k.shape, round(float(k.sum()), 12)  # doctest: +REQUIRES(poppy)
    ((51, 51), 1.0)
    """
    from .._validation import as_angle_scalar, as_int

    scale = as_angle_scalar(pixel_scale, "pixel_scale", allow_zero=False)
    ss = as_int(supersampling, "supersampling", minimum=1)
    if ss % 2 == 0:
        raise ValueError(f"supersampling must be odd, got {ss}")
    if wavelength is None:
        if band not in HEX_PSF_WAVELENGTH:
            raise ValueError(f"band {band!r} has no wavelength for the hexagonal-pupil PSF "
                             f"(known bands: {sorted(HEX_PSF_WAVELENGTH)}); pass wavelength=")
        wavelength = HEX_PSF_WAVELENGTH[band]
    if not isinstance(wavelength, u.Quantity) or wavelength.unit.physical_type != "length" \
            or not wavelength.isscalar:
        raise TypeError(f"wavelength must be a scalar length Quantity, got {wavelength!r}")
    lam = float(wavelength.to_value(u.m))
    if not (np.isfinite(lam) and lam > 0):
        raise ValueError(f"wavelength must be finite and > 0, got {wavelength}")
    half = max(2, math.ceil(_HALF_WIDTH / scale - 1e-9))
    m = (2 * half + 1) * ss
    return np.array(_poppy_kernel(lam, scale / ss, m))


def bin_kernel(kernel, supersampling):
    """The pixel-scale kernel of a supersampled one: the sums of its blocks of samples."""
    n = kernel.shape[0] // supersampling
    return kernel.reshape(n, supersampling, n, supersampling).sum(axis=(1, 3))


def half_max_fwhm(kernel):
    """FWHM (samples) of the azimuthally averaged profile, at half the peak, interpolated."""
    n = kernel.shape[0]
    c = (n - 1) / 2.0
    yy, xx = np.mgrid[:n, :n]
    r = np.hypot(xx - c, yy - c)
    edges = np.arange(0.0, c, 0.25)
    idx = np.digitize(r.ravel(), edges)
    prof = np.bincount(idx, weights=kernel.ravel(), minlength=len(edges) + 1)[1:len(edges)]
    cnt = np.bincount(idx, minlength=len(edges) + 1)[1:len(edges)]
    ok = cnt > 0
    rad = (0.5 * (edges[:-1] + edges[1:]))[ok[:len(edges) - 1]]
    prof = (prof / np.maximum(cnt, 1))[ok[:len(edges) - 1]]
    peak = kernel.max()
    below = np.flatnonzero(prof < 0.5 * peak)
    if len(below) == 0 or below[0] == 0:
        return float("nan")
    j = below[0]
    r0, r1, p0, p1 = rad[j - 1], rad[j], prof[j - 1], prof[j]
    return float(2.0 * (r0 + (p0 - 0.5 * peak) / (p0 - p1) * (r1 - r0)))
