"""Where a PSF image is centred.

A PSF image puts its point source at its central pixel, ``((nx - 1) / 2,
(ny - 1) / 2)`` (photutils' ``ImagePSF`` convention, and lensdual's). A PSF
image centred elsewhere (cut from a star off-centre, shifted by a pixel) moves
every position fitted with it by as much, in its band only: the bands then
disagree and the fits may fail outright. The configuration
(``lensdual.config``) and the photometry (:func:`~lensdual.photometry.psf_photometry`)
refuse such an image with one rule, :func:`check_psf_centred`.
"""

import numpy as np

__all__ = ["PSF_CENTRE_TOLERANCE", "check_psf_centred", "psf_centre_offset"]

#: A PSF image whose core is centred more than this many detector pixels from its
#: central pixel, in x or y, is centred on another pixel.
PSF_CENTRE_TOLERANCE = 0.5


def psf_centre_offset(psf, oversampling=None):
    """The offset ``(dx, dy)`` in detector pixels of a PSF image's core from its centre.

    The core is the connected region of pixels at or above half the peak that
    holds the peak; its flux-weighted centroid is compared with the central
    pixel ``((nx - 1) / 2, (ny - 1) / 2)``.

    Parameters
    ----------
    psf : 2-D array
        The PSF image (finite values).
    oversampling : int or (int, int), optional
        Its pixels per detector pixel (oy, ox); default 1.

    Returns
    -------
    dx, dy : float
        The offsets along x (columns) and y (rows), in detector pixels.
    """
    from scipy import ndimage

    arr = np.asarray(psf, dtype=np.float64)
    over = np.broadcast_to(np.asarray(1 if oversampling is None else oversampling), 2)
    peak = np.unravel_index(np.argmax(arr), arr.shape)
    labels, _ = ndimage.label(arr >= 0.5 * arr[peak])
    core = labels == labels[peak]
    weight = np.where(core, arr, 0.0)
    iy, ix = np.indices(arr.shape)
    cy, cx = (float((weight * i).sum() / weight.sum()) for i in (iy, ix))
    ny, nx = arr.shape
    return (cx - (nx - 1) / 2) / float(over[1]), (cy - (ny - 1) / 2) / float(over[0])


def check_psf_centred(psf, oversampling=None, name="psf"):
    """Raise ValueError naming ``name`` when a PSF image is not centred on its central pixel.

    It is not when :func:`psf_centre_offset` exceeds
    :data:`PSF_CENTRE_TOLERANCE` detector pixels in x or y.
    """
    dx, dy = psf_centre_offset(psf, oversampling)
    if max(abs(dx), abs(dy)) > PSF_CENTRE_TOLERANCE:
        ny, nx = np.shape(psf)
        dx, dy = round(dx, 2) + 0.0, round(dy, 2) + 0.0  # no "-0.00"
        raise ValueError(
            f"{name} is not centred on its central pixel ({(nx - 1) / 2:g}, {(ny - 1) / 2:g}): "
            f"its core (the pixels above half its peak) is centred ({dx:+.2f}, {dy:+.2f}) "
            "detector pixels (x, y) away. A PSF image puts its source at its central pixel, "
            "so every position fitted in this band would be off by that much (the bands would "
            "disagree) and its fits may fail: recentre the PSF image")
