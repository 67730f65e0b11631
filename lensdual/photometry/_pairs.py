"""The pairs table: PSF photometry of the point-source pairs of two arcs."""

import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.nddata import NDData
from astropy.table import QTable, Table

from .._frames import mean_direction, tangent_to_sky
from .._pairs_table import (
    ARCS,
    PAIR_ID,
    POSITION_COLUMNS,
    SKY_COLUMNS,
    bkg_col,
    flags_col,
    flux_col,
    flux_err_col,
    id_col,
    pos_err_col,
    positions,
    size_col,
    size_snr_col,
    sky_col,
    x_col,
    xy_cols,
    y_col,
)
from .._validation import as_positions
from ..exceptions import LensdualWarning
from ._background import _DEFAULT_BACKGROUND, SURFACE_BRIGHTNESS_BACKGROUNDS
from ._flags import _BAD_FLAGS, describe_flags
from ._inputs import (
    _as_oversampling,
    _as_wcs,
    _describe_input,
    _pixel_to_tangent_errors,
    file_of,
    squeeze_plane,
)
from ._psf import ArcPSFPhotometry

__all__ = ["measure_pairs"]


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
        img = squeeze_plane(img, f"{name}[{band!r}]")
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
    if all(c in cols for c in SKY_COLUMNS):
        sky1, sky2 = (pairs[c] for c in SKY_COLUMNS)
        if not isinstance(sky1, SkyCoord) or not isinstance(sky2, SkyCoord):
            raise TypeError("pairs['sky1'] and pairs['sky2'] must be SkyCoord columns")
        return sky1, sky2
    if all(c in cols for c in POSITION_COLUMNS):
        if reference is None:
            raise ValueError(
                "pairs gives x1, y1, x2, y2: pass reference, the SkyCoord of the origin of "
                "their tangent-plane frame (x towards the west, y towards the north)"
            )
        out = []
        for arc, theta in zip(ARCS, positions(pairs), strict=True):
            p = as_positions(theta, "pairs {}, {}".format(*xy_cols(arc)))
            out.append(tangent_to_sky(p[:, 0], p[:, 1], reference))
        return tuple(out)
    raise ValueError(
        "pairs must have SkyCoord columns sky1 and sky2, or angle columns x1, y1, x2, y2 "
        f"(with reference=...), got columns {cols}"
    )


def _check_bands(bands, images_l1, images_l2):
    """The bands to measure as a list (default: those of ``images_l1``), in both arcs."""
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
    return bands


def _check_pairs_and_reference(pairs, reference):
    """Check that ``pairs`` is a non-empty table and ``reference`` a scalar SkyCoord or None."""
    if not isinstance(pairs, Table):
        raise TypeError(f"pairs must be an astropy Table or QTable, got {type(pairs).__name__}")
    if len(pairs) == 0:
        raise ValueError("pairs has no rows")
    if reference is not None:
        if not isinstance(reference, SkyCoord) or not reference.isscalar:
            raise TypeError(f"reference must be a scalar SkyCoord or None, got {reference!r}")


def _check_units(images_l1, images_l2, bands):
    """Check that the two arcs' images of each band have convertible units (or none)."""
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


def _per_band(value, bands):
    """``{band: value}`` of one value for all bands, or of a dict per band (None if absent)."""
    if isinstance(value, Mapping):
        return {b: value.get(b) for b in bands}
    return dict.fromkeys(bands, value)


def _band_photometries(bands, psf_of, os_of, **settings):
    """One checked `ArcPSFPhotometry` per band, before any image is measured."""
    for band in bands:
        _as_oversampling(os_of[band], f"oversampling of band {band!r}")
    return {
        band: ArcPSFPhotometry(psf_of[band], warn=False, oversampling=os_of[band], **settings)
        for band in bands
    }


def _new_table(pairs):
    """A copy of ``pairs`` with a ``pair_id`` column (1, 2, ... when absent)."""
    out = QTable(pairs, copy=True)
    if PAIR_ID not in out.colnames:
        out.add_column(np.arange(1, len(pairs) + 1), name=PAIR_ID, index=0)
    return out


