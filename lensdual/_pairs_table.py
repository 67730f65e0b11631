"""The pairs table: its column names, its bands and its check.

Every step of lensdual reads and writes one `~astropy.table.QTable`, the
*pairs table* (``docs/pairs.rst``): one row per point-source pair on arcs L1
and L2, ``meta['bands']`` listing the photometric bands. This module is the
one place that spells its columns and checks one; every module that builds or
reads a pairs table goes through it.

Arcs are named ``1`` and ``2`` (``"1"``, ``"2"``, ``"L1"`` and ``"L2"`` are
accepted too), bands by their names::

    >>> from lensdual._pairs_table import flux_col, flux_err_col, pos_err_col
    >>> flux_col(1, "F150W"), flux_err_col("L2", "F150W"), pos_err_col(2)
    ('flux1_F150W', 'flux_err2_F150W', 'pos_err2')
"""

import warnings

import numpy as np
from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import QTable, Table

from .exceptions import MissingValuesWarning, SameImageError

__all__ = [
    "ARCS",
    "ID_COLUMNS",
    "NEEDS",
    "PAIR_ID",
    "POSITION_COLUMNS",
    "POS_ERR_COLUMNS",
    "SAME_IMAGE_SEPARATION",
    "SKY_COLUMNS",
    "arc_xy",
    "band_flux_cols",
    "band_fluxes",
    "check_distinct_arcs",
    "check_pairs_table",
    "flags_col",
    "flux_col",
    "flux_err_col",
    "table_sigma_pos",
    "id_col",
    "mu_flux_col",
    "mu_flux_err_col",
    "pair_bands",
    "pos_err_col",
    "positions",
    "sky_col",
    "x_col",
    "xy_cols",
    "y_col",
]

#: The two arcs, as they appear in column names.
ARCS = ("1", "2")


def _arc(arc):
    """``"1"`` or ``"2"`` from 1, 2, "1", "2", "L1" or "L2"."""
    key = str(arc)
    key = key[1:] if key in ("L1", "L2") else key
    if key not in ARCS:
        raise ValueError(f"arc must be 1 or 2 (or 'L1', 'L2'), got {arc!r}")
    return key


def id_col(arc):
    """Catalogue id of the source on ``arc``: ``id1`` or ``id2``."""
    return f"id{_arc(arc)}"


def x_col(arc):
    """Tangent-plane x (West) on ``arc``: ``x1`` or ``x2``."""
    return f"x{_arc(arc)}"


def y_col(arc):
    """Tangent-plane y (North) on ``arc``: ``y1`` or ``y2``."""
    return f"y{_arc(arc)}"


def xy_cols(arc):
    """``(x_col(arc), y_col(arc))``."""
    return x_col(arc), y_col(arc)


def sky_col(arc):
    """Optional SkyCoord position on ``arc``: ``sky1`` or ``sky2``."""
    return f"sky{_arc(arc)}"


def pos_err_col(arc):
    """1-sigma position error on ``arc`` (angle): ``pos_err1`` or ``pos_err2``."""
    return f"pos_err{_arc(arc)}"


def flux_col(arc, band):
    """PSF flux on ``arc`` in ``band``: ``flux1_<band>`` or ``flux2_<band>``."""
    return f"flux{_arc(arc)}_{band}"


def flux_err_col(arc, band):
    """Its 1-sigma error: ``flux_err1_<band>`` or ``flux_err2_<band>``."""
    return f"flux_err{_arc(arc)}_{band}"


def flags_col(arc, band):
    """Photometry flags of :func:`~lensdual.photometry.measure_pairs`:
    ``flags1_<band>`` or ``flags2_<band>``."""
    return f"flags{_arc(arc)}_{band}"


def size_col(arc, band):
    """Fitted source size of ``measure_pairs(source_model="resolved")`` (mas):
    ``size1_<band>`` or ``size2_<band>``."""
    return f"size{_arc(arc)}_{band}"


def size_snr_col(arc, band):
    """Significance of that size: ``size_snr1_<band>`` or ``size_snr2_<band>``."""
    return f"size_snr{_arc(arc)}_{band}"


