"""Write docs/_static/calibration/numbers.inc: the numbers the calibration page quotes
from the stored benchmark outputs.

They are read from the tables the page and its neighbours include, so the prose
cannot drift from them:

- ``calibration/heldout_new.txt``: ``benchmarks/calibration.py --methods
  adaptive --families macs1149_s5_lenstool,group_fold`` (the two families no
  choice has looked at); the cells that miss a target are those of
  ``benchmarks/calibration_tables.py --targets``;
- ``null_map/spline.txt``, ``spline_heldout.txt`` and ``demo_spline.txt``:
  ``benchmarks/null_map_calibration.py`` (the null calibration's spline map on
  four families, the two held-out ones and the demo's scenario);
- ``calibration/suite_seed100.txt``: the validation suite on 10 other
  constellations per cell (``benchmarks/calibration.py --seed 100`` over the
  families of ``suite_seed0.txt``);
- ``calibration/suite_seed2000.txt``: the same on 50 more constellations per
  cell (``--seed 2000 --n-const 50``), and ``calibration/suite_pooled70.txt``
  the three runs pooled, 70 constellations per cell (each run with
  ``--save-dir``, then ``--from-saves`` on the three folders);
- ``joint/calibration_heldout.txt``: ``benchmarks/joint_calibration.py
  --masking`` on the held-out families (the geometric test's false flags,
  ``ffr_geo``, on the compact galaxy-scale fold at 20 mas);
- ``profile_snr/small_constellations.txt``: ``benchmarks/profile_snr_calibration.py
  --n-sources 8,12`` (the development families, then the held-out ones);
- ``profile_snr/calibration.txt``: ``benchmarks/profile_snr_calibration.py``
  (the conservative SNR's false flags on the compact fold and Abell 370).

The calibration page's tables of the validation suite are the CSV files that
``benchmarks/calibration_tables.py --csv`` writes from its stored seed-0 run,
``calibration/suite_seed0.txt``. Run from the repository root after rerunning a
benchmark::

    python docs/scripts/calibration_numbers.py
"""

import re
import sys
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _records import benchmark_module  # noqa: E402
from _substitutions import write  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "docs" / "_static"
OUT = STATIC / "calibration"

#: The null map's runs: the development families, the held-out ones, the demo.
NULL_TABLES = ("spline.txt", "spline_heldout.txt", "demo_spline.txt")
#: The fraction of empirical p-values at or below this level (%) is judged.
NULL_LEVEL = 5.0
#: Columns of the null map's tables.
NULL_RATE = "null's rate"
FLAGS = "flags at SNR 3"
#: The first line of a null map's table: its settings.
NULL_HEADER = re.compile(r"null map: .*?; (\d+) constellations per cell")


def _targets_module():
    """``benchmarks/calibration_tables.py``: the reader and the targets of ``--targets``."""
    return benchmark_module("calibration_tables")


def read_cells(path):
    """``{(family, n_sources, method, noise): {column: value}}`` of a calibration.py output."""
    return _targets_module().read(path)


def missed_targets(cells):
    """The cells of the adaptive estimator that miss a target, with the reasons."""
    return _targets_module().missed_targets(cells)


def _number(text):
    """The leading number of a cell such as ``0.4 % [0.0, 2.4]``."""
    return float(text.split()[0])


def _interval(text):
    """The bracketed interval of a cell such as ``0.4 % [0.0, 2.4]``."""
    lo, hi = text[text.index("[") + 1:text.index("]")].split(",")
    return float(lo), float(hi)


def read_null_table(path):
    """The rows of a null_map_calibration.py table as dicts of the cells' text."""
    lines = [ln for ln in Path(path).read_text().splitlines() if "|" in ln]
    head = [h.strip() for h in lines[0].split("|")]
    return [dict(zip(head, (c.strip() for c in ln.split("|")), strict=True))
            for ln in lines[1:]]


def read_joint_table(path):
    """The rows of a joint_calibration.py table as dicts (numbers as floats)."""
    lines = [ln.split() for ln in Path(path).read_text().splitlines() if ln.strip()]
    head = lines[0]
    return [{k: (v if k == "family" else float(v)) for k, v in zip(head, parts, strict=True)}
            for parts in lines[1:]]


