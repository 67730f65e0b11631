"""Figures in the style of the paper (matplotlib).

Every function draws on a given ``ax`` or ``fig`` (or a new one) and returns
it, so that figures can be composed, restyled and saved by the caller.
"""

import numpy as np

__all__ = [
    "plot_true_vs_inferred",
    "plot_estimator_grid",
    "plot_error_histograms",
    "plot_pairing_map",
    "plot_duality",
    "plot_flux_field",
    "ds9_regions",
    "plot_arc_images",
    "plot_abundance_posterior",
]

_COLOURS = {"2v": "tab:orange", "quad": "tab:blue", "quad2": "tab:green"}
_LABELS = {"2v": "2v", "quad": "Quad (QW)", "quad2": "Quad, 2nd order"}


def _plt():
    import matplotlib.pyplot as plt

    return plt


def plot_true_vs_inferred(table, methods=("quad",), *, ax=None, title=None):
    """True vs inferred size magnification (paper Fig. 6).

    Parameters
    ----------
    table : `~astropy.table.QTable`
        Output of :func:`~lensdual.simulation.validation.estimator_errors` or
        :func:`~lensdual.simulation.validation.analog_errors`.
    methods : sequence of str
        Estimators to draw.
    ax : `matplotlib.axes.Axes`, optional
    title : str, optional

    Returns
    -------
    ax : `matplotlib.axes.Axes`
    """
    if ax is None:
        ax = _plt().subplots(figsize=(4.5, 4.5))[1]
    truth = np.asarray(table["mu_true"], dtype=float)
    for method in methods:
        mu = np.asarray(table[f"mu_size_{method}"], dtype=float)
        err = mu / truth - 1
        ax.scatter(truth, mu, s=12, color=_COLOURS.get(method), alpha=0.8,
                   label=f"{_LABELS.get(method, method)}: sd {np.nanstd(err):.1%}")
    lo, hi = np.nanmin(truth), np.nanmax(truth)
    pad = 0.1 * (hi - lo + 1e-9)
    ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], "r--", lw=1, label="duality")
    ax.set_xlabel(r"true $|\mu(L1)/\mu(L2)|$")
    ax.set_ylabel(r"inferred $\mu_{\rm size}$")
    ax.legend(fontsize="small")
    if title:
        ax.set_title(title)
    return ax


def plot_estimator_grid(table, methods=None, *, fig=None):
    """Fractional error per panel of the App. B grid (paper Fig. 10).

    Rows: target magnification ratio (from -1 down); columns: number of
    point sources. x: the pair's true ratio; y: fractional error.

    Parameters
    ----------
    table : `~astropy.table.QTable`
        Output of :func:`~lensdual.simulation.validation.appendix_b_grid`.
    methods : sequence of str, optional
        Default: all methods in the table.
    fig : `matplotlib.figure.Figure`, optional

    Returns
    -------
    fig : `matplotlib.figure.Figure`
    """
    methods = list(methods or table.meta["methods"])
    ratios = sorted(set(np.asarray(table["target_ratio"])))
    sizes = sorted(set(np.asarray(table["n_sources"])))
    if fig is None:
        fig = _plt().figure(figsize=(3.2 * len(sizes), 2.6 * len(ratios)))
    axes = fig.subplots(len(ratios), len(sizes), sharey=True, squeeze=False)
    for i, ratio in enumerate(ratios[::-1]):
        for j, n in enumerate(sizes):
            ax = axes[i, j]
            sel = (np.asarray(table["target_ratio"]) == ratio) & (
                np.asarray(table["n_sources"]) == n)
            for method in methods:
                ax.scatter(table["ratio"][sel], table[f"frac_err_{method}"][sel], s=8,
                           color=_COLOURS.get(method), alpha=0.7,
                           label=_LABELS.get(method, method))
            ax.axhline(0, color="k", lw=0.5)
            ax.set_title(f"N = {n}, ratio ~ {ratio:g}", fontsize="small")
            if i == len(ratios) - 1:
                ax.set_xlabel(r"true $\mu(L1)/\mu(L2)$")
            if j == 0:
                ax.set_ylabel("fractional error")
    axes[0, 0].legend(fontsize="x-small")
    fig.tight_layout()
    return fig


