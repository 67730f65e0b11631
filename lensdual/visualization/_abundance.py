"""The posterior on the sub-halo abundance."""

import numpy as np

from ._common import _plt

__all__ = ["plot_abundance_posterior"]


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