def _pct(x, digits=2):
    return f"{100 * x:.{digits}f}"


def _and(items):
    items = list(items)
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _null_row(rows, family, n_sources):
    return next(r for r in rows if r["family"] == family and r["sources"] == str(n_sources))


def heldout_numbers(cells):
    """The substitutions read from the run on the two families no choice has looked at."""
    sub = {}
    group = {(k[1], k[3]): r for k, r in cells.items()
             if k[0] == "group_fold" and k[2] == "adaptive"}
    for noise in (1, 2):
        r = group[(8, noise)]
        sub[f"cal_group8_w{noise}"] = f"{r['pull_w']:.1f}"
        sub[f"cal_group8_gw{noise}"] = f"{r['pull_gw']:.1f}"
    sub["cal_group8_ffr1"] = _pct(group[(8, 1)]["ffr"], 1)
    sub["cal_group8_tested1"] = _pct(group[(8, 1)]["tested"], 0)
    rest = [r["ffr"] for (n, noise), r in group.items() if n >= 20 or noise >= 5]
    sub["cal_group_ffr_rest"] = _pct(max(rest))
    m1149 = [r for k, r in cells.items() if k[0] == "macs1149_s5_lenstool"]
    sub["cal_m1149s5_ffr_max"] = _pct(max(r["ffr"] for r in m1149))
    missed = missed_targets(cells)
    sub["cal_heldout_missed"] = "; ".join(
        f"``{fam}`` with {n} sources at {noise:g} mas ({', '.join(why)})"
        for (fam, n, noise), why in missed.items()) or "none"
    return sub


def _range(values, scale=100.0, digits=2):
    return f"{scale * min(values):.{digits}f}-{scale * max(values):.{digits}f}"


def other_seed_numbers(cells):
    """The substitutions read from the validation suite on other constellations
    (seeds 100-109): false flags with 20-40 sources per family group, the
    8-source cells that fail, and the cells that miss a target."""
    def cell(family, n_sources, noise):
        return cells[(family, n_sources, "adaptive", float(noise))]

    def many(families, column="ffr"):
        return [r[column] for k, r in cells.items()
                if k[0] in families and k[1] >= 20 and k[2] == "adaptive"]

    sub = {"cal_s100_folds": _range(many(("cluster_fold", "smacs_analog"))),
           "cal_s100_smacs": _range(many(("smacs_lenstool",))),
           "cal_s100_cusp": _range(many(("cluster_cusp",))),
           "cal_s100_m1149": _range(many(("macs1149_lenstool",))),
           "cal_s100_galaxy": _range(many(("galaxy_fold",))),
           "cal_s100_galaxy_gw": _range(many(("galaxy_fold",), "pull_gw"), 1.0)}
    sub["cal_s100_galaxy8_gw"] = " / ".join(
        f"{cell('galaxy_fold', 8, noise)['pull_gw']:.2f}" for noise in (5, 10))
    tested = [cell("galaxy_fold", 8, noise)["tested"] for noise in (5, 10)]
    sub["cal_s100_galaxy8_tested"] = _range(tested, digits=0)
    sub["cal_s100_cusp8_gw"] = " / ".join(
        f"{cell('cluster_cusp', 8, noise)['pull_gw']:.2f}" for noise in (1, 20))
    sub["cal_s100_cusp8_20"] = f"{cell('cluster_cusp', 8, 20)['pull_gw']:.2f}"
    sub["cal_s100_m1149_8"] = _pct(cell("macs1149_lenstool", 8, 1)["ffr"])
    sub["cal_s100_galaxy20_10"] = _pct(cell("galaxy_fold", 20, 10)["ffr"])
    sub["cal_s100_missed"] = str(len(missed_targets(cells)))
    return sub


#: The cluster-scale families of the main table whose pulls and false flags the
#: page reads together (the folds and the SMACS families).
FOLDS = ("cluster_fold", "smacs_analog", "smacs_lenstool")
#: The cluster-scale families of the main table (the folds and the cusp).
CLUSTER = FOLDS + ("cluster_cusp",)