def plot_error_histograms(table, methods=None, *, ax=None, limit=0.3):
    """Distribution of fractional errors over all panels (paper Fig. 11).

    Parameters
    ----------
    table : `~astropy.table.Table`
        A table with ``frac_err_<method>`` columns, e.g. from
        :func:`lensdual.simulation.validation.appendix_b_grid`.
    methods : sequence of str, optional
        Estimators to draw (default ``table.meta["methods"]``).
    ax : `matplotlib.axes.Axes`, optional
        Axes to draw on (default: a new figure).
    limit : float
        The errors are clipped to ``[-limit, limit]`` (default 0.3).

    Returns
    -------
    ax : `matplotlib.axes.Axes`
    """
    methods = list(methods or table.meta["methods"])
    if ax is None:
        ax = _plt().subplots(figsize=(5, 3.5))[1]
    bins = np.linspace(-limit, limit, 61)
    for method in methods:
        e = np.asarray(table[f"frac_err_{method}"], dtype=float)
        e = np.clip(e[np.isfinite(e)], -limit, limit)
        ax.hist(e, bins=bins, histtype="step", lw=1.5, color=_COLOURS.get(method),
                label=f"{_LABELS.get(method, method)}: median |err| "
                      f"{np.median(np.abs(e)):.1%}")
    ax.set_xlabel("fractional error (clipped)")
    ax.set_ylabel("pairs")
    ax.legend(fontsize="small")
    return ax


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

    from .pairing import catalog_positions, pairs_positions

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
    from ._pairs_table import mu_flux_col, mu_flux_err_col

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


def ds9_regions(pairs, catalogs=None, *, radius=0.15):
    """DS9 regions of the detected sources and of the pairs, to load over the images.

    Parameters
    ----------
    pairs : `~astropy.table.Table`
        A pairs table with SkyCoord columns ``sky1`` and ``sky2`` (e.g. the
        output of :func:`~lensdual.duality.check_duality` on measured pairs).
        Pairs are drawn green, ``anomalous`` ones red and untested ones
        (``tested`` False) yellow.
    catalogs : dict, optional
        ``{"L1": table, "L2": table}`` of detections with ``id`` and a
        SkyCoord column ``sky``.
    radius : float
        Circle radius in arcsec (default 0.15).

    Returns
    -------
    regions : dict of str to `regions.Regions`
        ``"pairs"``: a numbered circle on both images of every pair and a line
        between them; ``"L1"``, ``"L2"``: a circle with the id of every
        detection (with ``catalogs``). Write them with
        ``regions["pairs"].write("pairs.reg", format="ds9")``.

    Examples
    --------
    >>> import astropy.units as u
    >>> from astropy.coordinates import SkyCoord
    >>> from astropy.table import QTable
    >>> from lensdual.visualization import ds9_regions
    >>> pairs = QTable({"pair_id": [1, 2],
    ...                 "sky1": SkyCoord([10.0, 10.001] * u.deg, [-5.0, -5.0] * u.deg),
    ...                 "sky2": SkyCoord([10.01, 10.011] * u.deg, [-5.0, -5.0] * u.deg)})
    >>> reg = ds9_regions(pairs)
    >>> len(reg["pairs"])  # two circles and a line per pair
    6
    """
    import astropy.units as u
    from astropy.coordinates import SkyCoord
    from astropy.table import Table
    from regions import CircleSkyRegion, LineSkyRegion, Regions

    from ._pairs_table import SKY_COLUMNS, sky_col

    if not isinstance(pairs, Table):
        raise TypeError(f"pairs must be an astropy Table, got {type(pairs).__name__}")
    for col in SKY_COLUMNS:
        if col not in pairs.colnames or not isinstance(pairs[col], SkyCoord):
            raise ValueError(f"pairs needs a SkyCoord column {col!r} (sky positions of the "
                             "pairs); measure_pairs gives it on images with a WCS")
    r = radius * u.arcsec
    out = []
    ids = pairs["pair_id"] if "pair_id" in pairs.colnames else range(1, len(pairs) + 1)
    for k, pid in enumerate(ids):
        if not (np.isfinite(pairs["sky1"][k].ra.deg) and np.isfinite(pairs["sky2"][k].ra.deg)):
            continue  # not measured: no position to draw
        colour = "green"
        if "anomalous" in pairs.colnames and pairs["anomalous"][k]:
            colour = "red"
        elif "tested" in pairs.colnames and not pairs["tested"][k]:
            colour = "yellow"
        for arc in ("1", "2"):
            meta = {"text": f"{pid}"}
            out.append(CircleSkyRegion(pairs[sky_col(arc)][k], r, meta=meta,
                                       visual={"color": colour}))
        out.append(LineSkyRegion(pairs["sky1"][k], pairs["sky2"][k],
                                 visual={"color": colour, "dash": 1}))
    result = {"pairs": Regions(out)}
    for arc, cat in (catalogs or {}).items():
        if "sky" not in cat.colnames or not isinstance(cat["sky"], SkyCoord):
            raise ValueError(f"catalogs[{arc!r}] needs a SkyCoord column 'sky'")
        idcol = cat["id"] if "id" in cat.colnames else range(len(cat))
        result[arc] = Regions([CircleSkyRegion(sky, r, meta={"text": f"{i}"},
                                               visual={"color": "cyan"})
                               for sky, i in zip(cat["sky"], idcol, strict=True)])
    return result


