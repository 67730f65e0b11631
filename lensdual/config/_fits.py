"""What the configuration reads in FITS files: HDUs, WCS and pixel grids, units (BUNIT,
PIXAR_SR), error and weight maps and their sky noise, PSF images; and the reading of an
image as `~astropy.nddata.CCDData`."""

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.nddata import CCDData, Cutout2D, StdDevUncertainty
from astropy.nddata.utils import NoOverlapError
from astropy.wcs import WCS, FITSFixedWarning

from ..exceptions import HDUError, MissingValuesWarning
from ._values import _suggest

_MIN_PSF_SIZE = 5
#: Bands of an arc share one pixel grid when their WCSs agree to this many pixels.
_GRID_TOLERANCE = 0.01
#: An error map disagreeing with the image's own sky noise by more than this
#: factor (either way) draws a warning.
_NOISE_FACTOR = 3.0


def _hdu_label(hdu):
    return f"HDU {hdu}" if isinstance(hdu, int) else f"HDU {hdu!r}"


def _hdu_names(hdul):
    return ", ".join(f"{i} {h.name!r}" if h.name else str(i) for i, h in enumerate(hdul))


def _is_2d_image(hdu):
    return bool(hdu.is_image) and len(hdu.shape) == 2


def _find_hdu(hdul, hdu, path):
    """Index of the requested HDU of ``hdul`` (the first 2-D image for None)."""
    if hdu is None:
        for i, h in enumerate(hdul):
            if _is_2d_image(h):
                return i
        raise HDUError(f"{path} has no HDU with 2-D image data (HDUs: {_hdu_names(hdul)})"
                        + _cube_hint(hdul), on_hdu_key=False)
    if isinstance(hdu, int):
        if hdu >= len(hdul):
            n = len(hdul)
            raise HDUError(f"{_hdu_label(hdu)} does not exist in {path} "
                            f"({n} HDU{'' if n == 1 else 's'}: {_hdu_names(hdul)})",
                            on_hdu_key=True)
        index = hdu
    else:
        try:
            index = hdul.index_of(hdu)
        except KeyError:
            hint = _suggest(hdu.upper(), [h.name for h in hdul if h.name])
            raise HDUError(f"{_hdu_label(hdu)} does not exist in {path}{hint} "
                            f"(HDUs: {_hdu_names(hdul)})", on_hdu_key=True) from None
    h = hdul[index]
    if not _is_2d_image(h):
        if not h.is_image:
            what = "a table"
        else:
            what = f"{len(h.shape)}-D data" if h.shape else "no data"
        raise HDUError(f"{_hdu_label(hdu)} of {path} has no 2-D image data (it has {what})"
                        + _cube_hint(hdul), on_hdu_key=True)
    return index


def _cube_hint(hdul):
    """Words on the image HDUs that are cubes (their shapes, and what to do)."""
    cubes = [(i, h.shape) for i, h in enumerate(hdul) if h.is_image and len(h.shape or ()) > 2]
    if not cubes:
        return ""
    listed = ", ".join(f"HDU {i} has shape {shape}" for i, shape in cubes)
    single = any(all(n == 1 for n in shape[:-2]) for _, shape in cubes)
    return (f"; {listed}" + (": a cube of one plane; write that plane as a 2-D image (e.g. "
                            "data[0] with the celestial WCS, wcs.celestial)" if single else
                            ": a cube; write the plane of the band as a 2-D image"))