def _half_up(x, digits, scale=1.0):
    """``scale`` times ``x`` rounded half up to ``digits`` decimals, as text; ``x`` is
    read from its shortest repr (the stored tables' own digits), and zero is "0"."""
    value = Decimal(repr(float(x))) * Decimal(repr(float(scale)))
    if value == 0:
        return "0"
    return str(value.quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP))


def _span(values, digits, scale=100.0):
    """The range ``lo-hi`` of ``scale`` times ``values`` (NaN left out), rounded half up."""
    values = [v for v in values if v == v]
    lo, hi = (_half_up(v, digits, scale) for v in (min(values), max(values)))
    return lo if lo == hi else f"{lo}-{hi}"


def suite_numbers(seed0, seed100):
    """The substitutions read from the validation suite on seed 0 (the page's main
    table) and on seeds 100-109: the claims of "When to trust a flag" and "What
    the table says", and the quad2 ranges the method page quotes."""
    def rows(cells, families, method="adaptive", sources=None, noises=None):
        return [r for (fam, n, m, noise), r in cells.items()
                if fam in families and m == method and (sources is None or n in sources)
                and (noises is None or noise in noises)]

    def col(rows_, name):
        return [r[name] for r in rows_]

    def one(family, n_sources, noise, method="adaptive"):
        return seed0[(family, n_sources, method, float(noise))]

    sub = {}
    # quad2: close to calibrated on the cluster folds with 20-40 sources, not next
    # to cusps at 1-2 mas, nor with 8 sources, nor on the galaxy fold
    sub["cal_q2_folds"] = _span(col(rows(seed0, ("cluster_fold", "smacs_analog"), "quad2",
                                         (20, 40)), "ffr"), 2)
    sub["cal_q2_cusp12"] = _span(col(rows(seed0, ("cluster_cusp",), "quad2", None, (1, 2)),
                                     "ffr"), 1)
    sub["cal_q2_n8_max"] = _half_up(max(col(rows(seed0, CLUSTER, "quad2", (8,)), "ffr")), 1, 100)
    galaxy_q2 = col(rows(seed0, ("galaxy_fold",), "quad2"), "ffr")
    sub["cal_q2_galaxy"] = _span(galaxy_q2, 0)
    sub["cal_q2_galaxy_max"] = _half_up(max(galaxy_q2), 0, 100)

    # the folds and the SMACS families, 8-40 sources
    folds = rows(seed0, FOLDS)
    sub["cal_folds_ffr"] = _span(col(folds, "ffr"), 2)
    sub["cal_folds_w"] = _span(col(folds, "pull_w"), 2, 1.0)
    sub["cal_folds8_gw"] = _span(col(rows(seed0, FOLDS, sources=(8,), noises=(1, 2)),
                                     "pull_gw"), 2, 1.0)
    # the cusp
    sub["cal_cusp_ffr"] = _span(col(rows(seed0, ("cluster_cusp",)), "ffr"), 2)
    r = one("cluster_cusp", 40, 20)
    sub["cal_cusp40_20_ffr"] = _half_up(r["ffr"], 2, 100)
    sub["cal_cusp40_20_bias"] = _half_up(r["bias"], 1, 100)
    sub["cal_cusp40_20_sig3"] = _half_up(r["sig"] / 3, 1, 100)
    for noise in (1, 20):
        r = one("cluster_cusp", 8, noise)
        sub[f"cal_cusp8_{noise}_w"] = _half_up(r["pull_w"], 2)
        sub[f"cal_cusp8_{noise}_gw"] = _half_up(r["pull_gw"], 2)
        sub[f"cal_cusp8_{noise}_tested"] = _half_up(r["tested"], 0, 100)
    # the galaxy fold
    galaxy8 = rows(seed0, ("galaxy_fold",), sources=(8,))
    sub["cal_gal8_tested"] = " / ".join(_half_up(one("galaxy_fold", 8, noise)["tested"], 0, 100)
                                        for noise in (1, 2, 5))
    for noise in (10, 20):
        sub[f"cal_gal8_tested{noise}"] = _half_up(one("galaxy_fold", 8, noise)["tested"], 0, 100)
    sub["cal_gal8_w"] = _span(col(galaxy8, "pull_w"), 2, 1.0)
    sub["cal_gal8_gw"] = _span(col(galaxy8, "pull_gw"), 2, 1.0)
    galaxy = rows(seed0, ("galaxy_fold",), sources=(20, 40))
    sub["cal_gal_ffr"] = _span(col(galaxy, "ffr"), 2)
    sub["cal_gal_w"] = _span(col(galaxy, "pull_w"), 2, 1.0)
    sub["cal_gal_gw"] = _span(col(galaxy, "pull_gw"), 2, 1.0)
    sub["cal_gal20_1_tested"] = _half_up(one("galaxy_fold", 20, 1)["tested"], 0, 100)
    sub["cal_gal8_ffr_both"] = _span(col(galaxy8 + rows(seed100, ("galaxy_fold",),
                                                        sources=(8,)), "ffr"), 2)
    # power on the cluster fold at 5 mas, a 25 % anomaly
    for method, short in (("adaptive", "power"), ("quad2", "q2_power")):
        sub[f"cal_{short}"] = " / ".join(
            _half_up(one("cluster_fold", n, 5, method)["pow25"], 0, 100) for n in (8, 20, 40))
    for n in (20, 40):
        sub[f"cal_power{n}"] = _half_up(one("cluster_fold", n, 5)["pow25"], 0, 100)
    sub["cal_sig20_5"] = _half_up(one("cluster_fold", 20, 5)["sig"], 1, 100)
    sub["cal_q2_sig20_5"] = _half_up(one("cluster_fold", 20, 5, "quad2")["sig"], 1, 100)
    # 8 sources: the worst false flags of MACS J1149 at 1 mas (either seed set) and
    # of Abell 370 at 5 mas (seed 0)
    m1149 = [seed0[("macs1149_lenstool", 8, "adaptive", 1.0)]["ffr"],
             seed100[("macs1149_lenstool", 8, "adaptive", 1.0)]["ffr"]]
    sub["cal_m1149_8_worst"] = _half_up(max(m1149), 1, 100)
    sub["cal_a370_8_5"] = _half_up(one("a370_lenstool", 8, 5)["ffr"], 1, 100)
    # Abell 370 with 20-40 sources at 10-20 mas, both seed sets
    a370 = [r["ffr"] for cells in (seed0, seed100)
            for r in rows(cells, ("a370_lenstool",), sources=(20, 40), noises=(10, 20))]
    sub["cal_a370_coarse"] = _span(a370, 2)
    return sub


