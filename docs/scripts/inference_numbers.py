"""Write docs/_static/inference/numbers.inc: the numbers the inference page quotes
from the stored benchmark outputs.

The page includes the outputs themselves; this script reads the numbers its
prose quotes from them, so the prose cannot drift from the listings:

- ``coverage.txt``: ``benchmarks/inference_coverage.py --n-universes 150
  --out docs/_static/inference/coverage.txt`` (the SMACS0723 analogue and
  MACS J1149, the families the composite weight and the calibration were
  chosen on);
- ``coverage_heldout.txt``: the same with ``--families a2744_s3_lenstool
  --n-universes 100``;
- ``coverage_heldout_cusp.txt``: the same with ``--families cluster_cusp
  --n-universes 50 --n-real 200 --n-grid 10 --n-mocks 30``;
- ``coverage_heldout_new.txt`` and ``coverage_heldout_group.txt``: the families
  held out of the calibration, run once after it was built, ``--families
  macs1149_s5_lenstool`` and ``--families group_fold --log-m-host 14``, both
  with the cusp's settings (``--n-universes 100 --n-real 200 --n-grid 10
  --n-mocks 30``), and
  ``coverage_heldout_group_joint.txt`` and ``coverage_heldout_new_joint.txt``
  the group's and system 5's with ``--test joint``;
- ``coverage_oracle.txt``: the same with ``--families smacs_analog
  --n-universes 150 --oracle-noise`` (each measured anomaly replaced by the
  truth plus independent noise of its reported error);
- ``coverage_joint.txt``: the settings of ``coverage.txt`` with ``--test
  joint`` (``check_duality``'s joint test, in the universes and in the
  composite weight's mocks);
- ``coverage_los.txt``: the settings of ``coverage.txt`` with
  ``--los-normalization 1`` (line-of-sight haloes in the universes and the
  model); ``coverage_los_heldout.txt`` the same with ``--families
  a2744_s3_lenstool --n-universes 100``, and ``coverage_los_oracle.txt``
  with ``--families smacs_analog --oracle-noise``; ``coverage_los_smacs600.txt``
  with ``--families smacs_analog --n-universes 600 --n-calibration 600`` and
  ``coverage_los_a2744_400.txt`` with ``--families a2744_s3_lenstool
  --n-universes 400 --n-calibration 600`` (both ``--los-normalization 1``);
- ``los_speed.txt``: ``benchmarks/bench_inference_los.py`` (the SMACS0723
  analogue, 20 sources, 1000 realisations x 30 abundances);
- ``wdm.txt``: ``benchmarks/inference_wdm.py --out
  docs/_static/inference/wdm.txt``;
- ``posterior.txt``: ``docs/scripts/inference_figure.py`` (the figure's
  constellation and its settings);
- ``half_mode.txt``: ``docs/scripts/half_mode_figure.py`` (the half-mode
  example: ten constellations under CDM and under WDM);
- ``half_mode_coverage.txt``: ``benchmarks/inference_half_mode_coverage.py
  --n-universes 200 --n-systems 5 --out
  docs/_static/inference/half_mode_coverage.txt`` (with the calibration's
  default 300 mocks), ``half_mode_coverage_macs1149.txt`` the same with
  ``--family macs1149_lenstool`` and ``half_mode_coverage_group.txt`` with
  ``--family group_fold --log-m-host 14``.

Run from the repository root after rerunning one of them::

    python docs/scripts/inference_numbers.py
"""

import ast
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _substitutions import write  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "docs" / "_static" / "inference"

