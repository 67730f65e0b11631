"""Make docs/_static/smacs0723_critical_curve.png: the SMACS0723 Lenstool model.

The tangential and radial critical curves of the Mahler et al. (2023) model
at z = 2.17 (system 4's fitted redshift), over the multiple images of
arcs.dat. Needs the model in ../shared/data/smacs0723_mahler2022 (not part of
lensdual); run from the repository root::

    python docs/scripts/lenstool_critical_curve.py
"""

from pathlib import Path

import astropy.units as u
import matplotlib

matplotlib.use("agg")
import matplotlib.pyplot as plt  # noqa: E402

from lensdual.parametric import read_lenstool, read_lenstool_images  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data" / "smacs0723_mahler2022"
OUT = ROOT / "docs" / "_static" / "smacs0723_critical_curve.png"


def main():
    model = read_lenstool(DATA / "best.par")
    images = read_lenstool_images(DATA / "arcs.dat", reference=model)
    system = model.lens_system(2.17)
    curves = system.critical_curves(half_width=70 * u.arcsec, grid_spacing=0.15 * u.arcsec)
    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    for i, c in enumerate(curves):
        ax.plot(c[:, 0], c[:, 1], "r-", lw=0.8, label="critical curve, z = 2.17" if i == 0
                else None)
    for sys_id in sorted(set(images["system"]), key=str):
        sel = images[images["system"] == sys_id]
        ax.plot(sel["x"], sel["y"], "o", ms=4, mfc="none")
        ax.annotate(str(sys_id), (sel["x"][0].value, sel["y"][0].value), fontsize=6,
                    xytext=(3, 3), textcoords="offset points")
    ax.set_xlim(70, -70)  # x points West: East to the left as on the sky
    ax.set_ylim(-70, 70)
    ax.set_aspect("equal")
    ax.set_xlabel("x (arcsec, West)")
    ax.set_ylabel("y (arcsec, North)")
    ax.set_title("SMACS0723, Mahler et al. 2023 (ICLv2): multiple images", fontsize="medium")
    ax.legend(loc="lower left", fontsize="small")
    fig.tight_layout()
    fig.savefig(OUT, dpi=90)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
