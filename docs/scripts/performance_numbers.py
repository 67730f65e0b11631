"""Write docs/_static/performance/numbers.inc: the numbers the performance page
quotes from the stored benchmark outputs.

Each benchmark writes what it prints to a file with ``--output`` (first lines:
the cores and the load average it was measured at); this script reads those
files, so the page cannot drift from them:

- ``estimators.txt``: ``benchmarks/bench_estimators.py``;
- ``null_calibration.txt``: ``benchmarks/bench_null_calibration.py``;
- ``solver.txt``: ``benchmarks/bench_solver.py``;
- ``lenstool.txt``: ``benchmarks/bench_lenstool.py``;
- ``sensitivity.txt``: ``benchmarks/bench_sensitivity.py --n-lenstronomy 80
  --repeat 3 --no-dask``;
- ``scale_estimators.txt``: ``benchmarks/bench_scale_estimators.py --sizes 300
  1000 10000 100000 --adaptive-uncapped-max 1000``;
- ``scale_pairing.txt``: ``benchmarks/bench_scale_pairing.py``;
- ``joint.txt``: ``benchmarks/bench_joint.py``;
- ``memory_2048.txt``, ``memory_4096.txt`` and ``memory_4096_noerror.txt``:
  ``benchmarks/bench_memory_run.py --size 2048``, ``--size 4096`` and ``--size
  4096 --no-error --cases run``;
- ``compile.txt``: ``benchmarks/bench_compile.py`` (CPU times, quoted by the
  install and Lenstool pages);
- ``neighbour_cap.txt``: ``benchmarks/neighbour_cap.py`` (accuracies, not
  times).

The load averages of the last two are not part of the performance page's,
whose figures are wall times.

Run from the repository root after rerunning a benchmark (each with
``--output docs/_static/performance/<file>``)::

    python docs/scripts/performance_numbers.py
"""

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _records import header, read_lines, search  # noqa: E402
from _substitutions import value_range, write  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "_static" / "performance"

#: The estimators the estimator benchmark times against the numpy reference.
ESTIMATORS = ("quad", "2v", "quad2")
#: The image finder's two settings in the solver benchmark (row name -> short name).
FINDERS = {"ImageFinder default": "fine", "ImageFinder coarse": "coarse"}
#: The lenstronomy models of the Lenstool benchmark (row label start -> short name).
LENSTRONOMY = {"lenstronomy 298 NIE": "nie", "lenstronomy 149 PJAFFE_ELLIPSE_POTENTIAL":
               "pjaffe_ell", "lenstronomy 149 PJAFFE (circular)": "pjaffe"}
#: The numbers of spurious candidates per arc of the pairing benchmark's rows.
SPURIOUS = (0, 100, 300, 500)
#: The constellation sizes of the joint test's benchmark.
JOINT_SIZES = (20, 40)


def estimators(path):
    """``bench_estimators.py``: Numba against the numpy reference, first calls."""
    lines = read_lines(path)
    m = search(r"N = (\d+) pairs, n_bootstrap = (\d+)", lines, path)
    sub = {"perf_est_pairs": m.group(1), "perf_est_boot": m.group(2)}
    for method in ESTIMATORS:
        m = search(rf"^{method}\s+([\d.]+)\s+([\d.]+)\s+(\d+)x$", lines, path)
        sub[f"perf_est_{method}_numba"] = m.group(1)
        sub[f"perf_est_{method}_ref"] = m.group(2)
        sub[f"perf_est_{method}_ratio"] = f"{m.group(3)}x"
    m = search(r"first call of quad, 2v, quad2: ([\d.]+) s with an empty Numba cache, "
               r"([\d.]+) s with a warm cache", lines, path)
    sub["perf_est_cold"], sub["perf_est_warm"] = m.groups()
    return sub


