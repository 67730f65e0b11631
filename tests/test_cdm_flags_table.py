"""benchmarks/cdm_population_flags.py: the counts of its table, on a synthetic truth table."""

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import beta as beta_dist

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from cdm_population_flags import summary_lines, tabulate  # noqa: E402


def synthetic(n=400, seed=5):
    rng = np.random.default_rng(seed)
    matched = rng.random(n) < 0.9
    tested = rng.random(n) < 0.6
    shift = np.abs(rng.normal(0, 0.2, n))
    subhalo = matched & (shift > 0.085)
    # flagged only where tested; perturbed pairs more often, large shifts most often
    flagged = tested & (rng.random(n) < np.where(subhalo, np.clip(2 * shift, 0, 1), 0.05))
    mass = 10 ** rng.uniform(8, 10, n)
    mass[:3] = (1e8, 1e9, 1e10)  # the edges: 1e9 in the upper bin, 1e10 in it too
    return {"matched": matched, "subhalo": subhalo, "tested": tested, "anomalous": flagged,
            "shift": np.where(matched, shift, np.nan),
            "nearest_mass": np.where(matched, mass, np.nan)}


def test_the_counts_of_the_cdm_flags_table():
    """True and false positives, misses and the splits, counted here pair by pair."""
    rows = synthetic()
    t = tabulate(rows)
    tp = fp = missed = missed_tested = clean = clean_tested = perturbed = 0
    mass_bins = {"1e8-1e9": [0, 0, 0], "1e9-1e10": [0, 0, 0]}
    shift_bins = {"< 0.10": [0, 0, 0], "0.10-0.25": [0, 0, 0], ">= 0.25": [0, 0, 0]}
    for i in range(len(rows["matched"])):
        if not rows["matched"][i]:
            continue
        flag, tested = rows["anomalous"][i], rows["tested"][i]
        if rows["subhalo"][i]:
            perturbed += 1
            tp += flag
            missed += not flag
            missed_tested += tested and not flag
            m, s = rows["nearest_mass"][i], rows["shift"][i]
            mk = "1e8-1e9" if m < 1e9 else "1e9-1e10"
            sk = "< 0.10" if s < 0.10 else ("0.10-0.25" if s < 0.25 else ">= 0.25")
            for bins, key in ((mass_bins, mk), (shift_bins, sk)):
                bins[key][0] += 1
                bins[key][1] += tested
                bins[key][2] += flag
        else:
            clean += 1
            clean_tested += tested
            fp += flag
    assert (t["perturbed"], t["tp"], t["missed"], t["missed_tested"]) == (
        perturbed, tp, missed, missed_tested)
    assert (t["clean"], t["clean_tested"], t["fp"]) == (clean, clean_tested, fp)
    assert tp > 0 and fp > 0 and missed > 0
    assert t["matched"] == t["perturbed"] + t["clean"]
    assert t["fp_rate"] == pytest.approx(fp / clean_tested)
    # the one-sided 95 % Clopper-Pearson upper limit
    assert t["fp_limit"] == pytest.approx(beta_dist.ppf(0.95, fp + 1, clean_tested - fp))
    assert {label: [n, k, f] for label, n, k, f in t["by_mass"]} == mass_bins
    assert {label: [n, k, f] for label, n, k, f in t["by_shift"]} == shift_bins
    text = "\n".join(summary_lines(t))
    assert f"true positives: {tp} of {perturbed} perturbed pairs" in text
    assert f"false positives: {fp} of {clean_tested} clean pairs tested" in text


def test_no_flag_gives_a_limit_and_no_clean_pair_tested_none():
    rows = synthetic(n=50)
    rows["anomalous"] = np.zeros(50, dtype=bool)
    t = tabulate(rows)
    n = t["clean_tested"]
    assert t["fp"] == t["tp"] == 0
    assert t["fp_limit"] == pytest.approx(1 - 0.05 ** (1 / n))
    rows["tested"] = np.zeros(50, dtype=bool)
    t = tabulate(rows)
    assert np.isnan(t["fp_rate"]) and np.isnan(t["fp_limit"])
    assert "rate -" in "\n".join(summary_lines(t))
