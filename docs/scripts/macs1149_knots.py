"""Make docs/_static/macs1149_knots.png and the numbers and tables of docs/knots.rst.

The knots of the spiral host of SN Refsdal in MACS J1149 (CATS v4 catalogue),
paired across the spiral's macro-images 1.1, 1.2 and 1.3 with the CATS v4
Lenstool model, their model-independent size magnification beside the
model's magnification ratio. Needs the CATS models folder (``$LENSDUAL_HFF_DIR``,
else ../shared/data/hff_cats_lenstool; not part of lensdual); run from the
repository root::

    python docs/scripts/macs1149_knots.py [--no-figure]

Writes into ``docs/_static/knots/`` the files that docs/knots.rst includes
(:func:`include_files`): ``numbers.inc`` (reST substitutions of every number the
page quotes), ``table.inc`` (the summary table), ``summary.txt`` (the
assignment) and ``comparison.txt`` (every knot). ``tests/test_docs_numbers.py``
checks that the committed files are what this script writes.
"""

import argparse
import os
from pathlib import Path

import astropy.units as u
import numpy as np

from lensdual.estimators import estimate_sigma_pos
from lensdual.pairing import pairs_from_knots, read_macro_images
from lensdual.parametric import compare_size_with_models, read_lenstool, read_lenstool_images

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "docs" / "_static"
INCLUDES = STATIC / "knots"
FIGURE = STATIC / "macs1149_knots.png"
HALF = 17.0
MACROS = ["1.1", "1.2", "1.3"]
PAIRS = [("1.1", "1.3"), ("1.2", "1.3"), ("1.1", "1.2")]
#: The knots of the spiral host: catalogue systems 1000-1999.
KNOT_SYSTEMS = (1000, 2000)
#: The knots next to the cluster member that lenses SN Refsdal (on 1.1).
MEMBER_KNOTS = ("1026", "1050", "1052")
#: The catalogue's rounding of positions (degrees).
ROUNDING_DEG = 1e-5
#: The median |pull| of unit Gaussian pulls.
GAUSSIAN_MEDIAN_PULL = 0.6745


def data_dir():
    """The folder of the CATS v4 MACS J1149 model and catalogue."""
    hff = os.environ.get("LENSDUAL_HFF_DIR") or ROOT.parent / "shared/data/hff_cats_lenstool"
    return Path(hff) / "macs1149_v4"


def is_knot(system):
    return KNOT_SYSTEMS[0] <= int(system) < KNOT_SYSTEMS[1]


def compute(data=None):
    """The knot pairs (by the model and by the centres) and the comparison per pair."""
    data = data_dir() if data is None else Path(data)
    catalogue = data / "imawcs_spiral_secured.mul"
    model = read_lenstool(data / "best.par")
    centres = read_macro_images(catalogue, MACROS)
    knots = pairs_from_knots(catalogue, centres, knots=is_knot, model=model)
    by_centre = pairs_from_knots(catalogue, centres, knots=is_knot)
    comparisons = {}
    for key in PAIRS:
        tab = knots.pairs[key]
        t1 = np.column_stack([tab["x1"], tab["y1"]])
        t2 = np.column_stack([tab["x2"], tab["y2"]])
        sigma, degree, dof = estimate_sigma_pos(t1, t2, full_output=True)
        cmp = compare_size_with_models(tab, {"CATS_v4": model}, sigma_pos=sigma)
        comparisons[key] = {"table": cmp, "pairs": tab, "sigma": sigma, "degree": degree,
                            "dof": dof}
    return {"catalogue": catalogue, "model": model, "knots": knots, "by_centre": by_centre,
            "comparisons": comparisons}


def _pair_stats(c):
    cmp = c["table"]
    ok = np.isin(cmp["mu_size_status"], ["ok", "misfit"])
    pulls = np.log(cmp["mu_size"] / cmp["mu_CATS_v4"]) / np.hypot(
        cmp["ln_mu_size_err"], cmp["ln_mu_CATS_v4_err"])
    det = cmp["parity"] != 0
    bad = np.asarray(cmp["disagree_CATS_v4"], bool)
    return {"n": len(cmp), "tested": int(ok.sum()), "disagree": [str(k) for k in cmp["knot"][bad]],
            "median_pull": float(np.median(np.abs(pulls[ok]))),
            "parity_agree": int(np.sum(det & (cmp["parity"] == cmp["parity_CATS_v4"]))),
            "parity_determined": int(det.sum())}


def _row(cmp, knot):
    return cmp[list(cmp["knot"]).index(knot)]


def _f(x, digits=2):
    return f"{x:.{digits}f}"


