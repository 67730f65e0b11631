"""The pairing map and the duality figures (paper Figs. 3 and 4) and the flux field."""

import numpy as np

from ._common import _plt

__all__ = ["plot_pairing_map", "plot_duality", "plot_flux_field"]


def plot_pairing_map(pairs, catalog1=None, catalog2=None, *, ax=None, offset=None):
    """The pairing map (paper Fig. 3): both constellations in L2's orientation.

    The L1 positions are flipped (for a map of parity -1) and rotated, not
    scaled, onto the orientation of L2, as in the paper: the rotation (or
    reflection) is the orthogonal factor of the polar decomposition of the
    fitted map from L1 to L2 (``A^-1``, with ``A`` from
    ``pairs.meta['map']``, or fitted to the pairs when it is missing), applied
    about the centroid of the paired L1 points, which is moved onto the
    centroid of the paired L2 points (plus ``offset``). Lines join the pairs;
    the pair ids label the L2 points.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        Output of :func:`~lensdual.pairing.pair_constellations` or
        :func:`~lensdual.pairing.pairs_from_ids`, or any pairs table with
        ``x1``, ``y1``, ``x2``, ``y2`` (at least 3 pairs without a fitted
        map) and ``pair_id``.
    catalog1, catalog2 : `~astropy.table.Table` or `~astropy.units.Quantity`, optional
        The full catalogues: their unpaired points are drawn as open symbols
        (positions read as recorded in ``pairs.meta``, see
        :func:`~lensdual.pairing.pair_constellations`).
    ax : `matplotlib.axes.Axes`, optional
    offset : `~astropy.units.Quantity`, shape (2,), optional
        Shift of the drawn L1 constellation (e.g. to draw it beside L2
        rather than on top of it). Default: none.

    Returns
    -------
    ax : `matplotlib.axes.Axes`
    """
    from astropy import units as u
    from matplotlib.collections import LineCollection

    from ..pairing import catalog_positions, pairs_positions

    x1, x2 = pairs_positions(pairs)
    meta_map = pairs.meta.get("map") or {}
    a_mat = meta_map.get("A")
    if a_mat is None:
        if len(x1) < 3:
            raise ValueError("pairs has no fitted map (meta['map']) and fewer than 3 pairs")
        design = np.column_stack([x2, np.ones(len(x2))])
        a_mat = np.linalg.lstsq(design, x1, rcond=None)[0][:2].T
    a_mat = np.asarray(a_mat, dtype=float)
    u_mat, _, vt = np.linalg.svd(np.linalg.inv(a_mat))
    rot = u_mat @ vt  # orthogonal, det = parity of the map
    parity = int(np.sign(np.linalg.det(rot)))
    shift = np.zeros(2) if offset is None else u.Quantity(offset, u.arcsec).value
    c1, c2 = x1.mean(axis=0), x2.mean(axis=0)

    def to_l2(x):
        return (x - c1) @ rot.T + c2 + shift

    if ax is None:
        ax = _plt().subplots(figsize=(5, 5))[1]
    meta = pairs.meta
    for cat, name, colour, marker, transform in (
        (catalog2, "catalog2", "tab:blue", "o", None),
        (catalog1, "catalog1", "tab:orange", "s", to_l2),
    ):
        if cat is None:
            continue
        xy = catalog_positions(cat, name, meta.get("position_columns", ("x", "y")),
                                meta.get("reference"))
        if transform is not None:
            xy = transform(xy)
        ax.scatter(xy[:, 0], xy[:, 1], s=30, facecolors="none", edgecolors=colour,
                   marker=marker, lw=0.8, zorder=2)
    y1 = to_l2(x1)
    ax.add_collection(LineCollection(np.stack([y1, x2], axis=1), colors="0.5", lw=0.8,
                                     zorder=1, label="pairs"))
    ax.scatter(x2[:, 0], x2[:, 1], s=30, color="tab:blue", marker="o", zorder=3, label="L2")
    what = "flipped and rotated" if parity < 0 else "rotated"
    ax.scatter(y1[:, 0], y1[:, 1], s=30, color="tab:orange", marker="s", zorder=3,
               label=f"L1 ({what})")
    ids = pairs["pair_id"] if "pair_id" in pairs.colnames else np.arange(1, len(x1) + 1)
    for pid, (x, y) in zip(np.asarray(ids), x2, strict=True):
        ax.annotate(str(pid), (x, y), xytext=(3, 3), textcoords="offset points",
                    fontsize="x-small", zorder=4)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x [arcsec] (L2 frame)")
    ax.set_ylabel("y [arcsec] (L2 frame)")
    ax.legend(fontsize="small")
    return ax