def bkg_col(arc, band):
    """The photometry's fitted background under the source on ``arc`` (surface
    brightness): ``bkg1_<band>`` or ``bkg2_<band>``."""
    return f"bkg{_arc(arc)}_{band}"


def band_flux_cols(band):
    """``(flux1_<band>, flux2_<band>, flux_err1_<band>, flux_err2_<band>)``."""
    return (flux_col(1, band), flux_col(2, band), flux_err_col(1, band), flux_err_col(2, band))


def mu_flux_col(band):
    """Flux ratio of one band, appended by :func:`~lensdual.duality.check_duality`."""
    return f"mu_flux_{band}"


def mu_flux_err_col(band):
    """Its 1-sigma error, appended by :func:`~lensdual.duality.check_duality`."""
    return f"mu_flux_err_{band}"


#: Integer pair id, stable through the pipeline (from 1).
PAIR_ID = "pair_id"
#: Catalogue ids of the two images of a pair (optional).
ID_COLUMNS = (id_col(1), id_col(2))
#: Position columns every pairs table needs (arcsec or any angle unit).
POSITION_COLUMNS = (*xy_cols(1), *xy_cols(2))
#: Optional SkyCoord positions.
SKY_COLUMNS = (sky_col(1), sky_col(2))
#: Optional 1-sigma position errors (angles).
POS_ERR_COLUMNS = (pos_err_col(1), pos_err_col(2))

_FLUX_PREFIX = flux_col(1, "")


def pair_bands(pairs):
    """Bands of a pairs table: ``meta['bands']``, else those with ``flux1_<band>`` columns.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        A pairs table (see :ref:`pairs-table` in the docs).

    Returns
    -------
    bands : list of str

    Raises
    ------
    ValueError
        The table names no band.

    Examples
    --------
    >>> from astropy.table import QTable
    >>> from lensdual.duality import pair_bands
    >>> pair_bands(QTable({"flux1_F150W": [1.0], "flux2_F150W": [2.0]}))
    ['F150W']
    """
    bands = pairs.meta.get("bands")
    if bands is None:
        bands = [name[len(_FLUX_PREFIX):] for name in pairs.colnames
                 if name.startswith(_FLUX_PREFIX)]
    elif isinstance(bands, str):
        bands = [bands]
    bands = list(bands)
    if not bands:
        raise ValueError(
            "the pairs table names no bands: set meta['bands'] or add flux1_<band>, "
            "flux2_<band>, flux_err1_<band> and flux_err2_<band> columns"
        )
    return bands


def arc_xy(pairs, arc):
    """(N, 2) float array of the positions on ``arc`` in arcsec.

    No check beyond the unit conversion: see :func:`positions` for a checked read.
    """
    x, y = xy_cols(arc)
    return np.column_stack([pairs[x].to_value(u.arcsec), pairs[y].to_value(u.arcsec)])


def masked_rows(col):
    """The rows where ``col`` (a MaskedColumn or Masked Quantity) is masked.

    Parameters
    ----------
    col : column-like
        A table column.

    Returns
    -------
    rows : `~numpy.ndarray` of int
        The masked rows (empty for an unmasked column).
    """
    mask = getattr(col, "mask", None)
    if mask is None or isinstance(col, SkyCoord):
        return np.empty(0, dtype=int)
    return np.flatnonzero(np.asarray(mask, dtype=bool).reshape(len(col), -1).any(axis=1))


def _angle_column(pairs, name):
    """A column as an angle Quantity, or TypeError naming it; ValueError where
    it is masked (a position cannot be missing)."""
    col = pairs[name]
    rows = masked_rows(col)
    if rows.size:
        raise ValueError(f"pairs column {name!r} has masked (missing) values at row(s) "
                         f"{rows.tolist()}; a pair needs both positions: remove those pairs "
                         "or fill in their positions")
    unit = None if isinstance(col, SkyCoord) else getattr(col, "unit", None)
    if unit is None or u.Unit(unit).physical_type != "angle":
        raise TypeError(f"pairs column {name!r} must have angular units (e.g. arcsec), got {unit}")
    return u.Quantity(col, copy=False)


