"""The Gaussian blurs of the photometry: the high-pass filter and normalised convolution."""

import numpy as np
from scipy.ndimage import gaussian_filter

# Gaussian blurs of the high-pass filter: those of lensdual.detection.
_BLUR_MODE = "reflect"
_BLUR_TRUNCATE = 4.0


def _blur(image, sigma):
    return gaussian_filter(image, sigma, mode=_BLUR_MODE, truncate=_BLUR_TRUNCATE)


def _reach(sigma):
    """Radius of the kernel of ``gaussian_filter(..., sigma, truncate=4)``, in pixels."""
    return int(_BLUR_TRUNCATE * float(sigma) + 0.5)


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
