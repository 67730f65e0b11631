"""Write docs/_static/joint/status.inc: the numbers the joint-test page's Status quotes.

They are read from the calibration tables of ``benchmarks/joint_calibration.py
--masking`` that the page includes: ``calibration_dev.txt`` (the development
families), ``calibration_heldout.txt`` (the families held out of earlier
choices, run once more) and ``calibration_heldout_new.txt`` (the families no
choice has looked at), so the prose cannot drift from the tables. The history
of the rules (``history_numbers``) is read from the earlier runs the page also
includes: ``calibration_heldout_v1.txt`` (the first version on the first two
held-out families), ``calibration_dev_strict_gate.txt`` (the gate that asked
every neighbour), ``calibration_dev_step2_bound.txt`` (the gate as it stands,
with step 2's earlier bound) and ``calibration_dev_no_drop.txt`` (step 2 as it
stands, before step 1 dropped neighbours off the others' fit). The tables with
``--snr-definition conservative`` (``conservative_numbers``):
``calibration_dev_conservative.txt`` and ``calibration_heldout_conservative.txt``.
Run from the repository root after rerunning the benchmark::

    python docs/scripts/joint_status.py
"""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "docs" / "_static" / "joint"

#: The cluster-scale development families the power targets are read on
#: (Abell 370 and galaxy_fold, where the field is mostly declined, aside).
CLUSTER = ("cluster_fold", "cluster_cusp", "smacs_analog", "smacs_lenstool",
           "macs1149_lenstool", "a2744_lenstool", "as1063_lenstool", "as1063_s13_lenstool")
#: False-flag target at significance 3.
TARGET = 0.005
#: Power target on a 25 % anomaly at 20 mas with 2 % flux errors.
POWER_TARGET = 0.9
#: Short names of the held-out families in the substitutions.
HELD_OUT = {"galaxy_sie_compact": "compact", "a2744_s3_lenstool": "a2744s3",
            "macs1149_s5_lenstool": "m1149s5", "group_fold": "group"}
#: The held-out tables: the families of earlier choices run once more, and the
#: families no choice has looked at, run once.
HELD_OUT_TABLES = ("calibration_heldout.txt", "calibration_heldout_new.txt")


def read_table(path):
    """The rows of a calibration table as dicts (numbers as floats)."""
    lines = [ln.split() for ln in Path(path).read_text().splitlines() if ln.strip()]
    head = lines[0]
    rows = []
    for parts in lines[1:]:
        row = dict(zip(head, parts, strict=True))
        for key in head[1:]:
            row[key] = float(row[key])
        rows.append(row)
    return rows


def held_out_rows(folder=STATIC):
    """The rows of every held-out table."""
    return [row for name in HELD_OUT_TABLES for row in read_table(folder / name)]


def _pct(x, digits=0):
    return f"{100 * x:.{digits}f}"


def _range(values, digits=0):
    lo, hi = _pct(min(values), digits), _pct(max(values), digits)
    return f"{lo} %" if lo == hi else f"{lo} to {hi} %"


def compute(dev, heldout):
    """The substitutions (name -> text) from the rows of both tables."""
    sub = {"jt_cells": str(len(dev))}
    sub["jt_cells_ok"] = str(sum(r["ffr"] <= TARGET for r in dev))
    sub["jt_cells_fail"] = str(sum(r["ffr_l95"] > TARGET for r in dev))
    above = [r for r in dev if r["ffr"] > TARGET]
    sub["jt_cells_above"] = str(len(above))
    parts = []
    for fam in dict.fromkeys(r["family"] for r in above):
        rows = [r for r in above if r["family"] == fam]
        parts.append(f"``{fam}`` ({len(rows)}: {_range([r['ffr'] for r in rows], 2)}, "
                     f"geometric {_range([r['ffr_geo'] for r in rows], 2)})")
    sub["jt_above_list"] = "; ".join(parts) if parts else "none"
    pulls = [r["field_pull_w"] for r in dev if r["field"] >= 0.5]
    sub["jt_pull_range"] = f"{min(pulls):.2f} to {max(pulls):.2f}"

    def cells(n, noise, ferr, fams=CLUSTER):
        return [r for r in dev if r["family"] in fams and r["n_sources"] == n
                and r["noise_mas"] == noise and r["flux_err"] == ferr]

    for n in (20, 40):
        rows = cells(n, 20, 0.02)
        sub[f"jt_pow{n}"] = _range([r["pow25"] for r in rows])
        sub[f"jt_powgeo{n}"] = _range([r["pow25_geo"] for r in rows])
        met = [r["family"] for r in rows if r["pow25"] >= POWER_TARGET]
        sub[f"jt_pow{n}_met"] = f"{len(met)} of {len(rows)}"
        miss = sorted((r["pow25"], r["family"]) for r in rows if r["pow25"] < POWER_TARGET)
        sub[f"jt_pow{n}_miss"] = (", ".join(f"``{f}`` {_pct(p)} %" for p, f in miss)
                                  if miss else "none")
    sub["jt_pow5pc"] = _range([r["pow25"] for n in (20, 40) for r in cells(n, 20, 0.05)])
    one = [r["pow25"] - r["pow25_geo"] for n in (20, 40) for r in cells(n, 1, 0.02)]
    sub["jt_pow1mas_gain"] = f"{100 * min(one):+.1f} to {100 * max(one):+.1f}"
    below = [r for r in dev if r["pow25"] < r["pow25_geo"] - 0.005]
    sub["jt_below_geo"] = str(len(below))
    sub["jt_mask"], sub["jt_mask_worst"] = _masking(dev)
    for fam, short in HELD_OUT.items():
        rows = [r for r in heldout if r["family"] == fam]
        if not rows:
            continue
        sub[f"jt_{short}_field_max"] = _pct(max(r["field"] for r in rows))
        top = max(rows, key=lambda r: r["ffr"])
        sub[f"jt_{short}_ffr_max"] = (
            f"{_pct(top['ffr'], 2)} % (95 % lower limit {_pct(top['ffr_l95'], 2)} %, "
            f"{int(top['n_sources'])} sources, {top['noise_mas']:g} mas, geometric "
            f"{_pct(top['ffr_geo'], 2)} %)")
        sub[f"jt_{short}_fail"] = str(sum(r["ffr_l95"] > TARGET for r in rows))
        for n in (20, 40):
            at = [r for r in rows if r["n_sources"] == n]
            p20 = [r for r in at if r["noise_mas"] == 20 and r["flux_err"] == 0.02]
            m5 = [r for r in at if r["noise_mas"] == 5 and r["flux_err"] == 0.02]
            if p20:
                sub[f"jt_{short}_pow{n}"] = f"{_pct(p20[0]['pow25'])} %"
                sub[f"jt_{short}_powgeo{n}"] = f"{_pct(p20[0]['pow25_geo'])} %"
            if m5:
                sub[f"jt_{short}_mask{n}"] = f"{_pct(m5[0]['mask25'])} %"
    return sub


