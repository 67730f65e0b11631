"""Figures of :mod:`lensdual.sensitivity`: flux-excess violins (Fig. 8) and SNR maps (Fig. 9)."""

import numpy as np
from astropy import units as u

__all__ = ["plot_flux_excess_violin", "plot_detection_snr_map"]


def plot_flux_excess_violin(table, ax=None, mu_size_band=None):
    """Violins of the flux excess per ``r_eff`` (paper Fig. 8).

    Parameters
    ----------
    table : `~astropy.table.QTable`
        From :func:`~lensdual.sensitivity.flux_excess_distribution`.
    ax : `matplotlib.axes.Axes`, optional
    mu_size_band : (float, float), optional
        Lower and upper edge of a hatched reference band (e.g. the 16-84 %
        range of ``mu_size``).

    Returns
    -------
    ax : `matplotlib.axes.Axes`

    Examples
    --------
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> import numpy as np
    >>> from lensdual.sensitivity import flux_excess_distribution, plot_flux_excess_violin
    >>> tab = flux_excess_distribution(0.5 * np.eye(2), {"theta_E": 0.02}, [0.5, 1.0, 2.0],
    ...                                n_angles=4, n_grid=200)
    >>> ax = plot_flux_excess_violin(tab, mu_size_band=(0.9, 1.1))
    >>> type(ax).__name__
    'Axes'
    >>> import matplotlib.pyplot as plt
    >>> plt.close(ax.figure)
    """
    import matplotlib.pyplot as plt

    for col in ("r_eff", "flux_excess"):
        if col not in getattr(table, "colnames", ()):
            raise ValueError(f"table must have column {col!r} (from flux_excess_distribution)")
    if ax is None:
        _, ax = plt.subplots()
    r = np.asarray(table["r_eff"], dtype=float)
    fe = np.asarray(table["flux_excess"], dtype=float)
    levels = np.unique(r)
    data = [fe[r == lv] for lv in levels]
    width = 0.8 * (np.min(np.diff(levels)) if levels.size > 1 else 1.0)
    ax.violinplot(data, positions=levels, widths=width, showmedians=True)
    if mu_size_band is not None:
        lo, hi = (float(v) for v in mu_size_band)
        ax.axhspan(lo, hi, hatch="//", fill=False, color="0.4", lw=0)
    ax.axhline(1.0, color="0.5", ls=":")
    ax.set_yscale("log")
    ax.set_xlabel(r"$r_{\rm eff}$")
    ax.set_ylabel("flux excess")
    return ax


def _edges(v, log):
    w = np.log10(v) if log else v
    if w.size == 1:
        e = np.array([w[0] - 0.5, w[0] + 0.5])
    else:
        mid = 0.5 * (w[1:] + w[:-1])
        e = np.concatenate([[2 * w[0] - mid[0]], mid, [2 * w[-1] - mid[-1]]])
    return 10**e if log else e


def plot_detection_snr_map(table, *, columns=None, axes=None, vmin=0.3, vmax=100.0,
                           levels=(3, 5, 10), cmap="viridis"):
    """SNR maps over ``r_eff`` (x) and mass (y), one panel per column (paper Fig. 9).

    Parameters
    ----------
    table : `~astropy.table.QTable`
        From :func:`~lensdual.sensitivity.detection_snr_map` (one concentration model).
    columns : sequence of str, optional
        SNR columns to show; default every ``snr_p*`` column.
    axes : sequence of `matplotlib.axes.Axes`, optional
        One per column; default a new row of panels.
    vmin, vmax : float
        Limits of the logarithmic colour scale.
    levels : sequence of float
        SNR contour levels (white lines); the dashed line is ``r_eff = 1``.
    cmap : str
        Colour map.

    Returns
    -------
    axes : list of `matplotlib.axes.Axes`
    mesh : `matplotlib.collections.QuadMesh`
        Of the last panel (for a colour bar).

    Examples
    --------
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> import numpy as np
    >>> import astropy.units as u
    >>> from lensdual.sensitivity import detection_snr_map, plot_detection_snr_map
    >>> table = detection_snr_map([1e8, 1e9] * u.Msun, [0.5, 1.0, 2.0],
    ...                           jacobian=np.diag([-0.6, 0.2]), sigma_rel=0.1,
    ...                           n_angles=4, n_grid=100)
    >>> axes, mesh = plot_detection_snr_map(table)
    >>> len(axes), type(mesh).__name__
    (3, 'QuadMesh')
    >>> import matplotlib.pyplot as plt
    >>> plt.close(axes[0].figure)
    """
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    names = getattr(table, "colnames", ())
    for col in ("mass", "r_eff"):
        if col not in names:
            raise ValueError(f"table must have column {col!r} (from detection_snr_map)")
    if columns is None:
        columns = [c for c in names if c.startswith("snr_p")]
    columns = list(columns)
    if not columns or any(c not in names for c in columns):
        raise ValueError(f"columns must name SNR columns of the table, got {columns}")
    mass = u.Quantity(table["mass"], u.Msun).value
    r = np.asarray(table["r_eff"], dtype=float)
    mu, ru = np.unique(mass), np.unique(r)
    if mu.size * ru.size != len(table):
        raise ValueError("table must hold one row per (mass, r_eff) pair")
    im, ir = np.searchsorted(mu, mass), np.searchsorted(ru, r)
    if axes is None:
        _, axes = plt.subplots(1, len(columns), figsize=(4 * len(columns), 3.4),
                               sharey=True, squeeze=False)
        axes = axes[0]
    axes = list(np.atleast_1d(axes))
    if len(axes) != len(columns):
        raise ValueError(f"need one axes per column: {len(columns)} columns, {len(axes)} axes")
    xe, ye = _edges(ru, False), _edges(mu, True)
    mesh = None
    for ax, col in zip(axes, columns, strict=True):
        z = np.full((mu.size, ru.size), np.nan)
        z[im, ir] = np.asarray(table[col], dtype=float)
        mesh = ax.pcolormesh(xe, ye, np.clip(z, vmin, vmax), norm=LogNorm(vmin, vmax),
                             cmap=cmap, shading="flat")
        if levels and ru.size > 1 and mu.size > 1:
            cs = ax.contour(ru, mu, z, levels=sorted(levels), colors="w", linewidths=0.8)
            ax.clabel(cs, fmt="%g", fontsize=7)
        ax.axvline(1.0, color="w", ls="--", lw=0.8)
        ax.set_yscale("log")
        ax.set_xlabel(r"$r_{\rm eff}$")
        ax.set_title(col.replace("snr_p", "SNR, ").replace("snr_mean", "mean SNR")
                     + ("th percentile" if col.startswith("snr_p") else ""))
    axes[0].set_ylabel(r"$M_{200}$ [$M_\odot$]")
    return axes, mesh
