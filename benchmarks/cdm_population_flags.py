"""The demo's CDM population over many seeds: flags against the pairs it truly perturbs.

Run on demand (about 15-40 s of CPU per seed)::

    python benchmarks/cdm_population_flags.py [--seeds 30] [--n-sources 12] [--output FILE]

For every seed, ``simulate_demo(subhalo="cdm")`` draws the demo's CDM
population (pyHalo's conventions and default abundance, 1e8-1e10 Msun, one
disc per arc), ``render_demo`` renders the point scene, the whole pipeline
runs with its default settings (``analyse``: detection, PSF photometry,
automatic pairing, the adaptive estimator, the geometric test; the adaptive
estimator's errors are analytic, so ``n_bootstrap`` plays no part) and
``compare_with_truth`` matches the measured pairs to the true ones. A pair is
truly perturbed (``subhalo`` True) when its true magnification ratio departs
from the smooth lens's by more than ``DEMO_CDM_THRESHOLD`` in
``|ln(mu_true / mu_macro)|``.

Reported, summed over the seeds: the sub-haloes drawn per seed; the pairs
measured, matched to a true pair and tested, and the untested pairs by their
``mu_size_status``; the perturbed pairs, those of them flagged (true
positives) and not flagged (missed, split into tested and untested); the
clean pairs flagged (false positives), their rate among the clean pairs
tested and its one-sided 95 % Clopper-Pearson upper limit; and the perturbed
pairs split by the mass of the sub-halo nearest to either of their images
and by the size of the perturbation.
"""

import argparse
import time
import warnings

import numpy as np
from _output import Record, add_output_argument

#: The test these records were made with: the geometric test with the linearised
#: SNR (the default until the joint test became it).
GEOMETRIC = {"test": "geometric", "snr_definition": "log"}

#: The one-sided confidence of the upper limit on the false-flag rate.
CONFIDENCE = 0.95
#: Bins of the nearest sub-halo's mass [Msun] (the population's range, one per decade).
MASS_BINS = (1e8, 1e9, 1e10)
#: Bins of |ln(mu_true / mu_macro)| of the perturbed pairs (from the threshold up).
SHIFT_EDGES = (0.10, 0.25)


def pair_rows(comparison, result, seed):
    """Per measured pair of one seed: what the tabulation needs, as a dict of arrays.

    ``matched`` (matched to a true pair), ``subhalo`` (truly perturbed),
    ``tested``, ``anomalous``, ``status`` (``mu_size_status``), ``shift``
    (``|ln(mu_true / mu_macro)|``, NaN when unmatched) and ``nearest_mass``
    (Msun, of the sub-halo nearest to either image; NaN when unmatched).
    """
    import astropy.units as u

    n = len(comparison)
    return {
        "seed": np.full(n, seed),
        "matched": np.asarray(comparison["source"]) >= 0,
        "subhalo": np.asarray(comparison["subhalo"], dtype=bool),
        "tested": np.asarray(result["tested"], dtype=bool),
        "anomalous": np.asarray(comparison["anomalous"], dtype=bool),
        "status": np.asarray(result["mu_size_status"]).astype(str),
        "shift": np.abs(np.log(np.asarray(comparison["mu_true"], dtype=float)
                               / np.asarray(comparison["mu_macro"], dtype=float))),
        "nearest_mass": comparison["nearest_mass"].to_value(u.Msun),
    }


def one(seed, n_sources):
    """The pipeline on one seed's CDM demo: ``(pair_rows, comparison meta, CPU seconds)``."""
    from lensdual.demo import compare_with_truth, render_demo, simulate_demo
    from lensdual.pipeline import analyse

    start = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        system, truth = simulate_demo(subhalo="cdm", n_sources=n_sources, seed=seed)
        demo = render_demo(system, truth, seed=seed)
        analysis = analyse(demo.images, psf=demo.psf, seed=seed, **GEOMETRIC)
    comparison = compare_with_truth(analysis.result, truth, demo.centre)
    meta = dict(comparison.meta)
    meta["expected_subhaloes"] = truth.meta["subhaloes"].meta["expected_number"]
    return pair_rows(comparison, analysis.result, seed), meta, time.process_time() - start


def upper_limit(k, n, confidence=CONFIDENCE):
    """One-sided Clopper-Pearson upper limit on a rate of ``k`` in ``n``."""
    from scipy.stats import beta

    if n == 0:
        return np.nan
    return 1.0 if k == n else float(beta.ppf(confidence, k + 1, n - k))