#: The families the composite weight was chosen on (``coverage.txt``).
DEVELOPMENT = ("smacs_analog", "macs1149_lenstool")
#: The held-out Lenstool model (``coverage_heldout.txt``).
HELD_OUT = "a2744_s3_lenstool"
#: The page's targets: the 68 % and 95 % intervals' coverage (nominal,
#: tolerance) and the largest median bias (dex).
TARGET68 = (0.68, 0.05)
TARGET95 = (0.95, 0.03)
MAX_BIAS = 0.1
#: The bins of the truth's position in the prior that the prose describes: the
#: lowest (next to the prior's lower bound), the middle and the highest one.
LOW_BIN = "[-3, -2)"
MID_BIN = "[-2, -1.5)"
TOP_BIN = "[-1.5, -0.5)"
#: The short names of the development families in the substitutions.
SHORT = {"smacs_analog": "smacs", "macs1149_lenstool": "macs1149"}
#: The families held out of the calibration, run once after it was built
#: (``coverage_heldout_new.txt``, ``coverage_heldout_group.txt``), and the
#: families held out of the composite weight, rerun with the calibration
#: (``coverage_heldout.txt``, ``coverage_heldout_cusp.txt``), by short name.
CALIBRATION_HELD_OUT = {"s5": "macs1149_s5_lenstool", "group": "group_fold",
                        "a2744": "a2744_s3_lenstool", "cusp": "cluster_cusp"}

_FAMILY = re.compile(r"^(\w+): (\d+) universes, (\d+) sources, ([\d.]+) mas, ([\d.]+) % flux"
                     r"(?:, (\w+) test)?; (?:line-of-sight haloes x ([\d.]+); )?"
                     r"forward model (\d+) x (\d+); "
                     r"composite weight from (\d+) mocks; (?:calibrated on (\d+) mocks; )?"
                     r"t_sim=(\d+)s t_weight=(\d+)s(?: t_calibration=(\d+)s)?")
_ROW = re.compile(r"^  (?:w=)?([\d.]+|calibrated)\s+(.*)$")
_MOCKS = re.compile(r"^\s+the calibration's mocks \((\d+) used\): uncalibrated (.*)$")
_BIN = re.compile(r"^\s+log10 truth in (\[[^)]*\)): n=\s*(\d+) (.*)$")
_WDM = re.compile(r"^sigma_pos\s+([\d.]+) mas: weight ([\d.]+); .*N_95 = (\S+) constellations$")


def _values(text):
    """``{name: float}`` of the ``name=value`` fields of a line, and ``<name>_err``
    of the binomial errors ``name=value (+-err)``."""
    values = {k: float(v) for k, v in re.findall(r"(\w+)=([-+\d.]+)", text)}
    values |= {f"{k}_err": float(v) for k, v in re.findall(r"(\w+)=[\d.]+ \(\+-([\d.]+)\)", text)}
    return values


def read_coverage(path):
    """The runs of an ``inference_coverage.py`` output.

    Returns
    -------
    settings : dict
        The command line's arguments (the file's first line).
    families : dict
        Per family: ``head`` (the settings and times of its line, and ``test``:
        ``"geometric"`` where the line names none, as before ``--test``) and
        ``rows``, one per posterior (``w``: the weight, or ``"calibrated"``;
        the line's statistics, ``bins`` by the truth's position in the prior,
        and for the calibrated one ``mocks``, its mocks' uncalibrated coverage).
    """
    lines = Path(path).read_text().splitlines()
    settings = ast.literal_eval(lines[0].lstrip("# "))
    families, rows = {}, None
    for line in lines[1:]:
        if m := _FAMILY.match(line):
            names = ("universes", "sources", "mas", "flux", "test", "los", "n_real", "n_grid",
                     "mocks", "calibration_mocks", "t_sim", "t_weight", "t_calibration")
            head = dict(zip(names, m.groups()[1:], strict=True))
            head["test"] = head["test"] or "geometric"
            head["los"] = head["los"] or "0"
            rows = []
            families[m.group(1)] = {"head": head, "rows": rows}
        elif m := _ROW.match(line):
            rows.append({"w": m.group(1), **_values(m.group(2)), "bins": {}})
        elif m := _MOCKS.match(line):
            rows[-1]["mocks"] = {"used": int(m.group(1)), **_values(m.group(2))}
        elif m := _BIN.match(line):
            rows[-1]["bins"][m.group(1)] = {"n": int(m.group(2)), **_values(m.group(3))}
        elif line.strip():
            raise ValueError(f"{path}: unexpected line {line!r}")
    if not families:
        raise ValueError(f"{path}: no family")
    return settings, families


def weighted(family):
    """The row of a family's run with its composite weight (the second row)."""
    rows = family["rows"]
    if len(rows) not in (2, 3) or rows[0]["w"] != "1":
        raise ValueError("a coverage run has a row with weight 1, then the weighted one")
    return rows[1]