def null_calibration(path):
    """``bench_null_calibration.py``: threads against serial, and the reverse map's cost."""
    lines = read_lines(path)
    m = search(r"default \(threads\) ([\d.]+) s, serial ([\d.]+) s \(x([\d.]+)\); "
               r"identical results", lines, path)
    sub = {"perf_null_threads": m.group(1), "perf_null_serial": m.group(2),
           "perf_null_ratio": f"{m.group(3)}x"}
    m = search(r"with the reverse map ([\d.]+) s .*forward only ([\d.]+) s .*cost x([\d.]+)",
               lines, path)
    sub |= dict(zip(("perf_null_reverse", "perf_null_forward", "perf_null_reverse_cost"),
                    m.groups(), strict=True))
    m = search(r"joint test: log ([\d.]+) s, conservative ([\d.]+) s", lines, path)
    sub |= dict(zip(("perf_null_joint", "perf_null_joint_cons"), m.groups(), strict=True))
    return sub


def solver(path):
    """``bench_solver.py``: the image finder against lenstronomy's solver."""
    lines = read_lines(path)
    m = search(r"timed on (\d+) sources: ([\d.]+) s per source", lines, path)
    sub = {"perf_solver_lt_n": m.group(1), "perf_solver_lt": f"{float(m.group(2)):.2f}"}
    m = search(r"^NFW_ELLIPSE_CSE cluster, (\d+) sources", lines, path)
    sub["perf_solver_n"] = m.group(1)
    for row, short in FINDERS.items():
        m = search(rf"^{row} \(.*?\)\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+(\d+)"
                   r"\s+([\d.]+)\s+(\d+)$", lines, path)
        _, build, solve, per, ratio, amort, amort_ratio = m.groups()
        sub[f"perf_solver_{short}_build"] = f"{float(build):.2f}"
        sub[f"perf_solver_{short}_solve"] = f"{float(solve):.2g}"
        sub[f"perf_solver_{short}_per_ms"] = f"{1e3 * float(per):.1f}"
        sub[f"perf_solver_{short}_ratio"] = f"{ratio}x"
        sub[f"perf_solver_{short}_amort"] = f"{float(amort):.2g}"
        sub[f"perf_solver_{short}_amort_ratio"] = f"{amort_ratio}x"
        m = search(rf"^\s+{row} \(.*?\)\s+total\s+(\d+)\s+histogram (\{{.*\}})$", lines, path)
        hist = {int(k): int(v) for k, v in re.findall(r"(\d+): (\d+)", m.group(2))}
        sub[f"perf_solver_{short}_images"] = ", ".join(
            f"{k} {'source' if k == 1 else 'sources'} with {n} images"
            for n, k in sorted(hist.items()))
        m = search(rf"^\s+{row} \(.*?\)\s+on those: .*?, (\d+) of lenstronomy's (\d+) images",
                   lines, path)
        sub[f"perf_solver_{short}_matched"] = f"{m.group(1)} of lenstronomy's {m.group(2)}"
    return sub


def lenstool(path):
    """``bench_lenstool.py``: the dPIE kernels against lenstronomy's profiles."""
    lines = read_lines(path)
    m = search(r"grid (\d+) x \d+ = \d+ points over \+-([\d.]+) arcsec, (\d+) potentials",
               lines, path)
    sub = {"perf_lt_grid": m.group(1), "perf_lt_half": m.group(2), "perf_lt_n": m.group(3)}
    for label, short in (("lensdual alpha \\+ hessian, 1 thread", "sep"),
                         ("lensdual alpha_hessian \\(one pass\\), 1 thread", "onepass"),
                         ("lensdual alpha_hessian, (\\d+) threads", "threads")):
        m = search(rf"^{label}\s+([\d.]+)$", lines, path)
        sub[f"perf_lt_{short}"] = m.groups()[-1]
        if short == "threads":
            sub["perf_lt_n_threads"] = m.group(1)
    for label, short in LENSTRONOMY.items():
        m = search(rf"^{re.escape(label)}.*?\s+([\d.]+)\s+([\d.]+)x\s+([\d.]+)x$", lines, path)
        sub[f"perf_lt_{short}"] = m.group(1)
        sub[f"perf_lt_{short}_ratio"] = f"{float(m.group(2)):.2g}x"
        sub[f"perf_lt_{short}_ratio_threads"] = f"{float(m.group(3)):.2g}x"
    m = search(r"alpha_NIE\| = ([\d.e+-]+) arcsec", lines, path)
    sub["perf_lt_nie_diff"] = m.group(1)
    m = search(r"one elliptical NFW.*lensdual ([\d.]+) s .*NFW_ELLIPSE_POTENTIAL ([\d.]+) s "
               r"\(([\d.]+)x\)", lines, path)
    sub["perf_lt_nfw"], sub["perf_lt_nfw_lt"] = m.group(1), m.group(2)
    sub["perf_lt_nfw_ratio"] = f"{float(m.group(3)):.2g}x"
    return sub


