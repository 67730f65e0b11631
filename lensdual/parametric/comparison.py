"""One call from a duality-checked pairs table to the parametric comparison.

:func:`parametric_comparison` puts the pairs in the frame of a Lenstool model
and/or fits a lenstronomy model to their positions, and returns the table of
:func:`~lensdual.parametric.compare_with_parametric` with the figure of
:func:`~lensdual.parametric.plot_parametric_comparison` (what ``lensdual run
--parametric`` writes).
"""

import os

from astropy import units as u
from astropy.coordinates import SkyCoord
from astropy.table import QTable, Table

from .._frames import tangent_xy
from .._pairs_table import POSITION_COLUMNS, table_sigma_pos
from .._validation import as_real
from ..duality import DEFAULT_SNR_THRESHOLD
from ..visualization._parametric import plot_parametric_comparison
from ._frame import frame_reference, in_lenstool_frame, sky_positions, with_positions
from .fitting import DEFAULT_MODEL, compare_with_parametric, fit_parametric_lens
from .lenstool import LenstoolModel, read_lenstool

__all__ = ["parametric_comparison"]

_POSITIONS = POSITION_COLUMNS






def _check_options(pairs, *, fit, lenstool, z_source, reference, centre, fit_kwargs):
    """Check the types of :func:`parametric_comparison`'s options; return ``z_source``."""
    if not isinstance(pairs, Table):
        raise TypeError("pairs must be an astropy Table (check_duality output), got "
                        f"{type(pairs).__name__}")
    if not isinstance(fit, bool):
        raise TypeError(f"fit must be True or False, got {fit!r}")
    if lenstool is None and not fit:
        raise ValueError("nothing to compare: give lenstool=... (a Lenstool best.par) and/or "
                         "fit=True (a lenstronomy fit)")
    if z_source is None:
        raise ValueError("z_source is required")
    zs = as_real(z_source, "z_source")
    for name, value in (("reference", reference), ("centre", centre)):
        if value is not None and not (isinstance(value, SkyCoord) and value.isscalar):
            raise TypeError(f"{name} must be a scalar SkyCoord or None, got {value!r}")
    if fit_kwargs is not None and not isinstance(fit_kwargs, dict):
        raise TypeError(f"fit_kwargs must be a dict or None, got {type(fit_kwargs).__name__}")
    return zs


def _duality_table(pairs):
    """``pairs`` as a QTable (no copy), checked for the columns of check_duality."""
    tab = QTable(pairs, copy=False)
    missing = [c for c in ("mu_flux", "mu_flux_err", "mu_size", "mu_size_err")
               if c not in tab.colnames]
    if missing:
        raise ValueError(f"pairs lacks the column(s) {missing}: pass the output of "
                         "check_duality")
    return tab




def _lenstool_model(lenstool, zs):
    """The LenstoolModel of ``lenstool`` (read from a path), checked for ``zs``; or None."""
    if lenstool is None:
        return None
    if isinstance(lenstool, LenstoolModel):
        lt_model = lenstool
    elif isinstance(lenstool, (str, os.PathLike)):
        lt_model = read_lenstool(lenstool)
    else:
        raise TypeError("lenstool must be a path or a LenstoolModel, got "
                        f"{type(lenstool).__name__}")
    lt_model.dls_ds(zs)  # z_source > z_lens, checked before any fitting
    return lt_model


def _needed_sky(tab, reference, *, lt_model, fit, centre):
    """The pairs' ``(sky1, sky2)`` if the Lenstool model or a fit about ``centre`` needs them."""
    need_sky = lt_model is not None or (fit and centre is not None)
    sky = sky_positions(tab, reference) if need_sky else None
    if need_sky and sky is None:
        what = "the Lenstool model's frame" if lt_model is not None else "the frame of centre"
        raise ValueError(f"cannot place the pairs in {what}: the table has no sky1, sky2 "
                         "columns and no reference (pass reference=..., or keep "
                         "meta['reference'] of measure_pairs)")
    return sky