def calibrated(family):
    """The row of a family's run with the calibrated posterior (the third row)."""
    rows = family["rows"]
    if len(rows) != 3 or rows[2]["w"] != "calibrated":
        raise ValueError("the coverage run has no calibrated posterior (--n-calibration)")
    return rows[2]


def read_wdm(path):
    """``{sigma_pos (mas): (weight, N_95)}`` and the first line of ``inference_wdm.py``'s output."""
    lines = Path(path).read_text().splitlines()
    runs = {}
    for line in lines:
        if m := _WDM.match(line):
            runs[m.group(1)] = (float(m.group(2)), m.group(3))
    if not runs:
        raise ValueError(f"{path}: no astrometry row")
    return runs, lines[0]


def _pct(x):
    return f"{100 * x:.0f}"


def _signed_range(values):
    lo, hi = sorted((min(values), max(values)), key=abs)
    return f"{lo:+.2f}" if f"{lo:+.2f}" == f"{hi:+.2f}" else f"{lo:+.2f} to {hi:+.2f}"


def coverage_numbers(dev, heldout):
    """The substitutions read from the coverage runs (development and held out)."""
    settings, families = dev
    heads = [families[f]["head"] for f in DEVELOPMENT]
    keys = ("sources", "mas", "flux", "n_real", "n_grid", "mocks")
    if any(h[k] != heads[0][k] for h in heads for k in keys):
        raise ValueError("the development families were run with different settings")
    head = heads[0]
    sub = {"inf_cov_sources": head["sources"], "inf_cov_mas": head["mas"],
           "inf_cov_flux": head["flux"], "inf_cov_mocks": head["mocks"],
           "inf_cov_real": head["n_real"], "inf_cov_grid": head["n_grid"],
           "inf_cov_threads": str(settings["threads"])}
    rows = [weighted(families[f]) for f in DEVELOPMENT]
    sub["inf_bias_low"] = _signed_range([r["bins"][LOW_BIN]["bias_median"] for r in rows])
    sub["inf_bias_mid"] = _signed_range([r["bins"][MID_BIN]["bias_median"] for r in rows])
    sub["inf_bias_all"] = _signed_range([r["bias_median"] for r in rows])
    smacs = families["smacs_analog"]["rows"][0]
    sub["inf_smacs_w1_cov68"] = _pct(smacs["cov68"])
    sub["inf_smacs_w1_cov95"] = _pct(smacs["cov95"])
    a2744 = weighted(heldout[1][HELD_OUT])
    sub["inf_a2744_w"] = f"{float(a2744['w']):g}"
    sub["inf_a2744_cov68"] = _pct(a2744["cov68"])
    sub["inf_a2744_cov95"] = _pct(a2744["cov95"])
    return sub


def _unsigned_range(values, fmt="{:.2f}"):
    lo, hi = (fmt.format(v) for v in (min(values), max(values)))
    return lo if lo == hi else f"{lo} to {hi}"


def joint_numbers(dev, joint):
    """The coverage under the joint test (``coverage_joint.txt``), per development
    family and weight, and the geometric run's (``coverage.txt``) it is compared with."""
    keys = ("universes", "sources", "mas", "flux", "n_real", "n_grid", "mocks")
    sub = {}
    for run, test in ((dev, "geometric"), (joint, "joint")):
        for family in DEVELOPMENT:
            head = run[1][family]["head"]
            if head["test"] != test:
                raise ValueError(f"the {test} run of {family} used the {head['test']} test")
            if any(head[k] != dev[1][family]["head"][k] for k in keys):
                raise ValueError(f"the joint run of {family} has other settings than the "
                                 "geometric one")
    for family in DEVELOPMENT:
        name = SHORT[family]
        w1, wc = joint[1][family]["rows"][0], weighted(joint[1][family])
        geo = weighted(dev[1][family])
        sub[f"inf_joint_w_{name}"] = f"{float(wc['w']):g}"
        for key in ("cov68", "cov95"):
            sub[f"inf_joint_{key}_{name}"] = _pct(wc[key])
            sub[f"inf_joint_w1_{key}_{name}"] = _pct(w1[key])
            sub[f"inf_geo_{key}_{name}"] = _pct(geo[key])
        # one decimal: a miss of the 68 % target by less than a point must show
        sub[f"inf_joint_cov68_{name}"] = f"{100 * wc['cov68']:.1f}"
        sub[f"inf_joint_cov68_err_{name}"] = _pct(wc["cov68_err"])
    joint_rows = [weighted(joint[1][f]) for f in DEVELOPMENT]
    geo_rows = [weighted(dev[1][f]) for f in DEVELOPMENT]
    sub["inf_joint_bias_all"] = _signed_range([r["bias_median"] for r in joint_rows])
    sub["inf_joint_width"] = _unsigned_range([r["width95"] for r in joint_rows])
    sub["inf_geo_width"] = _unsigned_range([r["width95"] for r in geo_rows])
    for name, bin_ in (("low", LOW_BIN), ("top", TOP_BIN)):
        for test, rows in (("joint", joint_rows), ("geo", geo_rows)):
            sub[f"inf_{test}_{name}_cov68"] = _unsigned_range(
                [100 * r["bins"][bin_]["cov68"] for r in rows], "{:.0f}")
        sub[f"inf_joint_{name}_n"] = _unsigned_range(
            [r["bins"][bin_]["n"] for r in joint_rows], "{:d}")
    return sub


