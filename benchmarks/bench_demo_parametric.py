"""What ``lensdual demo --parametric`` adds to the demo: its cost and its fit.

Run on demand (a few minutes)::

    python benchmarks/bench_demo_parametric.py [--runs 1] [--output FILE]

Runs ``python -m lensdual demo --quiet`` without and with ``--parametric``
(seed 0), each in a fresh process with the Numba cache as it is (run the demo
once before, so that both find it warm), ``--runs`` times each, alternating.
Reports the best wall time and the best CPU time (the process and the ones it
waited for: the second process that compiles kernels, where it runs) of each,
and the difference, which is what the parametric fit adds; then, from the
report of the last ``--parametric`` run, the fit's chi-square and degrees of
freedom, the number of pairs that break duality against the fitted model,
and the pairs the geometric test flags with their SNR. With ``--output FILE``
the figures also go to FILE: ``docs/parametric_fits.rst`` quotes
``docs/_static/parametric/demo.txt`` through
``docs/scripts/parametric_numbers.py``.
"""

import argparse
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _output import Record, add_output_argument


def _children_cpu():
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_demo(outdir, parametric):
    """Wall and CPU time (s) of one demo in a fresh process, and its report's text."""
    cmd = [sys.executable, "-m", "lensdual", "demo", "--quiet", "--outdir", str(outdir)]
    if parametric:
        cmd.append("--parametric")
    cpu, start = _children_cpu(), time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True)
    wall = time.perf_counter() - start
    return wall, _children_cpu() - cpu, (Path(outdir) / "report.txt").read_text()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1, help="runs of each (default 1)")
    add_output_argument(parser)
    args = parser.parse_args(argv)
    rec = Record()
    times = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.runs):
            for parametric in (False, True):
                wall, cpu, report = run_demo(Path(tmp) / f"{k}_{parametric}", parametric)
                times[parametric].append((wall, cpu))
    best = {p: (min(t[0] for t in ts), min(t[1] for t in ts)) for p, ts in times.items()}
    rec.say(f"lensdual demo (seed 0), best of {args.runs}: wall / CPU time")
    for parametric, label in ((False, "without --parametric"), (True, "with --parametric")):
        rec.say(f"  {label:<22}{best[parametric][0]:6.1f} s / {best[parametric][1]:6.1f} s")
    rec.say(f"  added by the fit      {best[True][0] - best[False][0]:6.1f} s / "
            f"{best[True][1] - best[False][1]:6.1f} s")
    text = " ".join(report.split())
    m = re.search(r"chi2 = ([\d.]+) for (\d+) degrees of freedom", text)
    rec.say(f"fit: chi2 = {m.group(1)} for {m.group(2)} degrees of freedom")
    m = re.search(r"against the fitted model, (\d+) pair\(s\) break duality", text)
    rec.say(f"pairs that break duality against the fitted model: {m.group(1)}")
    flagged = re.findall(r"pair (\d+) \(mu_flux = [^)]*?SNR ([\d.]+)", text)
    rec.say("pairs the geometric test flags: "
            + (", ".join(f"pair {p} at SNR {snr}" for p, snr in flagged) or "none"))
    rec.write(args.output)


if __name__ == "__main__":
    main()