def _fit_frame(tab, sky, centre, lt_tab):
    """``(table, description)``: the pairs in the frame of the fit."""
    if centre is not None:
        frame_tab = with_positions(tab, tangent_xy(sky[0], centre),
                                    tangent_xy(sky[1], centre))
        return frame_tab, (f"tangent plane about RA={centre.icrs.ra.deg:.7f} "
                           f"Dec={centre.icrs.dec.deg:.7f} deg (centre)")
    if lt_tab is not None:
        return lt_tab, "Lenstool model frame"
    return tab, "pairs frame"




def _fit_and_compare(tab, frame_tab, *, model, z_lens, zs, fit_kwargs, snr_threshold,
                     n_samples, seed):
    """Fit the lenstronomy model in ``frame_tab``'s frame: ``(comparison table, meta)``."""
    kwargs = {"seed": seed}
    sigma_pos = table_sigma_pos(tab)
    if sigma_pos is not None:
        kwargs["sigma_pos"] = sigma_pos
    kwargs.update(fit_kwargs or {})
    fitted = fit_parametric_lens(frame_tab, model=model, z_lens=z_lens, z_source=zs,
                                 **kwargs)
    parametric = compare_with_parametric(frame_tab, fitted, snr_threshold=snr_threshold,
                                         n_samples=n_samples, seed=seed)
    meta = {"fit_model": list(fitted.model),
            "sigma_pos": float(fitted.sigma_pos.to_value(u.arcsec)), "chi2": float(fitted.chi2),
            "dof": int(fitted.dof),
            "best_params": {k: float(v) for k, v in fitted.best_params.items()}}
    return parametric, meta


def _add_lenstool_columns(parametric, lt_table):
    """Add the Lenstool model's ``*_model`` columns to the fit's table as ``*_lenstool``."""
    for name in ("mu", "ratio", "snr", "anomalous"):
        src = "mu_model" if name == "mu" else f"{name}_model"
        parametric[f"{name}_lenstool"] = lt_table[src]
    return parametric


