"""PSF profiles of unit total flux, pixel-integrated where analytic.

A profile is called as ``profile(dx, dy, fwhm=None)`` on pixel offsets from
the source and has ``grad``, ``radius`` and ``describe``; with ``highpass``
(a Gaussian sigma in pixels) it is the profile minus its blur by that
Gaussian, the PSF of the high-pass filtered image.
"""

import numpy as np
from scipy.ndimage import gaussian_filter
from scipy.special import erf

from ._filters import _BLUR_TRUNCATE

_FWHM_TO_SIGMA = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))


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