def sensitivity(path):
    """``bench_sensitivity.py``: the detection-SNR map, serial and in threads, and lenstronomy."""
    lines = read_lines(path)
    sub = {"perf_sens_placements": search(r"= (\d+) placements", lines, path).group(1)}
    m = search(r"^lensdual serial:\s+([\d.]+) s\s+\((\d+) us per placement\)", lines, path)
    sub["perf_sens_serial"] = f"{float(m.group(1)):.1f}"
    sub["perf_sens_serial_per"] = f"{int(m.group(2)) / 1e3:.2f}"
    m = search(r"^lensdual, (\d+) threads:\s+([\d.]+) s\s+\(speed-up ([\d.]+), identical: True\)",
               lines, path)
    sub["perf_sens_workers"] = m.group(1)
    sub["perf_sens_threads"] = f"{float(m.group(2)):.1f}"
    sub["perf_sens_threads_ratio"] = f"{m.group(3)}x"
    m = search(r"^lenstronomy, (\d+) random placements: ([\d.]+) s per placement -> ([\d.]+) h",
               lines, path)
    sub["perf_sens_lt_n"] = m.group(1)
    sub["perf_sens_lt_per"] = f"{1e3 * float(m.group(2)):.0f}"
    extrapolated = float(m.group(2)) * int(sub["perf_sens_placements"])
    sub["perf_sens_lt_map"] = f"{round(extrapolated, -2):.0f}"
    sub["perf_sens_ratio"] = search(r"speed-up per placement \(serial lensdual\): (\d+)x",
                                    lines, path).group(1) + "x"
    m = search(r"image counts: equal in (\d+) of (\d+); lenstronomy found fewer in (\d+), "
               r"lensdual fewer in (\d+)", lines, path)
    sub["perf_sens_counts"] = f"{m.group(1)} of the {m.group(2)}"
    sub["perf_sens_lt_fewer"], sub["perf_sens_ld_fewer"] = m.group(3), m.group(4)
    for name, short in (("M <= 1e9", "light"), ("M > 1e9", "heavy")):
        m = search(rf"{re.escape(name)} \((\d+)\): median ([\d.e+-]+), max ([\d.e+-]+)",
                   lines, path)
        sub[f"perf_sens_{short}_median"], sub[f"perf_sens_{short}_max"] = m.group(2), m.group(3)
        for stat, value in (("median", m.group(2)), ("max", m.group(3))):
            sub[f"perf_sens_{short}_{stat}_pct"] = f"{100 * float(value):.2g} %"
    return sub


def _pairing_result(runs):
    """The pairing's outcome over the seeds: true pairs found (wrong ones), refusals."""
    refused = [r for r in runs if r["note"]]
    done = [r for r in runs if not r["note"]]
    if not done:
        return f"refused ({len(refused)} of {len(runs)})"
    true = done[0]["true"]
    text = (f"{value_range([r['found'] for r in done], '{:d}')} / {true} "
            f"({value_range([r['wrong'] for r in done], '{:d}')})")
    return text + (f"; {len(refused)} refused" if refused else "")


def read_scale_pairing(path):
    """The runs of ``bench_scale_pairing.py``, one dict per line of its table
    (``note``: the start of the refusal's message, empty when it paired)."""
    runs = []
    pattern = re.compile(r"^\s*(yes|no)\s+(\d+)\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+(\d+)/(\d+)\s+"
                         r"(\d+)\s*(.*)$")
    for line in read_lines(path):
        m = pattern.match(line)
        if m:
            runs.append({"fluxes": m.group(1) == "yes", "spurious": int(m.group(2)),
                         "seed": int(m.group(3)), "time": float(m.group(4)),
                         "peak": float(m.group(5)), "found": int(m.group(6)),
                         "true": int(m.group(7)), "wrong": int(m.group(8)),
                         "note": m.group(9).strip()})
    if not runs:
        raise ValueError(f"{path}: no pairing runs")
    return runs


