"""The posterior on the sub-halo abundance, alone or with the WDM half-mode mass."""

import numpy as np

from ._common import _plt

__all__ = ["plot_abundance_posterior", "plot_half_mode_posterior"]


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


def _credible_levels(dens, cell, masses=(0.68, 0.95)):
    """The density levels above which the highest-density region holds each of
    ``masses`` of the probability (``dens`` times ``cell``, the cells' areas)."""
    order = np.argsort(dens.ravel())[::-1]
    mass = np.cumsum((dens * cell).ravel()[order])
    mass /= mass[-1]
    return [float(dens.ravel()[order][min(np.searchsorted(mass, m), mass.size - 1)])
            for m in masses]


def plot_half_mode_posterior(posterior, *, fig=None):
    r"""The joint posterior on the sub-halo abundance and the WDM half-mode mass.

    Left, the joint density against ``log10 sigma_sub`` and ``log10 m_hm``,
    with the 68 % and 95 % highest-density regions outlined; right, the
    half-mode mass's marginal with its 95 % upper limit.

    Parameters
    ----------
    posterior : `~astropy.table.QTable`
        Output of :func:`~lensdual.inference.half_mode_posterior`.
    fig : `matplotlib.figure.Figure`, optional
        The figure to draw on (a new one by default).

    Returns
    -------
    fig : `matplotlib.figure.Figure`
        With the two axes, joint density first.

    Raises
    ------
    ValueError
        ``posterior`` lacks the columns or metadata of a half-mode posterior.
    """
    need = {"log10_mhm", "log10_sigma_sub", "posterior"}
    if not need <= set(posterior.colnames) or \
            "log10_mhm_upper_95" not in posterior.meta.get("inference", {}):
        raise ValueError("posterior must be the output of "
                         "lensdual.inference.half_mode_posterior")
    plt = _plt()
    if fig is None:
        fig = plt.figure(figsize=(8.5, 3.6))
    ax, axm = fig.subplots(1, 2, gridspec_kw={"width_ratios": (1.6, 1)})
    log_m = np.unique(np.asarray(posterior["log10_mhm"], dtype=float))
    # rows run over the abundances for each half-mode mass in turn
    log_s = np.asarray(posterior["log10_sigma_sub"], dtype=float)[:len(posterior) // log_m.size]
    dens = np.asarray(posterior["posterior"], dtype=float).reshape(log_m.size, log_s.size)
    mesh = ax.pcolormesh(log_s, log_m, dens, shading="nearest", cmap="Blues")
    fig.colorbar(mesh, ax=ax, label="posterior per dex$^2$")
    if log_m.size > 1 and log_s.size > 1:
        cell = np.outer(np.gradient(log_m), np.gradient(log_s))
        levels = sorted(set(_credible_levels(dens, cell)))
        if len(levels) > 1 or levels[0] < dens.max():
            ax.contour(log_s, log_m, dens, levels=levels, colors="k", linewidths=(0.8, 1.4)[
                :len(levels)])
    ax.set_xlabel(r"$\log_{10}\Sigma_{\rm sub}$ [kpc$^{-2}$]")
    ax.set_ylabel(r"$\log_{10} m_{\rm hm}$ [M$_\odot$]")
    meta = posterior.meta["inference"]
    axm.plot(log_m, meta["marginal_log10_mhm"], lw=1.8)
    axm.axvline(meta["log10_mhm_upper_95"], color="k", ls="--", lw=1,
                label=f"95 % upper limit {meta['log10_mhm_upper_95']:.2f}")
    axm.set_ylim(bottom=0)
    axm.set_xlabel(r"$\log_{10} m_{\rm hm}$ [M$_\odot$]")
    axm.set_ylabel("marginal per dex")
    axm.legend(frameon=False, fontsize=8)
    return fig