def parametric_comparison(pairs, *, lenstool=None, fit=False,
                          model=DEFAULT_MODEL, z_lens=None, z_source=None,
                          reference=None, centre=None, fit_kwargs=None,
                          snr_threshold=DEFAULT_SNR_THRESHOLD,
                          n_samples=300, seed=0):
    r"""Compare the pairs' flux ratios with ``mu_size`` and parametric models, in one call.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        Output of :func:`~lensdual.duality.check_duality`: positions ``x1, y1,
        x2, y2`` (angles) in the tangent-plane frame about ``reference``
        (x west, y north, as :func:`~lensdual.photometry.measure_pairs` writes
        them), optionally the same positions as SkyCoord columns ``sky1``,
        ``sky2`` (used in preference), and the ``mu_flux``, ``mu_size``
        columns with their errors.
    lenstool : str, os.PathLike or `~lensdual.parametric.LenstoolModel`, optional
        A Lenstool model (a ``best.par`` path or a model read by
        :func:`~lensdual.parametric.read_lenstool`). The pairs' sky positions
        are converted into its frame (about its own ``runmode`` reference).
    fit : bool
        Fit a lenstronomy model (``model``) to the pairs' positions with
        :func:`~lensdual.parametric.fit_parametric_lens`.
    model : str or sequence of str
        lenstronomy profiles of the fit (default ``("NFW_ELLIPSE_CSE",
        "SHEAR")``).
    z_lens : float, optional
        Lens redshift of the fit; default: the Lenstool model's.
    z_source : float
        Source redshift (required).
    reference : `~astropy.coordinates.SkyCoord`, optional
        Origin of the pairs' frame; default ``pairs.meta['reference']``.
        Needed when a sky position is needed and the table has no ``sky1``,
        ``sky2``.
    centre : `~astropy.coordinates.SkyCoord`, optional
        Sky position of the lens centre (e.g. the BCG). The fit works in the
        tangent-plane frame about it (x west, y north); without it, in the
        Lenstool model's frame when ``lenstool`` is given, else in the pairs'
        own frame. The default bounds of the fit assume a lens-centred frame.
    fit_kwargs : dict, optional
        More keyword arguments of
        :func:`~lensdual.parametric.fit_parametric_lens` (``fixed_params``,
        ``n_starts``, ``bounds``, ...). ``sigma_pos`` defaults to the one of
        the duality test (``pairs.meta['duality']['sigma_pos']``), ``seed``
        to ``seed``.
    snr_threshold : float
        A pair is anomalous when its SNR exceeds this (default 3).
    n_samples : int
        Parameter draws for ``mu_model_err`` of the fit.
    seed : int, `numpy.random.Generator` or None
        Seed of the fit and of the error draws.

    Returns
    -------
    table : `~astropy.table.QTable`
        :func:`~lensdual.parametric.compare_with_parametric`'s table for the
        fit when ``fit`` is True, else for the Lenstool model. With both, the
        Lenstool model's columns are added as ``mu_lenstool``,
        ``ratio_lenstool``, ``snr_lenstool`` and ``anomalous_lenstool``.
        ``meta['parametric']`` records the settings: ``lenstool`` (path or
        None), ``fit_model`` (list or None), ``z_lens``, ``z_source``,
        ``fit_frame``, and for a fit ``sigma_pos`` (arcsec), ``chi2``, ``dof``
        and ``best_params``.
    figure : `matplotlib.figure.Figure`
        :func:`~lensdual.parametric.plot_parametric_comparison` of the table.

    Raises
    ------
    TypeError
        ``pairs`` not a table, ``lenstool``, ``reference`` or ``centre`` of
        the wrong type, ``fit`` not a bool.
    ValueError
        Nothing to compare (no ``lenstool`` and ``fit=False``), no
        ``z_source``, no ``z_lens`` for a fit without a Lenstool model, no
        sky positions where they are needed, missing duality columns, and
        the errors of :func:`~lensdual.parametric.read_lenstool` and
        :func:`~lensdual.parametric.fit_parametric_lens` -- all before any
        fitting starts.
    """
    zs = _check_options(pairs, fit=fit, lenstool=lenstool, z_source=z_source,
                        reference=reference, centre=centre, fit_kwargs=fit_kwargs)
    tab = _duality_table(pairs)
    reference = frame_reference(tab, reference)
    lt_model = _lenstool_model(lenstool, zs)
    if fit and z_lens is None:
        if lt_model is None:
            raise ValueError("z_lens is required for the fit (or give a Lenstool model)")
        z_lens = lt_model.z_lens
    sky = _needed_sky(tab, reference, lt_model=lt_model, fit=fit, centre=centre)
    lt_tab = None if lt_model is None else in_lenstool_frame(tab, lt_model, sky)

    parametric = None
    meta = {"lenstool": None if lt_model is None else str(lt_model.path),
            "fit_model": None, "z_lens": None if z_lens is None else float(z_lens),
            "z_source": zs, "fit_frame": None}
    if fit:
        frame_tab, meta["fit_frame"] = _fit_frame(tab, sky, centre, lt_tab)
        parametric, fit_meta = _fit_and_compare(
            tab, frame_tab, model=model, z_lens=z_lens, zs=zs, fit_kwargs=fit_kwargs,
            snr_threshold=snr_threshold, n_samples=n_samples, seed=seed)
        meta.update(fit_meta)
    if lt_tab is not None:
        lt_table = compare_with_parametric(lt_tab, lt_model, z_source=zs,
                                           snr_threshold=snr_threshold)
        parametric = (lt_table if parametric is None
                      else _add_lenstool_columns(parametric, lt_table))
    parametric.meta["parametric"] = meta
    ax = plot_parametric_comparison(parametric)
    return parametric, ax.figure
