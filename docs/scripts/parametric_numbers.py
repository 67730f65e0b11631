"""Write the tables and numbers of the parametric-fits page.

The SMACS0723-analogue cases are read from ``docs/_static/parametric/cases.txt``,
the stored output of ``benchmarks/parametric_cases.py`` (seeded: every number
but the fit times is reproducible), into one CSV table per ``sigma_pos``
(``cases_006.csv``, ``cases_001.csv``) and ``numbers.inc`` in the same folder.
``numbers.inc`` also holds what the page quotes from ``demo.txt``
(``benchmarks/bench_demo_parametric.py``: what ``lensdual demo --parametric``
adds) and ``mcmc.txt`` (``benchmarks/bench_mcmc.py``: the emcee posterior's
cost and convergence). Run from the repository root after rerunning a
benchmark::

    python benchmarks/parametric_cases.py --output docs/_static/parametric/cases.txt
    python benchmarks/bench_demo_parametric.py --output docs/_static/parametric/demo.txt
    python benchmarks/bench_mcmc.py --output docs/_static/parametric/mcmc.txt
    python docs/scripts/parametric_numbers.py
"""

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _records import search  # noqa: E402
from _substitutions import csv_text, include_files, write_files  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "_static" / "parametric"

_SIGMA = re.compile(r"^sigma_pos = ([\d.]+) arcsec$")
_ROW = re.compile(r"^\((\w)\) (.+?)\s{2,}(\S+) / (\d+)\s+(\S+(?: %)?) / (\S+(?: %)?)\s+"
                  r"(\S+(?: %)?) / (\S+(?: %)?)\s+(\S+) / (\S+)\s+(\S+) / (\S+)\s+(\d+) s$")
_DETAIL = re.compile(r"^\s+worst pair: size (\d+), model (\d+); SNR of pair 1: size (\S+), "
                     r"model (\S+); best fit: (.*)$")
_SPREAD = re.compile(r"^\s+Laplace 1-sigma \(fitted space\) \[bounds\], draws on a bound: (.*)$")
_PARAM = re.compile(r"(\w+) \+-(\S+) \[(\S+), (\S+)\] (\d+) %")
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
        elif m := _SPREAD.match(line):
            row["spread"] = {name: {"width": width, "lower": lo, "upper": hi,
                                    "on_bound": int(pct)}
                             for name, width, lo, hi, pct in _PARAM.findall(m.group(1))}
    if not runs or not all(runs.values()):
        raise ValueError(f"{path}: not an output of parametric_cases.py")
    return runs


def _key(sigma):
    """``0.06`` -> ``006``: the name of a ``sigma_pos`` in files and substitutions."""
    return sigma.replace(".", "")


def tables(runs):
    """One CSV table per ``sigma_pos``: ``{"cases_<sigma>.csv": text}``."""
    files = {}
    for sigma, rows in runs.items():
        files[f"cases_{_key(sigma)}.csv"] = csv_text(
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
            on_bound = [par["on_bound"] for par in row["spread"].values()]
            sub[f"{key}_on_bound"] = f"{min(on_bound)}-{max(on_bound)}"
            e1 = row["spread"]["e1"]
            sub[f"{key}_e1_width"] = e1["width"]
            sub[f"{key}_e1_bound"] = e1["upper"]
    sigmas = sorted(runs, key=float)
    coarse, fine = runs[sigmas[-1]]["a"], runs[sigmas[0]]["a"]
    sub["par_size_err_shrink"] = f"{float(coarse['relerr_size']) / float(fine['relerr_size']):.0f}"
    return sub


def demo_numbers(path):
    """``bench_demo_parametric.py``: the fit's cost and result in the demo."""
    lines = Path(path).read_text().splitlines()
    m = search(r"^\s+added by the fit\s+(-?[\d.]+) s / \s*(-?[\d.]+) s$", lines, path)
    sub = {"par_demo_added_wall": f"{float(m.group(1)):.0f}",
           "par_demo_added_cpu": f"{float(m.group(2)):.0f}"}
    m = search(r"^fit: chi2 = ([\d.]+) for (\d+) degrees of freedom$", lines, path)
    sub["par_demo_chi2"], sub["par_demo_dof"] = m.groups()
    m = search(r"^pairs that break duality against the fitted model: (\d+)$", lines, path)
    sub["par_demo_model_flags"] = m.group(1)
    m = search(r"^pairs the geometric test flags: pair (\d+) at SNR ([\d.]+)$", lines, path)
    sub["par_demo_snr"] = f"{float(m.group(2)):.0f}"
    return sub


def mcmc_numbers(path):
    """``bench_mcmc.py``: autocorrelation times and the cost of the emcee chain."""
    lines = Path(path).read_text().splitlines()
    sub = {}
    for line in lines:
        m = re.match(r"^sigma_pos = ([\d.]+) arcsec, n_mcmc = (\d+): (\d+) walkers x (\d+) "
                     r"steps, (\d+) burn-in; largest tau (\d+) steps, kept steps / tau (\d+); "
                     r"chain ([\d.]+) s, ([\d.]+) ms per evaluation$", line)
        if m is None:
            continue
        key = f"par_mcmc{_key(m.group(1))}"
        walkers, steps, burn, tau = (int(m.group(i)) for i in (3, 4, 5, 6))
        sub[f"{key}_n"] = m.group(2)
        sub[f"{key}_steps"] = str(steps)
        sub[f"{key}_kept"] = str(steps - burn)
        sub[f"{key}_tau"] = str(tau)
        sub[f"{key}_n_tau"] = m.group(7)
        sub[f"{key}_chain"] = f"{float(m.group(8)):.0f}"
        sub[f"{key}_per_eval"] = f"{float(m.group(9)):.1f}"
        # the evaluations for 50 tau of kept steps when a quarter is burn-in
        needed = 50 * tau * walkers * 4 / 3
        sub[f"{key}_needed"] = f"{round(needed, -4):.0f}"
    if not sub:
        raise ValueError(f"{path}: no runs")
    return sub


def compute(folder=OUT):
    """``({file name: text}, substitutions)`` from the stored runs under ``folder``."""
    runs = read(folder / "cases.txt")
    sub = numbers(runs) | demo_numbers(folder / "demo.txt") | mcmc_numbers(folder / "mcmc.txt")
    return tables(runs) | include_files(sub), sub


def main(out=OUT):
    """Write the files into ``out`` (the docs' folder by default); returns the substitutions."""
    files, sub = compute()
    write_files(files, out)
    return sub


if __name__ == "__main__":
    main()