def _header_wcs(header, hdul):
    """The WCS of ``header`` (lookup tables from ``hdul``), without FITSFixedWarning noise."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FITSFixedWarning)
        return WCS(header, hdul)


def _cutout(shape, wcs, center, size):
    """`~astropy.nddata.Cutout2D` of an array of ``shape`` (no data is read)."""
    dummy = np.broadcast_to(np.int8(0), shape)
    return Cutout2D(dummy, center, size, wcs=wcs, mode="trim", copy=False)


def _psf_oversampling(path, hdu):
    """The oversampling a PSF file declares (WebbPSF / STPSF ``OVERSAMP``; 1 for their
    detector-sampled ``DET_SAMP`` extension), or None."""
    try:
        with fits.open(path) as hdul:
            index = _find_hdu(hdul, hdu, path)
            header = hdul[index].header
            if str(header.get("EXTNAME", "")).upper().startswith("DET_"):
                return None
            value = header.get("OVERSAMP", hdul[0].header.get("OVERSAMP"))
    except Exception:  # unreadable: reported elsewhere
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value > 1 and \
            float(value).is_integer():
        return int(value)
    return None


@dataclass
class _ImageInfo:
    """What the validation learnt about an image HDU."""

    shape: tuple
    wcs: WCS | None
    bunit: str | None
    unit: u.UnitBase | None = None
    path: Path | None = None


def _inspect_fits(path, hdu, *, celestial=False):
    """Open ``path`` lazily and check the HDU: an `_ImageInfo`; `HDUError` if unusable.

    With ``celestial``, the HDU must have a valid celestial WCS (then in ``wcs``).
    """
    try:
        hdul = fits.open(path)
    except Exception as exc:  # any failure means the file is unusable
        raise HDUError(f"{path} is not a readable FITS file ({exc})", on_hdu_key=False) from None
    with hdul:
        try:
            index = _find_hdu(hdul, hdu, path)
            header = hdul[index].header
            shape = tuple(hdul[index].shape)
        except HDUError:
            raise
        except Exception as exc:
            raise HDUError(f"{path} is not a readable FITS file ({exc})",
                            on_hdu_key=False) from None
        wcs = None
        if celestial:
            where = f"{_hdu_label(index)} of {path}"
            try:
                wcs = _header_wcs(header, hdul)
            except Exception as exc:
                raise HDUError(f"the WCS in the header of {where} is invalid ({exc})",
                                on_hdu_key=False) from None
            if not wcs.has_celestial:
                raise HDUError(f"the header of {where} has no celestial WCS (RA/Dec axes), "
                                "which is needed to pair the arcs on the sky", on_hdu_key=False)
            wcs = wcs.celestial
        bunit = header.get("BUNIT")
        bunit = bunit.strip() if isinstance(bunit, str) else None
    return _ImageInfo(shape=shape, wcs=wcs, bunit=bunit)


def _grid_mismatch(ref, info):
    """How the pixel grid of ``info`` differs from that of ``ref`` (two `_ImageInfo` with
    a WCS), or None when they agree to `_GRID_TOLERANCE` pixels."""
    if info.shape != ref.shape:
        return f"shape {info.shape} against {ref.shape}"
    ny, nx = ref.shape[-2:]
    corners = np.array([[0, 0], [nx - 1, 0], [0, ny - 1], [nx - 1, ny - 1],
                        [(nx - 1) / 2, (ny - 1) / 2]], dtype=float)
    world = ref.wcs.pixel_to_world(corners[:, 0], corners[:, 1])
    px, py = info.wcs.world_to_pixel(world)
    off = float(np.max(np.hypot(px - corners[:, 0], py - corners[:, 1])))
    if not off > _GRID_TOLERANCE:
        return None
    return f"its WCS puts the same sky up to {off:.3g} pixels elsewhere"


def _read_psf(path, hdu):
    """The PSF image, normalised to unit sum; ValueError if unusable."""
    with fits.open(path, memmap=False) as hdul:
        index = _find_hdu(hdul, hdu, path)
        arr = np.array(hdul[index].data, dtype=np.float64)
    ny, nx = arr.shape
    if ny % 2 == 0 or nx % 2 == 0 or min(ny, nx) < _MIN_PSF_SIZE:
        raise ValueError(f"the PSF image in {path} must have an odd shape of at least "
                         f"{_MIN_PSF_SIZE}x{_MIN_PSF_SIZE} pixels (centred on its central "
                         f"pixel), got {ny}x{nx}")
    if not np.isfinite(arr).all():
        raise ValueError(f"the PSF image in {path} contains NaN or infinite values")
    total = arr.sum()
    if not total > 0:
        raise ValueError(f"the PSF image in {path} must have a positive sum, got {total}")
    return arr / total


_STRUCTURAL = re.compile(
    r"^(SIMPLE|XTENSION|BITPIX|NAXIS\d*|EXTEND|PCOUNT|GCOUNT|BZERO|BSCALE|BLANK|BUNIT|"
    r"CHECKSUM|DATASUM|WCSAXES|(CTYPE|CRPIX|CRVAL|CDELT|CUNIT|CROTA)\d+|(CD|PC|PV|PS)\d+_\d+|"
    r"(A|B|AP|BP)_(ORDER|DMAX|\d+_\d+)|LONPOLE|LATPOLE)$"
)


def _meta(header):
    """The header without the keywords of the data layout, unit and WCS transformation.

    Those are in the CCDData's attributes; kept in ``meta`` they would go stale
    with a cutout (``CRPIX``) or clash with the WCS written by `CCDData.write`.
    """
    meta = header.copy()
    for key in list(meta):
        if key and _STRUCTURAL.match(key):
            meta.remove(key, ignore_missing=True, remove_all=True)
    return meta


def _product_map(path):
    """("error", "ERR") or ("weight", "WHT") when ``path`` is a pipeline product with
    such an extension beside a SCI extension; else None."""
    try:
        with fits.open(path) as hdul:
            names = {h.name.upper() for h in hdul}
    except Exception:  # unreadable files are reported by inspect_fits
        return None
    if "SCI" not in names:
        return None
    if "ERR" in names:
        return ("error", "ERR")
    if "WHT" in names:
        return ("weight", "WHT")
    return None


def _pixel_area(header, hdul):
    """PIXAR_SR of a JWST product (the image's header, else the primary's), or None."""
    for h in (header, hdul[0].header):
        value = h.get("PIXAR_SR")
        if isinstance(value, (int, float)) and value > 0:
            return float(value)
    return None


def _exposure_weighted(spec):
    """True when the weight map is a drizzled product's WHT made with exposure-time
    (not inverse-variance) weights: HST's D###WTSC / FINAL_WHT keywords say 'EXP'."""
    if str(spec.weight_hdu).upper() != "WHT":
        return False
    with fits.open(spec.weight) as hdul:
        for h in hdul:
            for key, value in h.header.items():
                if (key.endswith("WTSC") or key in ("FINALWHT", "FINAL_WHT_TYPE")) and \
                        isinstance(value, str) and value.strip().upper() == "EXP":
                    return True
    return False


