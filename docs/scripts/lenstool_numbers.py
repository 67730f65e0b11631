"""Write the table and numbers of the Lenstool page's experiment on the real cluster.

They are read from ``docs/_static/lenstool/real_model.txt``, the stored output
of ``benchmarks/real_model_constellation.py`` (which needs the SMACS0723
Lenstool model), into ``real_model.csv`` and ``numbers.inc`` in the same
folder. Run from the repository root after rerunning the benchmark::

    python benchmarks/real_model_constellation.py --output docs/_static/lenstool/real_model.txt
    python docs/scripts/lenstool_numbers.py
"""

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _substitutions import include_files, write_files  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "_static" / "lenstool"

_HEAD = re.compile(r"^system 4 at z = ([\d.]+), source centre .* arcsec; sigma = ([\d.]+) arcsec$")
_CASE = re.compile(r"^N = (\d+) sources, (\d+) constellations, (\d+) pairs, true ratios "
                   r"([\d.]+)-([\d.]+)$")
_ROW = re.compile(r"^\s+(\w+)\s+median \|err\|\s+([\d.]+) %\s+68 % half width\s+([\d.]+) %\s+"
                  r"95 % \|err\|\s+([\d.]+) %$")


def read(path):
    """The settings and the rows (one per number of sources and method) of a stored run."""
    head, cases, rows = None, [], []
    for line in Path(path).read_text().splitlines():
        if m := _HEAD.match(line):
            head = {"z": m.group(1), "sigma": m.group(2)}
        elif m := _CASE.match(line):
            cases.append(dict(zip(("n", "seeds", "pairs", "lo", "hi"), m.groups(), strict=True)))
        elif m := _ROW.match(line):
            rows.append({"n": cases[-1]["n"], "method": m.group(1), "median": m.group(2),
                         "half68": m.group(3), "p95": m.group(4)})
    if head is None or not rows:
        raise ValueError(f"{path}: not an output of real_model_constellation.py")
    return head, cases, rows


def compute(folder=OUT):
    """``({file name: text}, substitutions)`` from the stored run under ``folder``."""
    head, cases, rows = read(folder / "real_model.txt")
    table = "".join(f"{r['n']}, {r['method']}, {r['median']} %, {r['half68']} %, {r['p95']} %\n"
                    for r in rows)
    lo = min(float(c["lo"]) for c in cases)
    hi = max(float(c["hi"]) for c in cases)
    seeds = {c["seeds"] for c in cases}
    if len(seeds) != 1:
        raise ValueError("the numbers of sources were run on different numbers of seeds")
    sub = {"lt_real_z": head["z"], "lt_real_sigma": head["sigma"],
           "lt_real_ratios": f"{lo:.2f}-{hi:.2f}", "lt_real_seeds": seeds.pop()}
    return {"real_model.csv": table} | include_files(sub), sub


def main(out=OUT):
    """Write the files into ``out`` (the docs' folder by default); returns the substitutions."""
    files, sub = compute()
    write_files(files, out)
    return sub


if __name__ == "__main__":
    main()