def null_numbers(dev, heldout, demo, first_lines):
    """The substitutions read from the null calibration's runs of its spline map
    (``first_lines``: the tables' first lines, which say their settings)."""
    p5 = f"p_emp <= {NULL_LEVEL:g} % [95 %]"
    sub = {}
    held = [r for r in dev if _interval(r[p5])[0] <= NULL_LEVEL]
    sub["cal_null_held"] = f"{len(held)} of the {len(dev)}"
    sub["cal_null_n_const"] = NULL_HEADER.match(first_lines[0]).group(1)
    sub["cal_null_gal8_warned"] = _null_row(dev, "galaxy_fold", 8)["warned"]
    sub["cal_null_a370_8_warned"] = _null_row(dev, "a370_lenstool", 8)["warned"]
    sub["cal_null_gal12_p5"] = f"{_number(_null_row(dev, 'galaxy_fold', 12)[p5]):.1f}"
    a370 = [_null_row(dev, "a370_lenstool", n) for n in (12, 20)]
    null_rates = _and(f"{_number(r[NULL_RATE]):.1f}" for r in a370)
    flags = _and(f"{_number(r[FLAGS]):.2f}" for r in a370)
    sub["cal_null_a370_rates"] = f"{null_rates} % against the {flags} %"
    compact = [r for r in heldout if r["family"] == "galaxy_sie_compact"]
    flags = _and(f"{_number(r[FLAGS]):.2f}" for r in compact)
    sources = _and(r["sources"] for r in compact)
    sub["cal_compact_flags"] = f"{flags} % of the clean pairs with {sources} sources"
    sub["cal_compact_warned"] = _and(r["warned"] for r in compact[:2])
    sub["cal_compact_p5_20"] = f"{_number(_null_row(heldout, 'galaxy_sie_compact', 20)[p5]):.1f}"
    sub["cal_demo_chi2"] = demo[0]["map chi2/dof"]
    sub["cal_demo_warned"] = demo[0]["warned"]
    return sub