def _cell(rows, family, n_sources, noise, flux_err=0.02):
    """The row of one cell of a calibration table."""
    return next(r for r in rows if r["family"] == family and r["n_sources"] == n_sources
                and r["noise_mas"] == noise and r["flux_err"] == flux_err)


def _masking(rows):
    """The masking trial's range at 5 mas and 2 % flux errors on the cluster-scale
    families (20 and 40 sources) and its lowest cell, as text."""
    mask = [r for r in rows if r["family"] in CLUSTER and r["noise_mas"] == 5
            and r["flux_err"] == 0.02]
    worst = min(mask, key=lambda r: r["mask25"])
    return (_range([r["mask25"] for r in mask]),
            f"``{worst['family']}`` with {int(worst['n_sources'])} sources, "
            f"{_pct(worst['mask25'])} %")


def history_numbers(folder=STATIC):
    """The substitutions of "How the rules were reached": Abell 370's false flags
    in the first held-out run (20 sources at 1 and 5 mas, 2 % flux errors), the
    fraction of pairs with a field and the power on ``cluster_cusp`` with 20
    sources at 20 mas under the gate that asked every neighbour and under the
    binomial gate, both with step 2's earlier bound, and the masking trial
    before step 1 dropped neighbours."""
    first = read_table(folder / "calibration_heldout_v1.txt")
    strict = read_table(folder / "calibration_dev_strict_gate.txt")
    # the binomial gate against the strict one, both with step 2's earlier bound
    dev = read_table(folder / "calibration_dev_step2_bound.txt")
    sub = {"jt_v1_a370": _range([_cell(first, "a370_lenstool", 20, noise)["ffr"]
                                 for noise in (1, 5)], 1)}
    for rows, when in ((strict, "strict"), (dev, "now")):
        cell = _cell(rows, "cluster_cusp", 20, 20)
        sub[f"jt_gate_field_{when}"] = _pct(cell["field"])
        sub[f"jt_gate_pow_{when}"] = _pct(cell["pow25"])
    sub["jt_mask_nodrop"], sub["jt_mask_nodrop_worst"] = _masking(
        read_table(folder / "calibration_dev_no_drop.txt"))
    return sub


#: The error models of ``benchmarks/joint_field_variants.py``, stored as
#: ``variants_<name>.txt``.
VARIANTS = ("bound", "eb", "honest")


def read_variant(path):
    """The rows of a ``joint_field_variants.py`` record (its header lines and the
    cells' timing comments skipped), and its number of constellations per cell."""
    lines = Path(path).read_text().splitlines()
    settings = next(ln for ln in lines if ln.startswith("# variant"))
    n_const = int(settings.split("; ")[1].split()[0])
    body = [ln.split("#")[0].split() for ln in lines if not ln.startswith(("#", "cores:", "load"))]
    head = body[0]
    rows = []
    for parts in body[1:]:
        if parts:
            row = dict(zip(head, parts, strict=True))
            for key in head[1:]:
                row[key] = float(row[key])
            rows.append(row)
    return rows, n_const