def los_numbers(dev, los, heldout, oracle):
    """The coverage with line-of-sight haloes (``coverage_los*.txt``), per development
    family, on Abell 2744 (held out) and with oracle noise."""
    keys = ("universes", "sources", "mas", "flux", "test", "n_real", "n_grid", "mocks")
    for family in DEVELOPMENT:
        head = los[1][family]["head"]
        if head["los"] == "0" or any(head[k] != dev[1][family]["head"][k] for k in keys):
            raise ValueError(f"the line-of-sight run of {family} has other settings than "
                             "coverage.txt's, or no line-of-sight haloes")
    sub = {}
    for family in DEVELOPMENT:
        name = SHORT[family]
        row = weighted(los[1][family])
        sub[f"inf_los_w_{name}"] = f"{float(row['w']):g}"
        for key in ("cov68", "cov95"):
            sub[f"inf_los_{key}_{name}"] = f"{100 * row[key]:.1f}"
            sub[f"inf_los_{key}_err_{name}"] = _pct(row[f"{key}_err"])
        sub[f"inf_los_bias_{name}"] = f"{row['bias_median']:+.3f}"
    a2744 = weighted(heldout[1][HELD_OUT])
    sub["inf_los_a2744_w"] = f"{float(a2744['w']):g}"
    sub["inf_los_a2744_cov68"] = _pct(a2744["cov68"])
    sub["inf_los_a2744_cov95"] = _pct(a2744["cov95"])
    sub["inf_los_a2744_bias"] = f"{a2744['bias_median']:+.3f}"
    row = oracle[1]["smacs_analog"]["rows"][0]
    sub["inf_los_oracle_cov68"] = _pct(row["cov68"])
    sub["inf_los_oracle_cov95"] = _pct(row["cov95"])
    return sub


def group_joint_numbers(path, short="group"):
    """The calibrated joint anomalies on a held-out family (``inf_joint_cal_<short>_*``:
    the group's, or system 5's)."""
    fam = read_coverage(path)[1][CALIBRATION_HELD_OUT[short]]
    if fam["head"]["test"] != "joint":
        raise ValueError(f"{path}: not a run of the joint test")
    row = calibrated(fam)
    return {f"inf_joint_cal_{short}_cov68": _pct(row["cov68"]),
            f"inf_joint_cal_{short}_cov95": _pct(row["cov95"]),
            f"inf_joint_cal_{short}_cov95_err": _pct(row["cov95_err"]),
            f"inf_joint_cal_{short}_width": f"{row['width95']:.2f}"}