def _north_up(ccd):
    """``ccd`` (data, wcs) with north up and east left: reprojected when the pixel grid
    is rotated and ``reproject`` is installed, else as stored (with a note)."""
    import warnings

    from .exceptions import LensdualWarning

    wcs = ccd.wcs.celestial
    pc = wcs.wcs.get_pc() * wcs.wcs.get_cdelt()[:, None]
    angle = np.degrees(np.arctan2(pc[1, 0], pc[1, 1]))  # rotation of the y axis from north
    if abs(angle) < 0.5 and pc[0, 0] < 0:
        return np.asarray(ccd.data, dtype=float), wcs, True
    try:
        from reproject import reproject_interp
    except ImportError:
        warnings.warn("the image is not north-up and reproject is not installed: it is "
                      "drawn as stored, with a compass (pip install reproject)",
                      LensdualWarning, stacklevel=3)
        return np.asarray(ccd.data, dtype=float), wcs, False
    from astropy.wcs import WCS

    scale = np.sqrt(abs(np.linalg.det(pc)))
    ny, nx = ccd.data.shape
    centre = wcs.pixel_to_world((nx - 1) / 2, (ny - 1) / 2)
    target = WCS(naxis=2)
    target.wcs.ctype = ["RA---TAN", "DEC--TAN"]
    target.wcs.crval = [centre.ra.deg, centre.dec.deg]
    size = int(np.ceil(np.hypot(nx, ny)))
    target.wcs.crpix = [(size + 1) / 2, (size + 1) / 2]
    target.wcs.cdelt = [-scale, scale]
    data, _ = reproject_interp((np.asarray(ccd.data, dtype=float), wcs), target,
                               shape_out=(size, size))
    return data, target, True