def read_profile_table(path):
    """The cells of ``benchmarks/profile_snr_calibration.py``'s table: per row the
    family, sources, noise and the false-flag rate of each SNR (log, profile,
    cons)."""
    rows = []
    held_out = False
    for line in path.read_text().splitlines():
        parts = line.replace("[", " ").replace("]", " ").replace(",", " ").split()
        if parts and parts[0] == "#" and "held out" in line:
            held_out = True
        if not parts or parts[0].startswith("#") or parts[0] == "family":
            continue
        row = {"family": parts[0], "sources": int(parts[1]), "noise_mas": float(parts[2]),
               "n": int(parts[3]), "held_out": held_out}
        if parts[4] == "untested":  # every pair of the cell untestable
            rows.append(row | {"log": float("nan"), "profile": float("nan"),
                               "cons": float("nan"), "cons_l95": float("nan")})
            continue
        rows.append(row | {"log": float(parts[4]), "profile": float(parts[7]),
                           "cons": float(parts[10]), "cons_l95": float(parts[11])})
    return rows


def profile_numbers(rows):
    """The conservative SNR's largest false-flag rate on the compact galaxy-scale
    folds and Abell 370 with 20-40 sources, against the linearised SNR's."""
    sub = {}
    for key, family in (("compact", "galaxy_sie_compact"), ("a370", "a370_lenstool")):
        cells = [r for r in rows if r["family"] == family]
        sub[f"cal_{key}_cons"] = (f"{_pct(max(r['cons'] for r in cells))} % (the linearised "
                                  f"SNR's: up to {_pct(max(r['log'] for r in cells))} %)")
    return sub


#: The galaxy-scale development families, apart from the cluster-scale ones.
GALAXY_SCALE = ("galaxy_fold", "galaxy_epl_compact", "galaxy_sie_compact", "group_fold")
#: The suite's false-flag target.
FFR_TARGET = 0.005


def small_numbers(rows):
    """The default test with 8 and 12 sources (the geometric test with the
    conservative SNR: the flux field predicts no pair below 13 sources): the
    cells that fail the suite's rule (95 % lower limit above 0.5 %), the
    largest false-flag rate of the other cluster-scale cells, the cells where
    every pair is untestable, and the same on the held-out families."""
    def cell_text(r):
        return (f"``{r['family']}`` with {r['sources']} sources at {r['noise_mas']:g} mas "
                f"({_pct(r['cons'])} %, lower limit {_pct(r['cons_l95'])} %)")

    sub = {}
    for key, held in (("dev", False), ("held", True)):
        part = [r for r in rows if r["held_out"] == held]
        tested = [r for r in part if r["n"] > 0]
        fails = [r for r in tested if r["cons_l95"] > FFR_TARGET]
        # the highest rate of the cluster-scale cells that do not fail
        cluster = [r for r in tested if r["family"] not in GALAXY_SCALE and r not in fails]
        top = max(cluster, key=lambda r: r["cons"])
        sub[f"cal_small_{key}_cluster_max"] = cell_text(top)
        sub[f"cal_small_{key}_fail"] = _and([cell_text(r) for r in fails]) if fails else "none"
        sub[f"cal_small_{key}_n_fail"] = str(len(fails))
        sub[f"cal_small_{key}_cells"] = str(len(part))
        untested = [r for r in part if r["n"] == 0]
        sub[f"cal_small_{key}_untested"] = (_and([
            f"``{r['family']}`` with {r['sources']} sources at {r['noise_mas']:g} mas"
            for r in untested]) if untested else "none")
    return sub


def joint_numbers(rows):
    """The geometric test's false flags on the compact fold at 20 mas with 20-40
    sources, both flux errors (the joint-test page's held-out table)."""
    ffr = [r["ffr_geo"] for r in rows
           if r["family"] == "galaxy_sie_compact" and r["noise_mas"] == 20]
    return {"cal_compact_geo20": f"{_pct(min(ffr))}-{_pct(max(ffr))}"}