def numbers(result):
    """``{name: text}`` of every number docs/knots.rst quotes."""
    knots, cmps, model = result["knots"], result["comparisons"], result["model"]
    cat = read_lenstool_images(result["catalogue"], reference=model)
    systems = {int(s) for s in cat["system"] if is_knot(s)}
    out = {"n_knots": str(len(systems)), "knot_ids": f"{min(systems)}–{max(systems)}",
           "z_source": f"{knots.z_source}", "n_images": str(len(knots.images))}
    for key in PAIRS:
        tag = key[0].replace(".", "") + key[1].replace(".", "")
        s = _pair_stats(cmps[key])
        out[f"n_{tag}"] = str(s["n"])
        out[f"sigma_{tag}"] = f"{cmps[key]['sigma'].to_value(u.mas):.0f} mas"
        out[f"pull_{tag}"] = _f(s["median_pull"])
        n_centre = len(result["by_centre"].pairs[key])
        out[f"centre_{tag}"] = str(n_centre)
    stats = [_pair_stats(cmps[k]) for k in PAIRS]
    tested = sum(s["tested"] for s in stats)
    out["n_tested"] = str(tested)
    out["n_agree"] = str(tested - sum(len(s["disagree"]) for s in stats))
    out["n_disagree"] = str(sum(len(s["disagree"]) for s in stats))
    status = np.asarray(result["by_centre"].images["status"])
    out["centre_extra"] = str(int(np.sum(status == "extra")))
    sig = [cmps[k]["sigma"].to_value(u.mas) for k in PAIRS]
    out["sigma_min"], out["sigma_max"] = f"{min(sig):.0f}", f"{max(sig):.0f}"
    out["gaussian_pull"] = _f(GAUSSIAN_MEDIAN_PULL)
    step = (ROUNDING_DEG * u.deg).to_value(u.mas)
    rounding = step / np.sqrt(12)
    out["rounding_step"] = f"{step:.0f} mas"
    out["rounding_rms"] = f"{rounding:.0f} mas"
    out["rounding_factor"] = f"{min(sig) / rounding:.0f}"
    # knot 1052 across 1.1 / 1.2: the parity's significance
    out["parity_snr_1052"] = f"{_row(cmps[('1.1', '1.2')]['table'], '1052')['parity_snr']:.1f}"
    # the knots by the cluster member (on 1.1): model ratio and mu_size, 1.1 / 1.3 and 1.1 / 1.2
    member = [_row(cmps[k]["table"], n) for k in PAIRS if k[0] == "1.1" for n in MEMBER_KNOTS]
    ratios = [r["mu_CATS_v4"] for r in member]
    sizes = [r["mu_size"] for r in member]
    out["member_model"] = f"{min(ratios):.1f}–{max(ratios):.1f}"
    out["member_size"] = f"{min(sizes):.1f}–{max(sizes):.1f}"
    # knot 1003 across 1.2 / 1.3, and the model's magnification of its images
    r = _row(cmps[("1.2", "1.3")]["table"], "1003")
    out["k1003_model"], out["k1003_size"] = _f(r["mu_CATS_v4"], 1), _f(r["mu_size"], 1)
    out["k1003_lnerr"] = _f(r["ln_mu_size_err"])
    lens = model.lens_model(knots.z_source)
    for macro, key, side in (("11", ("1.1", "1.3"), "1"), ("12", ("1.2", "1.3"), "1"),
                             ("13", ("1.2", "1.3"), "2")):
        sky = _row(cmps[key]["pairs"], "1003")[f"sky{side}"]
        x, y = np.ravel(model.to_model_frame(sky).to_value(u.arcsec))
        out[f"k1003_mu{macro}"] = f"{float(lens.magnification(x, y)):+.0f}"
    # 1.1 / 1.2: ranges of mu_size, of the model ratio, the largest error of ln mu_size
    t = cmps[("1.1", "1.2")]["table"]
    out["size_range_1112"] = f"{np.min(t['mu_size']):.2f}–{np.max(t['mu_size']):.2f}"
    out["model_range_1112"] = f"{np.min(t['mu_CATS_v4']):.2f}–{np.max(t['mu_CATS_v4']):.1f}"
    out["max_lnerr_1112"] = _f(np.max(t["ln_mu_size_err"]), 1)
    return out


def substitutions(values):
    """reST substitution definitions, ``|knots_<name>|``, one a line."""
    return "".join(f".. |knots_{k}| replace:: {v}\n" for k, v in values.items())


def summary_table(result):
    """The list-table of the page: one row per pair of macro-images."""
    lines = [".. list-table:: MACS J1149 knots: ``mu_size`` against the CATS v4 model",
             "   :header-rows: 1", ""]
    head = ["macro-images", "knots", "``sigma_pos`` (fit degree)", "tested",
            "disagree (> 3 sigma)", "median ``|pull|``", "parity agrees (where determined)"]
    rows = [head]
    for key in PAIRS:
        c = result["comparisons"][key]
        s = _pair_stats(c)
        bad = f"{len(s['disagree'])} ({', '.join(s['disagree'])})" if s["disagree"] else "0"
        rows.append([f"{key[0]} / {key[1]}", str(s["n"]),
                     f"{c['sigma'].to_value(u.mas):.0f} mas ({c['degree']})", str(s["tested"]),
                     bad, _f(s["median_pull"]), f"{s['parity_agree']} / {s['parity_determined']}"])
    for row in rows:
        lines.append(f"   * - {row[0]}")
        lines.extend(f"     - {cell}" for cell in row[1:])
    return "\n".join(lines) + "\n"


