"""Make docs/_static/macs1149_knots.png and print the tables of docs/knots.rst.

The knots of the spiral host of SN Refsdal in MACS J1149 (CATS v4 catalogue),
paired across the spiral's macro-images 1.1, 1.2 and 1.3 with the CATS v4
Lenstool model, their model-independent size magnification beside the
model's magnification ratio. Needs ../shared/data/hff_cats_lenstool (not part
of lensdual); run from the repository root::

    python docs/scripts/macs1149_knots.py
"""

from pathlib import Path

import astropy.units as u
import matplotlib
import numpy as np

matplotlib.use("agg")
import matplotlib.pyplot as plt  # noqa: E402

from lensdual.estimators import estimate_sigma_pos  # noqa: E402
from lensdual.pairing import pairs_from_knots, read_macro_images  # noqa: E402
from lensdual.parametric import (  # noqa: E402
    compare_size_with_models,
    plot_size_vs_model,
    read_lenstool,
)

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data" / "hff_cats_lenstool" / "macs1149_v4"
OUT = ROOT / "docs" / "_static" / "macs1149_knots.png"
HALF = 17.0
PAIRS = [("1.1", "1.3"), ("1.2", "1.3"), ("1.1", "1.2")]


def main():
    catalogue = DATA / "imawcs_spiral_secured.mul"
    model = read_lenstool(DATA / "best.par")
    centres = read_macro_images(catalogue, ["1.1", "1.2", "1.3"])
    knots = pairs_from_knots(catalogue, centres, knots=lambda s: 1000 <= int(s) < 2000,
                             model=model)
    print(knots.summary())
    fig, axes = plt.subplots(2, 2, figsize=(11, 10.5))
    ax = axes[0, 0]
    from lensdual.parametric import read_lenstool_images

    cat = read_lenstool_images(catalogue, reference=model)
    sel = np.isin(cat["id"], knots.images["id"])
    cat = cat[sel]
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
        tab = knots.pairs[key]
        t1 = np.column_stack([tab["x1"], tab["y1"]])
        t2 = np.column_stack([tab["x2"], tab["y2"]])
        sigma, degree, dof = estimate_sigma_pos(t1, t2, full_output=True)
        cmp = compare_size_with_models(tab, {"CATS_v4": model}, sigma_pos=sigma)
        plot_size_vs_model(cmp, ax=ax)
        ax.set_title(f"{key[0]} / {key[1]}: {len(tab)} knots, sigma_pos = "
                     f"{sigma.to_value(u.mas):.0f} mas (degree-{degree} residuals)", fontsize=9)
        print(f"\n{key[0]} / {key[1]}: sigma_pos = {sigma.to(u.mas):.0f} (degree {degree}, "
              f"{dof} dof)")
        print(" knot  mu_size  +-ln   status  parity  mu_CATS  +-ln  parity  SNR")
        for r in cmp:
            print(f" {r['knot']:>4}  {r['mu_size']:6.2f}  {r['ln_mu_size_err']:5.2f}  "
                  f"{r['mu_size_status']:>6}  {r['parity']:+d}      {r['mu_CATS_v4']:6.2f}  "
                  f"{r['ln_mu_CATS_v4_err']:5.2f}  {r['parity_CATS_v4']:+d}    "
                  f"{r['snr_CATS_v4']:5.2f}")
        ok = np.isin(cmp["mu_size_status"], ["ok", "misfit"])
        pulls = np.log(cmp["mu_size"] / cmp["mu_CATS_v4"]) / np.hypot(
            cmp["ln_mu_size_err"], cmp["ln_mu_CATS_v4_err"])
        det = cmp["parity"] != 0
        bad = ", ".join(str(k) for k in cmp["knot"][np.asarray(cmp["disagree_CATS_v4"], bool)])
        print(f" tested {int(ok.sum())}, disagree (SNR or parity, > 3) "
              f"{int(cmp['disagree_CATS_v4'].sum())} ({bad}), "
              f"median |pull| {np.median(np.abs(pulls[ok])):.2f}, parity agrees "
              f"{int(np.sum(det & (cmp['parity'] == cmp['parity_CATS_v4'])))} of "
              f"{int(det.sum())} determined")
    fig.tight_layout()
    fig.savefig(OUT, dpi=90)
    print(f"\nwrote {OUT}")


if __name__ == "__main__":
    main()
