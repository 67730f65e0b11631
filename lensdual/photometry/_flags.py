"""The bits of the ``flags`` columns: photutils' PSF flags plus lensdual's own.

Bits 1 to 2048 are those of photutils' `~photutils.psf.PSFPhotometry`, with
the same meaning (photutils' ``psf/flags.py``); lensdual's own bits start at
2**16, so that a value of a ``flags`` column decodes the same way with
`~photutils.psf.decode_psf_flags` for every photutils bit.
"""

import enum

__all__ = ["PhotometryFlag", "UNUSABLE_FLAGS", "describe_flags"]


class PhotometryFlag(enum.IntFlag):
    """The bits of the ``flags`` columns of :func:`psf_photometry` and :func:`measure_pairs`.

    Bits 1 to 2048 are photutils' `~photutils.psf.PSFPhotometry` flags, with
    the same meaning (see `~photutils.psf.decode_psf_flags`); lensdual's own
    bits start at 2**16 and never reuse a photutils bit. A flag in
    :data:`UNUSABLE_FLAGS` makes the measurement unusable: :func:`measure_pairs`
    sets its fluxes (and its share of the position) to NaN.

    Examples
    --------
    >>> from lensdual.photometry import UNUSABLE_FLAGS, PhotometryFlag
    >>> flags = PhotometryFlag(32 | 65536)
    >>> [flag.name for flag in flags]
    ['NEAR_BOUND', 'OUTSIDE_IMAGE']
    >>> bool(flags & UNUSABLE_FLAGS), bool(PhotometryFlag.NEAR_BOUND & UNUSABLE_FLAGS)
    (True, False)
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
    FLAT_TOP = 1 << 19
    TOO_RESOLVED = 1 << 20


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
    PhotometryFlag.FLAT_TOP: ("flat-topped core where the PSF peaks (saturated or clipped: "
                              "the flux is not that of a point source)"),
    PhotometryFlag.TOO_RESOLVED: ("too resolved (source_model='resolved'): over 10 % of the "
                                  "fitted model's flux lies outside the fitting box, or its "
                                  "size reached the largest fitted"),
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
    | PhotometryFlag.FLAT_TOP
    | PhotometryFlag.TOO_RESOLVED
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
