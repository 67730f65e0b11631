"""Write docs/_static/detection/numbers.inc: the timings the detection page quotes.

They are read from ``docs/_static/detection/timings.txt``, the output of
``benchmarks/bench_detection.py`` (first lines: the cores and the load average
it was measured at), so the page cannot drift from it. Run from the repository
root after rerunning the benchmark::

    python benchmarks/bench_detection.py --output docs/_static/detection/timings.txt
    python docs/scripts/detection_numbers.py
"""

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _records import header, search  # noqa: E402
from _substitutions import write  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "_static" / "detection"

#: The timed cases (row label start -> short name).
CASES = {"blurs": "blurs", "PointSourceFilter": "filter", "numpy chain": "numpy",
         "find_point_sources": "find"}
#: The steps of the filter (label start -> short name).
STEPS = {"first Numba pass": "pass1", "second Numba pass": "pass2",
         "finiteness checks": "finite", "noise estimate": "noise",
         "low-level estimate": "low"}


def compute(folder=OUT):
    """The substitutions (name -> text) from the stored output under ``folder``."""
    path = folder / "timings.txt"
    lines = path.read_text().splitlines()
    sub = dict(zip(("det_cores", "det_load"), header(path), strict=True))
    m = search(r"^two (\d+) x \d+ float64 bands, (\d+) injected point sources, (\d+) found; "
               r"best of (\d+)$", lines, path)
    for name, value in zip(("size", "injected", "found", "repeat"), m.groups(), strict=True):
        sub[f"det_{name}"] = value
    for label, short in CASES.items():
        m = search(rf"^{re.escape(label)}.*?\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)$", lines, path)
        sub[f"det_{short}_time"] = f"{float(m.group(1)):.2f}"
        sub[f"det_{short}_ratio"] = m.group(2)
    for label, short in STEPS.items():
        m = search(rf"^\s+{re.escape(label)}.*?\s+([\d.]+) s$", lines, path)
        sub[f"det_{short}_time"] = f"{float(m.group(1)):.2f}"
    m = search(r"fresh interpreter: ([\d.]+) s with an empty Numba cache, ([\d.]+) s with a "
               r"warm one", lines, path)
    sub["det_first_cold"], sub["det_first_warm"] = m.groups()
    return sub


def main(out=OUT):
    """Write the include file into ``out`` (the docs' folder by default)."""
    return write(compute(), out)


if __name__ == "__main__":
    main()
