"""Write docs/_static/scenes/resolved.inc: the numbers the pages quote from the resolved fit.

They are read from the stored output of ``benchmarks/resolved_photometry.py
--output docs/_static/scenes/resolved_photometry.txt``, which
``docs/mock_images.rst`` includes whole, so the prose of
``docs/mock_images.rst`` and ``docs/photometry.rst`` cannot drift from the
table. Run from the repository root after rerunning the benchmark::

    python docs/scripts/resolved_numbers.py
"""

import math
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "docs" / "_static" / "scenes"
RECORD = "resolved_photometry.txt"
METHODS = ("point", "resolved", "joint")
#: The anomaly of the benchmark's last table: image 1's tangential magnification x 1.3.
ANOMALY = 1.3
#: Standard error of the median of n Gaussian values, times sqrt(n) / sd: sqrt(pi / 2).
MEDIAN_SE = math.sqrt(math.pi / 2)
#: Standard error of the 16-84 % half-width of n Gaussian values, times sqrt(n) / sd
#: (from the asymptotic covariance of the two sample quantiles).
HALF_WIDTH_SE = 0.96


def _numbers(line):
    return [float(v) for v in line.replace("|", " ").split()]


def read_record(path):
    """The three tables of the record: stamp rows (with ``n``, the realisations per
    row), anomaly rows and demo rows (with ``pairs``), each a list of dicts."""
    stamps, anomaly, demo = [], [], []
    part = None
    reps = 0
    for line in Path(path).read_text().splitlines():
        if line.startswith("1. Stamps"):
            part = "stamps"
            reps = int(re.search(r"(\d+) noise realisations", line).group(1))
        elif line.startswith("   A true anomaly"):
            part = "anomaly"
        elif line.startswith("2. The demo"):
            part = "demo"
        if "|" not in line or not line.strip()[:1].isdigit():
            continue
        v = _numbers(line)
        if part == "stamps":
            row = {"r": v[0], "mu1": v[1], "mu2": v[2], "n": reps}
            for k, m in enumerate(METHODS):
                row[m] = {"bias": v[3 + 3 * k], "sd": v[4 + 3 * k], "pull": v[5 + 3 * k]}
            stamps.append(row)
        elif part == "anomaly":
            anomaly.append({"r": v[0], **dict(zip(METHODS, v[3:6], strict=True))})
        elif part == "demo":
            demo.append({"r": v[0], "point": {"bias": v[1], "width": v[2], "pull": v[3]},
                         "resolved": {"bias": v[4], "width": v[5], "pull": v[6]},
                         "pairs": int(v[7])})
    return stamps, anomaly, demo


def _pct(x, digits=1):
    return f"{100 * x:+.{digits}f} %"


def _range(values, fmt="{:.2f}"):
    lo, hi = fmt.format(min(values)), fmt.format(max(values))
    return lo if lo == hi else f"{lo} to {hi}"


def compute(stamps, anomaly, demo):
    """The substitutions (name -> text)."""
    sub = {}
    for r in (5.0, 20.0):
        rows = [s for s in stamps if s["r"] == r]
        sub[f"rs_point_bias{int(r)}"] = _range([100 * s["point"]["bias"] for s in rows],
                                               "{:+.1f}") + " %"
    for m in ("resolved", "joint"):
        sub[f"rs_{m}_maxbias"] = f"{100 * max(abs(s[m]['bias']) for s in stamps):.1f} %"
        sub[f"rs_{m}_pulls"] = _range([s[m]["pull"] for s in stamps])
    sub["rs_point_pulls"] = _range([s["point"]["pull"] for s in stamps if s["r"] == 0.0])
    points = [s for s in stamps if s["r"] == 0.0]
    sub["rs_noise_cost"] = _range([s["resolved"]["sd"] / s["point"]["sd"] for s in points],
                                  "{:.1f}")
    sub["rs_reps_rows"] = str(len(stamps))
    n = min(s["n"] for s in stamps)
    sub["rs_reps"] = str(n)
    sd = max(s["resolved"]["sd"] for s in stamps)
    sub["rs_bias_se"] = f"{100 * MEDIAN_SE * sd / math.sqrt(n):.1f} %"
    sub["rs_pull_se"] = f"{HALF_WIDTH_SE / math.sqrt(n):.2f}"
    for row in anomaly:
        for m in METHODS:
            lost = -row[m] / math.log(ANOMALY)
            sub[f"rs_{m}_lost{int(row['r'])}"] = f"{int(round(100 * lost))} %"
    sub["rs_joint_lost"] = sub["rs_joint_lost20"]
    sub["rs_resolved_lost"] = sub["rs_resolved_lost20"]
    for row in demo:
        if row["r"] in (0.0, 40.0, 80.0):
            for m in ("point", "resolved"):
                sub[f"rs_demo_{m}{int(row['r'])}"] = _pct(row[m]["bias"])
    zero = [row for row in demo if row["r"] == 0.0][0]
    sub["rs_demo_width_cost"] = f"{zero['resolved']['width'] / zero['point']['width']:.1f}"
    sub["rs_demo_resolved_maxbias"] = f"{100 * max(abs(r['resolved']['bias']) for r in demo):.1f} %"
    sub["rs_demo_resolved_pulls"] = _range([r["resolved"]["pull"] for r in demo])
    pairs = [r["pairs"] for r in demo]
    sub["rs_demo_pairs"] = _range(pairs, "{:.0f}")
    width = max(r["resolved"]["width"] for r in demo)
    sub["rs_demo_bias_se"] = f"{100 * MEDIAN_SE * width / math.sqrt(min(pairs)):.1f} %"
    return sub


def include_files(sub):
    """``{"resolved.inc": text}``: one reST substitution per number."""
    text = "".join(f".. |{k}| replace:: {v}\n" for k, v in sub.items())
    return {"resolved.inc": text}


def main(out=STATIC):
    sub = compute(*read_record(STATIC / RECORD))
    for name, text in include_files(sub).items():
        (Path(out) / name).write_text(text)
        print(text, end="")
    return sub


if __name__ == "__main__":
    main()