@dataclass
class _Troubles:
    """What was not measured: per pair the notes and unusable flags, per fit the pairs."""

    ids: np.ndarray  # the pair ids
    notes: list = field(init=False)  # per pair: why something was not measured
    pair_flags: np.ndarray = field(init=False)  # per pair: OR of the unusable flags
    flagged: list = field(default_factory=list)  # per arc and band: the pairs with a bad fit

    def __post_init__(self):
        """Start with no note and no flag."""
        self.notes = [[] for _ in range(len(self.ids))]
        self.pair_flags = np.zeros(len(self.ids), np.int64)

    def record_fits(self, arc, band, flags, bad, src_ids, path):
        """Note the unusable fits (``bad``) of one arc and band."""
        ids = self.ids
        if bad.any():
            self.flagged.append(f"L{arc} {band}: pairs {ids[bad].tolist()[:10]}")
        for i in np.flatnonzero(bad):
            known = src_ids is not None and src_ids[i] is not np.ma.masked
            src = f" (source id {src_ids[i]})" if known else ""
            where = f"L{arc} {band}" + ("" if path is None else f" [{path}]")
            self.notes[i].append(
                f"pair {ids[i]}{src}, {where}: {describe_flags(flags[i], unusable_only=True)}"
            )
            self.pair_flags[i] |= flags[i] & _BAD_FLAGS

    def note(self, rows, text):
        """Note ``"pair <id>: <text>"`` for each pair of ``rows``."""
        for i in rows:
            self.notes[i].append(f"pair {self.ids[i]}: {text}")


class _ArcResult(NamedTuple):
    """One arc's measurement: mean positions and errors (arcsec), per band the fluxes,
    and the offsets of the bands registered onto the first (arcsec)."""

    x: np.ndarray
    y: np.ndarray
    err: np.ndarray
    fluxes: dict  # band -> (flux, flux_err, flags)
    offsets: dict  # band -> (dx, dy, significance, n_sources), bands that were shifted
    sizes: dict  # band -> (size in mas, its significance); empty for point sources
    backgrounds: dict  # band -> the fitted background (image unit / arcsec^2); may be empty


#: A band's median position offset from the first band of its arc is removed
#: (and reported) beyond this many standard errors: a point source has one
#: position in every band, so such an offset is a registration error of the images.
BAND_OFFSET_SIGNIFICANCE = 5.0
#: Fewest sources measured in both bands for a band offset to be estimated.
_MIN_OFFSET_SOURCES = 3


def _band_offset(x0, y0, s0, xb, yb, sb):
    """The median offset of band b from band 0 and its significance; None with too few
    sources measured in both."""
    both = np.isfinite(x0) & np.isfinite(y0) & np.isfinite(xb) & np.isfinite(yb)
    both &= np.isfinite(s0) & np.isfinite(sb)
    if both.sum() < _MIN_OFFSET_SOURCES:
        return None
    dx = np.median(xb[both] - x0[both])
    dy = np.median(yb[both] - y0[both])
    # the standard error of a median: sqrt(pi / 2) times that of the mean
    se = np.sqrt(np.pi / 2) * np.sqrt(np.median(s0[both] ** 2 + sb[both] ** 2) / both.sum())
    return dx, dy, float(np.hypot(dx, dy) / se) if se > 0 else np.inf, int(both.sum())


def _fit_band(phot, img, sky_init, arc, band, reference):
    """PSF photometry of one arc and band: ``(result, flags, bad, x, y, sigma)``, in arcsec."""
    # x, y, sigma: the fitted positions and their errors in the tangent-plane frame about
    # reference, NaN where the fit gave none
    wcs = _as_wcs(img.wcs, f"images_l{arc}[{band!r}].wcs")
    label = _describe_input(f"images_l{arc}[{band!r}] (arc L{arc}, band {band})", img)
    px, py = wcs.world_to_pixel(sky_init)
    px, py = np.atleast_1d(px), np.atleast_1d(py)
    res = phot(img, np.column_stack([px, py]), label=label)
    flags = np.asarray(res["flags"], dtype=np.int64)
    bad = (flags & _BAD_FLAGS) != 0
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
    return res, flags, bad, xb, yb, sig


def _usable_fluxes(res, flags, bad):
    """``(flux, flux_err, flags)`` of one band, NaN where the fit is unusable."""
    flux, flux_err = res["flux"].copy(), res["flux_err"].copy()
    flux[bad] = np.nan  # not measured (pairs-table convention)
    flux_err[bad] = np.nan
    return flux, flux_err, flags


