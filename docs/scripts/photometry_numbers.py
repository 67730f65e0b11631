"""Write docs/_static/photometry/numbers.inc: the numbers the photometry page quotes.

They are read from ``docs/_static/photometry/speed.txt``, the output of
``benchmarks/bench_photometry.py`` (first lines: the cores and the load average
it was measured at), so the page cannot drift from it. Run from the repository
root after rerunning the benchmark::

    python benchmarks/bench_photometry.py --repeat 5 --output docs/_static/photometry/speed.txt
    python docs/scripts/photometry_numbers.py
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _records import header, search  # noqa: E402
from _substitutions import write  # noqa: E402

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


def main(out=OUT):
    """Write the include file into ``out`` (the docs' folder by default)."""
    return write(compute(), out)


if __name__ == "__main__":
    main()
