"""The per-pair test of geometrical duality (paper Sect. 3.3 and 5.1.1).

For a point-source pair imaged on arcs L1 and L2, lensing conserves surface
brightness, so the flux ratio ``mu_flux = F(L1) / F(L2)`` must equal the size
magnification ``mu_size = |det J|`` estimated from the constellation's
geometry. :func:`check_duality` measures both, with errors, and flags the pairs
where they disagree.
"""

import warnings

import numpy as np
from astropy import units as u
from astropy.table import QTable, Table
from scipy.special import chdtrc

from ._validation import as_real
from .estimators import size_magnification
from .exceptions import LensdualWarning

__all__ = ["POSITION_COLUMNS", "SNR_DEFINITIONS", "check_duality", "pair_bands", "flux_ratios"]

#: Position columns every pairs table needs (arcsec or any angle unit).
POSITION_COLUMNS = ("x1", "y1", "x2", "y2")

#: Definitions of the duality signal-to-noise ratio, see :func:`check_duality`.
SNR_DEFINITIONS = ("log", "paper")

_FLUX_KINDS = ("flux1", "flux2", "flux_err1", "flux_err2")


def _as_qtable(pairs):
    if not isinstance(pairs, Table):
        raise TypeError(
            "pairs must be an astropy Table or QTable (the pairs table), got "
            f"{type(pairs).__name__}"
        )
    return QTable(pairs, copy=True)


def pair_bands(pairs):
    """Bands of a pairs table: ``meta['bands']``, else those with ``flux1_<band>`` columns.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        A pairs table (see :ref:`pairs-table` in the docs).

    Returns
    -------
    bands : list of str
    """
    bands = pairs.meta.get("bands")
    if bands is None:
        bands = [name[len("flux1_"):] for name in pairs.colnames if name.startswith("flux1_")]
    elif isinstance(bands, str):
        bands = [bands]
    bands = list(bands)
    if not bands:
        raise ValueError(
            "the pairs table names no bands: set meta['bands'] or add flux1_<band>, "
            "flux2_<band>, flux_err1_<band> and flux_err2_<band> columns"
        )
    return bands


def _positions(tab):
    missing = [c for c in POSITION_COLUMNS if c not in tab.colnames]
    if missing:
        raise ValueError(f"pairs table lacks the position column(s) {missing}")
    out = []
    for c in POSITION_COLUMNS:
        col = tab[c]
        if not isinstance(col, u.Quantity) or col.unit.physical_type != "angle":
            unit = getattr(col, "unit", None)
            raise TypeError(f"pairs column {c!r} must have angular units (e.g. arcsec), got {unit}")
        out.append(col.to(u.arcsec))
    theta1 = np.column_stack([out[0].value, out[1].value]) * u.arcsec
    theta2 = np.column_stack([out[2].value, out[3].value]) * u.arcsec
    return theta1, theta2


def _band_fluxes(tab, band):
    """Return flux1, flux2, err1, err2 of one band as float arrays in one unit."""
    names = [f"{kind}_{band}" for kind in _FLUX_KINDS]
    missing = [n for n in names if n not in tab.colnames]
    if missing:
        raise ValueError(f"pairs table lacks the column(s) {missing} of band {band!r}")
    cols = [tab[n] for n in names]
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
    f1, f2, e1, e2 = values
    for name, f in zip(names[:2], (f1, f2), strict=True):
        bad = np.isfinite(f) & (f <= 0)
        if bad.any():
            raise ValueError(
                f"{name} must be positive for a flux ratio; non-positive at row(s) "
                f"{np.flatnonzero(bad).tolist()}"
            )
    for name, e in zip(names[2:], (e1, e2), strict=True):
        bad = ~(np.isfinite(e) & (e > 0))
        if bad.any():
            raise ValueError(
                f"{name} must be finite and positive; bad at row(s) {np.flatnonzero(bad).tolist()}"
            )
    return f1, f2, e1, e2