#: How the pooled-run prose names the families.
FAMILY_NAMES = {"cluster_fold": "the cluster fold", "cluster_cusp": "the cusp",
                "galaxy_fold": "the galaxy fold", "smacs_analog": "the SMACS0723 analogue",
                "smacs_lenstool": "SMACS0723", "macs1149_lenstool": "MACS J1149",
                "a2744_lenstool": "Abell 2744", "a370_lenstool": "Abell 370",
                "as1063_lenstool": "Abell S1063", "as1063_s13_lenstool": "Abell S1063 system 13"}
#: The cluster-scale families of the page's first bullet.
CLUSTER_SCALE = ("cluster_fold", "cluster_cusp", "smacs_analog", "smacs_lenstool",
                 "macs1149_lenstool", "a2744_lenstool", "as1063_s13_lenstool")
#: The runs pooled into ``suite_pooled70.txt``, as the prose labels them.
SEED_SETS = (("suite_seed0.txt", "seeds 0-9"), ("suite_seed100.txt", "seeds 100-109"),
             ("suite_seed2000.txt", "seeds 2000-2049"))
#: A comment of a pooled cell that the test declines (benchmarks/calibration.py).
DECLINED = re.compile(r"^(\S+) (\d+) adaptive (\S+) .*# declined (\d+) pairs: width (\S+), "
                      r"beyond 3 sigma (\S+)$")


def _cell_name(fam, n_src, noise):
    return f"{FAMILY_NAMES.get(fam, fam)} with {n_src} sources at {noise:g} mas"


def _adaptive_cells(cells):
    """The adaptive estimator's cells, keyed ``(family, n_sources, noise)`` as
    :func:`missed_targets` keys them."""
    return {(k[0], k[1], k[3]): r for k, r in cells.items() if k[2] == "adaptive"}