_BAND_MARKERS = ("o", "s", "D", "^", "v", "P")


def plot_duality(result, *, bands=None, ax=None, annotate=True, title=None):
    r"""Flux magnification against size magnification (paper Fig. 4).

    Every pair is drawn once per band, at (``mu_size``, ``mu_flux_<band>``)
    on logarithmic axes with its error bars (``mu_size_p16`` to
    ``mu_size_p84``, or ``mu_size_err``; ``mu_flux_err_<band>``), labelled by
    its ``pair_id``. The solid line is geometrical duality, mu_flux =
    mu_size; pairs flagged ``anomalous`` are drawn in red.

    Parameters
    ----------
    result : `~astropy.table.Table`
        Output of :func:`~lensdual.duality.check_duality`.
    bands : sequence of str, optional
        Bands to draw; default ``result.meta['bands']`` (or every
        ``mu_flux_<band>`` column).
    ax : `matplotlib.axes.Axes`, optional
    annotate : bool
        Write the pair ids beside the points.
    title : str, optional

    Returns
    -------
    ax : `matplotlib.axes.Axes`
    """
    from .._pairs_table import mu_flux_col, mu_flux_err_col

    missing = [c for c in ("mu_size", "mu_size_err", "pair_id") if c not in result.colnames]
    if missing:
        raise ValueError(f"result lacks the columns {missing}: pass the output of "
                         "lensdual.duality.check_duality")
    if bands is None:
        bands = result.meta.get("bands") or [
            c[len("mu_flux_"):] for c in result.colnames
            if c.startswith("mu_flux_") and not c.startswith("mu_flux_err")]
    bands = list(bands)
    for band in bands:
        if mu_flux_col(band) not in result.colnames:
            raise ValueError(f"result has no column {mu_flux_col(band)!r}")
    if ax is None:
        ax = _plt().subplots(figsize=(5.5, 5))[1]
    size = np.asarray(result["mu_size"], dtype=float)
    if "mu_size_p16" in result.colnames:
        lo = size - np.asarray(result["mu_size_p16"], dtype=float)
        hi = np.asarray(result["mu_size_p84"], dtype=float) - size
    else:
        lo = hi = np.asarray(result["mu_size_err"], dtype=float)
    flagged = (np.asarray(result["anomalous"], dtype=bool) if "anomalous" in result.colnames
               else np.zeros(len(result), dtype=bool))
    ids = np.asarray(result["pair_id"])
    values = [size]
    for k, band in enumerate(bands):
        flux = np.asarray(result[mu_flux_col(band)], dtype=float)
        ferr = (np.asarray(result[mu_flux_err_col(band)], dtype=float)
                if mu_flux_err_col(band) in result.colnames else np.zeros_like(flux))
        values.append(flux)
        marker = _BAND_MARKERS[k % len(_BAND_MARKERS)]
        for sel, colour, label in ((~flagged, f"C{k}", band),
                                   (flagged, "tab:red", f"{band}, anomalous")):
            if not sel.any():
                continue
            ax.errorbar(size[sel], flux[sel], xerr=[lo[sel], hi[sel]], yerr=ferr[sel],
                        fmt=marker, ms=5, color=colour, mfc="none" if k else colour,
                        lw=0.8, capsize=1.5, label=label, zorder=3)
    if annotate:
        stacked = np.vstack(values[1:])
        # the highest band per pair; NaN for a pair with no flux ratio (not measured)
        top = np.where(np.isfinite(stacked).any(axis=0),
                       np.max(np.where(np.isfinite(stacked), stacked, -np.inf), axis=0), np.nan)
        for x, y, i, bad in zip(size, top, ids, flagged, strict=True):
            if np.isfinite(x) and np.isfinite(y):
                ax.annotate(str(i), (x, y), xytext=(3, 4), textcoords="offset points",
                            fontsize=7, color="tab:red" if bad else "0.25")
    finite = np.concatenate(values)
    finite = finite[np.isfinite(finite) & (finite > 0)]
    if finite.size:
        lo_lim, hi_lim = finite.min() / 1.3, finite.max() * 1.3
        ax.plot([lo_lim, hi_lim], [lo_lim, hi_lim], "k-", lw=1, label="duality", zorder=1)
        ax.set_xlim(lo_lim, hi_lim)
        ax.set_ylim(lo_lim, hi_lim)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(r"size magnification $\mu_{\rm size}$")
    ax.set_ylabel(r"flux magnification $\mu_{\rm flux} = F(L1)/F(L2)$")
    ax.legend(fontsize="small", loc="upper left")
    if title:
        ax.set_title(title)
    return ax