def scale_pairing(path):
    """``bench_scale_pairing.py``: time, peak memory and result per spurious count."""
    runs = read_scale_pairing(path)
    sub = {"perf_pair_seeds": str(len({r["seed"] for r in runs})),
           "perf_pair_true": str(runs[0]["true"])}
    for fluxes, short in ((False, "pos"), (True, "flux")):
        for n in SPURIOUS:
            rows = [r for r in runs if r["fluxes"] == fluxes and r["spurious"] == n]
            if not rows:
                raise ValueError(f"{path}: no run with {n} spurious candidates, fluxes {fluxes}")
            key = f"perf_pair_{short}{n}"
            sub[f"{key}_time"] = value_range([r["time"] for r in rows], unit=" s")
            sub[f"{key}_peak"] = f"{max(r['peak'] for r in rows):.0f} MB"
            sub[f"{key}_result"] = _pairing_result(rows)
    return sub


def joint(path):
    """``bench_joint.py``: the joint duality test against the geometric one."""
    lines = read_lines(path)
    sub = {}
    for n in JOINT_SIZES:
        m = search(rf"^{n} ([\d.]+) ([\d.]+) ([\d.]+) ([\d.]+) ([\d.]+)$", lines, path)
        sub[f"perf_joint{n}_geo"], sub[f"perf_joint{n}_joint"] = m.group(1), m.group(2)
        sub[f"perf_joint{n}_ratio"] = f"{m.group(3)}x"
        sub[f"perf_joint{n}_default"] = m.group(4)
        sub[f"perf_joint{n}_default_ratio"] = f"{m.group(5)}x"
    return sub


def scale_estimators(path):
    """``bench_scale_estimators.py``: the neighbour cap against the uncapped estimators."""
    sub = {}
    pattern = re.compile(r"^\s*(\d+)\s+(\w+)\s+([\d.]+)\s+(?:--\s+--\s+--|([\d.]+)\s+"
                         r"([\d.]+)\s+(\S+)\s+(\S+))\s*$")
    for line in read_lines(path):
        m = pattern.match(line)
        if not m:
            continue
        n, method, capped, uncapped, ratio, median, top = m.groups()
        key = f"perf_scale{n}_{method}"
        sub[f"{key}_capped"] = f"{float(capped):.2g}"
        if uncapped is None:
            sub[f"{key}_uncapped"] = sub[f"{key}_ratio"] = sub[f"{key}_diff"] = "--"
            continue
        sub[f"{key}_uncapped"] = f"{float(uncapped):.2g}"
        sub[f"{key}_ratio"] = f"{float(ratio):.2g}x"
        median, top = float(median), float(top)
        sub[f"{key}_diff"] = ("identical" if top == 0 else
                              f"median {100 * median:.2g} %, max {100 * top:.2g} %")
    if not sub:
        raise ValueError(f"{path}: no rows")
    largest = max(int(k.split("_")[1][len("scale"):]) for k in sub)
    fast = max(float(sub[f"perf_scale{largest}_{m}_capped"]) for m in ESTIMATORS)
    sub["perf_scale_largest_fast"] = f"{fast:.2g}"
    return sub


def memory_run(path):
    """``bench_memory_run.py``: peak memory and time of each case at one size."""
    lines = read_lines(path)
    m = search(r"^# size (\d+), error maps: (True|False)", lines, path)
    key = f"perf_mem{m.group(1)}" + ("" if m.group(2) == "True" else "_noerr")
    sub = {}
    for case in ("detect", "photometry", "run"):
        m = re.search(rf"^{case}\s+(\d+)\s+(\d+)\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+(-?\d+)"
                      r"\s+([\d.]+)", "\n".join(lines), re.MULTILINE)
        if m is None:
            continue
        data, inputs, peak, over_data, over_inputs, extra, time = m.groups()
        sub[f"{key}_data"], sub[f"{key}_inputs"] = data, inputs
        sub[f"{key}_{case}_peak"] = peak
        sub[f"{key}_{case}_over_data"] = f"{float(over_data):.1f}"
        sub[f"{key}_{case}_over_inputs"] = f"{float(over_inputs):.1f}"
        sub[f"{key}_{case}_extra"] = extra
        sub[f"{key}_{case}_time"] = f"{float(time):.2g}"
        sub[f"{key}_{case}_extra_over_data"] = f"{float(extra) / float(data):.1f}"
    if not sub:
        raise ValueError(f"{path}: no case")
    return sub


