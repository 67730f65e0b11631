"""Write docs/_static/photometry/numbers.inc and the CSV tables the photometry page
quotes.

The speed numbers are read from ``docs/_static/photometry/speed.txt``, the output
of ``benchmarks/bench_photometry.py``; the accuracy tables and numbers from
``docs/_static/photometry/accuracy.txt``, the output of
``benchmarks/photometry_accuracy.py`` (first lines of both: the cores and the
load average they were run at), so the page cannot drift from them. Run from
the repository root after rerunning the benchmarks::

    python benchmarks/bench_photometry.py --repeat 5 --output docs/_static/photometry/speed.txt
    python benchmarks/photometry_accuracy.py --output docs/_static/photometry/accuracy.txt
    python docs/scripts/photometry_numbers.py
"""

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _records import header, read_lines, search  # noqa: E402
from _substitutions import csv_text, include_files, value_range, write_files  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "_static" / "photometry"

#: The background strategies timed per isolated source; the first is the reference.
STRATEGIES = ("ridge", "plane", "residual")


def compute(folder=OUT):
    """The substitutions (name -> text) from the stored output under ``folder``."""
    path = folder / "speed.txt"
    lines = path.read_text().splitlines()
    sub = dict(zip(("phot_cores", "phot_load"), header(path), strict=True))
    m = search(r"^isolated sources: (\d+) on a (\d+) x (\d+) arc image", lines, path)
    sub["phot_iso_n"] = m.group(1)
    sub["phot_iso_shape"] = f"{m.group(2)} x {m.group(3)}"
    for strategy in STRATEGIES:
        m = search(rf"^{strategy}\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)$", lines, path)
        sub[f"phot_{strategy}_ms"] = f"{float(m.group(2)):.0f}"
        sub[f"phot_{strategy}_ratio"] = f"{float(m.group(3)):.1f}"
    m = search(r"^large image: (\d+) sources on (\d+) x (\d+) px", lines, path)
    sub["phot_large_n"] = m.group(1)
    sub["phot_large_shape"] = f"{m.group(2)} x {m.group(3)}"
    for label, short in (("psf=FWHM", "psf"), ("psf=None", "nopsf")):
        m = search(rf"^\s+{label}: wall ([\d.]+) s, CPU ([\d.]+) s$", lines, path)
        sub[f"phot_large_{short}"] = f"{float(m.group(2)):.1f}"
    m = search(r"psf=None / psf=FWHM, CPU: ([\d.]+)$", lines, path)
    sub["phot_nopsf_ratio"] = f"{float(m.group(1)):.1f}"
    m = search(r"^high-pass filter \(sigma ([\d.]+) px\) removes ([\d.]+) % of the "
               r"least-squares flux of a ([\d.]+) px FWHM", lines, path)
    sub["phot_highpass_loss"] = f"{float(m.group(2)):.0f}"
    return sub


#: The background strategies of the accuracy tables, in their order, as the page
#: names them.
ACCURACY_ORDER = ("none", "local", "constant", "plane", "quadratic", "residual",
                  "residual-plane", "ridge")


def read_accuracy(path):
    """The tables of the stored output of ``benchmarks/photometry_accuracy.py``:
    ``{title line: {row label: {column: number}}}``. A table is the indented lines
    under its title from the first one without numbers, its column names; a row's
    label is the words before its numbers (an SNR bin's ``5 - 10``, a variant's
    ``radius 80 px``)."""
    tables, title, columns = {}, None, None
    for line in read_lines(path):
        words = line.split()
        if not line.startswith("  "):
            title, columns = line, None
        elif not any(_is_number(w) for w in words):
            columns = words[1:]
            tables[title] = {}
        elif columns is not None and len(words) > len(columns):
            label = " ".join(words[: len(words) - len(columns)])
            values = [float(w) for w in words[len(words) - len(columns):]]
            tables[title][label] = dict(zip(columns, values, strict=True))
    return tables


def _is_number(word):
    try:
        float(word)
    except ValueError:
        return False
    return True


def section(tables, prefix, path):
    """The title starting with ``prefix`` and its table."""
    for title, rows in tables.items():
        if title.startswith(prefix):
            return title, rows
    raise ValueError(f"{path}: no table {prefix!r}")


def _small(x, signed=False):
    """Two decimals below 2 in absolute value, one above."""
    sign = "+" if signed else ""
    return f"{x:{sign}.2f}" if abs(x) < 2 else f"{x:{sign}.1f}"


def _name(strategy, bold):
    return "**ridge** (default)" if bold else f'``"{strategy}"``'


def comparison_rows(rows, columns):
    """CSV rows of a comparison table: ``columns`` of each strategy, the default bold."""
    fmt = {"med_ln": lambda x: f"{x:+.3f}".replace("-0.000", "+0.000"),
           "med_abs_ln": lambda x: f"{x:.3f}",
           "pull_mean": lambda x: _small(x, True), "pull_std": _small,
           "err_crb": lambda x: f"{x:.2f}", "pos_rms": lambda x: f"{x:.3f}",
           "pos_pull_std": _small}
    out = []
    for strategy in ACCURACY_ORDER:
        bold = strategy == "ridge"
        cells = [fmt[c](rows[strategy][c]) for c in columns]
        if bold:
            cells = [v if c == "err_crb" else f"**{v}**" for c, v in
                     zip(columns, cells, strict=True)]
        out.append([_name(strategy, bold), *cells])
    return out