def calibration_numbers(dev, held, los, los_heldout, joint):
    """The calibrated posterior's coverage: on the development families
    (``inf_cal_*``), the held-out ones (``held``: short name -> run; ``inf_ho_*``),
    with line-of-sight haloes (``inf_los_cal_*``) and under the joint test
    (``inf_joint_cal_*``)."""
    heads = [dev[1][f]["head"] for f in DEVELOPMENT]
    if heads[0]["calibration_mocks"] is None or any(
            h["calibration_mocks"] != heads[0]["calibration_mocks"] for h in heads):
        raise ValueError("the development runs have no calibration, or different ones")
    n = int(heads[0]["calibration_mocks"])
    sub = {"inf_cal_mocks": str(n), "inf_cov_t_cal": heads[0]["t_calibration"],
           # the binomial error of a coverage measured on the calibration's mocks
           "inf_cal_err68": f"{100 * (0.68 * 0.32 / n) ** 0.5:.1f}",
           "inf_cal_err95": f"{100 * (0.95 * 0.05 / n) ** 0.5:.1f}"}
    for family in DEVELOPMENT:
        name = SHORT[family]
        cal, wc = calibrated(dev[1][family]), weighted(dev[1][family])
        sub[f"inf_cal_cov68_{name}"] = f"{100 * cal['cov68']:.1f}"
        sub[f"inf_cal_cov95_{name}"] = f"{100 * cal['cov95']:.1f}"
        sub[f"inf_cal_width_{name}"] = f"{cal['width95']:.2f}"
        sub[f"inf_cw_width_{name}"] = f"{wc['width95']:.2f}"
        sub[f"inf_cal_mocks68_{name}"] = _pct(cal["mocks"]["cov68"])
        sub[f"inf_cal_mocks95_{name}"] = _pct(cal["mocks"]["cov95"])
        for run, prefix in ((los, "inf_los_cal"), (joint, "inf_joint_cal")):
            row = calibrated(run[1][family])
            sub[f"{prefix}_cov68_{name}"] = f"{100 * row['cov68']:.1f}"
            sub[f"{prefix}_cov95_{name}"] = f"{100 * row['cov95']:.1f}"
            sub[f"{prefix}_cov68_err_{name}"] = _pct(row["cov68_err"])
            sub[f"{prefix}_width_{name}"] = f"{row['width95']:.2f}"
            sub[f"{prefix}_mocks68_{name}"] = _pct(row["mocks"]["cov68"])
            sub[f"{prefix}_w1_cov68_{name}"] = _pct(run[1][family]["rows"][0]["cov68"])
    rows = [calibrated(dev[1][f]) for f in DEVELOPMENT]
    sub["inf_cal_bias_all"] = _signed_range([r["bias_median"] for r in rows])
    for short, run in held.items():
        fam = run[1][CALIBRATION_HELD_OUT[short]]
        w1, wc, cal = fam["rows"][0], weighted(fam), calibrated(fam)
        sub[f"inf_ho_{short}_universes"] = fam["head"]["universes"]
        sub[f"inf_ho_{short}_w"] = f"{float(wc['w']):g}"
        for key in ("cov68", "cov95"):
            sub[f"inf_ho_{short}_cal_{key}"] = _pct(cal[key])
            sub[f"inf_ho_{short}_w1_{key}"] = _pct(w1[key])
            sub[f"inf_ho_{short}_w_{key}"] = _pct(wc[key])
        sub[f"inf_ho_{short}_cal_cov68_err"] = _pct(cal["cov68_err"])
        sub[f"inf_ho_{short}_cal_bias"] = f"{cal['bias_median']:+.2f}"
        sub[f"inf_ho_{short}_cal_width"] = f"{cal['width95']:.2f}"
        sub[f"inf_ho_{short}_w_width"] = f"{wc['width95']:.2f}"
        sub[f"inf_ho_{short}_mocks95"] = _pct(cal["mocks"]["cov95"])
    row = calibrated(los_heldout[1][HELD_OUT])
    sub["inf_los_a2744_cal_cov68"] = _pct(row["cov68"])
    sub["inf_los_a2744_cal_mocks68"] = _pct(row["mocks"]["cov68"])
    sub["inf_los_a2744_w1_cov68"] = _pct(los_heldout[1][HELD_OUT]["rows"][0]["cov68"])
    sub["inf_los_a2744_cal_cov95"] = _pct(row["cov95"])
    return sub