def comparison_text(result):
    """Every knot of every pair of macro-images, as a text table."""
    lines = []
    for key in PAIRS:
        c = result["comparisons"][key]
        s = _pair_stats(c)
        lines.append(f"{key[0]} / {key[1]}: sigma_pos = {c['sigma'].to_value(u.mas):.0f} mas "
                     f"(degree {c['degree']}, {c['dof']} dof)")
        lines.append(" knot  mu_size  +-ln   status  parity  mu_CATS  +-ln  parity  SNR")
        for r in c["table"]:
            lines.append(f" {r['knot']:>4}  {r['mu_size']:6.2f}  {r['ln_mu_size_err']:5.2f}  "
                         f"{r['mu_size_status']:>6}  {r['parity']:+d}      "
                         f"{r['mu_CATS_v4']:6.2f}  {r['ln_mu_CATS_v4_err']:5.2f}  "
                         f"{r['parity_CATS_v4']:+d}    {r['snr_CATS_v4']:5.2f}")
        lines.append(f" tested {s['tested']}, disagree (SNR or parity, > 3) "
                     f"{len(s['disagree'])} ({', '.join(s['disagree'])}), median |pull| "
                     f"{s['median_pull']:.2f}, parity agrees {s['parity_agree']} of "
                     f"{s['parity_determined']} determined")
        lines.append("")
    return "\n".join(lines[:-1]) + "\n"


def include_files(result):
    """``{file name in docs/_static/knots: text}`` of the files docs/knots.rst includes."""
    return {"numbers.inc": substitutions(numbers(result)),
            "table.inc": summary_table(result),
            "summary.txt": result["knots"].summary() + "\n",
            "comparison.txt": comparison_text(result)}


def figure(result, path=FIGURE):
    """The knots over the critical curve, and mu_size against the model for each pair."""
    import matplotlib

    matplotlib.use("agg")
    import matplotlib.pyplot as plt

    from lensdual.parametric import plot_size_vs_model

    knots, model = result["knots"], result["model"]
    fig, axes = plt.subplots(2, 2, figsize=(11, 10.5))
    ax = axes[0, 0]
    cat = read_lenstool_images(result["catalogue"], reference=model)
    cat = cat[np.isin(cat["id"], knots.images["id"])]
    status = dict(zip(knots.images["id"], knots.images["status"], strict=True))
    mxy = model.to_model_frame(knots.macro_images["sky"]).value
    centre = 0.5 * (mxy.min(axis=0) + mxy.max(axis=0))
    system = model.lens_system(knots.z_source)
    curves = system.critical_curves(center=centre * u.arcsec, half_width=HALF * u.arcsec,
                                    grid_spacing=0.05 * u.arcsec)
    for i, c in enumerate(curves):
        ax.plot(c[:, 0], c[:, 1], "r-", lw=0.7,
                label=f"critical curve, z = {knots.z_source}" if i == 0 else None)
    colours = {"used": "C0", "extra": "C1", "unassigned": "0.5", "inconsistent": "C3",
               "single": "C4", "ambiguous": "C2"}
    for st, col in colours.items():
        s = np.array([status[i] == st for i in cat["id"]])
        if s.any():
            ax.plot(cat["x"][s], cat["y"][s], "o", ms=3.5, color=col, mfc="none" if st != "used"
                    else col, label=f"{st} ({int(s.sum())})")
    for name, (x, y) in zip(knots.macro_images["name"], mxy, strict=True):
        ax.annotate(name, (x, y), fontsize=11, xytext=(8, -14), textcoords="offset points")
    ax.set_xlim(centre[0] + HALF, centre[0] - HALF)
    ax.set_ylim(centre[1] - HALF, centre[1] + HALF)
    ax.set_aspect("equal")
    ax.set_xlabel("x (arcsec, West)")
    ax.set_ylabel("y (arcsec, North)")
    ax.legend(fontsize="x-small", loc="lower right")
    ax.set_title("knot images of the SN Refsdal host (CATS v4)", fontsize=9)
    for ax, key in zip(axes.flat[1:], PAIRS, strict=True):
        c = result["comparisons"][key]
        plot_size_vs_model(c["table"], ax=ax)
        ax.set_title(f"{key[0]} / {key[1]}: {len(c['table'])} knots, sigma_pos = "
                     f"{c['sigma'].to_value(u.mas):.0f} mas (degree-{c['degree']} residuals)",
                     fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-figure", action="store_true", help="write the include files only")
    args = parser.parse_args(argv)
    result = compute()
    INCLUDES.mkdir(parents=True, exist_ok=True)
    for name, text in include_files(result).items():
        (INCLUDES / name).write_text(text)
        print(f"wrote {INCLUDES / name}")
    print(result["knots"].summary())
    print()
    print(comparison_text(result))
    if not args.no_figure:
        figure(result)
        print(f"wrote {FIGURE}")


if __name__ == "__main__":
    main()