def accuracy(folder=OUT):
    """The substitutions and the CSV tables (file name -> text) of the accuracy study."""
    path = folder / "accuracy.txt"
    sections = read_accuracy(path)
    lines = read_lines(path)
    sub, files = {}, {}
    m = search(r"^photometry accuracy: realisations (\d+) per comparison table, (\d+) "
               r"for the SNR table, (\d+) per variant", lines, path)
    sub["phot_acc_real"], sub["phot_acc_snr_real"], sub["phot_acc_var_real"] = m.groups()
    for peak in ("40", "100"):
        m = search(rf"^comparison, A = {peak}: (\d+) sources on the arc", lines, path)
        sub[f"phot_acc_n{peak}"] = m.group(1)
    noise = [search(r"^  crest noise ([\d.]+); source peaks ([\d.]+) - ([\d.]+) times",
                    lines[lines.index(title) + 1:], path)
             for title in (section(sections, f"comparison, A = {peak}:", path)[0]
                           for peak in ("40", "100"))]
    sub["phot_acc_noise40"] = f"{float(noise[0].group(1)):.1f}"
    sub["phot_acc_peaks40"] = (f"{float(noise[0].group(2)):.1f} - "
                               f"{float(noise[0].group(3)):.0f}")
    sub["phot_acc_noise100"] = f"{float(noise[1].group(1)):.1f}"
    _, a40 = section(sections, "comparison, A = 40:", path)
    _, a100 = section(sections, "comparison, A = 100:", path)
    files["comparison_40.csv"] = csv_text(comparison_rows(
        a40, ("med_ln", "med_abs_ln", "pull_mean", "pull_std", "err_crb", "pos_rms",
              "pos_pull_std")))
    files["comparison_100.csv"] = csv_text(comparison_rows(
        a100, ("med_abs_ln", "pull_std", "err_crb", "pos_rms")))
    title, a0 = section(sections, "comparison, A = 0:", path)
    sub["phot_acc_n0"] = re.search(r": (\d+) all sources", title).group(1)
    sub["phot_acc_zero_ln"] = f"{max(abs(r['med_ln']) for r in a0.values()):.3f}"
    sub["phot_acc_zero_pull"] = value_range([r["pull_std"] for r in a0.values()], "{:.2f}",
                                            "")
    sub["phot_acc_zero_pos"] = value_range([r["pos_pull_std"] for r in a0.values()],
                                           "{:.2f}")
    groups = {"naive": ("none", "local"),
              "poly": ("constant", "plane", "residual", "residual-plane"),
              "quadratic": ("quadratic",), "ridge": ("ridge",)}
    for key, members in groups.items():
        sub[f"phot_acc_zero_crb_{key}"] = value_range([a0[s]["err_crb"] for s in members],
                                                      "{:.2f}")
    gain = 1 - a0["plane"]["err_crb"] / a0["ridge"]["err_crb"]
    sub["phot_acc_plane_gain"] = f"{100 * gain:.0f}"
    title, hard = section(sections, "harder arc", path)
    m = re.search(r"scales ([\d.]+) x ([\d.]+) px", title)
    sub["phot_acc_hard_scales"] = f"{m.group(1)} x {m.group(2)} px"
    for strategy, key in (("ridge", "ridge"), ("quadratic", "quad"),
                          ("residual-plane", "rp")):
        sub[f"phot_acc_hard_{key}_ln"] = f"{hard[strategy]['med_abs_ln']:.3f}"
        sub[f"phot_acc_hard_{key}_pull"] = _small(hard[strategy]["pull_std"])
    title, snr = section(sections, "accuracy against SNR", path)
    sub["phot_acc_snr_n"] = re.search(r": (\d+) sources on the arc", title).group(1)
    files["snr.csv"] = csv_text(
        [[label, f"{r['n']:.0f}", f"{r['med_ln']:+.3f}", f"{r['rms_ln']:.3f}",
          f"{r['pull_mean']:+.2f}", f"{r['pull_std']:.2f}", f"{r['pos_rms']:.3f}",
          f"{r['pos_pull_std']:.2f}"] for label, r in snr.items()])
    _, var = section(sections, "scene variants", path)
    sub["phot_acc_var_n"] = value_range([r["n"] for r in var.values()], "{:.0f}")
    for label, r in var.items():
        key = label.replace(" px", "").replace(" ", "").replace(".", "").lower()
        sub[f"phot_acc_var_{key}"] = f"{r['ridge']:.2f}"
        sub[f"phot_acc_var_{key}_q"] = f"{r['quadratic']:.2f}"
    return sub, files


def main(out=OUT):
    """Write the include file and the CSV tables into ``out`` (the docs' folder by
    default); returns the substitutions."""
    sub, tables = accuracy()
    sub = compute() | sub
    write_files(include_files(sub) | tables, out)
    return sub


if __name__ == "__main__":
    main()
