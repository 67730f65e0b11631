"""Write the tables and numbers of the parametric-fits page's SMACS0723-analogue cases.

They are read from ``docs/_static/parametric/cases.txt``, the stored output of
``benchmarks/parametric_cases.py`` (seeded: every number but the fit times is
reproducible), into one CSV table per ``sigma_pos`` (``cases_006.csv``,
``cases_001.csv``) and ``numbers.inc`` in the same folder. Run from the
repository root after rerunning the benchmark::

    python benchmarks/parametric_cases.py --output docs/_static/parametric/cases.txt
    python docs/scripts/parametric_numbers.py
"""

import csv
import io
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _substitutions import include_files  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "_static" / "parametric"

_SIGMA = re.compile(r"^sigma_pos = ([\d.]+) arcsec$")
_ROW = re.compile(r"^\((\w)\) (.+?)\s{2,}(\S+) / (\d+)\s+(\S+(?: %)?) / (\S+(?: %)?)\s+"
                  r"(\S+(?: %)?) / (\S+(?: %)?)\s+(\S+) / (\S+)\s+(\S+) / (\S+)\s+(\d+) s$")
_DETAIL = re.compile(r"^\s+worst pair: size (\d+), model (\d+); SNR of pair 1: size (\S+), "
                     r"model (\S+); best fit: (.*)$")
_FIELDS = ("chi2", "dof", "size_med", "size_max", "model_med", "model_max", "relerr_size",
           "relerr_model", "flag_size", "flag_model", "time")


def read(path):
    """``{sigma_pos text: {case letter: row}}`` of a stored run; a row holds the
    table's cells (text), the pair-1 SNRs, the worst pairs and the best fit."""
    runs, rows = {}, None
    for line in Path(path).read_text().splitlines():
        if m := _SIGMA.match(line):
            rows = runs[m.group(1)] = {}
        elif m := _ROW.match(line):
            row = rows[m.group(1)] = {"label": f"({m.group(1)}) {m.group(2)}"}
            row |= dict(zip(_FIELDS, m.groups()[2:], strict=True))
        elif m := _DETAIL.match(line):
            row["worst_size"], row["worst_model"] = int(m.group(1)), int(m.group(2))
            row["snr_size"], row["snr_model"] = m.group(3), m.group(4)
            row["best"] = {k.split(".")[-1]: float(v)
                           for k, v in re.findall(r"(\S+)=([-\d.e+]+)", m.group(5))}
    if not runs or not all(runs.values()):
        raise ValueError(f"{path}: not an output of parametric_cases.py")
    return runs


def _key(sigma):
    """``0.06`` -> ``006``: the name of a ``sigma_pos`` in files and substitutions."""
    return sigma.replace(".", "")


def _csv(rows):
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows(rows)
    return out.getvalue()


def tables(runs):
    """One CSV table per ``sigma_pos``: ``{"cases_<sigma>.csv": text}``."""
    files = {}
    for sigma, rows in runs.items():
        files[f"cases_{_key(sigma)}.csv"] = _csv(
            [r["label"], f"{r['chi2']} / {r['dof']}", f"{r['size_med']} / {r['size_max']}",
             f"{r['model_med']} / {r['model_max']}",
             f"{r['relerr_size']} / {r['relerr_model']}",
             f"{r['flag_size']} / {r['flag_model']}", f"{r['time']} s"]
            for r in rows.values())
    return files


def numbers(runs):
    """``par<sigma>_<case>_<field>`` for every cell and SNR, the best fit's ``Rs``,
    and how much ``mu_size``'s errors shrink from the largest to the smallest
    ``sigma_pos`` (case (a))."""
    sub = {}
    for sigma, rows in runs.items():
        for case, row in rows.items():
            key = f"par{_key(sigma)}_{case}"
            for field in (*_FIELDS, "snr_size", "snr_model"):
                sub[f"{key}_{field}"] = row[field]
            sub[f"{key}_rs"] = f"{row['best']['Rs']:.0f}"
    sigmas = sorted(runs, key=float)
    coarse, fine = runs[sigmas[-1]]["a"], runs[sigmas[0]]["a"]
    sub["par_size_err_shrink"] = f"{float(coarse['relerr_size']) / float(fine['relerr_size']):.0f}"
    return sub


def compute(folder=OUT):
    """``({file name: text}, substitutions)`` from the stored run under ``folder``."""
    runs = read(folder / "cases.txt")
    sub = numbers(runs)
    return tables(runs) | include_files(sub), sub


def main(out=OUT):
    """Write the files into ``out`` (the docs' folder by default); returns the substitutions."""
    files, sub = compute()
    for name, text in files.items():
        (Path(out) / name).write_text(text)
    print(files["numbers.inc"], end="")
    return sub


if __name__ == "__main__":
    main()