def variant_numbers(folder=STATIC):
    """The substitutions of the error models tried for steps 2 and 4: per model,
    the field's pull widths and the power on a 25 % anomaly at 20 mas (20 and 40
    sources) on the cluster-scale families, how many of them reach the power
    target with 20 sources, and the cells that fail by the suite's rule."""
    sub = {}
    for name in VARIANTS:
        rows, n_const = read_variant(folder / f"variants_{name}.txt")
        sub["jt_var_n_const"] = str(n_const)
        cluster = [r for r in rows if r["family"] in CLUSTER]
        sub[f"jt_var_{name}_pull"] = (f"{min(r['field_pull_w'] for r in cluster):.2f} to "
                                      f"{max(r['field_pull_w'] for r in cluster):.2f}")
        for n_src in (20, 40):
            pow20 = [r["pow25"] for r in cluster
                     if r["n_sources"] == n_src and r["noise_mas"] == 20]
            sub[f"jt_var_{name}_pow{n_src}"] = _range(pow20)
            met = sum(p >= POWER_TARGET for p in pow20)
            sub[f"jt_var_{name}_met{n_src}"] = f"{met} of {len(pow20)}"
        fail = [f"``{r['family']}`` with {int(r['n_sources'])} sources at {r['noise_mas']:g} "
                f"mas ({_pct(r['ffr'], 2)} %, lower limit {_pct(r['ffr_l95'], 2)} %)"
                for r in rows if r["ffr_l95"] > TARGET]
        sub[f"jt_var_{name}_fail"] = "; ".join(fail) if fail else "none"
    return sub


#: The joint test's tables with ``--snr-definition conservative``: the development
#: families (with the second compact galaxy-scale fold) and the held-out ones, run once.
CONSERVATIVE_TABLES = ("calibration_dev_conservative.txt",
                       "calibration_heldout_conservative.txt")


def conservative_numbers(folder=STATIC):
    """The joint test with the conservative SNR against the linearised one."""
    dev_c, held_c = (read_table(folder / name) for name in CONSERVATIVE_TABLES)
    dev = read_table(folder / "calibration_dev.txt")
    sub = {"jt_cons_cells": str(len(dev_c)),
           "jt_cons_cells_ok": str(sum(r["ffr"] <= TARGET for r in dev_c)),
           "jt_cons_cells_fail": str(sum(r["ffr_l95"] > TARGET for r in dev_c))}
    for key, fam in (("a370", "a370_lenstool"), ("galfold", "galaxy_fold"),
                     ("compact", "galaxy_epl_compact")):
        worst = max((r for r in dev_c if r["family"] == fam), key=lambda r: r["ffr"])
        sub[f"jt_cons_{key}_ffr_max"] = (
            f"{_pct(worst['ffr'], 2)} % ({round(worst['ffr'] * worst['n'])} of "
            f"{int(worst['n'])} tested pairs with {int(worst['n_sources'])} sources at "
            f"{worst['noise_mas']:g} mas)")
    old = [r for r in dev if r["family"] in ("a370_lenstool", "galaxy_fold")]
    sub["jt_log_a370gal_ffr_max"] = f"{_pct(max(r['ffr'] for r in old), 2)} %"
    # the same cells of both tables: the largest change of power and of masking
    key = ("family", "n_sources", "noise_mas", "flux_err")
    by_key = {tuple(r[k] for k in key): r for r in dev}
    pairs = [(by_key[tuple(r[k] for k in key)], r) for r in dev_c
             if tuple(r[k] for k in key) in by_key]
    sub["jt_cons_pow_change"] = _pct(max(abs(a["pow25"] - b["pow25"]) for a, b in pairs), 1)
    sub["jt_cons_mask_change"] = _pct(
        max(abs(a["mask25"] - b["mask25"]) for a, b in pairs
            if a["mask25"] == a["mask25"] and b["mask25"] == b["mask25"]), 0)
    # cells where the default (the joint test with the conservative SNR) is more than
    # half a point below the geometric test, with either SNR
    sub["jt_cons_below_geo"] = str(sum(
        b["pow25"] < min(b["pow25_geo"], a["pow25_geo"]) - 0.005 for a, b in pairs))
    sub["jt_cons_cells_common"] = str(len(pairs))
    sub["jt_cons_held_fail"] = str(sum(r["ffr_l95"] > TARGET for r in held_c))
    sub["jt_cons_held_ffr_max"] = f"{_pct(max(r['ffr'] for r in held_c), 2)} %"
    compact = [r for r in held_c if r["family"] == "galaxy_sie_compact"]
    sub["jt_cons_held_compact_ffr_max"] = f"{_pct(max(r['ffr'] for r in compact), 2)} %"
    return sub


def include_files(sub):
    """``{"status.inc": text}``: one reST substitution per number."""
    text = "".join(f".. |{k}| replace:: {v}\n" for k, v in sub.items())
    return {"status.inc": text}


def main():
    dev = read_table(STATIC / "calibration_dev.txt")
    sub = (compute(dev, held_out_rows()) | history_numbers(STATIC) | variant_numbers()
           | conservative_numbers())
    for name, text in include_files(sub).items():
        (STATIC / name).write_text(text)
        print(text, end="")
    return sub


if __name__ == "__main__":
    main()