def positions(pairs):
    """The positions ``theta1``, ``theta2``: two (N, 2) Quantities in arcsec.

    Raises ValueError naming the missing position columns, TypeError naming a
    column without angular units.
    """
    missing = [c for c in POSITION_COLUMNS if c not in pairs.colnames]
    if missing:
        raise ValueError(f"pairs table lacks the position column(s) {missing}")
    out = [_angle_column(pairs, c).to(u.arcsec) for c in POSITION_COLUMNS]
    theta1 = np.column_stack([out[0].value, out[1].value]) * u.arcsec
    theta2 = np.column_stack([out[2].value, out[3].value]) * u.arcsec
    return theta1, theta2


def _missing_as_nan(names, cols, values, band):
    """Masked entries of a band's flux columns become NaN ("not measured"), with a
    warning naming the columns and rows."""
    masked = []
    for i, (name, col) in enumerate(zip(names, cols, strict=True)):
        rows = masked_rows(col)
        if rows.size:
            values[i] = np.array(values[i], dtype=np.float64)  # never write into the input
            values[i][rows] = np.nan
            masked.append(f"{name} at row(s) {rows.tolist()}")
    if masked:
        warnings.warn(f"band {band!r}: masked entries are missing values, read as not "
                      f"measured (NaN): {'; '.join(masked)}", MissingValuesWarning,
                      stacklevel=4)


def _magnitudes_as_fluxes(names, cols):
    """Flux columns in AB magnitudes become flux densities (nJy), and errors in
    magnitudes flux errors (``sigma_F = F ln(10) / 2.5 sigma_m``); magnitudes
    without a photometric system are refused, naming the column."""
    units = [getattr(c, "unit", None) for c in cols]
    if not any(isinstance(un, u.MagUnit) or un == u.mag for un in units):
        return cols
    out = list(cols)
    for i in (0, 1):
        if units[i] == u.mag:
            raise ValueError(f"{names[i]} is in magnitudes without a photometric system "
                             "(mag): give AB magnitudes (astropy.units.ABmag) or fluxes")
        if isinstance(units[i], u.MagUnit):
            try:
                out[i] = u.Quantity(cols[i].to(u.nJy))
            except u.UnitConversionError:
                raise ValueError(f"{names[i]} is in {units[i]}, which lensdual cannot convert "
                                 "to a flux density: give AB magnitudes or fluxes") from None
    for i in (2, 3):
        if isinstance(units[i], u.MagUnit):
            raise ValueError(f"{names[i]} is in {units[i]}: a magnitude error is a difference "
                             "of magnitudes (astropy.units.mag), or give a flux error")
        if units[i] == u.mag:
            if not isinstance(units[i - 2], u.MagUnit):
                raise ValueError(f"{names[i]} is in magnitudes but {names[i - 2]} is not: give "
                                 "both in magnitudes or both as fluxes")
            out[i] = out[i - 2] * (np.log(10.0) / 2.5) * cols[i].value
    return out


def band_fluxes(pairs, band):
    """Return flux1, flux2, err1, err2 of one band as float arrays in one unit.

    The four columns of :func:`band_flux_cols` must exist, share one unit (or
    all have none), the fluxes be positive and their errors finite and
    positive where the flux is finite (a NaN flux means "not measured").
    Fluxes in AB magnitudes are converted to flux densities, and errors in
    magnitudes to flux errors.
    Raises ValueError naming the offending column.
    """
    names = band_flux_cols(band)
    missing = [n for n in names if n not in pairs.colnames]
    if missing:
        raise ValueError(f"pairs table lacks the column(s) {missing} of band {band!r}")
    cols = _magnitudes_as_fluxes(names, [pairs[n] for n in names])
    units = [c.unit if isinstance(c, u.Quantity) else None for c in cols]
    ref = units[0]
    values = []
    for name, col, unit in zip(names, cols, units, strict=True):
        if (unit is None) != (ref is None):
            raise ValueError(
                f"flux units of band {band!r} do not match: {names[0]} has unit {ref}, "
                f"{name} has unit {unit}"
            )
        if unit is None:
            values.append(np.asarray(col, dtype=np.float64))
        else:
            try:
                values.append(np.asarray(col.to_value(ref), dtype=np.float64))
            except u.UnitConversionError as exc:
                raise ValueError(
                    f"flux units of band {band!r} do not match: {names[0]} has unit {ref}, "
                    f"{name} has unit {unit}"
                ) from exc
    _missing_as_nan(names, cols, values, band)
    f1, f2, e1, e2 = values
    for name, f in zip(names[:2], (f1, f2), strict=True):
        bad = np.isfinite(f) & (f <= 0)
        if bad.any():
            raise ValueError(
                f"{name} must be positive for a flux ratio; non-positive at row(s) "
                f"{np.flatnonzero(bad).tolist()}"
            )
    for name, f, e in zip(names[2:], (f1, f2), (e1, e2), strict=True):
        # a NaN flux means "not measured": its error may be NaN too
        bad = np.isfinite(f) & ~(np.isfinite(e) & (e > 0))
        if bad.any():
            raise ValueError(
                f"{name} must be finite and positive; bad at row(s) "
                f"{np.flatnonzero(bad).tolist()} (a NaN flux, not measured, may have a NaN "
                "error)"
            )
    return f1, f2, e1, e2


