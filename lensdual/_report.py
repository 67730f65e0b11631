"""The text the commands print: the pairs table, the verdict and the reports.

`format_pairs_table`, `verdict` and `format_report` turn an
`~lensdual.pipeline.Analysis` into the report of ``lensdual demo`` and
``lensdual run`` (``report.txt``); `parametric_paragraph` adds the paragraph
on a parametric comparison, and `knot_report` is the report of a
`~lensdual.pipeline.KnotAnalysis`. `lensdual.pipeline` re-exports them under
the same names.
"""

from pathlib import Path

import numpy as np
from astropy import units as u

from ._doubts import doubts_of

__all__ = ["format_pairs_table", "verdict", "format_report", "parametric_paragraph",
           "knot_report"]


#: Below this many pairs the paper's estimators fit one nearly global map: their
#: mu_size is almost the same for every pair and their error omits the map's curvature.
_FEW_PAIRS = 7


def _fmt(value, spec=".3f"):
    value = float(value)
    return "nan" if not np.isfinite(value) else format(value, spec)


def format_pairs_table(result):
    """The per-pair table as printed by the commands.

    Parameters
    ----------
    result : `~astropy.table.QTable`
        The duality table (:func:`~lensdual.duality.check_duality`, e.g.
        ``Analysis.result``) with the ``id1``, ``id2`` columns of the pairing.

    Returns
    -------
    str
        One line per pair: ids, ``mu_flux`` per band, ``mu_size`` and its
        error, their ratio, the significance (the Gaussian-equivalent SNR
        the flag is set on, see :func:`~lensdual.duality.check_duality`) and
        the flag (``ANOMALOUS``, ``ok`` or ``untested (why)``), under a
        header line.
    """
    bands = list(result.meta.get("bands", []))
    head = ["pair", "id1", "id2"] + [f"mu_flux {b}" for b in bands] + [
        "mu_size", "+-", "ratio", "SNR", "flag"]
    rows = []
    for row in result:
        cells = [str(row["pair_id"]), str(row["id1"]), str(row["id2"])]
        cells += [_fmt(row[f"mu_flux_{b}"]) for b in bands]
        cells += [_fmt(row["mu_size"]), _fmt(row["mu_size_err"]),
                  _fmt(row["duality_ratio"]), _fmt(_significance(row), ".1f"),
                  _flag(row)]
        rows.append(cells)
    widths = [max(len(h), *(len(r[k]) for r in rows)) if rows else len(h)
              for k, h in enumerate(head)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(head, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join(lines)


def _significance(row):
    """The Gaussian-equivalent SNR a flag is set on (the SNR for older tables)."""
    return row["significance"] if "significance" in row.colnames else row["snr"]


def _snr_words(row):
    """"SNR 4.1", or with a Student's t error "SNR 4.1 (3.2 sigma, t with 6 dof)"."""
    snr = float(row["snr"])
    dof = float(row["snr_dof"]) if "snr_dof" in row.colnames else np.inf
    if not np.isfinite(dof):
        return f"SNR {_fmt(snr, '.1f')}"
    return (f"SNR {_fmt(snr, '.1f')} ({_fmt(_significance(row), '.1f')} sigma: its size error "
            f"is estimated, Student's t with {dof:.0f} degrees of freedom)")


def _flag(row):
    """The flag column of the printed table: ANOMALOUS, ok, or why a pair is untested."""
    if row["anomalous"]:
        return "ANOMALOUS"
    if "tested" in row.colnames and not row["tested"]:
        return f"untested ({_untested_reason(row)})"
    return "ok"


def _untested_reason(row):
    if "doubt" in row.colnames and str(row["doubt"]):
        return "doubtful pairing"
    if "flux_doubt" in row.colnames and str(row["flux_doubt"]):
        return "doubtful flux ratio"
    if "smooth_field_fails" in row.colnames and row["smooth_field_fails"]:
        return "geometry and neighbours' fluxes disagree: the smooth field fails here"
    status = str(row["mu_size_status"]) if "mu_size_status" in row.colnames else ""
    if not np.isfinite(float(row["mu_size"])):
        return "no mu_size"
    if status in ("untestable", "failed"):
        return f"mu_size {status}"
    if not np.isfinite(float(row["mu_flux"])):
        return "no flux ratio"
    return "no SNR"


def _criterion(snr_definition, threshold):
    """The words of the flag's criterion, after "a pair is"."""
    if snr_definition == "paper":
        return (f"anomalous when |mu_flux/mu_size - 1| exceeds {threshold:g} times the "
                "ratio's relative size error (the paper's SNR). ")
    if snr_definition == "profile":
        return (f"anomalous when the profile-likelihood SNR of mu_flux = |det J| exceeds "
                f"{threshold:g}. ")
    text = f"anomalous when |ln(mu_flux/mu_size)| exceeds {threshold:g} times its error"
    if snr_definition == "conservative":
        return text + " and its profile-likelihood SNR does too (the conservative SNR). "
    return text + ". "


def verdict(result, sigma_pos):
    """One paragraph on which pairs break duality, and how strongly.

    Parameters
    ----------
    result : `~astropy.table.QTable`
        The duality table (:func:`~lensdual.duality.check_duality`, e.g.
        ``Analysis.result``).
    sigma_pos : `~astropy.units.Quantity`
        The positional errors used (``Analysis.sigma_pos``): a scalar or one
        per point source.

    Returns
    -------
    str
        The verdict: what was measured and how, the pairs that could not be
        tested and why, the calibration of the family of tests, and each pair
        that breaks duality.
    """
    meta = result.meta.get("duality", {})
    bands = list(result.meta.get("bands", []))
    threshold = meta.get("snr_threshold", 3.0)
    sig = np.asarray(u.Quantity(sigma_pos, u.arcsec).to_value(u.mas))
    if sig.size > 1:
        known = sig[np.isfinite(sig)]  # a pair not measured has no position error
        median = f"{np.median(known):.1f} mas" if known.size else "unknown"
        sig_text = f"positional errors from the PSF fits (median {median})"
    else:
        sig_text = f"sigma_pos = {float(sig):.1f} mas"
    method = meta.get("method", "?")
    errors = ("analytic errors that include the estimator's truncation error"
              if method == "adaptive" else
              f"{meta.get('n_bootstrap', '?')} bootstrap realisations (position noise only)")
    text = (f"{len(result)} point-source pairs were measured on arcs L1 and L2 in "
            f"{len(bands)} band{'s' if len(bands) != 1 else ''} ({', '.join(bands)}). "
            f"Size magnifications from the {method} estimator with "
            f"{sig_text} and {errors}; a pair is "
            + _criterion(meta.get("snr_definition", "log"), threshold))
    if meta.get("test_auto"):
        text += f"Geometric test: {meta['test_auto']}. "
    if meta.get("test") == "joint":
        n_field = int(np.count_nonzero(np.asarray(result["field_status"]) == "ok"))
        text += (f"Joint test: the flux ratio is tested against mu_size combined with the "
                 f"flux field of the neighbours' flux ratios where they predict it ({n_field} "
                 f"of {len(result)} pairs; the others are tested on their geometry alone), "
                 "and a pair where the two disagree is not tested. ")
    if "tested" in result.colnames:
        n_tested = int(np.count_nonzero(result["tested"]))
        untested = result[~np.asarray(result["tested"], dtype=bool)]
    else:
        n_tested, untested = meta.get("n_tested", len(result)), result[:0]
    if len(untested):
        reasons = {}
        for row in untested:
            reasons.setdefault(_untested_reason(row), []).append(str(row["pair_id"]))
        listed = "; ".join(f"{why}: pair{'s' if len(ids) > 1 else ''} {', '.join(ids)}"
                           for why, ids in reasons.items())
        text += (f"{len(untested)} pair(s) could not be tested and are NOT passes "
                 f"(column 'tested'; {listed}). ")
        doubtful = untested[doubts_of(untested) != ""]
        if len(doubtful):
            text += ("Doubtful pairings are left out of the size magnification of the other "
                     "pairs and never counted as anomalies: "
                     + "; ".join(f"pair {r['pair_id']} ({r['id1']}, {r['id2']}): {r['doubt']}"
                                 for r in doubtful) + ". ")
        fluxes = untested[doubts_of(untested, "flux_doubt") != ""]
        if len(fluxes):
            text += ("Pairs whose flux ratio is doubtful keep their place in the geometry and "
                     "are never counted as anomalies: "
                     + "; ".join(f"pair {r['pair_id']}: {r['flux_doubt']}" for r in fluxes)
                     + ". ")
    if method != "adaptive" and len(result) < _FEW_PAIRS:
        text += (f"WARNING: only {len(result)} pairs: the {method} estimator then fits one "
                 "nearly global map (mu_size almost the same for every pair) and its error "
                 "holds the position noise only, not the map's curvature, so its flags are "
                 f"not calibrated. Use at least {_FEW_PAIRS} pairs and the adaptive "
                 "estimator. ")
    bad = result[np.asarray(result["anomalous"], dtype=bool)]
    text += _calibration_sentence(len(bad), n_tested, meta)
    if len(bad) == 0:
        if n_tested == 0:
            text += ("No pair could be tested, so the data say nothing about geometrical "
                     "duality here: no conclusion on sub-haloes.")
        elif len(untested):
            text += (f"No pair breaks geometrical duality among the {n_tested} tested: no "
                     "sub-halo is detected near them; the untested pairs are no evidence "
                     "either way.")
        else:
            text += ("No pair breaks geometrical duality: flux and size magnifications agree "
                     "everywhere, so no sub-halo is detected near these point sources.")
        return text
    parts = []
    for row in bad:
        ratio = float(row["duality_ratio"])
        if ratio > 1:
            how = f"its L1 image is {ratio - 1:.0%} brighter, relative to L2,"
        else:
            how = f"its L2 image is {1 / ratio - 1:.0%} brighter, relative to L1,"
        parts.append(f"pair {row['pair_id']} (mu_flux = {_fmt(row['mu_flux'])} +- "
                     f"{_fmt(row['mu_flux_err'])}, mu_size = {_fmt(row['mu_size'])} +- "
                     f"{_fmt(row['mu_size_err'])}, ratio {_fmt(ratio, '.2f')}, "
                     f"{_snr_words(row)}{_empirical_words(row)}: {how} than the geometry "
                     "allows)")
    n_bad = len(bad)
    text += (f"{n_bad} pair{'s break' if n_bad > 1 else ' breaks'} geometrical duality: "
             + "; ".join(parts) + ". A flux anomaly at fixed geometry is the signature of "
             "unseen sub-structure (a sub-halo) near one of the two images. "
             f"The other {n_tested - n_bad} tested pairs agree with duality.")
    return text + _null_confirmation(bad, meta)


def _empirical_words(row):
    """", empirical p = 0.1% against the null calibration" where it was run."""
    if "p_value_empirical" not in row.colnames or not np.isfinite(row["p_value_empirical"]):
        return ""
    return f", empirical p = {_percent(float(row['p_value_empirical']))} against the null"


def _null_confirmation(bad, meta):
    """How many flags the null calibration's empirical p-values confirm (empty without one)."""
    null = meta.get("null_calibration")
    if not null or "p_value_empirical" not in bad.colnames or "p_threshold" not in meta:
        return ""
    p_thr = float(meta["p_threshold"])
    n_real = int(null["n_realisations"])
    if 1.0 / (n_real + 1) > p_thr:
        return (f" The null calibration's {n_real} realisations cannot give an empirical "
                f"p-value below {_percent(p_thr)}, so they cannot confirm a flag at this "
                f"threshold: run at least {int(np.ceil(1.0 / p_thr - 1.0))} to do so.")
    p_emp = np.asarray(bad["p_value_empirical"], dtype=float)
    n_conf = int(np.count_nonzero(p_emp <= p_thr))
    if len(bad) == 1:
        what = "confirms this flag" if n_conf else "does not confirm this flag"
    else:
        what = f"confirms {n_conf} of the {len(bad)} flags"
    text = f" The null calibration {what} (empirical p <= {_percent(p_thr)})."
    if null.get("map_interpolates"):
        text += (f" But the null map ({null['map']}) interpolates the pairs: the constellation "
                 "does not sample the map finely enough to tell its bending from the position "
                 "noise, so its empirical p-values are uncertain.")
    if n_conf < len(bad):
        text += (" A flag that the null does not confirm may come from the estimator's own "
                 "bias where the magnification ratio changes steeply across the constellation "
                 "and the astrometry is coarse (see the calibration page): look at it closely "
                 "before calling it a sub-halo.")
    return text


def _percent(p):
    """A probability as a percentage, '< 0.01 %' below 1e-4."""
    if not np.isfinite(p):
        return "undefined"
    return "< 0.01%" if p < 1e-4 else f"{100 * p:.2g}%"


def _calibration_sentence(n_bad, n_tested, meta):
    """'k pairs of N flagged; the chance of at least one such flag without any sub-halo...'."""
    if "p_any_false_flag" not in meta:
        return ""
    text = (f"{n_bad} pair{'s' if n_bad != 1 else ''} of {n_tested} tested flagged "
            f"(expected without any sub-halo: {meta['expected_false_flags']:.2g}); ")
    if n_bad:
        text += (f"the chance of at least one flag as strong without any sub-halo is "
                 f"{_percent(meta['family_wise_p'])}. ")
    else:
        text += (f"the chance of at least one flag without any sub-halo is "
                 f"{_percent(meta['p_any_false_flag'])}. ")
    null = meta.get("null_calibration")
    if null:
        floor = (" (the smallest p-value this many realisations can give)"
                 if null["family_wise_p_empirical"] <= 1.5 / null["n_realisations"] else "")
        text += (f"On {null['n_realisations']} simulated clean constellations like this one "
                 f"(null calibration) {null['false_alarm_rate']:.2%} of pairs were flagged "
                 f"(nominal {null['nominal_false_alarm_rate']:.2%}), "
                 f"{null['p_any_false_flag']:.1%} of them had at least one flag, and a flag "
                 f"as strong as the strongest here occurred in "
                 f"{_percent(null['family_wise_p_empirical'])}{floor}. ")
    return text


def format_report(analysis, extra=()):
    """The report the commands print and write to ``report.txt``.

    Parameters
    ----------
    analysis : `Analysis`
        What :func:`analyse` found.
    extra : sequence of str, optional
        Paragraphs appended after the verdict (empty ones are skipped).

    Returns
    -------
    str
        The pairs table (:func:`format_pairs_table`), the :func:`verdict`,
        the extra paragraphs and the warnings raised on the way.
    """
    parts = [format_pairs_table(analysis.result), "", verdict(analysis.result,
                                                             analysis.sigma_pos)]
    parts += [p for p in extra if p]
    if analysis.warnings:
        parts += ["", "Warnings raised on the way:"] + [f"  {w}" for w in analysis.warnings]
    return "\n".join(parts)


def parametric_paragraph(table):
    """The report's paragraph on a parametric comparison table."""
    meta = table.meta.get("parametric", {})
    parts = []
    if meta.get("fit_model"):
        parts.append(f"A parametric lenstronomy fit ({' + '.join(meta['fit_model'])}, "
                     f"chi2 = {meta.get('chi2', float('nan')):.1f} for {meta.get('dof')} "
                     f"degrees of freedom at sigma_pos = {meta.get('sigma_pos', 0) * 1e3:.0f} "
                     "mas)")
    if meta.get("lenstool"):
        parts.append(f"the Lenstool model {Path(meta['lenstool']).name}")
    text = " and ".join(parts) + " predicted |mu(L1)/mu(L2)| for every pair"
    text = text[0].upper() + text[1:]
    model_label = "the fitted model" if meta.get("fit_model") else "the Lenstool model"
    for col, label in (("anomalous_model", model_label),
                       ("anomalous_lenstool", "the Lenstool model")):
        if col in table.colnames:
            ids = [str(i) for i in table["pair_id"][np.asarray(table[col], dtype=bool)]]
            text += (f"; against {label}, {len(ids)} pair(s) break duality"
                     + (f" ({', '.join(ids)})" if ids else ""))
    return text + " (parametric.ecsv, parametric.png)."


def _knot_summary(tab, name):
    """One model's line of a knot table: disagreements, then parity."""
    bad = tab["knot"][np.asarray(tab[f"disagree_{name}"], bool)]
    parity = np.asarray(tab["parity"])
    determined = parity != 0
    agree = int(np.sum(determined & (parity == np.asarray(tab[f"parity_{name}"]))))
    text = (f"  {name}: {len(bad)} of {len(tab)} knots disagree beyond SNR "
            f"{tab.meta['snr_threshold']:g} (SNR or parity)"
            + (f" ({', '.join(str(b) for b in bad)})" if len(bad) else "")
            + f"; parity agrees for {agree} of the {int(determined.sum())} knots where it "
              "is determined")
    if (~determined).any():
        text += (f" (undetermined: {', '.join(str(k) for k in tab['knot'][~determined])})")
    return text


def knot_report(analysis):
    """A text report of a `KnotAnalysis`.

    Parameters
    ----------
    analysis : `KnotAnalysis`
        What :func:`analyse_knots` found.

    Returns
    -------
    str
        The assignment of the knot images, then one block per pair of
        macro-images with every knot's ``mu_size`` and model ratios.
    """
    lines = [analysis.knot_pairs.summary()]
    for key, tab in analysis.tables.items():
        sigma = analysis.sigma_pos[key]
        how = (f"measured from the residuals of a degree-{analysis.sigma_degree[key]} map"
               if analysis.sigma_degree[key] else "given")
        lines += ["", f"Macro-images {key[0]} (L1) / {key[1]} (L2): {len(tab)} knots, "
                      f"sigma_pos = {sigma.to_value(u.mas):.0f} mas ({how})"]
        names = list(tab.meta.get("models", []))
        head = f"  {'knot':>6} {'mu_size':>8} {'+-ln':>5} {'status':>10}"
        for n in names:
            head += f" {('mu_' + n)[:14]:>14} {'+-ln':>5} {'SNR':>5}"
        lines.append(head)
        for r in tab:
            status = r["mu_size_status"] if "mu_size_status" in tab.colnames else ""
            ln = r["ln_mu_size_err"] if "ln_mu_size_err" in tab.colnames else np.nan
            row = f"  {r['knot']:>6} {r['mu_size']:8.3f} {ln:5.2f} {status:>10}"
            for n in names:
                flag = " !" if r[f"disagree_{n}"] else ""
                row += (f" {r[f'mu_{n}']:14.3f} {r[f'ln_mu_{n}_err']:5.2f} "
                        f"{r[f'snr_{n}']:5.2f}{flag}")
            lines.append(row)
        for n in names:
            lines.append(_knot_summary(tab, n))
    return "\n".join(lines)