def _measure_arc(arc, images, sky_init, bands, phot_of, reference, troubles, src_ids,
                 with_background=False):
    """Measure all bands of one arc and combine the positions: an `_ArcResult`.

    A band whose median offset from the first band exceeds
    :data:`BAND_OFFSET_SIGNIFICANCE` standard errors is shifted onto it
    before the bands' positions are combined (and the offset reported).
    """
    n = len(troubles.ids)
    sum_w = np.zeros(n)
    sum_x = np.zeros(n)
    sum_y = np.zeros(n)
    fluxes, sizes, backgrounds = {}, {}, {}
    per_band = []
    for band in bands:
        img = images[band]
        res, flags, bad, xb, yb, sig = _fit_band(phot_of[band], img, sky_init, arc, band,
                                                 reference)
        troubles.record_fits(arc, band, flags, bad, src_ids, file_of(img))
        ok = np.isfinite(xb) & np.isfinite(yb) & np.isfinite(sig) & (sig > 0) & ~bad
        per_band.append((np.where(ok, xb, np.nan), np.where(ok, yb, np.nan), sig, ok))
        fluxes[band] = _usable_fluxes(res, flags, bad)
        if with_background:
            backgrounds[band] = _surface_brightness(res, bad, img.wcs, arc, band)
        if "size" in res.colnames:
            sizes[band] = (_size_mas(res, img.wcs, arc, band), np.asarray(res["size_snr"]))
    offsets = {}
    x0, y0, s0, _ = per_band[0]
    for k, band in enumerate(bands):
        xb, yb, sig, ok = per_band[k]
        if k:
            found = _band_offset(x0, y0, s0, xb, yb, sig)
            if found is not None and found[2] > BAND_OFFSET_SIGNIFICANCE:
                offsets[band] = found
                xb, yb = xb - found[0], yb - found[1]
        w = np.where(ok, 1.0 / np.where(ok, sig, 1.0) ** 2, 0.0)
        sum_w += w
        sum_x += np.where(ok, xb, 0.0) * w
        sum_y += np.where(ok, yb, 0.0) * w
    with np.errstate(invalid="ignore", divide="ignore"):
        xm = np.where(sum_w > 0, sum_x / sum_w, np.nan)
        ym = np.where(sum_w > 0, sum_y / sum_w, np.nan)
        err = np.where(sum_w > 0, 1.0 / np.sqrt(sum_w), np.nan)
    troubles.note(np.flatnonzero(sum_w == 0), f"no band measured its L{arc} position (NaN)")
    return _ArcResult(xm, ym, err, fluxes, offsets, sizes, backgrounds)


def _in_image(background):
    """Whether the background strategy fits the light under a source in the image itself
    (a name of :data:`SURFACE_BRIGHTNESS_BACKGROUNDS` or a LocalBackground)."""
    from photutils.background import LocalBackground

    return (isinstance(background, LocalBackground)
            or (isinstance(background, str) and background in SURFACE_BRIGHTNESS_BACKGROUNDS))


def _pixel_area_arcsec2(wcs, arc, band):
    """The pixel area of an image at its reference pixel (arcsec^2)."""
    from astropy.wcs.utils import proj_plane_pixel_area

    wcs = _as_wcs(wcs, f"images_l{arc}[{band!r}].wcs")
    unit = u.Unit(wcs.celestial.world_axis_units[0] or "deg")
    return float(proj_plane_pixel_area(wcs.celestial) * unit.to(u.arcsec) ** 2)


def _per_solid_angle(unit):
    """Whether ``unit`` is already per solid angle (a surface brightness, e.g. MJy/sr)."""
    d = u.Unit(unit).decompose()
    return any(b == u.rad and p == -2 for b, p in zip(d.bases, d.powers, strict=True))