def repeated_pair_ids(values):
    """The ``pair_id`` values that occur more than once (sorted), and their rows.

    Parameters
    ----------
    values : array-like
        The ``pair_id`` column.

    Returns
    -------
    repeated : list
        The repeated values.
    rows : list of int
        The rows that hold them.
    """
    values = np.asarray(values)
    uniq, counts = np.unique(values, return_counts=True)
    repeated = uniq[counts > 1]
    rows = np.flatnonzero(np.isin(values, repeated))
    return repeated.tolist(), rows.tolist()


def check_unique_pair_ids(pairs, name="pairs table"):
    """Raise ValueError when the ``pair_id`` column of ``pairs`` repeats a value."""
    if PAIR_ID not in pairs.colnames:
        return
    repeated, rows = repeated_pair_ids(pairs[PAIR_ID])
    if repeated:
        raise ValueError(f"{name}: pair_id must identify one pair, but {repeated} occur more "
                         f"than once (rows {rows}); renumber the pairs or drop the duplicates")


#: Pairs whose two images are closer than this on the sky are the same image.
SAME_IMAGE_SEPARATION = 1.0 * u.mas


def check_distinct_arcs(pairs):
    """Raise `~lensdual.exceptions.SameImageError` when arcs L1 and L2 are one image.

    They are when every pair with both positions known (``x1, y1, x2, y2``)
    has its two images within :data:`SAME_IMAGE_SEPARATION` of each other: an
    identity map with zero residuals, from the same files (or copies of
    them) given for both arcs or the L1 positions copied into the L2
    columns. Every size magnification and flux ratio would be 1 by
    construction. The pipeline (on the pairing, before any photometry) and
    :func:`~lensdual.duality.check_duality` apply this one rule.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        A pairs table with the position columns (angles, one common frame).
    """
    theta1, theta2 = positions(pairs)
    sep = np.hypot(*(theta1 - theta2).to_value(u.mas).T)
    known = np.isfinite(sep)
    if known.any() and np.all(sep[known] < SAME_IMAGE_SEPARATION.to_value(u.mas)):
        raise SameImageError(
            f"arcs L1 and L2 are the same image: all {int(known.sum())} pairs with both "
            f"positions have their two images within {SAME_IMAGE_SEPARATION:g} of each other "
            "(an identity map: the same files, copies of them, or the L1 positions given "
            "for L2?). The two arcs must be two different images of the source; no test of "
            "duality is possible here: every size magnification and flux ratio would be 1 "
            "by construction")


def _check_ids(pairs):
    missing = [c for c in ID_COLUMNS if c not in pairs.colnames]
    if missing:
        raise ValueError(f"pairs table lacks the id column(s) {missing}")


def _check_sky(pairs):
    missing = [c for c in SKY_COLUMNS if c not in pairs.colnames]
    if missing:
        raise ValueError(f"pairs table lacks the sky column(s) {missing}")
    for c in SKY_COLUMNS:
        if not isinstance(pairs[c], SkyCoord):
            raise TypeError(f"pairs column {c!r} must be a SkyCoord, got "
                            f"{type(pairs[c]).__name__}")


