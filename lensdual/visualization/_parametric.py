"""Figures of the parametric comparisons: magnifications per pair, and ``mu_size``
against a model's ratio."""

import numpy as np
from astropy.table import Table

__all__ = ["plot_parametric_comparison", "plot_size_vs_model"]


def plot_parametric_comparison(table, ax=None):
    """Plot ``mu_flux``, ``mu_size`` and ``mu_model`` per pair, with error bars.

    Parameters
    ----------
    table : `~astropy.table.Table`
        Output of :func:`~lensdual.parametric.compare_with_parametric` (or of
        :func:`~lensdual.parametric.parametric_comparison`, whose
        ``mu_lenstool`` column, when present, is drawn too).
    ax : `matplotlib.axes.Axes`, optional
        Axes to draw on (default: a new figure).

    Returns
    -------
    ax : `matplotlib.axes.Axes`
    """
    import matplotlib.pyplot as plt

    if not isinstance(table, Table):
        raise TypeError(f"table must be an astropy Table, got {type(table).__name__}")
    missing = [c for c in ("pair_id", "mu_flux", "mu_size", "mu_model") if c not in table.colnames]
    if missing:
        raise ValueError(f"table lacks the column(s) {missing}: pass compare_with_parametric's "
                         "output")
    if ax is None:
        _, ax = plt.subplots(figsize=(7, 4))
    x = np.asarray(table["pair_id"], dtype=float)
    lenstool_only = str(table.meta.get("model", "")).startswith("Lenstool")
    series = [("mu_flux", r"$\mu_{\rm flux}$ (flux ratio)", "o", -0.2),
              ("mu_size", r"$\mu_{\rm size}$ (model-independent)", "s", 0.0),
              ("mu_model", r"$\mu_{\rm model}$ ("
               + ("Lenstool model" if lenstool_only else "parametric") + ")", "D", 0.2)]
    if "mu_lenstool" in table.colnames:
        series.append(("mu_lenstool", r"$\mu_{\rm model}$ (Lenstool model)", "v", 0.3))
    for name, label, marker, dx in series:
        err = (np.asarray(table[f"{name}_err"], float) if f"{name}_err" in table.colnames
               else None)
        ax.errorbar(x + dx, np.asarray(table[name], float), yerr=err, fmt=marker, ms=4,
                    capsize=2, label=label)
    if "mu_true" in table.colnames:
        ax.scatter(x, np.asarray(table["mu_true"], float), marker="_", s=200, color="k",
                   label="truth", zorder=3)
    for flag, col in (("anomalous_size", "C1"), ("anomalous_model", "C2"),
                      ("anomalous_lenstool", "C3")):
        if flag in table.colnames:
            sel = np.asarray(table[flag], bool)
            ax.scatter(x[sel], np.asarray(table["mu_flux"], float)[sel], s=120,
                       facecolors="none", edgecolors=col, label=f"{flag.replace('_', ' ')}")
    ax.set_yscale("log")
    ax.set_xlabel("pair id")
    ax.set_ylabel(r"$|\mu(L1)/\mu(L2)|$")
    ax.legend(fontsize="small")
    return ax


def plot_size_vs_model(table, model=None, ax=None, *, label_pairs=True):
    """Plot ``mu_size`` against a model's ratio per pair, with both error bars.

    Parameters
    ----------
    table : `~astropy.table.Table`
        Output of :func:`~lensdual.parametric.compare_size_with_models`.
    model : str, optional
        Which model (default: the first of ``table.meta['models']``).
    ax : `matplotlib.axes.Axes`, optional
        Axes to draw on (default: a new figure).
    label_pairs : bool
        Write the knot (or pair id) beside each point.

    Returns
    -------
    ax : `matplotlib.axes.Axes`
    """
    import matplotlib.pyplot as plt

    if not isinstance(table, Table) or "mu_size" not in table.colnames:
        raise TypeError("table must be the output of compare_size_with_models")
    names = list(table.meta.get("models", []))
    model = names[0] if model is None and names else model
    if f"mu_{model}" not in table.colnames:
        raise ValueError(f"no model {model!r} in the table (models: {names})")
    if ax is None:
        _, ax = plt.subplots(figsize=(5.5, 5))
    mu_s = np.asarray(table["mu_size"], float)
    mu_m = np.asarray(table[f"mu_{model}"], float)
    ln_s = np.asarray(table["ln_mu_size_err"], float)
    ln_m = np.asarray(table[f"ln_mu_{model}_err"], float)
    testable = np.isin(np.asarray(table["mu_size_status"]), ("ok", "misfit"))
    bad = np.asarray(table[f"disagree_{model}"], bool)
    for sel, style, lab in ((testable & ~bad, dict(fmt="o", color="C0"), "agree"),
                            (bad, dict(fmt="o", color="C3"), "disagree (> threshold)"),
                            (~testable, dict(fmt="x", color="0.5"), "untestable")):
        if sel.any():
            # an error of ln mu beyond ~709 is an unbounded bar (inf), not a warning
            with np.errstate(over="ignore"):
                xerr = [mu_m[sel] * (1 - np.exp(-ln_m[sel])),
                        mu_m[sel] * (np.exp(ln_m[sel]) - 1)]
                yerr = [mu_s[sel] * (1 - np.exp(-ln_s[sel])),
                        mu_s[sel] * (np.exp(ln_s[sel]) - 1)]
            ax.errorbar(mu_m[sel], mu_s[sel], xerr=xerr, yerr=yerr, ms=4, capsize=2,
                        linestyle="none", label=lab, **style)
    finite = np.isfinite(mu_s) & np.isfinite(mu_m) & (mu_s > 0) & (mu_m > 0)
    if finite.any():
        lo = 0.7 * min(mu_s[finite].min(), mu_m[finite].min())
        hi = 1.4 * max(mu_s[finite].max(), mu_m[finite].max())
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8, label="duality (1:1)")
        ax.set_xlim(lo, hi)
        ax.set_ylim(lo, hi)
    if label_pairs:
        labels = table["knot"] if "knot" in table.colnames else table["pair_id"]
        for xm, ys, lab in zip(mu_m, mu_s, labels, strict=True):
            if np.isfinite(xm) and np.isfinite(ys):
                ax.annotate(str(lab), (xm, ys), fontsize=6, xytext=(3, 3),
                            textcoords="offset points")
    from matplotlib.ticker import LogLocator, StrMethodFormatter

    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(StrMethodFormatter("{x:g}"))
        axis.set_minor_formatter(StrMethodFormatter(""))
    m1, m2 = table.meta.get("macro1", "L1"), table.meta.get("macro2", "L2")
    ax.set_xlabel(rf"model $|\mu({m1}) / \mu({m2})|$ ({model})")
    ax.set_ylabel(r"$\mu_{\rm size}$ (model-independent)")
    ax.legend(fontsize="small")
    return ax
