"""Write the tutorial's table of the demo over 30 seeds and the numbers the
tutorial, the calibration page and the method page quote from it, from the
stored output of ``benchmarks/demo_calibration.py``
(``docs/_static/tutorial/demo_calibration.txt``): ``demo_calibration.csv`` and
``numbers.inc`` in that folder. Run from the repository root after rerunning
the benchmark (``python benchmarks/demo_calibration.py --seeds 30 --output
docs/_static/tutorial/demo_calibration.txt``)::

    python docs/scripts/demo_calibration_numbers.py
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _substitutions import csv_text, include_files, write_files  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "_static" / "tutorial"
RECORD = OUT / "demo_calibration.txt"
#: The scenarios as the table names them (the concentrations are those of
#: `lensdual.simulation.SUBHALOES`: c = 100 and the mass-concentration relation's
#: 28.6 at 1e8 Msun).
SCENARIOS = {"none": "no sub-halo", "overconcentrated": "over-concentrated (c = 100)",
             "small": "on the MCR (c = 28.6)"}
#: The methods as the table names them: the adaptive estimator under the geometric
#: test with the linearised SNR, quad2, the adaptive estimator under the joint test
#: with the linearised SNR, and the defaults (the joint test with the conservative SNR).
METHODS = {"adaptive": "adaptive, geometric test", "quad2": "quad2",
           "joint": "adaptive, joint test", "default": "default (joint, conservative SNR)"}
#: The methods with a flux field.
JOINT = ("joint", "default")
#: The demo target of the joint test (issue 32): at most this many per cent false
#: flags among the clean pairs tested ...
TARGET_RATE = 0.5
#: ... and the over-concentrated sub-halo flagged in at least this many of 30 seeds.
TARGET_HITS = 29


def read_record(path=RECORD):
    """The per-seed rows of the record (dicts with the seed, scenario, method, pairs,
    pairs tested, false flags, whether the sub-halo was flagged and, for the joint
    test, how many pairs had a flux-field prediction, else None) and its summary,
    ``{(scenario, method): (clean pairs tested, false flags, seeds flagged or None,
    (pairs with a field, pairs) or None)}``."""
    rows, summary = [], {}
    for line in Path(path).read_text().splitlines():
        words = line.split()
        if len(words) == 10 and words[0].isdigit():
            rows.append({"seed": int(words[0]), "scenario": words[1], "method": words[2],
                         "n": int(words[3]), "tested": int(words[4]),
                         "false": int(words[5]), "hit": words[6] == "True",
                         "significance": float(words[8]),
                         "field_ok": None if words[9] == "-" else int(words[9])})
        elif len(words) == 7 and words[0] in SCENARIOS:
            hits = None if words[5] == "-" else int(words[5].split("/")[0])
            field = None if words[6] == "-" else tuple(int(w) for w in words[6].split("/"))
            summary[(words[0], words[1])] = (int(words[2]), int(words[3]), hits, field)
    return rows, summary


def _pct(num, den, digits=2):
    return f"{100 * num / den:.{digits}f}"


def compute(rows, summary):
    """The table's rows and the substitutions ``{name: text}``: the counts are the
    benchmark's summary, the clean pairs and the seeds come from its per-seed rows.

    ``dc_<method>_<scenario>_rate``: false flags per scenario (per cent);
    ``dc_<method>_hits`` and ``dc_<method>_small_hits``: seeds where the
    over-concentrated and the mass-concentration-relation sub-halo were flagged;
    ``dc_<method>_clean``, ``_false``, ``_rate``: pooled over the three scenarios."""
    table = [["scenario", "estimator", "clean pairs tested", "false flags",
              "sub-halo flagged"]]
    sub = {}
    totals = {}
    runs = {}
    for scenario, label in SCENARIOS.items():
        for method, name in METHODS.items():
            part = [r for r in rows if r["scenario"] == scenario and r["method"] == method]
            with_sub = scenario != "none"
            clean = sum(r["n"] - with_sub for r in part)
            tested, false, hits, _ = summary[(scenario, method)]
            totals.setdefault(method, [0, 0])
            totals[method][0] += tested
            totals[method][1] += false
            table.append([label, name, f"{tested} of {clean}",
                          f"{false} ({_pct(false, tested)} %)",
                          f"{hits} of {len(part)} seeds" if with_sub else "--"])
            sub[f"dc_{method}_{scenario}_rate"] = _pct(false, tested)
            if with_sub:
                key = "hits" if scenario == "overconcentrated" else f"{scenario}_hits"
                sub[f"dc_{method}_{key}"] = f"{hits} of {len(part)}"
                runs[(scenario, method)] = (hits, len(part))
    for method, (tested, false) in totals.items():
        sub[f"dc_{method}_clean"] = str(tested)
        sub[f"dc_{method}_false"] = str(false)
        sub[f"dc_{method}_rate"] = _pct(false, tested)
    sub["dc_quad2_max_rate"] = max((sub[f"dc_quad2_{s}_rate"] for s in SCENARIOS), key=float)
    sub["dc_seeds"] = str(len({r["seed"] for r in rows}))
    fewest = min((r for r in rows if r["method"] == "adaptive"
                  and r["scenario"] == "overconcentrated"), key=lambda r: r["tested"])
    sub["dc_fewest_tested"] = str(fewest["tested"])
    sub["dc_fewest_seed"] = str(fewest["seed"])
    sub["dc_fewest_hit"] = "flagged" if fewest["hit"] else "missed"
    # the joint tests: how many pairs had a flux-field prediction, and the demo target
    sub["dc_target_rate"] = f"{TARGET_RATE}"
    sub["dc_target_hits"] = f"{TARGET_HITS} of 30"
    geometric = {(r["seed"], r["scenario"]): (r["tested"], r["false"], r["hit"])
                 for r in rows if r["method"] == "adaptive"}
    for method in JOINT:
        field = [s[3] for (_, m), s in summary.items() if m == method]
        sub[f"dc_{method}_field_ok"] = str(sum(f[0] for f in field))
        sub[f"dc_{method}_field_pairs"] = str(sum(f[1] for f in field))
        n_runs = sum(r["method"] == method for r in rows)
        sub[f"dc_{method}_runs"] = str(n_runs)
        differ = sum((r["tested"], r["false"], r["hit"])
                     != geometric[(r["seed"], r["scenario"])]
                     for r in rows if r["method"] == method)
        sub[f"dc_{method}_vs_geometric"] = (
            "the same as the geometric test's in every run" if differ == 0 else
            f"different from the geometric test's in {differ} of {n_runs} runs")
        hits, n_hit_runs = runs[("overconcentrated", method)]
        tested, false = totals[method]
        met = 100 * false <= TARGET_RATE * tested and 30 * hits >= TARGET_HITS * n_hit_runs
        sub[f"dc_{method}_target"] = "meets" if met else "does not meet"
    # the over-concentrated sub-halo where the default missed it, against the
    # linearised geometric test on the same pairs
    sig = {(r["seed"], r["method"]): r["significance"] for r in rows
           if r["scenario"] == "overconcentrated"}
    missed = [r["seed"] for r in rows if r["method"] == "default"
              and r["scenario"] == "overconcentrated" and not r["hit"]]
    sub["dc_default_missed"] = ("none" if not missed else "; ".join(
        f"seed {k}, significance {sig[(k, 'default')]:.1f} against "
        f"{sig[(k, 'adaptive')]:.1f} with the linearised SNR" for k in missed))
    return table, sub


def files(rows, summary):
    """``{file name: text}`` of the table and the substitutions."""
    table, sub = compute(rows, summary)
    return {"demo_calibration.csv": csv_text(table), **include_files(sub)}


def main():
    write_files(files(*read_record()), OUT)


if __name__ == "__main__":
    main()