def _check_position_errors(pairs):
    missing = [c for c in POS_ERR_COLUMNS if c not in pairs.colnames]
    if missing:
        raise ValueError(f"pairs table lacks the position-error column(s) {missing}")
    for c in POS_ERR_COLUMNS:
        err = _angle_column(pairs, c).to_value(u.arcsec)
        bad = ~np.isnan(err) & ~(np.isfinite(err) & (err > 0))
        if bad.any():
            raise ValueError(f"{c} must be positive (NaN: not measured); bad at row(s) "
                             f"{np.flatnonzero(bad).tolist()}")


#: The parts :func:`check_pairs_table` can be asked for.
NEEDS = ("positions", "fluxes", "position_errors", "ids", "sky")


def check_pairs_table(pairs, need=("positions",), *, bands=None):
    """Check that ``pairs`` is a pairs table with the parts ``need``.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        The table to check (not modified).
    need : str or sequence of str
        Parts of :data:`NEEDS`: ``"positions"`` (``x1``, ``y1``, ``x2``,
        ``y2`` with angular units), ``"fluxes"`` (for every band,
        ``flux1_<band>``, ``flux2_<band>``, ``flux_err1_<band>``,
        ``flux_err2_<band>`` in one unit, positive fluxes, positive errors where
        the flux is measured), ``"position_errors"`` (``pos_err1``, ``pos_err2``,
        angles, positive or NaN), ``"ids"`` (``id1``, ``id2``) and ``"sky"``
        (SkyCoord ``sky1``, ``sky2``).
    bands : sequence of str, optional
        Bands checked by ``"fluxes"``; default :func:`pair_bands`.

    Raises
    ------
    TypeError
        ``pairs`` is not a table, a position is not an angle, a sky column not a
        SkyCoord.
    ValueError
        A missing column (named), a repeated ``pair_id``, flux units that do
        not match, non-positive fluxes or errors, no band, an unknown part in
        ``need``.

    Examples
    --------
    >>> import astropy.units as u
    >>> from astropy.table import QTable
    >>> from lensdual._pairs_table import check_pairs_table
    >>> pairs = QTable({"x1": [0.0] * u.arcsec, "y1": [0.0] * u.arcsec,
    ...                 "x2": [1.0] * u.arcsec})
    >>> check_pairs_table(pairs)
    Traceback (most recent call last):
    ...
    ValueError: pairs table lacks the position column(s) ['y2']
    """
    if not isinstance(pairs, Table):
        raise TypeError(
            "pairs must be an astropy Table or QTable (the pairs table), got "
            f"{type(pairs).__name__}"
        )
    need = (need,) if isinstance(need, str) else tuple(need)
    unknown = [n for n in need if n not in NEEDS]
    if unknown:
        raise ValueError(f"need has unknown part(s) {unknown}; choose from {list(NEEDS)}")
    tab = pairs if isinstance(pairs, QTable) else QTable(pairs, copy=False)
    check_unique_pair_ids(tab)
    if "positions" in need:
        positions(tab)
    if "position_errors" in need:
        _check_position_errors(tab)
    if "ids" in need:
        _check_ids(tab)
    if "sky" in need:
        _check_sky(tab)
    if "fluxes" in need:
        for band in pair_bands(tab) if bands is None else ([bands] if isinstance(bands, str)
                                                           else list(bands)):
            band_fluxes(tab, band)

def table_sigma_pos(tab):
    """The position error of a duality result: its test's scalar ``sigma_pos``, else the
    median of its ``pos_err1``, ``pos_err2``; None when it has neither."""
    duality = tab.meta.get("duality")
    used = duality.get("sigma_pos") if isinstance(duality, dict) else None
    if isinstance(used, u.Quantity) and used.isscalar and used.unit.physical_type == "angle":
        return used.to(u.arcsec)
    if all(c in tab.colnames for c in POS_ERR_COLUMNS):
        errs = np.concatenate([u.Quantity(tab[c], u.arcsec).value for c in POS_ERR_COLUMNS])
        errs = errs[np.isfinite(errs) & (errs > 0)]
        if errs.size:
            return float(np.median(errs)) * u.arcsec
    return None