def plot_arc_images(images, result, *, band=None, fig=None, margin=0.4, scale_bar=1.0,
                    mapped=True):
    """The paper's Fig. 3 as astronomers draw it: both arcs' images with numbered pairs.

    Each arc is drawn on `~astropy.visualization.wcsaxes.WCSAxes` (RA/Dec
    grid), north up and east left (reprojected with ``reproject`` when the
    image is rotated), cut out around its pairs, with an arcsec scale bar and
    a numbered circle on every pair: red for ``anomalous``, yellow for
    untested, green otherwise. With ``mapped`` a third panel shows the
    mapped view of :func:`plot_pairing_map`.

    Parameters
    ----------
    images : dict
        ``{"L1": CCDData or {band: CCDData}, "L2": ...}`` with celestial WCS.
    result : `~astropy.table.Table`
        A pairs table with SkyCoord ``sky1``, ``sky2`` (e.g. the output of
        :func:`~lensdual.duality.check_duality` on measured pairs).
    band : str, optional
        Which band to draw (default the first).
    fig : `matplotlib.figure.Figure`, optional
    margin : float
        Margin around the pairs, arcsec (default 0.4).
    scale_bar : float
        Length of the scale bar, arcsec (default 1).
    mapped : bool
        Add the mapped view as a third panel (default True).

    Returns
    -------
    fig : `matplotlib.figure.Figure`
    """
    from astropy.coordinates import SkyCoord
    from astropy.nddata import Cutout2D
    from astropy.visualization import AsinhStretch, ImageNormalize, PercentileInterval

    from ._pairs_table import SKY_COLUMNS, sky_col

    plt = _plt()
    for col in SKY_COLUMNS:
        if col not in result.colnames or not isinstance(result[col], SkyCoord):
            raise ValueError(f"result needs a SkyCoord column {col!r}")
    from matplotlib import patheffects

    # a dark outline keeps the pair markers readable on bright and dark pixels
    outline = (patheffects.withStroke(linewidth=2.5, foreground="black"),)
    n_panels = 3 if mapped else 2
    if fig is None:
        fig = plt.figure(figsize=(5.0 * n_panels, 5.0))
    ids = result["pair_id"] if "pair_id" in result.colnames else range(1, len(result) + 1)
    colour = np.array(["lime"] * len(result), dtype=object)
    if "tested" in result.colnames:
        colour[~np.asarray(result["tested"], bool)] = "yellow"
    if "anomalous" in result.colnames:
        colour[np.asarray(result["anomalous"], bool)] = "red"
    for k, arc in enumerate(("L1", "L2")):
        img = images[arc]
        if isinstance(img, dict):
            img = img[band if band is not None else next(iter(img))]
        data, wcs, north = _north_up(img)
        sky = result[sky_col(arc)]
        px, py = wcs.world_to_pixel(sky)
        finite = np.isfinite(px) & np.isfinite(py)
        if not finite.any():
            raise ValueError(f"no pair has a finite position on arc {arc}")
        px, py = px[finite], py[finite]
        scale = float(np.sqrt(abs(np.linalg.det(wcs.pixel_scale_matrix))) * 3600.0)
        pad = margin / scale
        box = (int(np.ceil(np.ptp(py) + 2 * pad)) + 1, int(np.ceil(np.ptp(px) + 2 * pad)) + 1)
        centre = ((px.min() + px.max()) / 2, (py.min() + py.max()) / 2)
        cut = Cutout2D(data, centre, box, wcs=wcs, mode="partial", fill_value=np.nan)
        ax = fig.add_subplot(1, n_panels, k + 1, projection=cut.wcs)
        finite = np.isfinite(cut.data)
        norm = ImageNormalize(cut.data[finite] if finite.any() else None,
                              interval=PercentileInterval(99.5), stretch=AsinhStretch(0.05))
        ax.imshow(cut.data, origin="lower", cmap="gray_r", norm=norm)
        cx, cy = cut.wcs.world_to_pixel(sky)
        radius = 0.12 / scale
        good = np.isfinite(cx) & np.isfinite(cy)
        if good.sum() > 1:
            from scipy.spatial import cKDTree

            pts = np.column_stack([cx[good], cy[good]])
            nearest = cKDTree(pts).query(pts, k=2)[0]
            radius = min(radius, 0.4 * float(np.median(nearest[:, 1])))
        for x, y, pid, c in zip(cx, cy, ids, colour, strict=True):
            if not (np.isfinite(x) and np.isfinite(y)):
                continue  # a pair whose position on this arc was not measured
            ax.add_patch(plt.Circle((x, y), radius, fill=False, color=c, lw=1.2,
                                    path_effects=outline))
            ax.annotate(str(pid), (x, y), xytext=(4, 4), textcoords="offset points",
                        color=c, fontsize=8, fontweight="bold", path_effects=outline)
        ny, nx = cut.data.shape
        length = scale_bar / scale
        x0, y0 = 0.06 * nx, 0.06 * ny
        ax.plot([x0, x0 + length], [y0, y0], color="k", lw=2)
        ax.text(x0 + length / 2, y0 + 0.02 * ny, f'{scale_bar:g}"', ha="center", va="bottom")
        if not north:
            ax.text(0.97, 0.03, "not north-up", transform=ax.transAxes, ha="right",
                    fontsize=7, color="0.3")
        ax.coords[0].set_axislabel("RA")
        ax.coords[1].set_axislabel("Dec")
        ax.set_title(f"arc {arc}" + (f" ({band})" if band else ""))
    if mapped:
        ax = fig.add_subplot(1, n_panels, 3)
        plot_pairing_map(result, ax=ax)
        ax.set_title("mapped view (L1 rotated onto L2)")
    fig.tight_layout()
    return fig