def los_more_numbers(runs):
    """The line-of-sight reruns with more universes and mocks (``inf_losmore_<name>_*``,
    ``runs``: name -> (path, family)): the calibrated coverages, their binomial errors,
    the mocks' and the universes' uncalibrated 68 % coverage, the counts."""
    sub = {}
    for name, (path, family) in runs.items():
        fam = read_coverage(path)[1][family]
        if fam["head"]["los"] == "0":
            raise ValueError(f"{path}: not a run with line-of-sight haloes")
        cal, w1 = calibrated(fam), fam["rows"][0]
        sub[f"inf_losmore_{name}_universes"] = fam["head"]["universes"]
        sub[f"inf_losmore_{name}_mocks"] = str(cal["mocks"]["used"])
        for key in ("cov68", "cov95"):
            sub[f"inf_losmore_{name}_{key}"] = f"{100 * cal[key]:.1f}"
            sub[f"inf_losmore_{name}_{key}_err"] = f"{100 * cal[key + '_err']:.1f}"
        sub[f"inf_losmore_{name}_mocks68"] = f"{100 * cal['mocks']['cov68']:.1f}"
        sub[f"inf_losmore_{name}_w1_cov68"] = f"{100 * w1['cov68']:.1f}"
    return sub


def los_speed_numbers(path):
    """The line-of-sight haloes' planes, counts, cost and anomalies (``los_speed.txt``)."""
    text = Path(path).read_text()
    pats = {
        "head": r"^\w+: (\d+) pairs, (\d+) realisations x (\d+) abundances",
        "planes": r"\((\d+) planes\)",
        "per_image": r"realisation: (\d+) \(radius [\d.]+ arcsec\), (\d+) \(radius",
        "times": r"forward model: ([\d.]+) s without, ([\d.]+) s with: ratio ([\d.]+)",
        "without": r"sd of ln\(f1/f2\) without: ([\d.]+) at (\S+) kpc\^-2, ([\d.]+) at (\S+)",
        "with": r"sd of ln\(f1/f2\) with   : ([\d.]+) at \S+ kpc\^-2, ([\d.]+) at",
    }
    m = {k: re.search(p, text, re.MULTILINE) for k, p in pats.items()}
    missing = [k for k, v in m.items() if v is None]
    if missing:
        raise ValueError(f"{path}: no {missing}")
    lo, hi = sorted(int(v) for v in m["per_image"].groups())
    return {
        "inf_los_pairs": m["head"].group(1), "inf_los_real": m["head"].group(2),
        "inf_los_grid": m["head"].group(3), "inf_los_planes": m["planes"].group(1),
        "inf_los_per_image": f"{lo} to {hi}" if lo != hi else str(lo),
        "inf_los_t_without": f"{float(m['times'].group(1)):.0f}",
        "inf_los_t_with": f"{float(m['times'].group(2)):.0f}",
        "inf_los_sigma_low": m["without"].group(2), "inf_los_sigma_high": m["without"].group(4),
        "inf_los_sd_low_without": m["without"].group(1),
        "inf_los_sd_high_without": m["without"].group(3),
        "inf_los_sd_low_with": m["with"].group(1), "inf_los_sd_high_with": m["with"].group(2),
    }


def oracle_numbers(oracle):
    """The coverage of the run with oracle noise, weight 1 (the SMACS0723 analogue)."""
    row = oracle[1]["smacs_analog"]["rows"][0]
    return {"inf_oracle_cov68": _pct(row["cov68"]), "inf_oracle_cov95": _pct(row["cov95"])}


def wdm_numbers(runs, first_line):
    """The substitutions read from the CDM-WDM run: N_95 per astrometry, mocks per model."""
    sub = {f"inf_wdm_n{float(mas):g}": n for mas, (_, n) in runs.items()}
    sub["inf_wdm_mocks"] = re.search(r"(\d+) mocks per model", first_line).group(1)
    return sub


def posterior_numbers(path):
    """The figure's constellation: sources, astrometry, flux errors, forward model."""
    first = Path(path).read_text().split("\n", 1)[0]
    m = re.match(r"# (\w+): (\d+) sources, ([\d.]+) mas, ([\d.]+) % flux errors, (\d+) "
                 r"realisations x (\d+) abundances", first)
    if m is None:
        raise ValueError(f"{path}: unexpected first line {first!r}")
    names = ("inf_post_sources", "inf_post_mas", "inf_post_flux", "inf_post_real",
             "inf_post_grid")
    return dict(zip(names, m.groups()[1:], strict=True))


