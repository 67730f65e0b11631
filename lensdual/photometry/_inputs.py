"""Input handling of the photometry: images, WCS, PSF specifications, positions."""

import warnings

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.nddata import (
    InverseVariance,
    NDData,
    StdDevUncertainty,
    VarianceUncertainty,
)
from astropy.table import Table
from astropy.wcs.wcsapi import BaseHighLevelWCS, BaseLowLevelWCS, HighLevelWCSWrapper

from .._frames import tangent_xy
from .._psf_image import check_psf_centred
from .._validation import as_int, split_image
from ..exceptions import LensdualWarning

# x/y column names understood in a positions table, in order of preference
_X_NAMES = ("x_fit", "x_centroid", "xcentroid", "x_init", "x_0", "x")
_Y_NAMES = ("y_fit", "y_centroid", "ycentroid", "y_init", "y_0", "y")


def _as_wcs(wcs, name):
    if wcs is None or isinstance(wcs, BaseHighLevelWCS):
        return wcs
    if isinstance(wcs, BaseLowLevelWCS):
        return HighLevelWCSWrapper(wcs)
    raise TypeError(f"{name} must be an astropy WCS or None, got {type(wcs).__name__}")


# meta keys that may hold the file an image was read from (FITS headers are
# case-insensitive; dict metas are not)
_FILE_KEYS = ("FILENAME", "filename", "file", "FILE", "path")


def file_of(image):
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
    path = file_of(image)
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


def squeeze_plane(image, name, stacklevel=4):
    """A 2-D image from a cube with a single plane (shape (1, ny, nx)), with a warning.

    Other inputs are returned as they are (2-D, or wrong in a way that
    ``split_image`` reports); a cube with several planes is a ValueError.
    ``stacklevel`` is that of the warning (4: the caller of the caller of the
    caller of this function).
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
        stacklevel=stacklevel,
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


def _split_parts(image, name, label=None, stacklevel=4):
    """The parts of an image, nothing copied: (where, data, mask, unit, wcs, uncertainty).

    ``stacklevel`` is that of the warning of `squeeze_plane`, counted from it.
    """
    where = _describe_input(name, image, label)
    image = squeeze_plane(image, where, stacklevel)
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


def _error_map(unc, name, unit, full_shape, box):
    """The uncertainty of an image as a standard deviation in the image's unit (in ``box``)."""
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
    return error


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
    error = None if unc is None else _error_map(unc, name, unit, full_shape, box)
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


def _quantity_psf(psf, name):
    """The PSF setting of a Quantity FWHM: ('angle', FWHM) or ('gaussian', pixels)."""
    if not psf.isscalar:
        raise ValueError(f"{name} (a Gaussian FWHM) must be a scalar, got shape {psf.shape}")
    if psf.unit.physical_type == "angle":
        _check_fwhm(psf.to_value(u.arcsec), psf, name)
        return "angle", psf
    if psf.unit == u.pix:
        fwhm = psf.value
    else:
        raise TypeError(
            f"{name} as a Quantity must be an angle or in pixels (u.pix), got unit {psf.unit!s}"
        )
    return "gaussian", _check_fwhm(fwhm, psf, name)


def _array_psf(psf, name, oversampling):
    """The PSF setting of an array: ('gaussian', FWHM) for a scalar, else ('image', ImagePSF)."""
    from photutils.psf import ImagePSF

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
    check_psf_centred(arr, os_, f"{name} (a PSF image)")
    # photutils' convention: an oversampled image sums to oy * ox
    return "image", ImagePSF(arr * (os_[0] * os_[1] / total), oversampling=os_)


def _psf_spec(psf, name="psf", oversampling=None):
    """The PSF setting checked: ('gaussian', FWHM in pixels or None), ('image', ImagePSF)
    or ('angle', the FWHM as an angle, converted to pixels by `_psf_in_pixels`)."""
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
        return _quantity_psf(psf, name)
    if isinstance(psf, (np.ndarray, list, tuple)):
        return _array_psf(psf, name, oversampling)
    if isinstance(psf, (int, float, np.integer, np.floating)) and not isinstance(psf, bool):
        return "gaussian", _check_fwhm(float(psf), psf, name)
    raise TypeError(
        f"{name} must be a Gaussian FWHM (Quantity angle or pixels, or a number of pixels), a 2-D "
        f"PSF array, a photutils ImagePSF or None, got {type(psf).__name__}"
    )


def _psf_in_pixels(kind, spec, wcs, shape, name="psf"):
    """The checked PSF setting (from `_psf_spec`) on an image of that WCS and shape:
    ('gaussian', FWHM in pixels or None) or ('image', ImagePSF)."""
    if kind != "angle":
        return kind, spec
    if wcs is None:
        raise ValueError(f"{name} given as an angle ({spec}) needs an image with a celestial WCS")
    fwhm = spec.to_value(u.arcsec) / _pixel_scale(wcs, shape, "image")
    return "gaussian", _check_fwhm(fwhm, spec, name)


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