def _surface_brightness(res, bad, wcs, arc, band):
    """The fitted background at each source as a surface brightness per arcsec^2 (an
    image unit per pixel divided by the pixel area; one per solid angle converted),
    NaN where the fit is unusable."""
    bkg = u.Quantity(res["bkg"], copy=True)
    if _per_solid_angle(bkg.unit):
        unit = bkg.unit
        flux = u.Unit(1.0)
        for base, power in zip(unit.bases, unit.powers, strict=True):
            if base.physical_type not in ("angle", "solid angle"):
                flux = flux * base**power
        bkg = bkg.to(flux * unit.scale / u.arcsec**2)
    else:
        bkg = bkg / (_pixel_area_arcsec2(wcs, arc, band) * u.arcsec**2)
    bkg[bad] = np.nan
    return bkg


def _size_mas(res, wcs, arc, band):
    """The fitted sizes of a resolved fit (pixels) in mas, with the image's mean pixel
    scale."""
    from astropy.wcs.utils import proj_plane_pixel_scales

    wcs = _as_wcs(wcs, f"images_l{arc}[{band!r}].wcs")
    scale = float(np.sqrt(np.prod(proj_plane_pixel_scales(wcs.celestial))))
    unit = wcs.celestial.world_axis_units[0] or "deg"
    return np.asarray(res["size"], dtype=np.float64) * (scale * u.Unit(unit)).to_value(u.mas)


def _offset_warning(per_arc, bands):
    """The text of the band-registration warning; None where no band was shifted."""
    parts = []
    for arc in ARCS:
        for band, (dx, dy, z, n) in per_arc[arc].offsets.items():
            parts.append(f"on arc L{arc}, band {band} is offset from {bands[0]} by (dx, dy) = "
                         f"({1e3 * dx:.1f}, {1e3 * dy:.1f}) mas (median of {n} sources, "
                         f"{z:.0f} standard errors)")
    if not parts:
        return None
    return ("; ".join(parts) + ". A point source has one position in every band: the images' "
            "WCS disagree (registration), or the bands' PSF images are not centred alike "
            "(by less than the half pixel that refuses a PSF image). The offsets were removed "
            "before the bands' positions were combined (meta['photometry']['band_offsets']); "
            "register the images, or recentre the PSF images, to be sure.")


def _write_positions(out, per_arc, reference):
    """Set the mean positions, their errors and sky positions of both arcs in ``out``."""
    for arc in ARCS:
        xm, ym, err = per_arc[arc][:3]
        out[x_col(arc)] = xm * u.arcsec
        out[y_col(arc)] = ym * u.arcsec
        out[pos_err_col(arc)] = err * u.arcsec
        out[sky_col(arc)] = tangent_to_sky(xm, ym, reference)


def _write_fluxes(out, per_arc, bands):
    """Set the fluxes, errors and flags of each band in ``out`` (L2 in the unit of L1)."""
    for band in bands:
        f1, e1, g1 = per_arc["1"].fluxes[band]
        f2, e2, g2 = per_arc["2"].fluxes[band]
        if isinstance(f1, u.Quantity):
            f2, e2 = f2.to(f1.unit), e2.to(f1.unit)
        out[flux_col(1, band)] = f1
        out[flux_col(2, band)] = f2
        out[flux_err_col(1, band)] = e1
        out[flux_err_col(2, band)] = e2
        out[flags_col(1, band)] = g1
        out[flags_col(2, band)] = g2
        for arc in ARCS:
            if band in per_arc[arc].sizes:
                size, snr = per_arc[arc].sizes[band]
                out[size_col(arc, band)] = size * u.mas
                out[size_snr_col(arc, band)] = snr
        if band in per_arc["1"].backgrounds:
            b1, b2 = per_arc["1"].backgrounds[band], per_arc["2"].backgrounds[band]
            out[bkg_col(1, band)] = b1
            out[bkg_col(2, band)] = b2.to(b1.unit)


def _measured(per_arc, bands, troubles):
    """Per pair: both positions known and some band with both fluxes (notes the others)."""
    n = len(troubles.ids)
    positions_ok = np.ones(n, bool)
    for arc in ("1", "2"):
        positions_ok &= np.isfinite(per_arc[arc].x) & np.isfinite(per_arc[arc].y)
    some_band = np.zeros(n, bool)
    for band in bands:
        f1, f2 = per_arc["1"].fluxes[band][0], per_arc["2"].fluxes[band][0]
        some_band |= np.isfinite(np.asarray(getattr(f1, "value", f1))) & np.isfinite(
            np.asarray(getattr(f2, "value", f2))
        )
    troubles.note(np.flatnonzero(positions_ok & ~some_band),
                  "no band has both fluxes (no flux ratio)")
    return positions_ok & some_band