def read_half_mode_coverage(path):
    """``{"sigma_sub": {...}, "log10_mhm": {...}}`` (coverages and their errors, bias,
    width) and the run's summary line of ``inference_half_mode_coverage.py``; with a
    calibration also ``calibrated_sigma_sub``, ``calibrated_log10_mhm`` and
    ``mocks`` (the calibration's mocks used and their uncalibrated coverages)."""
    lines = Path(path).read_text().splitlines()
    out = {}
    for line in lines:
        words = line.split()
        key = ("calibrated_" + words[1] if words and words[0] == "calibrated"
               else words[0] if words else None)
        if key in ("sigma_sub", "log10_mhm", "calibrated_sigma_sub", "calibrated_log10_mhm"):
            out[key] = {k: float(v) for k, v in re.findall(r"(\w+)=([-+\d.]+)", line)}
            out[key] |= {f"{k}_err": float(v) for k, v in
                         re.findall(r"(cov\d+)=[\d.]+ \(\+-([\d.]+)\)", line)}
        m = re.search(r"the calibration's mocks \((\d+) used\): uncalibrated sigma_sub "
                      r"cov68=([\d.]+) cov95=([\d.]+), log10_mhm cov68=([\d.]+) "
                      r"cov95=([\d.]+)", line)
        if m:
            out["mocks"] = {"n": int(m.group(1)), "sigma_cov68": float(m.group(2)),
                            "sigma_cov95": float(m.group(3)), "mhm_cov68": float(m.group(4)),
                            "mhm_cov95": float(m.group(5))}
    return out, lines[1]


def half_mode_numbers(example_path, coverage_path):
    """The half-mode example's two posteriors (``hm_*``) and the injection-recovery
    coverage of both marginals (``inf_hm_*``)."""
    text = Path(example_path).read_text().splitlines()
    sub = {}
    head = re.search(r"m_hm = ([\d, ]+), (\d+) realisations x (\d+) abundances; composite "
                     r"weight ([\d.]+).*; (\d+) mock constellations per truth, sigma_sub = "
                     r"([\d.]+)", text[0])
    if head is None:
        raise ValueError(f"{example_path}: unexpected first line {text[0]!r}")
    grid, *values = head.groups()
    for name, value in zip(("real", "n_grid", "weight", "systems", "sigma_truth"), values,
                           strict=True):
        sub[f"inf_hm_ex_{name}"] = value
    masses = grid.split(", ")
    sub["inf_hm_ex_grid"] = f"{masses[0]} to {masses[-1]}"
    for line in text[1:]:
        m = re.match(r"truth (CDM|WDM log10 m_hm = ([\d.]+)): sigma_sub median ([\d.]+), 95 % "
                     r"\[([\d.]+), ([\d.]+)\] kpc\^-2; log10 m_hm median ([\d.]+), 95 % "
                     r"\[([\d.]+), ([\d.]+)\], upper 95 % ([\d.]+).*; (\d+) pairs flagged", line)
        if m is None:
            continue
        tag = "cdm" if m.group(1) == "CDM" else "wdm"
        if tag == "wdm":
            sub["inf_hm_ex_wdm_truth"] = m.group(2)
        sub[f"inf_hm_ex_{tag}_sigma"] = m.group(3)
        sub[f"inf_hm_ex_{tag}_sigma95"] = f"{m.group(4)} to {m.group(5)}"
        sub[f"inf_hm_ex_{tag}_median"] = m.group(6)
        sub[f"inf_hm_ex_{tag}_upper"] = m.group(9)
        sub[f"inf_hm_ex_{tag}_flags"] = m.group(10)
    cov, summary = read_half_mode_coverage(coverage_path)
    n = re.match(r"\w+: (\d+) universes x (\d+) constellations", summary)
    sub["inf_hm_universes"], sub["inf_hm_systems"] = n.groups()
    sub |= _half_mode_coverage(cov, "inf_hm")
    for name, key in (("sigma", "sigma_sub"), ("mhm", "log10_mhm")):
        sub[f"inf_hm_{name}_err"] = _pct(cov[key]["cov68_err"])
    sub["inf_hm_width"] = f"{cov['log10_mhm']['width95']:.1f}"
    return sub