def flux_ratios(pairs):
    """Flux ratios ``F(L1)/F(L2)`` per band and combined over bands.

    Per band, the ratio's logarithmic error is
    ``sqrt((e1/F1)**2 + (e2/F2)**2)`` (first-order propagation). The bands are
    combined by the inverse-variance weighted mean of ``ln mu_flux``; a
    lensed pair has the same ratio in every band, so the chi-square of the
    band ratios about that mean (``chromatic_chi2``, ``nbands - 1`` degrees
    of freedom) tests the pairing. A NaN flux means "not measured in that
    band": the band is left out for that pair.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        Pairs table with ``flux1_<band>``, ``flux2_<band>``, ``flux_err1_<band>``
        and ``flux_err2_<band>`` for every band of :func:`pair_bands`.

    Returns
    -------
    table : `~astropy.table.QTable`
        Columns ``mu_flux_<band>``, ``mu_flux_err_<band>`` per band, then
        ``mu_flux``, ``mu_flux_err``, ``ln_mu_flux_err``, ``chromatic_chi2``,
        ``chromatic_dof`` and ``chromatic_pvalue``.
    """
    tab = _as_qtable(pairs)
    bands = pair_bands(tab)
    n = len(tab)
    out = QTable()
    ln_mu = np.full((len(bands), n), np.nan)
    ln_err = np.full((len(bands), n), np.nan)
    for i, band in enumerate(bands):
        f1, f2, e1, e2 = _band_fluxes(tab, band)
        mu = f1 / f2
        s = np.hypot(e1 / f1, e2 / f2)
        out[f"mu_flux_{band}"] = mu
        out[f"mu_flux_err_{band}"] = mu * s
        ln_mu[i] = np.log(mu)
        ln_err[i] = s
    valid = np.isfinite(ln_mu)
    w = np.where(valid, 1.0 / np.where(valid, ln_err, 1.0) ** 2, 0.0)
    wsum = w.sum(axis=0)
    nvalid = valid.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(wsum > 0, (w * np.where(valid, ln_mu, 0.0)).sum(axis=0) / wsum, np.nan)
        sig = np.where(wsum > 0, 1.0 / np.sqrt(wsum), np.nan)
    chi2 = (w * np.where(valid, ln_mu - mean, 0.0) ** 2).sum(axis=0)
    dof = np.maximum(nvalid - 1, 0)
    chi2 = np.where(nvalid > 0, chi2, np.nan)
    pvalue = np.where(dof > 0, chdtrc(np.maximum(dof, 1), chi2), np.nan)
    if (nvalid == 0).any():
        warnings.warn(
            f"no band has a finite flux ratio for row(s) {np.flatnonzero(nvalid == 0).tolist()};"
            " their mu_flux is NaN",
            LensdualWarning,
            stacklevel=2,
        )
    out["mu_flux"] = np.exp(mean)
    out["mu_flux_err"] = np.exp(mean) * sig
    out["ln_mu_flux_err"] = sig
    out["chromatic_chi2"] = chi2
    out["chromatic_dof"] = dof
    out["chromatic_pvalue"] = pvalue
    return out