def _trouble_warning(troubles, measured, notes):
    """The text of measure_pairs' warning about unmeasured pairs; None when all is clean."""
    troubled = np.flatnonzero([bool(v) for v in troubles.notes])
    if not troubled.size:
        return None
    ids = troubles.ids
    dropped = np.flatnonzero(~measured)
    text = (
        f"measure_pairs: {troubled.size} of {len(ids)} pair(s) not fully measured (NaN where "
        f"unusable; see the photometry_flags, photometry_note and flags columns)"
    )
    if troubles.flagged:
        text += "; flagged fits: " + ", ".join(troubles.flagged)
    if dropped.size:
        text += f"; pairs {ids[dropped].tolist()} cannot be tested (measured = False)"
    text += ". Why: " + "; ".join(notes[i] for i in troubled[:30])
    return text


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
    source_model="point",
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
    source_model : {"point", "resolved"}, optional
        Passed to :func:`psf_photometry`: ``"point"`` (default) fits every
        source as the PSF; ``"resolved"`` refits it as the PSF convolved
        with an elliptical Gaussian of free size, on each image alone, so
        that slightly resolved sources (star clusters stretched differently
        on the two arcs) keep their flux ratio (see
        :ref:`photometry-resolved`), and adds the size columns below.
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
        * with a ``background`` fitted in the image itself (one of
          :data:`SURFACE_BRIGHTNESS_BACKGROUNDS`: ``"ridge"``, the default,
          the polynomials and ``"local"``, or a LocalBackground), per band
          ``bkg1_<band>``, ``bkg2_<band>``: that background at the fitted
          position per arcsec\ :sup:`2` (the image unit per pixel over the
          pixel area; an image unit per solid angle, e.g. MJy/sr, converted;
          L2 in the unit of L1), NaN where the fit is unusable. Lensing
          conserves surface brightness, so the lensed arc's light is the same
          under both images of a pair;
          light that is not lensed (a patch under one image, a member's or
          the intracluster light) is not;
        * with ``source_model="resolved"``, per band ``size1_<band>``,
          ``size2_<band>`` (mas): the standard deviation of the fitted
          Gaussian along its major axis (before the PSF; negative: the
          signed square root of a negative fitted variance, as noise gives
          a point source), and ``size_snr1_<band>``, ``size_snr2_<band>``:
          that variance over its error (above 3 the source is resolved).
          A source too resolved to be used (over 10 % of its fitted flux
          outside the fitting box) has the unusable flag ``TOO_RESOLVED``
          (NaN flux, and the pair's ``photometry_note`` says so);
        * ``photometry_flags``: per pair, the sum of the unusable flags
          (:data:`UNUSABLE_FLAGS`) of all its fits; 0 when all were usable;
        * ``photometry_note``: per pair, what was not measured and why, in
          words, each entry naming the pair id, the source id (columns
          ``id1``/``id2`` when present), the arc, the band and the file
          (``meta['FILENAME']`` of the image); "" when clean;
        * ``measured``: True when both positions are known and at least one
          band has both fluxes (the pair can be tested).

        ``meta['bands']`` lists the bands, ``meta['reference']`` is the
        frame origin (SkyCoord), ``meta['photometry']`` the settings and
        ``band_offsets``: per arc, the offset (dx, dy) in mas of every band
        that was registered onto the arc's first band before the positions
        were combined (a band whose median offset over the sources measured
        in both exceeds :data:`BAND_OFFSET_SIGNIFICANCE` standard errors; a
        point source has one position in every band, so such an offset is a
        registration error of the images, and it is warned about).
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

    Examples
    --------
    One pair in one band: two 31 x 31 cut-outs (0.03 arcsec pixels) of arcs
    that lie 1.8 arcsec apart in declination, each with one point source:

    >>> import numpy as np
    >>> from scipy.special import erf
    >>> from astropy.nddata import CCDData
    >>> from astropy.table import QTable
    >>> from astropy.wcs import WCS
    >>> from lensdual.photometry import measure_pairs
    >>> def cutout(x, y, flux, dec):
    ...     k = np.sqrt(2) * 2.5 / 2.3548  # a Gaussian PSF of FWHM 2.5 pixels
    ...     px = np.diff(erf((np.arange(32) - 0.5 - x) / k)) / 2
    ...     py = np.diff(erf((np.arange(32) - 0.5 - y) / k)) / 2
    ...     wcs = WCS(naxis=2)
    ...     wcs.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    ...     wcs.wcs.crval, wcs.wcs.crpix = [110.8, dec], [16, 16]
    ...     wcs.wcs.cdelt = [-0.03 / 3600, 0.03 / 3600]
    ...     return CCDData(10.0 + flux * np.outer(py, px), unit="adu", wcs=wcs)
    >>> l1 = {"F150W": cutout(15.4, 14.8, 600.0, -73.45)}
    >>> l2 = {"F150W": cutout(14.7, 15.3, 500.0, -73.4505)}
    >>> pairs = QTable({"sky1": l1["F150W"].wcs.pixel_to_world([15], [15]),
    ...                 "sky2": l2["F150W"].wcs.pixel_to_world([15], [15])})
    >>> out = measure_pairs(l1, l2, pairs, psf=2.5, background="constant")
    >>> out.meta["bands"], out["measured"].tolist()
    (['F150W'], [True])
    >>> out["flux1_F150W"].value.round(1).tolist(), out["flux2_F150W"].value.round(1).tolist()
    ([600.0], [500.0])
    >>> np.round((out["y1"] - out["y2"]).to_value("arcsec"), 3).tolist()
    [1.785]
    """
    images_l1 = _check_images(images_l1, "images_l1")
    images_l2 = _check_images(images_l2, "images_l2")
    bands = _check_bands(bands, images_l1, images_l2)
    _check_pairs_and_reference(pairs, reference)
    _check_units(images_l1, images_l2, bands)
    psf_of = _per_band(psf, bands)
    os_of = _per_band(oversampling, bands)
    phot_of = _band_photometries(
        bands,
        psf_of,
        os_of,
        background=background,
        fit_shape=fit_shape,
        xy_bounds=xy_bounds,
        neighbour_passes=neighbour_passes,
        check_psf=check_psf,
        source_model=source_model,
    )

    sky1_init, sky2_init = _initial_sky(pairs, reference)
    if reference is None:
        reference = mean_direction(sky1_init, sky2_init)

    out = _new_table(pairs)
    troubles = _Troubles(np.asarray(out[PAIR_ID]))
    per_arc = {}
    for arc, images, sky_init in (("1", images_l1, sky1_init), ("2", images_l2, sky2_init)):
        # a masked id (a partner that was never detected) is named by its pair only
        src_ids = np.ma.asarray(out[id_col(arc)]) if id_col(arc) in out.colnames else None
        per_arc[arc] = _measure_arc(
            arc, images, sky_init, bands, phot_of, reference, troubles, src_ids,
            with_background=_in_image(background),
        )

    _write_positions(out, per_arc, reference)
    _write_fluxes(out, per_arc, bands)
    offset_text = _offset_warning(per_arc, list(bands))
    if offset_text:
        warnings.warn(offset_text, LensdualWarning, stacklevel=2)
    measured = _measured(per_arc, bands, troubles)
    out["photometry_flags"] = troubles.pair_flags
    out["photometry_note"] = ["; ".join(v) for v in troubles.notes]
    out["measured"] = measured
    out.meta["bands"] = list(bands)
    out.meta["reference"] = reference
    out.meta["photometry"] = {
        "background": background if isinstance(background, str) else repr(background),
        "fit_shape": fit_shape,
        "xy_bounds": xy_bounds,
        "neighbour_passes": neighbour_passes,
        "source_model": source_model,
        "psf": {b: repr(p) for b, p in psf_of.items()},
        "oversampling": {b: os_of[b] for b in bands},
        "frame": "gnomonic about reference, x west, y north, arcsec",
        "band_offsets": {f"L{arc}": {band: [float(1e3 * dx), float(1e3 * dy)]
                                     for band, (dx, dy, _, _) in per_arc[arc].offsets.items()}
                         for arc in ARCS},
    }
    text = _trouble_warning(troubles, measured, out["photometry_note"])
    if text is not None:
        warnings.warn(text, LensdualWarning, stacklevel=2)
    return out