def _half_mode_coverage(cov, prefix):
    """Both marginals' 68 and 95 % coverage and the abundance's bias, named ``prefix_*``;
    with a calibration the same named ``prefix_cal_*``, the abundance's 95 % widths
    (``prefix_width_sigma``, ``prefix_cal_width_sigma``) and the half-mode mass's
    calibrated one (``prefix_cal_width``)."""
    sub = {}
    for name, key in (("sigma", "sigma_sub"), ("mhm", "log10_mhm")):
        for c in ("cov68", "cov95"):
            sub[f"{prefix}_{name}_{c}"] = _pct(cov[key][c])
            if f"calibrated_{key}" in cov:
                sub[f"{prefix}_cal_{name}_{c}"] = _pct(cov[f"calibrated_{key}"][c])
    sub[f"{prefix}_bias"] = f"{cov['sigma_sub']['bias_median']:+.2f}"
    if "calibrated_sigma_sub" in cov:
        sub[f"{prefix}_cal_bias"] = f"{cov['calibrated_sigma_sub']['bias_median']:+.2f}"
        sub[f"{prefix}_width_sigma"] = f"{cov['sigma_sub']['width95']:.2f}"
        sub[f"{prefix}_cal_width_sigma"] = f"{cov['calibrated_sigma_sub']['width95']:.2f}"
        sub[f"{prefix}_cal_width"] = f"{cov['calibrated_log10_mhm']['width95']:.1f}"
        sub[f"{prefix}_cal_mocks"] = str(cov["mocks"]["n"])
    return sub


def half_mode_second_family(path, prefix="inf_hm2"):
    """The same coverage on another family (``prefix_*``)."""
    return _half_mode_coverage(read_half_mode_coverage(path)[0], prefix)


def compute(folder=OUT):
    """The substitutions (name -> text) from the stored outputs under ``folder``."""
    sub = coverage_numbers(read_coverage(folder / "coverage.txt"),
                           read_coverage(folder / "coverage_heldout.txt"))
    sub |= oracle_numbers(read_coverage(folder / "coverage_oracle.txt"))
    sub |= joint_numbers(read_coverage(folder / "coverage.txt"),
                         read_coverage(folder / "coverage_joint.txt"))
    sub |= los_numbers(read_coverage(folder / "coverage.txt"),
                       read_coverage(folder / "coverage_los.txt"),
                       read_coverage(folder / "coverage_los_heldout.txt"),
                       read_coverage(folder / "coverage_los_oracle.txt"))
    sub |= calibration_numbers(
        read_coverage(folder / "coverage.txt"),
        {"s5": read_coverage(folder / "coverage_heldout_new.txt"),
         "group": read_coverage(folder / "coverage_heldout_group.txt"),
         "a2744": read_coverage(folder / "coverage_heldout.txt"),
         "cusp": read_coverage(folder / "coverage_heldout_cusp.txt")},
        read_coverage(folder / "coverage_los.txt"),
        read_coverage(folder / "coverage_los_heldout.txt"),
        read_coverage(folder / "coverage_joint.txt"))
    sub |= group_joint_numbers(folder / "coverage_heldout_group_joint.txt")
    sub |= group_joint_numbers(folder / "coverage_heldout_new_joint.txt", "s5")
    sub |= los_more_numbers({"smacs": (folder / "coverage_los_smacs600.txt", "smacs_analog"),
                             "a2744": (folder / "coverage_los_a2744_400.txt", HELD_OUT)})
    sub |= los_speed_numbers(folder / "los_speed.txt")
    sub |= wdm_numbers(*read_wdm(folder / "wdm.txt"))
    sub |= posterior_numbers(folder / "posterior.txt")
    sub |= half_mode_numbers(folder / "half_mode.txt", folder / "half_mode_coverage.txt")
    sub |= half_mode_second_family(folder / "half_mode_coverage_macs1149.txt")
    sub |= half_mode_second_family(folder / "half_mode_coverage_group.txt", "inf_hm3")
    return sub


def main(out=OUT):
    """Write the include file into ``out`` (the docs' folder by default)."""
    return write(compute(), out)


if __name__ == "__main__":
    main()