def tabulate(rows):
    """The counts of the table from the pairs of all seeds (dict of equal-length arrays).

    Returns a dict: ``pairs``, ``matched``, ``tested``; ``perturbed``,
    ``perturbed_tested``, ``tp``, ``missed``, ``missed_tested``; ``clean``,
    ``clean_tested``, ``fp``, ``fp_rate``, ``fp_limit``; ``unmatched_flagged``;
    ``by_mass`` and ``by_shift``: lists of ``(label, perturbed, tested, tp)``.
    Unmatched pairs are neither perturbed nor clean.
    """
    matched = np.asarray(rows["matched"], dtype=bool)
    sub = np.asarray(rows["subhalo"], dtype=bool) & matched
    clean = ~np.asarray(rows["subhalo"], dtype=bool) & matched
    tested = np.asarray(rows["tested"], dtype=bool)
    flag = np.asarray(rows["anomalous"], dtype=bool)
    shift = np.asarray(rows["shift"], dtype=float)
    mass = np.asarray(rows["nearest_mass"], dtype=float)
    fp, clean_tested = int((clean & flag).sum()), int((clean & tested).sum())
    out = {
        "pairs": int(matched.size), "matched": int(matched.sum()), "tested": int(tested.sum()),
        "perturbed": int(sub.sum()), "perturbed_tested": int((sub & tested).sum()),
        "tp": int((sub & flag).sum()), "missed": int((sub & ~flag).sum()),
        "missed_tested": int((sub & ~flag & tested).sum()),
        "clean": int(clean.sum()), "clean_tested": clean_tested, "fp": fp,
        "fp_rate": fp / clean_tested if clean_tested else np.nan,
        "fp_limit": upper_limit(fp, clean_tested),
        "unmatched_flagged": int((~matched & flag).sum()),
    }
    status = np.asarray(rows["status"]) if "status" in rows else np.full(matched.size, "-")
    out["untested_status"] = {s: int((~tested & (status == s)).sum())
                              for s in sorted(set(status[~tested].tolist()))}

    def split(cuts):
        return [(label, int((sub & c).sum()), int((sub & c & tested).sum()),
                 int((sub & c & flag).sum())) for label, c in cuts]

    out["by_mass"] = split([(f"1e{np.log10(lo):.0f}-1e{np.log10(hi):.0f}",
                             (mass >= lo) & ((mass < hi) | (hi == MASS_BINS[-1]) & (mass == hi)))
                            for lo, hi in zip(MASS_BINS[:-1], MASS_BINS[1:], strict=True)])
    edges = (0.0, *SHIFT_EDGES, np.inf)
    out["by_shift"] = split([(f"< {hi:.2f}" if lo == 0 else f"{lo:.2f}-{hi:.2f}"
                              if np.isfinite(hi) else f">= {lo:.2f}",
                              (shift >= lo) & (shift < hi))
                             for lo, hi in zip(edges[:-1], edges[1:], strict=True)])
    return out


def summary_lines(t):
    """The summary table of :func:`tabulate`'s counts, as lines of text."""
    def pct(x):
        return "-" if not np.isfinite(x) else f"{100 * x:.1f} %"

    lines = [
        f"pairs measured {t['pairs']}, matched to a true pair {t['matched']}, "
        f"tested {t['tested']}; unmatched pairs flagged {t['unmatched_flagged']}",
        "untested pairs by mu_size_status: "
        + (", ".join(f"{s} {n}" for s, n in t["untested_status"].items()) or "none"),
        "",
        " pairs                      all  tested  flagged  not flagged",
        f" perturbed (subhalo)     {t['perturbed']:6d}  {t['perturbed_tested']:6d}  "
        f"{t['tp']:7d}  {t['missed']:11d}",
        f" clean                   {t['clean']:6d}  {t['clean_tested']:6d}  "
        f"{t['fp']:7d}  {t['clean'] - t['fp']:11d}",
        "",
        f"true positives: {t['tp']} of {t['perturbed']} perturbed pairs "
        f"({t['perturbed_tested']} tested; missed {t['missed']}, of which "
        f"{t['missed_tested']} tested)",
        f"false positives: {t['fp']} of {t['clean_tested']} clean pairs tested "
        f"(rate {pct(t['fp_rate'])}, one-sided {100 * CONFIDENCE:.0f} % Clopper-Pearson "
        f"upper limit {pct(t['fp_limit'])})",
        "",
        " perturbed pairs by the nearest sub-halo's mass [Msun]",
        "   mass           perturbed  tested  flagged  missed",
    ]
    lines += [f"   {label:13s} {n:10d}  {k:6d}  {f:7d}  {n - f:6d}" for label, n, k, f
              in t["by_mass"]]
    lines += ["", " perturbed pairs by |ln(mu_true/mu_macro)|",
              "   shift          perturbed  tested  flagged  missed"]
    lines += [f"   {label:13s} {n:10d}  {k:6d}  {f:7d}  {n - f:6d}" for label, n, k, f
              in t["by_shift"]]
    return lines


def main(argv=None):
    from lensdual.demo import DEMO_CDM_THRESHOLD

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--n-sources", type=int, default=12)
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rec.say("The demo's CDM population, flags against the pairs it perturbs "
            "(benchmarks/cdm_population_flags.py)")
    rec.say(f"simulate_demo(subhalo='cdm', n_sources={args.n_sources}), render_demo (point "
            f"scene), analyse (adaptive, geometric test, linearised SNR), seeds "
            f"{seeds.start}-{seeds.stop - 1}; perturbed: |ln(mu_true/mu_macro)| > "
            f"{DEMO_CDM_THRESHOLD:.3f}")
    rec.say("")
    rec.say("seed subhaloes expected pairs matched tested perturbed perturbed_matched "
            "true_pos false_pos cpu_s")
    rows, counts, cpu = [], [], 0.0
    for seed in seeds:
        r, meta, seconds = one(seed, args.n_sources)
        rows.append(r)
        cpu += seconds
        counts.append(meta["n_subhaloes"])
        t = tabulate(r)
        rec.say(f"{seed} {meta['n_subhaloes']} {meta['expected_subhaloes']:.1f} {t['pairs']} "
                f"{t['matched']} {t['tested']} {meta['n_subhalo_pairs']} {t['perturbed']} "
                f"{t['tp']} {t['fp']} {seconds:.0f}")
    pooled = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    counts = np.asarray(counts)
    rec.say("")
    rec.say(f"over {len(seeds)} seeds: sub-haloes drawn per seed {counts.min()}-{counts.max()} "
            f"(mean {counts.mean():.1f}); CPU {cpu / 60:.1f} min")
    for line in summary_lines(tabulate(pooled)):
        rec.say(line)
    rec.write(args.output)


if __name__ == "__main__":
    main()