def _sky_noise(data, err, mask):
    """``(scatter, quoted)``: the robust (3-sigma clipped) scatter of the image's sky
    pixels and the median error the map quotes there (NaN without sky pixels)."""
    from astropy.stats import sigma_clipped_stats

    good = ~mask & np.isfinite(err)
    _, median, std = sigma_clipped_stats(data[good], sigma=3.0, maxiters=5)
    sky = good & (np.abs(data - median) < 3.0 * std)
    return float(std), (float(np.median(err[sky])) if sky.any() else np.nan)


def _sky_scale(data, err, mask, where):
    """The factor that makes ``err`` match the image's own sky noise (with a warning)."""
    from ..exceptions import LensdualWarning

    std, quoted = _sky_noise(data, err, mask)
    factor = std / quoted if np.isfinite(quoted) else 1.0
    warnings.warn(f"{where}: an exposure-time weight (not inverse variance); errors are "
                  f"1/sqrt(WHT) scaled by {factor:.3g} to the sky noise of the image",
                  LensdualWarning, stacklevel=3)
    return factor


def _read_map(path, hdu, slices, unit=None):
    """A map's pixels; with ``unit``, converted from the map's own BUNIT to it."""
    with fits.open(path) as hdul:
        index = _find_hdu(hdul, hdu, path)
        data = np.array(hdul[index].section[slices], dtype=np.float64)
        bunit = hdul[index].header.get("BUNIT")
    if unit is not None and isinstance(bunit, str) and bunit.strip():
        data *= u.Unit(bunit.strip(), parse_strict="raise").to(unit)
    return data