def plot_flux_field(result, *, fig=None, title=None):
    r"""The neighbours' flux field across the constellation (the joint test).

    Left: the pairs at their arc-L2 positions, coloured by the measured
    ``ln mu_flux``; a ring around each pair shows, in the same colours, its
    flux-field prediction ``ln_mu_field`` from the other pairs (a pair whose
    ring and centre differ is off its neighbours' field). Right: each pair's
    flux ratio against its prediction, ``ln mu_flux - ln_mu_field`` with the
    total error bar (flux error and prediction error), against the pair id,
    with the geometric ``ln mu_size`` for comparison. Pairs flagged
    ``anomalous`` are outlined (left) and drawn (right) in red.

    Parameters
    ----------
    result : `~astropy.table.Table`
        Output of :func:`~lensdual.duality.check_duality` with
        ``test="joint"``.
    fig : `matplotlib.figure.Figure`, optional
    title : str, optional

    Returns
    -------
    fig : `matplotlib.figure.Figure`

    Raises
    ------
    ValueError
        ``result`` lacks the joint test's columns.
    """
    from astropy import units as u

    need = ("ln_mu_field", "ln_mu_field_err", "mu_flux", "mu_flux_err", "mu_size", "pair_id",
            "x2", "y2", "anomalous")
    missing = [c for c in need if c not in result.colnames]
    if missing:
        raise ValueError(f"result lacks the columns {missing}: pass the output of "
                         "lensdual.duality.check_duality(..., test='joint')")
    plt = _plt()
    if fig is None:
        fig = plt.figure(figsize=(10, 4.4))
    ax_map, ax_res = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.1, 1]})
    x = u.Quantity(result["x2"]).to_value(u.arcsec)
    y = u.Quantity(result["y2"]).to_value(u.arcsec)
    flux = np.asarray(result["mu_flux"], dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ln_flux = np.log(flux)
        ln_flux_err = np.asarray(result["mu_flux_err"], dtype=float) / flux
        ln_size = np.log(np.asarray(result["mu_size"], dtype=float))
    field = np.asarray(result["ln_mu_field"], dtype=float)
    field_err = np.asarray(result["ln_mu_field_err"], dtype=float)
    flagged = np.asarray(result["anomalous"], dtype=bool)
    ids = np.asarray(result["pair_id"])
    finite = np.concatenate([ln_flux[np.isfinite(ln_flux)], field[np.isfinite(field)]])
    vmin, vmax = (finite.min(), finite.max()) if finite.size else (0.0, 1.0)
    predicted = np.isfinite(field)
    ax_map.scatter(x[predicted], y[predicted], c=field[predicted], s=320, cmap="viridis",
                   vmin=vmin, vmax=vmax, edgecolors="none")
    ax_map.scatter(x, y, s=130, facecolors="white", edgecolors="none")
    points = ax_map.scatter(x, y, c=ln_flux, s=60, cmap="viridis", vmin=vmin, vmax=vmax,
                            edgecolors=np.where(flagged, "tab:red", "0.3"),
                            linewidths=np.where(flagged, 2.0, 0.5))
    for xi, yi, i, bad in zip(x, y, ids, flagged, strict=True):
        ax_map.annotate(str(i), (xi, yi), xytext=(6, 6), textcoords="offset points",
                        fontsize=7, color="tab:red" if bad else "0.25")
    fig.colorbar(points, ax=ax_map, label=r"$\ln \mu$ (centre: flux ratio; ring: neighbours)")
    ax_map.set_aspect("equal", adjustable="datalim")
    ax_map.set_xlabel("x2 (arcsec, to the west)")
    ax_map.set_ylabel("y2 (arcsec)")
    ax_map.set_title("arc L2: flux ratios and their flux-field predictions", fontsize="medium")
    order = np.arange(len(result))
    resid = ln_flux - field
    err = np.hypot(ln_flux_err, field_err)
    for sel, colour, label in ((~flagged, "C0", "flux ratio - field"),
                               (flagged, "tab:red", "anomalous")):
        sel = sel & predicted
        if sel.any():
            ax_res.errorbar(order[sel], resid[sel], yerr=err[sel], fmt="o", color=colour,
                            ms=4, capsize=2, label=label)
    ax_res.plot(order, ln_size - field, "x", color="0.5", ms=5,
                label=r"$\ln\mu_{\rm size}$ - field")
    ax_res.axhline(0.0, color="k", lw=1)
    ax_res.set_xticks(order, [str(i) for i in ids], fontsize=6, rotation=90)
    ax_res.set_xlabel("pair")
    ax_res.set_ylabel(r"$\ln \mu - \ln \mu_{\rm field}$")
    ax_res.legend(fontsize="small")
    ax_res.set_title("against the neighbours' prediction", fontsize="medium")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig
