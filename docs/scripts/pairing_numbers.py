"""Write the tables and numbers the pairing page quotes from the stored benchmark outputs.

- ``docs/_static/pairing/accuracy.txt``: ``benchmarks/pairing_accuracy.py
  --output docs/_static/pairing/accuracy.txt`` (random maps, and the SMACS0723
  analogue) gives ``accuracy.csv``, ``smacs.csv`` and the numbers of the
  accuracy section;
- ``docs/_static/performance/scale_pairing.txt``:
  ``benchmarks/bench_scale_pairing.py`` (the performance page's record: true
  pairs buried in spurious candidates) gives the numbers of the section on
  chance maps.

All go to ``docs/_static/pairing/`` (the numbers to ``numbers.inc``). Run from
the repository root after rerunning a benchmark::

    python docs/scripts/pairing_numbers.py
"""

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _substitutions import csv_text, include_files, value_range, write_files  # noqa: E402
from performance_numbers import read_scale_pairing  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "docs" / "_static"
OUT = STATIC / "pairing"

#: The rows whose per-system time the page quotes (case -> short name).
TIMED = {"m = 12, sigma = 0.005\"": "15", "m = 24": "30"}

_NN = re.compile(r"^median nearest-neighbour distance on L2 \(m = 12\): ([\d.]+) arcsec$")
_CASE = re.compile(r"^(.+?)\s+(\d+)\s+(\d+ \+ \d+)\s+([\d.]+)%\s+(\d+)%\s+(\d+)\s+(\d+)\s+(\d+)"
                   r"\s+(\d+)$")
_SMACS_HEAD = re.compile(r"^SMACS0723 analogue, seeds (\d+-\d+): (\d+) true pairs among "
                         r"(\d+ \+ \d+) points$")
_SMACS_GEOMETRY = re.compile(r"^  median \|det A\| \(mu_true\) ([\d.]+); nearest-neighbour "
                             r"distance on L2: median ([\d.]+) arcsec, smallest ([\d.]+) arcsec; "
                             r"largest residual of an affine map fitted to the true pairs "
                             r"([\d.]+) arcsec$")
_SMACS = re.compile(r"^(.+?)\s+(\d+)\s+([\d.]+)%\s+(\d+)%\s+(\d+)\s+(\d+)\s+(\d+)\s+(\d+)$")
_UNRELATED = re.compile(r"^unrelated catalogues, (\d+) \+ \d+ points, \d+ seeds, without the "
                        r"decoy check: (\d+-\d+) pairs$")
_REFUSED = re.compile(r"^refused: (.+), seed (\d+); without the decoy check "
                      r"(?:(\d+) of (\d+) right, (\d+) wrong|refused)$")
_BROUGHT = re.compile(r"the best map brings (\d+) of")


def read_accuracy(path):
    """The tables of a ``pairing_accuracy.py`` output.

    Returns
    -------
    result : dict
        ``nn`` (the median nearest-neighbour distance on L2, arcsec), ``cases``
        and ``smacs`` (one dict per row), ``refused`` (one dict per refused
        system: its case and seed, and the pairing without the decoy check),
        ``smacs_head`` (seeds, true pairs, points and geometry of the
        analogue) and ``unrelated`` (points per catalogue -> range of the
        pairs found on unrelated catalogues).
    """
    result = {"cases": [], "smacs": [], "refused": [], "unrelated": {}}
    for line in Path(path).read_text().splitlines():
        if m := _NN.match(line):
            result["nn"] = float(m.group(1))
        elif m := _SMACS_HEAD.match(line):
            result["smacs_head"] = dict(zip(("seeds", "true", "points"), m.groups(), strict=True))
        elif m := _SMACS_GEOMETRY.match(line):
            result["smacs_head"] |= dict(zip(("det", "nn", "nn_min", "affine"), m.groups(),
                                             strict=True))
        elif m := _UNRELATED.match(line):
            result["unrelated"][m.group(1)] = m.group(2)
        elif m := _REFUSED.match(line):
            case, seed, right, true, wrong = m.groups()
            result["refused"].append({"case": case, "seed": int(seed), "right": right,
                                      "true": true, "wrong": wrong})
        elif (m := _CASE.match(line)) and "smacs_head" not in result:
            names = ("systems", "points", "found", "clean", "max_wrong", "refused",
                     "quadratic", "ms")
            result["cases"].append({"case": m.group(1), **dict(zip(names, m.groups()[1:],
                                                                   strict=True))})
        elif (m := _SMACS.match(line)) and "smacs_head" in result:
            names = ("systems", "found", "clean", "max_wrong", "refused", "quadratic", "ms")
            result["smacs"].append({"case": m.group(1), **dict(zip(names, m.groups()[1:],
                                                                   strict=True))})
    for key in ("nn", "smacs_head"):
        if key not in result:
            raise ValueError(f"{path}: no {key} line")
    if not result["cases"] or not result["smacs"] or not result["unrelated"]:
        raise ValueError(f"{path}: a table is empty")
    return result


def case_label(case, nn=None):
    """The page's label of a case: reST math, and the noise in units of the
    median nearest-neighbour distance ``nn`` (when given)."""
    label = case.replace("|det A|", r":math:`|\det A|`")
    m = re.search(r'sigma = ([\d.]+)"', label)
    if m:
        label = label.replace("sigma", r":math:`\sigma`")
        if nn is not None:
            label += f" (~{100 * float(m.group(1)) / nn:.1f} % NN)"
    return label


def tables(acc):
    """``{"accuracy.csv": text, "smacs.csv": text}``: the page's two tables."""
    rows = [[case_label(r["case"], acc["nn"]), r["points"], f"{r['found']} %",
             f"{r['clean']} %", r["max_wrong"], r["refused"]] for r in acc["cases"]]
    smacs = [[r["case"], f"{r['found']} %", f"{r['clean']} %", r["max_wrong"], r["refused"]]
             for r in acc["smacs"]]
    return {"accuracy.csv": csv_text(rows), "smacs.csv": csv_text(smacs)}


def accuracy_numbers(acc):
    """The substitutions read from the accuracy run."""
    cases = acc["cases"]
    systems = [int(r["systems"]) for r in cases]
    sub = {"pair_nn": f"{acc['nn']:.2g}", "pair_systems": str(max(systems)),
           "pair_systems_few": str(min(systems)), "pair_systems_total": str(sum(systems)),
           "pair_refused_total": str(sum(int(r["refused"]) for r in cases))}
    by_case = {r["case"]: r for r in cases}
    for case, short in TIMED.items():
        sub[f"pair_ms{short}"] = by_case[case]["ms"]
        sub[f"pair_points{short}"] = by_case[case]["points"]
    parts = []
    for case in dict.fromkeys(r["case"] for r in acc["refused"]):
        rows = [r for r in acc["refused"] if r["case"] == case]
        paired = [r for r in rows if r["right"] is not None]
        text = f"{len(rows)} with {case_label(case)}"
        if paired:
            text += (f", paired without the check with "
                     f"{value_range([int(r['right']) for r in paired], '{}')} of "
                     f"{value_range([int(r['true']) for r in paired], '{}')} pairs right and "
                     f"{value_range([int(r['wrong']) for r in paired], '{}')} wrong")
        parts.append(text)
    sub["pair_refused_detail"] = "; ".join(parts) or "none"
    head = acc["smacs_head"]
    for key in ("seeds", "true", "points", "det"):
        sub[f"pair_smacs_{key}"] = head[key]
    for key in ("nn", "nn_min", "affine"):
        sub[f"pair_smacs_{key}"] = f"{float(head[key]):.2g}"
    noise_free = acc["smacs"][0]
    if noise_free["case"] != "none":
        raise ValueError("the analogue's first row is the noise-free one")
    sub["pair_smacs_quadratic"] = f"{noise_free['quadratic']} of {noise_free['systems']}"
    for points, pairs in acc["unrelated"].items():
        sub[f"pair_unrelated{points}"] = pairs
    return sub


def crowded_numbers(runs):
    """The substitutions read from the crowded pairings of ``bench_scale_pairing.py``."""
    crowded = [r for r in runs if r["spurious"] > 0]
    spurious = sorted({r["spurious"] for r in crowded})
    sub = {"pair_crowd_true": str(crowded[0]["true"]),
           "pair_crowd_spurious": f"{spurious[0]}-{spurious[-1]}"}
    for fluxes, short in ((False, "pos"), (True, "flux")):
        rows = [r for r in crowded if r["fluxes"] == fluxes]
        refused = [r for r in rows if r["note"]]
        sub[f"pair_crowd_{short}_cases"] = str(len(rows))
        sub[f"pair_crowd_{short}_refused"] = str(len(refused))
        sub[f"pair_crowd_{short}_paired"] = str(len(rows) - len(refused))
        brought = [int(_BROUGHT.search(r["note"]).group(1)) for r in refused]
        sub[f"pair_crowd_{short}_brought"] = value_range(brought, "{}") if brought else "--"
    return sub


def compute(folder=STATIC):
    """The tables and substitutions from the stored outputs under ``folder``:
    ``({name: csv text}, {substitution: text})``."""
    acc = read_accuracy(folder / "pairing" / "accuracy.txt")
    sub = accuracy_numbers(acc)
    sub |= crowded_numbers(read_scale_pairing(folder / "performance" / "scale_pairing.txt"))
    return tables(acc), sub


def main(out=OUT):
    """Write ``numbers.inc`` and the tables into ``out`` (the docs' folder by
    default); returns the substitutions."""
    csv_files, sub = compute()
    write_files(include_files(sub) | csv_files, out)
    return sub


if __name__ == "__main__":
    main()