def compile_times(path):
    """``bench_compile.py``: CPU time to compile the kernels of each case."""
    lines = read_lines(path)
    sub = {}
    for case in ("adaptive", "lenstool"):
        m = search(rf"^{case}\s+([\d.]+) \(\s*[\d.]+\)\s+([\d.]+) \(\s*[\d.]+\)\s+([\d.]+)$",
                   lines, path)
        sub[f"perf_compile_{case}"] = f"{float(m.group(3)):.0f}"
    return sub


def neighbour_cap(path):
    """``neighbour_cap.py``: what the neighbour cap changes on the smooth test map."""
    lines = read_lines(path)
    sub = {"perf_cap_pairs": search(r"^(\d+) pairs of the smooth test map", lines, path).group(1)}
    for method in ("quad", "quad2"):
        m = search(rf"^{method}\s+([\d.]+)%\s+([\d.]+)%$", lines, path)
        capped, uncapped = float(m.group(1)), float(m.group(2))
        sub[f"perf_cap_{method}_capped"] = f"{capped:.2g}"
        sub[f"perf_cap_{method}_uncapped"] = f"{uncapped:.2g}"
    m = search(r"^adaptive, (\d+) pairs, ([\d.]+) mas noise, capped against uncapped",
               lines, path)
    sub["perf_cap_compared"], sub["perf_cap_noise"] = m.groups()
    m = search(r"the same estimate .*: (\d+) of (\d+) pairs", lines, path)
    sub["perf_cap_same"] = m.group(1)
    m = search(r"errors in quadrature: median ([\d.e+-]+), 90th percentile ([\d.]+)",
               lines, path)
    sub["perf_cap_z_median"], sub["perf_cap_z90"] = m.groups()
    m = search(r"error capped / uncapped: median ([\d.]+)", lines, path)
    sub["perf_cap_err_ratio"] = f"{float(m.group(1)):.2f}"
    for label in ("capped", "uncapped"):
        m = search(rf"pulls against the exact mu, {label}: 16-84 % (-?[\d.]+) to (-?[\d.]+)",
                   lines, path)
        sub[f"perf_cap_pull_{label}"] = f"{m.group(1)} to {m.group(2)}"
    m = search(r"capped: pull width \(16-84 % half-width\) ([\d.]+), beyond 3 sigma "
               r"([\d.]+) %", lines, path)
    sub["perf_cap_width"], sub["perf_cap_beyond3"] = m.groups()
    return sub


#: The stored outputs and the reader of each.
READERS = {"estimators.txt": estimators, "null_calibration.txt": null_calibration,
           "solver.txt": solver, "lenstool.txt": lenstool, "sensitivity.txt": sensitivity,
           "scale_estimators.txt": scale_estimators, "scale_pairing.txt": scale_pairing,
           "joint.txt": joint, "memory_2048.txt": memory_run, "memory_4096.txt": memory_run,
           "memory_4096_noerror.txt": memory_run}


#: Stored outputs that are not wall times (their load is not the page's), and their readers.
RESULTS = {"compile.txt": compile_times, "neighbour_cap.txt": neighbour_cap}


def compute(folder=OUT):
    """The substitutions (name -> text) from the stored outputs under ``folder``."""
    sub = {}
    cores, loads = set(), []
    for name, reader in READERS.items():
        sub |= reader(folder / name)
        n, load = header(folder / name)
        cores.add(n)
        loads.append(float(load))
    if len(cores) != 1:
        raise ValueError(f"the stored outputs were measured on different numbers of cores: "
                         f"{sorted(cores)}")
    sub["perf_cores"] = cores.pop()
    sub["perf_load"] = value_range(loads, "{:.1f}")
    for name, reader in RESULTS.items():
        sub |= reader(folder / name)
    return sub


def main(out=OUT):
    """Write the include file into ``out`` (the docs' folder by default)."""
    return write(compute(), out)


if __name__ == "__main__":
    main()