def plot_abundance_posterior(posterior, *, ax=None, paper_bound=None, cdm=None, label=None):
    r"""The posterior on the sub-halo abundance ``sigma_sub`` (per dex).

    The density is drawn against ``sigma_sub`` on a log axis, with its
    68 % and 95 % equal-tailed intervals shaded and the median marked.

    Parameters
    ----------
    posterior : `~astropy.table.QTable`
        Output of :func:`~lensdual.inference.abundance_posterior`.
    ax : `matplotlib.axes.Axes`, optional
    paper_bound : `~astropy.units.Quantity`, optional
        An upper limit to draw as a vertical dashed line (e.g. the paper's
        binomial bound, :func:`~lensdual.abundance.surface_density_limit`),
        in kpc^-2.
    cdm : `~astropy.units.Quantity`, optional
        A reference abundance to draw as a dotted line (e.g. pyHalo's CDM
        default ``sigma_sub`` = 0.025 kpc^-2).
    label : str, optional
        Legend label of the density.

    Returns
    -------
    ax : `matplotlib.axes.Axes`

    Raises
    ------
    ValueError
        ``posterior`` lacks the posterior columns or their metadata.
    """
    from astropy import units as u

    if not {"sigma_sub", "posterior"} <= set(posterior.colnames) or \
            "inference" not in posterior.meta:
        raise ValueError("posterior must be the output of lensdual.inference.abundance_posterior")
    plt = _plt()
    if ax is None:
        ax = plt.figure(figsize=(5.5, 3.6)).add_subplot()
    x = u.Quantity(posterior["sigma_sub"]).to_value(u.kpc**-2)
    y = np.asarray(posterior["posterior"], dtype=float)
    meta = posterior.meta["inference"]
    line, = ax.plot(x, y, lw=1.8, label=label or f"posterior ({meta['n_pairs']} pairs)")
    for key, alpha in (("interval_95", 0.15), ("interval_68", 0.3)):
        lo, hi = u.Quantity(meta[key]).to_value(u.kpc**-2)
        sel = (x >= lo) & (x <= hi)
        ax.fill_between(x[sel], 0, y[sel], color=line.get_color(), alpha=alpha, lw=0)
    ax.axvline(u.Quantity(meta["median"]).to_value(u.kpc**-2), color=line.get_color(), lw=0.8)
    if paper_bound is not None:
        ax.axvline(u.Quantity(paper_bound).to_value(u.kpc**-2), color="k", ls="--", lw=1,
                   label="binomial bound (95 %)")
    if cdm is not None:
        ax.axvline(u.Quantity(cdm).to_value(u.kpc**-2), color="tab:green", ls=":", lw=1.2,
                   label="CDM reference")
    ax.set_xscale("log")
    ax.set_xlim(x[0], x[-1])
    ax.relim()  # every posterior drawn on ax so far, not only the first
    ax.set_autoscaley_on(True)
    ax.autoscale_view(scalex=False)
    ax.set_ylim(bottom=0)
    ax.set_xlabel(r"$\Sigma_{\rm sub}$ (pyHalo sigma_sub) [kpc$^{-2}$]")
    ax.set_ylabel("posterior per dex")
    ax.legend(frameon=False, fontsize=8)
    return ax