def pooled_numbers(pooled, sets, declined_lines):
    """The substitutions read from the validation suite pooled over 70
    constellations per cell (``sets``: the three runs pooled, in the order of
    :data:`SEED_SETS`; ``declined_lines``: the pooled table's lines)."""
    cell = _adaptive_cells(pooled)
    set_cells = [_adaptive_cells(cells) for cells in sets]
    n = sum(r["n"] for r in cell.values())
    sub = {"cal_p70_pairs": f"{n / 1e6:.1f}",
           "cal_p70_ffr": _pct(sum(r["n"] * r["ffr"] for r in cell.values()) / n),
           "cal_p70_cells": str(len(cell))}
    missed = missed_targets(pooled)
    sub["cal_p70_missed"] = str(len(missed))
    sig = [k for k, why in missed.items() if any("significant" in w for w in why)]
    sub["cal_p70_nsig"] = str(len(sig))
    sub["cal_p70_sig"] = _and(
        f"{_cell_name(*k)}, {_pct(cell[k]['ffr'])} % (lower limit {_pct(cell[k]['ffr_l95'])} %)"
        for k in sig) if sig else "none"
    labels = " / ".join(label for _, label in SEED_SETS)
    nonsig = [k for k, why in missed.items()
              if any(w.startswith("false flags") for w in why) and k not in sig]
    sub["cal_p70_nonsig"] = _and(
        f"{_cell_name(*k)}, {_pct(cell[k]['ffr'])} % "
        f"({labels}: {' / '.join(_pct(c[k]['ffr']) for c in set_cells)} %)"
        for k in nonsig) if nonsig else "none"
    declined = [m.groups() for m in map(DECLINED.match, declined_lines) if m]
    sub["cal_p70_declined_n"] = str(len(declined))
    sub["cal_p70_declined"] = _and(f"{FAMILY_NAMES.get(d[0], d[0])} at {float(d[2]):g} mas"
                                   for d in declined)
    sub["cal_p70_declined_gw"] = _range([float(d[4]) for d in declined], 1.0)
    sub["cal_p70_declined_out"] = _range([float(d[5]) for d in declined], digits=1)
    widths = [k for k, why in missed.items() if any(w.startswith("width") for w in why)]
    sub["cal_p70_widths"] = _and(f"{_cell_name(*k)} ({cell[k]['pull_gw']:.2f})" for k in widths)
    bias = [k for k, why in missed.items() if any(w.startswith("bias") for w in why)]
    sub["cal_p70_bias"] = _and(f"{_cell_name(*k)}, {_pct(cell[k]['bias'], 1)} % against a "
                               f"third of its median error, {_pct(cell[k]['sig'] / 3, 1)} %"
                               for k in bias) if bias else "none"
    cluster = [r for k, r in cell.items() if k[0] in CLUSTER_SCALE and k[1] >= 20]
    sub["cal_p70_cluster_gw"] = _range([r["pull_gw"] for r in cluster], 1.0)
    sub["cal_p70_cluster_ffr_max"] = _pct(max(r["ffr"] for r in cluster))
    errors = [r["sig"] for k, r in cell.items()
              if k[0] in CLUSTER_SCALE and k[1] == 20 and 5 <= k[2] <= 20]
    sub["cal_p70_err_5_20"] = f"{100 * min(errors):.0f} to {100 * max(errors):.0f}"
    galaxy = [r for k, r in cell.items() if k[0] == "galaxy_fold" and k[1] >= 20]
    sub["cal_p70_gal_ffr"] = _range([r["ffr"] for r in galaxy])
    galaxy8 = [r["pull_w"] for k, r in cell.items()
               if k[0] == "galaxy_fold" and k[1] == 8 and r["tested"] >= 0.5]
    sub["cal_p70_gal8_w"] = f"{max(galaxy8):.1f}"
    fold = {n_src: cell[("cluster_fold", n_src, 5.0)]["pow25"] for n_src in (8, 20, 40)}
    sub["cal_p70_pow8"] = f"{100 * fold[8]:.0f}"
    sub["cal_p70_fold_pow"] = f"{100 * fold[20]:.1f} / {100 * fold[40]:.1f}"
    sub["cal_p70_fold20_pow"] = f"{100 * fold[20]:.1f}"
    sub["cal_sets_fold20_pow"] = _and(
        f"{100 * c[('cluster_fold', 20, 5.0)]['pow25']:.1f}" for c in set_cells)
    for n_src, noises in ((40, (10, 20)), (20, (5, 10))):
        for (_, label), c in zip(SEED_SETS, set_cells, strict=True):
            sub[f"cal_as1063_{n_src}_{label.split()[1].split('-')[0]}"] = " / ".join(
                _pct(c[("as1063_lenstool", n_src, float(x))]["ffr"]) for x in noises)
    return sub


def compute(folder=STATIC):
    """The substitutions (name -> text) from the stored tables under ``folder``."""
    sub = heldout_numbers(read_cells(folder / "calibration" / "heldout_new.txt"))
    paths = [folder / "null_map" / name for name in NULL_TABLES]
    sub |= null_numbers(*(read_null_table(p) for p in paths),
                        [p.read_text().split("\n", 1)[0] for p in paths])
    sub |= joint_numbers(read_joint_table(folder / "joint" / "calibration_heldout.txt"))
    sub |= profile_numbers(read_profile_table(folder / "profile_snr" / "calibration.txt"))
    sub |= small_numbers(read_profile_table(folder / "profile_snr" / "small_constellations.txt"))
    seed0 = read_cells(folder / "calibration" / "suite_seed0.txt")
    seed100 = read_cells(folder / "calibration" / "suite_seed100.txt")
    sub |= other_seed_numbers(seed100)
    sub["cal_s0_missed"] = str(len(missed_targets(seed0)))
    pooled = folder / "calibration" / "suite_pooled70.txt"
    sub |= pooled_numbers(read_cells(pooled),
                          [read_cells(folder / "calibration" / name) for name, _ in SEED_SETS],
                          pooled.read_text().splitlines())
    sub |= suite_numbers(seed0, seed100)
    return sub


def main(out=OUT):
    """Write the include files into ``out`` (the docs' folder by default)."""
    return write(compute(), out)


if __name__ == "__main__":
    main()