def check_duality(
    pairs,
    method="quad",
    *,
    sigma_pos=0.06 * u.arcsec,
    n_bootstrap=1000,
    snr_threshold=3.0,
    seed=None,
    snr_definition="log",
    weight_power=2,
    min_angle=5 * u.deg,
):
    r"""Test geometrical duality, ``mu_flux = mu_size``, for every pair.

    Parameters
    ----------
    pairs : `~astropy.table.Table` or `~astropy.table.QTable`
        The pairs table (:ref:`pairs-table`): positions ``x1, y1, x2, y2``
        (angles, one common frame) and, for every band, ``flux1_<band>``,
        ``flux2_<band>``, ``flux_err1_<band>``, ``flux_err2_<band>``. The
        bands are ``meta['bands']`` or, without it, every ``flux1_<band>``.
        It is not modified.
    method : {"quad", "2v", "quad2"}
        Size-magnification estimator, see
        :func:`~lensdual.estimators.relative_jacobian`.
    sigma_pos : `~astropy.units.Quantity`
        Positional uncertainty for the bootstrap of ``mu_size`` (default
        0.06 arcsec), see :func:`~lensdual.estimators.size_magnification`.
    n_bootstrap : int
        Bootstrap realisations (default 1000).
    snr_threshold : float
        A pair is ``anomalous`` when its SNR exceeds this (default 3).
    seed : int, `numpy.random.Generator` or None
        Seed of the bootstrap.
    snr_definition : {"log", "paper"}
        Which SNR sets ``anomalous``. ``"log"`` (default):
        :math:`|\ln R| / \sqrt{\sigma_{\ln F}^2 + \sigma_{\ln S}^2}` with
        :math:`R` = ``duality_ratio``, :math:`\sigma_{\ln F}` the error of
        :math:`\ln \mu_{\rm flux}` and :math:`\sigma_{\ln S}` half the 16-84 %
        width of the bootstrap distribution of :math:`\ln \mu_{\rm size}`;
        both errors count, and the statistic is symmetric between a brighter
        L1 and a brighter L2 image. ``"paper"``: the paper's Sect. 5.2.3
        definition, :math:`|R - 1| / (R\,\sigma_{\mu_{\rm size}}/\mu_{\rm size})`,
        size error only. Both are always returned (``snr`` and ``snr_paper``).
    weight_power, min_angle
        Estimator settings, see :func:`~lensdual.estimators.relative_jacobian`.

    Returns
    -------
    result : `~astropy.table.QTable`
        A copy of ``pairs`` with these columns appended (replaced if present):
        ``jacobian``, ``parity``, ``mu_size``, ``mu_size_err``,
        ``mu_size_p16``, ``mu_size_p84``, ``mu_flux_<band>``,
        ``mu_flux_err_<band>``, ``mu_flux``, ``mu_flux_err``,
        ``chromatic_chi2``, ``chromatic_dof``, ``chromatic_pvalue``,
        ``duality_ratio`` (``mu_flux / mu_size``), ``duality_ratio_err``,
        ``snr``, ``snr_paper`` and ``anomalous``. A ``pair_id`` column
        (from 1) is added when missing. ``meta`` records the settings.

    Raises
    ------
    TypeError
        ``pairs`` is not a table, or positions lack angular units.
    ValueError
        Missing columns, non-positive fluxes or flux errors, mismatched flux
        units, and the bad inputs listed in
        :func:`~lensdual.estimators.relative_jacobian`.
    """
    tab = _as_qtable(pairs)
    if not isinstance(snr_definition, str) or snr_definition not in SNR_DEFINITIONS:
        raise ValueError(
            f"snr_definition must be one of {list(SNR_DEFINITIONS)}, got {snr_definition!r}"
        )
    snr_threshold = as_real(snr_threshold, "snr_threshold", minimum=0.0)
    bands = pair_bands(tab)
    theta1, theta2 = _positions(tab)
    flux = flux_ratios(tab)  # validates the flux columns before the bootstrap runs
    size = size_magnification(
        theta1,
        theta2,
        method,
        sigma_pos=sigma_pos,
        n_bootstrap=n_bootstrap,
        seed=seed,
        weight_power=weight_power,
        min_angle=min_angle,
    )

    if "pair_id" not in tab.colnames:
        tab.add_column(np.arange(1, len(tab) + 1), name="pair_id", index=0)
    for name in ("jacobian", "parity", "mu_size", "mu_size_err", "mu_size_p16", "mu_size_p84"):
        tab[name] = size[name]
    for name in flux.colnames:
        if name != "ln_mu_flux_err":
            tab[name] = flux[name]

    mu_size = np.asarray(size["mu_size"], dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.asarray(flux["mu_flux"], dtype=float) / mu_size
        ln_size_err = 0.5 * (
            np.log(np.asarray(size["mu_size_p84"])) - np.log(np.asarray(size["mu_size_p16"]))
        )
        ln_flux_err = np.asarray(flux["ln_mu_flux_err"], dtype=float)
        ln_total = np.hypot(ln_flux_err, ln_size_err)
        snr = np.abs(np.log(ratio)) / ln_total
        rel_size_err = np.asarray(size["mu_size_err"]) / mu_size
        snr_paper = np.abs(ratio - 1.0) / (ratio * rel_size_err)
    tab["duality_ratio"] = ratio
    tab["duality_ratio_err"] = ratio * ln_total
    tab["snr"] = snr
    tab["snr_paper"] = snr_paper
    chosen = snr if snr_definition == "log" else snr_paper
    tab["anomalous"] = np.isfinite(chosen) & (chosen > snr_threshold)

    tab.meta["bands"] = bands
    tab.meta["duality"] = {
        "method": method,
        "sigma_pos": size.meta["sigma_pos"],
        "n_bootstrap": size.meta["n_bootstrap"],
        "snr_threshold": snr_threshold,
        "snr_definition": snr_definition,
    }
    return tab
