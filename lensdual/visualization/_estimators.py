"""Figures of the estimators' accuracy on simulated constellations (paper Figs. 6, 10 and 11)."""

import numpy as np

from ._common import _plt

__all__ = ["plot_true_vs_inferred", "plot_estimator_grid", "plot_error_histograms"]


_COLOURS = {"2v": "tab:orange", "quad": "tab:blue", "quad2": "tab:green"}
_LABELS = {"2v": "2v", "quad": "Quad (QW)", "quad2": "Quad, 2nd order"}


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
