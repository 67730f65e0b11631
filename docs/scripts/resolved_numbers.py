"""Write docs/_static/scenes/resolved.inc: the numbers the pages quote from the resolved fit.

They are read from the stored output of ``benchmarks/resolved_photometry.py
--output docs/_static/scenes/resolved_photometry.txt``, which
``docs/mock_images.rst`` includes whole, so the prose of
``docs/mock_images.rst`` and ``docs/photometry.rst`` cannot drift from the
table. Run from the repository root after rerunning the benchmark::

    python docs/scripts/resolved_numbers.py
"""

import math
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "docs" / "_static" / "scenes"
RECORD = "resolved_photometry.txt"
METHODS = ("point", "resolved", "joint")
#: The anomaly of the benchmark's last table: image 1's tangential magnification x 1.3.
ANOMALY = 1.3


def _numbers(line):
    return [float(v) for v in line.replace("|", " ").split()]


def read_record(path):
    """The three tables of the record: stamp rows, anomaly rows and demo rows, each a
    list of dicts."""
    stamps, anomaly, demo = [], [], []
    part = None
    for line in Path(path).read_text().splitlines():
        if line.startswith("1. Stamps"):
            part = "stamps"
        elif line.startswith("   A true anomaly"):
            part = "anomaly"
        elif line.startswith("2. The demo"):
            part = "demo"
        if "|" not in line or not line.strip()[:1].isdigit():
            continue
        v = _numbers(line)
        if part == "stamps":
            row = {"r": v[0], "mu1": v[1], "mu2": v[2]}
            for k, m in enumerate(METHODS):
                row[m] = {"bias": v[3 + 3 * k], "sd": v[4 + 3 * k], "pull": v[5 + 3 * k]}
            stamps.append(row)
        elif part == "anomaly":
            anomaly.append({"r": v[0], **dict(zip(METHODS, v[3:6], strict=True))})
        elif part == "demo":
            demo.append({"r": v[0], "point": {"bias": v[1], "width": v[2], "pull": v[3]},
                         "resolved": {"bias": v[4], "width": v[5], "pull": v[6]}})
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
    for row in anomaly:
        for m in METHODS:
            lost = -row[m] / math.log(ANOMALY)
            sub[f"rs_{m}_lost{int(row['r'])}"] = f"{100 * lost:.0f} %"
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