def _check_noise(data, err, mask, where):
    """Warn when the error map disagrees with the image's own sky noise by > _NOISE_FACTOR."""
    from ..exceptions import LensdualWarning

    if np.count_nonzero(~mask & np.isfinite(err)) < 100:
        return
    std, quoted = _sky_noise(data, err, mask)
    if not (np.isfinite(quoted) and std > 0 and quoted > 0):
        return
    ratio = quoted / std
    if not 1.0 / _NOISE_FACTOR <= ratio <= _NOISE_FACTOR:
        warnings.warn(
            f"{where}: the error map quotes a median sky error of {quoted:.3g}, but the sky "
            f"pixels of the image scatter by {std:.3g} (robust, 3-sigma clipped): "
            f"{ratio:.3g} times the measured noise. Fluxes, positions and every SNR inherit "
            "this error: check the error map's units and scaling", LensdualWarning,
            stacklevel=3)


def _warn_bad_errors(bad, where):
    """Warn when pixels with data have an error that is not finite and positive."""
    n_bad = int(np.count_nonzero(bad))
    if n_bad:
        warnings.warn(f"{where}: {n_bad} pixel(s) with data have an error that is zero, "
                      "negative or not finite; they are masked, and a source on them is "
                      "not measured", MissingValuesWarning, stacklevel=3)


def _read_image(spec, arc, psf):
    """One CCDData; ValueError / OSError on unusable files."""
    with fits.open(spec.image) as hdul:
        index = _find_hdu(hdul, spec.hdu, spec.image)
        hdu = hdul[index]
        header = hdu.header.copy()
        full_wcs = _header_wcs(header, hdul)
        if not full_wcs.has_celestial:
            raise ValueError(f"the header of {spec.image} has no celestial WCS")
        wcs = full_wcs.celestial
        shape = tuple(hdu.shape)
        slices = (slice(None), slice(None))
        if arc.cutout_center is not None:
            try:
                cut = _cutout(shape, wcs, arc.cutout_center, arc.cutout_size)
            except NoOverlapError:
                raise ValueError(f"the cutout of arc {arc.name} does not overlap "
                                 f"{spec.image}") from None
            slices, wcs = cut.slices_original, cut.wcs
        data = np.array(hdu.section[slices], dtype=np.float64)
        pixar = _pixel_area(header, hdul)
    unit = spec.unit
    if unit is None:
        bunit = header.get("BUNIT")
        bunit = bunit.strip() if isinstance(bunit, str) else ""
        unit = u.Unit(bunit, parse_strict="raise") if bunit else u.dimensionless_unscaled
    map_unit = unit
    scale = 1.0
    if pixar is not None and unit.is_equivalent(u.MJy / u.sr):
        # surface brightness (JWST MJy/sr) to flux per pixel (nJy) with the pixel area
        scale = (unit * u.sr).to(u.nJy) * pixar
        unit = u.nJy
        data *= scale
    mask = ~np.isfinite(data)
    uncertainty = None
    where = f"arc {arc.name}, {spec.image.name}"
    if spec.error is not None:
        err = _read_map(spec.error, spec.error_hdu, slices, unit=map_unit) * scale
        bad_error = ~(np.isfinite(err) & (err > 0))
        _warn_bad_errors(bad_error & ~mask, f"{where} (error map {spec.error.name})")
        mask |= bad_error
        _check_noise(data, err, mask, f"{where} (error map {spec.error.name})")
        uncertainty = StdDevUncertainty(err)
    elif spec.weight is not None:
        weight = _read_map(spec.weight, spec.weight_hdu, slices) / scale**2
        good = np.isfinite(weight) & (weight > 0)
        err = np.full(weight.shape, np.nan)
        err[good] = 1.0 / np.sqrt(weight[good])
        mask |= ~good
        if _exposure_weighted(spec):  # scaled to the sky noise: nothing left to check
            err *= _sky_scale(data, err, mask, f"{where} (weight map {spec.weight.name})")
        else:
            _check_noise(data, err, mask, f"{where} (weight map {spec.weight.name})")
        uncertainty = StdDevUncertainty(err)
    meta = _meta(header)
    meta["FILENAME"] = str(spec.image)
    return CCDData(data, unit=unit, wcs=wcs, uncertainty=uncertainty, mask=mask,
                   meta=meta, psf=None if psf is None else psf.copy())

