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
#: The scenarios as the table names them.
SCENARIOS = {"none": "no sub-halo", "overconcentrated": "over-concentrated"}


def read_record(path=RECORD):
    """The per-seed rows of the record (dicts with the seed, scenario, method, pairs,
    pairs tested, false flags and whether the sub-halo was flagged) and its summary,
    ``{(scenario, method): (clean pairs tested, false flags, seeds flagged or None)}``."""
    rows, summary = [], {}
    for line in Path(path).read_text().splitlines():
        words = line.split()
        if len(words) == 9 and words[0].isdigit():
            rows.append({"seed": int(words[0]), "scenario": words[1], "method": words[2],
                         "n": int(words[3]), "tested": int(words[4]),
                         "false": int(words[5]), "hit": words[6] == "True"})
        elif len(words) == 6 and words[0] in SCENARIOS:
            hits = None if words[5] == "-" else int(words[5].split("/")[0])
            summary[(words[0], words[1])] = (int(words[2]), int(words[3]), hits)
    return rows, summary


def _pct(num, den, digits=2):
    return f"{100 * num / den:.{digits}f}"


def compute(rows, summary):
    """The table's rows and the substitutions ``{name: text}``: the counts are the
    benchmark's summary, the clean pairs and the seeds come from its per-seed rows."""
    table = [["scenario", "estimator", "clean pairs tested", "false flags",
              "sub-halo flagged"]]
    sub = {}
    totals = {}
    for scenario, label in SCENARIOS.items():
        for method in ("adaptive", "quad2"):
            part = [r for r in rows if r["scenario"] == scenario and r["method"] == method]
            with_sub = scenario != "none"
            clean = sum(r["n"] - with_sub for r in part)
            tested, false, hits = summary[(scenario, method)]
            totals.setdefault(method, [0, 0])
            totals[method][0] += tested
            totals[method][1] += false
            table.append([label, method, f"{tested} of {clean}",
                          f"{false} ({_pct(false, tested)} %)",
                          f"{hits} of {len(part)} seeds" if with_sub else "--"])
            sub[f"dc_{method}_{scenario}_rate"] = _pct(false, tested)
            if with_sub:
                sub[f"dc_{method}_hits"] = f"{hits} of {len(part)}"
    for method, (tested, false) in totals.items():
        sub[f"dc_{method}_clean"] = str(tested)
        sub[f"dc_{method}_false"] = str(false)
        sub[f"dc_{method}_rate"] = _pct(false, tested)
    sub["dc_seeds"] = str(len({r["seed"] for r in rows}))
    fewest = min((r for r in rows if r["method"] == "adaptive"
                  and r["scenario"] == "overconcentrated"), key=lambda r: r["tested"])
    sub["dc_fewest_tested"] = str(fewest["tested"])
    sub["dc_fewest_seed"] = str(fewest["seed"])
    sub["dc_fewest_hit"] = "flagged" if fewest["hit"] else "missed"
    return table, sub


def files(rows, summary):
    """``{file name: text}`` of the table and the substitutions."""
    table, sub = compute(rows, summary)
    return {"demo_calibration.csv": csv_text(table), **include_files(sub)}


def main():
    write_files(files(*read_record()), OUT)


if __name__ == "__main__":
    main()
